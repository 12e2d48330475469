"""Measure the refinement on a trained run's held-out test shapes (the figures of docs/refinement.md).

    PYTHONPATH=. python notebooks/refinement_measure.py CKPT WORLD DECODER_DIR OUT.jsonl [SHAPES] [SIZE] [FIRST]

Per test shape, from its first 1 and 6 views fused by Bayes: IoU / Chamfer (Pix3D protocol, 64^3
mesh) of the fused code and of the code refined on the views' masks and on masks + depth; the
latent error against the shape's own code and its Mahalanobis^2 / D under the posterior; and,
from one view, the median full-covariance vertex std on hidden over visible vertices.
"""

import json
import sys
import time

import numpy as np
import torch
import trimesh

from ushape.data.layout import WorldIndex
from ushape.decoder.artifacts import load_codes
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.encoder.datamodule import view_files
from ushape.fusion import BayesianFusion
from ushape.mesh.extraction import extract_mesh
from ushape.metrics.pix3d import pix3d_metrics, reference_from_mesh
from ushape.propagation.linearised import latent_jacobian
from ushape.reconstruction.predictor import load_predictor
from ushape.reconstruction.visibility import hidden_over_visible
from ushape.refinement import ObservationSettings, RefineSettings, refine, world_views


def scores(decoder, code, reference, cov=None, world_to_cam=None):
    with frozen(decoder):
        sdf = code_sdf_fn(decoder, code)
        mesh, _ = extract_mesh(sdf, 64)
        out = pix3d_metrics(mesh, lambda p: (sdf(torch.as_tensor(p, dtype=torch.float32)) < 0).numpy(), reference, emd=False)
        if cov is not None:
            _, g = latent_jacobian(decoder, code, torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32))
            cov = torch.diag(cov) if cov.ndim == 1 else cov
            std = ((g @ cov) * g).sum(-1).clamp_min(0).sqrt().numpy()
            out.update(hidden_over_visible(mesh, std, world_to_cam), std_median=float(np.median(std)))
    return out


def main(ckpt, world_root, decoder_dir, out, shapes=4, size=32, first=0):
    torch.set_num_threads(1)
    world, codes, predictor = WorldIndex.load(world_root), load_codes(f"{decoder_dir}/codes_test.pt"), load_predictor(ckpt)
    decoder = predictor.decoder
    for shape_id in world.shape_ids("test")[int(first) : int(first) + int(shapes)]:
        images, _, _ = predictor.load_images(view_files(world.root, shape_id))
        mu, var = predictor.encode(images)
        truth = codes.lookup(shape_id)
        reference = reference_from_mesh(trimesh.load(world.mesh_path(shape_id), process=False))
        row = {"shape": shape_id, "own_code": scores(decoder, truth, reference)}
        for n in (1, 6):
            fused = BayesianFusion()(mu[:n], var[:n])
            views = world_views(world.views_path(shape_id), list(range(n)))
            w2c = views[0].world_to_cam if n == 1 else None
            cases = {"fused": (fused.mu, torch.diag(fused.var), None, 0.0)}
            for mode in ("masks", "depth"):
                start = time.perf_counter()
                settings = RefineSettings(mode=mode, observation=ObservationSettings(size=int(size)))
                post = refine(decoder, fused.mu, fused.var, views, settings)
                cases[mode] = (post.mu, post.cov, post.record(), time.perf_counter() - start)
            for name, (code, cov, record, seconds) in cases.items():
                error = (truth - code).double()
                row[f"{n}view_{name}"] = {
                    **scores(decoder, code, reference, cov if n == 1 else None, w2c),
                    "sq_error": float(error @ error),
                    "trace": float(torch.diagonal(cov).sum()),
                    "mahalanobis2_per_dim": float(error @ torch.linalg.solve(cov.double(), error)) / error.numel(),
                    "refine": record,
                    "seconds": round(seconds, 1),
                }
        with open(out, "a") as f:
            f.write(json.dumps(row) + "\n")
        print(shape_id, {k: round(v["iou"], 3) for k, v in row.items() if isinstance(v, dict)}, flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
