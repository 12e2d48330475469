"""Which fusion rule a reconstruction uses: the calibrated `shared` rule where the run has its fit, else Bayesian.

Bayesian fusion treats the views' errors as independent; measured, most of a view's error is shared by
every view of the shape (docs/fusion_calibration.md), so its fused variance is over-confident from a
few views on. `python reconstruct.py --fit-temperature` fits the shared error S beside the temperature;
once it is there, a reconstruction that names no rule uses `shared` with it (and the temperature, which
S was fitted against, and the SDF temperature fitted on the rule's own fused variance), and summary.json
says so under "fusion", "fusion_calibration" and "sdf_temperature".
"""

from __future__ import annotations

from typing import Any

from ushape.fusion import BayesianFusion, BayesianKFusion, SharedErrorFusion
from ushape.recalibration import apply_temperature
from ushape.reconstruction.predictor import Predictor, read_shared_error, read_temperatures, temperature_path


def calibrate_fusion(fusion: Any, predictor: Predictor) -> Any:
    """The rule with the run's fitted shared error where it needs one (the predictor then applies its
    temperature, which S was fitted against); any other rule as it is."""
    if not isinstance(fusion, SharedErrorFusion) or fusion.shared_var is not None:
        return fusion
    fit = read_shared_error(predictor.checkpoint)
    if fit is None:
        raise ValueError(
            f"fusion {fusion.name!r} needs the shared error fitted on val, and "
            f"{temperature_path(predictor.checkpoint)} holds none: run "
            f"`python reconstruct.py --fit-temperature --checkpoint {predictor.checkpoint}` first"
        )
    if predictor.temperature is None:
        predictor.temperature, predictor.sdf_temperature = read_temperatures(predictor.checkpoint)
    return with_fit(fusion, fit, predictor.checkpoint)


def with_fit(fusion: SharedErrorFusion, fit, checkpoint) -> SharedErrorFusion:
    """The shared rule carrying a run's fitted shared error and its SDF calibration (`read_shared_error`)."""
    source = str(temperature_path(checkpoint))
    sdf = (fit.sdf_temperature, fit.sdf_floor, fit.sdf_distance_scale)
    return fusion.calibrated(fit.shared_var, fit.view_scale, source, *sdf)


def default_fusion(predictor: Predictor, k: int | None = None) -> Any:
    """`shared` (Bayesian-K's views with k) calibrated on the run's val split where it was fitted, else Bayesian."""
    if read_shared_error(predictor.checkpoint) is None:
        return BayesianFusion()
    return calibrate_fusion(SharedErrorFusion(k=k), predictor)


def calibrated_counterpart(fusion: Any, predictor: Predictor) -> Any:
    """Bayesian (or Bayesian-K) as `shared` (`shared`-K: the same views, the same mean) where the run has the
    shared error fitted; every other rule, or a run without the fit, as it is (shared is calibrated)."""
    fusion = fusion if fusion is not None else BayesianFusion()
    if isinstance(fusion, SharedErrorFusion):
        return calibrate_fusion(fusion, predictor)
    if not isinstance(fusion, (BayesianFusion, BayesianKFusion)) or read_shared_error(predictor.checkpoint) is None:
        return fusion
    return calibrate_fusion(SharedErrorFusion(k=getattr(fusion, "k", None), var_floor=fusion.var_floor), predictor)


class TemperatureScaled:
    """A fusion rule applied to view variances scaled by a latent temperature first: for views encoded
    without it by a predictor that is not to be changed (eval.py's, shared by every protocol)."""

    def __init__(self, rule: Any, temperature: float) -> None:
        self.rule, self.temperature = rule, float(temperature)
        self.name = getattr(rule, "name", type(rule).__name__)

    def __call__(self, mu, var):
        return self.rule(mu, apply_temperature(var, self.temperature))


def refinement_prior(predictor: Predictor) -> Any | None:
    """The run's calibrated `shared` rule for the views as this predictor encodes them, without changing the
    predictor (where it does not apply its stored temperature, the rule scales the variances by it, as S was
    fitted on them); None where the run has no shared error fitted. The prior reconstruct.py refines."""
    fit = read_shared_error(predictor.checkpoint)
    if fit is None:
        return None
    rule = with_fit(SharedErrorFusion(), fit, predictor.checkpoint)
    if predictor.temperature is not None:
        return rule
    return TemperatureScaled(rule, read_temperatures(predictor.checkpoint)[0])
