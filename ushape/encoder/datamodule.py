"""Stage-2 data: rendered views of each shape paired with its stage-1 latent code.

World layout read here (written by the renderer):
    <world_root>/splits/{train,val,test}.json        JSON list of shape ids
    <world_root>/renders/<shape_id>/00.png .. NN.png  RGBA, alpha = object mask
    <world_root>/renders/<shape_id>/views.npz         cameras, masks, depth (not needed here)
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable, Sequence

import lightning as L
import torch
from torch import Tensor
from torch.utils.data import DataLoader, Dataset

from ushape import atomic
from ushape.data.augment import build_transform, load_rgba
from ushape.data.layout import RENDERS_DIR, read_split
from ushape.decoder.artifacts import CodeTable, codes_file, load_codes

log = logging.getLogger(__name__)


def view_files(world_root: str | Path, shape_id: str, views: Sequence[int] | None = None) -> list[Path]:
    """The PNG renders of one shape, in view order; `views` picks indices (None: all)."""
    folder = Path(world_root) / RENDERS_DIR / shape_id
    # Not the temporary files of interrupted atomic writes (".03.png.x.tmp.png"): they are no views.
    files = sorted(p for p in folder.glob("*.png") if not atomic.is_temp_file(p))
    if not files:
        raise FileNotFoundError(f"no renders in {folder}: render the world first (expects 00.png, 01.png, ...)")
    if views is None:
        return files
    if any(not 0 <= v < len(files) for v in views):
        raise ValueError(f"views {list(views)} out of range for {folder} ({len(files)} renders)")
    return [files[v] for v in views]


class RenderDataset(Dataset):
    """(rendered view, latent code) pairs of one split -> dict(image [3, H, W], code [D], shape_id, view).

    Shapes are the split's ids that have a code in `codes`. `transform(rgba, generator)` turns the
    premultiplied RGBA [4, H, W] into RGB [3, image_size, image_size]; the default resizes and
    composites on white. With `deterministic`, item i always gets generator seed (seed, i), so
    random transforms (backgrounds, the corrupted-views crops) repeat exactly across epochs and runs.
    """

    def __init__(
        self,
        world_root: str | Path,
        split: str,
        codes: CodeTable,
        image_size: int = 128,
        views: Sequence[int] | None = None,
        transform: Callable[..., Tensor] | None = None,
        deterministic: bool = False,
        seed: int = 0,
    ) -> None:
        self.world_root = Path(world_root)
        split_ids = read_split(world_root, split)
        known = set(codes.shape_ids)
        self.shape_ids = [s for s in split_ids if s in known]
        if not self.shape_ids:
            raise ValueError(f"none of the {len(split_ids)} '{split}' shapes has a code in the given code table")
        if len(self.shape_ids) < len(split_ids):
            log.warning(
                "%d of %d '%s' shapes have no code; skipped",
                len(split_ids) - len(self.shape_ids),
                len(split_ids),
                split,
            )
        self.codes = codes.as_dict()
        self.items = []  # (shape_id, view index, png path)
        for shape_id in self.shape_ids:
            files = view_files(world_root, shape_id, views)
            indices = list(views) if views is not None else range(len(files))
            self.items += [(shape_id, view, path) for view, path in zip(indices, files)]
        self.transform = transform if transform is not None else build_transform(image_size, train=False)
        self.deterministic, self.seed = deterministic, seed

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict:
        shape_id, view, path = self.items[index]
        generator = None
        if self.deterministic:
            generator = torch.Generator().manual_seed(self.seed * 1_000_003 + index)
        image = self.transform(load_rgba(path), generator)
        return {"image": image, "code": self.codes[shape_id], "shape_id": shape_id, "view": view}


class SplitLoaders:
    """train/val/test dataloaders of a DataModule from its `_loader(split, shuffle)`."""

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)


class EncoderDataModule(SplitLoaders, L.LightningDataModule):
    """Train split with codes_train.pt and random augmentation; val/test with their codes, repeatable."""

    def __init__(
        self,
        world_root: str | Path,
        decoder_dir: str | Path,
        image_size: int = 128,
        batch_size: int = 64,
        num_workers: int = 0,
        min_scale: float = 0.5,
        mask_mode: str = "gt_mask",
        background_dir: str | Path | None = None,
        flip: bool = True,
        views: Sequence[int] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.datasets: dict[str, RenderDataset] = {}

    def dataset(self, split: str, train: bool, seed: int | None = None) -> RenderDataset:
        """The split's views, augmented if `train`; repeatable unless training without a `seed`."""
        hp = self.hparams
        codes = load_codes(Path(hp.decoder_dir) / codes_file(split))
        transform = build_transform(hp.image_size, train, hp.min_scale, hp.mask_mode, hp.background_dir, hp.flip)
        views = list(hp.views) if hp.views is not None else None
        deterministic = not train or seed is not None
        return RenderDataset(
            hp.world_root,
            split,
            codes,
            hp.image_size,
            views,
            transform,
            deterministic,
            hp.seed if seed is None else seed,
        )

    def setup(self, stage: str | None = None) -> None:
        if stage in (None, "fit") and "train" not in self.datasets:
            self.datasets["train"] = self.dataset("train", train=True)
        if stage in (None, "fit", "validate") and "val" not in self.datasets:
            self.datasets["val"] = self.dataset("val", train=False)
        if stage in (None, "test") and "test" not in self.datasets:
            self.datasets["test"] = self.dataset("test", train=False)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        hp = self.hparams
        return DataLoader(
            self.datasets[split],
            batch_size=hp.batch_size,
            shuffle=shuffle,
            num_workers=hp.num_workers,
            persistent_workers=hp.num_workers > 0,
            drop_last=shuffle and len(self.datasets[split]) > hp.batch_size,
        )
