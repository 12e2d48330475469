"""A new strategy, fusion rule or protocol is one module and one YAML file, here in the tests folder, run through
`ushape active` and `eval.py` with nothing under ushape/ edited (the protocol's own test: evaluation/test_plugin.py)."""

import json
import warnings
from pathlib import Path

from eval_world import fit_sphere_run
from hydra import compose, initialize_config_dir

from ushape.cli import main
from ushape.evaluation.command import run_eval

TESTS = Path(__file__).resolve().parents[1]
CONF = str(TESTS.parent / "conf")
TOY_STRATEGIES = TESTS / "planning" / "toy_strategies"
TOY_FUSION_CONF = TESTS / "fusion" / "toy_conf"


def _eval(overrides, run_dir, tmp_path):
    common = [f"runs=[{run_dir}]", f"cache_dir={tmp_path / 'cache'}", "tensorboard=false", "showcase.shapes=0"]
    with initialize_config_dir(CONF, version_base="1.3"):
        cfg = compose("eval", overrides=common + ["protocol.resolution=24", "protocol.n_points=128", *overrides])
    cfg.out_dir = str(tmp_path / "eval")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_eval(cfg)
    return tmp_path / "eval"


def test_a_strategy_from_the_tests_folder_runs_in_active_and_in_table_a(sphere_world, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(TOY_STRATEGIES.parent))
    monkeypatch.setenv("USHAPE_ROOT", str(tmp_path))
    run = fit_sphere_run(sphere_world, tmp_path)
    out = tmp_path / "active"
    argv = ["active", "--run", str(run), "--views", "3", "--resolution", "24", "--start", "1", "--out", str(out)]
    assert main([*argv, "--strategy", "toy", "--strategy-dir", str(TOY_STRATEGIES)]) == 0
    steps = json.loads((out / "summary.json").read_text())["steps"]
    assert [s["view"] for s in steps] == [1, 7, 6]  # the highest open index, 8 recorded views
    assert main([*argv, "--strategy", "toy"]) == 2  # not among the package's strategies without its folder
    protocol = [
        "protocols=[active]",
        "++plugins.active.strategies=[toy,random]",
        f"++plugins.active.strategy_dirs=[{TOY_STRATEGIES}]",
        "++plugins.active.views=2",
        "++plugins.active.scales=[1.0]",
    ]
    tables = (_eval(protocol, run, tmp_path) / "tables.md").read_text()
    rows = [line.split("|")[3].strip() for line in tables.splitlines() if line.startswith("| Ours")]
    assert {"toy", "random"} <= set(rows)


def test_a_fusion_rule_from_the_tests_folder_is_the_sweep_row_of_eval(sphere_world, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(TOY_FUSION_CONF.parent))
    monkeypatch.setenv("USHAPE_ROOT", str(tmp_path))
    run = fit_sphere_run(sphere_world, tmp_path)
    out = _eval(
        ["protocols=[single_view]", "fusion=toy", f"hydra.searchpath=[file://{TOY_FUSION_CONF}]"], run, tmp_path
    )
    (row,) = json.loads((out / "eval_row.json").read_text())
    assert row["fusion"] == "first-view" and 0 <= row["multi_view_iou"] <= 1
