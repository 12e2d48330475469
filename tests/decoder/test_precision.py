"""precision auto: bf16 on AMX CPUs and CUDA devices of compute capability >= 8.0, fp32 elsewhere (mocked hardware)."""

import logging

import pytest
import torch

from ushape.decoder import precision as P

AMX = {"amx_bf16": True, "amx_tile": True, "avx512_bf16": True}
NO_AMX = {"amx_bf16": False, "amx_tile": False, "avx512_bf16": True}  # this machine: an AMD EPYC
TILE_ONLY = {"amx_bf16": False, "amx_tile": True}


@pytest.mark.parametrize(
    ("capabilities", "expected"), [(AMX, "bf16"), (NO_AMX, "fp32"), (TILE_ONLY, "fp32"), ({"avx2": True}, "fp32")]
)
def test_auto_on_a_cpu_needs_both_amx_flags(capabilities, expected, tmp_path):
    no_cpuinfo = tmp_path / "missing"  # the fallback finds nothing, so only the mapping decides
    flags = P.cpu_flags(capabilities, no_cpuinfo)
    faster, why = P.bf16_is_faster("cpu", flags)
    assert ("bf16" if faster else "fp32") == expected
    assert ("without AMX" in why) == (expected == "fp32")


def test_auto_reads_torch_capabilities(monkeypatch):
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: AMX)
    assert P.resolve_precision("auto")[0] == "bf16"
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: NO_AMX)
    assert P.resolve_precision("auto")[0] == "fp32"


def test_cpuinfo_is_the_fallback_where_torch_names_no_amx_flags(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nflags\t\t: fpu avx2 avx512_bf16 amx_bf16 amx_tile amx_int8\n\nprocessor\t: 1\n")
    assert P.cpu_flags({}, cpuinfo) == {"amx_bf16": True, "amx_tile": True}
    cpuinfo.write_text("flags\t\t: fpu avx2 avx512f avx512_bf16\n")
    assert P.cpu_flags({"avx2": True}, cpuinfo) == {"amx_bf16": False, "amx_tile": False}
    assert P.cpu_flags({}, tmp_path / "absent") == {"amx_bf16": False, "amx_tile": False}


@pytest.mark.parametrize(("capability", "expected"), [((9, 0), "bf16"), ((8, 0), "bf16"), ((7, 5), "fp32")])
def test_auto_on_cuda_needs_compute_capability_8(monkeypatch, capability, expected):
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda device=None: capability)
    assert P.resolve_precision("auto", "cuda")[0] == expected


def test_explicit_choices_are_kept_and_other_devices_get_fp32(monkeypatch, caplog):
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: AMX)
    assert P.resolve_precision("fp32")[0] == "fp32"
    assert P.resolve_precision("bf16")[0] == "bf16"
    assert P.resolve_precision("auto", "meta")[0] == "fp32"
    with caplog.at_level(logging.INFO, logger="ushape.decoder.precision"):
        P.resolve_precision("auto")
    assert "precision auto -> bf16 on cpu" in caplog.text


def test_an_unknown_precision_names_the_choices():
    with pytest.raises(ValueError, match="auto.*fp32.*bf16"):
        P.resolve_precision("fp16")


@pytest.mark.parametrize(("capabilities", "auto"), [(AMX, True), (NO_AMX, False)])
def test_training_bf16_auto_follows_the_amx_rule_and_explicit_choices_stay(monkeypatch, capabilities, auto):
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: capabilities)
    P._auto_bf16.cache_clear()
    try:
        assert P.training_bf16("auto", "cpu") is auto
        assert P.training_bf16(True, "cpu") is True and P.training_bf16(False, "cpu") is False
    finally:
        P._auto_bf16.cache_clear()
    with pytest.raises(ValueError, match="true, false or 'auto'"):
        P.training_bf16("fp16", "cpu")


def test_an_accelerator_name_gives_its_device(monkeypatch):
    assert P.accelerator_device("cpu") == torch.device("cpu")
    assert P.accelerator_device("gpu") == torch.device("cuda") == P.accelerator_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert P.accelerator_device("auto") == torch.device("cpu")
