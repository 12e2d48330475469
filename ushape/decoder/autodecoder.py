"""Stage 1: DeepSDF's auto-decoder, the decoder and one learnt code per training shape trained jointly."""

from __future__ import annotations

import math
from functools import partial
from typing import Any, Mapping

import lightning as L
import numpy as np
import torch
import trimesh
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import Tensor, nn

from ushape.decoder.losses import clamped_l1, code_regulariser
from ushape.decoder.precision import training_bf16
from ushape.decoder.query import code_sdf_fn, decoder_autocast
from ushape.mesh.extraction import EmptySurfaceError, extract_mesh
from ushape.mesh.preview import preview_image
from ushape.metrics.reconstruction import (
    chamfer_deepsdf,
    iou_from_occupancy,
    mesh_inside_fn,
    occupancy_grid,
    sdf_inside_fn,
)


def resolve_decoder_config(decoder: Any, latent_size: int) -> dict[str, Any]:
    """The decoder's `_target_` config as a plain dict, its latent size filled in and checked."""
    config = OmegaConf.to_container(OmegaConf.create(decoder), resolve=True)
    if "_target_" not in config:
        raise ValueError("the decoder config needs a `_target_`, e.g. ushape.decoder.network.DeepSDFDecoder")
    config.setdefault("latent_size", latent_size)
    if config["latent_size"] != latent_size:
        raise ValueError(
            f"decoder latent_size {config['latent_size']} differs from the module's latent_size {latent_size}"
        )
    return config


def deepsdf_lr_factor(epoch: int, step_epochs: int, gamma: float) -> float:
    """DeepSDF's StepLearningRateSchedule factor gamma ** (epoch_1 // step) at our 0-based `epoch`.

    DeepSDF counts epochs from 1, so its first drop comes at our epoch step - 1 (torch's StepLR,
    counting from 0, would drop one epoch late), as its code regulariser's ramp does.
    """
    return gamma ** ((epoch + 1) // step_epochs)


# The optimiser (a Hydra `_partial_` config) that both parameter groups share: DeepSDF's Adam.
DEEPSDF_OPTIMIZER = {"_target_": "torch.optim.Adam", "_partial_": True}


class AutoDecoderModule(L.LightningModule):
    """Decoder f(x, z) plus an embedding of codes, trained on clamped L1 with DeepSDF's code prior.

    Defaults follow DeepSDF's specs.json: codes ~ N(0, (1/sqrt(D))^2) bounded by norm 1, clamp 0.1,
    Adam with lr 5e-4 (decoder) / 1e-3 (codes), both halved every 500 epochs, regulariser 1e-4
    ramped in over 100 epochs. Validation meshes a few *training* shapes from their codes and
    scores them against the ground-truth meshes (Chamfer, IoU) and logs pictures of them.
    """

    def __init__(
        self,
        decoder: dict,
        num_shapes: int,
        latent_size: int = 64,
        code_init_std: float | None = None,
        code_max_norm: float | None = 1.0,
        clamp_distance: float = 0.1,
        code_reg_lambda: float = 1e-4,
        code_reg_warmup_epochs: int = 100,
        lr_net: float = 5e-4,
        lr_codes: float = 1e-3,
        lr_step_epochs: int = 500,
        lr_gamma: float = 0.5,
        optimizer: Mapping[str, Any] = DEEPSDF_OPTIMIZER,
        bf16: bool | str = False,
        val_every_n_epochs: int = 50,
        val_mesh_resolution: int = 64,
        val_iou_resolution: int = 32,
        val_chamfer_points: int = 30000,
        val_image_size: int = 128,
    ) -> None:
        super().__init__()
        if num_shapes < 1:
            raise ValueError(f"num_shapes must be >= 1, got {num_shapes}")
        self.decoder_config = resolve_decoder_config(decoder, latent_size)
        if OmegaConf.is_config(optimizer):
            optimizer = OmegaConf.to_container(optimizer, resolve=True)
        optimizer = {**optimizer, "_partial_": True}  # rebound before save_hyperparameters reads it
        self.save_hyperparameters()  # the decoder *config* included, so a checkpoint rebuilds the module
        self.decoder = instantiate(self.decoder_config)
        self.codes = nn.Embedding(num_shapes, latent_size, max_norm=code_max_norm)
        std = 1.0 / math.sqrt(latent_size) if code_init_std is None else code_init_std
        nn.init.normal_(self.codes.weight, 0.0, std)
        # Ground-truth occupancies of validation shapes, computed once (inside tests are the slow part).
        self._gt_cache: dict[str, tuple[trimesh.Trimesh, np.ndarray]] = {}

    @property
    def bf16(self) -> bool:
        """Whether the decoder runs under bf16 autocast on this module's device ("auto": where it is faster)."""
        return training_bf16(self.hparams.bf16, self.device)

    def forward(self, xyz: Tensor, index: Tensor) -> Tensor:
        """SDF of training shapes `index` [B] at points xyz [B, S, 3]. -> [B, S]"""
        return self.decoder(xyz, self.codes(index)[:, None, :])

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        hp = self.hparams
        codes = self.codes(batch["index"])  # [B, D]; the embedding renormalises rows above max_norm
        with decoder_autocast(self.device, self.bf16):
            pred = self.decoder(batch["xyz"], codes[:, None, :])  # [B, S]
        sdf_loss = clamped_l1(pred.float(), batch["sdf"], hp.clamp_distance)
        # DeepSDF counts epochs from 1, so the ramp is already non-zero in the first epoch.
        code_reg = code_regulariser(codes, hp.code_reg_lambda, self.current_epoch + 1, hp.code_reg_warmup_epochs)
        loss = sdf_loss + code_reg
        batch_size = codes.shape[0]
        self.log_dict(
            {"train/loss": loss, "train/sdf_loss": sdf_loss, "train/code_reg": code_reg},
            on_step=False,
            on_epoch=True,
            prog_bar=False,
            batch_size=batch_size,
        )
        self.log(
            "train/loss_epoch", loss, on_step=False, on_epoch=True, prog_bar=True, logger=False, batch_size=batch_size
        )
        return loss

    def on_train_epoch_end(self) -> None:
        norms = self.codes.weight.detach().norm(dim=1)
        lr_net, lr_codes = (group["lr"] for group in self.optimizers().param_groups)
        self.log_dict(
            {
                "train/code_norm_mean": norms.mean(),
                "train/code_norm_max": norms.max(),
                "train/lr_net": lr_net,
                "train/lr_codes": lr_codes,
            }
        )

    def configure_optimizers(self) -> dict[str, Any]:
        hp = self.hparams
        # DeepSDF's two parameter groups, each with its own lr, in the configured optimiser (Adam).
        optimiser = instantiate(hp.optimizer)(
            [
                {"params": self.decoder.parameters(), "lr": hp.lr_net},
                {"params": self.codes.parameters(), "lr": hp.lr_codes},
            ]
        )
        scheduler = torch.optim.lr_scheduler.LambdaLR(
            optimiser, partial(deepsdf_lr_factor, step_epochs=hp.lr_step_epochs, gamma=hp.lr_gamma)
        )
        return {"optimizer": optimiser, "lr_scheduler": {"scheduler": scheduler, "interval": "epoch"}}

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        hp = self.hparams
        gt_mesh, gt_occupancy = self._ground_truth(batch["mesh_path"])
        code = self.bounded_codes()[batch["index"]]
        sdf_fn = code_sdf_fn(self.decoder, code, bf16=self.bf16)
        occupancy = occupancy_grid(sdf_inside_fn(sdf_fn), hp.val_iou_resolution)
        self.log("val/iou", iou_from_occupancy(gt_occupancy, occupancy), batch_size=1)
        try:
            mesh, _ = extract_mesh(sdf_fn, hp.val_mesh_resolution)
        except EmptySurfaceError:
            mesh = None  # early in training a code may give no surface: no Chamfer, a blank picture
        else:
            self.log("val/chamfer", chamfer_deepsdf(gt_mesh, mesh, hp.val_chamfer_points), batch_size=1)
        self.log("val/empty_meshes", float(mesh is None), batch_size=1, reduce_fx="sum")
        self._log_picture(f"val/mesh/{batch['shape_id']}", gt_mesh, mesh)

    def _ground_truth(self, mesh_path: str) -> tuple[trimesh.Trimesh, np.ndarray]:
        if mesh_path not in self._gt_cache:
            mesh = trimesh.load(mesh_path, force="mesh", process=False)  # merging vertices can break manifoldness
            self._gt_cache[mesh_path] = (mesh, occupancy_grid(mesh_inside_fn(mesh), self.hparams.val_iou_resolution))
        return self._gt_cache[mesh_path]

    def _log_picture(self, tag: str, gt_mesh: trimesh.Trimesh, mesh: trimesh.Trimesh | None) -> None:
        """Ground truth | reconstruction side by side, if the logger can take images (TensorBoard)."""
        experiment = getattr(self.logger, "experiment", None)
        if not hasattr(experiment, "add_image"):
            return
        size = self.hparams.val_image_size
        picture = np.concatenate([preview_image(gt_mesh, size), preview_image(mesh, size)], axis=1)
        experiment.add_image(tag, picture, global_step=self.global_step, dataformats="HWC")

    @torch.no_grad()
    def bounded_codes(self) -> Tensor:
        """All training codes as a lookup returns them, rows above max_norm scaled onto it. -> [num_shapes, D]

        Computed out of place: nn.Embedding's own lookup renormalises its weight in place, which
        validation (run under inference mode) must not do.
        """
        weight = self.codes.weight.detach()
        if self.codes.max_norm is None:
            return weight.clone()
        norms = weight.norm(dim=1, keepdim=True)
        # Same factor as torch.embedding_renorm_, including its 1e-7 guard.
        scale = torch.where(norms > self.codes.max_norm, self.codes.max_norm / (norms + 1e-7), torch.ones_like(norms))
        return weight * scale
