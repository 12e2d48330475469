"""Tables, plots and result files of an evaluation; the grid inside test; run discovery."""

import json

import numpy as np
import pytest
import torch

from ushape.evaluation import tables
from ushape.evaluation.code_metrics import grid_inside_fn
from ushape.evaluation.runner import load_results
from ushape.evaluation.sources import resolve_runs, sweep_runs
from ushape.mesh.extraction import sdf_grid


def test_grid_inside_test_interpolates_in_our_axis_order():
    centre = torch.tensor([0.3, 0.0, -0.2])
    inside = grid_inside_fn(sdf_grid(lambda p: (p - centre).norm(dim=-1) - 0.4, 33))
    points = np.array([[0.3, 0, -0.2], [0.3, 0.35, -0.2], [0.3, 0.45, -0.2], [0.75, 0, -0.2], [0.3, 0, 0.25]])
    assert inside(points).tolist() == [True, True, False, False, False]
    assert not inside(np.array([[1.5, 0.0, 0.0]]))[0]


def _cell(encoder, protocol, scale, method, iou, views=1):
    labels = {"es": "Ours", "nll": "Ours-NLL", "l2": "FroDO*"}
    return {
        "encoder": encoder,
        "label": labels[encoder],
        "protocol": protocol,
        "min_scale": scale,
        "method": method,
        "views": views,
        "n": 3,
        "iou": iou,
        "cd": 0.1,
        "emd": 0.2,
    }


def test_table3_percentages_are_relative_to_frodo_single_and_average():
    summary = [
        _cell("l2", "single", 1.0, "single-view", 0.40),
        _cell("l2", "multi", 1.0, "average", 0.50, 10),
        _cell("es", "single", 1.0, "single-view", 0.44),
        _cell("es", "multi", 1.0, "bayesian-4", 0.55, 10),
        _cell("es", "multi", 1.0, "bayesian", 0.45, 10),
    ]
    table = tables.table3(summary, 10)
    rows = {(r[0], r[2]): r for r in table.rows}
    assert rows[("Ours", "Single-view")][4] == pytest.approx(10.0)
    assert rows[("Ours", "Bayesian-4")][4] == pytest.approx(10.0)
    assert rows[("Ours", "Bayesian(-all)")][4] == pytest.approx(-10.0)
    assert [r[0] for r in table.rows][0] == "FroDO*"  # baseline first, as in the paper


def test_table4_columns_are_min_scales_and_missing_cells_are_dashes():
    summary = [_cell("l2", "multi", 1.0, "average", 0.5, 10), _cell("l2", "multi", 0.1, "average", 0.3, 10)]
    table = tables.table4(summary)
    assert table.columns == ["Method", "1", "0.8", "0.4", "0.2", "0.1"]
    assert table.rows == [["FroDO*", 0.5, None, None, None, 0.3]]
    markdown = table.to_markdown()
    assert "| FroDO* | 0.5000 | – | – | – | 0.3000 |" in markdown
    assert table.to_csv().splitlines()[1] == "FroDO*,0.5,,,,0.3"


def test_evaluation_writes_every_table_plot_and_row(evaluated_dir):
    names = {p.name for p in evaluated_dir.iterdir()}
    assert {
        "results.json",
        "records.csv",
        "summary.csv",
        "tables.md",
        "table1.csv",
        "table3.csv",
        "table4.csv",
        "table5.csv",
        "tables1.csv",
        "tabled.csv",
        "depth.csv",
        "eval_row.json",
        "tensorboard",
        "meshes",
        "plots",
    } <= names
    plots = {p.name for p in (evaluated_dir / "plots").iterdir()}
    assert plots == {
        "calibration_latent.png",
        "calibration_sdf.png",
        "calibration_depth.png",
        "iou_vs_k.png",
        "iou_vs_min_scale.png",
    }
    assert list((evaluated_dir / "tensorboard").glob("events.out.tfevents.*"))
    assert len(list((evaluated_dir / "meshes").glob("*.png"))) == 6  # 3 encoders x (single, fused) x 1 shape
    text = (evaluated_dir / "results.json").read_text()
    json.loads(text, parse_constant=lambda c: pytest.fail(f"results.json holds {c}: not strict JSON"))
    rows = json.loads((evaluated_dir / "eval_row.json").read_text())
    assert [(r["label"], r["fusion"], r["min_scale"]) for r in rows] == [
        ("Ours", "bayesian-2", 0.4),
        ("Ours-NLL", "bayesian-2", 0.4),
        ("FroDO*", "bayesian-2", 0.4),
    ]


def test_table_s1_lists_the_equal_variance_baseline_first(evaluated_dir):
    result = load_results(evaluated_dir)
    table = tables.table_s1(result["uncertainty"], result["summary"])
    assert table.rows[0][0].startswith("Equal Var") and "constant" in table.caption
    methods = {(r[0], r[2]) for r in table.rows}
    assert ("Ours", "linearised") in methods and ("Ours-NLL", "mc") in methods
    assert not any(r[0] == "FroDO*" for r in table.rows)  # its only uncertainty is the equal-variance one
    ious = [r[-1] for r in table.rows if r[1] == "predicted"]
    assert all(0 < iou <= 1 for iou in ious)


def test_load_results_explains_a_missing_evaluation(tmp_path):
    with pytest.raises(FileNotFoundError, match="eval.py"):
        load_results(tmp_path)


def test_runs_are_resolved_from_folders_sweeps_or_the_newest(tmp_path):
    with pytest.raises(FileNotFoundError, match="do not exist"):
        resolve_runs([tmp_path / "nope"])
    sweep = tmp_path / "outputs" / "multirun" / "d" / "t"
    for job in ("0_loss=es", "1_loss=nll", "10_loss=l2"):
        (sweep / job).mkdir(parents=True)
        (sweep / job / "run.json").write_text(json.dumps({"stage": "encoder"}))
    (sweep / "2_unfinished").mkdir()
    assert [p.name for p in sweep_runs(sweep)] == ["0_loss=es", "1_loss=nll", "10_loss=l2"]
    assert [p.name for p in resolve_runs(root=tmp_path)] == ["0_loss=es", "1_loss=nll", "10_loss=l2"]
    with pytest.raises(FileNotFoundError, match="no finished encoder run"):
        resolve_runs(root=tmp_path / "empty")


def test_error_tracking_table_has_a_row_per_probabilistic_encoder_and_crop(evaluated_dir):
    result = load_results(evaluated_dir)
    table = tables.table_error_tracking(result["error_tracking"])
    crops = set(result["protocols"]["corrupted"]["single_view_scales"]) - {1.0}
    pooled = {f"1 & {s:g}" for s in crops}
    assert {r[1] for r in table.rows} == crops | {1.0} | pooled
    assert {r[0] for r in table.rows} == {"Ours", "Ours-NLL", "FroDO*"}
    assert all(-1 <= r[6] <= 1 for r in table.rows if r[0] != "FroDO*")
    assert all(r[6] is None for r in table.rows if r[0] == "FroDO*")  # NaN -> null in results.json
    # Shape accuracy beside the latent error; a pooled row counts the clean and the cropped views.
    assert all(0 <= r[3] <= 1 and r[4] > 0 for r in table.rows)
    single = {(r[0], r[1]): r for r in table.rows}
    for label in ("Ours", "FroDO*"):
        for s in crops:
            assert single[(label, f"1 & {s:g}")][7] == single[(label, 1.0)][7] + single[(label, s)][7]
    assert "does the predicted variance track the error" in (evaluated_dir / "tables.md").read_text()


def test_table1_brackets_the_encoders_with_the_decoder_ceiling_and_the_mean_code(evaluated_dir):
    result = load_results(evaluated_dir)
    rows = {r[0]: r for r in tables.table1(result["summary"]).rows}
    ceiling, mean = rows["Stage-1 codes (decoder ceiling)"], rows["Mean training code (no image)"]
    # The analytic decoder reproduces each ellipsoid from its own code; the mean radius fits none exactly.
    assert ceiling[2] > 0.85 and ceiling[2] > mean[2]
    assert ceiling[5] == mean[5] == len({r["shape_id"] for r in result["records"] if r["protocol"] == "single"})
