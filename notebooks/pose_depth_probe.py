"""What one view's pose estimate lacks: the object's distance. pose_measure.py with one of five probes.

    PYTHONPATH=. python notebooks/pose_depth_probe.py given-position MODEL OUT.jsonl --world W --views 1 \\
        --set translation_prior=0.01
    PYTHONPATH=. python notebooks/pose_depth_probe.py trace MODEL OUT.jsonl --world W --views 1 --shapes 12

given-position: every hypothesis starts at the true object position in the first camera (its rotation still
searched), held there by the translation prior that --set gives: the known-camera refinement's IoU that is left
to the rotation alone. One view only (a group's reference camera is the first view's). With --mode depth the
true scale (1) is kept too where --set scale_prior=0.01 holds it.
trace: prints each LM call's depth error (the object's origin along the first camera's axis, + farther) before
and after it, for the screening (code fixed, the widest silhouette) and the joint runs: where the estimate moves.
given-scale (--mode depth): the hypotheses placed by the mask's box at the true scale (1: the world's depth is in
object units) instead of by the depth, held there by --set scale_prior=0.01; the position is estimated.
hold-in-screening: PoseSettings.hold_depth in the screening only, the joint runs free.
reset-after-screening: each screened hypothesis's depth put back where the mask's box placed it (its image
centre kept), the joint runs free from there.
Everything else is pose_measure.py's, arguments included (docs/pose.md, "From one view ...").
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import pose_measure  # noqa: E402

from ushape.refinement import pose_search  # noqa: E402
from ushape.refinement.pose import Pose  # noqa: E402

TRUTH: dict[str, np.ndarray] = {}
TRACE: list[dict] = []
_pose_row, _staged = pose_measure.pose_row, pose_search.staged


def pose_row(decoder, fused, views, *args, **kwargs):
    TRUTH["t"] = Pose.from_world_to_cam(views[0].world_to_cam).t
    TRACE.clear()
    row = _pose_row(decoder, fused, views, *args, **kwargs)
    if TRACE:
        print("trace", json.dumps(TRACE), flush=True)
    return row


def at_true_position(R, view, cam_from_ref, points, distance) -> Pose:
    if not np.allclose(cam_from_ref, np.eye(4)):
        raise SystemExit("given-position places one view's object: pass --views 1")
    return Pose(R, TRUTH["t"].copy(), 1.0)


def traced(problem, state, iterations, code_stages, schedule):
    before = float(state.poses[0].t[2] - TRUTH["t"][2])
    out = _staged(problem, state, iterations, code_stages, schedule)
    after = float(out[1].poses[0].t[2] - TRUTH["t"][2])
    TRACE.append({"joint": code_stages > 0, "before": round(before, 3), "after": round(after, 3)})
    return out


def held_in_screening(problem, state, iterations, code_stages, schedule):
    problem.pose_settings = replace(problem.pose_settings, hold_depth=code_stages == 0)
    return traced(problem, state, iterations, code_stages, schedule)


def reset_after_screening(problem, state, iterations, code_stages, schedule):
    before = list(state.poses)
    out = traced(problem, state, iterations, code_stages, schedule)
    if code_stages == 0:  # x t keeps the object's image centre and puts its depth back
        out[1].poses = [Pose(p.R, p.t * (b.t[2] / p.t[2]), p.scale) for p, b in zip(out[1].poses, before)]
    return out


PROBES = {"trace": traced, "hold-in-screening": held_in_screening, "reset-after-screening": reset_after_screening}


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in ("given-position", "given-scale", *PROBES):
        raise SystemExit(__doc__)
    probe = sys.argv.pop(1)
    pose_measure.pose_row = pose_row
    if probe == "given-position":
        pose_search.placed_hypothesis = at_true_position
        pose_search.depth_placed = lambda pose, *args, **kwargs: pose  # --mode depth: the truth is not moved
    elif probe == "given-scale":
        pose_search.depth_placed = lambda pose, *args, **kwargs: pose  # placed at scale 1, the world's truth
    else:
        pose_search.staged = PROBES[probe]
    pose_measure.main()


if __name__ == "__main__":
    main()
