"""Why a next-view strategy helps or not (Table A-why), measured on the sequences the active protocol runs.

Per sequence: the spread of the views taken (mean angle between every two of them, about the object).
Per decision of a strategy that scores the current mesh's uncertainty, or the expected information gain
(steps 2..N):
- score vs latent-error drop: the Spearman rank correlation, over the candidates still open, between the
  strategy's score and how much nearer the belief would come to the shape's own code with that view (the
  fused code; for a refined belief, the belief refined on that view's masks or depth as one more view).
  It peeks at every candidate's image, as the oracle does, to say whether the score knew what each view
  would bring; > 0: it did.
- std shrink seen / unseen: on the mesh the choice was made on, the SDF std after fusing the chosen view
  over the std before, median over the vertices that view sees divided by the median over those it does
  not. Below 1: seeing a part makes it surer than the rest (a local uncertainty); 1: every part shrinks alike.

How high can the first correlation be? `ideal_rank_correlation` measures it where the information scores'
own model holds exactly (linear observations, Gaussian code and noise): a single realised drop scatters about
its expectation, so even the expected drop itself does not rank the realised ones perfectly.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch

from ushape.encoder.latent_metrics import spearman_correlation
from ushape.evaluation.tables import Table, encoder_order
from ushape.fusion.rules import FusedCode, fuse_bayesian
from ushape.planning import CandidateViews, Step
from ushape.planning.strategies import code_distance, distances_with_each
from ushape.propagation.linearised import propagate_linearised


def view_spread(steps: Sequence[Step], candidates: CandidateViews) -> float:
    """Mean angle (degrees) between every two views taken (NaN for a single view)."""
    d = candidates.directions[[s.view for s in steps]]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    pairs = [(i, j) for i in range(len(d)) for j in range(i + 1, len(d))]
    if not pairs:
        return math.nan
    return float(np.degrees(np.mean([np.arccos(np.clip(d[i] @ d[j], -1.0, 1.0)) for i, j in pairs])))


class RealisedDrops:
    """Per open candidate of a decision, how much nearer to the shape's own code the belief would come with that
    view: the fused code of the views taken plus it (observer none), or the refined belief updated on its
    masks (and depth) with the current belief as the prior (a refining observer; one view refined, not all)."""

    def __init__(self, encode, true_code: torch.Tensor, decoder, observer) -> None:
        self.encode, self.true_code, self.decoder, self.observer = encode, true_code.float(), decoder, observer

    def __call__(self, steps: Sequence[Step], k: int) -> np.ndarray:  # [C], NaN where taken
        """Drops for the decision that chose steps[k], from the belief after steps[:k]."""
        before, n = steps[k - 1], len(steps[k].scores)
        taken = [s.view for s in steps[:k]]
        start = float((before.mu - self.true_code).norm())
        if not hasattr(self.observer, "updated_mean"):
            distances = distances_with_each(self.encode, fuse_bayesian, taken, n, code_distance(self.true_code))
        else:
            belief = FusedCode(before.mu, before.var, torch.arange(k))
            distances = np.full(n, np.inf)
            for c in (c for c in range(n) if c not in taken):
                mu = self.observer.updated_mean(self.decoder, belief, self.encode.observed(c))
                distances[c] = float((mu - self.true_code).norm())
        return np.where(np.isfinite(distances), start - distances, np.nan)


def linear_updates(
    cov: torch.Tensor,  # [D, D] the belief's covariance Sigma
    informations: torch.Tensor,  # [C, D, D] each candidate's J_c^T W J_c
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(Sigma^-1 [D, D], A_c^(1/2) [C, D, D], Sigma'_c = (Sigma^-1 + A_c)^-1 [C, D, D]): what `simulated_drops` needs of
    a decision, the same for every draw of the truth and the noise."""
    cov = 0.5 * (cov.double() + cov.double().T)
    A = 0.5 * (informations.double() + informations.double().transpose(1, 2))
    precision = torch.linalg.inv(cov)
    values, vectors = torch.linalg.eigh(A)
    return precision, vectors * values.clamp(min=0).sqrt()[:, None, :], torch.linalg.inv(precision + A)


def simulated_drops(
    cov: torch.Tensor,  # [D, D] the belief's covariance Sigma
    informations: torch.Tensor,  # [C, D, D] each candidate's J_c^T W J_c
    error: torch.Tensor,  # [D] the belief's error mu - z
    generator: torch.Generator,
    updates: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,  # linear_updates(cov, informations)
) -> torch.Tensor:  # [C]
    """|e|^2 - |e'_c|^2 per candidate, one draw of each candidate's observation noise, in the linear-Gaussian model
    the information scores assume: e'_c = Sigma'_c (Sigma^-1 e + eta_c), eta_c = J_c^T W n_c ~ N(0, A_c),
    Sigma'_c = (Sigma^-1 + A_c)^-1. With e ~ N(0, Sigma) its mean is tr(Sigma - Sigma'_c)."""
    precision, root, posterior = updates if updates is not None else linear_updates(cov, informations)
    noise = torch.randn(root.shape[:2], generator=generator, dtype=torch.float64)
    eta = (root @ noise[..., None])[..., 0]
    after = (posterior @ (precision @ error.double() + eta)[..., None])[..., 0]
    return error.double().pow(2).sum() - after.pow(2).sum(dim=1)


def ideal_rank_correlation(
    cov: torch.Tensor,  # [D, D]
    informations: torch.Tensor,  # [C, D, D]
    scores: torch.Tensor,  # [C] a strategy's scores of the candidates
    draws: int = 200,
    seed: int = 0,
) -> float:
    """Mean Spearman correlation of the scores with the drops `simulated_drops` gives for a true code drawn from
    the belief (e ~ N(0, Sigma)): the score-vs-latent-drop correlation the scores would reach if the belief and
    the linearised observations were exact."""
    generator = torch.Generator().manual_seed(seed)
    L = torch.linalg.cholesky(0.5 * (cov.double() + cov.double().T))
    updates = linear_updates(cov, informations)
    values = []
    for _ in range(draws):
        error = L @ torch.randn(L.shape[0], generator=generator, dtype=torch.float64)
        drops = simulated_drops(cov, informations, error, generator, updates)
        values.append(float(spearman_correlation(scores.double(), drops)))
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def decision_diagnostics(steps: Sequence[Step], drops: RealisedDrops, decoder, scored: bool = False) -> list[dict]:
    """One row per step chosen on a surface (or, `scored`, on any score): its score-vs-latent-drop correlation and,
    where a surface was computed, its std shrink ratio."""
    rows = []
    for k in range(1, len(steps)):
        step = steps[k]
        if step.scores is None or (step.surface is None and not scored):
            continue
        taken = [s.view for s in steps[:k]]
        open_views = [c for c in range(len(step.scores)) if c not in taken]
        realised = drops(steps, k)[open_views]
        correlation = (
            float(
                spearman_correlation(
                    torch.as_tensor(step.scores[open_views]), torch.tensor(realised, dtype=torch.float32)
                )
            )
            if len(open_views) > 1
            else math.nan
        )
        shrink = _shrink(step, decoder) if step.surface is not None else math.nan
        rows.append({"step": k + 1, "score_vs_latent_drop": correlation, "shrink_seen_over_unseen": shrink})
    return rows


def _shrink(step: Step, decoder) -> float:
    surface = step.surface
    vertices = torch.as_tensor(np.asarray(surface.mesh.vertices), dtype=torch.float32)
    _, after = propagate_linearised(decoder, step.mu.float(), step.var.float(), vertices)
    ratio = np.sqrt(after.double().numpy() / np.maximum(surface.variance, 1e-20))
    seen = surface.visible[step.view]
    if not seen.any() or seen.all():
        return math.nan
    return float(np.median(ratio[seen]) / np.median(ratio[~seen]))


def table_active_why(rows: Sequence[dict]) -> Table:
    """Table A-why: per strategy, the views' spread, and for the uncertainty strategies what their scores knew."""
    table = Table(
        "Table A-why: what the next-view choices were based on",
        "spread: mean angle between every two views taken. score vs latent drop: Spearman correlation, over the "
        "open candidates of each decision, of the strategy's score with how much nearer that view would bring "
        "the fused code to the shape's own (mean over decisions; > 0: the score knew which view helps). std "
        "shrink seen/unseen: median over decisions of the std shrink on the vertices the chosen view sees over "
        "the shrink on those it does not (< 1: the uncertainty is local; 1: every part shrinks alike).",
        ["Encoder", "min scale", "strategy", "sequences", "spread (deg)", "decisions", "score vs latent drop"]
        + ["std shrink seen/unseen"],
    )
    labels = dict(encoder_order([{"encoder": r["encoder"], "label": r["label"]} for r in rows]))
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["encoder"], row["min_scale"], row["method"]), []).append(row)
    for (encoder, scale, method), items in sorted(groups.items(), key=lambda item: (item[0][0], -item[0][1])):
        decisions = [d for item in items for d in item["decisions"]]
        correlations = [d["score_vs_latent_drop"] for d in decisions if math.isfinite(d["score_vs_latent_drop"])]
        shrinks = [d["shrink_seen_over_unseen"] for d in decisions if math.isfinite(d["shrink_seen_over_unseen"])]
        spreads = [item["spread"] for item in items if math.isfinite(item["spread"])]
        table.rows.append(
            [labels.get(encoder, encoder), scale, method, len(items), float(np.mean(spreads)) if spreads else None]
            + [len(decisions), float(np.mean(correlations)) if correlations else None]
            + [float(np.median(shrinks)) if shrinks else None]
        )
    return table
