"""A frozen backbone with cached features: the cache is reused, only the head trains, images agree."""

import torch

from ushape.encoder.datamodule import EncoderDataModule
from ushape.encoder.feature_cache import FeatureDataModule
from ushape.encoder.fit import fit_encoder
from ushape.encoder.module import EncoderModule

ES = {"_target_": "ushape.encoder.losses.energy_score", "_partial_": True, "n_samples": 16}


def _frozen(tiny_encoder, **head):
    return {**tiny_encoder, "freeze_backbone": True, "hidden": 16, **head}


def test_cache_holds_clean_and_augmented_passes_and_is_reused(world, decoder_dir, tiny_encoder, world_spec):
    model = EncoderModule(str(decoder_dir), _frozen(tiny_encoder), ES)
    images = EncoderDataModule(world, decoder_dir, image_size=16, batch_size=4, min_scale=0.3)
    data = FeatureDataModule(images, model.encoder.features, {"backbone": "tiny"}, train_passes=3)
    data.setup("fit")
    n_train = world_spec["splits"]["train"] * world_spec["n_views"]
    train = data.datasets["train"]
    assert (
        len(train) == 3 * n_train and len(data.datasets["val"]) == world_spec["splits"]["val"] * world_spec["n_views"]
    )
    clean, cropped = train.features[:n_train], train.features[n_train : 2 * n_train]
    assert not torch.allclose(clean, cropped)  # the augmented pass really is another image
    first = images.dataset("train", train=False)[0]
    with torch.no_grad():
        assert torch.allclose(model.encoder.features(first["image"][None])[0], clean[0], atol=1e-5)

    def must_not_run(images):
        raise AssertionError("the cached features were computed again")

    again = FeatureDataModule(images, must_not_run, {"backbone": "tiny"}, train_passes=3)
    again.setup("fit")
    assert torch.equal(again.datasets["train"].features, train.features)
    other = FeatureDataModule(images, model.encoder.features, {"backbone": "other"}, train_passes=3)
    assert other.cache_file("train") != data.cache_file("train")


def test_fit_on_cached_features_trains_the_head_only(world, decoder_dir, tiny_encoder, tmp_path):
    # The shipped ImageNet weights: the same backbone before and after, whatever the random state.
    lite0 = {"_target_": "ushape.encoder.backbones.efficientnet_lite0", "pooling": "stages"}
    encoder = _frozen({**tiny_encoder, "backbone": lite0}, members=3)
    before = EncoderModule(str(decoder_dir), encoder, ES).encoder.state_dict()
    trainer = {"accelerator": "cpu", "max_epochs": 2, "enable_progress_bar": False, "enable_model_summary": False}
    best = fit_encoder(
        world,
        decoder_dir,
        tmp_path / "run",
        encoder,
        ES,
        module={"optimizer": "adam", "lr": 1e-2},
        data={"image_size": 16, "batch_size": 4, "cached_features": True, "train_passes": 2},
        trainer=trainer,
        logger=False,
    )
    model = EncoderModule.load_from_checkpoint(best)
    after = model.encoder.state_dict()
    assert all(torch.equal(after[k], v) for k, v in before.items() if k.startswith("backbone."))
    assert any(not torch.equal(after[k], v) for k, v in before.items() if k.startswith("head."))
    image = torch.rand(2, 3, 16, 16)
    mu, logvar = model(image)  # the checkpoint encodes images end to end
    assert mu.shape == logvar.shape == (2, tiny_encoder["latent_size"])


def test_cached_features_need_a_frozen_backbone(world, decoder_dir, tiny_encoder, tmp_path):
    import pytest

    with pytest.raises(ValueError, match="freeze_backbone=true"):
        fit_encoder(
            world,
            decoder_dir,
            tmp_path / "run",
            tiny_encoder,
            ES,
            data={"image_size": 16, "cached_features": True},
            trainer={"max_epochs": 1},
            logger=False,
        )


def test_frozen_backbone_stays_in_eval_mode_and_out_of_the_optimiser(decoder_dir, tiny_encoder):
    model = EncoderModule(str(decoder_dir), _frozen(tiny_encoder), ES)
    model.train()
    assert not model.encoder.backbone.training and model.encoder.head.training
    assert all(not p.requires_grad for p in model.encoder.backbone.parameters())


def test_the_head_reads_frozen_features_standardised_by_the_training_views(world, decoder_dir, tiny_encoder, tmp_path):
    encoder = _frozen(tiny_encoder)
    trainer = {"accelerator": "cpu", "max_epochs": 1, "enable_progress_bar": False, "enable_model_summary": False}
    best = fit_encoder(
        world,
        decoder_dir,
        tmp_path / "run",
        encoder,
        ES,
        data={"image_size": 16, "batch_size": 4, "cached_features": True, "train_passes": 2},
        trainer=trainer,
        logger=False,
    )
    model = EncoderModule.load_from_checkpoint(best)
    cached = torch.load(next((world / "features").glob("train-*.pt")), weights_only=False)["features"]
    assert torch.allclose(model.encoder.feature_mean, cached.mean(0), atol=1e-5)  # kept in the checkpoint
    standardised = model.encoder.head_input(cached)
    assert torch.allclose(standardised.mean(0), torch.zeros(cached.shape[1]), atol=1e-4)
    image = torch.rand(1, 3, 16, 16)
    with torch.no_grad():  # images end to end = the head on the standardised features of the same image
        direct = model.encoder.head(model.encoder.head_input(model.encoder.features(image)))
        assert torch.allclose(model.encoder(image)[0], direct[0])
