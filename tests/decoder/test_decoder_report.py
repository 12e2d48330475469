"""The stage-1 report scores a finished decoder folder against its ground-truth meshes."""

import json
import math

from ushape.decoder.report import REPORT_FILE, report


def test_report_on_the_sphere_decoder(fitted_sphere_folder):
    result = report(fitted_sphere_folder, n_shapes=2, resolution=32)
    for split in ("train", "val", "test"):
        summary = result[split]
        assert summary["shapes"], split
        assert summary["empty"] == 0
        # Spheres are easy: a trained decoder must get them nearly right, held-out ones included.
        assert summary["iou_mean"] > 0.7, (split, summary)
        assert math.isfinite(summary["chamfer_mean"]) and summary["chamfer_mean"] < 5e-3
        assert (fitted_sphere_folder / f"report_{split}.png").stat().st_size > 0
    assert json.loads((fitted_sphere_folder / REPORT_FILE).read_text())["resolution"] == 32
