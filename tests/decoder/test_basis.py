"""Rebasing the latent space: an exact reparametrisation (same SDF), principal axes as the new basis."""

import pytest
import torch

from ushape.decoder.artifacts import (
    DONE_FILE,
    CodeTable,
    codes_file,
    load_codes,
    load_decoder,
    save_codes,
    save_decoder,
)
from ushape.decoder.basis import BASIS_FILE, ensure_basis, pca_basis, rebase_decoder, to_basis
from ushape.decoder.network import DeepSDFDecoder

CONFIG = {
    "_target_": "ushape.decoder.network.DeepSDFDecoder",
    "latent_size": 6,
    "hidden_dims": [32, 32, 32],
    "latent_in": [2],
    "dropout": 0.2,
    "weight_norm": True,
}


def _decoder():
    torch.manual_seed(0)
    return DeepSDFDecoder(**{k: v for k, v in CONFIG.items() if k != "_target_"}).eval()


def test_pca_axes_are_orthonormal_and_decorrelate_the_codes():
    generator = torch.Generator().manual_seed(0)
    codes = (
        torch.randn(200, 4, generator=generator)
        @ torch.tensor([[3.0, 0, 0, 0], [1.0, 1.0, 0, 0], [0, 0, 0.5, 0], [0, 0, 0.2, 0.1]])
        + 2.0
    )
    mean, rotation, variance = pca_basis(codes)
    assert torch.allclose(rotation.T @ rotation, torch.eye(4), atol=1e-5)
    y = to_basis(codes, mean, rotation)
    cov = torch.cov(y.T)
    assert torch.allclose(cov, torch.diag(variance), atol=1e-3 * variance[0])
    assert (variance[:-1] >= variance[1:]).all()
    assert torch.allclose(y.mean(0), torch.zeros(4), atol=1e-5)


def test_the_rebased_decoder_gives_the_same_sdf_for_the_same_shape():
    decoder = _decoder()
    codes = torch.randn(50, 6)
    mean, rotation, _ = pca_basis(codes)
    rebased, config = rebase_decoder(decoder, mean, rotation)
    xyz = torch.rand(300, 3) * 2 - 1
    z = codes[:3]
    y = to_basis(z, mean, rotation)
    for i in range(3):
        with torch.no_grad():
            assert torch.allclose(rebased(xyz, y[i]), decoder(xyz, z[i]), atol=1e-5)
    assert config["weight_norm"] is False and config["hidden_dims"] == [32, 32, 32]


def test_only_a_deepsdf_decoder_can_be_rebased():
    with pytest.raises(TypeError, match="DeepSDFDecoder"):
        rebase_decoder(torch.nn.Linear(3, 1), torch.zeros(3), torch.eye(3))


def test_ensure_basis_writes_a_complete_folder_once(tmp_path):
    source = tmp_path / "decoder"
    source.mkdir()
    decoder = _decoder()
    save_decoder(source / "decoder.pt", decoder, CONFIG)
    torch.manual_seed(1)
    for split, n in (("train", 40), ("test", 5)):
        save_codes(source / codes_file(split), CodeTable([f"{split}_{i}" for i in range(n)], torch.randn(n, 6)))
    with pytest.raises(FileNotFoundError, match="not a finished"):
        ensure_basis(source, "pca")
    (source / DONE_FILE).write_text("done\n")
    assert ensure_basis(source, "identity") == source
    with pytest.raises(ValueError, match="latent_basis"):
        ensure_basis(source, "ica")
    rebased_dir = ensure_basis(source, "pca")
    assert (rebased_dir / DONE_FILE).is_file() and (rebased_dir / BASIS_FILE).is_file()
    stamp = (rebased_dir / "decoder.pt").stat().st_mtime_ns
    assert ensure_basis(source, "pca") == rebased_dir and (rebased_dir / "decoder.pt").stat().st_mtime_ns == stamp
    xyz = torch.rand(100, 3) * 2 - 1
    old, new = load_decoder(source), load_decoder(rebased_dir)
    for split in ("train", "test"):
        before, after = load_codes(source / codes_file(split)), load_codes(rebased_dir / codes_file(split))
        assert after.shape_ids == before.shape_ids
        with torch.no_grad():
            assert torch.allclose(new(xyz, after.codes[0]), old(xyz, before.codes[0]), atol=1e-5)
