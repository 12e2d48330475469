"""ushape: uncertainty-aware 3D object reconstruction from images with a neural shape prior.

The packages follow the data's way (the order is in the README's "Package layout" and checked by
tests/test_import_flow.py); `ushape <command>` (ushape.cli) runs everything.
"""

from ushape.torchvision_cpu import ensure_torchvision_importable

# Must run before anything imports torchvision (lightning does, through torchmetrics).
ensure_torchvision_importable()

__version__ = "0.1.0"
