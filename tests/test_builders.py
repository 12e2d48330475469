"""Configs with a `_target_` build that class with the run's own arguments; plain mappings build the default."""

import lightning as L
import pytest
from lightning.pytorch.callbacks import EarlyStopping, LearningRateMonitor
from omegaconf import OmegaConf

from ushape.builders import build, build_all


class Recorder:
    def __init__(self, **kwargs):
        self.kwargs = kwargs


def test_a_target_is_built_with_the_config_and_the_run_time_arguments():
    config = OmegaConf.create({"_target_": "test_builders.Recorder", "a": 1, "nested": {"_target_": "x.Y", "b": 2}})
    marker = object()
    built = build(config, dict, logger=marker)
    assert isinstance(built, Recorder)
    assert built.kwargs == {"a": 1, "nested": {"_target_": "x.Y", "b": 2}, "logger": marker}
    assert type(built.kwargs["nested"]) is dict  # passed on as a plain dict, not built


def test_a_plain_mapping_builds_the_default():
    assert build({"a": 1}, Recorder, b=2).kwargs == {"a": 1, "b": 2}
    assert build(None, Recorder).kwargs == {}


def test_the_trainer_config_builds_a_lightning_trainer(tmp_path):
    trainer = build(
        {"_target_": "lightning.pytorch.Trainer", "accelerator": "cpu", "max_epochs": 1, "enable_progress_bar": False},
        L.Trainer,
        default_root_dir=str(tmp_path),
        logger=False,
    )
    assert isinstance(trainer, L.Trainer) and trainer.max_epochs == 1


def test_callbacks_are_built_in_order_and_null_entries_dropped():
    configs = OmegaConf.create(
        {
            "lr_monitor": {"_target_": "lightning.pytorch.callbacks.LearningRateMonitor", "logging_interval": "step"},
            "off": None,
            "early_stopping": {"_target_": "lightning.pytorch.callbacks.EarlyStopping", "monitor": "val/loss"},
        }
    )
    built = build_all(configs)
    assert [type(c) for c in built] == [LearningRateMonitor, EarlyStopping]
    assert build_all(None) == []


def test_an_unknown_target_says_which():
    with pytest.raises(ImportError, match="no_such_module"):
        build({"_target_": "no_such_module.Thing"}, dict)
