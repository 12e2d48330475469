"""Mesh writer: std survives PLY and GLB round trips, colours follow the documented range, colour bar exists."""

import numpy as np
import pytest
import trimesh
from PIL import Image

from ushape.reconstruction.export import colour_range, read_glb_std, read_ply_std, std_colours, write_mesh_files


def test_std_round_trips_through_ply_and_glb(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    std = np.linspace(0.0, 0.2, len(mesh.vertices)).astype(np.float32)
    files = write_mesh_files(mesh, std, tmp_path, "shape", std_max=0.1, cmap="viridis")
    assert np.array_equal(read_ply_std(files["ply"]), std)
    assert np.array_equal(read_glb_std(files["glb"]), std)
    ply = trimesh.load(files["ply"], process=False)
    assert np.allclose(ply.vertices, mesh.vertices, atol=1e-6)
    # vertices with std >= std_max get the colormap's top colour
    top = std_colours(np.array([0.1]), 0.1, "viridis")[0]
    assert np.array_equal(ply.visual.vertex_colors[-1], top)
    bar = Image.open(files["colour_bar"])
    assert bar.size[0] > bar.size[1] > 0 and files["std_max"] == 0.1


def test_colour_range_and_colours():
    std = np.r_[np.zeros(99), 100.0]  # one outlier must not set the scale
    assert colour_range(std) == pytest.approx(np.percentile(std, 99))
    assert colour_range(np.zeros(5)) == 1.0
    with pytest.raises(ValueError, match="std_max"):
        colour_range(std, 0.0)
    colours = std_colours(np.array([0.0, 0.5, 1.0, 3.0]), 1.0, "inferno")
    assert colours.dtype == np.uint8 and colours.shape == (4, 4)
    assert np.array_equal(colours[2], colours[3]) and not np.array_equal(colours[0], colours[1])


def test_wrong_std_length_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="std values"):
        write_mesh_files(trimesh.creation.box(), np.zeros(3), tmp_path)
