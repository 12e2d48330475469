"""Stage 2 as a LightningModule: train the image encoder on (view, stage-1 code) pairs.

The paper: ResNet-50 from ImageNet, lr 0.1, batch 64, polynomial lr decay, 50 epochs. lr 0.1 is
an SGD-with-momentum learning rate (Adam diverges at that size), so SGD with momentum 0.9 is the
default. The optimiser is a Hydra `_partial_` config (conf/optimizer/), built over the trainable
parameters in `configure_optimizers`. The poly schedule decays every step:
lr_k = lr * (1 - k / K) ** poly_power over the K steps of `max_epochs` epochs.
"""

from __future__ import annotations

import functools
import inspect
import math
from pathlib import Path
from typing import Any, Callable, Mapping

import lightning as L
import torch
from hydra.utils import instantiate
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import OmegaConf
from torch import Tensor

from ushape.builders import build
from ushape.decoder.artifacts import codes_file, load_codes, load_decoder
from ushape.decoder.precision import training_bf16
from ushape.encoder.figures import mesh_panel, render_code
from ushape.encoder.heads import GaussianEnsemble, ImageEncoder
from ushape.encoder.latent_metrics import latent_scores
from ushape.encoder.losses import ensemble_loss, l2_loss
from ushape.metrics.calibration import calibration_curve, plot_calibration

LossFn = Callable[..., Tensor]


def loss_config(loss: LossFn | Mapping[str, Any]) -> dict[str, Any]:
    """A Hydra partial config for a loss given as a config or as a function / functools.partial."""
    if OmegaConf.is_config(loss):
        loss = OmegaConf.to_container(loss, resolve=True)
    if isinstance(loss, Mapping):
        if "_target_" not in loss:
            raise ValueError("the loss config needs a `_target_`, e.g. ushape.encoder.losses.energy_score")
        return {**loss, "_partial_": True}
    func, keywords = (loss.func, dict(loss.keywords)) if isinstance(loss, functools.partial) else (loss, {})
    return {"_target_": f"{func.__module__}.{func.__qualname__}", "_partial_": True, **keywords}


HEAD_INITS = ("fixed", "prior")
PAPER_OPTIMIZER = {"_target_": "torch.optim.SGD", "_partial_": True, "lr": 0.1, "momentum": 0.9, "weight_decay": 1e-4}
# Checkpoints written before optimisers were configs name one of these (with lr, momentum, weight_decay).
NAMED_OPTIMIZERS = {"sgd": "torch.optim.SGD", "adam": "torch.optim.Adam", "adamw": "torch.optim.AdamW"}


def optimizer_config(
    optimizer: Mapping[str, Any] | str,
    lr: float | None = None,
    momentum: float | None = None,
    weight_decay: float | None = None,
) -> dict[str, Any]:
    """The optimiser as a `_partial_` config; lr, momentum and weight_decay, where given, override its values.

    A name (sgd, adam, adamw) is what checkpoints before configured optimisers hold: it becomes that
    class with their defaults (lr 0.1, weight decay 1e-4, SGD's momentum 0.9).
    """
    if OmegaConf.is_config(optimizer):
        optimizer = OmegaConf.to_container(optimizer, resolve=True)
    if isinstance(optimizer, str):
        if optimizer not in NAMED_OPTIMIZERS:
            raise ValueError(
                f"optimizer must be a `_partial_` config or one of {sorted(NAMED_OPTIMIZERS)}, got {optimizer!r}"
            )
        config = {"_target_": NAMED_OPTIMIZERS[optimizer], "_partial_": True, "lr": 0.1, "weight_decay": 1e-4}
        if optimizer == "sgd":
            config["momentum"] = 0.9
        else:  # those checkpoints hold momentum=0.9 whatever the optimiser; only SGD took it
            momentum = None
    elif isinstance(optimizer, Mapping) and "_target_" in optimizer:
        config = {**optimizer, "_partial_": True}
    else:
        raise ValueError(f"optimizer needs a `_target_` (e.g. torch.optim.SGD), got {optimizer!r}")
    overrides = {"lr": lr, "momentum": momentum, "weight_decay": weight_decay}
    return {**config, **{k: v for k, v in overrides.items() if v is not None}}


def code_prior(decoder_path: str | Path) -> tuple[Tensor, Tensor]:
    """Mean [D] and per-dimension variance [D] of the stage-1 training codes beside the decoder."""
    folder = Path(decoder_path)
    folder = folder if folder.is_dir() else folder.parent
    codes = load_codes(folder / codes_file("train")).codes
    if codes.shape[0] < 2:
        raise ValueError(f"head_init=prior needs at least 2 training codes in {folder}; use head_init=fixed")
    return codes.mean(0), codes.var(0)


class EncoderModule(L.LightningModule):
    """Image encoder (backbone + Gaussian head) with a latent-space loss; the decoder only for pictures.

    The frozen decoder is loaded from `decoder_path` (a path is the hyperparameter, never a module)
    and kept outside the module tree: it is in neither the optimiser nor the checkpoint.
    A model trained with `l2_loss` predicts no variance; it is scored with the paper's
    equal-variance baseline sigma^2 = 1. head_init="prior" starts the head at the training codes'
    mean and per-dimension variance instead of log-variance -4 everywhere: Adam moves a bias by about
    lr per step, so in a few hundred CPU steps (lr 1e-3) the fixed start can move each log-variance
    by well under one unit and the variances stay nearly equal across dimensions.
    """

    def __init__(
        self,
        decoder_path: str,
        encoder: Mapping[str, Any],
        loss: LossFn | Mapping[str, Any],
        optimizer: Mapping[str, Any] | str = PAPER_OPTIMIZER,
        lr: float | None = None,
        momentum: float | None = None,
        weight_decay: float | None = None,
        poly_power: float = 0.9,
        max_epochs: int | None = None,
        bf16: bool | str = False,
        val_samples: int = 1000,
        calibration_levels: int = 20,
        log_meshes: bool = False,
        mesh_views: int = 4,
        mesh_resolution: int = 48,
        head_init: str = "fixed",
    ) -> None:
        super().__init__()
        if head_init not in HEAD_INITS:
            raise ValueError(f"head_init must be one of {HEAD_INITS}, got {head_init!r}")
        if OmegaConf.is_config(encoder):
            encoder = OmegaConf.to_container(encoder, resolve=True)
        # Rebound before save_hyperparameters, which reads the locals: plain dicts, loadable later.
        encoder, loss = dict(encoder), loss_config(loss)
        optimizer = optimizer_config(optimizer, lr, momentum, weight_decay)
        lr = momentum = weight_decay = None  # folded into `optimizer`
        self.save_hyperparameters()
        self.loss_fn = instantiate(loss)
        self._loss_takes_generator = "generator" in inspect.signature(self.loss_fn).parameters
        self.predicts_variance = getattr(self.loss_fn, "func", self.loss_fn) is not l2_loss
        self.encoder = build(encoder, ImageEncoder)  # its `_target_` (an ImageEncoder subclass), else ImageEncoder
        # object.__setattr__ keeps the decoder out of parameters(), state_dict() and the optimiser.
        object.__setattr__(self, "decoder", load_decoder(decoder_path, frozen=True))
        decoder_latent = getattr(self.decoder, "latent_size", None)
        if decoder_latent is not None and decoder_latent != self.encoder.head.latent_size:
            raise ValueError(
                f"encoder.latent_size={self.encoder.head.latent_size} but the decoder at "
                f"{decoder_path} takes codes of size {decoder_latent}; set encoder.latent_size={decoder_latent}"
            )
        if head_init == "prior":
            mean, var = code_prior(decoder_path)
            self.encoder.head.start_at(mean, var)
        self._outputs: dict[str, list] = {}

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        """images [B, 3, H, W] in [0, 1] -> (mu [B, D], logvar [B, D]); logvar is 0 for an l2 model."""
        return self._head_outputs(lambda: self.encoder(images), images.device)

    def _head_outputs(self, run: Callable[[], tuple[Tensor, Tensor]], device: torch.device) -> tuple[Tensor, Tensor]:
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=training_bf16(self.hparams.bf16, device)):
            mu, logvar = run()
        mu, logvar = mu.float(), logvar.float()
        # x0 rather than zeros_like keeps the unused head in the graph (DDP wants every parameter used).
        return (mu, logvar) if self.predicts_variance else (mu, logvar * 0.0)

    def predict_batch(self, batch: dict) -> tuple[Tensor, Tensor]:
        """(mu, logvar) [B, D] of a batch of images, or of cached backbone features (FeatureDataModule)."""
        if "features" in batch:
            features = self.encoder.head_input(batch["features"])
            return self._head_outputs(lambda: self.encoder.head(features), features.device)
        return self(batch["image"])

    def training_step(self, batch: dict, batch_idx: int) -> Tensor:
        head = self.encoder.head
        if isinstance(head, GaussianEnsemble):
            loss = self._ensemble_loss(head, batch)
            batch_size = len(batch["shape_id"])
        else:
            mu, logvar = self.predict_batch(batch)
            loss, batch_size = self.loss_fn(mu, logvar, batch["code"]), mu.shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=batch_size)
        return loss

    def _ensemble_loss(self, head: GaussianEnsemble, batch: dict) -> Tensor:
        """`ensemble_loss` over the members' shares of the batch (cross-fitted if the head says so)."""
        features = self.encoder.head_input(
            batch["features"] if "features" in batch else self.encoder.features(batch["image"])
        )
        mus, logvars = self._head_outputs(lambda: head.member_outputs(features), features.device)
        member_of = head.member_of(list(batch["shape_id"])).to(features.device)
        return ensemble_loss(self.loss_fn, mus, logvars, batch["code"], member_of, head.cross_fit)

    def _eval_step(self, batch: dict, prefix: str) -> None:
        mu, logvar = self.predict_batch(batch)
        generator = torch.Generator(device=mu.device).manual_seed(0)
        loss = self.loss_fn(
            mu, logvar, batch["code"], **({"generator": generator} if self._loss_takes_generator else {})
        )
        self.log(f"{prefix}/loss", loss, prog_bar=True, batch_size=mu.shape[0], sync_dist=True)
        out = self._outputs
        for key, value in (("mu", mu), ("logvar", logvar), ("code", batch["code"])):
            out.setdefault(key, []).append(value.detach())
        if self.hparams.log_meshes and "image" in batch and len(out.setdefault("images", [])) < self.hparams.mesh_views:
            take = self.hparams.mesh_views - len(out["images"])
            out["images"] += list(batch["image"][:take].detach().cpu())
            out.setdefault("mesh_codes", []).extend(zip(mu[:take].detach(), batch["code"][:take]))

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, "val")

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, "test")

    def on_validation_epoch_end(self) -> None:
        self._log_epoch_scores("val")

    def on_test_epoch_end(self) -> None:
        self._log_epoch_scores("test")

    def _log_epoch_scores(self, prefix: str) -> None:
        out, self._outputs = self._outputs, {}
        if not out.get("mu"):
            return
        mu, logvar, code = (self._gathered(out[k]) for k in ("mu", "logvar", "code"))
        generator = torch.Generator(device=mu.device).manual_seed(0)
        scores = latent_scores(mu, logvar, code, self.hparams.val_samples, self.hparams.calibration_levels, generator)
        if not self.predicts_variance:
            scores.pop("rank_corr")  # a constant variance ranks nothing
        for name, value in scores.items():
            self.log(f"{prefix}/{name}", value.float())
        self._log_figures(prefix, mu, logvar, code, out)

    def _gathered(self, parts: list[Tensor]) -> Tensor:
        """This rank's [N_r, D] pieces, joined across all ranks -> [N, D]."""
        local = torch.cat(parts)
        return self.all_gather(local).reshape(-1, local.shape[-1]) if self.trainer.world_size > 1 else local

    def _log_figures(self, prefix: str, mu: Tensor, logvar: Tensor, code: Tensor, out: dict) -> None:
        writer = self._tensorboard()
        if writer is None or self.trainer.sanity_checking:
            return
        levels, err = self.hparams.calibration_levels, (mu - code).abs()
        curves = {"equal variance (sigma=1)": calibration_curve(err, torch.ones_like(err), levels)}
        if self.predicts_variance:
            curves["predicted"] = calibration_curve(err, torch.exp(0.5 * logvar), levels)
        writer.add_figure(
            f"{prefix}/latent_calibration", plot_calibration(curves, "latent calibration"), self.global_step
        )
        if out.get("images"):
            self.decoder.to(self.device)
            predicted = [render_code(self.decoder, m, self.hparams.mesh_resolution) for m, _ in out["mesh_codes"]]
            target = [render_code(self.decoder, z, self.hparams.mesh_resolution) for _, z in out["mesh_codes"]]
            writer.add_figure(
                f"{prefix}/meshes", mesh_panel(torch.stack(out["images"]), predicted, target), self.global_step
            )

    def _tensorboard(self):
        for logger in self.loggers:
            if isinstance(logger, TensorBoardLogger):
                return logger.experiment
        return None

    def configure_optimizers(self):
        hp = self.hparams
        params = [p for p in self.encoder.parameters() if p.requires_grad]  # a frozen backbone stays out
        opt = instantiate(hp.optimizer)(params)
        total = self._total_steps()
        schedule = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: max(0.0, 1.0 - k / total) ** hp.poly_power)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}

    def _total_steps(self) -> int:
        """Steps of the poly schedule: `max_epochs` epochs if set, else the whole trainer run."""
        trainer = self.trainer
        run_steps = trainer.estimated_stepping_batches  # also sets up the train loader
        if self.hparams.max_epochs is None:
            return max(1, int(run_steps))
        per_epoch = math.ceil(trainer.num_training_batches / trainer.accumulate_grad_batches)
        return max(1, per_epoch * self.hparams.max_epochs)
