"""Training codes made the way held-out codes are: latent optimisation against the frozen decoder.

Stage 1 leaves two kinds of codes. Training codes are auto-decoded: learnt jointly with the
network, capped at norm 1, and not converged (optimising further from them still moves them).
Val/test codes come from latent optimisation from a near-zero start. An encoder trained on the
first kind and scored on the second learns one mapping and is judged on another: measured on the
quickstart chairs, re-optimising training shapes from scratch lands 0.49 from their stage-1 codes,
while a typical code is 0.85 from the mean. The re-coded folder is a complete stage-1 folder
(same decoder, `codes_train.pt` by `optimise_codes` with the settings that made val/test, val/test
codes as they were, DONE last) that stage 2, evaluation and reconstruct use unchanged.
"""

from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path
from typing import Any, Mapping

from ushape import atomic
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.artifacts import (
    DECODER_FILE,
    DONE_FILE,
    CodeTable,
    codes_file,
    derived_folder,
    load_decoder,
    save_codes,
)
from ushape.decoder.latent_optim import optimise_codes

log = logging.getLogger(__name__)

CODE_SOURCES = ("autodecoder", "reoptimised")


def recode_folder(
    decoder_dir: str | Path, out_dir: str | Path, world_root: str | Path, latent_optim: Mapping[str, Any] | None
) -> Path:
    """Write the re-coded copy of a finished stage-1 folder (module docstring); DONE is written last."""
    decoder_dir, out_dir = Path(decoder_dir), Path(out_dir)
    if not (decoder_dir / DONE_FILE).is_file():
        raise FileNotFoundError(f"{decoder_dir} is not a finished stage-1 folder (no {DONE_FILE}); train stage 1 first")
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy2(decoder_dir / DECODER_FILE, out_dir / DECODER_FILE)
    for split in ("val", "test"):
        shutil.copy2(decoder_dir / codes_file(split), out_dir / codes_file(split))
    shapes = SDFSamplesDataset(world_root, "train", samples_per_shape=2)  # optimise_codes draws its own
    started = time.time()
    codes = optimise_codes(load_decoder(decoder_dir, frozen=True), shapes, **dict(latent_optim or {}))
    seconds = time.time() - started
    log.info("re-optimised %d training codes in %.1f s", len(shapes), seconds)
    save_codes(out_dir / codes_file("train"), CodeTable(shapes.shape_ids, codes))
    atomic.write_json(
        out_dir / DONE_FILE,
        {
            "codes": "reoptimised",
            "source": str(decoder_dir.resolve()),
            "latent_optim": dict(latent_optim or {}),
            "seconds": round(seconds, 1),
        },
    )
    return out_dir


def ensure_codes(
    decoder_dir: str | Path, source: str, world_root: str | Path, latent_optim: Mapping[str, Any] | None = None
) -> Path:
    """The stage-1 folder whose codes stage 2 learns: the folder itself (autodecoder) or <folder>/codes_reoptimised."""
    if source not in CODE_SOURCES:
        raise ValueError(f"codes must be one of {CODE_SOURCES}, got {source!r}")
    decoder_dir = Path(decoder_dir)
    if source == "autodecoder":
        return decoder_dir
    return derived_folder(
        decoder_dir / f"codes_{source}",
        lambda out: recode_folder(decoder_dir, out, world_root, latent_optim),
        "training codes re-optimised like the held-out ones",
    )
