"""The refined posterior's std from a whole view and from the same view cut above the legs, on one colour scale.

    PYTHONPATH=. python notebooks/refine_legs_figure.py RUN OUT.png [--mode masks|depth] [--keep 0.55] [--shape N]

RUN is an encoder run folder. The first (or N-th) test shape's view 0 is reconstructed twice with
`reconstruct.py --refine MODE`: from the whole render (its camera, mask and depth from views.npz), and from
its top `keep` fraction of rows, a photo cut off at the seat, with a camera file for the crop (the crop
changes K only; its mask and depth are the crop's). Both overviews share the colour scale `--std-max`
(default 0.05) and are stacked, whole view on top, into OUT.png.
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from ushape.data.layout import WorldIndex
from ushape.reconstruction.cli import main as reconstruct
from ushape.reconstruction.predictor import load_predictor
from ushape.refinement.views import crop_camera


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--mode", default="masks", choices=("masks", "depth"))
    parser.add_argument("--keep", type=float, default=0.55, help="fraction of the image's rows kept, from the top")
    parser.add_argument("--shape", type=int, default=0, help="which test shape (index in the test split)")
    parser.add_argument("--std-max", type=float, default=0.05)
    args = parser.parse_args()
    world = WorldIndex.load(load_predictor(args.run).world)
    shape_id = world.shape_ids("test")[args.shape]
    image = world.root / "renders" / shape_id / "00.png"
    views = np.load(world.views_path(shape_id))
    rgba = np.asarray(Image.open(image))
    h, w = rgba.shape[:2]
    rows = int(round(args.keep * h))
    overviews = []
    with tempfile.TemporaryDirectory() as tmp:
        cut = Path(tmp) / "cut.png"
        Image.fromarray(rgba[:rows]).save(cut)
        cameras = Path(tmp) / "cut_cameras.npz"
        np.savez(
            cameras,
            K=crop_camera(views["K"][0], (0, 0, rows, w), (rows, w))[None],
            world_to_cam=views["world_to_cam"][:1],
            masks=views["masks"][:1, :rows],
            depth=views["depth"][:1, :rows],
        )
        for name, source, extra in (("whole", image, []), ("cut", cut, ["--cameras", str(cameras)])):
            out = Path(tmp) / name
            common = ["--run", args.run, "--refine", args.mode, "--std-max", str(args.std_max), "--out", str(out)]
            if reconstruct([str(source), *common, *extra]) != 0:
                raise SystemExit(f"reconstruct.py failed on the {name} view")
            overviews.append(Image.open(out / "overview.png").convert("RGB"))
    width = max(o.width for o in overviews)
    sheet = Image.new("RGB", (width, sum(o.height for o in overviews)), "white")
    top = 0
    for overview in overviews:
        sheet.paste(overview, (0, top))
        top += overview.height
    sheet.save(args.out)
    print(f"{shape_id} view 0, refined on {args.mode}: whole view on top, cut at {args.keep:.0%} below -> {args.out}")


if __name__ == "__main__":
    main()
