"""How well can a next-view score rank the candidates by the latent drop their views bring? Measured and ideal.

    PYTHONPATH=. python notebooks/information_ceiling.py RUN OUT.jsonl [--shapes 8] [--decisions 3] \
        [--observe masks|depth] [--size 24]

Along the random strategy's refined sequence of each of the first `--shapes` test shapes (24 orbit candidates,
the run's calibrated prior, as Table A refines), at the belief after 1..`--decisions` views, every open candidate
gets its predicted rows' information A_c = J_c^T W J_c (`candidate_information`, no image of it) and two scores:
the `information` strategy's log det and the expected latent drop tr(Sigma - Sigma'_c). Per decision, one row:
- `measured_*`: Spearman of each score with the realised drop (Table A-why's: the belief refined on the
  candidate's real view, with the current posterior as the prior);
- `ideal_*`: the same Spearman where the scores' model holds exactly (`ideal_rank_correlation`: a true code
  drawn from the belief, each view's observation linear with Gaussian noise of weight W). No score can be
  expected to rank the realised drops better than this on these candidates;
- the mean expected drop and the current trace.
`--summary` prints the means over the rows of OUT.jsonl. Rows already in OUT.jsonl are skipped on a rerun.
"""

import argparse
import json
import os

import numpy as np
import torch

from ushape.data.layout import WorldIndex
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.encoder.latent_metrics import spearman_correlation
from ushape.evaluation.active_diagnostics import RealisedDrops, ideal_rank_correlation
from ushape.planning import ViewEncoder, active_reconstruction, build_strategy, candidate_views
from ushape.planning.information import candidate_information, information_gain, surface_variance_drop
from ushape.planning.observers import build_observer
from ushape.planning.sequence import start_view
from ushape.reconstruction.calibrated_fusion import refinement_prior
from ushape.reconstruction.predictor import load_predictor


def decision_row(predictor, candidates, steps, k, settings, drops) -> dict:
    """Measured and ideal Spearman of both scores for the decision made after steps[:k]."""
    belief = steps[k - 1]
    cov = belief.var.double() if belief.var.ndim == 2 else torch.diag(belief.var.double())
    taken = [s.view for s in steps[:k]]
    open_views = [c for c in range(len(candidates)) if c not in taken]
    A = torch.stack(
        [
            candidate_information(
                predictor.decoder,
                belief.mu,
                candidates.K[c],
                candidates.world_to_cam[c],
                tuple(candidates.image_hw[c]),
                settings,
            )
            for c in open_views
        ]
    )
    identity = torch.eye(cov.shape[0], dtype=torch.float64)  # tr(I (Sigma - Sigma')): the expected latent drop
    scores = {
        "logdet": torch.tensor([information_gain(cov, a) for a in A], dtype=torch.float64),
        "trace": torch.tensor([surface_variance_drop(cov, a, identity) for a in A], dtype=torch.float64),
    }
    realised = torch.as_tensor(drops(steps, k)[open_views], dtype=torch.float64)
    row = {"views": k, "open": len(open_views), "trace": float(torch.trace(cov))}
    row["expected_drop"] = float(scores["trace"].mean())
    for name, score in scores.items():
        row[f"measured_{name}"] = float(spearman_correlation(score, realised))
        row[f"ideal_{name}"] = ideal_rank_correlation(cov, A, score)
    return row


def summarise(path: str) -> None:
    rows = [json.loads(line) for line in open(path)]
    for key in ("measured_logdet", "ideal_logdet", "measured_trace", "ideal_trace", "expected_drop", "trace"):
        values = np.array([r[key] for r in rows], dtype=float)
        values = values[np.isfinite(values)]
        print(f"{key:16s} mean {values.mean():.3f} +- {values.std(ddof=1) / len(values) ** 0.5:.3f} (n={len(values)})")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--shapes", type=int, default=8)
    parser.add_argument("--decisions", type=int, default=3)
    parser.add_argument("--observe", default="masks", choices=("masks", "depth"))
    parser.add_argument("--size", type=int, default=24, help="rays per image side (Table A's active_refine_size)")
    parser.add_argument("--summary", action="store_true", help="print the means of OUT.jsonl and stop")
    args = parser.parse_args()
    if args.summary:
        return summarise(args.out)
    done = {(r["shape"], r["views"]) for r in map(json.loads, open(args.out))} if os.path.exists(args.out) else set()
    torch.set_num_threads(1)
    predictor = load_predictor(args.run)
    world = WorldIndex.load(predictor.world)
    codes = load_codes(os.path.join(predictor.model.hparams.decoder_path, codes_file("test")))
    observer = build_observer(args.observe, size=args.size, iterations=15)
    settings = build_strategy("information", 0, None, size=args.size).settings(args.observe)
    for shape in world.shape_ids("test")[: args.shapes]:
        if all((shape, k) in done for k in range(1, args.decisions + 1)):
            continue
        candidates = candidate_views(world, shape, "auto", 12, 2)
        encode = ViewEncoder(predictor, candidates, 1.0, 0)
        steps = active_reconstruction(
            candidates,
            encode,
            build_strategy("random", 0),
            predictor.decoder,
            args.decisions + 1,
            start_view(0, shape, len(candidates)),
            fusion=refinement_prior(predictor),
            resolution=40,
            observe=observer,
        )
        drops = RealisedDrops(encode, codes.lookup(shape), predictor.decoder, observer)
        for k in range(1, args.decisions + 1):
            if (shape, k) in done:
                continue
            row = {"shape": shape, **decision_row(predictor, candidates, steps, k, settings, drops)}
            print(json.dumps(row), flush=True)
            with open(args.out, "a") as f:
                f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
