"""Stage 2 on a frozen backbone: each view's features computed once and cached, only the head trains.

Fine-tuning a backbone on a few thousand renders memorises them (quickstart chairs: the training loss
keeps falling after epoch 2 while the held-out error stays flat), and on 2 CPU cores it limits the
images to 64 px. With the backbone frozen, every training view is encoded once at native resolution,
as a clean pass and `train_passes - 1` augmented passes (crops, flips: what the variance must learn
to react to), and an epoch of the head costs milliseconds. The features are cached beside the world
(`<world>/features/`), keyed by everything that determines them, so the jobs of a sweep share them.
Validation and test views are encoded clean, as the image pipeline serves them.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path
from typing import Any, Callable

import lightning as L
import torch
from filelock import FileLock
from torch import Tensor
from torch.utils.data import ConcatDataset, DataLoader, Dataset

from ushape import atomic
from ushape.encoder.datamodule import EncoderDataModule, RenderDataset, SplitLoaders

log = logging.getLogger(__name__)

FEATURES_DIR = "features"


class FeatureDataset(Dataset):
    """Cached features [N, F] of views, with each view's code -> dict(features, code, shape_id, view)."""

    def __init__(self, features: Tensor, items: list[tuple[str, int]], codes: dict[str, Tensor]) -> None:
        if features.ndim != 2 or features.shape[0] != len(items):
            raise ValueError(f"features {tuple(features.shape)} do not match {len(items)} views")
        self.features, self.items, self.codes = features, items, codes

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict:
        shape_id, view = self.items[index]
        return {"features": self.features[index], "code": self.codes[shape_id], "shape_id": shape_id, "view": view}


@torch.no_grad()
def encode_views(dataset: Dataset, features: Callable[[Tensor], Tensor], batch_size: int = 64) -> Tensor:
    """Backbone features [N, F] of every image of `dataset` (items with "image" [3, H, W]), in order."""
    parts = [features(batch["image"]) for batch in DataLoader(dataset, batch_size=batch_size)]
    return torch.cat(parts).float()


class FeatureDataModule(SplitLoaders, L.LightningDataModule):
    """The views of an EncoderDataModule as cached frozen-backbone features (module docstring).

    `features(images [B, 3, H, W]) -> [B, F]` is the frozen part of the encoder; `identity` names it
    in the cache key (backbone config), together with the world, image size and augmentation.
    """

    def __init__(
        self,
        images: EncoderDataModule,
        features: Callable[[Tensor], Tensor],
        identity: dict[str, Any],
        train_passes: int = 4,
        batch_size: int = 256,
    ) -> None:
        super().__init__()
        if train_passes < 1:
            raise ValueError(f"train_passes must be >= 1 (one clean pass, the rest augmented), got {train_passes}")
        self.images, self.features, self.identity = images, features, identity
        self.train_passes, self.batch_size = train_passes, batch_size
        self.datasets: dict[str, FeatureDataset] = {}

    def _passes(self, split: str) -> list[RenderDataset]:
        """The image datasets whose views are cached: clean, then augmented with fixed seeds (train only)."""
        clean = self.images.dataset(split, train=False)
        if split != "train":
            return [clean]
        seed = self.images.hparams.seed
        return [clean] + [
            self.images.dataset(split, train=True, seed=seed * 1000 + p) for p in range(1, self.train_passes)
        ]

    def cache_file(self, split: str) -> Path:
        hp = self.images.hparams
        key = {
            "identity": self.identity,
            "split": split,
            "image_size": hp.image_size,
            "views": hp.views,
            "passes": self.train_passes if split == "train" else 1,
            "seed": hp.seed,
        }
        if split == "train":
            key.update(min_scale=hp.min_scale, mask_mode=hp.mask_mode, background_dir=hp.background_dir, flip=hp.flip)
        digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]
        return Path(hp.world_root) / FEATURES_DIR / f"{split}-{digest}.pt"

    def _load(self, split: str) -> FeatureDataset:
        passes = self._passes(split)
        items = [(shape_id, view) for ds in passes for shape_id, view, _ in ds.items]
        path = self.cache_file(split)
        path.parent.mkdir(parents=True, exist_ok=True)
        with FileLock(str(path) + ".lock"):
            cached = torch.load(path, map_location="cpu", weights_only=False) if path.is_file() else None
            if cached is None or cached["items"] != items:
                started = time.time()
                features = encode_views(ConcatDataset(passes), self.features)
                atomic.torch_save({"items": items, "features": features}, path)
                log.info("encoded %d %s views in %.1f s -> %s", len(items), split, time.time() - started, path)
            else:
                features = cached["features"]
        return FeatureDataset(features, items, passes[0].codes)

    def setup(self, stage: str | None = None) -> None:
        wanted = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(stage, ("train", "val", "test"))
        for split in wanted:
            if split not in self.datasets:
                self.datasets[split] = self._load(split)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        dataset = self.datasets[split]
        return DataLoader(
            dataset, batch_size=self.batch_size, shuffle=shuffle, drop_last=shuffle and len(dataset) > self.batch_size
        )
