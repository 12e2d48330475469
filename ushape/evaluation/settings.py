"""What every evaluation protocol shares: the split, the views, how finely shapes are meshed and scored,
the decoder's precision, the seed, the shape cap and the calibration levels (conf/protocol/paper.yaml's
`protocol` node, sized by the presets paper and quick); the files an evaluation writes are named in workspace.py.

Each protocol's own settings sit in its YAML file (conf/protocol/plugins/<name>.yaml) and in its class
(evaluation.plugin); results.json records both.
"""

from __future__ import annotations

from dataclasses import dataclass

from ushape.decoder.precision import check_precision
from ushape.evaluation.protocols import GROUP_SIZE

# What `protocols=auto` runs (the others are asked for by name: protocols=[active], ...).
PAPER_PROTOCOLS = ("single_view", "multi_view", "corrupted", "uncertainty", "locality", "depth")


@dataclass
class Settings:
    """What every protocol shares (conf/eval.yaml's `protocol`)."""

    split: str = "test"
    group_size: int = GROUP_SIZE  # views per multi-view instance
    resolution: int = 64  # marching-cubes grid
    n_points: int = 1024  # surface points for CD and EMD
    precision: str = "auto"  # the decoder's: fp32, bf16, or auto (resolved by evaluate_runs)
    single_view_views: int | None = None  # single views scored: each shape's first (None: all)
    calibration_levels: int = 20
    code_iterations: int = 800  # latent optimisation of test codes the decoder never saw (data=pix3d)
    max_shapes: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.group_size < 1 or self.resolution < 8:
            raise ValueError("group_size must be >= 1 and resolution >= 8 (grid points per axis)")
        check_precision(self.precision)
