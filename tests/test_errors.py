"""The one error path: which errors are bad input, their one-line messages, and HYDRA_FULL_ERROR's switch."""

import os

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import InstantiationException
from hydra.utils import instantiate

from ushape.errors import (
    FULL_ERROR,
    InputError,
    MissingInputError,
    bad_input_exit,
    describe,
    reporting_bad_input,
    unknown_key,
    unknown_option,
)
from ushape.workspace import CONFIG_DIR


def _composition_error(overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        with pytest.raises(Exception) as raised:
            compose("train", overrides=overrides)
    return raised.value


def test_an_unknown_option_lists_the_choices_and_the_close_match():
    assert unknown_option("loss/nl", ["es", "l2", "nll"]) == (
        "loss=nl: no such option of the config group loss; choose one of es, l2, nll (did you mean loss=nll?); "
        "a new option is a file conf/loss/<name>.yaml"
    )
    assert "did you mean" not in unknown_option("category/sofas", ["chairs", "tables"])


def test_an_unknown_key_gives_its_close_match_and_the_keys_there():
    line = unknown_key("stage2.max_epoch", ["max_epochs", "data"], "3")
    assert line == (
        "stage2.max_epoch=3: stage2 has no key max_epoch; did you mean stage2.max_epochs? "
        "(its keys: max_epochs, data); +stage2.max_epoch=3 adds a new key"
    )
    assert unknown_key("lossx", ["loss"], None).startswith("lossx=...: the config has no key lossx; did you mean loss?")


def test_hydra_composition_errors_are_described_from_the_exception():
    assert describe(_composition_error(["loss=bogus"])).startswith("loss=bogus: no such option")
    assert "did you mean stage2.max_epochs?" in describe(_composition_error(["stage2.max_epoch=3"]))
    assert describe(_composition_error(["stage2.max_epochs=[1"])).startswith("cannot read the override")


def test_a_targets_input_error_is_named_with_its_key():
    """Hydra wraps what a constructor raises; the InputError under it is the message."""
    config = {"_target_": "ushape.data.real.shapenet.synset_id", "category": "sofas"}
    with pytest.raises(InstantiationException) as raised:
        instantiate(config)
    assert describe(raised.value).startswith("config: unknown ShapeNet category 'sofas'")
    assert describe(RuntimeError("a bug")) is None and describe(ValueError("maybe a bug")) is None
    assert isinstance(MissingInputError("x"), FileNotFoundError) and isinstance(MissingInputError("x"), InputError)


def test_bad_input_is_one_line_and_exit_2_unless_hydra_full_error(monkeypatch, capsys):
    monkeypatch.delenv(FULL_ERROR, raising=False)
    with pytest.raises(SystemExit) as stop:
        with reporting_bad_input():
            assert os.environ[FULL_ERROR] == "1"  # so that Hydra raises its errors to us
            raise InputError("data.root=/x does not exist")
    assert stop.value.code == 2 and capsys.readouterr().err == "error: data.root=/x does not exist\n"
    assert FULL_ERROR not in os.environ  # restored
    with pytest.raises(KeyError):  # not bad input: the traceback stays
        with reporting_bad_input():
            raise KeyError("bug")
    monkeypatch.setenv(FULL_ERROR, "1")
    with pytest.raises(InputError):
        with reporting_bad_input():
            raise InputError("shown with its traceback")
    assert bad_input_exit(InputError("x")) is None


def test_a_target_that_does_not_import_is_named_with_its_key():
    """eval.py methods=[{_target_: ushape.nope.Thing}] ended in a 93-line traceback."""
    with pytest.raises(InstantiationException) as caught:
        instantiate({"methods": [{"_target_": "ushape.nope.Thing"}]}).methods
    line = describe(caught.value)
    assert line is not None and "ushape.nope.Thing: no such class or function can be imported" in line, line


def test_a_missing_dataset_folder_is_named_before_the_config_is_printed(tmp_path):
    from repo_commands import run_command

    missing = tmp_path / "no_voxels"
    result = run_command(tmp_path, "train.py", "data=r2n2", f"data.voxels_root={missing}", timeout=300)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert f"data.voxels_root={missing} is not a folder" in result.stderr
    assert "stage1" not in result.stdout + result.stderr  # the config tree was not printed
