"""Pose and shape together from masks: the object's pose as part of the refinement's state, for views with no
camera in the object's frame.

Views come in pose groups. The views of one group share one unknown object pose T_g (`pose.Pose`) and know
their motion from the group's reference camera (cam_from_ref: a robot's odometry, a turntable, R2N2's rows
with the object's frame hidden); a view with no known motion is a group of its own (cam_from_ref = I).
The state is theta = (z, xi_1 .. xi_G): the code and each group's pose perturbation (`pose` module), and

    E(theta) = 1/2 (z - mu)^T Sigma^-1 (z - mu) + sum_g 1/2 e_g^T P_g e_g + 1/2 sum_i W_i r_i(z, T)^2,

with the same silhouette residuals and weights as the known-camera refinement (`posterior`), and a prior
on each pose about its starting hypothesis: e_g = (rotation vector, translation in object units, log
scale) from the hypothesis to T_g, precision P_g (`PoseSettings`). The scale is in the state only where
it is observable: a group with a baseline, or one whose views carry depth maps (refinement mode "depth"); from
one view's masks a larger, farther object looks the same.

Depth (an RGB-D camera, DSP-SLAM's setting): a view's depth map is in its camera's units (metres, say), the
object's frame in the decoder's. Each depth return is divided by the group's scale before it is back-projected,
so a return is the camera-fixed point x = s R x_obj + t like a silhouette's ray minimum, and its rows' pose
columns follow from ds/dx at it alike (`pose.point_jacobian`, the log-scale column included). Only the
"surface" depth residual is supported here: the traced depth's residual would also need the return's own
derivative in the scale.

Where the search starts and which start wins: `pose_search` (refine_pose_and_shape, the entry point).

The Laplace posterior at the MAP is a full covariance over (z, xi): (prior precision + s J^T W J)^-1 (the pose's
rows with their own s where `pose_information_scale` is fitted). The
code's marginal (its [D, D] block: the pose integrated out, exactly for the Gaussian) is the shape's
posterior, so the vertex std computed from it is marginalised over the pose in the object's frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
import torch
from torch import Tensor

from ushape.encoder.viewpoint import camera_azimuth_elevation
from ushape.refinement.observation import ObservationSettings, Residuals, code_functions, code_grid, residuals
from ushape.refinement.pose import TRANSLATION, Pose, point_jacobian, scale_observable
from ushape.refinement.posterior import (
    Posterior,
    prior_precision,
    row_weights,
)
from ushape.refinement.ray_search import SDFGrid
from ushape.refinement.views import ObservedView

# A valid camera in front of the object: what an unposed view carries until the estimate replaces it.
PLACEHOLDER_CAMERA = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 2.0], [0, 0, 0, 1.0]])


@dataclass(frozen=True)
class PoseSettings:
    """How the pose is searched and what is assumed of it before the masks are read."""

    azimuths: int = 8  # starting hypotheses per group, evenly around the object's vertical (+y)
    elevation: float = 27.5  # their camera elevation in degrees (R2N2's renders: 25-30)
    distance: float = 2.0  # their first camera distance (object units), then set by the mask's box
    keep: int = 2  # hypotheses that run the joint LM after screening
    screen_iterations: int = 6  # pose-only LM steps per hypothesis at the fused code
    # Silhouette sharpness per LM stage, x the observation's tau, widest first: a pose far off has silhouette rows
    # only where a wide sigmoid reaches. Screening runs at the first; the joint runs go through all of them.
    tau_schedule: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
    stage_iterations: int = 8  # LM steps at most per sharpness
    # ... of which the last this many move the code with the pose
    code_stages: int = 2
    # A code whose SDF lies within this of the ray search's grid (at its probe nodes) reads that grid instead of
    # building its own, with the search's margin widened by the drift (`GridCache`; 0: a grid per code)
    grid_reuse: float = 0.05
    rotation_prior_deg: float = 60.0  # the prior's std about each hypothesis, per axis
    # ... where a viewpoint head chose the hypotheses: its azimuth is within 15 degrees for 92 % of val chairs
    rotation_prior_with_head_deg: float = 10.0
    # The prior's std of the tilt (rotation about the object's two horizontal axes, x and z) where it differs from
    # the rotation's: an upright object seen from a known elevation range (None: the rotation's std on every axis)
    tilt_prior_deg: float | None = None
    translation_prior: float = 1.0  # ... in object units
    scale_prior: float = 0.15  # ... of the log scale (where a baseline makes it observable)
    distinct_deg: float = 30.0  # a runner-up is a pose at least this far from the winner
    ambiguous_gap: float = 3.0  # a runner-up within this energy of the winner: ambiguous
    # With a viewpoint head: the azimuth bins within this much -log p of the image's most likely one start
    # hypotheses (at most `azimuths` of them), with the best one's half turn
    appearance_window: float = 4.0
    # s of the pose's rows in the Laplace covariance (None: the code's information scale), fitted on val shapes so
    # the rotation's squared error matches its variance (`reconstruct.py --fit-pose`)
    pose_information_scale: float | None = None
    # Hold each group's distance along its reference camera's axis while the code is fixed (the screening and the
    # joint run's first stages), freeing it with the code: at the fused code the wide silhouettes move the object
    # away from the camera. Off: holding it removes that bias and changes which rotation wins, for no IoU gain
    # measured (docs/pose.md, "From one view, what the IoU lacks is the object's distance")
    hold_depth: bool = False

    def precision(self, dofs: int, with_head: bool = False) -> Tensor:  # [dofs, dofs] float64
        rotation = self.rotation_prior_with_head_deg if with_head else self.rotation_prior_deg
        tilt = rotation if self.tilt_prior_deg is None else self.tilt_prior_deg
        # the state's rotation is R_hyp exp(omega), omega in the object's axes: y is its vertical (the azimuth)
        stds = [math.radians(a) for a in (tilt, rotation, tilt)] + [self.translation_prior] * 3 + [self.scale_prior]
        return torch.diag(1.0 / torch.tensor(stds[:dofs], dtype=torch.float64) ** 2)


@dataclass(frozen=True)
class PoseGroups:
    """Which views share a pose: group [V] (index per view) and cam_from_ref [V] ([4, 4] rigid, from the group's
    reference camera; identity for a view alone)."""

    group: tuple[int, ...]
    cams_from_ref: tuple[np.ndarray, ...]

    @classmethod
    def separate(cls, n_views: int) -> "PoseGroups":
        """Every view its own pose (no known relative motion)."""
        return cls(tuple(range(n_views)), tuple(np.eye(4) for _ in range(n_views)))

    @classmethod
    def shared(cls, cams_from_first: Sequence[np.ndarray]) -> "PoseGroups":
        """One pose for all, each view's motion from the first camera given."""
        return cls(tuple(0 for _ in cams_from_first), tuple(np.asarray(c, dtype=np.float64) for c in cams_from_first))

    @classmethod
    def from_cameras(cls, world_to_cams: Sequence[np.ndarray]) -> "PoseGroups":
        """One pose for views whose cameras [V][4, 4] are known in some common frame (odometry, a turntable, R2N2's
        rows): only their motion from the first is kept."""
        first = np.linalg.inv(np.asarray(world_to_cams[0], dtype=np.float64))
        return cls.shared([np.asarray(w2c, dtype=np.float64) @ first for w2c in world_to_cams])

    @property
    def count(self) -> int:
        return max(self.group) + 1 if self.group else 0

    def members(self, g: int) -> list[int]:
        return [i for i, k in enumerate(self.group) if k == g]

    def dofs(self, g: int) -> int:
        return 7 if scale_observable([self.cams_from_ref[i] for i in self.members(g)]) else 6


def group_dofs(groups: PoseGroups, views: Sequence[ObservedView], use_depth: bool) -> list[int]:
    """Each group's pose degrees of freedom: 7 (with the log scale) where a baseline or, with use_depth, a view's
    depth map makes the object's size observable; else 6."""
    return [
        7 if use_depth and any(views[i].depth is not None for i in groups.members(g)) else groups.dofs(g)
        for g in range(groups.count)
    ]


def in_object_units(view: ObservedView, world_to_cam: np.ndarray, scale: float) -> ObservedView:
    """The view through an object-unit camera (`Pose.object_camera`), its depth map (camera units) divided by the
    scale the object is seen at, so its returns land where the camera saw them."""
    depth = None if view.depth is None else view.depth / scale
    return replace(view, world_to_cam=world_to_cam, depth=depth)


@dataclass
class PosedPosterior(Posterior):
    """The refined code (its marginal: mu [D], cov [D, D]) with each pose group's MAP pose, its covariance over
    (rotation [rad], translation [object units], log scale where observable), and the hypotheses' report."""

    poses: list[Pose] = field(default_factory=list)
    pose_cov: list[Tensor] = field(default_factory=list)
    hypotheses: list[dict[str, Any]] = field(default_factory=list)  # per group: its hypotheses and runner-up
    cameras: list[np.ndarray] = field(default_factory=list)  # per view: its estimated world_to_cam [4, 4]
    scales: list[float] = field(default_factory=list)  # per view: its group's scale (object -> camera units)

    def posed_views(self, views: Sequence[ObservedView]) -> list[ObservedView]:
        """The views (as given to the estimate) through their estimated cameras, depth maps in object units."""
        return [in_object_units(v, c, s) for v, c, s in zip(views, self.cameras, self.scales)]

    def pose_record(self, g: int) -> dict[str, Any]:
        """Group g's pose, its std (degrees per axis and overall; object units; log scale) and hypotheses."""
        cov, pose = self.pose_cov[g].double(), self.poses[g]
        rot = cov[:3, :3]
        return {
            "rotation_std_deg": math.degrees(math.sqrt(float(torch.trace(rot)) / 3.0)),
            "rotation_std_deg_axes": [math.degrees(math.sqrt(float(v))) for v in torch.diagonal(rot)],
            "translation_std": [math.sqrt(float(v)) for v in torch.diagonal(cov[3:6, 3:6])],
            "scale": pose.scale,
            "scale_std": math.sqrt(float(cov[6, 6])) if cov.shape[0] > 6 else None,
            **self.hypotheses[g],
        }

    def record(self) -> dict[str, Any]:
        out = super().record()
        out["pose"] = {
            "estimated": True,
            "groups": [self.pose_record(g) for g in range(len(self.poses))],
            "cameras": [c.tolist() for c in self.cameras],
        }
        return out


# ---- the state's energy and Jacobian -------------------------------------------------------------------------


class GridCache:
    """The ray search's SDF grid (`observation.code_grid`), shared by nearby codes.

    A grid is built at one code and read for every later code whose SDF stays within `reuse` of it: the drift is
    measured at `probes` of the grid's nodes (half those nearest its surface, where silhouettes are decided, half
    spread over the ball, where a new part could appear) by one decoder pass, and the search widens its margin by
    twice that drift, so a ray the new code brings near the surface still gets exact decoder samples. A code that
    moved further gets a grid of its own. Pose-only steps and hypotheses screened at one code read one grid; code
    steps of a converging LM, each a small move, read it until their drift adds up (reuse = 0: a grid per code).
    """

    def __init__(self, reuse: float = 0.0, probes: int = 1024) -> None:
        self.reuse, self.probes = reuse, probes
        self.z: Tensor | None = None
        self.grid: Any = None
        self.probe_points = torch.zeros(0, 3)
        self.probe_values = torch.zeros(0)
        self.built = 0  # grids built so far (for the cost's accounting)

    def get(self, decoder: torch.nn.Module, z: Tensor, obs: ObservationSettings) -> Any:
        if self.z is not None and torch.equal(self.z, z):
            return self.grid
        if self.grid is not None and self.reuse > 0 and self.probe_values.numel():
            sdf, _ = code_functions(decoder, z.detach().float())
            drift = float((sdf(self.probe_points) - self.probe_values).abs().max())
            if drift <= self.reuse:
                return replace(self.grid, drift=drift)
        self.z, self.grid = z.clone(), code_grid(decoder, z, obs)
        self.built += 1
        if self.grid is not None and self.reuse > 0:
            self.probe_points, self.probe_values = grid_probes(self.grid, self.probes)
        return self.grid


def grid_probes(grid: SDFGrid, count: int) -> tuple[Tensor, Tensor]:
    """`count` of the grid's queried nodes: half those with the smallest |SDF|, half evenly spread over the rest,
    as (points [K, 3], their stored values [K])."""
    values, queried = grid.volume.reshape(-1), grid.queried()
    if queried.numel() <= count:
        chosen = queried
    else:
        order = queried[values[queried].abs().argsort()]
        near, rest = order[: count // 2], order[count // 2 :]
        spread = rest[torch.linspace(0, rest.numel() - 1, count - near.numel()).long()]
        chosen = torch.cat([near, spread])
    return grid.nodes(chosen), values[chosen]


@dataclass
class State:
    z: Tensor  # [D] float64
    poses: list[Pose]


class Problem:
    """One joint refinement: the prior, the views and their groups, and the pose priors about the hypotheses."""

    def __init__(
        self,
        decoder,
        mu,
        var,
        views,
        groups,
        settings,
        pose_settings,
        hypotheses,
        code_precision=None,
        azimuth_logp=None,
    ):
        self.decoder, self.views, self.groups = decoder, list(views), groups
        self.azimuth_logp = azimuth_logp  # per view: log p(azimuth bin) [bins] from the image, or None
        self.settings, self.pose_settings, self.obs = settings, pose_settings, settings.observation
        self.mu = mu.detach().double()
        self.code_precision = prior_precision(var) if code_precision is None else code_precision
        self.hypotheses = hypotheses  # [G] Pose: each pose prior's centre
        self.use_depth = settings.mode == "depth"
        self.dofs = group_dofs(groups, self.views, self.use_depth)
        self.pose_precision = [
            pose_settings.precision(d, self.has_head(g, azimuth_logp)) for g, d in enumerate(self.dofs)
        ]
        D = self.mu.shape[0]
        self.columns = [D + sum(self.dofs[:g]) for g in range(groups.count)]
        self.width = D + sum(self.dofs)
        self.grids = GridCache(pose_settings.grid_reuse)

    def posed(self, state: State) -> list[ObservedView]:
        """The views through the state's cameras, in object units: each depth map divided by its group's scale."""
        return [
            in_object_units(v, state.poses[g].object_camera(c), state.poses[g].scale)
            for v, g, c in zip(self.views, self.groups.group, self.groups.cams_from_ref)
        ]

    def has_head(self, g: int, azimuth_logp) -> bool:
        return azimuth_logp is not None and any(azimuth_logp[i] is not None for i in self.groups.members(g))

    def appearance(self, state: State) -> float:
        """sum over views of -log p(the azimuth bin the state's pose puts the camera in), relative to each view's
        most likely bin: what the image says of the pose, beside the masks (0 without a viewpoint head)."""
        return appearance_energy(state.poses, self.groups, self.azimuth_logp)

    def pose_errors(self, state: State) -> list[np.ndarray]:
        return [self.hypotheses[g].error(state.poses[g])[: self.dofs[g]] for g in range(self.groups.count)]

    def residuals(self, state: State) -> tuple[Residuals, Tensor]:
        z = state.z.float()
        grid = self.grids.get(self.decoder, z, self.obs)
        res = residuals(self.decoder, z, self.posed(state), self.obs, self.use_depth, jacobian=False, grid=grid)
        return res, row_weights(res, self.settings)

    def energy(self, state: State, res: Residuals, w: Tensor) -> float:
        dz = state.z - self.mu
        e = 0.5 * dz @ self.code_precision @ dz + 0.5 * (w * res.r.double().square()).sum()
        for err, P in zip(self.pose_errors(state), self.pose_precision):
            err = torch.as_tensor(err)
            e = e + 0.5 * err @ P @ err
        return float(e)

    def jacobian(self, state: State, res: Residuals) -> Tensor:  # [R, width] float64
        """dr/d(z, xi_1..xi_G): one gradient pass over the rows' points, the code and pose columns by the chain rule."""
        J = torch.zeros(res.r.shape[0], self.width, dtype=torch.float64)
        points = torch.cat([p.points for p in res.pending]) if res.pending else torch.zeros(0, 3)
        if not points.shape[0]:
            return J
        _, gradients = code_functions(self.decoder, state.z.float())
        _, grad_z, grad_x = gradients(points)
        D, start = self.mu.shape[0], 0
        for p in res.pending:
            end = start + p.points.shape[0]
            if end > start:
                gz, gx = grad_z[start:end], grad_x[start:end]
                g = self.groups.group[int(res.view[p.rows[0]])]
                c, d = self.columns[g], self.dofs[g]
                J[p.rows, :D] = p.finish(gz, gx).double()
                J[p.rows, c : c + d] = p.finish(point_jacobian(p.points, gx, d), gx).double()
            start = end
        return J

    def prior_terms(self, state: State) -> tuple[Tensor, Tensor]:
        """The priors' Gauss-Newton Hessian [width, width] and gradient [width] (a pose error's Jacobian in its
        own perturbation taken as the identity: exact at the hypothesis, first order about it)."""
        H = torch.zeros(self.width, self.width, dtype=torch.float64)
        g = torch.zeros(self.width, dtype=torch.float64)
        D = self.mu.shape[0]
        H[:D, :D] = self.code_precision
        g[:D] = self.code_precision @ (state.z - self.mu)
        for k, (err, P) in enumerate(zip(self.pose_errors(state), self.pose_precision)):
            c, d = self.columns[k], self.dofs[k]
            H[c : c + d, c : c + d] = P
            g[c : c + d] = P @ torch.as_tensor(err)
        return H, g

    def step(self, state: State, delta: Tensor) -> State:
        D = self.mu.shape[0]
        poses = [
            p.perturbed(delta[self.columns[g] : self.columns[g] + self.dofs[g]].numpy())
            for g, p in enumerate(state.poses)
        ]
        return State(state.z + delta[:D], poses)


def at_sharpness(problem: Problem, multiple: float) -> Problem:
    """The same problem with the silhouette's tau multiplied by `multiple`."""
    obs = replace(problem.settings.observation, tau=problem.settings.observation.tau * multiple)
    stage = Problem(
        problem.decoder,
        problem.mu,
        None,
        problem.views,
        problem.groups,
        replace(problem.settings, observation=obs),
        problem.pose_settings,
        problem.hypotheses,
        code_precision=problem.code_precision,
        azimuth_logp=problem.azimuth_logp,
    )
    stage.grids = problem.grids  # the SDF grid does not depend on the sharpness
    return stage


def staged(problem: Problem, state: State, iterations: int, code_stages: int, schedule: Sequence[float]):
    """`levenberg_marquardt` at each sharpness of the schedule in turn, each from the last's result, the code free
    in the last `code_stages` of them (the poses alone before): (the final stage's problem, state, residuals,
    weights, J, energy, steps in all)."""
    total = 0
    for k, multiple in enumerate(schedule):
        stage = at_sharpness(problem, multiple)
        code_free = k >= len(schedule) - code_stages
        state, res, w, J, e, steps = levenberg_marquardt(stage, state, iterations, code_free)
        total += steps
    return stage, state, res, w, J, e, total


def levenberg_marquardt(problem: Problem, state: State, iterations: int, code_free: bool):
    """Damped Gauss-Newton over the poses (and the code where code_free): (state, residuals, weights, J, energy,
    steps); J is None where the residuals went non-finite."""
    settings = problem.settings
    res, w = problem.residuals(state)
    J = problem.jacobian(state, res)
    e = problem.energy(state, res, w)
    free = torch.ones(problem.width, dtype=torch.bool)
    free[: problem.mu.shape[0]] = code_free
    lam, steps = settings.damping, 0
    for steps in range(1, iterations + 1):
        if not (torch.isfinite(res.r).all() and torch.isfinite(J).all()):
            return state, res, w, None, e, steps
        H_prior, g_prior = problem.prior_terms(state)
        H = H_prior + J.T @ (w[:, None] * J)
        if not code_free and problem.pose_settings.hold_depth:
            H = H + depth_hold(problem, state, H)
        H = H[free][:, free]
        g = (g_prior + J.T @ (w * res.r.double()))[free]
        improved = False
        for _ in range(6):
            delta = torch.zeros(problem.width, dtype=torch.float64)
            delta[free] = torch.linalg.solve(H + lam * torch.diag(torch.diagonal(H)), -g)
            trial = problem.step(state, delta)
            trial_res, trial_w = problem.residuals(trial)
            trial_e = problem.energy(trial, trial_res, trial_w)
            if trial_e < e:
                improved = True
                break
            lam *= 4.0
        if not improved:
            break
        state, res, w, lam = trial, trial_res, trial_w, max(lam / 3.0, 1e-7)
        J = problem.jacobian(state, res)
        done = (e - trial_e) < settings.tolerance * max(e, 1e-12)
        e = trial_e
        if done:
            break
    return state, res, w, J, e, steps


def depth_hold(problem: Problem, state: State, H: Tensor) -> Tensor:  # [width, width] float64
    """A stiffness on each group's translation along its reference camera's axis: kappa n n^T with n = R^T e_z,
    the camera's axis in the object's axes (a step v moves the object by scale R v), kappa far above H's diagonal,
    so a damped Gauss-Newton step leaves the object's distance where it is."""
    out = torch.zeros_like(H)
    kappa = 1e6 * (1.0 + float(H.diagonal().abs().max()))
    for g, pose in enumerate(state.poses):
        n = torch.as_tensor(pose.R[2], dtype=torch.float64)  # R^T e_z
        c = problem.columns[g] + TRANSLATION.start
        out[c : c + 3, c : c + 3] = kappa * torch.outer(n, n)
    return out


def appearance_energy(poses: Sequence[Pose], groups: PoseGroups, azimuth_logp: Sequence[Tensor | None] | None) -> float:
    """sum over views of -(log p(bin of the camera's azimuth under its group's pose) - max log p)."""
    if azimuth_logp is None:
        return 0.0
    total = 0.0
    for i, logp in enumerate(azimuth_logp):
        if logp is None:
            continue
        camera = poses[groups.group[i]].object_camera(groups.cams_from_ref[i])
        azimuth, _ = camera_azimuth_elevation(camera)
        k = int(round(azimuth / (360.0 / logp.shape[0]))) % logp.shape[0]
        total += float(logp.max() - logp[k])
    return total
