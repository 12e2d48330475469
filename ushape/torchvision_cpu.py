"""Make the CUDA-built torchvision 0.28 wheel importable next to a CPU build of torch 2.13.

The one place this is solved. torchvision 0.28.0 is the only release for torch 2.13.0, and
PyPI ships it built against CUDA. With a CPU torch its compiled extension (``_C``) cannot
load, and then ``torchvision._meta_registrations`` fails at import with
``operator torchvision::nms does not exist``; ``import lightning`` fails with it, because
torchmetrics imports torchvision. Declaring the schemas of the two operators that the meta
registrations refer to (``nms`` and ``qnms``) before torchvision is imported lets models
and transforms import and run. The detection ops themselves (nms, roi_align, ...) remain
unavailable, and ushape does not use them.

``ushape/__init__.py`` calls :func:`ensure_torchvision_importable` first thing, so
``import ushape`` before ``import lightning`` or ``import torchvision`` is all a user needs.
Where the extension loads (a matching CUDA machine) nothing is declared.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import torch

_SCHEMAS = {
    "nms": "nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
    "qnms": "qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
}
_library: torch.library.Library | None = None  # kept alive: dropping it unregisters the ops


def _extension_loads() -> bool:
    spec = importlib.util.find_spec("torchvision")
    if spec is None or spec.origin is None:
        return True  # no torchvision: nothing to repair
    candidates = sorted(Path(spec.origin).parent.glob("_C*.so"))
    for lib in candidates:
        try:
            torch.ops.load_library(str(lib))
            return True
        except (OSError, RuntimeError):
            return False
    return False


def ensure_torchvision_importable() -> bool:
    """Declare torchvision's nms/qnms schemas when its compiled ops cannot load; True if declared."""
    global _library
    if _library is not None or "torchvision" in sys.modules:
        return False
    if _extension_loads():
        return False
    if _has_schema("nms"):
        return False
    _library = torch.library.Library("torchvision", "DEF")
    for schema in _SCHEMAS.values():
        _library.define(schema)
    return True


def _has_schema(name: str) -> bool:
    try:
        getattr(torch.ops.torchvision, name)
        return True
    except (AttributeError, RuntimeError):
        return False
