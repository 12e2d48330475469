"""The auto-decoder module: code table, training, resuming, and the finished stage-1 folder."""

import json
import shutil

import lightning as L
import pytest
import torch
from sphere_world import FAST_FIT, FAST_TRAINER, SPLITS

from ushape.decoder.artifacts import load_codes, load_decoder
from ushape.decoder.autodecoder import AutoDecoderModule, deepsdf_lr_factor
from ushape.decoder.datamodule import SDFDataModule
from ushape.decoder.fit import fit_decoder
from ushape.decoder.losses import clamped_l1
from ushape.decoder.query import code_sdf_fn


def test_codes_start_at_deepsdf_scale(tiny_decoder_config):
    module = AutoDecoderModule(
        decoder={**tiny_decoder_config, "latent_size": 64, "hidden_dims": [128, 128, 128]},
        num_shapes=2000,
        latent_size=64,
    )
    assert module.codes.weight.std().item() == pytest.approx(1 / 8, rel=0.03)
    assert module.codes.weight.mean().abs().item() < 0.01


def test_code_max_norm_bounds_lookups_and_export(tiny_decoder_config):
    module = AutoDecoderModule(decoder=tiny_decoder_config, num_shapes=3, latent_size=8, code_max_norm=1.0)
    with torch.no_grad():
        module.codes.weight[1] = 5.0 * torch.ones(8) / 8**0.5  # norm 5
    bounded = module.bounded_codes()
    assert bounded[1].norm().item() == pytest.approx(1.0, abs=1e-5)
    # A row within the bound is left as it is: to within one fp32 step (2^-23 relative), so any scale other
    # than 1 shows, whatever the CPU's kernels do with a multiplication by ones.
    torch.testing.assert_close(bounded[0], module.codes.weight[0], rtol=2**-23, atol=0.0)
    looked_up = module.codes(torch.tensor([1]))[0]
    assert looked_up.norm().item() == pytest.approx(1.0, abs=1e-5)
    assert torch.allclose(looked_up, bounded[1], atol=1e-6)


def test_decoder_latent_size_must_match(tiny_decoder_config):
    with pytest.raises(ValueError, match="latent_size"):
        AutoDecoderModule(decoder=tiny_decoder_config, num_shapes=3, latent_size=16)


@pytest.mark.parametrize("bf16", [False, True])
def test_training_reduces_the_loss(sphere_world, tiny_decoder_config, bf16):
    L.seed_everything(0)
    dm = SDFDataModule(sphere_world, samples_per_shape=512, shapes_per_batch=4)
    module = AutoDecoderModule(
        decoder=tiny_decoder_config, num_shapes=dm.num_shapes, latent_size=8, lr_net=3e-3, lr_codes=1e-2, bf16=bf16
    )
    batch = next(iter(dm.train_dataloader()))

    def loss() -> float:
        with torch.no_grad():
            return clamped_l1(module(batch["xyz"], batch["index"]), batch["sdf"], 0.1).item()

    before = loss()
    trainer = L.Trainer(**FAST_TRAINER, max_epochs=40, logger=False, enable_checkpointing=False, limit_val_batches=0)
    trainer.fit(module, datamodule=dm)
    assert loss() < 0.7 * before


class EpochCounter(L.Callback):
    def __init__(self):
        self.started = []

    def on_train_epoch_start(self, trainer, pl_module):
        self.started.append(trainer.current_epoch)


def test_resume_continues_the_epoch_count(sphere_world, tiny_decoder_config, tmp_path):
    out = fit_decoder(
        sphere_world, tmp_path, tiny_decoder_config, trainer={**FAST_TRAINER, "max_epochs": 2}, **FAST_FIT
    )
    last = torch.load(out / "checkpoints" / "last.ckpt", weights_only=False)
    assert last["epoch"] == 1 and last["global_step"] == 2 * 2  # 4 shapes / 2 per batch = 2 steps per epoch
    (out / "DONE").unlink()  # as if the run had stopped before finishing
    counter = EpochCounter()
    fit_decoder(
        sphere_world,
        tmp_path,
        tiny_decoder_config,
        trainer={**FAST_TRAINER, "max_epochs": 3},
        callbacks=[counter],
        **FAST_FIT,
    )
    assert counter.started == [2]  # only the missing third epoch ran
    last = torch.load(out / "checkpoints" / "last.ckpt", weights_only=False)
    assert last["epoch"] == 2 and last["global_step"] == 3 * 2
    assert json.loads((out / "DONE").read_text())["epochs"] == 3
    rebuilt = AutoDecoderModule.load_from_checkpoint(out / "checkpoints" / "last.ckpt")
    assert rebuilt.codes.num_embeddings == 4


def test_a_folder_whose_epochs_are_done_finishes_its_held_out_codes_without_its_checkpoints(
    sphere_world, tiny_decoder_config, tmp_path
):
    """Stopped while latent-optimising the test codes, with the checkpoints gone (a folder carried without its
    optimiser state): the rerun trains no epoch, keeps the decoder and the val codes, and computes the test codes."""
    trainer = {**FAST_TRAINER, "max_epochs": 2}
    out = fit_decoder(sphere_world, tmp_path, tiny_decoder_config, trainer=trainer, **FAST_FIT)
    fitted = json.loads((out / "FITTED").read_text())
    assert fitted["epochs"] == 2 and fitted["max_epochs"] == 2
    decoder_bytes, val_bytes = (out / "decoder.pt").read_bytes(), (out / "codes_val.pt").read_bytes()
    test_codes = load_codes(out / "codes_test.pt")
    for name in ("DONE", "codes_test.pt"):
        (out / name).unlink()
    shutil.rmtree(out / "checkpoints")
    counter = EpochCounter()
    fit_decoder(sphere_world, tmp_path, tiny_decoder_config, trainer=trainer, callbacks=[counter], **FAST_FIT)
    assert counter.started == []  # no epoch ran, and none could have: no checkpoint was left
    assert (out / "decoder.pt").read_bytes() == decoder_bytes and (out / "codes_val.pt").read_bytes() == val_bytes
    again = load_codes(out / "codes_test.pt")
    assert again.shape_ids == test_codes.shape_ids and again.codes.shape == test_codes.codes.shape
    assert json.loads((out / "DONE").read_text())["epochs"] == 2


def zero_crossing_radius(decoder, code) -> float:
    """Radius where the decoder's SDF along +x changes sign (the spheres are centred)."""
    sdf = code_sdf_fn(decoder, code)
    radii = torch.linspace(0.0, 0.95, 951)
    values = sdf(torch.stack([radii, torch.zeros_like(radii), torch.zeros_like(radii)], dim=1))
    return radii[int(torch.nonzero(values > 0)[0])].item()


def test_fitted_folder_is_complete_and_recovers_radii(fitted_sphere_folder):
    folder = fitted_sphere_folder
    assert (folder / "DONE").exists() and (folder / "checkpoints" / "last.ckpt").exists()
    decoder = load_decoder(folder)
    train, val, test = (load_codes(folder / f"codes_{s}.pt") for s in ("train", "val", "test"))
    assert train.shape_ids == list(SPLITS["train"]) and train.codes.shape == (4, 8)
    for table, split in ((train, "train"), (val, "val"), (test, "test")):
        for shape_id, radius in SPLITS[split].items():
            # val/test codes come from latent optimisation of shapes the decoder never saw.
            assert zero_crossing_radius(decoder, table.lookup(shape_id)) == pytest.approx(radius, abs=0.03)


def test_fit_logs_training_and_validation(fitted_sphere_folder):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(fitted_sphere_folder / "tensorboard"), size_guidance={"images": 0})
    events.Reload()
    scalars = set(events.Tags()["scalars"])
    assert {
        "train/loss",
        "train/sdf_loss",
        "train/code_reg",
        "train/lr_net",
        "train/lr_codes",
        "train/code_norm_mean",
        "train/code_norm_max",
        "val/chamfer",
        "val/iou",
    } <= scalars
    assert events.Scalars("val/iou")[-1].value > 0.8
    assert events.Scalars("val/chamfer")[-1].value < 2e-3
    assert "val/mesh/r60" in events.Tags()["images"]


def test_lr_steps_when_deepsdf_does():
    # DeepSDF's epochs count from 1: its lr halves at its epoch 500, our (0-based) epoch 499.
    factors = [deepsdf_lr_factor(e, step_epochs=500, gamma=0.5) for e in (0, 498, 499, 998, 999, 2000)]
    assert factors == [1.0, 1.0, 0.5, 0.5, 0.25, 0.0625]  # the last: DeepSDF epoch 2001


def test_module_schedule_follows_deepsdf(tiny_decoder_config):
    module = AutoDecoderModule(
        decoder=tiny_decoder_config,
        num_shapes=2,
        latent_size=8,
        lr_net=1e-3,
        lr_codes=2e-3,
        lr_step_epochs=3,
        lr_gamma=0.5,
    )
    scheduler = module.configure_optimizers()["lr_scheduler"]["scheduler"]
    lrs = []
    for _ in range(7):  # the lr used in epochs 0..6, then the epoch-end step Lightning takes
        lrs.append([group["lr"] for group in scheduler.optimizer.param_groups])
        scheduler.optimizer.step()
        scheduler.step()
    assert [round(net / 1e-3, 6) for net, _ in lrs] == [1, 1, 0.5, 0.5, 0.5, 0.25, 0.25]
    assert all(codes == pytest.approx(2 * net) for net, codes in lrs)


def test_a_damaged_last_checkpoint_resumes_from_the_newest_intact_one(
    sphere_world, tiny_decoder_config, tmp_path, caplog
):
    """A truncated last.ckpt used to fail every rerun with a raw traceback while epoch=1-step=4.ckpt sat beside it."""
    out = fit_decoder(
        sphere_world, tmp_path, tiny_decoder_config, trainer={**FAST_TRAINER, "max_epochs": 2}, **FAST_FIT
    )
    checkpoints = out / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == ["epoch=1-step=4.ckpt", "last.ckpt"]
    last = checkpoints / "last.ckpt"
    last.write_bytes(last.read_bytes()[:1000])
    (out / "DONE").unlink()
    counter = EpochCounter()
    with caplog.at_level("WARNING", logger="ushape.checkpoints"):
        fit_decoder(
            sphere_world,
            tmp_path,
            tiny_decoder_config,
            trainer={**FAST_TRAINER, "max_epochs": 3},
            callbacks=[counter],
            **FAST_FIT,
        )
    assert counter.started == [2]  # epochs 0-1 were kept, not retrained
    assert "last.ckpt is damaged" in caplog.text and "resuming from epoch=1-step=4.ckpt" in caplog.text
    assert (checkpoints / "last.ckpt.damaged").exists()
    assert torch.load(last, weights_only=False)["epoch"] == 2


def test_train_seconds_add_up_over_resumed_segments(sphere_world, tiny_decoder_config, tmp_path):
    """DONE's train_seconds counted only the last segment of a resumed stage 1."""
    out = fit_decoder(
        sphere_world, tmp_path, tiny_decoder_config, trainer={**FAST_TRAINER, "max_epochs": 1}, **FAST_FIT
    )
    last = out / "checkpoints" / "last.ckpt"
    blob = torch.load(last, weights_only=False)
    (clock,) = [k for k in blob["callbacks"] if k.startswith("TrainingClock")]
    blob["callbacks"][clock]["seconds"] = 5000.0  # as if the first segment had run for 5000 s
    torch.save(blob, last)
    (out / "DONE").unlink()
    fit_decoder(sphere_world, tmp_path, tiny_decoder_config, trainer={**FAST_TRAINER, "max_epochs": 2}, **FAST_FIT)
    done = json.loads((out / "DONE").read_text())
    assert done["epochs"] == 2 and done["train_seconds"] >= 5000.0 and done["total_seconds"] >= done["train_seconds"]
