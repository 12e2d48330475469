"""Fit the latent temperature T (var' = T var) of a trained run on its val split and keep it beside the checkpoint.

The val split's targets are the stage-1 codes `codes_val.pt` of the run's decoder (latent-optimised
with the decoder frozen); its images are the world's renders, prepared as evaluation prepares them.
`temperature.json` = {"temperature", "n_images", "nll_before", "nll_after", "checkpoint"}.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader

from ushape import atomic
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.encoder.datamodule import RenderDataset
from ushape.recalibration.temperature import fit_temperature, gaussian_nll_with_temperature
from ushape.reconstruction.predictor import Predictor, temperature_path


def val_predictions(predictor: Predictor, world: str | Path, batch_size: int = 32) -> tuple[torch.Tensor, ...]:
    """(mu [N, D], var [N, D], code [N, D]) of every val render, without any temperature."""
    codes = load_codes(Path(predictor.model.hparams.decoder_path) / codes_file("val"))
    dataset = RenderDataset(world, "val", codes, predictor.image_size)
    saved, predictor.temperature = predictor.temperature, None
    mus, variances, targets = [], [], []
    try:
        for batch in DataLoader(dataset, batch_size=batch_size):
            mu, var = predictor.encode(batch["image"])
            mus.append(mu), variances.append(var), targets.append(batch["code"])
    finally:
        predictor.temperature = saved
    return torch.cat(mus), torch.cat(variances), torch.cat(targets)


def fit_and_store_temperature(predictor: Predictor, world: str | Path | None = None) -> dict[str, Any]:
    """Fit T on the run's val split, write temperature.json beside the checkpoint, return its content."""
    world = world or predictor.world
    if world is None:
        raise ValueError("which world's val split? pass a run folder (its run.json names the world) or `world=`")
    mu, var, code = val_predictions(predictor, world)
    temperature = fit_temperature(mu, var, code)
    record = {
        "temperature": temperature,
        "n_images": int(mu.shape[0]),
        "nll_before": gaussian_nll_with_temperature(mu, var, code, 1.0),
        "nll_after": gaussian_nll_with_temperature(mu, var, code, temperature),
        "checkpoint": str(predictor.checkpoint),
        "world": str(world),
    }
    atomic.write_json(temperature_path(predictor.checkpoint), record)
    return record
