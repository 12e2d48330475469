"""A reconstruction method adds its own rows to every table, and the protocols stay as they are."""

import warnings

import pytest
from eval_world import make_run, tiny_protocols, tiny_settings

from ushape.evaluation.methods import ReconstructionMethod, method_variants
from ushape.evaluation.report import build_tables
from ushape.evaluation.runner import evaluate_all
from ushape.evaluation.views import Encodings


class Same(ReconstructionMethod):
    name, label = "same", "same codes"


class MeanCode(ReconstructionMethod):
    """Every view's code replaced by the mean of all views' codes at that crop (one shape for all)."""

    name, label = "mean", "mean code"

    def encodings(self, run, encodings, min_scale):
        mu = encodings.mu.mean(0, keepdim=True).expand_as(encodings.mu)
        return Encodings(encodings.keys, mu.clone(), encodings.var)


def test_a_method_is_scored_as_rows_of_its_own_in_every_table(sphere_world, sphere_codes, tmp_path):
    settings, protocols = tiny_settings(), tiny_protocols(["single_view", "multi_view", "uncertainty"])
    run = make_run(sphere_world, sphere_codes, None, "es", tmp_path, settings)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = evaluate_all([run], settings, None, protocols=protocols, methods=[Same(), MeanCode()])
    cells = {(r["encoder"], r["protocol"], r["method"]): r for r in result["summary"]}
    plain, same, mean = (cells[(e, "single", "single-view")] for e in ("es", "es+same", "es+mean"))
    # the encoder's codes, scored again: the same code meets the same scorer (its cache), so the same IoU exactly
    assert same["iou"] == plain["iou"] and same["n"] == plain["n"] == 16
    assert mean["iou"] < plain["iou"]  # one code for two ellipsoids fits neither
    assert cells[("es+mean", "multi", "bayesian")]["label"] == "Ours + mean code"
    tables = {t.name.split(":")[0]: t for t in build_tables(result)}
    assert [row[0] for row in tables["Table 1"].rows][:3] == ["Ours", "Ours + mean code", "Ours + same codes"]
    assert {row[0] for row in tables["Table S1"].rows} >= {"Ours + mean code", "Ours + same codes"}


def test_a_method_needs_a_name(sphere_world, sphere_codes, tmp_path):
    run = make_run(sphere_world, sphere_codes, None, "es", tmp_path, tiny_settings())
    with pytest.raises(ValueError, match="needs a name"):
        method_variants(run, [ReconstructionMethod()])
    assert method_variants(run, []) == [run]
