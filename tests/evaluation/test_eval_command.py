"""eval.py's logic end to end: a real (tiny) encoder run folder -> tables and a sweep row; config choices."""

import json
import warnings

import pytest
from eval_world import fit_sphere_run
from hydra import compose, initialize_config_dir

from ushape.evaluation.command import configured_setting, protocols_for, run_eval
from ushape.evaluation.settings import PAPER_PROTOCOLS

CONF = str(__import__("pathlib").Path(__file__).resolve().parents[2] / "conf")


def _compose(overrides):
    with initialize_config_dir(CONF, version_base="1.3"):
        return compose("eval", overrides=overrides)


def test_sweep_jobs_score_only_their_setting_unless_told_otherwise():
    assert protocols_for("auto", multirun=False) == list(PAPER_PROTOCOLS)  # active only when asked for
    assert protocols_for("auto", multirun=True) == []
    assert protocols_for(["single_view"], multirun=True) == ["single_view"]
    fuse, name, scale = configured_setting(_compose(["fusion=bayesian_k", "fusion.k=2", "crop.min_scale=0.1"]))
    assert (name, scale) == ("bayesian-2", 0.1) and fuse.k == 2
    assert configured_setting(_compose(["fusion=average"]))[1:] == ("average", 1.0)


def test_eval_writes_tables_and_the_setting_row_for_a_real_run(sphere_world, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("USHAPE_ROOT", str(tmp_path))
    run_dir = fit_sphere_run(sphere_world, tmp_path)
    out = tmp_path / "eval"
    cfg = _compose(
        [
            f"runs=[{run_dir}]",
            f"cache_dir={tmp_path / 'cache'}",
            "tensorboard=false",
            "protocols=[single_view,uncertainty]",
            "protocol.resolution=24",
            "protocol.n_points=128",
            "++plugins.uncertainty.sdf_points=100",
            "protocol.single_view_views=2",
            "fusion=bayesian_k",
            "fusion.k=3",
        ]
    )
    cfg.out_dir = str(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        iou = run_eval(cfg)
    assert 0 <= iou <= 1
    results = json.loads((out / "results.json").read_text())
    assert results["precision"]["requested"] == "auto"  # protocol=quick's default, resolved once
    assert results["settings"]["precision"] == results["precision"]["resolved"] in ("fp32", "bf16")
    row = json.loads((out / "eval_row.json").read_text())[0]
    assert (row["label"], row["fusion"], row["n_views"]) == ("Ours-NLL", "bayesian-3", 4)  # 2 shapes x 2 views
    assert "Table 1" in (out / "tables.md").read_text() and "Table S1" in capsys.readouterr().out
    shown = sorted(p.stem for p in (out / "meshes").glob("*.npz"))  # the showcase, in the page's 3D viewer
    page = (out / "report.html").read_text()
    assert shown and all(f'"label": "{stem}"' in page for stem in shown) and "<table><tr><th>" in page
    cfg.out_dir = None  # the default: into the evaluated run's folder
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_eval(cfg)
    assert [p.parent.parent for p in run_dir.glob("eval/*/tables.md")] == [run_dir / "eval"]
    cfg.temperature = True  # asked for, but never fitted for this run
    with pytest.raises(SystemExit) as stop:  # bad input: one line naming the missing file, exit 2
        run_eval(cfg)
    assert stop.value.code == 2 and "temperature.json" in capsys.readouterr().err


def test_eval_explains_a_missing_run(tmp_path, capsys):
    cfg = _compose([f"runs=[{tmp_path / 'missing'}]"])
    cfg.out_dir = str(tmp_path)
    with pytest.raises(SystemExit) as stop:  # bad input: one line, exit 2
        run_eval(cfg)
    assert stop.value.code == 2 and "do not exist" in capsys.readouterr().err


def test_eval_adds_the_refined_rows_of_a_method_config(sphere_world, tmp_path, monkeypatch):
    monkeypatch.setenv("USHAPE_ROOT", str(tmp_path))
    run_dir = fit_sphere_run(sphere_world, tmp_path)
    method = "{_target_: ushape.evaluation.refine_method.RefineMethod, mode: masks, size: 4, iterations: 2}"
    cfg = _compose(
        [
            f"runs=[{run_dir}]",
            f"cache_dir={tmp_path / 'cache'}",
            f"out_dir={tmp_path / 'eval'}",
            "tensorboard=false",
            "protocols=[single_view]",
            "protocol.resolution=16",
            "protocol.n_points=64",
            "protocol.single_view_views=1",
            "protocol.group_size=2",
            "protocol.max_shapes=1",
            f"methods=[{method}]",
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_eval(cfg)
    tables = (tmp_path / "eval" / "tables.md").read_text()
    assert "| Ours-NLL + refine (masks) |" in tables
    rows = {r["label"]: r for r in json.loads((tmp_path / "eval" / "eval_row.json").read_text())}
    assert rows["Ours-NLL + refine (masks)"]["n_instances"] == rows["Ours-NLL"]["n_instances"] == 4
    assert list((tmp_path / "cache" / "refine").glob("*.pt"))


def test_eval_scores_a_shipped_model_by_name_on_a_given_world(sphere_world, tmp_path, monkeypatch):
    """runs=[pretrained:<name>] world=<folder>: a model from the package, scored like a run."""
    from ushape.reconstruction import pretrained

    monkeypatch.setenv("USHAPE_ROOT", str(tmp_path))
    run_dir = fit_sphere_run(sphere_world, tmp_path)
    pretrained.export_pretrained(run_dir, "sphere", tmp_path / "shipped")
    monkeypatch.setattr(pretrained, "PRETRAINED_DIR", tmp_path / "shipped")
    out = tmp_path / "eval_shipped"
    cfg = _compose(
        [
            "runs=[pretrained:sphere]",
            f"world={sphere_world.root}",
            f"cache_dir={tmp_path / 'cache'}",
            "tensorboard=false",
            "protocols=[single_view]",
            "protocol.resolution=24",
            "protocol.n_points=128",
            "protocol.single_view_views=2",
        ]
    )
    cfg.out_dir = str(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        iou = run_eval(cfg)
    assert 0 <= iou <= 1 and "Table 1" in (out / "tables.md").read_text()
    page = (out / "report.html").read_text()  # the evaluation's page: its tables (and plots, showcase meshes)
    assert "<table><tr><th>" in page and "Table 1" in page
