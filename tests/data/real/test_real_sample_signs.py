"""Signs of our SDF on every real sample model against its official voxelisation (tolerant check).

A sample is compared only when it lies at least one voxel from the voxel surface (its voxel
and all 26 neighbours agree): faces on voxel boundaries and thin parts thickened to a voxel
make the voxels differ from the mesh nearer than that (see ushape.data.real.voxel_check).
"""

import os
from pathlib import Path

import numpy as np
import pytest

from ushape.data.real.mesh_sdf import MeshSdf, SignReport, load_mesh, normalise_mesh, sample_mesh_sdf
from ushape.data.real.pix3d import load_voxels, voxel_to_model
from ushape.data.real.voxel_check import has_interior, read_solid_binvox, tolerant_truth
from ushape.data.sampling import sample_points

# As conftest.REAL_SAMPLE (a conftest cannot be imported by name here): parametrizing needs the list at collection.
REAL_SAMPLE = Path(os.path.dirname(os.path.abspath(__file__))).parents[3] / "shared" / "data" / "real_sample"
CHAIRS = "03001627"


def real_models():
    """(test id, model file, voxel file) of every ShapeNetCore.v2 and Pix3D model in the shared sample."""
    shapenet = sorted(REAL_SAMPLE.glob("ShapeNetCore.v2/*/*/models/model_normalized.obj"))
    pix3d = sorted(REAL_SAMPLE.glob("pix3d/model/*/*/model.obj"))
    return [pytest.param(p, p.parent / "model_normalized.solid.binvox", id=p.parents[1].name[:8]) for p in shapenet] + [
        pytest.param(p, p.parent / "voxel.mat", id=p.parent.name) for p in pix3d
    ]


def official_voxels(model, voxel_file):
    """(occupancy, voxel-centre index -> model frame [4,4]) of a model's official voxelisation."""
    if voxel_file.suffix == ".mat":
        occupancy = load_voxels(voxel_file)
        return occupancy, voxel_to_model(load_mesh(model), occupancy.shape[0])
    return read_solid_binvox(voxel_file)


@pytest.mark.parametrize("model, voxel_file", real_models())
def test_signs_agree_with_official_voxels(model, voxel_file, rng):
    occupancy, index_to_model = official_voxels(model, voxel_file)
    mesh, centre, scale = normalise_mesh(load_mesh(model))
    points = sample_points(mesh, 6000, rng)
    sdf = MeshSdf(mesh)
    inside = sdf.inside(points)
    report = SignReport.of(sdf.signs)
    checked, truth = tolerant_truth(occupancy, index_to_model, points / scale + centre)
    agreement = np.mean(inside[checked] == truth[checked])
    assert checked.sum() > 3000 and agreement >= 0.99
    if has_interior(occupancy):
        assert truth[checked].sum() > 300
        assert report.confidence > 0.99
    else:
        # Surface-only voxels: the mesh is open (IKEA_HENRIKSDAL has no back), so a flood fill from
        # outside enters it and its voxels are a hollow shell. Reachability matches the shell; the
        # winding number would fill the seat, so the report says the sign depends on the method.
        assert report.confidence < 0.9 and report.winding_agreement < 0.9


def test_shapenet_samples_match_binvox_in_normalised_frame(shapenet_sample, rng):
    chair_dir = shapenet_sample / CHAIRS / "1b7ba5484399d36bc5e50b867ca2d0b9" / "models"
    mesh, centre, scale = normalise_mesh(load_mesh(chair_dir / "model_normalized.obj"))
    samples, report = sample_mesh_sdf(mesh, 20_000, rng)
    occupancy, transform = read_solid_binvox(chair_dir / "model_normalized.solid.binvox")
    rows = np.concatenate([samples["pos"], samples["neg"]]).astype(np.float64)
    checked, truth = tolerant_truth(occupancy, transform, rows[:, :3] / scale + centre)
    assert checked.sum() > 10_000 and truth[checked].sum() > 1000
    assert np.mean((rows[checked, 3] < 0) == truth[checked]) > 0.99
    assert report.confidence > 0.99


def test_pix3d_voxel_frame_puts_the_surface_on_occupied_voxels(pix3d_sample):
    # The frame map is found independently of any sign test: surface points must land on or beside
    # occupied voxels (a face on a voxel boundary may have been voxelised on its other side).
    for folder in sorted((pix3d_sample / "model").glob("*/*")):
        mesh = load_mesh(folder / "model.obj")
        occupancy = load_voxels(folder / "voxel.mat")
        to_index = np.linalg.inv(voxel_to_model(mesh))
        points = mesh.sample(3000)
        index = np.rint(points @ to_index[:3, :3].T + to_index[:3, 3]).astype(int)
        offsets = np.stack(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        near = np.clip(index[:, None, :] + offsets, 0, 127)
        assert occupancy[tuple(near.transpose(2, 0, 1))].any(axis=1).mean() > 0.99, folder.name
