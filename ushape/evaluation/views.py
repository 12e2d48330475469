"""Test views as the encoder sees them in evaluation, optionally corrupted, and their cached encodings.

The corrupted-views protocol (the paper's Tables 4-5) crops every input to a random area in
[min_scale, 1] and resizes it back, exactly as the training augmentation does. Each view's crop
comes from its own generator, seeded by (seed, shape id, view), so a view is cropped the same way
in every run, by every encoder, whatever else is evaluated.

A view is read with its mask (`mask_input="gt_mask"`: the alpha the encoder composites as it was
trained to) or as a photo (`"none"`: alpha ignored, the RGB background kept; Pix3D's "w/o Mask" rows).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import torch
from torch import Tensor
from tqdm.auto import tqdm

from ushape import atomic
from ushape.data.augment import corrupted_view, load_rgba, read_image, view_seed
from ushape.data.layout import WorldIndex

MASK_INPUTS = ("gt_mask", "none")


@dataclass(frozen=True)
class ViewKey:
    shape_id: str
    view: int


def test_views(world: WorldIndex, split: str = "test", shape_ids: Sequence[str] | None = None) -> list[ViewKey]:
    """Every (shape, view) of a split's renders, in shape then view order."""
    ids = world.shape_ids(split) if shape_ids is None else list(shape_ids)
    if not ids:
        raise ValueError(f"the '{split}' split of {world.root} is empty: nothing to evaluate")
    return [ViewKey(s, v) for s in ids for v in range(world.view_count(s))]


def load_view(path: Path, mask_input: str = "gt_mask") -> Tensor:
    """Premultiplied RGBA [4, H, W] of a view: its own alpha (gt_mask), or opaque (none: the photo as is)."""
    if mask_input not in MASK_INPUTS:
        raise ValueError(f"mask_input must be one of {MASK_INPUTS}, got {mask_input!r}")
    if mask_input == "none":
        rgb = torch.from_numpy(read_image(path)[..., :3]).permute(2, 0, 1)
        return torch.cat([rgb, torch.ones_like(rgb[:1])])
    return load_rgba(path)


@dataclass(frozen=True)
class Estimate:
    """One reconstructed Gaussian: mu [D], var [D] (diagonal) or [D, D] (full), and why the method that made
    it fell back to its input (None: it did not)."""

    mu: Tensor
    var: Tensor
    fallback: str | None = None


@dataclass(frozen=True)
class Encodings:
    """Per-view latent Gaussians: keys[i] has mu[i], var[i] (var = 1 for an l2 encoder). var is [N, D], or
    [N, D, D] for a method that gives full covariances; fallbacks[i], where a method set it, says why that
    method fell back to the view's encoding (None: it did not)."""

    keys: list[ViewKey]
    mu: Tensor  # [N, D]
    var: Tensor  # [N, D] or [N, D, D]
    fallbacks: tuple[str | None, ...] | None = None

    @property
    def marginal_var(self) -> Tensor:  # [N, D]
        """Each dimension's own variance: var itself, or a full covariance's diagonal."""
        return self.var if self.var.ndim == 2 else torch.diagonal(self.var, dim1=-2, dim2=-1)

    def select(self, keys: Sequence[ViewKey]) -> tuple[Tensor, Tensor]:
        """(mu [K, D], var [K, D] or [K, D, D]) of the given views, in their order."""
        index = {k: i for i, k in enumerate(self.keys)}
        missing = [k for k in keys if k not in index]
        if missing:
            raise KeyError(f"{len(missing)} views were not encoded, e.g. {missing[0]}")
        rows = torch.tensor([index[k] for k in keys], dtype=torch.long)
        return self.mu[rows], self.var[rows]

    def first_views(self, n_views: int | None) -> "Encodings":
        """Only each shape's first n_views views (None: all)."""
        if n_views is None:
            return self
        rows = [i for i, k in enumerate(self.keys) if k.view < n_views]
        fallbacks = None if self.fallbacks is None else tuple(self.fallbacks[i] for i in rows)
        index = torch.tensor(rows, dtype=torch.long)
        return Encodings([self.keys[i] for i in rows], self.mu[index], self.var[index], fallbacks)


def encoder_tag(predictor) -> str:
    """Identifies an encoder's outputs: checkpoint path, size, mtime and temperature."""
    stat = Path(predictor.checkpoint).stat()
    text = f"{Path(predictor.checkpoint).resolve()}|{stat.st_size}|{stat.st_mtime_ns}|{predictor.temperature}"
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def encoder_inputs(
    predictor, world: WorldIndex, keys: Sequence[ViewKey], min_scale: float, seed: int, mask_input: str = "gt_mask"
) -> Tensor:
    """The images [V, 3, S, S] the encoder is shown for `keys`: each cropped to min_scale by its own seed."""
    return torch.stack(
        [
            corrupted_view(
                load_view(world.image_path(k.shape_id, k.view), mask_input),
                predictor.image_size,
                min_scale,
                view_seed(seed, k.shape_id, k.view),
                predictor.mask_mode,
                predictor.background_value,
            )
            for k in keys
        ]
    )


def encode_views(
    predictor,
    world: WorldIndex,
    keys: Sequence[ViewKey],
    min_scale: float,
    seed: int = 0,
    cache_dir: Path | None = None,
    batch_size: int = 32,
    mask_input: str = "gt_mask",
) -> Encodings:
    """Encode every view (cropped to min_scale) with `predictor.encode`; reuse the cache file when present."""
    keys = list(keys)
    cache = None
    if cache_dir is not None:
        # The world folder too: two Pix3D worlds (another crop margin or size) share their shape ids.
        views = "|".join(f"{k.shape_id}/{k.view}" for k in keys)
        listing = hashlib.sha1(f"{Path(world.root).resolve()}|{views}".encode()).hexdigest()[:12]
        read = "" if mask_input == "gt_mask" else f"_{mask_input}"
        cache = Path(cache_dir) / f"enc_{encoder_tag(predictor)}_{min_scale:g}_{seed}_{listing}{read}.pt"
        if cache.is_file():
            blob = torch.load(cache, map_location="cpu", weights_only=False)
            return Encodings(keys, blob["mu"], blob["var"])
    mus, vars_ = [], []
    for start in tqdm(range(0, len(keys), batch_size), desc=f"encode (min_scale {min_scale:g})", leave=False):
        images = encoder_inputs(predictor, world, keys[start : start + batch_size], min_scale, seed, mask_input)
        mu, var = predictor.encode(images)
        mus.append(mu.float())
        vars_.append(var.float())
    encodings = Encodings(keys, torch.cat(mus), torch.cat(vars_))
    if cache is not None:
        atomic.torch_save({"mu": encodings.mu, "var": encodings.var}, cache)
    return encodings
