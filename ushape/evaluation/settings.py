"""What an evaluation measures and how finely: the size preset of conf/protocol/ (paper, quick) as one
dataclass, and the names of the files an evaluation writes.

The values are shared by the protocols (conf/protocol/plugins/<name>.yaml binds the ones each reads), so
`eval.py protocol=paper` and `protocol.<key>=...` size every protocol at once; results.json records them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from ushape.decoder.precision import check_precision
from ushape.evaluation.active import check_active_settings
from ushape.evaluation.protocols import GROUP_SIZE
from ushape.propagation import SDF_CLAMP
from ushape.propagation.depth_implicit import DEPTH_METHODS

# What `protocols=auto` runs (the active protocol is asked for by name: protocols=[active]).
PAPER_PROTOCOLS = ("single_view", "multi_view", "corrupted", "uncertainty", "locality", "depth")
RESULT_ROW = "eval_row.json"
# The row lists every encoder contributes to an evaluation's result (concatenated over encoders).
ROW_KEYS = ("records", "uncertainty", "error_tracking", "locality", "locality_views", "depth", "active", "rows")
RESULTS = "results.json"


@dataclass
class Settings:
    """What to evaluate and how finely (conf/eval.yaml's `settings`)."""

    split: str = "test"
    group_size: int = GROUP_SIZE
    table4_k: int = 4
    resolution: int = 64
    n_points: int = 1024
    precision: str = "auto"  # the decoder's: fp32, bf16, or auto (resolved by evaluate_runs)
    single_view_scales: Sequence[float] = (1.0, 0.1, 0.01)
    single_view_views: int | None = None
    corrupted_scales: Sequence[float] = (0.8, 0.4, 0.2, 0.1, 0.01)
    sdf_points: int = 1024
    mc_samples: int = 10
    sdf_views: int | None = None
    sdf_clamp: float | None = SDF_CLAMP
    calibration_levels: int = 20
    locality_points: int = 2048
    locality_scale: float = 0.1
    locality_views: int | None = None
    depth_size: int = 48
    depth_views: int | None = 2
    depth_methods: Sequence[str] = ("implicit", "mc")
    depth_codes: int = 10
    depth_steps: int = 50
    max_shapes: int | None = None
    showcase_shapes: int = 2
    code_iterations: int = 800
    active_views: int = 6
    active_strategies: Sequence[str] = (
        "uncertainty",
        "unseen-uncertainty",
        "farthest",
        "random",
        "oracle",
        "information",
    )
    active_observe: Sequence[str] = ("none",)  # after each view: none (fused), masks, depth (refined on the views)
    active_refine_size: int = 24  # rays per image side, of the refinement and of the information strategy
    active_refine_iterations: int = 15
    active_scales: Sequence[float] = (1.0, 0.1)
    active_shapes: int | None = None
    active_candidates: str = "auto"
    active_azimuths: int = 12
    active_elevations: int = 2
    seed: int = 0
    protocols: Sequence[str] = PAPER_PROTOCOLS

    def __post_init__(self) -> None:
        if self.group_size < 1 or self.resolution < 8:
            raise ValueError("group_size must be >= 1 and resolution >= 8 (grid points per axis)")
        if not set(self.depth_methods) <= set(DEPTH_METHODS) or self.depth_size < 1 or self.depth_codes < 2:
            raise ValueError(
                f"depth_methods must be some of {DEPTH_METHODS}, depth_size >= 1 and depth_codes >= 2; "
                f"got {list(self.depth_methods)}, {self.depth_size}, {self.depth_codes}"
            )
        check_active_settings(self)
        check_precision(self.precision)
