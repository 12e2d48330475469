"""The active protocol end to end on the ellipsoid world: records, Table A, its plot and the sequence figure."""

import math
from dataclasses import replace

import pytest
from eval_world import make_run, tiny_protocols, tiny_settings

from ushape.evaluation.active_tables import paired_gain, reference_of, table_active, views_to_reach
from ushape.evaluation.report import write_results
from ushape.evaluation.runner import evaluate_all
from ushape.evaluation.showcase import Showcase
from ushape.planning.sequence import ActivePlan, method_name, start_view

STRATEGIES = ("uncertainty", "unseen-uncertainty", "farthest", "random", "oracle", "information")


@pytest.fixture(scope="module")
def active_result(sphere_world, sphere_codes, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("active")
    settings = tiny_settings()
    protocols = tiny_protocols(["active"], active=dict(views=3, scales=(1.0, 0.1)))
    runs = [make_run(sphere_world, sphere_codes, tmp / "cache", name, tmp, settings) for name in ("es", "l2")]
    result = evaluate_all(runs, settings, tmp / "cache", None, tmp / "out", protocols, showcase=Showcase(0))
    write_results(result, tmp / "out", tensorboard=False)
    return result, tmp / "out"


def test_every_strategy_is_scored_after_each_view_from_one_shared_start(active_result):
    records = [r for r in active_result[0]["records"] if r["protocol"] == "active"]
    assert {r["encoder"] for r in records} == {"es"}  # FroDO* predicts no variance to plan with
    assert {r["method"] for r in records} == set(STRATEGIES)
    assert len(records) == 2 * 2 * len(STRATEGIES) * 3  # shapes x crops x strategies x views
    for shape_id in ("test_0", "test_1"):
        for scale in (1.0, 0.1):
            firsts = {r["item"] for r in records if (r["shape_id"], r["min_scale"], r["views"]) == (shape_id, scale, 1)}
            assert firsts == {str(start_view(0, shape_id, 8))}
            ious = {r["iou"] for r in records if (r["shape_id"], r["min_scale"], r["views"]) == (shape_id, scale, 1)}
            assert len(ious) == 1  # one cached encoding of the start view, scored by the same call
    assert all(len(r["item"].split("-")) == r["views"] for r in records)
    assert all(0 <= r["iou"] <= 1 for r in records)


def test_table_a_plot_and_sequence_are_written(active_result):
    _, out = active_result
    tables = (out / "tables.md").read_text()
    assert "Table A: active reconstruction (IoU after k views)" in tables and "unseen-uncertainty" in tables
    assert "Table A: active reconstruction (CD after k views)" in tables
    assert (out / "plots" / "active_iou_vs_views.png").is_file()
    assert {p.name for p in (out / "plots").glob("active_sequence_*.png")} == {
        "active_sequence_es_1.png",
        "active_sequence_es_0.1.png",
    }


def test_table_a_compares_each_strategy_with_random_shape_by_shape():
    def records(method, per_view):
        return [
            {"encoder": "es", "label": "Ours", "protocol": "active", "min_scale": 1.0, "method": method}
            | {"views": k, "shape_id": s, "iou": iou, "cd": 1 - iou if iou < 0.7 else math.nan}
            for k, ious in enumerate(per_view, start=1)
            for s, iou in zip("ab", ious)
        ]

    rows = records("random", [[0.2, 0.4], [0.3, 0.5], [0.4, 0.6]]) + records(
        "uncertainty", [[0.2, 0.4], [0.4, 0.5], [0.5, 0.8]]
    )
    table = table_active(rows)
    row = next(r for r in table.rows if r[2] == "uncertainty")
    assert row[3:6] == pytest.approx([0.3, 0.45, 0.65])
    # Gains over random at views 2-3: shape a (0.1 + 0.1) / 2 = 0.1, shape b (0 + 0.2) / 2 = 0.1.
    gain, se = row[-4], row[-3]
    assert gain == pytest.approx(0.1) and se == pytest.approx(0.0)
    assert row[-2] == 2  # random's mean at 2 views (0.4) is reached by the guided one at 2 (0.45)
    assert row[-1] is None  # no step timed
    assert math.isnan(next(r for r in table.rows if r[2] == "random")[-4])
    # Chamfer: lower is better, so the drop against random is the gain; shape b's empty view 3 (NaN) is
    # left out of its average: (0.1 + 0.1) / 2 for a, 0 for b.
    chamfer = next(r for r in table_active(rows, "cd").rows if r[2] == "uncertainty")
    assert chamfer[3:5] == pytest.approx([0.7, 0.55]) and chamfer[-4] == pytest.approx(0.05)
    assert views_to_reach({1: 0.1, 2: 0.3}, 0.5) is None
    assert views_to_reach({1: 0.4, 2: 0.3}, 0.35, sign=-1) == 2
    assert all(math.isnan(v) for v in paired_gain({1: [0.5]}, {1: [0.5]}))  # no view after the first to compare


def test_a_refined_row_is_compared_with_random_refined_alike_and_timed():
    def records(method, per_view, seconds):
        return [
            {"encoder": "es", "label": "Ours", "protocol": "active", "min_scale": 1.0, "method": method}
            | {"views": k, "shape_id": s, "iou": iou, "cd": 0.1, "seconds": seconds * k}
            for k, ious in enumerate(per_view, start=1)
            for s, iou in zip("ab", ious)
        ]

    rows = records("random", [[0.2, 0.2], [0.2, 0.2]], 1.0) + records("random+masks", [[0.4, 0.4], [0.5, 0.5]], 2.0)
    rows += records("information+masks", [[0.4, 0.4], [0.6, 0.7]], 3.0)
    row = next(r for r in table_active(rows).rows if r[2] == "information+masks")
    assert row[-4] == pytest.approx(0.15)  # against random+masks (0.5), not plain random (0.2)
    assert row[-1] == pytest.approx(6.0)  # mean seconds of the steps after the first
    assert reference_of("information+depth") == "random+depth" and reference_of("farthest") == "random"
    assert method_name("information", "none") == "information" and method_name("random", "masks") == "random+masks"


def test_table_a_why_says_what_the_choices_were_based_on(active_result):
    result, out = active_result
    rows = result["active"]
    assert len(rows) == 2 * 2 * len(STRATEGIES)  # one per sequence
    guided = [d for r in rows if r["method"] == "uncertainty" for d in r["decisions"]]
    assert len(guided) == 2 * 2 * 2 and all(r["decisions"] == [] for r in rows if r["method"] == "random")
    informed = [d for r in rows if r["method"] == "information" for d in r["decisions"]]
    assert len(informed) == 2 * 2 * 2 and all(math.isnan(d["shrink_seen_over_unseen"]) for d in informed)
    # The ellipsoid decoder reads one code dimension: fusing a view shrinks every vertex's std by one factor
    # (exactly, where the clean views all give one mean; within 3 % where crops move the mean, and the mesh).
    for row in (r for r in rows if r["method"] == "uncertainty"):
        tolerance = 1e-6 if row["min_scale"] == 1.0 else 3e-2
        assert all(d["shrink_seen_over_unseen"] == pytest.approx(1.0, abs=tolerance) for d in row["decisions"])
    assert "Table A-why" in (out / "tables.md").read_text()


def test_view_spread_is_the_mean_angle_between_the_views_taken(sphere_world):
    from ushape.evaluation.active_diagnostics import view_spread
    from ushape.planning import Step, candidate_views

    candidates = candidate_views(sphere_world, "test_0")  # azimuths 0, 45, ..., elevation 20

    def steps(*views):
        return [Step(v, None, None) for v in views]

    assert math.isnan(view_spread(steps(0), candidates))
    assert view_spread(steps(0, 4), candidates) == pytest.approx(180 - 2 * 20, abs=1e-4)  # over the top
    assert view_spread(steps(0, 0, 4), candidates) == pytest.approx(2 * 140 / 3, abs=1e-4)


def test_a_world_without_cameras_skips_the_protocol_and_says_why(sphere_world, sphere_codes, tmp_path, caplog):
    import shutil

    from ushape.data.layout import WorldIndex
    from ushape.decoder.artifacts import codes_file, load_codes
    from ushape.evaluation.active import active_records

    root = tmp_path / "photos"
    shutil.copytree(sphere_world.root, root)
    for path in root.glob("renders/*/views.npz"):
        path.unlink()  # photos without their cameras, as a Pix3D world
    settings = tiny_settings()
    run = make_run(WorldIndex.load(root), sphere_codes, tmp_path / "cache", "es", tmp_path, settings)
    codes = load_codes(sphere_codes / codes_file("test"))
    assert active_records(run, settings, ActivePlan(views=2), codes) == ([], [])
    assert "Table A skipped" in caplog.text and "no cameras" in caplog.text


def _kept_run(sphere_world, sphere_codes, tmp_path, **overrides):
    from ushape.decoder.artifacts import codes_file, load_codes

    plan = ActivePlan(**{**dict(views=2, scales=(1.0,), strategies=("random", "information")), **overrides})
    settings = tiny_settings()
    run = make_run(sphere_world, sphere_codes, tmp_path / "cache", "es", tmp_path, settings)
    return run, settings, plan, load_codes(sphere_codes / codes_file("test"))


def test_a_finished_sequence_is_kept_and_a_rerun_reads_it_instead_of_running_it(
    sphere_world, sphere_codes, tmp_path, monkeypatch
):
    import json

    from ushape.evaluation import active

    run, settings, plan, codes = _kept_run(sphere_world, sphere_codes, tmp_path, shapes=1)
    cache = tmp_path / "cache"
    first = active.active_records(run, settings, plan, codes, cache)
    assert len(list((cache / "active").glob("*.json"))) == 2  # one shape x two strategies
    ran = []
    run_sequence = active.run_sequence
    monkeypatch.setattr(active, "run_sequence", lambda *a, **k: ran.append(a[5]) or run_sequence(*a, **k))
    # The same selection: nothing runs, and what comes back is what was computed (NaN included).
    assert json.dumps(active.active_records(run, settings, plan, codes, cache)) == json.dumps(first) and ran == []
    # A larger selection runs only the sequences not kept yet: the second shape's.
    records, diagnostics = active.active_records(run, settings, replace(plan, shapes=None), codes, cache)
    assert ran == ["random", "information"] and len(diagnostics) == 4
    assert json.dumps([r for r in records if r["shape_id"] == "test_0"]) == json.dumps(first[0])
    # No cache folder: every sequence runs.
    active.active_records(run, settings, plan, codes, None)
    assert ran == ["random", "information"] * 2


def test_a_kept_sequence_is_keyed_by_what_decides_it(sphere_world, sphere_codes, tmp_path, caplog):
    from ushape.evaluation.active_cache import load_sequence, sequence_file

    run, settings, plan, codes = _kept_run(sphere_world, sphere_codes, tmp_path)
    cache, code = tmp_path / "cache", codes.lookup("test_0")

    def key(settings=settings, plan=plan, scale=1.0, observe="none", strategy="random", code=code):
        return sequence_file(cache, run, settings, plan, "test_0", code, scale, observe, strategy)

    base = key()
    assert key(plan=replace(plan, shapes=1, strategies=("random",), scales=(1.0, 0.1))) == base
    assert key(plan=replace(plan, refine_iterations=3)) != base
    assert key(replace(settings, seed=1)) != base and key(scale=0.1) != base
    assert key(observe="masks") != base and key(strategy="farthest") != base
    assert key(code=code + 1e-3) != base  # the shape's own code refitted (a world whose test codes are fitted)
    (tmp_path / "temperature.json").write_text('{"temperature": 2.0}')  # beside the checkpoint: a refit prior
    refit = key()
    assert refit != base
    (tmp_path / "refinement_calibration.json").write_text("{}")
    assert key() != refit
    assert sequence_file(None, run, settings, plan, "test_0", code, 1.0, "none", "random") is None
    refit = key()
    refit.parent.mkdir(parents=True)
    for damaged in ('{"steps": [', '[{"steps": []}]', '{"steps": []}'):  # cut off, not a sequence, keys missing
        refit.write_text(damaged)
        assert load_sequence(refit) is None  # reported and computed again, not trusted
    assert caplog.text.count("computing it again") == 3
