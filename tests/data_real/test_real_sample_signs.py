"""Signs of our SDF on the real sample models against their official voxelisations."""

import numpy as np
import pytest
from trimesh.exchange.binvox import parse_binvox, voxel_from_binvox

from ushape.data.mesh_sdf import MeshSdf, load_mesh, normalise_mesh, sample_mesh_sdf
from ushape.data.pix3d import load_voxels, voxel_to_model

CHAIRS = "03001627"


def read_solid_binvox(path):
    """(occupancy [D,D,D] indexed x,y,z, voxel-centre map index->model [4,4]) of a binvox file."""
    with open(path, "rb") as fh:
        data = parse_binvox(fh)
    occupancy = voxel_from_binvox(data.rle_data, data.shape, axis_order="xzy").encoding.dense
    step = data.scale / data.shape[0]
    # binvox_rw convention: voxel i covers translate + [i, i+1) * scale / dim.
    transform = np.diag([step, step, step, 1.0])
    transform[:3, 3] = np.asarray(data.translate) + 0.5 * step
    return occupancy, transform


def grid_check(mesh, occupancy, index_to_model, rng, n=6000):
    """Agreement of our inside test with the voxels at voxel centres >= 2 voxels from the surface.

    Half the centres are uniform over the grid (mostly outside), half drawn from occupied voxels,
    so inside is tested too. Returns (agreement, n checked, agreement on occupied voxels or None).
    """
    uniform = np.stack([rng.integers(0, s, n // 2) for s in occupancy.shape], axis=1)
    occupied = np.argwhere(occupancy)
    index = np.concatenate([uniform, occupied[rng.integers(0, len(occupied), n - n // 2)]])
    points = index @ index_to_model[:3, :3].T + index_to_model[:3, 3]
    sdf = MeshSdf(mesh, n_surface_samples=50_000)
    far = sdf.distance(points) > 2 * np.abs(index_to_model[:3, :3]).sum(axis=0).max()
    truth = occupancy[tuple(index[far].T)]
    agree = sdf.inside(points[far]) == truth
    inside_agreement = float(agree[truth].mean()) if truth.sum() >= 50 else None
    return float(agree.mean()), int(far.sum()), inside_agreement


@pytest.fixture(params=["1a6f615e8b1b5ae4dbbc9440457e303e", "1b5e876f3559c231532a8e162f399205",
                        "1b7ba5484399d36bc5e50b867ca2d0b9"])
def chair_dir(request, shapenet_sample):
    return shapenet_sample / CHAIRS / request.param / "models"


def test_shapenet_signs_match_solid_binvox(chair_dir, rng):
    mesh = load_mesh(chair_dir / "model_normalized.obj")
    occupancy, transform = read_solid_binvox(chair_dir / "model_normalized.solid.binvox")
    agreement, n, inside_agreement = grid_check(mesh, occupancy, transform, rng)
    assert n > 2000 and agreement > 0.99
    assert inside_agreement is None or inside_agreement > 0.97


def test_shapenet_samples_match_binvox_in_normalised_frame(shapenet_sample, rng):
    chair_dir = shapenet_sample / CHAIRS / "1b7ba5484399d36bc5e50b867ca2d0b9" / "models"
    mesh, centre, scale = normalise_mesh(load_mesh(chair_dir / "model_normalized.obj"))
    samples = sample_mesh_sdf(mesh, 20_000, rng, n_surface_samples=50_000)
    occupancy, transform = read_solid_binvox(chair_dir / "model_normalized.solid.binvox")
    rows = np.concatenate([samples["pos"], samples["neg"]]).astype(np.float64)
    model = rows[:, :3] / scale + centre
    index = np.floor((model - transform[:3, 3]) / transform[0, 0] + 0.5).astype(int)
    in_grid = np.all((index >= 0) & (index < occupancy.shape[0]), axis=1)
    far = in_grid & (np.abs(rows[:, 3]) / scale > 2 * transform[0, 0])
    truth = occupancy[tuple(index[far].T)]
    assert far.sum() > 2000 and truth.any()
    assert np.mean((rows[far, 3] < 0) == truth) > 0.99


@pytest.mark.parametrize("model", ["chair/IKEA_HENRIKSDAL", "chair/IKEA_IVAR", "table/IKEA_LACK_1", "table/IKEA_MALM_1"])
def test_pix3d_signs_match_voxel_mat(pix3d_sample, model, rng):
    folder = pix3d_sample / "model" / model
    mesh = load_mesh(folder / "model.obj")
    occupancy = load_voxels(folder / "voxel.mat")
    agreement, n, inside_agreement = grid_check(mesh, occupancy, voxel_to_model(mesh, occupancy.shape[0]), rng)
    assert n > 2000 and agreement > 0.95
    assert inside_agreement is None or inside_agreement > 0.95


def test_pix3d_voxel_frame_puts_the_surface_on_occupied_voxels(pix3d_sample):
    # The frame map is found independently of any sign test: surface points must land on voxels.
    for folder in sorted((pix3d_sample / "model").glob("*/*")):
        mesh = load_mesh(folder / "model.obj")
        occupancy = load_voxels(folder / "voxel.mat")
        to_index = np.linalg.inv(voxel_to_model(mesh))
        points = mesh.sample(3000)
        index = np.clip(np.rint(points @ to_index[:3, :3].T + to_index[:3, 3]).astype(int), 0, 127)
        assert occupancy[tuple(index.T)].mean() > 0.9, folder.name
