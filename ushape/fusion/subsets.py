"""Which views to fuse when a rule is scored or fitted at n fused views: index subsets of one shape's views."""

from __future__ import annotations

import torch
from torch import Tensor


def view_subsets(n_views: int, n_fused: int, draws: int, generator: torch.Generator) -> Tensor:
    """[R, n] view indices to fuse: every single view for n = 1, all views for n = V, else `draws` random
    subsets of n distinct views (each row ascending)."""
    if not 1 <= n_fused <= n_views:
        raise ValueError(f"cannot fuse {n_fused} of {n_views} views: pick 1 <= n <= {n_views}")
    if n_fused == 1:
        return torch.arange(n_views).unsqueeze(-1)
    if n_fused == n_views:
        return torch.arange(n_views).unsqueeze(0)
    rows = [torch.randperm(n_views, generator=generator)[:n_fused].sort().values for _ in range(draws)]
    return torch.stack(rows)
