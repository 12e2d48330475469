"""Configs are checked once composed, before any work: bad values named at once, no traceback, no empty folder."""

import re
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from PIL import Image
from repo_commands import run_command

from ushape.evaluation.command import run_eval
from ushape.reconstruction.cli import main as reconstruct_main
from ushape.training.validation import ConfigError, check_config

REPO = Path(__file__).resolve().parents[2]


def _compose(overrides, config="train"):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        return compose(config, overrides=overrides)


@pytest.mark.parametrize(
    "override, named",
    [
        ("crop.min_scale=0", "crop.min_scale=0"),
        ("crop.min_scale=1.5", "crop.min_scale=1.5"),
        ("crop.min_scale=-1", "crop.min_scale=-1"),
        ("stage=foo", "stage='foo'"),
        ("fusion=bayesian_k", None),
        ("stage2.max_epochs=0", "stage2.max_epochs=0"),
        ("data.n_train=0", "data.n_train=0 must be an integer >= 1"),
        ("encoder.latent_size=32", "encoder.latent_size=32 but decoder.latent_size=64"),
        ("data=pix3d", "is for evaluation only"),
        ("decoder.latent_size=32", None),  # the encoder's size follows the decoder's
    ],
)
def test_bad_values_are_named_before_anything_runs(override, named):
    """crop.min_scale=0 used to be rejected only at the first training batch, a minute in."""
    cfg = _compose([override])
    if named is None:
        check_config(cfg)  # a good config passes
        return
    with pytest.raises(ConfigError, match=named.replace("[", r"\[")):
        check_config(cfg)


def test_eval_checks_its_config_before_looking_for_runs(tmp_path, capsys):
    cfg = _compose(["crop.min_scale=0", "fusion=bayesian_k", "fusion.k=0", f"paths.root_dir={tmp_path}"], "eval")
    with pytest.raises(SystemExit) as stop:
        run_eval(cfg)
    assert stop.value.code == 2
    assert re.search(r"^error: .*crop.min_scale=0 .*; fusion.k=0 must be an integer >= 1", capsys.readouterr().err)


def test_reconstruct_with_k_0_is_one_line_not_a_traceback(tmp_path, capsys):
    """Hydra wrapped BayesianKFusion's ValueError in a 34-line traceback; the model was not even needed."""
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "v.png")
    code = reconstruct_main([str(tmp_path / "v.png"), "--fusion", "bayesian_k", "--k", "0", "--root", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and "k must be an integer >= 1" in err, err


def test_a_failed_run_leaves_no_folder(tmp_path):
    """`train.py stage=foo` printed a traceback and left an empty run folder behind."""
    result = run_command(tmp_path, "train.py", "stage=foo", "crop.min_scale=1.5", timeout=300)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "error: invalid config, nothing was run: stage='foo'" in result.stderr
    assert "crop.min_scale=1.5 must be a number in (0, 1]" in result.stderr
    assert list(tmp_path.rglob("*")) == [tmp_path / "outputs"]
