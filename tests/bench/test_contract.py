"""The precision contract, checked by forcing bf16 (auto picks fp32 on a CPU without AMX).

Mesh vs fp32: Chamfer <= 1e-5 (unit-sphere frame), IoU at 64^3 >= 0.995; vertex and depth std within
2 % (median relative); the evaluation's IoU within 0.002. On an analytic decoder that reads the point
through a Linear layer (so bf16 autocast rounds it), on a small DeepSDF decoder (folded in bf16), and on
a quickstart-sized (4 x 256) decoder fitted to a procedural chair. Where the fp32 re-evaluation of the
surface holds (`exact_surface`), the bf16 mesh is the fp32 mesh itself up to fp32 rounding: the fp32 decoder's
values move in their last bits with batch and thread count, which moves vertices by up to FP32_ROUNDING and,
where a grid value lies within that rounding of 0, may change the faces around it.
"""

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from scipy.spatial import cKDTree
from torch import nn

from ushape.bench.contract import FP32_ROUNDING, LIMITS, Contract, contract, median_relative, mesh_iou, same_mesh
from ushape.bench.depth import orbit_cameras
from ushape.mesh.extraction import marching_cubes
from ushape.propagation.field import decode_field, surface_field
from ushape.workspace import CONFIG_DIR


class RoundedEllipsoid(nn.Module):
    """An ellipsoid whose x semi-axis is 0.45 + 0.1 z_0 + 0.05 z_1, the point read through an identity Linear."""

    latent_size = 2

    def __init__(self) -> None:
        super().__init__()
        self.read = nn.Linear(3, 3, bias=False)
        with torch.no_grad():
            self.read.weight.copy_(torch.eye(3))

    def forward(self, xyz, z):
        p = self.read(xyz).float() - torch.tensor([0.05, -0.1, 0.02])
        a = 0.45 + 0.1 * z[..., 0] + 0.05 * z[..., 1]
        scale = torch.stack(torch.broadcast_tensors(a, torch.full_like(a, 0.3), torch.full_like(a, 0.6)), -1)
        return ((p / scale).norm(dim=-1) - 1) * 0.3


def test_bf16_moves_the_raw_field_but_not_the_mesh_on_an_analytic_decoder():
    decoder, code = RoundedEllipsoid(), torch.tensor([0.2, -0.3])
    field = decode_field(decoder, code, 48)
    assert (decode_field(decoder, code, 48, bf16=True) - field).abs().max() > 1e-4  # bf16 really rounds the points
    reference = marching_cubes(field)
    mesh = marching_cubes(surface_field(decoder, code, 48, bf16=True))
    # The fp32 mesh, as same_mesh asks: its vertices to fp32 rounding (the surface is re-evaluated in other
    # batches), its faces exactly, for they follow the signs and no grid value lies near 0 (2.5e-5 here, no cell is
    # ambiguous), far beyond that rounding. So the contract's figures are same_mesh's own 0 and 1 below.
    assert float(field.abs().min()) > 1e-5
    assert np.array_equal(mesh.faces, reference.faces) and same_mesh(mesh, reference)
    var = torch.tensor([0.01, 0.02])
    figures = contract(decoder, code, var, resolution=48, bf16=True, cameras=orbit_cameras(2, 16), depth_size=16)
    assert figures.met(), figures.text()
    assert (figures.chamfer, figures.iou) == (0.0, 1.0)  # the very fp32 mesh
    assert figures.depth_std is not None and figures.depth_std <= LIMITS["depth_std"]
    # fp32 against itself: the same calls on both sides, no difference at all
    same = contract(decoder, code, var, resolution=32, bf16=False)
    assert (same.chamfer, same.iou, same.vertex_std, same.eval_iou) == (0.0, 1.0, 0.0, 0.0)


def test_the_contract_reads_each_limit():
    good = Contract(chamfer=1e-6, iou=0.999, vertex_std=0.01, depth_std=None, eval_iou=0.001)
    assert good.met() and "contract met" in good.text()
    for field, bad in (("chamfer", 2e-5), ("iou", 0.99), ("vertex_std", 0.03), ("depth_std", 0.05), ("eval_iou", 0.01)):
        figures = Contract(**{**good.__dict__, field: bad})
        assert not figures.met() and "MISSED" in figures.text(), field


def test_median_relative_difference():
    reference = torch.tensor([1.0, 2.0, 4.0, 0.0, float("nan")])
    assert median_relative(torch.tensor([1.1, 2.0, 3.0, 5.0, 1.0]), reference) == pytest.approx(0.1)


@pytest.fixture(scope="module")
def quickstart_sized_decoder():
    """conf/decoder/small.yaml (the quickstart's 4 x 256, latent 64) fitted to procedural chair 0."""
    from hydra.utils import instantiate

    from ushape.bench.fitted import fit_decoder

    torch.manual_seed(0)
    decoder = instantiate(OmegaConf.load(CONFIG_DIR / "decoder" / "small.yaml"))
    code = 0.1 * torch.randn(decoder.latent_size)
    fit_decoder(decoder, code, steps=200, batch=4096)
    return decoder, code


@pytest.mark.slow
def test_bf16_meets_the_contract_on_a_quickstart_sized_decoder(quickstart_sized_decoder):
    decoder, code = quickstart_sized_decoder
    figures = contract(
        decoder,
        code,
        torch.full_like(code, 0.01),
        resolution=128,
        bf16=True,
        cameras=orbit_cameras(2, 32),
        depth_size=32,
        depth_var=torch.full_like(code, 0.001),
    )
    assert figures.met(), figures.text()


def test_a_deepsdf_decoder_in_bf16_meshes_as_in_fp32():
    """Folded in bf16 (the point kept float32) and its surface re-evaluated in fp32: the fp32 mesh up to fp32
    rounding (fp32 values move in their last bits with batch and threads)."""
    from ushape.decoder.network import DeepSDFDecoder
    from ushape.propagation.field import code_mesh

    torch.manual_seed(0)
    decoder = DeepSDFDecoder(latent_size=4, hidden_dims=(64,) * 4, latent_in=(2,), dropout=0.0).eval()
    code = 0.3 * torch.randn(4)
    with torch.no_grad():  # put the zero level set inside the cube
        decoder.layers[-1].bias -= torch.atanh(decode_field(decoder, code, 16).median())
    raw = decode_field(decoder, code, 40, bf16=True)
    assert not torch.equal(raw, decode_field(decoder, code, 40))  # bf16 really changes the values
    reference, _ = code_mesh(decoder, code, 40, "coarse_to_fine")
    mesh, stats = code_mesh(decoder, code, 40, "coarse_to_fine", bf16=True)
    assert len(reference.vertices) > 100
    # Not bit for bit: a grid value here lies 3e-7 from 0, within the rounding the re-evaluation's batches may
    # give it, so its sign and the faces around it may change. Face counts within 1 %, and every vertex within
    # FP32_ROUNDING of the other mesh's (the bf16 field's own mesh has 2 % more faces and vertices 0.03 off).
    assert abs(len(mesh.faces) - len(reference.faces)) <= 0.01 * len(reference.faces)
    for one, other in ((mesh, reference), (reference, mesh)):
        assert cKDTree(np.asarray(other.vertices)).query(np.asarray(one.vertices))[0].max() <= FP32_ROUNDING


def test_same_mesh_allows_fp32_rounding_only_and_open_meshes_get_no_iou():
    import trimesh

    box = trimesh.creation.box()
    moved = trimesh.Trimesh(box.vertices + FP32_ROUNDING / 2, box.faces, process=False)
    assert same_mesh(moved, box) and not same_mesh(trimesh.Trimesh(box.vertices * 1.01, box.faces), box)
    assert not same_mesh(trimesh.Trimesh(box.vertices, box.faces[::-1]), box)  # other faces
    assert mesh_iou(box, box, 16) == pytest.approx(1.0)
    sheet = trimesh.Trimesh([[-1, -1, 0.1], [1, -1, 0.1], [1, 1, 0.1], [-1, 1, 0.1]], [[0, 1, 2], [0, 2, 3]])
    assert np.isnan(mesh_iou(sheet, sheet, 16))  # an open surface encloses nothing: no IoU to give
    nan = Contract(chamfer=0.0, iou=float("nan"), vertex_std=0.0, depth_std=None, eval_iou=0.0)
    assert not nan.met()  # an IoU that cannot be measured does not meet the contract


def test_mesh_iou_turns_only_empty_occupancies_into_nan(monkeypatch):
    import trimesh

    import ushape.bench.contract as module

    def broken(*args):
        raise ValueError("occupancy shapes differ")  # any other failure of the IoU is a bug to see, not a NaN

    monkeypatch.setattr(module, "volumetric_iou", broken)
    with pytest.raises(ValueError, match="shapes differ"):
        mesh_iou(trimesh.creation.box(), trimesh.creation.box(), 8)
