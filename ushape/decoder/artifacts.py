"""What stage 1 leaves for stage 2: the decoder weights and the code tables, in one folder.

Layout of a decoder folder (every name lives here, nowhere else):
    decoder.pt          {"config": decoder config with `_target_`, "state_dict": ...}
    codes_<split>.pt    {"shape_ids": [str], "codes": Tensor [S, D]} for train (auto-decoded)
                        and val/test (latent-optimised with the decoder frozen)
    checkpoints/        Lightning checkpoints of the auto-decoder run (last.ckpt resumes)
    DONE                written last: the folder is complete and safe to reuse
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
from filelock import FileLock
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import Tensor, nn

from ushape import atomic
from ushape.workspace import DECODER_FILE, DONE_FILE

log = logging.getLogger(__name__)


def codes_file(split: str) -> str:
    return f"codes_{split}.pt"


@dataclass(frozen=True)
class CodeTable:
    """Shape id -> latent code."""

    shape_ids: list[str]
    codes: Tensor  # [S, D]

    def __post_init__(self) -> None:
        if self.codes.ndim != 2 or self.codes.shape[0] != len(self.shape_ids):
            raise ValueError(f"codes {tuple(self.codes.shape)} do not match {len(self.shape_ids)} shape ids")

    def lookup(self, shape_id: str) -> Tensor:
        return self.codes[self.shape_ids.index(shape_id)]

    def as_dict(self) -> dict[str, Tensor]:
        return dict(zip(self.shape_ids, self.codes))


def save_decoder(path: str | Path, decoder: nn.Module, config: Mapping[str, Any]) -> None:
    """Write the decoder's weights with the `_target_` config that rebuilds it."""
    config = OmegaConf.to_container(OmegaConf.create(dict(config)), resolve=True)
    if "_target_" not in config:
        raise ValueError("decoder config needs a `_target_` so the decoder can be rebuilt from the file")
    state = {k: v.detach().cpu() for k, v in decoder.state_dict().items()}
    atomic.torch_save({"config": config, "state_dict": state}, path)


def load_decoder(path: str | Path, frozen: bool = True) -> nn.Module:
    """Rebuild a decoder from `save_decoder`'s file; frozen means eval mode and no gradients."""
    path = Path(path)
    if path.is_dir():
        path = path / DECODER_FILE
    if not path.exists():
        raise FileNotFoundError(f"no stage-1 decoder at {path}: train one with `python train.py stage=decoder`")
    blob = _load(path, "stage-1 decoder")
    decoder = instantiate(blob["config"])
    decoder.load_state_dict(blob["state_dict"])
    if frozen:
        decoder.eval()
        decoder.requires_grad_(False)
    return decoder


def save_codes(path: str | Path, table: CodeTable) -> None:
    atomic.torch_save({"shape_ids": list(table.shape_ids), "codes": table.codes.detach().cpu()}, path)


def load_codes(path: str | Path) -> CodeTable:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no code table at {path}: stage 1 writes it (`python train.py stage=decoder`)")
    blob = _load(path, "code table")
    return CodeTable(list(blob["shape_ids"]), blob["codes"].float())


def _load(path: Path, what: str) -> dict:
    """torch.load of a stage-1 file; a damaged one is a ValueError naming it and how to repair it."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001  (torch and pickle raise many types on damaged files)
        raise ValueError(
            f"{what} {path} is damaged ({type(err).__name__}: {err}); delete {DONE_FILE} in its folder "
            "and rerun: stage 1 resumes from its last checkpoint and rewrites it"
        ) from err
    if not isinstance(blob, dict):
        raise ValueError(f"{what} {path} is damaged (not a dict)")
    return blob


# What loading a damaged or half-written decoder or code table raises.
LOAD_ERRORS = (FileNotFoundError, ValueError, KeyError, RuntimeError)


def folder_problem(folder: str | Path) -> str | None:
    """Why a finished (DONE) decoder folder cannot be used, or None: its decoder and code tables must load."""
    folder = Path(folder)
    try:
        load_decoder(folder)
        for split in ("train", "val", "test"):
            load_codes(folder / codes_file(split))
    except LOAD_ERRORS as err:
        return str(err)
    return None


def derived_folder(out_dir: str | Path, build: Callable[[Path], None], what: str) -> Path:
    """A stage-1 folder made from another one (rebased, re-coded), built once by `build(out_dir)`.

    Sweep jobs running at once build it only once (file lock); it counts as finished only when
    `build` has written DONE last, and an interrupted build is started again from scratch.
    """
    out_dir = Path(out_dir)
    if (out_dir / DONE_FILE).is_file():
        return out_dir
    with FileLock(str(out_dir) + ".lock"):
        if (out_dir / DONE_FILE).is_file():
            return out_dir
        if out_dir.exists():
            shutil.rmtree(out_dir)
        log.info("writing %s into %s", what, out_dir)
        build(out_dir)
    if not (out_dir / DONE_FILE).is_file():
        raise RuntimeError(f"building {what} did not finish {out_dir} (no {DONE_FILE})")
    return out_dir
