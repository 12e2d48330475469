"""Table D (depth-std calibration) in the evaluation: the true depth from the world, and the protocol end to end."""

import math
import shutil

import numpy as np
import pytest
from eval_world import N_VIEWS, B, make_run, tiny_protocols, tiny_settings

from ushape.data.layout import WorldIndex
from ushape.evaluation.depth_calibration import true_depths
from ushape.evaluation.plugins.depth import Depth
from ushape.evaluation.report import write_results
from ushape.evaluation.runner import evaluate_all


def test_true_depth_is_the_mesh_rendered_again_unless_the_world_keeps_it_at_that_size(sphere_world, tmp_path):
    size = 33
    [(depth, K, w2c)] = true_depths(sphere_world, "test_0", [0], size)
    assert depth.shape == (size, size) and np.isclose(K[0, 2], size / 2)
    # view 0 sits at azimuth 0, elevation 20, distance 3: the centre ray meets the ellipsoid (0.3, B, B) at s
    el = math.radians(20.0)
    s = 1 / math.sqrt(math.cos(el) ** 2 / 0.3**2 + math.sin(el) ** 2 / B**2)
    assert depth[size // 2, size // 2] == pytest.approx(3.0 - s, abs=3e-3)  # the icosphere is a little inside
    assert depth[0, 0] == 0  # a corner ray misses
    root = tmp_path / "world"
    shutil.copytree(sphere_world.root, root)
    views = root / "renders" / "test_0" / "views.npz"
    with np.load(views) as cams:
        np.savez(views, **cams, depth=np.full((N_VIEWS, size, size), 7.0, np.float32))
    [(stored, _, _)] = true_depths(WorldIndex.load(root), "test_0", [0], size)
    assert (stored == 7.0).all()
    [(other, _, _)] = true_depths(WorldIndex.load(root), "test_0", [0], 17)  # another size: rendered again
    assert other.max() < 7.0 and other.shape == (17, 17)


def test_depth_protocol_scores_probabilistic_encoders_and_writes_table_d(sphere_world, sphere_codes, tmp_path):
    settings = tiny_settings()
    protocols = tiny_protocols(["depth"], depth=dict(views=1, codes=6))
    runs = [make_run(sphere_world, sphere_codes, tmp_path / "cache", name, tmp_path, settings) for name in ("es", "l2")]
    result = evaluate_all(runs, settings, tmp_path / "cache", protocols=protocols)
    rows = {(r["encoder"], r["method"]): r for r in result["depth"]}
    assert set(rows) == {("es", "implicit"), ("es", "mc M=6")}  # l2 predicts no variance
    for row in rows.values():
        assert row["n_views"] == 2 and row["n_pixels"] > 20 and row["size"] == 16
        assert 0 <= row["coverage_68"] <= row["coverage_95"] <= 1 and 0 <= row["calibration_error"] <= 0.5
        assert row["mean_std"] > 0 and row["mean_abs_error"] < 0.5
    assert set(result["curves"]["depth"]) == {"Ours (depth, implicit)", "Ours (depth, mc M=6)"}
    out = tmp_path / "out"
    write_results(result, out, tensorboard=False)
    assert (out / "tabled.csv").is_file() and (out / "depth.csv").is_file()
    assert "Table D: depth uncertainty calibration" in (out / "tables.md").read_text()
    assert (out / "plots" / "calibration_depth.png").is_file()
    with pytest.raises(ValueError, match="methods must be some of"):
        Depth(methods=("sampled",))
