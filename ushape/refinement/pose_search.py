"""The search of `joint`'s pose-and-shape refinement: where it starts and which start wins.

Symmetry: chairs and tables look alike from the front and the back, so each pose group starts from several
azimuths around the object's vertical, at `elevation`, each placed so the fused code's silhouette covers the
first view's mask box (with a baseline: at the triangulated centre of the views' mask boxes, the scale set to
match; with a depth map: scaled about the camera so the code's nearest points sit at the returns' depth, which
sets the object's distance and size in the depth's units). Without a viewpoint head these are `azimuths` evenly
spaced ones; with one, the bins the images allow and the best one's half turn, each paying -log p of its azimuth
(`joint.appearance_energy`). Every start is screened by pose-only Levenberg-Marquardt steps at the fused code
with a wide silhouette; the best and the best distinct one (`distinct_deg` away) run the joint LM through the
sharpness schedule, and the lowest energy wins.
The runner-up is the lowest run whose pose ends at least `distinct_deg` from the winner's; a gap under
`ambiguous_gap` is reported as ambiguous (two poses the views explain about equally well). The Laplace
covariance over (code, pose) is taken at the winner (`joint` module docstring).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence

import numpy as np
import torch
from torch import Tensor

from ushape.data.cameras import look_at_extrinsics, orbit_position
from ushape.decoder.query import frozen
from ushape.refinement.joint import (
    PLACEHOLDER_CAMERA,
    GridCache,
    PosedPosterior,
    PoseGroups,
    PoseSettings,
    Problem,
    State,
    appearance_energy,
    staged,
)
from ushape.refinement.observation import code_functions
from ushape.refinement.pose import Pose, rotation_angle_deg
from ushape.refinement.pose_depth import depth_placed, usable_depth
from ushape.refinement.posterior import MODES, RefineSettings, summarise
from ushape.refinement.views import ObservedView, mask_box, screen_view


def interior_points(decoder: torch.nn.Module, z: Tensor, nodes: int = 24) -> Tensor:
    """Grid points [P, 3] inside the code's surface (at least the one nearest inside): where its silhouette falls."""
    sdf, _ = code_functions(decoder, z.float())
    axis = torch.linspace(-1.0, 1.0, nodes)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    values = sdf(points)
    inside = values < 0
    return points[inside] if bool(inside.any()) else points[values.argmin()][None]


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


def check_views(views: Sequence[ObservedView], groups: PoseGroups, settings: RefineSettings) -> None:
    """A ValueError, before any work, where the pose cannot be estimated from these views: not masks, a group
    entry per view missing, or a view whose mask does not outline the object."""
    if settings.mode not in MODES:
        raise ValueError(f"the pose is estimated from masks, or masks and depth: mode {settings.mode!r} is neither")
    if settings.mode == "depth" and settings.observation.depth_residual != "surface":
        raise ValueError(
            "the pose is estimated with the 'surface' depth residual only (the traced depth's residual has no "
            f"derivative in the object's scale here), got depth_residual={settings.observation.depth_residual!r}"
        )
    if len(groups.group) != len(views):
        raise ValueError(f"{len(views)} views but {len(groups.group)} group entries")
    for i, v in enumerate(views):
        screened = screen_view(replace(v, world_to_cam=PLACEHOLDER_CAMERA), use_depth=False)
        if screened.view is None:
            raise ValueError(f"view {i}: {screened.fallback}: a pose needs a mask that outlines the object")


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
    check_views(views, groups, settings)
    if azimuth_logp is not None and len(azimuth_logp) != len(views):
        raise ValueError(f"{len(views)} views but {len(azimuth_logp)} azimuth distributions")
    views, notes = usable_depth(views, settings)
    with frozen(decoder):
        points = interior_points(decoder, mu.detach()).numpy().astype(np.float64)
        starts = []
        for g in range(groups.count):
            members = groups.members(g)
            first = members[0]
            cam = np.asarray(groups.cams_from_ref[first], dtype=np.float64)
            logp = None if azimuth_logp is None else azimuth_logp[first]
            bins = None if logp is None else int(logp.shape[0])
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
            ranged = [i for i in members if views[i].depth is not None] if settings.mode == "depth" else []
            if ranged:  # a depth map: the object's distance, and so its size, in the depth's units
                ranging = np.asarray(groups.cams_from_ref[ranged[0]], dtype=np.float64)
                group_starts = [(a, depth_placed(p, views[ranged[0]], ranging, points)) for a, p in group_starts]
            if bins is not None:
                group_starts = likely_starts(group_starts, g, groups, azimuth_logp, pose_settings)
            starts.append(group_starts)
        return _search(decoder, mu, var, views, groups, settings, pose_settings, starts, azimuth_logp, notes)


def refine_from_poses(
    decoder: torch.nn.Module,
    mu: Tensor,  # [D] the fused code
    var: Tensor,  # [D] or [D, D] its variance
    views: Sequence[ObservedView],
    groups: PoseGroups,
    poses: Sequence[Pose],  # [G] one start per group, in its reference camera (a tracker's prediction, say)
    settings: RefineSettings = RefineSettings(),
    pose_settings: PoseSettings = PoseSettings(),
) -> PosedPosterior:
    """MAP (pose, code) and its Laplace posterior from one given pose per group, with no search over hypotheses:
    the same screening and joint schedule as `refine_pose_and_shape`, the pose prior (`rotation_prior_deg`,
    `tilt_prior_deg`, `translation_prior`, `scale_prior`) centred on the given poses. Where a pose is roughly
    known (a tracker, a previous frame), and to tell the search's errors from the joint refinement's: started at
    the true pose, what is left to the known-camera refinement is not the search's."""
    check_views(views, groups, settings)
    if len(poses) != groups.count:
        raise ValueError(f"{groups.count} pose groups but {len(poses)} starting poses")
    views, notes = usable_depth(views, settings)
    with frozen(decoder):
        starts = [[(0.0, p)] for p in poses]
        return _search(decoder, mu, var, views, groups, settings, pose_settings, starts, notes=notes)


def _search(
    decoder, mu, var, views, groups, settings, pose_settings, starts, azimuth_logp=None, notes=None
) -> PosedPosterior:
    """Screen every group's hypotheses at the fused code (the other groups at their best so far), run the joint LM
    from the best of all groups and from each group's distinct alternates, and return the lowest-energy run's
    Laplace posterior with each group's runner-up."""
    best = [h[0][1] for h in starts]
    schedule = pose_settings.tau_schedule or (1.0,)
    grids = GridCache(pose_settings.grid_reuse)  # shared by every problem below: the screened hypotheses read one

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
    return _laplace(winner["problem"], winner["state"], res, w, J, steps, winner["energy"], report, notes)


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


def _laplace(problem: Problem, state: State, res, w, J, steps, e, report, notes=None) -> PosedPosterior:
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
    posed = problem.posed(state)
    return PosedPosterior(
        mu=state.z.float(),
        cov=cov[:D, :D].float(),
        iterations=steps,
        energy_end=e,
        rows=rows,
        rms=rms,
        information=information[:D, :D],
        views=[
            {"used": "depth" if v.depth is not None and problem.use_depth else "masks", "fallback": note}
            for v, note in zip(problem.views, notes or [None] * len(problem.views))
        ],
        poses=state.poses,
        pose_cov=pose_cov,
        hypotheses=report,
        cameras=[v.world_to_cam for v in posed],
        scales=[state.poses[g].scale for g in problem.groups.group],
    )
