"""The `ushape` command's dispatch: every command listed, unknown ones refused with the list."""

import importlib

import pytest

from ushape.cli import COMMANDS, main, usage
from ushape.training.interrupts import resume_command


def test_every_command_has_a_main():
    for name, (module, _) in COMMANDS.items():
        assert callable(importlib.import_module(module).main), name


def test_help_lists_the_commands(capsys):
    assert main([]) == 0 and main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in COMMANDS)


def test_an_unknown_command_is_refused_with_the_list(capsys):
    assert main(["trian"]) == 2
    assert "unknown command 'trian'" in capsys.readouterr().err and "reconstruct" in usage()


def test_an_argparse_command_gets_its_arguments(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["gather", "--help"])
    assert exit_.value.code == 0 and "sweep" in capsys.readouterr().out


def test_a_stopped_run_is_resumed_the_way_it_was_started(tmp_path):
    assert resume_command(["ushape train", "loss=nll"], tmp_path) == f"ushape train loss=nll hydra.run.dir={tmp_path}"
    assert resume_command(["train.py", "loss=nll"], tmp_path) == f"python train.py loss=nll hydra.run.dir={tmp_path}"
