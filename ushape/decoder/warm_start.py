"""Stage 1 started from a finished decoder folder (`stage1.init_from`): more epochs for a decoder that underfits.

The new run's decoder takes the finished decoder's weights, and each training shape the two runs share takes
its trained code; shapes new to the run keep their fresh draw. Only the optimiser's state and the epoch count
start again, under the new run's own schedule (its epochs, learning rates and drops). An interrupted warm run
resumes from its own checkpoint, not from the folder it started from. The stage-1 identity names the
starting decoder by its weights' hash, so two runs from different starting points never share a folder.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import torch

from ushape.decoder.artifacts import DECODER_FILE, DONE_FILE, codes_file, load_codes
from ushape.errors import InputError

log = logging.getLogger(__name__)


def init_folder(init_from: str | Path) -> Path:
    """The finished decoder folder to start from, or an InputError saying what it lacks."""
    folder = Path(init_from).expanduser()
    missing = [name for name in (DECODER_FILE, codes_file("train"), DONE_FILE) if not (folder / name).is_file()]
    if missing:
        raise InputError(
            f"stage1.init_from={init_from}: not a finished stage-1 folder ({', '.join(missing)} missing); "
            "name an outputs/decoders/<category>-<hash> folder with a DONE file, or a shipped model's decoder/"
        )
    return folder


def init_fingerprint(init_from: str | Path) -> str:
    """What the stage-1 identity records of the starting decoder: its decoder.pt's SHA-256 (first 16 hex)."""
    return hashlib.sha256((init_folder(init_from) / DECODER_FILE).read_bytes()).hexdigest()[:16]


def warm_start(model, init_from: str | Path, train_ids: list[str]) -> int:
    """Load the starting folder's decoder weights and the shared shapes' codes into `model`
    (an AutoDecoderModule over `train_ids`). Returns how many codes were taken."""
    folder = init_folder(init_from)
    blob = torch.load(folder / DECODER_FILE, map_location="cpu", weights_only=False)
    try:
        model.decoder.load_state_dict(blob["state_dict"])
    except RuntimeError as err:
        raise InputError(
            f"stage1.init_from={init_from}: its decoder is another network than this run's decoder config "
            f"({str(err).splitlines()[0]}); start from a folder trained with the same `decoder` group"
        ) from None
    table = load_codes(folder / codes_file("train"))
    if table.codes.shape[1] != model.codes.weight.shape[1]:
        raise InputError(
            f"stage1.init_from={init_from}: its codes have {table.codes.shape[1]} dimensions, this run's "
            f"{model.codes.weight.shape[1]}"
        )
    index = {shape_id: i for i, shape_id in enumerate(table.shape_ids)}
    taken = 0
    with torch.no_grad():
        for row, shape_id in enumerate(train_ids):
            if shape_id in index:
                model.codes.weight[row] = table.codes[index[shape_id]]
                taken += 1
    log.info(
        "stage 1 starts from %s: its decoder, and the codes of %d of %d training shapes", folder, taken, len(train_ids)
    )
    return taken
