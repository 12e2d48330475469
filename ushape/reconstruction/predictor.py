"""A trained stage-2 run as a predictor: images -> one Gaussian over the latent code per view.

Where a run lives (written by `python train.py`, see ushape.training.train):
    outputs/runs/<date>/<time>_encoder_<category>_<loss>/
      run.json                 {"stage": "encoder", "encoder_checkpoint": ..., "decoder_dir": ...}
      .hydra/config.yaml       the composed config; stage2.data.image_size is the model's input size
      checkpoints/best.ckpt    the encoder (its frozen decoder is loaded from hparams.decoder_path)
      checkpoints/temperature.json   written by `fit_and_store_temperature` (beside the checkpoint)

User images are read as RGBA; a missing alpha means opaque. Non-square images are padded to a
square with transparent pixels (so the object keeps its aspect ratio), resized to the model's
input size and composited on the same plain background that `mask_mode=gt_mask` trains with.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Sequence

import torch
import torch.nn.functional as F
from omegaconf import OmegaConf
from torch import Tensor, nn

from ushape import atomic
from ushape.checkpoints import load_checkpoint
from ushape.data.augment import IMAGE_SUFFIXES, CompositeBackground, load_rgba, resize
from ushape.data.layout import VIEWS_FILE
from ushape.data.real.shapenet_rendering import METADATA_FILE as R2N2_METADATA
from ushape.errors import InputError, MissingInputError
from ushape.recalibration.shared_error import SharedError
from ushape.recalibration.temperature import apply_temperature
from ushape.workspace import (
    BEST_FILE,
    CHECKPOINT_DIR,
    HYDRA_CONFIG,
    LAST_FILE,
    RUN_SUMMARY,
    RUNS_DIR,
    TEMPERATURE_FILE,
    VIEWPOINT_FILE,
    relocated,
)

log = logging.getLogger(__name__)

DEFAULT_CHECKPOINTS = (Path(CHECKPOINT_DIR) / BEST_FILE, Path(CHECKPOINT_DIR) / LAST_FILE)
# An input whose longer side is more than this many times below the model's input size is warned about.
SMALLEST_UPSCALE = 4
NO_RUN_HINT = "train one with `make demo` / `python train.py experiment=quickstart`"


def latest_run(root: str | Path = ".") -> Path:
    """The newest run folder under <root>/outputs/runs whose run.json says stage == encoder."""
    runs_dir = Path(root) / RUNS_DIR
    candidates = []
    for summary in runs_dir.glob(f"**/{RUN_SUMMARY}"):
        try:
            stage = json.loads(summary.read_text()).get("stage")
        except (OSError, ValueError):
            continue
        if stage == "encoder":
            candidates.append(summary)
    if not candidates:
        raise MissingInputError(
            f"no finished encoder run (run.json with stage=encoder) under {runs_dir}: {NO_RUN_HINT}"
        )
    return max(candidates, key=lambda p: p.stat().st_mtime).parent


def resolve_checkpoint(source: str | Path) -> tuple[Path, Path | None]:
    """(checkpoint file, run folder or None) from a run folder or a .ckpt path."""
    source = Path(source).expanduser()
    if source.is_file():
        run_dir = source.parent.parent
        return source, run_dir if (run_dir / HYDRA_CONFIG).is_file() else None
    if not source.is_dir():
        raise MissingInputError(f"{source} is neither a run folder nor a checkpoint file: {NO_RUN_HINT}")
    summary = source / RUN_SUMMARY
    recorded = read_summary(source).get("encoder_checkpoint") if summary.is_file() else None
    if recorded:
        # This run's own checkpoints/ folder, wherever run.json was written: a copied or moved run
        # must never evaluate the checkpoint of the folder it was copied from.
        own = source / CHECKPOINT_DIR / Path(recorded).name
        if not own.is_file():
            raise MissingInputError(
                f"run folder {source} has no {CHECKPOINT_DIR}/{own.name}, the checkpoint its "
                f"{RUN_SUMMARY} names (deleted, or the folder was copied without it): {NO_RUN_HINT}"
            )
        return own, source
    for name in DEFAULT_CHECKPOINTS:
        if (source / name).is_file():
            return source / name, source
    raise MissingInputError(f"run folder {source} holds no encoder checkpoint (checkpoints/best.ckpt): {NO_RUN_HINT}")


def read_summary(run_dir: Path) -> dict:
    """The run's run.json ({} without one); a damaged one is named."""
    path = run_dir / RUN_SUMMARY
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise InputError(f"{path} is damaged ({err}): rerun the training command to rewrite it") from err


def temperature_path(checkpoint: str | Path) -> Path:
    return Path(checkpoint).parent / TEMPERATURE_FILE


def stored_temperature(path: Path) -> dict:
    """temperature.json's record; a damaged file is named, with what to do."""
    return atomic.read_json_object(path, "delete it and refit with `python reconstruct.py --fit-temperature --run RUN`")


def read_temperatures(checkpoint: str | Path) -> tuple[float, float | None]:
    """(latent T, SDF-space T or None where only a latent one was fitted), as `fit_and_store_temperature`
    stored them beside a checkpoint, read in one go."""
    path = temperature_path(checkpoint)
    if not path.is_file():
        raise MissingInputError(
            f"no {TEMPERATURE_FILE} beside {checkpoint}: fit it first with `python reconstruct.py --fit-temperature "
            f"--checkpoint {checkpoint}`"
        )
    record = stored_temperature(path)
    sdf = record.get("sdf_temperature")
    return float(record["temperature"]), None if sdf is None else float(sdf)


def read_shared_error(checkpoint: str | Path) -> SharedError | None:
    """The shared error S, view scale c and the rule's SDF temperature stored beside a checkpoint by
    `fit_and_store_temperature`, or None where no temperature was fitted, or it was fitted before S was
    (refit to get one). A fit stored before the rule had its own SDF temperature gets the single-view one."""
    path = temperature_path(checkpoint)
    if not path.is_file():
        return None
    stored = stored_temperature(path)
    record = stored.get("shared_error")
    if record is None:
        return None
    fit = SharedError.from_record(record)
    if fit.sdf_temperature is None and stored.get("sdf_temperature") is not None:
        log.info(
            "%s holds no SDF temperature for the shared rule (fitted before it had one): its fused SDF std "
            "uses the single-view T_sdf = %.3g; refit with `python reconstruct.py --fit-temperature`",
            path,
            float(stored["sdf_temperature"]),
        )
        fit = replace(fit, sdf_temperature=float(stored["sdf_temperature"]))
    return fit


def run_config(run_dir: Path | None) -> dict:
    """The run's composed Hydra config as a plain dict ({} without a run folder)."""
    if run_dir is None or not (run_dir / HYDRA_CONFIG).is_file():
        return {}
    return OmegaConf.to_container(OmegaConf.load(run_dir / HYDRA_CONFIG), resolve=False)


def input_settings(checkpoint_blob: dict, config: dict) -> tuple[int, str]:
    """(image_size, mask_mode) of the model's inputs: the run config first, then the checkpoint's datamodule."""
    data = dict(checkpoint_blob.get("datamodule_hyper_parameters") or {})
    data.update((config.get("stage2") or {}).get("data") or {})
    if "image_size" not in data:
        raise ValueError(
            "cannot tell the model's input size: pass the run folder (with .hydra/config.yaml) "
            "or a checkpoint trained with EncoderDataModule"
        )
    return int(data["image_size"]), str(data.get("mask_mode", "gt_mask"))


@dataclass
class Predictor:
    """An encoder checkpoint, its frozen decoder and how it wants its input images."""

    model: nn.Module  # EncoderModule in eval mode
    image_size: int
    checkpoint: Path
    run_dir: Path | None = None
    temperature: float | None = None
    sdf_temperature: float | None = None  # scales the SDF variance propagated from the (T-scaled) latent one
    mask_mode: str = "gt_mask"
    background_value: float = 1.0
    world: Path | None = field(default=None)
    # Where R2N2's frame sits in the model's, (r2n2_centre [3], r2n2_scale), for R2N2 renders' cameras; None:
    # the run's world tells (`refinement.inputs.typical_r2n2_frame`), a shipped model's model.json says
    r2n2_frame: tuple | None = None
    model_name: str | None = None  # the shipped model's name (ushape/pretrained/<name>); None: a trained run
    # The camera-azimuth head stored beside the checkpoint (reconstruct.py --fit-viewpoint); None: not fitted
    viewpoint: nn.Module | None = None

    @torch.no_grad()
    def features(self, images: Tensor) -> Tensor:
        """The frozen backbone's features [V, F] of images [V, 3, S, S] (what the heads read)."""
        self.model.eval()
        return self.model.encoder.features(images.float())

    def azimuth_log_probs(self, images: Tensor) -> Tensor | None:
        """log p(camera azimuth bin) [V, bins] of each image (`ushape.encoder.viewpoint`); None without a head."""
        return None if self.viewpoint is None else self.viewpoint.log_probs(self.features(images))

    @property
    def decoder(self) -> nn.Module:
        return self.model.decoder

    @property
    def latent_size(self) -> int:
        return int(self.model.encoder.head.latent_size)

    @torch.no_grad()
    def encode(self, images: Tensor) -> tuple[Tensor, Tensor]:
        """images [V, 3, H, W] in [0, 1] at the model's size -> (mu [V, D], var [V, D]), T-scaled if set."""
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"images must be [V, 3, H, W] RGB in [0, 1], got {tuple(images.shape)}")
        if images.shape[-2:] != (self.image_size, self.image_size):
            raise ValueError(
                f"images are {tuple(images.shape[-2:])}, the model takes {self.image_size}px: "
                "use `prepare` or `load_images`"
            )
        self.model.eval()
        mu, logvar = self.model(images.float())
        var = logvar.exp()
        return mu, (apply_temperature(var, self.temperature) if self.temperature is not None else var)

    def prepare(self, rgba: Tensor) -> Tensor:
        """Premultiplied RGBA [4, H, W] of any size -> model input RGB [3, S, S] on the training background."""
        composite = CompositeBackground("gt_mask", self.background_value)
        return composite(resize(pad_square(rgba), self.image_size))

    def load_images(
        self, paths: Sequence[str | Path], masks: Sequence[str | Path] | None = None, reframe: bool = True
    ) -> tuple[Tensor, list[Path], list[tuple[Path, str]]]:
        """(images [V, 3, S, S], the paths read, [(path, why)] skipped); a ValueError if none is readable.

        masks: one mask file per path (white = object), cutting the object out where the image has no alpha.
        reframe: a photo (not a render) whose object is framed unlike the training renders is cropped and
        padded to their framing (`frame_object`); renders are taken as they are.
        """
        if masks is not None and len(masks) != len(paths):
            raise InputError(f"{len(masks)} mask files for {len(paths)} images: pass one mask per image, in order")
        images, kept, skipped = [], [], []
        for i, path in enumerate(paths):
            try:
                rgba = load_rgba(path)
                if max(rgba.shape[-2:]) * SMALLEST_UPSCALE < self.image_size:
                    log.warning(
                        "%s is only %dx%d px, the model sees %d px: upsampling it adds no detail, expect a vague shape",
                        path,
                        rgba.shape[-1],
                        rgba.shape[-2],
                        self.image_size,
                    )
                if masks is not None:
                    rgba = cut_out(rgba, load_rgba(masks[i])[:3].mean(0) > 0.5, f"mask {masks[i]} of {path}")
                check_cut_out(rgba, path)
                if reframe and not is_render(path):
                    rgba = frame_object(rgba)
                images.append(self.prepare(rgba))
                kept.append(Path(path))
            except (ValueError, FileNotFoundError) as err:
                log.warning("skipped %s: %s", path, err)
                skipped.append((Path(path), str(err)))
        if not images:
            raise ValueError(
                f"none of the {len(paths)} input image(s) could be read: "
                + "; ".join(f"{p}: {why}" for p, why in skipped)
            )
        return torch.stack(images), kept, skipped


# How the training renders frame the object (R2N2's protocol). Measured on the r2n2 chairs and tables worlds
# (240 renders each): the object's bounding box spans 0.51-0.84 of the image side (5th-95th percentile,
# median 0.65), its centre within 0.09 of the image centre (95th percentile). A photo outside these bounds is
# cropped and padded so that its object spans FRAMED_SPAN about the centre.
FRAMED_SPANS, FRAMED_OFFSET, FRAMED_SPAN = (0.45, 0.90), 0.15, 0.65
# A border whose colours vary less than this (std over its pixels, RGB in [0, 1]) is a plain background.
PLAIN_BORDER_STD = 0.03


def is_render(path: str | Path) -> bool:
    """A render with its camera beside it (ours: views.npz; R2N2's: rendering_metadata.txt), named by its view."""
    path = Path(path)
    return path.stem.isdigit() and any((path.parent / name).is_file() for name in (VIEWS_FILE, R2N2_METADATA))


def cut_out(rgba: Tensor, mask: Tensor, source: str) -> Tensor:
    """Premultiplied RGBA [4, H, W] with alpha = mask [H, W] bool (the object), the rest transparent."""
    if tuple(mask.shape) != tuple(rgba.shape[-2:]):
        raise InputError(
            f"{source} is {mask.shape[1]}x{mask.shape[0]} pixels, the image {rgba.shape[2]}x{rgba.shape[1]}: "
            "pass a mask of the image's size"
        )
    alpha = mask.float()
    straight = rgba[:3] / rgba[3:].clamp(min=1e-6)
    return torch.cat([straight * alpha, alpha[None]])


def check_cut_out(rgba: Tensor, path: str | Path) -> None:
    """An InputError for a photo the model cannot read: opaque (no alpha, no mask) on a background that is not
    plain. The model was trained on objects cut out from their background."""
    if float(rgba[3].min()) < 0.99:
        return
    border = torch.cat([rgba[:3, 0], rgba[:3, -1], rgba[:3, :, 0], rgba[:3, :, -1]], dim=1)  # [3, P]
    if float(border.std(dim=1).max()) <= PLAIN_BORDER_STD:
        return
    raise InputError(
        f"{path} has no alpha channel and no mask, on a background that is not plain: the model reads objects "
        "cut out from their background. Pass a mask (--masks MASK.png, white = object, one per image) or an RGBA "
        "PNG whose alpha marks the object"
    )


def frame_object(rgba: Tensor) -> Tensor:
    """Premultiplied RGBA [4, H, W] -> a square [4, S, S] framing the object (alpha > 0.5) as the training renders
    do: unchanged but padded square where it already does (`FRAMED_SPANS`, `FRAMED_OFFSET`), else a square about
    the object's box spanning it by FRAMED_SPAN, transparent where it leaves the image."""
    square = pad_square(rgba)
    inside = square[3] > 0.5
    if not bool(inside.any()) or float(rgba[3].min()) > 0.99:  # nothing, or no alpha: the object is not marked
        return square
    side = square.shape[-1]
    rows, cols = inside.any(1).nonzero()[:, 0], inside.any(0).nonzero()[:, 0]
    box = max(int(rows[-1] - rows[0]) + 1, int(cols[-1] - cols[0]) + 1)
    centre = ((float(rows[0] + rows[-1]) + 1) / 2, (float(cols[0] + cols[-1]) + 1) / 2)
    offset = max(abs(centre[0] - side / 2), abs(centre[1] - side / 2)) / side
    if FRAMED_SPANS[0] <= box / side <= FRAMED_SPANS[1] and offset <= FRAMED_OFFSET:
        return square
    crop = max(1, round(box / FRAMED_SPAN))
    top, left = round(centre[0] - crop / 2), round(centre[1] - crop / 2)
    padded = F.pad(square, (max(0, -left), max(0, left + crop - side), max(0, -top), max(0, top + crop - side)))
    top, left = max(0, top), max(0, left)
    return padded[:, top : top + crop, left : left + crop]


def pad_square(rgba: Tensor) -> Tensor:
    """RGBA [4, H, W] -> [4, S, S], S = max(H, W), centred, padded with transparent pixels."""
    if rgba.ndim != 3 or rgba.shape[0] != 4:
        raise ValueError(f"expected premultiplied RGBA [4, H, W], got {tuple(rgba.shape)}")
    h, w = rgba.shape[-2:]
    size = max(h, w)
    top, left = (size - h) // 2, (size - w) // 2
    return F.pad(rgba, (left, size - w - left, top, size - h - top))


def collect_inputs(inputs: Iterable[str | Path]) -> list[Path]:
    """Image files from files and folders (a folder contributes its images, sorted by name)."""
    files: list[Path] = []
    for item in inputs:
        path = Path(item).expanduser()
        if path.is_dir():
            # Hidden files are no views: macOS's ._x.png, or the temporary file of an interrupted write.
            found = sorted(
                p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")
            )
            if not found:
                raise FileNotFoundError(f"folder {path} holds no {'/'.join(IMAGE_SUFFIXES)} images")
            files += found
        else:
            files.append(path)  # missing or unreadable files are reported per image by load_images
    if not files:
        raise ValueError("no input images given: pass one image, several, or a folder of them")
    return files


def trained_decoder(blob: dict, checkpoint: Path, run_dir: Path | None) -> Path:
    """The stage-1 decoder folder the encoder was trained against, found again if outputs/ moved."""
    recorded = (blob.get("hyper_parameters") or {}).get("decoder_path")
    if not recorded:
        raise InputError(f"checkpoint {checkpoint} records no decoder_path: not an encoder checkpoint of ushape")
    path = relocated(recorded, run_dir)
    if not path.exists():
        raise MissingInputError(
            f"the stage-1 decoder that {checkpoint} was trained against is gone: not at {recorded}"
            + (" nor at the same place under the outputs/ folder holding the run" if run_dir else "")
            + "; restore that folder (a retrained decoder would not match this encoder)"
        )
    return path


def load_predictor(
    source: str | Path | None = None,
    temperature: bool = False,
    root: str | Path = ".",
) -> Predictor:
    """A Predictor from a run folder or checkpoint (None: the newest encoder run under <root>/outputs/runs).

    temperature=True applies the T stored beside the checkpoint (var' = T var), and its SDF-space
    temperature where one was fitted (to the SDF and vertex variance propagated from var').
    """
    from ushape.encoder.module import EncoderModule  # lightning is imported only when a model is loaded

    run_dir = latest_run(root) if source is None else None
    checkpoint, run_dir = resolve_checkpoint(run_dir or source)
    blob = load_checkpoint(checkpoint)
    config = run_config(run_dir)
    image_size, mask_mode = input_settings(blob, config)
    model = EncoderModule.load_from_checkpoint(
        checkpoint, map_location="cpu", weights_only=False, decoder_path=str(trained_decoder(blob, checkpoint, run_dir))
    )
    model.eval()
    summary = read_summary(run_dir) if run_dir else {}
    world = relocated(summary["world"], run_dir) if summary.get("world") else None
    latent_t, sdf_t = read_temperatures(checkpoint) if temperature else (None, None)
    return Predictor(
        model=model,
        image_size=image_size,
        checkpoint=Path(checkpoint),
        run_dir=run_dir,
        temperature=latent_t,
        sdf_temperature=sdf_t,
        mask_mode=mask_mode,
        world=world,
        viewpoint=stored_viewpoint(checkpoint),
    )


def stored_viewpoint(checkpoint: str | Path) -> nn.Module | None:
    """The camera-azimuth head beside a checkpoint (reconstruct.py --fit-viewpoint), or None."""
    from ushape.encoder.viewpoint import load_viewpoint_head

    path = Path(checkpoint).parent / VIEWPOINT_FILE
    return load_viewpoint_head(path) if path.is_file() else None
