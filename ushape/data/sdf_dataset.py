"""SDF samples of one split of a world, drawn the way DeepSDF's training draws them.

Reads `<world_root>/splits/<split>.json` and `<world_root>/sdf/<shape_id>.npz` (keys "pos" [P, 4]
and "neg" [Q, 4], rows (x, y, z, sdf), DeepSDF's layout). Every item draws a fresh random half of
its samples from "pos" and half from "neg", with replacement, as DeepSDF's unpack_sdf_samples does,
so an epoch sees a different subset of each shape's ~100k samples.
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from ushape.data.layout import MESHES_DIR, SDF_DIR, WorldIndex, read_split

REBUILD_HINT = "rebuild the data with ushape.data.world.SyntheticWorld(...).build()"


def load_sdf_samples(path: str | Path) -> tuple[Tensor, Tensor]:
    """A shape's DeepSDF sample file as (pos [P, 4], neg [Q, 4]) float32 tensors, checked."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"SDF sample file {path} is missing; {REBUILD_HINT}")
    try:
        with np.load(path) as npz:
            pos, neg = np.asarray(npz["pos"], np.float32), np.asarray(npz["neg"], np.float32)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
        raise ValueError(f"SDF sample file {path} is corrupt or incomplete ({err}); {REBUILD_HINT}") from err
    for name, arr in (("pos", pos), ("neg", neg)):
        if arr.ndim != 2 or arr.shape[1] != 4 or arr.shape[0] == 0:
            raise ValueError(
                f"SDF sample file {path}: {name!r} must be a non-empty [N, 4] array, got {arr.shape}; {REBUILD_HINT}"
            )
    return torch.from_numpy(pos), torch.from_numpy(neg)


def sdf_points(world: WorldIndex, shape_id: str, n_points: int, seed: int = 0) -> tuple[Tensor, Tensor]:
    """A repeatable random subset of a shape's ground-truth SDF samples: points [P, 3], sdf [P]."""
    path = world.sdf_path(shape_id)
    if not path.is_file():
        raise FileNotFoundError(f"no ground-truth SDF samples {path}: the world folder is incomplete")
    blob = np.load(path)
    samples = np.concatenate([blob["pos"], blob["neg"]]).astype(np.float32)
    rng = np.random.default_rng(seed + zlib.crc32(shape_id.encode()))
    if len(samples) > n_points:
        samples = samples[rng.choice(len(samples), n_points, replace=False)]
    samples = torch.from_numpy(samples)
    return samples[:, :3].contiguous(), samples[:, 3].contiguous()


def draw_half_pos_half_neg(pos: Tensor, neg: Tensor, count: int, generator: torch.Generator | None = None) -> Tensor:
    """`count` rows, half drawn from pos [P, 4] and half from neg [Q, 4], with replacement. -> [count, 4]"""
    half = count // 2
    pos_idx = torch.randint(pos.shape[0], (count - half,), generator=generator)
    neg_idx = torch.randint(neg.shape[0], (half,), generator=generator)
    return torch.cat([pos[pos_idx], neg[neg_idx]], dim=0)


class SDFSamplesDataset(Dataset):
    """Item i: {"index": i, "xyz": [S, 3], "sdf": [S]} for the i-th shape of the split.

    Sample files are read on first use and kept in memory (a shape's ~100k samples are ~1.6 MB).
    """

    def __init__(self, world_root: str | Path, split: str, samples_per_shape: int) -> None:
        if samples_per_shape < 2:
            raise ValueError(f"samples_per_shape must be >= 2 (half positive, half negative), got {samples_per_shape}")
        self.world_root = Path(world_root)
        self.split = split
        self.samples_per_shape = samples_per_shape
        self.shape_ids = read_split(world_root, split)
        self._cache: dict[int, tuple[Tensor, Tensor]] = {}

    def __len__(self) -> int:
        return len(self.shape_ids)

    def sdf_path(self, index: int) -> Path:
        return self.world_root / SDF_DIR / f"{self.shape_ids[index]}.npz"

    def mesh_path(self, index: int) -> Path:
        return self.world_root / MESHES_DIR / f"{self.shape_ids[index]}.ply"

    def samples(self, index: int) -> tuple[Tensor, Tensor]:
        """All of shape `index`'s samples as (pos [P, 4], neg [Q, 4])."""
        if index not in self._cache:
            self._cache[index] = load_sdf_samples(self.sdf_path(index))
        return self._cache[index]

    def __getitem__(self, index: int) -> dict[str, Tensor | int]:
        rows = draw_half_pos_half_neg(*self.samples(index), self.samples_per_shape)
        return {"index": index, "xyz": rows[:, :3], "sdf": rows[:, 3]}
