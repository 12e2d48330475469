"""The stage-1 latent space in another orthonormal basis: same shapes, same decoder, rotated codes.

Stage 2 predicts a *diagonal* Gaussian over the code, so which directions it can call uncertain depends
on the basis. An auto-decoder's axes are arbitrary (an isotropic prior, random initial codes); in the
principal axes of the training codes (PCA) each axis is a direction the shapes really vary along,
ordered by how much (quickstart chairs: variance 0.13 on the first axis down to 0.0003 on the last,
against 0.004-0.046 on the raw axes). Measured on the quickstart chairs, it did not make the
uncertainty move onto cropped-away parts (README, Table L ablation); it is kept as an option to try
at larger scale.

The change of basis is exact: with z = mean + R y (R orthonormal [D, D]), the latent enters a DeepSDF
decoder only linearly (first layer and the latent_in layers), so W z + b = (W R) y + (W mean + b) is
folded into those weights. The rebased folder is a complete stage-1 folder (decoder.pt, codes_<split>.pt
with y = (z - mean) R, basis.pt, DONE) that stage 2, evaluation and reconstruct use unchanged.
Distances, L2 errors and the Energy Score are the same in either basis; a diagonal NLL is not.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from ushape import atomic
from ushape.decoder.artifacts import (
    DECODER_FILE,
    DONE_FILE,
    codes_file,
    derived_folder,
    load_codes,
    load_decoder,
    save_codes,
    save_decoder,
)
from ushape.decoder.network import DeepSDFDecoder
from ushape.workspace import BASIS_FILE

BASES = ("identity", "pca")


def pca_basis(codes: Tensor) -> tuple[Tensor, Tensor, Tensor]:  # [S, D] -> mean [D], R [D, D], variance [D]
    """Mean, principal axes as columns of R (descending variance, largest entry of each positive) and variances."""
    if codes.ndim != 2 or codes.shape[0] < 2:
        raise ValueError(f"PCA needs at least 2 codes [S, D], got shape {tuple(codes.shape)}")
    codes = codes.double()
    mean = codes.mean(0)
    centred = codes - mean
    variance, axes = torch.linalg.eigh(centred.T @ centred / (codes.shape[0] - 1))
    order = torch.argsort(variance, descending=True)
    variance, axes = variance[order].clamp_min(0), axes[:, order]
    signs = torch.sign(axes.gather(0, axes.abs().argmax(0, keepdim=True)))
    return mean.float(), (axes * signs).float(), variance.float()


def to_basis(codes: Tensor, mean: Tensor, rotation: Tensor) -> Tensor:  # [S, D] -> [S, D]
    """y = (z - mean) R."""
    return (codes - mean) @ rotation


def rebase_decoder(decoder: DeepSDFDecoder, mean: Tensor, rotation: Tensor) -> tuple[DeepSDFDecoder, dict]:
    """A decoder g with g(x, y) = decoder(x, mean + R y), and the config that rebuilds it (no weight norm)."""
    if not isinstance(decoder, DeepSDFDecoder):
        raise TypeError(
            f"only a DeepSDFDecoder can be rebased (its latent enters linearly), got {type(decoder).__name__}"
        )
    D = decoder.latent_size
    if mean.shape != (D,) or rotation.shape != (D, D):
        raise ValueError(f"mean {tuple(mean.shape)} / rotation {tuple(rotation.shape)} do not fit latent size {D}")
    linears = list(decoder.layers)
    config = {
        "_target_": "ushape.decoder.network.DeepSDFDecoder",
        "latent_size": D,
        "hidden_dims": [
            layer.weight.shape[0] + (D + 3 if i + 1 in decoder.latent_in else 0) for i, layer in enumerate(linears[:-1])
        ],
        "latent_in": list(decoder.latent_in),
        "dropout": decoder.dropout,
        "weight_norm": False,
        "output_tanh": decoder.output_tanh,
    }
    rebased = DeepSDFDecoder(**{k: v for k, v in config.items() if k != "_target_"})
    with torch.no_grad():
        for i, (old, new) in enumerate(zip(linears, rebased.layers)):
            weight, bias = old.weight.detach().clone(), old.bias.detach().clone()  # weight norm applied
            if i == 0 or i in decoder.latent_in:
                start = weight.shape[1] - (D + 3)  # the input ends with [z, xyz]
                w_z = weight[:, start : start + D]
                bias += w_z @ mean
                weight[:, start : start + D] = w_z @ rotation
            new.weight.copy_(weight)
            new.bias.copy_(bias)
    return rebased.eval(), config


def rebase_folder(decoder_dir: str | Path, out_dir: str | Path) -> Path:
    """Write the PCA-rebased copy of a complete stage-1 folder (module docstring); DONE is written last."""
    decoder_dir, out_dir = Path(decoder_dir), Path(out_dir)
    if not (decoder_dir / DONE_FILE).is_file():
        raise FileNotFoundError(f"{decoder_dir} is not a finished stage-1 folder (no {DONE_FILE}); train stage 1 first")
    train = load_codes(decoder_dir / codes_file("train"))
    mean, rotation, variance = pca_basis(train.codes)
    decoder, config = rebase_decoder(load_decoder(decoder_dir), mean, rotation)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / DONE_FILE).unlink(missing_ok=True)
    save_decoder(out_dir / DECODER_FILE, decoder, config)
    for path in sorted(decoder_dir.glob(codes_file("*"))):
        table = load_codes(path)
        save_codes(out_dir / path.name, type(table)(table.shape_ids, to_basis(table.codes, mean, rotation)))
    atomic.torch_save(
        {
            "basis": "pca",
            "source": str(decoder_dir.resolve()),
            "mean": mean,
            "rotation": rotation,
            "variance": variance,
        },
        out_dir / BASIS_FILE,
    )
    atomic.write_text(out_dir / DONE_FILE, "rebased\n")
    return out_dir


def ensure_basis(decoder_dir: str | Path, basis: str) -> Path:
    """The stage-1 folder to train stage 2 against: the folder itself, or its rebased copy <folder>/basis_<basis>."""
    if basis not in BASES:
        raise ValueError(f"latent_basis must be one of {BASES}, got {basis!r}")
    decoder_dir = Path(decoder_dir)
    if basis == "identity":
        return decoder_dir
    return derived_folder(
        decoder_dir / f"basis_{basis}",
        lambda out: rebase_folder(decoder_dir, out),
        f"the stage-1 latent space in the {basis} basis",
    )
