"""Gallery of synthetic shapes: a grid of shapes, each as a few renders on white, labelled with its style.

    ushape gallery --category chairs --n 16 --out outputs/gallery_chairs.png
    ushape gallery --category tables --root outputs/data/synthetic --n-train 32

Without --root the shapes are generated and rendered in memory (nothing cached); with
--root the world is built (or reused) there and its cached renders are shown.
"""

from __future__ import annotations

import argparse
import json
import math
import textwrap
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ushape import atomic
from ushape.data.cameras import metadata_to_cameras, sample_r2n2_views
from ushape.data.layout import WorldIndex
from ushape.data.rendering import on_white, render_views
from ushape.data.shading import part_colour_fn
from ushape.data.shape_artifacts import ShapeFactory, r2n2_frame
from ushape.data.world import SyntheticWorld, default_shape_factory, shape_seeds

LABEL_LINES = 4
LINE_HEIGHT = 12


def style_label(shape_id: str, style: dict[str, Any], chars_per_line: int) -> list[str]:
    """Up to LABEL_LINES lines: the shape id, then its style as compact key=value pairs."""

    def fmt(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.2f}"
        if isinstance(value, (list, tuple)):
            return "(" + ",".join(fmt(v) for v in value) + ")"
        return str(value)

    pairs = " ".join(f"{k}={fmt(v)}" for k, v in style.items())
    lines = [shape_id] + textwrap.wrap(pairs, chars_per_line)
    if len(lines) > LABEL_LINES:
        lines = lines[: LABEL_LINES - 1] + [lines[LABEL_LINES - 1][: chars_per_line - 3] + "..."]
    return lines


def compose_gallery(cells: Sequence[tuple[list[np.ndarray], list[str]]], columns: int) -> Image.Image:
    """One image: cells (renders [H,W,4] side by side, label lines below) in a grid."""
    if not cells:
        raise ValueError("nothing to show: the gallery needs at least one shape")
    h, w = cells[0][0][0].shape[:2]
    n_views = max(len(views) for views, _ in cells)
    cell_w, cell_h = n_views * w + 8, h + LABEL_LINES * LINE_HEIGHT + 8
    rows = math.ceil(len(cells) / columns)
    canvas = Image.new("RGB", (columns * cell_w, rows * cell_h), "white")
    draw, font = ImageDraw.Draw(canvas), ImageFont.load_default()
    for i, (views, lines) in enumerate(cells):
        x0, y0 = (i % columns) * cell_w, (i // columns) * cell_h
        for v, rgba in enumerate(views):
            canvas.paste(Image.fromarray(on_white(rgba)), (x0 + v * w, y0))
        for j, line in enumerate(lines):
            draw.text((x0 + 2, y0 + h + 2 + j * LINE_HEIGHT), line, fill=(40, 40, 40), font=font)
        draw.rectangle([x0, y0, x0 + cell_w - 5, y0 + cell_h - 5], outline=(225, 225, 225))
    return canvas


def cells_from_shapes(
    category: str,
    n: int,
    n_views: int,
    image_size: int,
    mesh_resolution: int,
    seed: int,
    factory: Optional[ShapeFactory] = None,
) -> list[tuple[list[np.ndarray], list[str]]]:
    """Gallery cells of n freshly generated shapes, rendered with R2N2-protocol cameras."""
    factory = factory or default_shape_factory(category)
    cells = []
    for s in shape_seeds(seed, {"train": n, "val": 0, "test": 0})["train"]:
        shape = factory(category, s)
        mesh = shape.mesh(resolution=mesh_resolution)
        centre, scale = r2n2_frame(mesh)
        rows = sample_r2n2_views(n_views, np.random.default_rng(s))
        Ks, w2cs = metadata_to_cameras(rows, image_size, r2n2_centre=centre, r2n2_scale=scale)
        views = render_views(mesh, Ks, w2cs, image_size, part_colour_fn(shape))
        cells.append((list(views["rgba"]), style_label(shape.shape_id, shape.style, _chars(n_views, image_size))))
    return cells


def cells_from_world(index: WorldIndex, n: int, n_views: int) -> list[tuple[list[np.ndarray], list[str]]]:
    """Gallery cells of the first n shapes of a built world (train split first), from its cached renders."""
    cells = []
    for shape_id in index.shape_ids()[:n]:
        style = json.loads(index.shape_path(shape_id).read_text())["style"]
        views = [np.asarray(Image.open(p).convert("RGBA")) for p in index.image_paths(shape_id)[:n_views]]
        cells.append((views, style_label(shape_id, style, _chars(len(views), index.image_size))))
    return cells


def _chars(n_views: int, image_size: int) -> int:
    return max(16, n_views * image_size // 6)  # the default bitmap font is ~6 px per character


def main(argv: Optional[Sequence[str]] = None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--category", default="chairs")
    parser.add_argument("--n", type=int, default=16, help="shapes in the gallery")
    parser.add_argument("--views", type=int, default=3, help="renders shown per shape")
    parser.add_argument("--columns", type=int, default=4)
    parser.add_argument("--out", default=None, help="PNG path (default outputs/gallery_<category>.png)")
    parser.add_argument("--root", default=None, help="build/reuse a cached world here and show its renders")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--image-size", type=int, default=137)
    parser.add_argument("--mesh-resolution", type=int, default=128)
    parser.add_argument("--n-train", type=int, default=None, help="with --root (default: --n)")
    parser.add_argument("--n-val", type=int, default=0)
    parser.add_argument("--n-test", type=int, default=0)
    parser.add_argument("--samples-per-shape", type=int, default=100_000)
    parser.add_argument("--n-views", type=int, default=24, help="with --root: views rendered per shape")
    parser.add_argument("--num-workers", type=int, default=0)
    args = parser.parse_args(argv)
    if args.n < 1:
        parser.error("--n must be at least 1")
    if args.root:
        index = SyntheticWorld(
            args.category,
            args.root,
            args.n_train or args.n,
            args.n_val,
            args.n_test,
            seed=args.seed,
            samples_per_shape=args.samples_per_shape,
            n_views=args.n_views,
            image_size=args.image_size,
            mesh_resolution=args.mesh_resolution,
            num_workers=args.num_workers,
        ).build()
        cells = cells_from_world(index, args.n, args.views)
    else:
        cells = cells_from_shapes(args.category, args.n, args.views, args.image_size, args.mesh_resolution, args.seed)
    out = Path(args.out or f"outputs/gallery_{args.category}.png")
    with atomic.atomic_path(out) as tmp:
        compose_gallery(cells, args.columns).save(tmp, format="PNG")
    print(f"wrote {out} ({len(cells)} shapes)")
    return out
