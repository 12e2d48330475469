"""Protocols as plug-ins: one from the tests folder runs through eval.py beside the paper's and adds its table."""

import csv
import json
import warnings
from pathlib import Path

import pytest
from eval_world import fit_sphere_run
from hydra import compose, initialize_config_dir

from ushape.evaluation.command import run_eval
from ushape.evaluation.plugin import available, load_protocols
from ushape.evaluation.settings import PAPER_PROTOCOLS

CONF = str(Path(__file__).resolve().parents[2] / "conf")
TOY = Path(__file__).resolve().parent / "toy_protocols"


def test_every_protocol_is_a_yaml_file_that_builds_its_class():
    names = sorted(available())
    assert names == sorted([*PAPER_PROTOCOLS, "active", "view_calibration"])
    assert [p.name for p in load_protocols(names)] == names
    with pytest.raises(ValueError, match=r"unknown protocols \['toy'\].*protocol_dirs"):
        load_protocols(["toy"])
    (toy,) = load_protocols(["toy"], dirs=[TOY])
    assert toy.weight == 0.5
    (toy,) = load_protocols(["toy"], {"toy": {"weight": 2.0}}, [TOY])  # eval.py ++plugins.toy.weight=2
    assert toy.weight == 2.0 and toy.config() == {"_target_": "toy_protocol.Toy", "weight": 2.0}
    with pytest.raises(TypeError, match="has no setting 'wieght'"):
        load_protocols(["toy"], {"toy": {"wieght": 2.0}}, [TOY])
    with pytest.raises(ValueError, match="plugins.depht sets the settings of an unknown protocol"):
        load_protocols(["depth"], {"depht": {"size": 8}})


def test_a_protocol_and_a_method_from_the_tests_folder_run_through_eval_and_write_their_rows(
    sphere_world, tmp_path, monkeypatch
):
    monkeypatch.setenv("USHAPE_ROOT", str(tmp_path))
    run_dir = fit_sphere_run(sphere_world, tmp_path)
    out = tmp_path / "eval"
    overrides = [
        f"runs=[{run_dir}]",
        f"cache_dir={tmp_path / 'cache'}",
        f"out_dir={out}",
        "tensorboard=false",
        "protocols=[single_view,toy]",
        f"protocol_dirs=[{TOY}]",
        "protocol.resolution=24",
        "protocol.n_points=128",
        "protocol.single_view_views=2",
        "showcase.shapes=0",
        "++plugins.toy.weight=0.25",  # a protocol's own setting, by its name
        "methods=[{_target_:toy_method.Same}]",
    ]
    with initialize_config_dir(CONF, version_base="1.3"):
        cfg = compose("eval", overrides=overrides)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_eval(cfg)
    assert "### Table T: toy" in (out / "tables.md").read_text()
    with open(out / "tablet.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows == [  # 2 shapes x 2 views, weight 0.25; the method's row beside the encoder's
        {"encoder": "nll", "views": "4", "weighted": "1.0"},
        {"encoder": "nll+same", "views": "4", "weighted": "1.0"},
    ]
    assert (out / "toy.csv").is_file()  # its own rows, by its csvs hook
    result = json.loads((out / "results.json").read_text())
    single = [r for r in result["records"] if r["protocol"] == "single"]
    assert [sum(r["encoder"] == e for r in single) for e in ("nll", "nll+same")] == [4, 4]  # asked twice, scored once
    assert [r["iou"] for r in single[:4]] == [r["iou"] for r in single[4:]]  # the same codes, the same scores
    assert result["runs"]["nll+same"]["run_dir"] == str(run_dir)
