"""Reconstruction from user images: a trained run as a predictor, fusion, mesh with uncertainty, outputs."""

from ushape.reconstruction.predictor import Predictor, collect_inputs, latest_run, load_predictor

__all__ = ["Predictor", "collect_inputs", "latest_run", "load_predictor"]
