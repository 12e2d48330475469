"""One stage-1 decoder per (category, data, decoder, stage-1 settings), shared by every stage-2 run.

A sweep such as `python train.py -m loss=es,nll,l2` needs the same decoder three times. The first
run to get here trains it; the others wait on a file lock and then reuse the finished folder. A
folder counts as finished only once its DONE marker exists (written last), so an interrupted
training is resumed from its last checkpoint rather than trusted.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
from filelock import FileLock
from omegaconf import DictConfig, OmegaConf

from ushape.decoder.artifacts import DONE_FILE, folder_problem
from ushape.decoder.precision import accelerator_device, training_bf16
from ushape.decoder.warm_start import init_fingerprint
from ushape.workspace import IDENTITY_FILE

log = logging.getLogger(__name__)

# The synthetic world is fully determined by its generating config, wherever it is cached; a real
# dataset's root *is* its content (3 sample chairs vs all of ShapeNet), so it stays in the identity.
_SYNTHETIC_TARGET = "ushape.data.world.SyntheticWorld"
# Data classes that moved after decoders were trained on them are hashed under their first name.
_FIRST_TARGET_NAMES = {"ushape.data.real.shapenet_world.ShapeNetWorld": "ushape.data.real_world.ShapeNetWorld"}
# Keys added to the stage-1 config after decoders were first trained, at the value every earlier
# decoder was trained with: left out of the identity there, so those decoders are still found.
_IMPLIED_STAGE1 = {
    ("module", "_target_"): "ushape.decoder.autodecoder.AutoDecoderModule",
    ("module", "optimizer"): {"_target_": "torch.optim.Adam", "_partial_": True},
}


def decoder_identity(cfg: DictConfig, legacy: bool = False) -> dict[str, Any]:
    """The part of the config that determines the stage-1 decoder (not logging, workers or device).

    legacy=True is the identity before stage1.data.num_workers was left out (see `legacy_decoder_dir_for`).
    """
    data = OmegaConf.to_container(cfg.data, resolve=True)
    data.pop("num_workers", None)
    stage1 = OmegaConf.to_container(cfg.stage1, resolve=True)
    if not legacy:
        # Loader processes change which random samples each batch draws, not the recipe being trained.
        (stage1.get("data") or {}).pop("num_workers", None)
    # Left out as the trainer's precision always was, so decoders trained before stage1.precision
    # existed (all fp32 on CPU) are still found.
    stage1.pop("precision", None)
    # bf16 "auto" is hashed as what it is on the trainer's device: false without AMX, the identity of
    # the fp32 decoders trained before "auto" existed; true where the training autocasts.
    device = trainer_device(cfg)
    for section in ("module", "latent_optim"):
        if (stage1.get(section) or {}).get("bf16") == "auto":
            stage1[section]["bf16"] = training_bf16("auto", device)
    # A warm start is named by the starting decoder's weights, not by where its folder lies; none: left out,
    # the identity of every decoder trained before init_from existed.
    if stage1.get("init_from") is None:
        stage1.pop("init_from", None)
    else:
        stage1["init_from"] = init_fingerprint(stage1["init_from"])
    for (section, key), value in _IMPLIED_STAGE1.items():
        if (stage1.get(section) or {}).get(key) == value:
            stage1[section].pop(key)
    if data.get("_target_") in _FIRST_TARGET_NAMES:
        data["_target_"] = _FIRST_TARGET_NAMES[data["_target_"]]
    if data.get("_target_") == _SYNTHETIC_TARGET:
        data.pop("root", None)
    elif data.get("root") is not None:
        data["root"] = str(Path(data["root"]).resolve())
    return {
        "category": cfg.category.name,
        "data": data,
        "decoder": OmegaConf.to_container(cfg.decoder, resolve=True),
        "stage1": stage1,
        "seed": int(cfg.seed),
    }


def trainer_device(cfg: DictConfig) -> torch.device:
    """The device the config's trainer trains on (its `accelerator`; none given: "auto")."""
    return accelerator_device(str((cfg.get("trainer") or {}).get("accelerator", "auto")))


def identity_hash(identity: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:12]


def decoder_dir_for(cfg: DictConfig, legacy: bool = False) -> Path:
    identity = decoder_identity(cfg, legacy)
    return Path(cfg.paths.decoders_dir).resolve() / f"{identity['category']}-{identity_hash(identity)}"


def legacy_decoder_dir_for(cfg: DictConfig) -> Path | None:
    """The decoder folder named by the older identity (with stage1.data.num_workers), if only it exists.

    Decoders trained, or being trained, before the worker count left the identity keep being found
    (and resumed from their checkpoints) instead of trained again from scratch.
    """
    folder, current = decoder_dir_for(cfg, legacy=True), decoder_dir_for(cfg)
    return folder if folder != current and folder.is_dir() and not current.exists() else None


def is_complete(decoder_dir: Path) -> bool:
    return (decoder_dir / DONE_FILE).exists()


def wait_until_complete(decoder_dir: Path, poll_s: float = 1.0) -> None:
    """Block until another process marks `decoder_dir` complete; fail if the process that started us dies."""
    parent = os.getppid()
    while not is_complete(decoder_dir):
        if os.getppid() != parent:
            raise RuntimeError(f"the process that launched this rank exited before finishing {decoder_dir}")
        time.sleep(poll_s)


def ensure_decoder(
    cfg: DictConfig, train: Callable[[Path], None], lock_timeout_s: float = -1, main: bool = True
) -> Path:
    """Return the finished decoder folder for `cfg`, calling `train(folder)` only if none exists yet.

    main=False is another rank of a DDP run whose rank 0 holds the lock: it calls `train` too (to join
    rank 0's fit, which alone writes the folder), then waits for the folder to be complete.
    """
    folder = legacy_decoder_dir_for(cfg) or decoder_dir_for(cfg)
    if main and is_complete(folder):
        problem = folder_problem(folder)
        if problem is None:
            log.info("Reusing the stage-1 decoder in %s", folder)
            return folder
        # Not trusted, not thrown away: rewritten from the last checkpoint (no epoch is trained again).
        log.warning(
            "the finished stage-1 decoder in %s is damaged (%s); rewriting it from its last checkpoint", folder, problem
        )
        with FileLock(str(folder) + ".lock", timeout=lock_timeout_s):
            if folder_problem(folder) is not None:
                (folder / DONE_FILE).unlink(missing_ok=True)
    elif is_complete(folder):
        return folder
    if not main:
        train(folder)
        wait_until_complete(folder)
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    identity_file = folder / IDENTITY_FILE
    with FileLock(str(folder) + ".lock", timeout=lock_timeout_s):
        if is_complete(folder):  # another run finished it while we waited
            log.info("Reusing the stage-1 decoder another run just finished: %s", folder)
            return folder
        from ushape import atomic

        atomic.write_json(identity_file, decoder_identity(cfg))
        log.info("Training the stage-1 decoder into %s", folder)
        train(folder)
        if not is_complete(folder):
            raise RuntimeError(f"stage-1 training returned without finishing {folder} (no {DONE_FILE} marker)")
    return folder
