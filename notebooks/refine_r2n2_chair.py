"""Refining on real renders: the shared 3D-R2N2 chair, fused vs refined on its renders' masks (docs/refinement.md).

    PYTHONPATH=. python notebooks/refine_r2n2_chair.py RUN [--out outputs/r2n2_refine] [--figure PNG]

Builds the ShapeNet world of the one shared chair that has R2N2 renders (its ShapeNetCore.v2 mesh, R2N2's
24 PNGs and cameras; masks from alpha), checks that our renderer's silhouette of the mesh through those
cameras matches the alpha masks, encodes the 24 renders with RUN's encoder, fuses views [0], [0, 8, 16]
and all 24 with the run's calibrated fusion (Bayes where not fitted), refines each fused code on the
same views' masks, and scores fused and refined against the mesh by the Pix3D protocol (64^3 meshes),
beside the ceiling: the chair's own code under the frozen decoder (latent-optimised on the world's SDF
samples, cached in OUT). Records each case's energies (prior and mask terms) at the fused, refined and own
codes. Writes OUT/results.json, the 3-view meshes, and the figure.

The frame: the run's decoder was trained on the synthetic chairs, which face +z; ShapeNet v2 chairs face
-z. The world's mesh and cameras are turned 180 degrees about y into the decoder's frame
(`DECODER_FROM_WORLD`) before any comparison; the script also scores the fused code against the
unturned mesh, to show which frame the codes live in.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402

from ushape.checkpoints import load_checkpoint  # noqa: E402
from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real import shapenet_rendering  # noqa: E402
from ushape.data.real.mesh_sdf import MeshSdf  # noqa: E402
from ushape.data.real.shapenet_world import ShapeNetWorld  # noqa: E402
from ushape.data.rendering import RayCaster, render_mesh, render_views  # noqa: E402
from ushape.decoder.latent_optim import optimise_codes  # noqa: E402
from ushape.decoder.query import code_sdf_fn  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.errors import MissingInputError  # noqa: E402
from ushape.metrics.pix3d import (  # noqa: E402
    ShapeReference,
    box_frame,
    pix3d_metrics,
    reference_from_mesh,
    sample_surface,
    voxel_iou,
    voxelise,
)
from ushape.propagation.field import code_mesh  # noqa: E402
from ushape.propagation.linearised import latent_jacobian, latent_variance  # noqa: E402
from ushape.reconstruction.calibrated_fusion import default_fusion  # noqa: E402
from ushape.reconstruction.export import coloured_mesh  # noqa: E402
from ushape.reconstruction.predictor import load_predictor, trained_decoder  # noqa: E402
from ushape.refinement import ObservationSettings, RefineSettings, refine, residuals, world_views  # noqa: E402
from ushape.refinement.posterior import energy, prior_precision, row_weights  # noqa: E402

CHAIR = "1a6f615e8b1b5ae4dbbc9440457e303e"  # the one shared chair with R2N2 renders
CASES = {"1": [0], "3": [0, 8, 16], "24": list(range(24))}
HELD_OUT_VIEW = 4  # shown in the figure, used by neither the 1- nor the 3-view case
# p_decoder = R p_world: the synthetic chairs the decoder learnt face +z, ShapeNet v2's face -z.
DECODER_FROM_WORLD = np.diag([-1.0, 1.0, -1.0])
MESH_RESOLUTION = 64


def build_world(out: Path, sample: Path) -> WorldIndex:
    """The ShapeNet world of the shared chair with R2N2's renders (the two chairs without renders would be
    skipped, and a hash split of three models would leave that chair out of train)."""
    split = out / "split.json"
    split.parent.mkdir(parents=True, exist_ok=True)
    split.write_text(json.dumps([CHAIR]))
    world = ShapeNetWorld(
        "chairs",
        str(sample / "ShapeNetCore.v2"),
        str(out / "data"),
        split_file=str(split),
        renderings_root=str(sample / "ShapeNetRendering"),
        samples_per_shape=20_000,  # only the mesh and views are used here
    )
    return world.build()


def mask_agreement(world: WorldIndex, mesh: trimesh.Trimesh, sample: Path) -> dict:
    """Silhouette IoU per view of R2N2's own PNGs (alpha >= 128) against our render of the mesh through the
    world's cameras, and of the world's stored masks against those PNGs."""
    with np.load(world.views_path(CHAIR)) as data:
        K, w2c, stored = data["K"], data["world_to_cam"], data["masks"]
    paths = shapenet_rendering.image_paths(sample / "ShapeNetRendering", "03001627", CHAIR, len(K))
    alpha = shapenet_rendering.alpha_mask(np.stack([shapenet_rendering.load_rgba(p, 137) for p in paths]))
    ours = render_views(mesh, K, w2c, 137)["mask"]

    def iou(a, b):
        return [float((x & y).sum() / max((x | y).sum(), 1)) for x, y in zip(a, b)]

    per_view = iou(alpha, ours)
    return {
        "views": int(len(K)),
        "iou_per_view": [round(v, 4) for v in per_view],
        "iou_view0": round(per_view[0], 4),
        "iou_mean": round(float(np.mean(per_view)), 4),
        "iou_min": round(float(np.min(per_view)), 4),
        "stored_masks_vs_png": round(float(np.mean(iou(alpha, stored))), 4),
        "foreground_pixels_view0": int(alpha[0].sum()),
    }


def turned(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices @ DECODER_FROM_WORLD.T, mesh.faces, process=False)


def decoder_views(world: WorldIndex, indices: list[int]):
    """The world's views (masks only: R2N2 has no depth) with cameras in the decoder's frame."""
    R = np.eye(4)
    R[:3, :3] = DECODER_FROM_WORLD.T  # p_world = R^T p_decoder
    return [replace(v, world_to_cam=v.world_to_cam @ R) for v in world_views(world.views_path(CHAIR), indices, False)]


def references(mesh: trimesh.Trimesh) -> dict[str, ShapeReference]:
    """The Pix3D reference of the mesh: voxels inside by ray parity (the protocol's, meant for watertight
    meshes) and by reachability from outside (ushape's sign for real CAD meshes); the same surface points."""
    frame = box_frame(mesh.vertices)
    points = frame.to_unit(sample_surface(mesh, 1024, 0))
    parity = reference_from_mesh(mesh)
    reachable = voxelise(MeshSdf(mesh).inside, frame, parity.occupancy.shape[0])
    return {"parity": parity, "reachable": ShapeReference(reachable, points)}


def mesh_of(decoder, code):
    mesh, _ = code_mesh(decoder, code, MESH_RESOLUTION, "coarse_to_fine")
    return mesh, code_sdf_fn(decoder, code)


def scores(decoder, code, refs: dict[str, ShapeReference]):
    mesh, sdf = mesh_of(decoder, code)

    def inside(p):
        return (sdf(torch.as_tensor(p, dtype=torch.float32)) < 0).numpy()

    out = {}
    for name, ref in refs.items():
        m = pix3d_metrics(mesh, inside, ref, emd=False)
        out[f"iou_{name}"], out["cd"] = round(float(m["iou"]), 4), round(float(m["cd"]), 5)
    return out, mesh


def vertex_std(decoder, code, var, vertices) -> np.ndarray:
    """Linearised SDF std [V] at mesh vertices from the code's variance [D] or covariance [D, D]."""
    _, jac = latent_jacobian(decoder, code, torch.as_tensor(np.asarray(vertices), dtype=torch.float32))
    return latent_variance(jac.double(), var.double()).clamp_min(0).sqrt().numpy()


def ceiling_code(decoder, world: WorldIndex) -> torch.Tensor:
    """The chair's own code under the frozen decoder: DeepSDF's latent optimisation on the world's SDF samples
    turned into the decoder's frame (the best this decoder can do on this chair, as the stage-1 codes are
    for the synthetic shapes)."""
    with np.load(world.sdf_path(CHAIR)) as data:
        rows = np.concatenate([data["pos"], data["neg"]])
    xyz = torch.as_tensor(rows[:, :3] @ DECODER_FROM_WORLD.T, dtype=torch.float32)
    return optimise_codes(decoder, [(xyz, torch.as_tensor(rows[:, 3], dtype=torch.float32))])[0]


def view_energy(decoder, z, mu, var, views, settings: RefineSettings) -> dict:
    """The refinement's energy at z (prior and mask terms) under the prior N(mu, var) and the views' masks."""
    res = residuals(decoder, z, views, settings.observation, use_depth=False, jacobian=False)
    w = row_weights(res, settings)
    dz = (z - mu).double()
    precision = prior_precision(var)
    return {
        "energy": round(energy(z, mu, precision, res, w), 2),
        "prior_term": round(float(0.5 * dz @ precision @ dz), 2),
        "mask_term": round(float(0.5 * (w * res.r.double().square()).sum()), 2),
    }


def figure(path: Path, world: WorldIndex, truth: trimesh.Trimesh, meshes: dict, rows: dict, std_max: float) -> None:
    """Inputs (views 0, 8, 16 and the held-out view) above the true, fused and refined meshes rendered through
    the same cameras, the R2N2 mask's outline drawn over each; fused and refined coloured by vertex std."""
    shown = CASES["3"] + [HELD_OUT_VIEW]
    with np.load(world.views_path(CHAIR)) as data:
        K, w2c, masks = data["K"][shown], data["world_to_cam"][shown], data["masks"][shown]
    R = np.eye(4)
    R[:3, :3] = DECODER_FROM_WORLD.T
    images = [plt.imread(world.image_path(CHAIR, v)) for v in shown]
    panels = [("R2N2 render", images)]
    truth_caster = RayCaster(truth)
    panels.append(("true mesh", [render_mesh(truth_caster, k, c, 137)["rgba"] for k, c in zip(K, w2c)]))
    for key, title in (("fused", "fused"), ("refined", "refined on 3 masks")):
        caster = RayCaster(meshes[key])
        renders = [render_mesh(caster, k, c @ R, 137)["rgba"] for k, c in zip(K, w2c)]
        r = rows[key]
        panels.append((f"{title}\nCD {r['cd']:.4f}, IoU {r['iou_reachable']:.2f}", renders))
    fig, axes = plt.subplots(len(panels), len(shown), figsize=(1.9 * len(shown) + 0.9, 1.95 * len(panels)))
    fig.subplots_adjust(left=0.1, right=0.86, top=0.93, bottom=0.02, wspace=0.05, hspace=0.12)
    for i, (title, renders) in enumerate(panels):
        for j, image in enumerate(renders):
            ax = axes[i, j]
            ax.imshow(image)
            if i > 0:
                ax.contour(masks[j], levels=[0.5], colors="deepskyblue", linewidths=0.6)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f"view {shown[j]}" + (" (held out)" if shown[j] == HELD_OUT_VIEW else ""), fontsize=8)
        axes[i, 0].set_ylabel(title, fontsize=8)
    sm = plt.cm.ScalarMappable(cmap="inferno", norm=plt.Normalize(0, std_max))
    top, bottom = axes[2, -1].get_position(), axes[-1, -1].get_position()
    cax = fig.add_axes([0.88, bottom.y0, 0.015, top.y1 - bottom.y0])
    fig.colorbar(sm, cax=cax, label="SDF std (linearised)")
    fig.suptitle("3D-R2N2 chair, 3 views fused, then refined on their masks (blue: R2N2 mask outline)", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("run")
    parser.add_argument("--sample", default="../shared/data/real_sample", help="the shared real_sample folder")
    parser.add_argument("--out", default="outputs/r2n2_refine")
    parser.add_argument("--figure", default="docs/figures/refine_r2n2_chair.png")
    parser.add_argument("--size", type=int, default=24, help="rays per image side")
    parser.add_argument("--cases", default="1,3,24")
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"run": args.run, "chair": CHAIR, "size": args.size}

    def save():
        (out / "results.json").write_text(json.dumps(results, indent=1))

    world = build_world(out, Path(args.sample))
    truth_world = trimesh.load(world.mesh_path(CHAIR), process=False)
    results["masks"] = mask_agreement(world, truth_world, Path(args.sample))
    print("masks", results["masks"], flush=True)
    truth = turned(truth_world)
    refs = references(truth)
    refs_unturned = references(truth_world)
    results["reference_parity_vs_reachable_iou"] = round(
        voxel_iou(refs["parity"].occupancy, refs["reachable"].occupancy), 4
    )

    try:  # the run's fitted temperature (and shared error) where `reconstruct.py --fit-temperature` made them
        predictor = load_predictor(args.run, temperature=True)
    except MissingInputError as err:
        print(f"no fitted temperature ({err}): raw variances, Bayesian fusion", flush=True)
        predictor = load_predictor(args.run)
    fusion = default_fusion(predictor)
    decoder = predictor.decoder
    results["decoder"] = str(
        trained_decoder(load_checkpoint(predictor.checkpoint), predictor.checkpoint, predictor.run_dir)
    )
    results["fusion"] = type(fusion).__name__
    results["temperature"] = predictor.temperature
    images, kept, _ = predictor.load_images(view_files(world.root, CHAIR))
    if len(kept) != 24:
        raise SystemExit(f"expected 24 renders of {CHAIR}, read {len(kept)}")
    mu, var = predictor.encode(images)
    start = time.perf_counter()
    cached = out / "ceiling_code.pt"
    if cached.is_file() and Path(torch.load(cached)["decoder"]).name == Path(results["decoder"]).name:
        own = torch.load(cached)["code"]
    else:
        own = ceiling_code(decoder, world)
        torch.save({"decoder": results["decoder"], "code": own}, cached)
    results["ceiling"], _ = scores(decoder, own, refs)
    results["ceiling"]["seconds"] = round(time.perf_counter() - start, 1)
    print("ceiling", results["ceiling"], flush=True)
    results["cases"] = {}
    meshes = {}
    for name in args.cases.split(","):
        chosen = CASES[name]
        fused = fusion(mu[chosen], var[chosen])
        views = decoder_views(world, chosen)
        row = {"views": chosen}
        row["fused"], fused_mesh = scores(decoder, fused.mu, refs)
        if name == "24":
            turned_not, _ = scores(decoder, fused.mu, refs_unturned)
            results["frame_check_fused24"] = {"decoder_frame": row["fused"], "world_frame_unturned": turned_not}
        start = time.perf_counter()
        settings = RefineSettings(mode="masks", observation=ObservationSettings(size=args.size))
        post = refine(decoder, fused.mu, fused.var, views, settings)
        seconds = time.perf_counter() - start
        row["refined"], refined_mesh = scores(decoder, post.mu, refs)
        row["refined"].update(seconds=round(seconds, 1), **post.record())
        row["energies"] = {
            key: view_energy(decoder, z, fused.mu, fused.var, views, settings)
            for key, z in (("fused", fused.mu), ("refined", post.mu), ("ceiling", own))
        }
        shift = (post.mu - fused.mu).double()
        row["code_shift_mahalanobis"] = round(float(shift @ prior_precision(fused.var) @ shift) ** 0.5, 3)
        results["cases"][name] = row
        print(name, row, flush=True)
        save()
        if name == "3":
            fused_std = vertex_std(decoder, fused.mu, fused.var, fused_mesh.vertices)
            refined_std = vertex_std(decoder, post.mu, post.cov, refined_mesh.vertices)
            std_max = float(np.percentile(fused_std, 99))
            meshes["fused"] = coloured_mesh(fused_mesh, fused_std, std_max)
            meshes["refined"] = coloured_mesh(refined_mesh, refined_std, std_max)
            for key, m in meshes.items():
                m.export(out / f"{key}_3views.ply")
            row["median_vertex_std"] = {"fused": float(np.median(fused_std)), "refined": float(np.median(refined_std))}
            figure(Path(args.figure), world, truth_world, meshes, row, std_max)
            save()


if __name__ == "__main__":
    main()
