"""What `python train.py` does: build the data, make sure stage 1 exists, train stage 2, report."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import lightning as L
from hydra.utils import instantiate
from lightning.pytorch.callbacks import Callback, LearningRateMonitor
from omegaconf import DictConfig, OmegaConf

from ushape import atomic
from ushape.builders import build_all
from ushape.data.layout import WorldIndex
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.decoder.basis import ensure_basis
from ushape.decoder.fit import fit_decoder
from ushape.decoder.precision import training_bf16
from ushape.decoder.recode import ensure_codes
from ushape.encoder.fit import fit_encoder
from ushape.errors import InputError
from ushape.training.decoder_store import ensure_decoder, trainer_device
from ushape.training.demo_meshes import demo_digest, write_demo_meshes
from ushape.training.summary import print_config, print_summary
from ushape.workspace import RUN_SUMMARY

log = logging.getLogger(__name__)


def train_stages(cfg: DictConfig, out_dir: Path, main: bool) -> float | None:
    """Train the configured stage(s) of a checked config into out_dir (`entry.run` guards it); the val metric."""
    out_dir.mkdir(parents=True, exist_ok=True)
    if main:
        print_config(cfg, out_dir / "config_tree.txt")
    L.seed_everything(cfg.seed, workers=True)
    started = time.time()

    resolve_training_bf16(cfg)
    world = build_world(cfg)
    decoder_dir = ensure_decoder(cfg, lambda folder: train_decoder(cfg, world, folder), main=main)
    summary: dict[str, Any] = {"stage": cfg.stage, "world": str(world.root.resolve()), "decoder_dir": str(decoder_dir)}
    metric = None
    if cfg.stage == "encoder":
        coded_dir = ensure_codes(
            decoder_dir, cfg.stage2.get("codes", "autodecoder"), world.root, _plain(cfg.stage1.latent_optim)
        )
        latent_dir = ensure_basis(coded_dir, cfg.stage2.get("latent_basis", "identity"))
        if latent_dir != decoder_dir:
            summary["latent_basis_dir"] = str(latent_dir)
        checkpoint = train_encoder(cfg, world, latent_dir, out_dir)
        if not main:
            return None
        summary["encoder_checkpoint"] = str(checkpoint)
        demo = _plain(cfg.stage2.get("demo_meshes") or {})
        codes_path = latent_dir / codes_file(demo.get("split", "val"))
        meshes = write_demo_meshes(
            checkpoint,
            world,
            out_dir / "meshes",
            **demo,
            fusion=instantiate(cfg.fusion) if cfg.get("fusion") else None,
            codes=load_codes(codes_path) if codes_path.is_file() else None,
        )
        if meshes is not None:
            summary["meshes"] = str(meshes)
            summary["demo"] = demo_digest(meshes)
        summary["tensorboard"] = str(out_dir / "tensorboard")
        metric = _checkpoint_score(checkpoint)
    elif not main:
        return None
    else:
        summary["tensorboard"] = str(decoder_dir / "tensorboard")
    summary["seconds"] = round(time.time() - started, 1)
    atomic.write_json(out_dir / RUN_SUMMARY, summary)
    print_summary(summary, out_dir)
    return metric


# The bf16 autocast switches of training: true, false or "auto" (where precision auto picks bf16).
TRAINING_BF16_KEYS = ("stage1.module.bf16", "stage1.latent_optim.bf16", "stage2.module.bf16")


def resolve_training_bf16(cfg: DictConfig) -> None:
    """Write true / false over every "auto" bf16 switch, for the trainer's device, before anything reads them.

    The stage-1 decoder's identity (its folder's hash) then names the precision it was trained in: on a
    CPU without AMX "auto" is false, the same identity as the fp32 decoders trained before "auto" existed.
    """
    device = trainer_device(cfg)
    for key in TRAINING_BF16_KEYS:
        value = OmegaConf.select(cfg, key)
        if value is None:
            continue
        try:
            OmegaConf.update(cfg, key, training_bf16(value, device))
        except ValueError as err:
            raise InputError(f"{key}: {err}") from None


def build_world(cfg: DictConfig) -> WorldIndex:
    """Instantiate the `data` config (synthetic, shapenet, ...) and build or validate its cache."""
    started = time.time()
    world = instantiate(cfg.data).build()
    log.info(
        "data ready in %.1f s: %s (%s)",
        time.time() - started,
        world.root,
        ", ".join(f"{k} {len(v)}" for k, v in world.splits.items()),
    )
    return world


def train_decoder(cfg: DictConfig, world: WorldIndex, folder: Path) -> None:
    s1 = cfg.stage1
    fit_decoder(
        callbacks=build_callbacks(cfg, logging=True),
        world_root=world.root,
        out_dir=folder,
        decoder=_plain(cfg.decoder),
        module=_plain(s1.module),
        trainer=stage_trainer(cfg.trainer, s1),
        data=_plain(s1.data),
        latent_optim=_plain(s1.latent_optim),
        checkpoint_every_n_epochs=s1.checkpoint_every_n_epochs,
        seed=cfg.seed,
        init_from=s1.get("init_from"),
    )


def train_encoder(cfg: DictConfig, world: WorldIndex, decoder_dir: Path, out_dir: Path) -> Path:
    s2 = cfg.stage2
    logger = instantiate(cfg.logger) if cfg.get("logger") else False
    return fit_encoder(
        callbacks=build_callbacks(cfg, logging=logger is not False),
        world_root=world.root,
        decoder_dir=decoder_dir,
        out_dir=out_dir,
        encoder=_plain(cfg.encoder),
        loss=_plain(cfg.loss),
        module={**_plain(s2.module), "max_epochs": s2.max_epochs},
        data={**_plain(s2.data), "seed": cfg.seed},
        trainer=stage_trainer(cfg.trainer, s2),
        logger=logger,
    )


def build_callbacks(cfg: DictConfig, logging: bool) -> list[Callback]:
    """The `callbacks` group's callbacks; without a logger, not those that only log (LearningRateMonitor)."""
    callbacks = build_all(cfg.get("callbacks"))
    return [c for c in callbacks if logging or not isinstance(c, LearningRateMonitor)]


def stage_trainer(trainer: DictConfig, stage: DictConfig) -> dict[str, Any]:
    """Trainer kwargs of one stage: the trainer group with the stage's epochs, and its precision unless null."""
    kwargs = {**_plain(trainer), "max_epochs": stage.max_epochs}
    if stage.get("precision") is not None:
        kwargs["precision"] = stage.precision
    return kwargs


def _checkpoint_score(checkpoint: Path) -> float | None:
    import torch

    blob = torch.load(checkpoint, map_location="cpu", weights_only=False)
    for callback in blob.get("callbacks", {}).values():
        score = callback.get("best_model_score") if isinstance(callback, dict) else None
        if score is not None:
            return float(score)
    return None


def _plain(node: Any) -> Any:
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node
