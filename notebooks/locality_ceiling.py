"""How local can a Gaussian over the code make the mesh's uncertainty? The refined posterior with its views'
information scaled by c, up to noise-free views.

    PYTHONPATH=. python notebooks/locality_ceiling.py RUN OUT.jsonl [--test 6] [--size 32] [--calibration JSON]
    PYTHONPATH=. python notebooks/locality_ceiling.py RUN OUT.jsonl --summary

Per test shape and mode (masks, depth): the code refined on views 0 and 6 (the calibrated prior, as
`refinement_measure.py`'s shrink; `--added farthest`: view 0 and the camera farthest from it, in place of 6),
its mesh, the vertices' dSDF/dz G [V, D] at that code, and each view's J^T W J there. For c in SCALES the
posteriors after view 0 and after both views are (P + c sum J^T W J)^-1 (P: the fused prior's precision of
those views), and on that one mesh:
- hidden / visible: median vertex std, hidden from view 0 over visible from it, after view 0;
- shrink: median std shrink from {0} to {0, 6}, on the vertices view 6 sees over the others;
- new / neither: the same shrink on the vertices view 6 sees and view 0 did not, over those neither sees.
c = 1 is the refined posterior; c -> infinity views without noise: what the views do not pin keeps the prior's
variance, and no Gaussian over this code can be more local than that. Beside them, how much of what view 6
sees view 0 saw, how many whitened directions one view's information pins (eigenvalues > 1, i.e. more than
the prior), and the share of the vertices' SDF variance under the prior in its leading 1, 2, 3, 5, 10, 20
directions. With `--calibration` (a `reconstruct.py --fit-refinement` file): the same three ratios as the mesh's
std is drawn with the fit (information scale s, T_sdf var + floor^2 with its floor where a view saw the vertex
and another where none did), the ratios a per-point term outside the code can add.
"""

import argparse
import json
import os

import numpy as np
import torch

from ushape.data.cameras import camera_centre
from ushape.data.layout import WorldIndex
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.encoder.datamodule import view_files
from ushape.mesh.extraction import extract_mesh
from ushape.mesh.visibility import median_ratio
from ushape.propagation.linearised import latent_jacobian, latent_variance
from ushape.recalibration.refine_information import seen_floor_variance
from ushape.reconstruction.calibrated_fusion import default_fusion
from ushape.reconstruction.predictor import load_predictor
from ushape.reconstruction.visibility import seen_by_views, visible_vertices
from ushape.refinement import ObservationSettings, RefineSettings, refine, world_views
from ushape.refinement.observation import residuals
from ushape.refinement.posterior import information_matrix, prior_precision, row_weights

SCALES = (0.1, 1.0, 10.0, 100.0, 1e6)
LEADING = (1, 2, 3, 5, 10, 20)


def vertex_std(G, cov):  # G [V, D], cov [D, D] -> [V]
    return latent_variance(G, cov).sqrt().numpy()


def information(decoder, z, views, settings):
    """J^T W J [D, D] of `views` at code z."""
    res = residuals(decoder, z.float(), views, settings.observation, settings.mode == "depth")
    return information_matrix(res, row_weights(res, settings))


def ratios(before, after, seen0, seen6):  # vertex std [V] after view 0 and after views 0 and 6
    shrink = before / np.maximum(after, 1e-15)
    return {
        "hidden_over_visible": median_ratio(before, ~seen0, seen0),
        "shrink": median_ratio(shrink, seen6, ~seen6),
        "new_over_neither": median_ratio(shrink, seen6 & ~seen0, ~seen6 & ~seen0),
    }


def fitted_std(G, cov, mesh, views, fit):
    """Vertex std [V] as the mesh is drawn with a stored fit's seen model."""
    var = torch.as_tensor(vertex_std(G, cov)).square()
    seen = torch.as_tensor(seen_by_views(mesh, np.asarray(mesh.vertices), views, fit["tolerance"]))
    return seen_floor_variance(var, seen, fit["sdf_temperature"], fit["floor_seen"], fit["floor_unseen"]).sqrt().numpy()


def added_view(views_npz, added: str) -> int:
    """The view added to view 0: an index, or "farthest" (the camera at the largest angle from view 0's, seen
    from the shape's centre)."""
    if added != "farthest":
        return int(added)
    centres = np.stack([camera_centre(v.world_to_cam) for v in world_views(views_npz, with_depth=False)])
    unit = centres / np.linalg.norm(centres, axis=1, keepdims=True)
    return int(1 + np.argmin(unit[1:] @ unit[0]))


def shape_row(predictor, fusion, world, shape_id, mode, size, fit=None, added="6"):
    decoder = predictor.decoder
    images, _, _ = predictor.load_images(view_files(world.root, shape_id))
    mu, var = predictor.encode(images)
    settings = RefineSettings(mode=mode, observation=ObservationSettings(size=size))
    a = added_view(world.views_path(shape_id), added)
    one, two = fusion(mu[[0]], var[[0]]), fusion(mu[[0, a]], var[[0, a]])
    v0, v6 = (world_views(world.views_path(shape_id), [i]) for i in (0, a))
    z = refine(decoder, two.mu, two.var, v0 + v6, settings).mu
    with frozen(decoder):
        mesh, _ = extract_mesh(code_sdf_fn(decoder, z), 64)
    _, G = latent_jacobian(decoder, z, torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32))
    G = G.double()
    info0, info6 = information(decoder, z, v0, settings), information(decoder, z, v6, settings)
    P1, P2 = prior_precision(one.var), prior_precision(two.var)
    seen0 = visible_vertices(mesh, camera_centre(v0[0].world_to_cam))
    seen6 = visible_vertices(mesh, camera_centre(v6[0].world_to_cam))
    root = torch.linalg.cholesky(torch.linalg.inv(P1))
    pinned = torch.linalg.eigvalsh(root.T @ info0 @ root)
    energy = torch.linalg.svdvals(G @ root).square()
    row = {
        "shape": shape_id,
        "mode": mode,
        "added": a,
        "seen6_also_seen0": float((seen0 & seen6).sum() / max(seen6.sum(), 1)),
        "newly_seen": float((seen6 & ~seen0).mean()),
        "pinned_directions": int((pinned > 1).sum()),
        "leading_share": [float(x) for x in (energy.cumsum(0) / energy.sum())[[k - 1 for k in LEADING]]],
        "scales": {},
    }
    for c in SCALES:
        before = vertex_std(G, torch.linalg.inv(P1 + c * info0))
        after = vertex_std(G, torch.linalg.inv(P2 + c * (info0 + info6)))
        row["scales"][str(c)] = ratios(before, after, seen0, seen6)
    if fit and fit.get("seen"):
        s = fit["information_scale"]
        before = fitted_std(G, torch.linalg.inv(P1 + s * info0), mesh, v0, fit["seen"])
        after = fitted_std(G, torch.linalg.inv(P2 + s * (info0 + info6)), mesh, v0 + v6, fit["seen"])
        row["fitted"] = ratios(before, after, seen0, seen6)
    return row


def summarise(path):
    rows = [json.loads(line) for line in open(path)]
    for mode in ("masks", "depth"):
        sel = [r for r in rows if r["mode"] == mode]
        if not sel:
            continue
        med = lambda key: np.median([r[key] for r in sel], axis=0)  # noqa: E731
        print(
            f"{mode} ({len(sel)} shapes): seen by view 6 and by view 0 {med('seen6_also_seen0'):.2f}, newly seen "
            f"{med('newly_seen'):.2f}, directions one view pins {med('pinned_directions'):.0f}, vertex SDF variance "
            f"in the leading {LEADING} directions {np.round(med('leading_share'), 2).tolist()}"
        )
        for c in SCALES:
            print(f"  c = {c:g}: " + medians([r["scales"][str(c)] for r in sel]))
        fitted = [r["fitted"] for r in sel if "fitted" in r]
        if fitted:
            print(f"  stored fit, seen model ({len(fitted)} shapes): " + medians(fitted))


def medians(records):
    keys = ("hidden_over_visible", "shrink", "new_over_neither")
    values = {k: np.median([r[k] for r in records if r[k] is not None]) for k in keys}
    return ", ".join(f"{k} {v:.2f}" for k, v in values.items())


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--test", type=int, default=6, help="first N test shapes")
    parser.add_argument("--size", type=int, default=32, help="rays per image side")
    parser.add_argument("--calibration", help="a refinement_calibration.json: the ratios also with its seen model")
    parser.add_argument(
        "--added",
        default="6",
        help='the view added to view 0: an index, or "farthest" (the camera farthest from view 0)',
    )
    parser.add_argument("--summary", action="store_true", help="print the medians of OUT.jsonl and stop")
    args = parser.parse_args()
    if args.summary:
        return summarise(args.out)
    done = set()
    if os.path.exists(args.out):
        done = {(r["shape"], r["mode"]) for r in map(json.loads, open(args.out))}
    stored = json.load(open(args.calibration)) if args.calibration else {}
    torch.set_num_threads(1)
    predictor = load_predictor(args.run, temperature=True)
    fusion = default_fusion(predictor)
    world = WorldIndex.load(predictor.world)
    for shape_id in world.shape_ids("test")[: args.test]:
        for mode in ("masks", "depth"):
            if (shape_id, mode) in done:
                continue
            row = shape_row(predictor, fusion, world, shape_id, mode, args.size, stored.get(mode), args.added)
            with open(args.out, "a") as f:
                f.write(json.dumps(row) + "\n")
            print(shape_id, mode, {c: v["shrink"] for c, v in row["scales"].items()}, flush=True)


if __name__ == "__main__":
    main()
