"""What `reconstruct` does beyond its inputs: one frozen dataclass, every field a flag of reconstruct.py."""

from __future__ import annotations

from dataclasses import dataclass

from ushape.data.cameras import R2N2_FOV_DEG
from ushape.reconstruction.export import DEFAULT_CMAP
from ushape.refinement.defaults import REFINE_DEFAULTS

POSE_CHOICES = ("auto", "estimate", "given")  # ReconstructionSettings.pose


@dataclass(frozen=True)
class ReconstructionSettings:
    """What `reconstruct` does beyond the inputs; every field has a command-line flag in reconstruct.py."""

    resolution: int = 128
    uncertainty: str = "linearised"
    n_samples: int = 10  # codes for MC vertex uncertainty
    depth_size: int = 64
    depth_method: str = "implicit"  # "implicit": trace the mean code once; "mc": trace depth_codes sampled codes
    depth_codes: int = 10  # M codes sphere-traced per view by depth_method "mc"
    depth_steps: int = 50
    std_max: float | None = None
    cmap: str = DEFAULT_CMAP
    seed: int = 0
    refine: str | None = None  # "masks" | "depth": refine the fused code on the views (ushape.refinement)
    refine_size: int = REFINE_DEFAULTS["size"]  # rays per image side the refinement compares
    # prior draws scored beside the fused mean; the LM starts from the lowest energy
    refine_starts: int = REFINE_DEFAULTS["starts"]
    # The object's pose for --refine masks (ushape.refinement.joint): "auto" estimates it where no view has a
    # camera, "estimate" always (a known camera's K is kept, its pose hidden), "given" never.
    pose: str = "auto"
    fov: float = R2N2_FOV_DEG  # degrees across the larger side of an image with no camera: its K
    # npz with world_to_cam [V, 4, 4] of the input views in any one frame (odometry, a turntable): only their
    # motion relative to each other is used, and they share one estimated object pose
    relative_poses: str | None = None
    # What the pose search assumes of the cameras (ushape.refinement.joint.PoseSettings): their elevation above the
    # object's ground plane in degrees (None: R2N2's renders', 27.5) and the prior's std of the object's tilt about
    # it (None: the rotation's own; an upright object and a known elevation range narrow it)
    elevation: float | None = None
    tilt_std: float | None = None
    # The decoder's: fp32, bf16, or auto (bf16 where faster: AMX CPUs, CUDA >= 8.0). Under bf16 the mesh
    # is searched in bf16 and placed by fp32 values; linearised and implicit stds use bf16 passes;
    # Monte Carlo stds stay fp32.
    precision: str = "auto"
