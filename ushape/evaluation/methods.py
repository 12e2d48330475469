"""How a view's code becomes a shape, as a dimension of the evaluation's records.

Today's method is the encoder's own Gaussian per view, fused by each table's rule. Another method is a
`ReconstructionMethod`, with two steps, each the identity by default:
  - `encodings`: given an encoder's encodings at a crop, the per-view Gaussians the protocols fuse
    (a method that replaces each view's code, say);
  - `after_fusion`: given one Gaussian and the views it came from (one view, or an instance fused by a
    table's rule), the Gaussian the protocols reconstruct and score (a refinement on those views, say).
    A single view is an instance of one: its own Gaussian passes through this step on its own view.
Each encoder is then scored once plainly and once per method, the latter under the name
`<encoder>+<method>` and the label `<label> + <method label>`, so every table gains the method's rows
and no protocol changes. The active protocol plans with the encoder itself, and meshes and figures are
saved for the plain runs.

A step may return a full covariance [D, D] (a Laplace posterior); it then flows into the propagation
(docs/full_covariance.md). When it gives its input back unchanged because it could not do better (a
refinement that diverged), `Estimate.fallback` says why, and the records count it.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import torch
from torch import Tensor

from ushape.errors import InputError
from ushape.evaluation.encoders import EncoderRun
from ushape.evaluation.protocols import EncoderSpec
from ushape.evaluation.views import Encodings, Estimate, ViewKey
from ushape.workspace import CONFIG_DIR

log = logging.getLogger(__name__)
METHODS_DIR = CONFIG_DIR / "method"


class ReconstructionMethod:
    """A method: `name` (in encoder names), `label` (in tables), and the two steps subclasses may override."""

    name: str = ""
    label: str = ""
    # (T_sdf, floor) of the SDF variance propagated from this method's Gaussians, T_sdf var + floor^2, where it
    # was given for them (a refined posterior is not the encoder's Gaussian the run's T_sdf was fitted on);
    # None: the run's single-view T_sdf and no floor.
    sdf_calibration: tuple[float, float | None] | None = None

    def encodings(self, run: EncoderRun, encodings: Encodings, min_scale: float) -> Encodings:
        """The per-view Gaussians [N, D] the protocols fuse for these views (default: the encoder's own)."""
        return encodings

    def sdf_calibration_for(self, run: EncoderRun, n_views: int = 1) -> tuple[float, float | None] | None:
        """(T_sdf, floor) of this method's SDF variance for a run's Gaussians of n_views views (default:
        `sdf_calibration`, the same for all)."""
        return self.sdf_calibration

    def after_fusion(self, context, fused: Estimate, keys: Sequence[ViewKey], min_scale: float) -> Estimate:
        """The Gaussian reconstructed from `fused`, the Gaussian of the views `keys` (each cropped at min_scale)
        combined by a table's rule (one view: its own). `context` is the encoder's `EvalContext` (its run,
        settings and cache folder). Default: `fused` itself."""
        return fused

    @property
    def changes_fused(self) -> bool:
        """Whether `after_fusion` is overridden (the identity is skipped, and a fusion-only protocol can tell)."""
        return type(self).after_fusion is not ReconstructionMethod.after_fusion


def sdf_variance_calibration(run) -> tuple[float | None, float | None]:
    """(T_sdf, floor) for the SDF variance of the Gaussians a run reconstructs with: its method's own where
    fitted (`ReconstructionMethod.sdf_calibration`), else the run's single-view T_sdf and no floor."""
    method = run.method
    own = method.sdf_calibration_for(run) if method is not None and method.changes_fused else None
    return own if own is not None else (run.predictor.sdf_temperature, None)


def per_view(context, encodings: Encodings, min_scale: float, done: dict[ViewKey, Estimate] | None = None) -> Encodings:
    """Every view's Gaussian passed through the run's method's `after_fusion` on that view alone.

    The variances come back [N, D] when every one stayed diagonal, else [N, D, D]; `fallbacks` says, per
    view, why the method fell back (None: it did not). No method, or one without the step: `encodings`.
    done: the views' results so far (read and filled in), so a view is stepped once per crop.
    """
    method = context.run.method
    if method is None or not method.changes_fused:
        return encodings
    done = {} if done is None else done
    fresh = [(i, key) for i, key in enumerate(encodings.keys) if key not in done]
    for i, key in fresh:
        done[key] = method.after_fusion(context, Estimate(encodings.mu[i], encodings.var[i]), [key], min_scale)
    if fresh:
        what = f"single views at min_scale {min_scale:g}"
        log_fallbacks(context.spec.name, [done[key].fallback for _, key in fresh], what)
    found = [done[key] for key in encodings.keys]
    return Encodings(
        list(encodings.keys),
        torch.stack([e.mu for e in found]),
        stack_variances([e.var for e in found]),
        fallbacks=tuple(e.fallback for e in found),
    )


def stack_variances(variances: Sequence[Tensor]) -> Tensor:
    """[N, D] when every variance is a diagonal [D]; else [N, D, D], diagonals made full."""
    if all(v.ndim == 1 for v in variances):
        return torch.stack(list(variances))
    return torch.stack([torch.diag(v) if v.ndim == 1 else v for v in variances])


def log_fallbacks(name: str, fallbacks: Sequence[str | None], what: str) -> int:
    """Log how many of a batch of reconstructions fell back, and why; returns the count."""
    reasons = [f for f in fallbacks if f is not None]
    if reasons:
        log.warning(
            "%s: %d of %d %s fell back to their input (%s)",
            name,
            len(reasons),
            len(fallbacks),
            what,
            "; ".join(sorted(set(reasons))),
        )
    return len(reasons)


def fallback_lines(summary: Sequence[dict]) -> list[str]:
    """One line per (encoder, protocol, min scale) of a method that may fall back: how many of its scored
    reconstructions did (the summary's `fallbacks`, summed over the cells' fusion rules)."""
    counts: dict[tuple, list[int]] = {}
    for row in summary:
        if "fallbacks" in row:
            count = counts.setdefault((row["label"], row["protocol"], row["min_scale"]), [0, 0])
            count[0], count[1] = count[0] + row["fallbacks"], count[1] + row["n"]
    return [
        f"{label}, {protocol} view(s) at min_scale {scale:g}: {fell} of {n} reconstructions fell back to their input"
        for (label, protocol, scale), (fell, n) in counts.items()
    ]


def method_variants(run: EncoderRun, methods: Sequence[ReconstructionMethod]) -> list[EncoderRun]:
    """The run scored plainly, then once per method under its own encoder name and label."""
    variants = [run]
    for method in methods:
        if not method.name:
            raise ValueError(f"{type(method).__name__} needs a name: it tells its rows from the encoder's")
        spec = EncoderSpec(
            f"{run.spec.name}+{method.name}",
            f"{run.spec.label} + {method.label or method.name}",
            run.spec.probabilistic,
        )
        variants.append(replace(run, spec=spec, method=method))
    return variants


def available_methods(folder: Path = METHODS_DIR) -> dict[str, Path]:
    """name -> YAML file of every method in conf/method/."""
    return {path.stem: path for path in sorted(Path(folder).glob("*.yaml"))}


def build_methods(entries: Sequence[Any], folder: Path = METHODS_DIR) -> list[ReconstructionMethod]:
    """eval.py's `methods`: each a name of conf/method/<name>.yaml, or a `_target_` config of its own."""
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    files = available_methods(folder)
    built = []
    for entry in entries:
        if isinstance(entry, str):
            if entry not in files:
                raise InputError(
                    f"methods: unknown method {entry!r}; choose from {sorted(files)} or give a `_target_` config"
                )
            entry = OmegaConf.load(files[entry])
        method = instantiate(entry)
        if not isinstance(method, ReconstructionMethod):
            raise InputError(
                f"methods: {entry} must build a ReconstructionMethod subclass, got {type(method).__name__}"
            )
        built.append(method)
    return built
