import torch

from ushape.evaluation.view_calibration import (
    calibration_across_views,
    interval_scores,
    plot_calibration_across_views,
    view_subsets,
)
from ushape.fusion import BayesianFusion, SharedErrorFusion


def _shapes(n_shapes=200, n_views=10, seed=0):
    """Views whose errors share e_shape ~ N(0, S): the shared rule with the true S is calibrated, Bayesian is not."""
    g = torch.Generator().manual_seed(seed)
    shared, view_var = torch.linspace(0.2, 0.6, 8), torch.linspace(0.3, 0.1, 8)
    shapes = []
    for _ in range(n_shapes):
        code = torch.randn(8, generator=g)
        e_shape = torch.randn(8, generator=g) * shared.sqrt()
        mu = code + e_shape + torch.randn(n_views, 8, generator=g) * view_var.sqrt()
        shapes.append((mu, view_var.expand(n_views, 8).clone(), code))
    return shared, shapes


def test_subsets_cover_single_views_and_draw_distinct_views():
    g = torch.Generator().manual_seed(0)
    assert torch.equal(view_subsets(4, 1, 5, g), torch.arange(4).unsqueeze(-1))
    assert torch.equal(view_subsets(4, 4, 5, g), torch.arange(4).unsqueeze(0))
    rows = view_subsets(12, 3, 7, g)
    assert rows.shape == (7, 3) and all(len(set(r.tolist())) == 3 for r in rows)


def test_interval_scores_of_exact_gaussian_errors():
    g = torch.Generator().manual_seed(0)
    std = torch.rand(200_000, generator=g) + 0.5
    scores = interval_scores((torch.randn(200_000, generator=g) * std).abs(), std)
    assert scores["calibration_error"] < 0.005 and abs(scores["coverage90"] - 0.9) < 0.005
    assert abs(scores["error_over_var"] - 1) < 0.02


def test_shared_rule_stays_calibrated_across_views_and_bayesian_does_not():
    shared, shapes = _shapes()
    rules = {"bayesian": BayesianFusion(), "shared": SharedErrorFusion(shared + 0.0, view_scale=1.0)}
    rows = {
        (r["fusion"], r["n_views"]): r for r in calibration_across_views(rules, shapes, view_counts=(1, 3, 10), draws=3)
    }
    for n in (1, 3, 10):
        assert rows[("shared", n)]["latent_calibration_error"] < 0.03
        assert abs(rows[("shared", n)]["latent_coverage90"] - 0.9) < 0.03
    assert rows[("bayesian", 10)]["latent_error_over_var"] > 5  # (S + v/10) / (v/10), about 20
    assert rows[("bayesian", 10)]["latent_calibration_error"] > 0.2
    fig = plot_calibration_across_views(list(rows.values()))
    assert len(fig.axes) == 1  # latent only: no SDF scored


def test_rules_of_a_run_include_shared_only_once_it_is_fitted(tmp_path):
    import json

    from ushape.evaluation.view_calibration import evaluation_rules, rule_sdf_temperature, table_view_calibration

    checkpoint = tmp_path / "best.ckpt"
    rules, latent_t, _ = evaluation_rules(checkpoint, 4)
    assert set(rules) == {"average", "bayesian", "bayesian-4", "intersection"} and latent_t is None
    record = {"temperature": 2.0, "sdf_temperature": 1.5, "shared_error": {"var": [0.1, 0.2], "view_scale": 0.5}}
    (tmp_path / "temperature.json").write_text(
        json.dumps({**record, "shared_error": {**record["shared_error"], "n_shapes": 3}})
    )
    rules, latent_t, sdf_t = evaluation_rules(checkpoint, 4)
    assert {"shared", "shared-4"} <= set(rules) and (latent_t, sdf_t) == (2.0, 1.5)
    assert rules["shared"].sdf_temperature == 1.5  # no SDF temperature of its own: the single-view one
    (tmp_path / "temperature.json").write_text(
        json.dumps({**record, "shared_error": {**record["shared_error"], "n_shapes": 3, "sdf_temperature": 1.8}})
    )
    rules, _, sdf_t = evaluation_rules(checkpoint, 4)
    assert rules["shared"].sdf_temperature == rules["shared-4"].sdf_temperature == 1.8 and sdf_t == 1.5
    assert rule_sdf_temperature(rules["shared"], sdf_t) == (1.8, None, None)
    assert rule_sdf_temperature(rules["bayesian"], sdf_t) == (1.5, None, None)
    shared_error = {**record["shared_error"], "n_shapes": 3, "sdf_temperature": 1.8, "sdf_floor": 0.01}
    shared_error["sdf_distance_scale"] = 0.6
    (tmp_path / "temperature.json").write_text(json.dumps({**record, "shared_error": shared_error}))
    rules, _, sdf_t = evaluation_rules(checkpoint, 4)
    assert rule_sdf_temperature(rules["shared-4"], sdf_t) == (1.8, 0.01, 0.6)  # the misfit floor, the distance term
    refined = rule_sdf_temperature(rules["shared"], sdf_t, after=lambda fused, keys: fused)
    assert refined == (1.5, None, None)  # refined: not the fused variance the shared factor and floor were fitted on
    fitted = rule_sdf_temperature(rules["shared"], sdf_t, after=lambda fused, keys: fused, after_sdf=(0.7, 0.004))
    assert fitted == (0.7, 0.004, None)  # a refinement's own SDF variance calibration, where one was fitted for it
    fused = rules["shared"](torch.zeros(2, 2), torch.ones(2, 2))
    assert torch.allclose(fused.var, torch.tensor([0.1 + 0.25, 0.2 + 0.25]))
    row = {"label": "Ours", "fusion": "shared", "n_views": 3, "n_shapes": 2}
    row.update(
        {f"{s}_{m}": 0.5 for s in ("latent", "sdf") for m in ("calibration_error", "error_over_var", "coverage90")}
    )
    assert table_view_calibration([row]).rows[0][:4] == ["Ours", "shared", 3, 2]
