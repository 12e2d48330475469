"""The camera-azimuth head of a trained encoder (`ushape.encoder.viewpoint`), fitted on its world's renders and
stored beside its checkpoint (`reconstruct.py --fit-viewpoint`), where the predictor and a shipped model load it.

Its features are the predictor's own: each render loaded and framed as reconstruct.py loads an input image,
then the frozen backbone, so the head reads at run time exactly what it was trained on.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ushape.data.layout import WorldIndex
from ushape.encoder.datamodule import view_files
from ushape.encoder.viewpoint import (
    camera_azimuth_elevation,
    fit_viewpoint_head,
    save_viewpoint_head,
    viewpoint_scores,
)
from ushape.errors import InputError
from ushape.reconstruction.predictor import Predictor
from ushape.workspace import VIEWPOINT_FILE

log = logging.getLogger(__name__)


def split_features(predictor: Predictor, world: WorldIndex, split: str, n_shapes: int | None) -> tuple:
    """(features [N, F], azimuths [N] degrees) of every render of the split's first n_shapes shapes."""
    features, azimuths = [], []
    for shape_id in world.shape_ids(split)[:n_shapes]:
        images, _, _ = predictor.load_images(view_files(world.root, shape_id))
        features.append(predictor.features(images))
        with np.load(world.views_path(shape_id)) as data:
            azimuths += [camera_azimuth_elevation(w2c)[0] for w2c in data["world_to_cam"]]
    if not features:
        raise InputError(f"the world {world.root} has no {split} shapes to fit the viewpoint head on")
    return torch.cat(features), torch.tensor(azimuths, dtype=torch.float64)


def fit_and_store_viewpoint(
    predictor: Predictor, n_shapes: int | None = None, val_shapes: int = 100, epochs: int = 30
) -> dict[str, Any]:
    """Fit the head on the train renders of the predictor's world (the first n_shapes; all where None), score it on
    val_shapes val shapes, store it beside the checkpoint and return its record."""
    if predictor.world is None:
        raise InputError("the viewpoint head is fitted on the model's world: pass a run (--run), not a shipped model")
    world = WorldIndex.load(predictor.world)
    started = time.perf_counter()
    train_x, train_az = split_features(predictor, world, "train", n_shapes)
    val_x, val_az = split_features(predictor, world, "val", val_shapes)
    encoded = time.perf_counter() - started
    head = fit_viewpoint_head(train_x, train_az, epochs=epochs)
    scores = {**viewpoint_scores(head, val_x, val_az), "train_views": int(train_x.shape[0])}
    scores.update(encode_seconds=round(encoded, 1), fit_seconds=round(time.perf_counter() - started - encoded, 1))
    path = Path(predictor.checkpoint).parent / VIEWPOINT_FILE
    save_viewpoint_head(head, path, scores)
    log.info("viewpoint head -> %s: %s", path, scores)
    return {"path": str(path), **scores}
