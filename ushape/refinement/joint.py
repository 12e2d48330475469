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
a group's baseline makes it observable; from one view a larger, farther object looks the same.

Symmetry: chairs and tables look alike from the front and the back, so each group starts from
`azimuths` hypotheses around the vertical, at `elevation`, placed so the fused code's silhouette covers the
mask's box. Each is screened by a few pose-only Levenberg-Marquardt steps at the fused code; the `keep`
lowest then run the joint LM over (pose, code), and the lowest final energy wins. The runner-up is the
lowest hypothesis whose rotation differs from the winner's by more than `distinct_deg`; an energy gap
under `ambiguous_gap` is reported as ambiguous (two poses the masks explain about equally well).

The Laplace posterior at the MAP is a full covariance over (z, xi): (prior precision + s J^T W J)^-1. The
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

from ushape.data.cameras import R2N2_FOV_DEG, look_at_extrinsics, orbit_position
from ushape.decoder.query import frozen
from ushape.encoder.viewpoint import camera_azimuth_elevation
from ushape.refinement.observation import ObservationSettings, Residuals, code_functions, code_grid, residuals
from ushape.refinement.pose import Pose, point_jacobian, rotation_angle_deg, scale_observable
from ushape.refinement.posterior import (
    Posterior,
    RefineSettings,
    prior_precision,
    row_weights,
    summarise,
)
from ushape.refinement.views import ObservedView, screen_view

# A valid camera in front of the object: what an unposed view carries until the estimate replaces it.
PLACEHOLDER_CAMERA = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 2.0], [0, 0, 0, 1.0]])


@dataclass(frozen=True)
class PoseSettings:
    """How the pose is searched and what is assumed of it before the masks are read."""

    azimuths: int = 8  # starting hypotheses per group, evenly around the object's vertical (+y)
    elevation: float = 27.5  # their camera elevation in degrees (R2N2's renders: 25-30)
    distance: float = 2.0  # their first camera distance (object units), then set by the mask's box
    fov_deg: float = R2N2_FOV_DEG  # field of view for an image with no intrinsics (across its larger side)
    keep: int = 2  # hypotheses that run the joint LM after screening
    screen_iterations: int = 6  # pose-only LM steps per hypothesis at the fused code
    # Silhouette sharpness per LM stage, x the observation's tau, widest first: a pose far off has silhouette rows
    # only where a wide sigmoid reaches. Screening runs at the first; the joint runs go through all of them.
    tau_schedule: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
    stage_iterations: int = 8  # LM steps at most per sharpness
    # ... of which the last this many move the code with the pose (each code step builds a new SDF grid; a pose
    # step reuses it)
    code_stages: int = 2
    rotation_prior_deg: float = 60.0  # the prior's std about each hypothesis, per axis
    # ... where a viewpoint head chose the hypotheses: its azimuth is within 15 degrees for 92 % of val chairs
    rotation_prior_with_head_deg: float = 10.0
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

    def precision(self, dofs: int, with_head: bool = False) -> Tensor:  # [dofs, dofs] float64
        rotation = self.rotation_prior_with_head_deg if with_head else self.rotation_prior_deg
        stds = [math.radians(rotation)] * 3 + [self.translation_prior] * 3 + [self.scale_prior]
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

    @property
    def count(self) -> int:
        return max(self.group) + 1 if self.group else 0

    def members(self, g: int) -> list[int]:
        return [i for i, k in enumerate(self.group) if k == g]

    def dofs(self, g: int) -> int:
        return 7 if scale_observable([self.cams_from_ref[i] for i in self.members(g)]) else 6


@dataclass
class PosedPosterior(Posterior):
    """The refined code (its marginal: mu [D], cov [D, D]) with each pose group's MAP pose, its covariance over
    (rotation [rad], translation [object units], log scale where observable), and the hypotheses' report."""

    poses: list[Pose] = field(default_factory=list)
    pose_cov: list[Tensor] = field(default_factory=list)
    hypotheses: list[dict[str, Any]] = field(default_factory=list)  # per group: its hypotheses and runner-up
    cameras: list[np.ndarray] = field(default_factory=list)  # per view: its estimated world_to_cam [4, 4]

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


def default_intrinsics(image_hw: tuple[int, int], fov_deg: float) -> np.ndarray:
    """K [3, 3] of an image with no camera file: the field of view across its larger side, centred."""
    h, w = image_hw
    f = 0.5 * max(h, w) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


# ---- the state's energy and Jacobian -------------------------------------------------------------------------


class GridCache:
    """The SDF grid of the last code asked for (`observation.code_grid`): steps that move only the poses, and every
    hypothesis screened at the fused code, build it once."""

    def __init__(self) -> None:
        self.z: Tensor | None = None
        self.grid: Any = None

    def get(self, decoder: torch.nn.Module, z: Tensor, obs: ObservationSettings) -> Any:
        if self.z is None or not torch.equal(self.z, z):
            self.z, self.grid = z.clone(), code_grid(decoder, z, obs)
        return self.grid


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
        self.dofs = [groups.dofs(g) for g in range(groups.count)]
        self.pose_precision = [
            pose_settings.precision(d, self.has_head(g, azimuth_logp)) for g, d in enumerate(self.dofs)
        ]
        D = self.mu.shape[0]
        self.columns = [D + sum(self.dofs[:g]) for g in range(groups.count)]
        self.width = D + sum(self.dofs)
        self.grids = GridCache()

    def posed(self, state: State) -> list[ObservedView]:
        return [
            replace(v, world_to_cam=state.poses[g].object_camera(c))
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
        res = residuals(self.decoder, z, self.posed(state), self.obs, False, jacobian=False, grid=grid)
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
        H = (H_prior + J.T @ (w[:, None] * J))[free][:, free]
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


# ---- hypotheses -------------------------------------------------------------------------------------------------


def interior_points(decoder: torch.nn.Module, z: Tensor, nodes: int = 24) -> Tensor:
    """Grid points [P, 3] inside the code's surface (at least the one nearest inside): where its silhouette falls."""
    sdf, _ = code_functions(decoder, z.float())
    axis = torch.linspace(-1.0, 1.0, nodes)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    values = sdf(points)
    inside = values < 0
    return points[inside] if bool(inside.any()) else points[values.argmin()][None]


def mask_box(view: ObservedView) -> tuple[float, float, float, float]:
    """(u0, v0, u1, v1) of the mask's observed foreground, pixel edges."""
    mask = (view.mask > 0.5) & view.seen()
    rows, cols = mask.any(1).nonzero().squeeze(1), mask.any(0).nonzero().squeeze(1)
    return float(cols.min()), float(rows.min()), float(cols.max() + 1), float(rows.max() + 1)


def placed_hypothesis(
    R: np.ndarray, view: ObservedView, cam_from_ref: np.ndarray, points: np.ndarray, distance: float
) -> Pose:
    """A pose of rotation R (object -> reference) whose projection of `points` into `view` matches its mask's box:
    the depth set by the boxes' sizes, then the offset by their centres (twice, the second to settle)."""
    K = np.asarray(view.K, dtype=np.float64)
    u0, v0, u1, v1 = mask_box(view)
    R_c, t_c = cam_from_ref[:3, :3], cam_from_ref[:3, 3]
    pose = Pose(R, R_c.T @ (np.array([0.0, 0.0, distance]) - t_c), 1.0)
    for _ in range(2):
        cam = pose.object_camera(cam_from_ref)
        x = points @ cam[:3, :3].T + cam[:3, 3]
        x = x[x[:, 2] > 1e-3]
        if x.shape[0] == 0:
            break
        uv = (x @ K.T)[:, :2] / x[:, 2:3]
        (a0, b0), (a1, b1) = uv.min(0), uv.max(0)
        size = max(a1 - a0, b1 - b0, 1e-6) / max(u1 - u0, v1 - v0)
        # the whole unit sphere (every shape of the decoder's frame) stays in front of the camera
        depth = float(np.clip(float(cam[2, 3]) * size, 1.1, 50.0 * distance))
        centre = np.array([(u0 + u1) / 2.0 - K[0, 2], (v0 + v1) / 2.0 - K[1, 2]]) / np.array([K[0, 0], K[1, 1]])
        shift = np.array([(a0 + a1) / 2.0 - K[0, 2], (b0 + b1) / 2.0 - K[1, 2]]) / np.array([K[0, 0], K[1, 1]])
        centre_cam = np.array([*(centre - shift + cam[:2, 3] / cam[2, 3]) * depth, depth])
        # the object's origin at centre_cam in the view's camera -> in the reference frame
        origin_ref = R_c.T @ (centre_cam * pose.scale - t_c)
        pose = Pose(R, origin_ref, pose.scale)
    return pose


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


def hypothesis_azimuths(settings: PoseSettings, bins: int | None) -> list[float]:
    """The azimuths the hypotheses start from: `azimuths` evenly spaced, or every bin of a viewpoint head."""
    count = bins or settings.azimuths
    return [360.0 * k / count for k in range(count)]


def likely_starts(starts, g, groups, azimuth_logp, settings: PoseSettings) -> list:
    """Group g's starts that the images allow: at most `azimuths` of lowest appearance energy within
    `appearance_window` of the best, and the best's half turn (so a front / back runner-up is weighed)."""

    def energy(start) -> float:
        poses = [start[1]] * groups.count  # only group g's views are scored
        members = groups.members(g)
        logps = [azimuth_logp[i] if i in members else None for i in range(len(azimuth_logp))]
        return appearance_energy(poses, groups, logps)

    scored = sorted(((energy(s), s) for s in starts), key=lambda x: x[0])
    best_energy, best = scored[0]
    kept = [s for e, s in scored if e <= best_energy + settings.appearance_window][: settings.azimuths]
    turn = (best[0] + 180.0) % 360.0
    half_turn = min(starts, key=lambda s: abs(((s[0] - turn) + 180.0) % 360.0 - 180.0))
    if all(half_turn is not s for s in kept):
        kept.append(half_turn)
    return kept


def triangulated_centre(views: Sequence[ObservedView], cams_from_ref: Sequence[np.ndarray]) -> np.ndarray | None:
    """The point [3] (reference frame) nearest, in least squares, to the rays through every view's mask-box centre;
    None where the rays are near parallel (no baseline to triangulate with)."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for view, cam in zip(views, cams_from_ref):
        u0, v0, u1, v1 = mask_box(view)
        ray = np.linalg.solve(np.asarray(view.K, dtype=np.float64), [(u0 + u1) / 2.0, (v0 + v1) / 2.0, 1.0])
        direction = cam[:3, :3].T @ ray
        direction /= np.linalg.norm(direction)
        centre = -cam[:3, :3].T @ cam[:3, 3]
        P = np.eye(3) - np.outer(direction, direction)
        A += P
        b += P @ centre
    if np.linalg.cond(A) > 1e6:
        return None
    return np.linalg.solve(A, b)


def rescaled(pose: Pose, centre: np.ndarray | None, cam_from_ref: np.ndarray) -> Pose:
    """The pose placed by one view moved to the triangulated centre and scaled so that view's silhouette keeps its
    size (size / distance fixed): with a baseline, the object's size in the reference frame's units."""
    if centre is None:
        return pose
    eye = -cam_from_ref[:3, :3].T @ cam_from_ref[:3, 3]
    near, placed = np.linalg.norm(centre - eye), np.linalg.norm(pose.t - eye)
    if (cam_from_ref[:3, :3] @ (centre - eye))[2] <= 0 or placed <= 0:  # behind the camera: keep the placement
        return pose
    return Pose(pose.R, centre.copy(), pose.scale * float(near / placed))


def hypothesis_rotations(
    settings: PoseSettings, cam_from_ref: np.ndarray, bins: int | None = None
) -> list[tuple[float, np.ndarray]]:
    """(azimuth, R [3, 3]): the object's rotation into the reference frame as seen from cameras around it at
    `elevation` (`hypothesis_azimuths`), for a view at cam_from_ref."""
    out = []
    for azimuth in hypothesis_azimuths(settings, bins):
        eye = orbit_position(azimuth, settings.elevation, 1.0)
        cam_from_object = look_at_extrinsics(eye, np.zeros(3))[:3, :3]
        out.append((azimuth, cam_from_ref[:3, :3].T @ cam_from_object))
    return out


# ---- the estimate ---------------------------------------------------------------------------------------------


def refine_pose_and_shape(
    decoder: torch.nn.Module,
    mu: Tensor,  # [D] the fused code
    var: Tensor,  # [D] or [D, D] its variance
    views: Sequence[ObservedView],  # K and mask used; world_to_cam is replaced by the estimate
    groups: PoseGroups,
    settings: RefineSettings = RefineSettings(),
    pose_settings: PoseSettings = PoseSettings(),
    azimuth_logp: Sequence[Tensor | None] | None = None,  # per view: log p(azimuth bin) [bins] (viewpoint head)
) -> PosedPosterior:
    """MAP (pose, code) and the Laplace posterior over both, from the views' masks, with no camera in the object's
    frame (module docstring), and from what the images say of their azimuth where a viewpoint head gave
    azimuth_logp. Every group needs at least one view whose mask shows the object."""
    if settings.mode != "masks":
        raise ValueError("the pose is estimated from masks alone: use mode 'masks' (depth needs known cameras)")
    if len(groups.group) != len(views):
        raise ValueError(f"{len(views)} views but {len(groups.group)} group entries")
    for i, v in enumerate(views):
        screened = screen_view(replace(v, world_to_cam=PLACEHOLDER_CAMERA), use_depth=False)
        if screened.view is None:
            raise ValueError(f"view {i}: {screened.fallback}: a pose needs a mask that outlines the object")
    with frozen(decoder):
        points = interior_points(decoder, mu.detach()).numpy().astype(np.float64)
        starts = []
        if azimuth_logp is not None and len(azimuth_logp) != len(views):
            raise ValueError(f"{len(views)} views but {len(azimuth_logp)} azimuth distributions")
        for g in range(groups.count):
            first = groups.members(g)[0]
            cam = np.asarray(groups.cams_from_ref[first], dtype=np.float64)
            logp = None if azimuth_logp is None else azimuth_logp[first]
            bins = None if logp is None else int(logp.shape[0])
            members = groups.members(g)
            centre = None
            if groups.dofs(g) == 7:  # a baseline: where the object is, and so its size in the reference's units
                centre = triangulated_centre([views[i] for i in members], [groups.cams_from_ref[i] for i in members])
            group_starts = [
                (
                    azimuth,
                    rescaled(placed_hypothesis(R, views[first], cam, points, pose_settings.distance), centre, cam),
                )
                for azimuth, R in hypothesis_rotations(pose_settings, cam, bins)
            ]
            if bins is not None:
                group_starts = likely_starts(group_starts, g, groups, azimuth_logp, pose_settings)
            starts.append(group_starts)
        return _search(decoder, mu, var, views, groups, settings, pose_settings, starts, azimuth_logp)


def _search(decoder, mu, var, views, groups, settings, pose_settings, starts, azimuth_logp=None) -> PosedPosterior:
    """Screen every group's hypotheses at the fused code (the other groups at their best so far), run the joint LM
    from the best of all groups and from each group's distinct alternates, and return the lowest-energy run's
    Laplace posterior with each group's runner-up."""
    best = [h[0][1] for h in starts]
    schedule = pose_settings.tau_schedule or (1.0,)
    grids = GridCache()  # one grid of the fused code for every hypothesis screened

    def about(hypotheses: list[Pose]) -> Problem:  # the problem with its pose priors about these hypotheses
        problem = Problem(
            decoder, mu, var, views, groups, settings, pose_settings, hypotheses, azimuth_logp=azimuth_logp
        )
        problem.grids = grids
        return problem

    screened: list[list[dict[str, Any]]] = []
    mu64 = mu.detach().double()
    for g in range(groups.count):
        rows = []
        for azimuth, hyp in starts[g]:
            hyps = list(best)
            hyps[g] = hyp
            problem = about(hyps)
            _, state, *_, e, _ = staged(
                problem, State(mu64.clone(), hyps), pose_settings.screen_iterations, 0, schedule[:1]
            )
            e += problem.appearance(state)
            rows.append({"azimuth": azimuth, "screen_energy": e, "pose": state.poses[g], "start": hyp})
        rows.sort(key=lambda r: r["screen_energy"])
        best[g] = rows[0]["pose"]
        screened.append(rows)
    chosen = [distinct_rows(rows, pose_settings) for rows in screened]
    plans = [tuple(0 for _ in screened)]  # per run: which of each group's distinct rows it starts from
    for g, picks in enumerate(chosen):
        plans += [tuple(k if h == g else 0 for h in range(len(screened))) for k in range(1, len(picks))]
    runs = []
    for plan in plans:
        rows = [screened[g][chosen[g][k]] for g, k in enumerate(plan)]
        problem = about([r["start"] for r in rows])
        problem, state, res, w, J, e, steps = staged(
            problem,
            State(mu64.clone(), [r["pose"] for r in rows]),
            pose_settings.stage_iterations,
            pose_settings.code_stages,
            schedule,
        )
        e += problem.appearance(state)
        runs.append({"plan": plan, "energy": e, "problem": problem, "state": state, "fit": (res, w, J, steps)})
    winner = min(runs, key=lambda r: r["energy"])
    report = [_group_report(g, screened[g], chosen[g], runs, winner, pose_settings) for g in range(len(screened))]
    res, w, J, steps = winner["fit"]
    return _laplace(winner["problem"], winner["state"], res, w, J, steps, winner["energy"], report)


def distinct_rows(rows: list[dict[str, Any]], pose_settings: PoseSettings) -> list[int]:
    """Indices of up to `keep` screened hypotheses, lowest energy first, each at least `distinct_deg` from those
    before it: the alternatives worth a joint run."""
    picks: list[int] = []
    for i, row in enumerate(rows):
        if all(rotation_angle_deg(row["pose"].R, rows[j]["pose"].R) >= pose_settings.distinct_deg for j in picks):
            picks.append(i)
        if len(picks) == pose_settings.keep:
            break
    return picks


def _group_report(g, rows, picks, runs, winner, pose_settings) -> dict[str, Any]:
    """Group g's hypotheses (start azimuth, screened energy, final energy of the joint run from it) and its
    runner-up: the lowest joint run whose pose of g ends at least `distinct_deg` from the winner's."""
    won = winner["state"].poses[g]
    hypotheses = [{"azimuth": r["azimuth"], "screen_energy": r["screen_energy"]} for r in rows]
    runner = None
    for run in runs:
        k = run["plan"][g]
        hypotheses[picks[k]].setdefault("joint_energy", run["energy"])
        angle = rotation_angle_deg(run["state"].poses[g].R, won.R)
        if angle >= pose_settings.distinct_deg and (runner is None or run["energy"] < runner["energy"]):
            runner = {
                "start_azimuth": rows[picks[k]]["azimuth"],
                "rotation_from_best_deg": angle,
                "energy": run["energy"],
                "energy_gap": run["energy"] - winner["energy"],
                "R": run["state"].poses[g].R.tolist(),
                "t": run["state"].poses[g].t.tolist(),
            }
    return {
        "start_azimuth": rows[picks[winner["plan"][g]]]["azimuth"],
        "energy": winner["energy"],
        "hypotheses": hypotheses,
        "runner_up": runner,
        "ambiguous": bool(runner is not None and runner["energy_gap"] < pose_settings.ambiguous_gap),
    }


def _laplace(problem: Problem, state: State, res, w, J, steps, e, report) -> PosedPosterior:
    D = problem.mu.shape[0]
    rows, rms = summarise(res)
    if J is None or not torch.isfinite(J).all():
        raise FloatingPointError("the joint refinement met a non-finite residual or Jacobian")
    H_prior, _ = problem.prior_terms(state)
    information = J.T @ (w[:, None] * J)
    # the code's information scale s on the code's rows, the pose's (fitted on val: pose_calibration) on the pose's
    pose_scale = problem.pose_settings.pose_information_scale
    scale = torch.full((problem.width,), problem.settings.information_scale, dtype=torch.float64)
    if pose_scale is not None:
        scale[D:] = pose_scale
    cov = torch.linalg.inv(H_prior + scale.sqrt()[:, None] * information * scale.sqrt()[None, :])
    cov = 0.5 * (cov + cov.T)
    pose_cov = [cov[c : c + d, c : c + d].float() for c, d in zip(problem.columns, problem.dofs)]
    cameras = [c for c in (v.world_to_cam for v in problem.posed(state))]
    return PosedPosterior(
        mu=state.z.float(),
        cov=cov[:D, :D].float(),
        iterations=steps,
        energy_end=e,
        rows=rows,
        rms=rms,
        information=information[:D, :D],
        views=[{"used": "masks", "fallback": None} for _ in problem.views],
        poses=state.poses,
        pose_cov=pose_cov,
        hypotheses=report,
        cameras=cameras,
    )
