"""train.py writes what bf16 "auto" means on the trainer's device over the config before anything reads it."""

import pytest
from omegaconf import OmegaConf

from ushape.decoder import precision
from ushape.errors import InputError
from ushape.training.train import TRAINING_BF16_KEYS, resolve_training_bf16


def _cfg(value, accelerator="cpu"):
    return OmegaConf.create(
        {
            "trainer": {"accelerator": accelerator},
            "stage1": {"module": {"bf16": value}, "latent_optim": {"bf16": value}},
            "stage2": {"module": {"bf16": value}},
        }
    )


@pytest.mark.parametrize("amx", [True, False])
def test_auto_becomes_what_the_device_decides_and_explicit_values_stay(monkeypatch, amx):
    monkeypatch.setattr(precision, "_auto_bf16", lambda device: amx)
    cfg = _cfg("auto")
    resolve_training_bf16(cfg)
    assert [OmegaConf.select(cfg, key) for key in TRAINING_BF16_KEYS] == [amx] * 3
    for value in (True, False):
        cfg = _cfg(value)
        resolve_training_bf16(cfg)
        assert [OmegaConf.select(cfg, key) for key in TRAINING_BF16_KEYS] == [value] * 3


def test_a_missing_switch_is_left_alone_and_a_bad_one_names_its_key():
    cfg = OmegaConf.create({"trainer": {"accelerator": "cpu"}, "stage1": {"module": {}}})
    resolve_training_bf16(cfg)
    assert OmegaConf.select(cfg, "stage1.module.bf16") is None
    with pytest.raises(InputError, match="stage1.module.bf16: bf16 must be true, false or 'auto'"):
        resolve_training_bf16(_cfg("fp16"))
