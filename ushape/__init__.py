"""ushape: uncertainty-aware 3D object reconstruction from images with a neural shape prior.

The data's way through the package:
shapes -> data (SDF samples, renders) -> decoder (stage 1) -> encoder (stage 2)
-> fusion -> propagation -> mesh -> evaluation.
"""

from ushape.torchvision_cpu import ensure_torchvision_importable

# Must run before anything imports torchvision (lightning does, through torchmetrics).
ensure_torchvision_importable()

__version__ = "0.1.0"
