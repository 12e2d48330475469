"""EncoderModule and fit_encoder: training moves the encoder only, scores are logged, checkpoints load."""

import functools

import lightning as L
import pytest
import torch

from ushape.encoder.datamodule import EncoderDataModule
from ushape.encoder.fit import fit_encoder
from ushape.encoder.heads import ImageEncoder
from ushape.encoder.losses import energy_score, l2_loss
from ushape.encoder.module import EncoderModule, loss_config, optimizer_config

ES = {"_target_": "ushape.encoder.losses.energy_score", "_partial_": True, "n_samples": 16}


def _trainer(tmp_path, **kw):
    defaults = dict(
        accelerator="cpu",
        max_epochs=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
    )
    return L.Trainer(**{**defaults, **kw})


def _datamodule(world, decoder_dir):
    return EncoderDataModule(world, decoder_dir, image_size=16, batch_size=4, min_scale=0.5)


def test_loss_config_round_trips_functions_and_partials():
    assert loss_config(l2_loss) == {"_target_": "ushape.encoder.losses.l2_loss", "_partial_": True}
    cfg = loss_config(functools.partial(energy_score, n_samples=8))
    assert cfg == {"_target_": "ushape.encoder.losses.energy_score", "_partial_": True, "n_samples": 8}
    with pytest.raises(ValueError, match="_target_"):
        loss_config({"n_samples": 3})


def test_optimizer_configs_and_the_names_older_checkpoints_hold():
    adam = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3, "weight_decay": 0.0}
    assert optimizer_config(adam) == adam
    assert optimizer_config(adam, lr=0.01)["lr"] == 0.01  # a shorthand beside the config
    assert optimizer_config("sgd") == {
        "_target_": "torch.optim.SGD",
        "_partial_": True,
        "lr": 0.1,
        "weight_decay": 1e-4,
        "momentum": 0.9,
    }
    assert optimizer_config("adamw", lr=0.5)["_target_"] == "torch.optim.AdamW"
    # An older Adam checkpoint's hparams (momentum 0.9 was saved for every optimiser) still build Adam.
    legacy = optimizer_config("adam", lr=1e-3, momentum=0.9, weight_decay=0.0)
    assert legacy == {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3, "weight_decay": 0.0}
    with pytest.raises(ValueError, match="_target_"):
        optimizer_config({"lr": 0.1})
    with pytest.raises(ValueError, match="adam"):
        optimizer_config("rmsprop")


def test_the_configured_optimiser_is_built_over_the_trainable_parameters(world, decoder_dir, tiny_encoder, tmp_path):
    adamw = {"_target_": "torch.optim.AdamW", "_partial_": True, "lr": 0.02, "weight_decay": 0.05}
    model = EncoderModule(str(decoder_dir), tiny_encoder, ES, optimizer=adamw)
    assert model.hparams.optimizer == adamw and model.hparams.lr is None  # what a checkpoint rebuilds
    trainer = _trainer(tmp_path, limit_train_batches=1, limit_val_batches=0)
    trainer.fit(model, datamodule=_datamodule(world, decoder_dir))
    optimiser = trainer.optimizers[0]
    assert isinstance(optimiser, torch.optim.AdamW) and optimiser.defaults["weight_decay"] == 0.05


class TaggedEncoder(ImageEncoder):
    """An ImageEncoder subclass named by the encoder config's `_target_`."""


def test_the_encoder_configs_target_is_what_is_built(decoder_dir, tiny_encoder):
    model = EncoderModule(str(decoder_dir), {**tiny_encoder, "_target_": "test_module.TaggedEncoder"}, ES)
    assert type(model.encoder) is TaggedEncoder
    assert type(EncoderModule(str(decoder_dir), tiny_encoder, ES).encoder) is ImageEncoder


def test_training_moves_the_encoder_and_never_the_decoder(world, decoder_dir, tiny_encoder, tmp_path):
    model = EncoderModule(str(decoder_dir), tiny_encoder, ES, lr=0.01)
    decoder_before = {k: v.clone() for k, v in model.decoder.state_dict().items()}
    head_before = model.encoder.head.mean.weight.clone()
    trainer = _trainer(tmp_path, limit_train_batches=2, limit_val_batches=0)
    trainer.fit(model, datamodule=_datamodule(world, decoder_dir))
    assert not torch.equal(model.encoder.head.mean.weight, head_before)
    assert all(p.grad is None and not p.requires_grad for p in model.decoder.parameters())
    assert all(torch.equal(v, decoder_before[k]) for k, v in model.decoder.state_dict().items())
    optimised = {id(p) for group in trainer.optimizers[0].param_groups for p in group["params"]}
    assert optimised.isdisjoint(id(p) for p in model.decoder.parameters())
    assert not any(k.startswith("decoder") for k in model.state_dict())


def test_latent_size_must_match_the_decoder(decoder_dir, tiny_encoder):
    with pytest.raises(ValueError, match="latent_size=8"):
        EncoderModule(str(decoder_dir), {**tiny_encoder, "latent_size": 5}, ES)


def test_validation_logs_latent_scores(world, decoder_dir, tiny_encoder, tmp_path):
    model = EncoderModule(str(decoder_dir), tiny_encoder, ES, val_samples=32)
    torch.nn.init.normal_(model.encoder.head.logvar.weight, std=0.1)  # zero-init gives one variance for all
    trainer = _trainer(tmp_path, limit_train_batches=1)
    trainer.validate(model, datamodule=_datamodule(world, decoder_dir))
    logged = trainer.callback_metrics
    for name in ("loss", "latent_l2", "latent_es", "latent_nll", "rank_corr", "calibration_error"):
        assert torch.isfinite(logged[f"val/{name}"]), name


def test_l2_model_is_scored_with_unit_variance(world, decoder_dir, tiny_encoder, tmp_path):
    model = EncoderModule(str(decoder_dir), tiny_encoder, {"_target_": "ushape.encoder.losses.l2_loss"})
    _, logvar = model(torch.rand(2, 3, 16, 16))
    assert torch.equal(logvar, torch.zeros_like(logvar))
    trainer = _trainer(tmp_path)
    trainer.validate(model, datamodule=_datamodule(world, decoder_dir))
    assert "val/rank_corr" not in trainer.callback_metrics and "val/latent_nll" in trainer.callback_metrics


def test_poly_schedule_reaches_zero_at_max_epochs(world, decoder_dir, tiny_encoder, tmp_path):
    model = EncoderModule(str(decoder_dir), tiny_encoder, ES, lr=0.1, max_epochs=2, poly_power=1.0)
    trainer = _trainer(tmp_path, max_epochs=1, limit_val_batches=0)  # 3 steps of a 6-step schedule
    trainer.fit(model, datamodule=_datamodule(world, decoder_dir))
    assert trainer.optimizers[0].param_groups[0]["lr"] == pytest.approx(0.1 * (1 - 3 / 6))


def test_fit_encoder_writes_a_loadable_checkpoint(world, decoder_dir, tmp_path, tiny_encoder):
    loss = {"_target_": "ushape.encoder.losses.gaussian_nll"}
    ckpt = fit_encoder(
        world,
        decoder_dir,
        tmp_path / "run",
        encoder=tiny_encoder,
        loss=loss,
        module={"lr": 0.01, "val_samples": 16},
        data={"image_size": 16, "batch_size": 4, "mask_mode": "none"},
        trainer={
            "accelerator": "cpu",
            "max_epochs": 1,
            "limit_train_batches": 2,
            "limit_val_batches": 1,
            "num_sanity_val_steps": 0,
            "enable_progress_bar": False,
        },
    )
    assert ckpt.exists() and ckpt.parent == tmp_path / "run" / "checkpoints"
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").exists()
    assert list((tmp_path / "run" / "tensorboard").rglob("events.out.tfevents.*"))
    blob = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert not any(k.startswith("decoder") for k in blob["state_dict"])
    restored = EncoderModule.load_from_checkpoint(ckpt).eval()
    assert restored.hparams.loss["_target_"] == loss["_target_"]
    assert restored(torch.rand(2, 3, 16, 16))[0].shape == (2, 8)


def test_prior_head_init_starts_at_the_training_codes_gaussian(decoder_dir, tiny_encoder):
    from ushape.decoder.artifacts import codes_file, load_codes

    codes = load_codes(decoder_dir / codes_file("train")).codes
    model = EncoderModule(str(decoder_dir), tiny_encoder, ES, head_init="prior").eval()
    with torch.no_grad():
        mu, logvar = model(torch.rand(3, 3, 24, 24))
    assert torch.allclose(mu, codes.mean(0).expand_as(mu), atol=1e-6)
    assert torch.allclose(logvar.exp(), codes.var(0).expand_as(logvar), rtol=1e-3)
    with pytest.raises(ValueError, match="head_init"):
        EncoderModule(str(decoder_dir), tiny_encoder, ES, head_init="zeros")


def test_last_checkpoint_is_the_last_epoch_and_resume_continues_there(world, decoder_dir, tmp_path, tiny_encoder):
    """Lightning wrote last.ckpt only with a new best: with a best at epoch 0 it stayed at epoch 0."""
    run = tmp_path / "run"
    trainer = {
        "accelerator": "cpu",
        "limit_train_batches": 1,
        "limit_val_batches": 1,
        "num_sanity_val_steps": 0,
        "enable_progress_bar": False,
        "enable_model_summary": False,
    }
    kwargs = dict(
        encoder=tiny_encoder,
        loss=ES,
        module={"lr": 0.01, "val_samples": 8},
        data={"image_size": 16, "batch_size": 4},
        logger=False,
        monitor="step",
    )  # min step: epoch 0 is best
    best = fit_encoder(world, decoder_dir, run, trainer={**trainer, "max_epochs": 2}, **kwargs)
    last = run / "checkpoints" / "last.ckpt"
    assert torch.load(best, map_location="cpu", weights_only=False)["epoch"] == 0
    blob = torch.load(last, map_location="cpu", weights_only=False)
    assert (blob["epoch"], blob["global_step"]) == (1, 2)
    started = []
    counter = L.Callback()
    counter.on_train_epoch_start = lambda trainer, module: started.append(trainer.current_epoch)
    fit_encoder(world, decoder_dir, run, trainer={**trainer, "max_epochs": 3}, callbacks=[counter], **kwargs)
    assert started == [2]  # one more epoch, from where last.ckpt left off
    blob = torch.load(last, map_location="cpu", weights_only=False)
    assert (blob["epoch"], blob["global_step"]) == (2, 3)
    fit_encoder(world, decoder_dir, run, trainer={**trainer, "max_epochs": 3}, callbacks=[counter], **kwargs)
    assert started == [2]  # a finished run rerun (a resumed sweep) trains nothing again
    assert sorted(p.name for p in last.parent.iterdir()) == ["best.ckpt", "last.ckpt"]
