"""Image augmentations of stage 2 on premultiplied RGBA tensors [4, H, W] in [0, 1].

The paper trains with random resize, horizontal flip and random backgrounds (clips from SUN);
its corrupted-views protocol crops each test view to a random area in [min_scale, 1]. Renders
keep the object mask in alpha, so crops and flips act on RGBA and the background is composited
last: `mask_mode="gt_mask"` puts the object on a plain background (the background removed by a
ground-truth mask), `mask_mode="none"` keeps a (random) background in the picture.

Every random step takes an optional torch.Generator, so evaluation can be made repeatable.
"""

from __future__ import annotations

import math
import warnings
import zlib
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image, ImageOps, UnidentifiedImageError
from torch import Tensor

MASK_MODES = ("gt_mask", "none")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")
CROP_RATIO = (3 / 4, 4 / 3)  # aspect range (w/h) of random crops, torchvision's RandomResizedCrop default


# Pillow modes holding one channel of integers wider than 8 bits. PNG's 16-bit grey opens as I;16
# (older Pillow: I); convert("RGBA") clips those at 255, so every real value read as white.
_WIDE_GREY_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I")
_WIDE_GREY_WHITE = 65535.0


def read_image(path: str | Path) -> np.ndarray:
    """An image file as straight (not premultiplied) RGBA float32 [H, W, 4] in [0, 1], upright.

    Every mode Pillow reads keeps its real content: 16-bit grey is scaled by 65535 (not clipped),
    palette/LA/CMYK/1-bit go through Pillow's own conversion, and a JPEG's EXIF orientation is
    applied. Modes with no fixed white level (32-bit float) are refused with a ValueError naming them,
    and so are images of more pixels than Pillow's MAX_IMAGE_PIXELS (89.5 Mpx, e.g. 9459 x 9459).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"image {path} does not exist")
    try:
        with _open_within_limit(path) as img:
            img = ImageOps.exif_transpose(img)
            if img.mode in _WIDE_GREY_MODES:
                grey = np.asarray(img, dtype=np.float32)
                if grey.min() < 0 or grey.max() > _WIDE_GREY_WHITE:
                    raise ValueError(f"{img.mode} values span [{grey.min():g}, {grey.max():g}], outside 16 bits")
                grey = grey / _WIDE_GREY_WHITE
                return np.stack([grey, grey, grey, np.ones_like(grey)], axis=-1)
            if img.mode == "F":
                raise ValueError("mode F (32-bit float) has no fixed white level; save it as 8- or 16-bit")
            return np.asarray(img.convert("RGBA"), dtype=np.float32) / 255.0
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as err:
        # Gigabytes to read, for a model that sees a few hundred pixels a side.
        raise ValueError(
            f"image {path} has more than {Image.MAX_IMAGE_PIXELS:,} pixels, Pillow's limit against "
            f"decompression bombs ({err}); downscale it to a few hundred pixels a side"
        ) from err
    except ValueError as err:
        raise ValueError(f"image {path} cannot be read as RGBA: {err}") from err
    except (UnidentifiedImageError, OSError, SyntaxError) as err:
        raise ValueError(f"image {path} is corrupt or unreadable ({err}); re-render or delete it") from err


def _open_within_limit(path: Path) -> Image.Image:
    """Image.open, raising DecompressionBombWarning too (Pillow only warns between MAX_IMAGE_PIXELS and twice it)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        return Image.open(path)


def premultiply(straight: np.ndarray) -> Tensor:
    """Straight RGBA float [H, W, 4] in [0, 1] -> premultiplied RGBA float [4, H, W]."""
    rgba = torch.from_numpy(np.ascontiguousarray(straight, dtype=np.float32)).permute(2, 0, 1).contiguous()
    rgba[:3] *= rgba[3:]
    return rgba


def load_rgba(path: str | Path) -> Tensor:
    """Read an image file as premultiplied RGBA float [4, H, W] in [0, 1] (opaque if it has no alpha)."""
    return premultiply(read_image(path))


def _uniform(low: float, high: float, generator: torch.Generator | None) -> float:
    return low + (high - low) * torch.rand((), generator=generator).item()


def _randint(high: int, generator: torch.Generator | None) -> int:
    return int(torch.randint(high, (), generator=generator).item())


def crop_box(
    height: int, width: int, min_scale: float, ratio: Sequence[float], generator: torch.Generator | None
) -> tuple[int, int, int, int]:
    """(top, left, h, w) covering an area fraction in [min_scale, 1] with aspect w/h in `ratio` (log-uniform)."""
    if not 0 < min_scale <= 1:
        raise ValueError(f"min_scale must be in (0, 1], got {min_scale}")
    area = height * width
    log_ratio = (math.log(ratio[0]), math.log(ratio[1]))
    for _ in range(10):
        target = area * _uniform(min_scale, 1.0, generator)
        aspect = math.exp(_uniform(*log_ratio, generator))
        w, h = round(math.sqrt(target * aspect)), round(math.sqrt(target / aspect))
        if 0 < w <= width and 0 < h <= height:
            return _randint(height - h + 1, generator), _randint(width - w + 1, generator), h, w
    # As torchvision does after 10 misses: the largest centred box of a legal aspect ratio.
    aspect = min(max(width / height, ratio[0]), ratio[1])
    h, w = (height, round(height * aspect)) if width / height > aspect else (round(width / aspect), width)
    h, w = min(h, height), min(w, width)
    return (height - h) // 2, (width - w) // 2, h, w


def random_crop(
    image: Tensor,  # [C, H, W]
    min_scale: float,
    generator: torch.Generator | None = None,
    ratio: Sequence[float] = CROP_RATIO,
) -> Tensor:
    """A random crop covering an area fraction in [min_scale, 1] of the image (not resized). -> [C, h, w]."""
    top, left, h, w = crop_box(image.shape[-2], image.shape[-1], min_scale, ratio, generator)
    return image[..., top : top + h, left : left + w]


def resize(image: Tensor, size: int) -> Tensor:
    """Bilinear, antialiased resize of [C, H, W] to [C, size, size]."""
    if image.shape[-2:] == (size, size):
        return image
    return F.interpolate(image[None], size=(size, size), mode="bilinear", antialias=True, align_corners=False)[0]


class RandomResizedCrop:
    """`random_crop` with area in [min_scale, 1], then resize to size x size."""

    def __init__(self, size: int, min_scale: float = 0.5, ratio: Sequence[float] = CROP_RATIO) -> None:
        self.size, self.min_scale, self.ratio = size, min_scale, tuple(ratio)

    def __call__(self, image: Tensor, generator: torch.Generator | None = None) -> Tensor:
        return resize(random_crop(image, self.min_scale, generator, self.ratio), self.size)


class Resize:
    def __init__(self, size: int) -> None:
        self.size = size

    def __call__(self, image: Tensor, generator: torch.Generator | None = None) -> Tensor:
        return resize(image, self.size)


class RandomHorizontalFlip:
    def __init__(self, p: float = 0.5) -> None:
        self.p = p

    def __call__(self, image: Tensor, generator: torch.Generator | None = None) -> Tensor:
        return image.flip(-1) if torch.rand((), generator=generator).item() < self.p else image


def _random_colour(generator: torch.Generator | None) -> Tensor:
    return torch.rand(3, 1, 1, generator=generator)


def procedural_background(height: int, width: int, generator: torch.Generator | None = None) -> Tensor:
    """A random texture [3, H, W] in [0, 1]: solid colour, linear gradient, smooth noise, stripes or checker."""
    kind = _randint(5, generator)
    ys = torch.linspace(0, 1, height).view(1, height, 1)
    xs = torch.linspace(0, 1, width).view(1, 1, width)
    a, b = _random_colour(generator), _random_colour(generator)
    if kind == 0:
        return a.expand(3, height, width).clone()
    if kind == 1:
        angle = _uniform(0, 2 * math.pi, generator)
        t = math.cos(angle) * xs + math.sin(angle) * ys
        t = (t - t.min()) / (t.max() - t.min()).clamp_min(1e-6)
        return a + (b - a) * t
    if kind == 2:
        cells = 2 + _randint(14, generator)
        coarse = torch.rand(1, 3, cells, cells, generator=generator)
        return F.interpolate(coarse, size=(height, width), mode="bicubic", align_corners=False)[0].clamp(0, 1)
    period = _uniform(0.05, 0.3, generator)
    if kind == 3:
        angle = _uniform(0, math.pi, generator)
        phase = (math.cos(angle) * xs + math.sin(angle) * ys) / period
        return torch.where(phase.floor() % 2 == 0, a, b)
    checker = ((xs / period).floor() + (ys / period).floor()) % 2 == 0
    return torch.where(checker, a, b)


class FolderBackgrounds:
    """Random crops of the images in a folder (e.g. SUN397), resized to the requested size."""

    def __init__(self, background_dir: str | Path, min_scale: float = 0.1) -> None:
        root = Path(background_dir)
        if not root.is_dir():
            raise FileNotFoundError(f"background_dir {root} is not a folder of images")
        self.files = sorted(p for p in root.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise FileNotFoundError(f"background_dir {root} holds no {'/'.join(IMAGE_SUFFIXES)} images")
        self.min_scale = min_scale

    def __call__(self, height: int, width: int, generator: torch.Generator | None = None) -> Tensor:
        image = load_rgba(self.files[_randint(len(self.files), generator)])[:3]
        crop = random_crop(image, self.min_scale, generator, ratio=(width / height, width / height))
        return F.interpolate(crop[None], size=(height, width), mode="bilinear", antialias=True, align_corners=False)[0]


class CompositeBackground:
    """Premultiplied RGBA [4, H, W] -> RGB [3, H, W] over a plain (gt_mask) or random (none) background."""

    def __init__(
        self,
        mask_mode: str = "gt_mask",
        background_value: float = 1.0,
        background_dir: str | Path | None = None,
    ) -> None:
        if mask_mode not in MASK_MODES:
            raise ValueError(f"mask_mode must be one of {MASK_MODES}, got {mask_mode!r}")
        self.mask_mode, self.background_value = mask_mode, background_value
        self.folder = FolderBackgrounds(background_dir) if background_dir is not None else None

    def background(self, height: int, width: int, generator: torch.Generator | None) -> Tensor:
        if self.mask_mode == "gt_mask":
            return torch.full((3, height, width), float(self.background_value))
        if self.folder is not None:
            return self.folder(height, width, generator)
        return procedural_background(height, width, generator)

    def __call__(self, image: Tensor, generator: torch.Generator | None = None) -> Tensor:
        if image.shape[0] != 4:
            raise ValueError(f"background compositing needs RGBA [4, H, W], got {tuple(image.shape)}")
        rgb, alpha = image[:3], image[3:]
        return (rgb + (1 - alpha) * self.background(image.shape[-2], image.shape[-1], generator)).clamp(0, 1)


class Compose:
    """Apply transforms in order, handing each the same generator."""

    def __init__(self, transforms: Sequence[Callable[..., Tensor]]) -> None:
        self.transforms = list(transforms)

    def __call__(self, image: Tensor, generator: torch.Generator | None = None) -> Tensor:
        for transform in self.transforms:
            image = transform(image, generator)
        return image


def build_transform(
    image_size: int,
    train: bool,
    min_scale: float = 0.5,
    mask_mode: str = "gt_mask",
    background_dir: str | Path | None = None,
    flip: bool = True,
    background_value: float = 1.0,
) -> Compose:
    """Training: random resized crop, flip, background. Evaluation: resize and background only."""
    composite = CompositeBackground(mask_mode, background_value, background_dir)
    if not train:
        return Compose([Resize(image_size), composite])
    steps: list[Callable[..., Tensor]] = [RandomResizedCrop(image_size, min_scale)]
    if flip:
        steps.append(RandomHorizontalFlip())
    return Compose([*steps, composite])


def view_seed(seed: int, shape_id: str, view: int) -> int:
    """A generator seed that depends only on (seed, shape id, view): stable across runs and processes."""
    return (seed * 1_000_003 + zlib.crc32(f"{shape_id}/{view}".encode())) % (2**63 - 1)


def corrupted_view(
    rgba: Tensor,
    image_size: int,
    min_scale: float,
    seed: int,
    mask_mode: str = "gt_mask",
    background_value: float = 1.0,
) -> Tensor:
    """Premultiplied RGBA [4, H, W] -> RGB [3, S, S]: a random crop of area in [min_scale, 1], resized, composited.

    min_scale = 1 keeps the whole image (the uncorrupted protocol). Deterministic in `seed`.
    """
    generator = torch.Generator().manual_seed(seed)
    top, left, h, w = crop_box(rgba.shape[-2], rgba.shape[-1], min_scale, CROP_RATIO, generator)
    image = resize(rgba[..., top : top + h, left : left + w], image_size)
    return CompositeBackground(mask_mode, background_value)(image, generator)


def corrupted_box(height: int, width: int, min_scale: float, seed: int) -> tuple[int, int, int, int]:
    """The crop (top, left, h, w) `corrupted_view(image, ..., min_scale, seed)` takes of a height x width image:
    its generator's first draws, so whoever needs a view's evaluation crop (which parts it removed, a
    refinement on what it shows) gets that very box."""
    return crop_box(height, width, min_scale, CROP_RATIO, torch.Generator().manual_seed(seed))
