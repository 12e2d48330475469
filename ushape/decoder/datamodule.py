"""Stage-1 data: SDF samples of the train shapes, and train-shape GT meshes for validation."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
from torch.utils.data import DataLoader, Dataset

from ushape.data.sdf_dataset import SDFSamplesDataset


class TrainMeshReferences(Dataset):
    """Item k: {"index": training-shape index, "shape_id": str, "mesh_path": str} of a few train shapes.

    An auto-decoder has codes only for its training shapes, so validation reconstructs those and
    compares them against their ground-truth meshes.
    """

    def __init__(self, shapes: SDFSamplesDataset, num_shapes: int) -> None:
        count = min(num_shapes, len(shapes))
        # Evenly spaced so a sorted split still gives varied shapes.
        self.indices = [int(i) for i in np.linspace(0, len(shapes) - 1, count).round()] if count else []
        self.shapes = shapes

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, k: int) -> dict[str, int | str]:
        i = self.indices[k]
        return {"index": i, "shape_id": self.shapes.shape_ids[i], "mesh_path": str(self.shapes.mesh_path(i))}


class SDFDataModule(L.LightningDataModule):
    """Batches of `shapes_per_batch` train shapes x `samples_per_shape` SDF samples (DeepSDF's scenes per batch)."""

    def __init__(
        self,
        world_root: str | Path,
        samples_per_shape: int = 16384,
        shapes_per_batch: int = 64,
        num_workers: int = 0,
        val_num_shapes: int = 4,
    ) -> None:
        super().__init__()
        if shapes_per_batch < 1:
            raise ValueError(f"shapes_per_batch must be >= 1, got {shapes_per_batch}")
        self.world_root = Path(world_root)
        self.samples_per_shape = samples_per_shape
        self.shapes_per_batch = shapes_per_batch
        self.num_workers = num_workers
        self.val_num_shapes = val_num_shapes
        self.train_set: SDFSamplesDataset | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is None:
            self.train_set = SDFSamplesDataset(self.world_root, "train", self.samples_per_shape)
            if len(self.train_set) == 0:
                raise ValueError(f"the train split of {self.world_root} is empty; the auto-decoder needs shapes")

    @property
    def num_shapes(self) -> int:
        self.setup()
        return len(self.train_set)

    def train_dataloader(self) -> DataLoader:
        self.setup()
        return DataLoader(
            self.train_set,
            batch_size=min(self.shapes_per_batch, len(self.train_set)),
            shuffle=True,
            drop_last=True,  # as DeepSDF: every step sees the same number of shapes
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
        )

    def val_dataloader(self) -> DataLoader:
        self.setup()
        return DataLoader(TrainMeshReferences(self.train_set, self.val_num_shapes), batch_size=None)
