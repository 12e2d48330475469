"""Which precision the decoder's inference runs in: "fp32", "bf16", or "auto" (bf16 where it is faster);
and whether training autocasts to bf16 (`training_bf16`: true, false or "auto", by the same rule).

bf16 surely pays where the hardware multiplies bf16 matrices natively: Intel CPUs with AMX
(amx_bf16 and amx_tile; 3-4x faster than fp32 on the 8x512 decoder) and CUDA devices of compute
capability 8.0 or newer (Ampere on). Elsewhere it depends on the CPU: bf16 autocast measured
1.5-1.8x slower than fp32 on an Intel avx512_bf16 CPU without AMX and 7-9x on an AVX2 one, while
the decoder folded in bf16 ran its field 2.2x faster than fp32 on an AMD EPYC with avx512_bf16.
So "auto" keeps fp32 without AMX (it is never slower than fp32), and `bf16` can be asked for on a
CPU where it is measured faster (bench.py's precision rows). "auto" is resolved once, where a command starts
(reconstruct.py, eval.py, bench.py), and what it resolved to is passed down as the `bf16` flag of
the decoding functions and recorded in the command's outputs.

AMX is read from `torch.cpu.get_capabilities()` (torch >= 2.8: the cpuinfo flags torch itself
dispatches on). On an older torch, or a build whose mapping lacks the AMX keys, the flags of
/proc/cpuinfo are read instead (Linux only; elsewhere no AMX is assumed, so "auto" stays fp32).
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import Mapping

import torch

log = logging.getLogger(__name__)

PRECISIONS = ("auto", "fp32", "bf16")
AMX_FLAGS = ("amx_bf16", "amx_tile")
CPUINFO = Path("/proc/cpuinfo")
# Compute capability from which CUDA devices have bf16 tensor cores (A100 is 8.0); older ones emulate it.
CUDA_BF16_CAPABILITY = (8, 0)


def check_precision(precision: str) -> str:
    """The precision itself, or a ValueError naming the choices."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    return precision


def cpu_flags(capabilities: Mapping | None = None, cpuinfo: Path = CPUINFO) -> dict[str, bool]:
    """{flag: present} for AMX_FLAGS: from torch's capabilities where they name them, else /proc/cpuinfo."""
    if capabilities is None:
        get = getattr(getattr(torch, "cpu", None), "get_capabilities", None)
        capabilities = get() if callable(get) else {}
    if all(flag in capabilities for flag in AMX_FLAGS):
        return {flag: bool(capabilities[flag]) for flag in AMX_FLAGS}
    try:
        text = cpuinfo.read_text()
    except OSError:
        return dict.fromkeys(AMX_FLAGS, False)
    flags = set()
    for line in text.splitlines():
        if line.startswith("flags"):
            flags.update(line.partition(":")[2].split())
    return {flag: flag in flags for flag in AMX_FLAGS}


def bf16_is_faster(device: torch.device | str = "cpu", capabilities: Mapping | None = None) -> tuple[bool, str]:
    """(whether bf16 runs faster than fp32 on `device`, why), as "auto" decides it."""
    device = torch.device(device)
    if device.type == "cpu":
        flags = cpu_flags(capabilities)
        if all(flags.values()):
            return True, "CPU with AMX (amx_bf16, amx_tile)"
        missing = ", ".join(flag for flag, present in flags.items() if not present)
        return False, f"CPU without AMX ({missing} absent): no native bf16 matrix unit, fp32 is kept"
    if device.type == "cuda":
        capability = tuple(torch.cuda.get_device_capability(device))
        shown = ".".join(map(str, capability))
        if capability >= CUDA_BF16_CAPABILITY:
            return True, f"CUDA device of compute capability {shown} (bf16 tensor cores)"
        return False, f"CUDA device of compute capability {shown} (< 8.0: no bf16 tensor cores)"
    return False, f"{device.type} device: bf16 is only chosen for AMX CPUs and CUDA devices"


def resolve_precision(
    precision: str, device: torch.device | str = "cpu", capabilities: Mapping | None = None
) -> tuple[str, str]:
    """("fp32" | "bf16", why) for a requested precision on `device`; "auto" asks `bf16_is_faster`. Logged."""
    check_precision(precision)
    if precision == "auto":
        faster, why = bf16_is_faster(device, capabilities)
        resolved = "bf16" if faster else "fp32"
    else:
        resolved, why = precision, "asked for"
    log.info("precision %s -> %s on %s: %s", precision, resolved, torch.device(device), why)
    return resolved, why


def training_bf16(bf16: bool | str, device: torch.device | str = "cpu") -> bool:
    """Whether a training step (stage 1, stage 2, latent optimisation) autocasts to bf16 on `device`.

    True / False as asked; "auto" where `bf16_is_faster` (AMX CPUs, CUDA >= 8.0). Autocast keeps the
    weights and the optimiser's state in fp32 (the master copy); only the matrix products run in bf16.
    """
    if isinstance(bf16, bool):
        return bf16
    if bf16 != "auto":
        raise ValueError(f"bf16 must be true, false or 'auto', got {bf16!r}")
    return _auto_bf16(str(torch.device(device)))


@functools.lru_cache(maxsize=None)
def _auto_bf16(device: str) -> bool:
    """`bf16_is_faster` once per device (a training step asks every step); logged when it is decided."""
    faster, why = bf16_is_faster(device)
    log.info("training bf16 auto -> %s on %s: %s", "bf16" if faster else "fp32", device, why)
    return faster


def accelerator_device(accelerator: str) -> torch.device:
    """The device a Lightning `accelerator` name trains on ("auto": CUDA where there is one)."""
    if accelerator in ("gpu", "cuda") or (accelerator == "auto" and torch.cuda.is_available()):
        return torch.device("cuda")
    return torch.device("cpu" if accelerator == "auto" else accelerator)
