"""Measure the refinement on a trained run (the figures of docs/refinement.md).

    PYTHONPATH=. python notebooks/refinement_measure.py RUN OUT.jsonl [--val N] [--test N] [--size S]

RUN is an encoder run folder (its checkpoints/best.ckpt, the world and stage-1 decoder it names). The prior
is the views' fused Gaussian: the shared-error rule where `reconstruct.py --fit-temperature` has fitted
it, else Bayes. Per shape and views fused (1, 3, 10; views spread around the orbit) and mode (masks,
depth): IoU / Chamfer (Pix3D protocol, 64^3 mesh) of the fused and refined codes and of the shape's own
code (the ceiling); the latent error, its |error| and the posterior's marginal std per dimension (for the
calibration error), and J^T W J. From 1 view: median vertex std hidden / visible. From views {0} to
{0, 6}: how much more the std shrinks on the vertices the added view sees than elsewhere (and on those only it
sees than on those neither sees). The
information scale s is fitted on the first N val shapes and applied to the test shapes' covariances.
"""

import argparse
import json
import os
import time
from dataclasses import replace

import numpy as np
import torch
import trimesh

from ushape.checkpoints import load_checkpoint
from ushape.data.augment import load_rgba
from ushape.data.cameras import camera_centre, project
from ushape.data.layout import WorldIndex
from ushape.data.sdf_dataset import sdf_points
from ushape.decoder.artifacts import load_codes
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.encoder.datamodule import view_files
from ushape.fusion import BayesianFusion
from ushape.mesh.visibility import median_ratio
from ushape.metrics.calibration import calibration_curve, calibration_error
from ushape.metrics.pix3d import pix3d_metrics, reference_from_mesh
from ushape.propagation import SDF_CLAMP
from ushape.propagation.field import code_mesh
from ushape.propagation.linearised import latent_jacobian, latent_variance
from ushape.recalibration.refine_information import (
    fit_information_scale,
    fit_sdf_recalibration,
    scaled_posterior_std,
    seen_floor_variance,
)
from ushape.reconstruction.calibrated_fusion import default_fusion
from ushape.reconstruction.predictor import load_predictor, trained_decoder
from ushape.reconstruction.visibility import hidden_over_visible, seen_by_views, visible_vertices
from ushape.refinement import ObservationSettings, RefineSettings, crop_view, refine, world_views
from ushape.refinement.observation import residuals
from ushape.refinement.posterior import prior_precision, row_weights

VIEWS = {1: [0], 3: [0, 4, 8], 6: [0, 2, 4, 6, 8, 10], 10: list(range(10))}  # views spread around the orbit


def mesh_of(decoder, code):
    mesh, _ = code_mesh(decoder, code, 64, "coarse_to_fine")
    return mesh, code_sdf_fn(decoder, code)


def scores(decoder, code, reference):
    mesh, sdf = mesh_of(decoder, code)
    inside = lambda p: (sdf(torch.as_tensor(p, dtype=torch.float32)) < 0).numpy()  # noqa: E731
    out = pix3d_metrics(mesh, inside, reference, emd=False)
    return {"iou": out["iou"], "cd": out["cd"]}, mesh


def vertex_std(decoder, code, cov, vertices):
    _, g = latent_jacobian(decoder, code, torch.as_tensor(np.asarray(vertices), dtype=torch.float32))
    return latent_variance(g.double(), cov.double()).sqrt().numpy()


def calibrated_std(decoder, post, prior_var, vertices, mesh, views, fit):
    """Vertex std of the refined posterior as reconstruct.py draws it with a stored fit's "seen" model: the
    covariance at the fit's information scale, T var + floor^2 with the floor where `views` saw the vertex."""
    cov = torch.linalg.inv(prior_precision(prior_var) + fit["information_scale"] * post.information.double())
    var = torch.as_tensor(vertex_std(decoder, post.mu, cov, vertices)).square()
    seen = torch.as_tensor(seen_by_views(mesh, vertices, views, fit["seen"]["tolerance"]))
    model = fit["seen"]
    return (
        seen_floor_variance(var, seen, model["sdf_temperature"], model["floor_seen"], model["floor_unseen"])
        .sqrt()
        .numpy()
    )


def shape_rows(args, predictor, fusion, world, codes, shape_id, with_vertices):
    decoder = predictor.decoder
    images, _, _ = predictor.load_images(view_files(world.root, shape_id))
    mu, var = predictor.encode(images)
    truth = codes.lookup(shape_id)
    reference = reference_from_mesh(trimesh.load(world.mesh_path(shape_id), process=False))
    rows = []
    points, sdf_true = sdf_points(world, shape_id, 256)
    own, _ = scores(decoder, truth, reference)
    for n, chosen in VIEWS.items():
        if n not in args.views or (shape_id, n) in args.done:
            continue
        fused = fusion(mu[chosen], var[chosen])
        views = world_views(world.views_path(shape_id), chosen)
        row = {"shape": shape_id, "views": n, "own": own, "fused": scores(decoder, fused.mu, reference)[0]}
        row["fused"]["abs_error"] = (fused.mu - truth).abs().tolist()
        row["fused"]["std"] = fused.var.sqrt().tolist()
        bayes = BayesianFusion()(mu[chosen], var[chosen])  # the paper's rule, beside the calibrated prior
        row["bayes"] = {"abs_error": (bayes.mu - truth).abs().tolist(), "std": bayes.var.sqrt().tolist()}
        for mode in ("masks", "depth"):
            start = time.perf_counter()
            settings = RefineSettings(
                mode=mode, tolerance=args.tolerance, observation=ObservationSettings(size=args.size, grid=args.grid)
            )
            post = refine(decoder, fused.mu, fused.var, views, settings)
            seconds = time.perf_counter() - start
            s, mesh = scores(decoder, post.mu, reference)
            s.update(seconds=round(seconds, 1), fallback=post.fallback, iterations=post.iterations)
            s["abs_error"] = (post.mu - truth).abs().tolist()
            s["information"] = post.information.tolist() if post.information is not None else None
            s["prior_precision"] = prior_precision(fused.var).tolist()
            s["sdf"] = sdf_rows(decoder, post.mu, points, sdf_true)
            s["sdf"]["seen"] = seen_by_views(mesh, points.numpy(), views).tolist()
            precision = prior_precision(fused.var)
            s["energy_map"] = energy_parts(decoder, post.mu, fused.mu, precision, views, settings)
            s["energy_own_code"] = energy_parts(decoder, truth, fused.mu, precision, views, settings)
            if with_vertices and n == 1:
                std = vertex_std(decoder, post.mu, post.cov, mesh.vertices)
                s.update(hidden_over_visible(mesh, std, views[0].world_to_cam))
                fit = args.stored.get(mode)
                fit = fit if fit and fit.get("seen") else None  # the same ratios with its seen / unseen floors
                (s["shrink_seen_over_unseen"], s["shrink_new_over_neither"]), fitted_shrink = shrink_ratio(
                    args, decoder, fusion, mu, var, world, shape_id, mode, fit
                )
                s["cut_over_full"], fitted_cut = cut_away_std(
                    args, predictor, fusion, world, shape_id, mode, post, truth, fit=fit, full_var=fused.var
                )
                if fit:
                    std = calibrated_std(decoder, post, fused.var, mesh.vertices, mesh, views, fit)
                    s["fitted"] = {
                        "std_hidden_over_visible": hidden_over_visible(mesh, std, views[0].world_to_cam)[
                            "std_hidden_over_visible"
                        ],
                        "shrink_seen_over_unseen": fitted_shrink[0],
                        "shrink_new_over_neither": fitted_shrink[1],
                        "cut_over_full": fitted_cut,
                    }
            row[mode] = s
        rows.append(row)
    return rows


def energy_parts(decoder, z, prior_mu, precision, views, settings):
    """(prior, data) halves of the refinement's energy at code z: is the MAP below the own code's energy?"""
    with frozen(decoder):
        res = residuals(decoder, z.float(), views, settings.observation, settings.mode == "depth", jacobian=False)
    dz = (z - prior_mu).double()
    data = 0.5 * (row_weights(res, settings) * res.r.double().square()).sum()
    return round(float(0.5 * dz @ precision.double() @ dz), 2), round(float(data), 2)


def sdf_rows(decoder, code, points, sdf_true):
    """|SDF error| [P] at ground-truth samples (clamped as evaluation clamps) and dSDF/dz [P, D] at the code,
    so the summary can propagate any posterior covariance: std = sqrt(diag(G cov G^T)). As the evaluation's
    linearised propagation, a point whose mean is beyond the clamp has no variance (its rows of G are 0)."""
    sdf, g = latent_jacobian(decoder, code, points)
    g = torch.where(sdf.abs()[:, None] < SDF_CLAMP, g, torch.zeros_like(g))
    error = (sdf.clamp(-SDF_CLAMP, SDF_CLAMP) - sdf_true.clamp(-SDF_CLAMP, SDF_CLAMP)).abs()
    return {"abs_error": error.tolist(), "jacobian": g.tolist()}


def shrink_ratio(args, decoder, fusion, mu, var, world, shape_id, mode, fit=None):
    """Median std shrink, views {0} -> {0, 6} (mesh of the 2-view MAP): (on the vertices view 6 sees over the
    others, on those view 6 sees and view 0 did not over those neither sees), from the posteriors' own std and,
    with `fit` (a stored refinement calibration), from the std with its seen / unseen floors (else None)."""
    settings = RefineSettings(
        mode=mode, tolerance=args.tolerance, observation=ObservationSettings(size=args.size, grid=args.grid)
    )
    posts, priors, seen_by = [], [], []
    for chosen in ([0], [0, 6]):
        fused = fusion(mu[chosen], var[chosen])
        seen_by.append(world_views(world.views_path(shape_id), chosen))
        posts.append(refine(decoder, fused.mu, fused.var, seen_by[-1], settings))
        priors.append(fused.var)
    mesh, _ = mesh_of(decoder, posts[1].mu)
    seen6, seen0 = (visible_vertices(mesh, camera_centre(views[-1].world_to_cam)) for views in (seen_by[1], seen_by[0]))

    def ratios(before, after):
        shrink = before / np.maximum(after, 1e-12)
        return median_ratio(shrink, seen6, ~seen6), median_ratio(shrink, seen6 & ~seen0, ~seen6 & ~seen0)

    own = ratios(*(vertex_std(decoder, posts[1].mu, p.cov, mesh.vertices) for p in posts))
    if fit is None:
        return own, None
    fitted = ratios(  # both posteriors' covariances at the 2-view MAP, as without the fit
        *(
            calibrated_std(decoder, replace(p, mu=posts[1].mu), v, mesh.vertices, mesh, views, fit)
            for p, v, views in zip(posts, priors, seen_by)
        )
    )
    return own, fitted


def calibration(rows, key, scale=None):
    """Latent calibration error of |error| against the marginal std, over rows (refined: at information scale)."""
    errors = torch.tensor([e for r in rows for e in r[key]["abs_error"]], dtype=torch.float64)
    if key in ("fused", "bayes"):
        std = torch.tensor([s for r in rows for s in r[key]["std"]], dtype=torch.float64)
    else:
        std = torch.cat(
            [
                scaled_posterior_std(
                    torch.tensor(r[key]["prior_precision"]), torch.tensor(r[key]["information"]), scale
                )
                for r in rows
            ]
        )
    return calibration_error(*calibration_curve(errors, std, 20))


def sdf_pool(rows, key, scale):
    """(|SDF error| [P], std [P]) of the refined posteriors over rows (linearised, full covariance at information
    scale s)."""
    errors, stds = [], []
    for r in rows:
        cov = torch.linalg.inv(
            torch.tensor(r[key]["prior_precision"], dtype=torch.float64)
            + scale * torch.tensor(r[key]["information"], dtype=torch.float64)
        )
        g = torch.tensor(r[key]["sdf"]["jacobian"], dtype=torch.float64)
        stds.append(latent_variance(g, cov).sqrt())
        errors.append(torch.tensor(r[key]["sdf"]["abs_error"], dtype=torch.float64))
    return torch.cat(errors), torch.cat(stds)


def sdf_calibration(rows, key, scale, floor=0.0, temperature=1.0):
    """SDF calibration error of the refined posteriors at information scale s, their variance T var + floor^2
    (floor: e.g. the decoder's own misfit, a std)."""
    errors, std = sdf_pool(rows, key, scale)
    return calibration_error(*calibration_curve(errors, (temperature * std.square() + floor**2).sqrt(), 20))


def sdf_seen_calibration(rows, key, fit):
    """SDF calibration error (all, seen, unseen samples) of the refined posteriors with a stored fit's seen model."""
    errors, std = sdf_pool(rows, key, fit["information_scale"])
    seen = torch.tensor([x for r in rows for x in r[key]["sdf"]["seen"]], dtype=torch.bool)
    m = fit["seen"]
    total = seen_floor_variance(std.square(), seen, m["sdf_temperature"], m["floor_seen"], m["floor_unseen"]).sqrt()
    return tuple(
        round(calibration_error(*calibration_curve(errors[k], total[k], 20)), 3) if k.any() else None
        for k in (torch.ones_like(seen), seen, ~seen)
    )


def fit_sdf(val, mode, scale, misfit):
    """(T_sdf, floor) of the refined SDF variance at information scale s, fitted on the val rows at 1, 3, 10 views."""
    groups = [sdf_pool(sel, mode, scale) for n in VIEWS if (sel := [r for r in val if r["views"] == n])]
    temperature, floor, _, before, after = fit_sdf_recalibration(groups, misfit)
    print(
        f"{mode}: SDF variance at s = {scale:.4g}: T_sdf {temperature:.3g}, floor {floor:.4g} (val worst CE "
        f"{max(before):.3f} -> {max(after):.3f})"
    )
    return temperature, floor


def median_error_ratio(rows, key):
    """Median |SDF error| of the refined code on the samples no view saw over that on the seen ones (None: no
    visibility recorded)."""
    if not all("seen" in r[key]["sdf"] for r in rows):
        return None
    e = np.array([x for r in rows for x in r[key]["sdf"]["abs_error"]])
    seen = np.array([x for r in rows for x in r[key]["sdf"]["seen"]], dtype=bool)
    return float(np.median(e[~seen]) / np.median(e[seen])) if seen.any() and (~seen).any() else None


def below(record):
    """Whether the MAP's energy is below the shape's own code's: the optimiser is then not what limits it."""
    return sum(record["energy_map"]) < sum(record["energy_own_code"])


def summarise(path, misfit=None, stored=None):
    """Tables of docs/refinement.md from the rows: IoU / ceiling, CD, std ratios, calibration at the fitted s;
    stored: a run's refinement_calibration.json (`reconstruct.py --fit-refinement`), whose s, T_sdf and floor
    are applied as reconstruct.py and `eval.py` apply them."""
    stored = json.load(open(stored)) if stored else {}
    rows = [json.loads(line) for line in open(path)]
    val, test = [r for r in rows if r["split"] == "val"], [r for r in rows if r["split"] == "test"]
    for mode in ("masks", "depth"):
        fit = [r for r in val if r[mode]["information"] is not None]
        if fit:
            scale, before, after = fit_information_scale(
                [torch.tensor(r[mode]["abs_error"]) for r in fit],
                [torch.tensor(r[mode]["prior_precision"]) for r in fit],
                [torch.tensor(r[mode]["information"]) for r in fit],
            )
            print(f"{mode}: information scale s = {scale:.4g} (val CE {before:.3f} at s = 1 -> {after:.3f})")
        else:  # measured with --val 0: nothing to fit s on
            scale = 1.0
            print(f"{mode}: no val rows, information scale s = 1")
        sdf_fit = {s: fit_sdf(fit, mode, s, misfit) for s in (1.0, scale)} if misfit else {}
        cli = stored.get(mode)
        if cli:
            s, t, f = cli["information_scale"], cli["sdf_temperature"], cli["sdf_floor"]
            print(f"{mode}: stored fit s = {s:.4g}, T_sdf {t:.3g}, floor {f:.4g}")
        for n in VIEWS:
            sel = [r for r in test if r["views"] == n]
            if not sel:
                continue
            paper = [r for r in sel if "bayes" in r]  # rows measured with the paper's rule beside the prior
            # A ratio of means: one shape's own code can be near-empty (a failed latent optimisation), and a
            # mean of per-shape ratios would then be dominated by that shape.
            ratio = lambda key: np.mean([r[key]["iou"] for r in sel]) / np.mean([r["own"]["iou"] for r in sel])  # noqa: E731
            line = {
                "views": n,
                "shapes": len(sel),
                "iou own": np.mean([r["own"]["iou"] for r in sel]),
                "iou fused": np.mean([r["fused"]["iou"] for r in sel]),
                f"iou {mode}": np.mean([r[mode]["iou"] for r in sel]),
                "iou/ceil fused": ratio("fused"),
                f"iou/ceil {mode}": ratio(mode),
                "cd fused": np.mean([r["fused"]["cd"] for r in sel]),
                f"cd {mode}": np.mean([r[mode]["cd"] for r in sel]),
                "cd falls on": f"{sum(r[mode]['cd'] < r['fused']['cd'] for r in sel)}/{len(sel)}",
                "CE prior": calibration(sel, "fused"),
                "CE bayes": calibration(paper, "bayes") if paper else None,
                "CE s=1": calibration(sel, mode, 1.0),
                "CE fitted s": calibration(sel, mode, scale),
                "SDF CE s=1": sdf_calibration(sel, mode, 1.0),
                "SDF CE fitted s": sdf_calibration(sel, mode, scale),
                "SDF CE s=1 + misfit floor": sdf_calibration(sel, mode, 1.0, misfit) if misfit else None,
                **{
                    f"SDF CE s={s:.3g}, val-fitted T_sdf, floor": sdf_calibration(sel, mode, s, f, t)
                    for s, (t, f) in sdf_fit.items()
                },
                "CE stored fit": calibration(sel, mode, cli["information_scale"]) if cli else None,
                "SDF CE stored fit": sdf_calibration(
                    sel, mode, cli["information_scale"], cli["sdf_floor"], cli["sdf_temperature"]
                )
                if cli
                else None,
                "SDF CE stored seen fit (all, seen, unseen)": sdf_seen_calibration(sel, mode, cli)
                if cli and cli.get("seen") and all("seen" in r[mode]["sdf"] for r in sel)
                else None,
                "|SDF error| median unseen / seen": median_error_ratio(sel, mode),
                "fallbacks": sum(r[mode]["fallback"] is not None for r in sel),
                "seconds": np.mean([r[mode]["seconds"] for r in sel]),
                "E(MAP) < E(own code)": f"{sum(below(r[mode]) for r in sel)}/{len(sel)}",
            }
            if n == 1:
                line["hidden/visible (median over shapes)"] = np.median(
                    [r[mode]["std_hidden_over_visible"] for r in sel]
                )
                line["shrink seen/unseen (median)"] = np.median([r[mode]["shrink_seen_over_unseen"] for r in sel])
                line["shrink newly seen/neither (median)"] = np.median(
                    [
                        r[mode]["shrink_new_over_neither"]
                        for r in sel
                        if r[mode].get("shrink_new_over_neither") is not None
                    ]
                )
                line["cut-away std crop/full (median)"] = np.median([r[mode]["cut_over_full"] for r in sel])
                fitted = [r[mode]["fitted"] for r in sel if "fitted" in r[mode]]
                names = (
                    "std_hidden_over_visible",
                    "shrink_seen_over_unseen",
                    "shrink_new_over_neither",
                    "cut_over_full",
                )
                for name in names if fitted else ():
                    line[f"{name}, seen floors (median)"] = np.median(
                        [f[name] for f in fitted if f.get(name) is not None]
                    )
            print({k: round(v, 3) if isinstance(v, float) else v for k, v in line.items()})


def cut_away_std(args, predictor, fusion, world, shape_id, mode, full, truth, keep=0.55, fit=None, full_var=None):
    """View 0 cropped to its top `keep` (a photo cut off at the seat): median std, on the own code's mesh
    vertices that fall in the cut-away part, of the refined posterior from the crop over that from the full view;
    from the posteriors' own std and, with `fit` (and the full view's prior variance `full_var`), from the std
    with the fit's seen / unseen floors (else None)."""
    decoder = predictor.decoder
    view = world_views(world.views_path(shape_id), [0])[0]
    h, w = view.image_hw
    box = (0, 0, int(round(keep * h)), w)
    rgba = load_rgba(view_files(world.root, shape_id)[0])
    mu, var = predictor.encode(predictor.prepare(rgba[:, : box[2]])[None])
    fused = fusion(mu, var)
    settings = RefineSettings(
        mode=mode, tolerance=args.tolerance, observation=ObservationSettings(size=args.size, grid=args.grid)
    )
    crop = crop_view(view, box, (box[2], w))
    cut = refine(decoder, fused.mu, fused.var, [crop], settings)
    mesh, _ = mesh_of(decoder, truth)
    uv, _ = project(np.asarray(mesh.vertices), view.K, view.world_to_cam)
    away = uv[:, 1] >= box[2]

    def ratio(stds):
        return float(np.median(stds[0][away]) / np.median(stds[1][away])) if away.any() else None

    own = ratio([vertex_std(decoder, p.mu, p.cov, mesh.vertices) for p in (cut, full)])
    if fit is None:
        return own, None
    fitted = ratio(  # seen decided on the own code's mesh, the one the ratio is read on
        [
            calibrated_std(decoder, p, v, mesh.vertices, mesh, [seen], fit)
            for p, v, seen in ((cut, fused.var, crop), (full, full_var, view))
        ]
    )
    return own, fitted


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--val", type=int, default=5)
    parser.add_argument("--test", type=int, default=6)
    parser.add_argument("--size", type=int, default=ObservationSettings.size, help="rays per image side (eval.py: 32)")
    parser.add_argument("--tolerance", type=float, default=RefineSettings.tolerance, help="LM stops below this gain")
    parser.add_argument("--grid", type=int, default=ObservationSettings.grid, help="SDF grid nodes (0: decoder)")
    parser.add_argument("--world", help="the world folder, where the run's summary does not name it yet")
    parser.add_argument(
        "--views", default="1,3,6,10", help="views fused, comma-separated counts of " + str(list(VIEWS))
    )
    parser.add_argument("--summary", action="store_true", help="print the tables from OUT.jsonl and stop")
    parser.add_argument(
        "--misfit",
        type=float,
        help="with --summary: the run's sdf_decoder_misfit (temperature.json): the SDF CE with it as a floor, and "
        "with the refined SDF variance's (T_sdf, floor <= misfit) fitted on the val rows",
    )
    parser.add_argument(
        "--calibration",
        help="a refinement_calibration.json: with --summary, applied to the test rows; when measuring, the locality "
        "ratios are also taken with its seen / unseen floors (rows' 'fitted')",
    )
    args = parser.parse_args()
    if args.summary:
        return summarise(args.out, args.misfit, args.calibration)
    args.views = [int(n) for n in args.views.split(",")]
    args.stored = json.load(open(args.calibration)) if args.calibration else {}
    unknown = sorted(set(args.views) - set(VIEWS))
    if unknown:
        parser.error(f"--views {unknown}: the measured view sets are {list(VIEWS)}")
    args.done = set()
    if os.path.exists(args.out):
        args.done = {(r["shape"], r["views"]) for r in map(json.loads, open(args.out)) if "views" in r}
    torch.set_num_threads(1)
    predictor = load_predictor(args.run, temperature=True)
    fusion = default_fusion(predictor)
    world = WorldIndex.load(args.world or predictor.world)
    decoder_dir = trained_decoder(load_checkpoint(predictor.checkpoint), predictor.checkpoint, predictor.run_dir)
    for split, count in (("val", args.val), ("test", args.test)):
        codes = load_codes(f"{decoder_dir}/codes_{split}.pt")
        for shape_id in world.shape_ids(split)[:count]:
            if all((shape_id, n) in args.done for n in args.views):
                continue
            for row in shape_rows(args, predictor, fusion, world, codes, shape_id, with_vertices=split == "test"):
                row.update(split=split, fusion=type(fusion).__name__)
                with open(args.out, "a") as f:
                    f.write(json.dumps(row) + "\n")
                print(
                    split,
                    shape_id,
                    row["views"],
                    {k: round(row[k]["iou"], 3) for k in ("own", "fused", "masks", "depth")},
                    flush=True,
                )


if __name__ == "__main__":
    main()
