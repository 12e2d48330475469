"""Calibration plot maths (supplement S2.2): how often errors fall inside the predicted p-interval.

Each prediction is a univariate Gaussian (one latent dimension, or one SDF value); the
interval for probability p is |error| <= Q(p) sigma with Q the two-sided standard normal
quantile, Pr(|X| <= Q(p)) = p, i.e. Q(p) = Phi^-1((1 + p) / 2), so Q(0.9973) = 3.
(The supplement's "Q(0.9984) ~ 3" is a slip; 3 sigma holds 99.73 %.)
"""

from __future__ import annotations

from typing import Mapping, Sequence

import torch
from torch import Tensor


def two_sided_quantile(p: Tensor) -> Tensor:
    """Q(p) = Phi^-1((1 + p)/2): the half-width in standard deviations holding probability p."""
    return torch.special.ndtri((1 + p) / 2)


def probability_levels(n_levels: int) -> Tensor:
    """T probabilities spread uniformly over (0, 1): the bin centres (t - 0.5)/T, t = 1..T."""
    if isinstance(n_levels, bool) or not isinstance(n_levels, int) or n_levels < 1:
        raise ValueError(f"n_levels must be a positive integer, got {n_levels!r}")
    return (torch.arange(n_levels, dtype=torch.float64) + 0.5) / n_levels


def calibration_curve(
    abs_error: Tensor,  # [N]
    sigma: Tensor,  # [N]
    n_levels: int = 100,
) -> tuple[Tensor, Tensor]:
    """Predicted probabilities p [T] and observed frequencies freq [T] of |error| <= Q(p_t) sigma.

    Inputs are flattened, so latent [N, D] or SDF [N, P] arrays can be passed as they are
    (every dimension / value counts as its own prediction, as in the paper).
    """
    abs_error = torch.as_tensor(abs_error, dtype=torch.float64).reshape(-1)
    sigma = torch.as_tensor(sigma, dtype=torch.float64).reshape(-1)
    if abs_error.shape != sigma.shape:
        raise ValueError(
            f"abs_error has {abs_error.numel()} values but sigma has {sigma.numel()}; pass one sigma per error"
        )
    if abs_error.numel() == 0:
        raise ValueError("no predictions: abs_error and sigma are empty")
    if not (torch.isfinite(abs_error).all() and torch.isfinite(sigma).all()):
        raise ValueError("abs_error or sigma holds NaN/inf values")
    if (abs_error < 0).any():
        raise ValueError("abs_error must be >= 0: pass |x - mu|, not the signed error")
    if (sigma < 0).any():
        raise ValueError("sigma must be >= 0 (a standard deviation, not a variance or log-variance)")
    p = probability_levels(n_levels)
    return p, interval_coverage(abs_error, sigma, p)


def interval_coverage(
    abs_error: Tensor,  # [N] float64, checked as calibration_curve checks it
    sigma: Tensor,  # [N] float64
    p: Tensor,  # [T] probability levels
) -> Tensor:
    """Fraction [T] of |error| <= Q(p_t) sigma, without calibration_curve's checks: for a fit that scores many
    variances of inputs it has checked once."""
    # Standardised error: the fraction inside Q(p) sigma is then one sorted search per level.
    # sigma = 0 is a point prediction: inside every interval if exact, outside all otherwise.
    ratio = torch.where(sigma > 0, abs_error / sigma.clamp(min=torch.finfo(torch.float64).tiny), torch.inf)
    ratio = torch.where((sigma == 0) & (abs_error == 0), 0.0, ratio)
    inside = torch.searchsorted(torch.sort(ratio).values, two_sided_quantile(p), right=True)
    return inside.double() / ratio.numel()


def calibration_error(p: Tensor, freq: Tensor) -> float:
    """Mean absolute gap |freq_t - p_t| over the levels: the area between the curve and Y=X
    (midpoint rule on uniform levels); 0 is perfect calibration, at most 0.5."""
    p, freq = torch.as_tensor(p, dtype=torch.float64), torch.as_tensor(freq, dtype=torch.float64)
    if p.shape != freq.shape or p.ndim != 1 or p.numel() == 0:
        raise ValueError(f"p {tuple(p.shape)} and freq {tuple(freq.shape)} must be the same non-empty 1-D curve")
    return float((freq - p).abs().mean())


def calibration_error_interval(
    abs_errors: Sequence[Tensor],  # per shape: |error| [N_s]
    sigmas: Sequence[Tensor],  # per shape: sigma [N_s]
    n_levels: int = 20,
    resamples: int = 200,
    level: float = 0.9,
    seed: int = 0,
) -> tuple[float, float]:
    """The central `level` interval of the calibration error over shapes drawn with replacement (a shape
    bootstrap): how far the pooled error could move on another draw of as many test shapes. A shape's
    predictions are correlated (one code error moves all its dimensions and SDF values), so the shape, not
    the prediction, is the unit resampled."""
    if not abs_errors or len(abs_errors) != len(sigmas):
        raise ValueError("pass one |error| and one sigma tensor per shape (at least one shape)")
    if not 0 < level < 1 or resamples < 1:
        raise ValueError(f"level must be in (0, 1) and resamples >= 1, got {level!r}, {resamples!r}")
    errors = [torch.as_tensor(e, dtype=torch.float64).reshape(-1) for e in abs_errors]
    stds = [torch.as_tensor(s, dtype=torch.float64).reshape(-1) for s in sigmas]
    generator = torch.Generator().manual_seed(seed)
    scores = []
    for _ in range(resamples):
        drawn = torch.randint(len(errors), (len(errors),), generator=generator).tolist()
        curve = calibration_curve(torch.cat([errors[i] for i in drawn]), torch.cat([stds[i] for i in drawn]), n_levels)
        scores.append(calibration_error(*curve))
    tail = (1 - level) / 2
    low, high = torch.quantile(
        torch.tensor(scores, dtype=torch.float64), torch.tensor([tail, 1 - tail], dtype=torch.float64)
    )
    return float(low), float(high)


def plot_calibration(curves: Mapping[str, tuple[Tensor, Tensor]], title: str = "Calibration"):
    """A matplotlib Figure: Y=X dashed, one line per method (legend shows its calibration error)."""
    from matplotlib.figure import Figure  # the pyplot-free Figure: no global state, no GUI backend

    if not curves:
        raise ValueError("no curves to plot: pass {method name: (p, freq)}")
    fig = Figure(figsize=(4.5, 4.5))
    ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1], linestyle="--", color="black", linewidth=1, label="ideal (Y = X)")
    for name, (p, freq) in curves.items():
        error = calibration_error(p, freq)
        ax.plot(torch.as_tensor(p).tolist(), torch.as_tensor(freq).tolist(), label=f"{name} (CE {error:.3f})")
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="predicted probability p", ylabel="observed frequency", title=title)
    ax.set_aspect("equal")
    ax.legend(loc="upper left", fontsize="small")
    fig.tight_layout()
    return fig
