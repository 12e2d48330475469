"""Table L (where the uncertainty sits): known answers for the point split, the ratios and their summary."""

import json

import numpy as np
import pytest
import trimesh

from ushape.data.cameras import look_at, project
from ushape.evaluation.locality import ViewParts, split_points, summarise_locality, view_record
from ushape.mesh.visibility import median_ratio

SIZE = 64


@pytest.fixture(scope="module")
def sphere_view():
    """A unit sphere, 3000 points on it, and a camera at distance 5 on the +x axis (azimuth 0, elevation 0)."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    points, _ = trimesh.sample.sample_surface(sphere, 3000, seed=0)
    K, w2c = look_at(0.0, 0.0, 5.0, 40.0, SIZE)
    return sphere, np.asarray(points), K, w2c


def test_points_split_into_hidden_kept_and_cropped_away(sphere_view):
    sphere, points, K, w2c = sphere_view
    box = (0, 0, SIZE, SIZE // 2)  # keep the left half of the image
    parts = split_points(sphere, points, K, w2c, box)
    visible = ~parts.hidden
    assert not (parts.kept & parts.away).any() and np.array_equal(parts.kept | parts.away, visible)
    # From distance 5 the visible cap is the one facing the camera, beyond the tangent cone (cos = 1/5).
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    facing = points @ centre / np.linalg.norm(centre)
    clear = np.abs(facing - 0.2) > 0.05
    assert np.array_equal(visible[clear], facing[clear] > 0.2)
    # Kept points project into the left half, cropped-away ones into the right half.
    uv, _ = project(points, K, w2c)
    assert (uv[parts.kept, 0] < SIZE / 2).all() and (uv[parts.away, 0] >= SIZE / 2).all()
    assert parts.kept.sum() > 100 and parts.away.sum() > 100


def test_the_whole_image_crops_nothing_away(sphere_view):
    sphere, points, K, w2c = sphere_view
    parts = split_points(sphere, points, K, w2c, (0, 0, SIZE, SIZE))
    assert not parts.away.any() and np.array_equal(parts.kept, ~parts.hidden)


def test_median_ratio_known_answers():
    values = np.array([1.0, 2.0, 3.0, 10.0])
    assert median_ratio(values, [False, False, True, True], [True, True, False, False]) == pytest.approx(6.5 / 1.5)
    assert median_ratio(values, [True] * 4, [True] * 4, under_values=values / 2) == pytest.approx(2.0)
    assert median_ratio(values, [False] * 4, [True] * 4) is None
    assert median_ratio(np.zeros(4), [True] * 4, [True] * 4) is None  # zero denominator


def test_view_record_measures_a_shift_onto_the_cropped_away_part():
    n = 12
    parts = ViewParts(hidden=np.arange(n) >= 8, kept=np.arange(n) < 4, away=(np.arange(n) >= 4) & (np.arange(n) < 8))
    clean = np.where(parts.hidden, 3.0, 1.0)  # the hidden third three times as uncertain
    cropped = np.where(parts.away, 2.0, clean)  # the crop doubles the std on what it removed, nothing else
    fused = clean * np.where(parts.hidden, 0.25, 0.5)  # other views shrink the hidden part's std more
    err_clean = np.ones(n)
    err_crop = np.where(parts.away, 4.0, 1.0)  # ... and the prediction got 4x worse there
    record = view_record(parts, (err_clean, clean), (err_crop, cropped), fused)
    assert record["n_visible"] == 8 and record["n_away"] == 4
    assert record["hidden_over_visible"] == pytest.approx(3.0)
    assert record["away_over_kept_clean"] == pytest.approx(1.0)
    assert record["away_over_kept_cropped"] == pytest.approx(2.0)
    assert record["crop_shift"] == pytest.approx(2.0)
    assert record["std_gain"] == pytest.approx(cropped.mean() / clean.mean())
    assert record["fused_hidden"] == pytest.approx(0.25) and record["fused_visible"] == pytest.approx(0.5)
    assert record["error_crop_shift"] == pytest.approx(4.0) and record["error_hidden_over_visible"] == pytest.approx(
        1.0
    )
    assert record["error_gain"] == pytest.approx(err_crop.mean())


def test_view_record_without_a_crop_has_no_crop_ratios():
    n = 6
    parts = ViewParts(hidden=np.arange(n) >= 3, kept=np.arange(n) < 3, away=np.zeros(n, bool))
    ones = (np.ones(n), np.ones(n))
    record = view_record(parts, ones, ones, np.ones(n))
    assert (
        record["away_over_kept_clean"] is None and record["crop_shift"] is None and record["error_crop_shift"] is None
    )
    assert record["hidden_over_visible"] == pytest.approx(1.0)


def _record(encoder, shift, n_away, hidden=1.0):
    return {
        "encoder": encoder,
        "label": encoder.upper(),
        "min_scale": 0.1,
        "n_visible": 100,
        "n_away": n_away,
        "hidden_over_visible": hidden,
        "away_over_kept_clean": 1.0,
        "away_over_kept_cropped": shift,
        "crop_shift": shift,
        "error_crop_shift": 1.0,
        "error_hidden_over_visible": 1.0,
        "std_gain": 1.0,
        "error_gain": 1.0,
        "fused_hidden": 0.3,
        "fused_visible": 0.3,
    }


def test_summary_takes_medians_and_counts_only_views_the_crop_really_cut():
    records = [
        _record("es", 2.0, 50, hidden=2.0),
        _record("es", 3.0, 50),
        _record("es", 0.5, 50),
        _record("es", 100.0, 1),
        _record("nll", 1.0, 0),
    ]  # n_away 1 and 0: under 5% of the visible
    rows = {r["encoder"]: r for r in summarise_locality(records)}
    es = rows["es"]
    assert es["n_views"] == 4 and es["n_cropped_views"] == 3
    assert es["crop_shift"] == pytest.approx(2.0) and es["crop_shift_above_1"] == pytest.approx(2 / 3)
    assert es["hidden_over_visible"] == pytest.approx(1.0) and es["hidden_over_visible_above_1"] == pytest.approx(0.25)
    assert rows["nll"]["n_cropped_views"] == 0 and rows["nll"]["crop_shift"] is None


def test_evaluation_writes_table_l_for_the_probabilistic_encoders(evaluated_dir):
    result = json.loads((evaluated_dir / "results.json").read_text())
    rows = {r["encoder"]: r for r in result["locality"]}
    assert set(rows) == {"es", "nll"}  # FroDO* has no variance to locate
    assert all(r["n_views"] == 16 for r in rows.values())  # 2 shapes x 8 views
    assert all(r["fused_visible"] is not None and 0 < r["fused_visible"] < 1 for r in rows.values())
    assert len(result["locality_views"]) == 32
    markdown = (evaluated_dir / "tables.md").read_text()
    assert "Table L: where the uncertainty sits" in markdown
    assert (evaluated_dir / "locality_views.csv").is_file()


def test_a_world_without_cameras_skips_table_l_with_a_warning(sphere_world, sphere_codes, tmp_path, caplog):
    import shutil

    from eval_world import make_run, tiny_protocols, tiny_settings

    from ushape.data.layout import WorldIndex
    from ushape.evaluation.runner import evaluate_all

    root = tmp_path / "photos"
    shutil.copytree(sphere_world.root, root)
    for cameras in root.glob("renders/*/views.npz"):
        cameras.unlink()  # like real photos: no known camera
    world = WorldIndex.load(root)
    settings = tiny_settings()
    run = make_run(world, sphere_codes, tmp_path / "cache", "es", tmp_path, settings)
    with caplog.at_level("WARNING"):
        result = evaluate_all([run], settings, tmp_path / "cache", protocols=tiny_protocols(["locality"]))
    assert result.get("locality", []) == [] and result.get("locality_views", []) == []
    assert "Table L skipped" in caplog.text and "no cameras" in caplog.text
