"""Observation model: what a code z predicts a calibrated view shows, and the Jacobian of that in z.

Silhouette (SDFDiff / DIST style): along each pixel ray, the minimum SDF m(z) over points in the
decoder's cube [-bound, bound]^3, found on a coarse then a fine sampling of the ray; the pixel's
predicted occupancy is p = sigmoid(-m / tau). The gradient flows through the argmin point x*:
dp/dz = -p (1 - p) / tau * ds/dz(x*, z) (the envelope theorem: the argmin's own motion does not
change m to first order). Only pixels within `band` tau of the surface get a Jacobian; elsewhere
p (1 - p) is below 1e-3 and the row is 0.

Depth, two models (`depth_residual`):
  - "surface" (the default; DeepSDF's shape completion, DSP-SLAM's surface term): each depth return,
    back-projected to the point x = o + d_obs d, should lie on the surface: r = s(x, z), dr/dz = ds/dz(x, z).
    Exact Jacobian, no tracing, and no blow-up at grazing rays.
  - "trace": sphere-trace the code's surface (`ushape.propagation.sphere_tracing`) and compare the
    rendered depth, differentiated implicitly, dt/dz = -(ds/dz) / (ds/dx . d)
    (`ushape.propagation.depth_implicit`), where the trace hits and the view has a return. On the
    trained chairs decoder this model measured worse (docs/refinement.md): a trace that reaches another
    part than the view saw, and the grazing-ray sensitivity, pull the code to shapes the masks allow
    but the depths do not.
Silhouettes handle the pixels without a return. Free space (`free_margin` > 0, with depth): the segment
of each returning ray in front of its return, up to `free_margin` short of it, must be empty: the row is
min(m, 0) of the segment's minimum SDF m, in SDF units like the surface term (DeepSDF's completion
samples free space the same way). Without it a code may put matter between the camera and the surface
it saw, which the surface term alone never sees. A hinge, not an occupancy with target 0: the true
surface seen at a slant has an SDF of only margin x cos(slant) at the segment's end, which a sigmoid
would read as partly occupied and push the surface back.

Pixels marked unobserved carry no residual. Rays are taken on a regular sub-grid of the image
(every `stride`-th pixel per axis) so a 64 px view and a 256 px view cost alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import torch
from torch import Tensor

from ushape.decoder.folded import fold_code
from ushape.propagation.depth_implicit import MIN_COSINE, depth_sensitivity
from ushape.propagation.linearised import sdf_gradients
from ushape.propagation.sphere_tracing import camera_rays, sphere_trace
from ushape.refinement.defaults import REFINE_DEFAULTS
from ushape.refinement.ray_search import PointsSDF, SDFGrid, ray_minimum, sdf_grid
from ushape.refinement.views import ObservedView

PointsGradients = Callable[[Tensor], tuple[Tensor, Tensor, Tensor]]  # [P, 3] -> (s [P], ds/dz [P, D], ds/dx [P, 3])


@dataclass(frozen=True)
class ObservationSettings:
    """How views are compared with a code; every field is a knob of conf/refine/*.yaml."""

    tau: float = 0.01  # silhouette sharpness, in SDF units (the unit-sphere frame)
    coarse: int = 24  # ray samples for the minimum SDF (inside the unit ball) ...
    fine: int = 8  # ... and samples around the coarse argmin
    band: float = 7.0  # rows with |m| / tau past this have p (1 - p) < 1e-3: no Jacobian
    size: int = REFINE_DEFAULTS["size"]  # rays per image side (every stride-th pixel; conf/refine.yaml)
    trace_steps: int = 40
    trace_eps: float = 2e-3
    bound: float = 1.0  # rays are sampled inside the ball of this radius (the trace: inside the cube)
    min_cosine: float = MIN_COSINE
    depth_residual: str = "surface"  # "surface" | "trace" (see the module docstring)
    free_margin: float = 0.03  # free space ends this far (camera z) before each depth return; 0: no free-space rows
    # Coarse ray samples read from an SDF grid of this many nodes per axis (0: from the decoder; ray_search.py) ...
    grid: int = 33
    # ... and a ray whose interpolated minimum is band x tau + this past the surface skips the decoder
    grid_slack: float = 0.05

    def search(self, sdf: PointsSDF) -> SDFGrid | None:
        """The SDF grid the coarse ray samples read at one code (None: they query the decoder)."""
        return sdf_grid(sdf, self.grid, self.bound) if self.grid else None

    def minimum(
        self, sdf: PointsSDF, origins: Tensor, directions: Tensor, far_limit: Tensor | None, grid: SDFGrid | None
    ) -> tuple[Tensor, Tensor]:
        """`ray_search.ray_minimum` with these settings: minimum SDF [R] and its point [R, 3]."""
        margin = self.band * self.tau + self.grid_slack + (2.0 * grid.drift if grid is not None else 0.0)
        return ray_minimum(sdf, origins, directions, self.coarse, self.fine, self.bound, far_limit, grid, margin)


KINDS = ("masks", "depth", "free")  # a row's kind: silhouette, depth return, free space before a return

# (ds/dz [N, D], ds/dx [N, 3]) at a term's Jacobian points -> its rows of dr/dz [N, D]
RowJacobian = Callable[[Tensor, Tensor], Tensor]


class Pending(NamedTuple):
    """Rows of dr/dz not computed yet: their indices [N], the points [N, 3] whose SDF gradients they need, and how
    those gradients become the rows. Every other row's Jacobian is 0.

    `finish(ds/dtheta [N, K], ds/dx [N, 3])` is the chain rule's last link, linear in its first argument: given
    the SDF's derivative at the points in any parameters theta (the code: ds/dz; the object's pose:
    `pose.point_jacobian`), it returns the rows' dr/dtheta [N, K]."""

    rows: Tensor
    points: Tensor
    finish: RowJacobian


class Residuals(NamedTuple):
    """Residuals r [R], their Jacobian dr/dz [R, D] ([0, D] until `with_jacobian`), per-row kind [R] (KINDS), and
    what the Jacobian needs (`pending`): a trial step whose energy does not fall never pays for it. `view` [R]:
    the index of each row's view (None where not recorded)."""

    r: Tensor
    J: Tensor
    kind: Tensor
    pending: tuple[Pending, ...] = ()
    view: Tensor | None = None


def no_rows() -> tuple[Tensor, Pending]:
    return torch.zeros(0), Pending(torch.zeros(0, dtype=torch.long), torch.zeros(0, 3), lambda gz, gx: gz)


def code_functions(decoder: torch.nn.Module, z: Tensor) -> tuple[PointsSDF, PointsGradients]:
    """(points -> sdf, points -> (sdf, ds/dz, ds/dx)) of the decoder at code z [D], float32, no parameter graph.

    A DeepSDFDecoder is folded at z (plain tensors, hand-written backward); any other decoder goes through autograd.
    """
    folded = fold_code(decoder, z)
    if folded is not None:
        return (lambda p: folded.sdf(p).float()), (lambda p: tuple(t.float() for t in folded.sdf_and_gradients(p)))

    def sdf(points: Tensor) -> Tensor:
        with torch.no_grad():
            return decoder(points, z.expand(points.shape[0], -1)).float()

    def gradients(points: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        s, gz, gx = sdf_gradients(decoder, z, points, with_xyz=True)
        return s.float(), gz.float(), gx.float()

    return sdf, gradients


def view_rays(view: ObservedView, settings: ObservationSettings) -> tuple[Tensor, Tensor, Tensor]:
    """Ray origins, directions [R, 3] (camera-z component 1) and flat pixel indices [R] of the observed sub-grid."""
    h, w = view.image_hw
    origins, directions = camera_rays(view.K, view.world_to_cam, (h, w), settings.trace_steps, settings.trace_eps)
    stride = max(1, -(-max(h, w) // settings.size))
    rows = torch.arange(stride // 2, h, stride)
    cols = torch.arange(stride // 2, w, stride)
    pixels = (rows[:, None] * w + cols[None, :]).reshape(-1)
    pixels = pixels[view.seen().reshape(-1)[pixels]]
    return origins[pixels], directions[pixels], pixels


def silhouette_residuals(
    sdf: PointsSDF,
    view: ObservedView,
    settings: ObservationSettings,
    grid: SDFGrid | None = None,  # the code's SDF grid for the coarse ray samples (settings.search)
) -> tuple[Tensor, Pending]:
    """Predicted minus observed occupancy r [R] at the view's observed sub-grid, and its Jacobian's rows: those within
    `band` tau of the surface, dp/dz = -p (1 - p) / tau ds/dz at each ray's argmin."""
    origins, directions, pixels = view_rays(view, settings)
    target = view.mask.reshape(-1)[pixels].float()
    minimum, points = settings.minimum(sdf, origins, directions, None, grid)
    p = torch.sigmoid(-minimum / settings.tau)
    near = (minimum.abs() < settings.band * settings.tau).nonzero().squeeze(1)
    scale = -(p * (1 - p))[near] / settings.tau
    return p - target, Pending(near, points[near], lambda gz, gx: scale[:, None] * gz)


def free_space_residuals(
    sdf: PointsSDF,
    view: ObservedView,
    settings: ObservationSettings,
    grid: SDFGrid | None = None,  # the code's SDF grid for the coarse ray samples (settings.search)
) -> tuple[Tensor, Pending]:
    """min(m, 0) [R'] of each returning ray's minimum SDF m in front of its return (`free_margin` short of it),
    in SDF units, and its Jacobian's rows (ds/dz at the minimum where m < 0): zero where that segment is empty,
    whatever the surface's slant."""
    if view.depth is None or settings.free_margin <= 0:
        return no_rows()
    origins, directions, pixels = view_rays(view, settings)
    observed = view.depth.reshape(-1)[pixels].float()
    rows = (observed > 0).nonzero().squeeze(1)
    far_limit = observed[rows] - settings.free_margin
    minimum, points = settings.minimum(sdf, origins[rows], directions[rows], far_limit, grid)
    r = minimum.clamp(max=0.0)  # an empty segment (+inf) has no residual
    inside = (r < 0).nonzero().squeeze(1)
    return r, Pending(inside, points[inside], lambda gz, gx: gz)


def depth_residuals(
    sdf: PointsSDF,
    view: ObservedView,
    settings: ObservationSettings,
    grid: SDFGrid | None = None,  # unused: depth rows need no ray search
) -> tuple[Tensor, Pending]:
    """Depth residuals r [R'] and their Jacobian's rows: the SDF at the back-projected returns ("surface"), or traced
    minus observed depth where the code's surface and the view both return ("trace")."""
    if view.depth is None:
        return no_rows()
    origins, directions, pixels = view_rays(view, settings)
    observed = view.depth.reshape(-1)[pixels].float()
    if settings.depth_residual == "surface":
        rows = (observed > 0).nonzero().squeeze(1)
        x = origins[rows] + observed[rows, None] * directions[rows]
        everything = torch.arange(rows.shape[0])
        return (sdf(x) if rows.numel() else torch.zeros(0)), Pending(everything, x, lambda gz, gx: gz)
    if settings.depth_residual != "trace":
        raise ValueError(f"depth_residual must be 'surface' or 'trace', got {settings.depth_residual!r}")
    t, hit = sphere_trace(
        lambda x, _code: sdf(x), origins, directions, 1, settings.trace_steps, settings.trace_eps, settings.bound
    )
    rows = (hit[0] & (observed > 0)).nonzero().squeeze(1)
    depth = t[0, rows]
    hits, along = origins[rows] + depth[:, None] * directions[rows], directions[rows]
    everything = torch.arange(rows.shape[0])
    return depth - observed[rows], Pending(
        everything, hits, lambda gz, gx: depth_sensitivity(gz, gx, along, settings.min_cosine)
    )


def with_jacobian(decoder: torch.nn.Module, z: Tensor, res: Residuals) -> Residuals:
    """`res` (the residuals at code z [D]) with dr/dz [R, D] filled in: one gradient pass over every pending point."""
    if res.J.shape[0] == res.r.shape[0]:
        return res
    J = torch.zeros(res.r.shape[0], z.shape[0])
    points = torch.cat([p.points for p in res.pending]) if res.pending else torch.zeros(0, 3)
    if points.shape[0]:
        _, gradients = code_functions(decoder, z.detach().float())
        _, grad_z, grad_x = gradients(points)
        start = 0
        for p in res.pending:
            end = start + p.points.shape[0]
            if end > start:
                J[p.rows] = p.finish(grad_z[start:end], grad_x[start:end])
            start = end
    return Residuals(res.r, J, res.kind, view=res.view)


def code_grid(decoder: torch.nn.Module, z: Tensor, settings: ObservationSettings) -> SDFGrid | None:
    """The SDF grid `residuals` reads for code z [D] (None where settings.grid is 0): for callers that move
    the cameras, not the code, and can build it once."""
    sdf, _ = code_functions(decoder, z.detach().float())
    return settings.search(sdf)


def residuals(
    decoder: torch.nn.Module,
    z: Tensor,  # [D]
    views: list[ObservedView],
    settings: ObservationSettings,
    use_depth: bool,
    jacobian: bool = True,  # False: r and kind, J [0, D] until `with_jacobian` (a trial step, a candidate code)
    grid: SDFGrid | None = None,  # the code's SDF grid where the caller has it (`code_grid`), else built here
) -> Residuals:
    """Every view's silhouette residuals (and depth and free-space residuals where use_depth), stacked, with dr/dz."""
    sdf, _ = code_functions(decoder, z.detach().float())
    grid = settings.search(sdf) if grid is None else grid
    terms = [(0, silhouette_residuals)] + ([(1, depth_residuals), (2, free_space_residuals)] if use_depth else [])
    rs, kinds, which, pending, offset = [], [], [], [], 0
    for index, view in enumerate(views):
        for kind, term in terms:
            r, rows = term(sdf, view, settings, grid)
            rs.append(r)
            kinds.append(torch.full((r.shape[0],), kind))
            which.append(torch.full((r.shape[0],), index))
            pending.append(rows._replace(rows=rows.rows + offset))
            offset += r.shape[0]
    res = Residuals(torch.cat(rs), torch.zeros(0, z.shape[0]), torch.cat(kinds), tuple(pending), torch.cat(which))
    return with_jacobian(decoder, z, res) if jacobian else res
