"""stage1.init_from: a stage-1 run that starts from a finished decoder folder's weights and training codes."""

import pytest
import torch
from omegaconf import OmegaConf
from sphere_world import FAST_FIT, FAST_TRAINER

from ushape.decoder.artifacts import CodeTable, codes_file, load_codes, load_decoder, save_codes
from ushape.decoder.autodecoder import AutoDecoderModule
from ushape.decoder.fit import fit_decoder
from ushape.decoder.warm_start import init_fingerprint, warm_start
from ushape.errors import InputError
from ushape.training.decoder_store import decoder_dir_for


@pytest.fixture
def finished(sphere_world, tiny_decoder_config, tmp_path):
    return fit_decoder(
        sphere_world, tmp_path / "first", tiny_decoder_config, trainer={**FAST_TRAINER, "max_epochs": 2}, **FAST_FIT
    )


def test_the_decoder_and_the_shared_shapes_codes_are_taken_and_new_shapes_keep_their_draw(
    finished, tiny_decoder_config
):
    trained = load_codes(finished / codes_file("train"))
    ids = [trained.shape_ids[1], "a_new_shape", trained.shape_ids[0]]
    module = AutoDecoderModule(decoder=tiny_decoder_config, num_shapes=3, latent_size=8)
    fresh = module.codes.weight.detach().clone()
    assert warm_start(module, finished, ids) == 2
    # Copies, not computations: the taken weights and codes are the stored tensors themselves, bit for bit on
    # any CPU, and the new shape's row is the untouched draw.
    assert torch.equal(module.codes.weight[0], trained.codes[1]) and torch.equal(
        module.codes.weight[2], trained.codes[0]
    )
    assert torch.equal(module.codes.weight[1], fresh[1])
    expected = load_decoder(finished).state_dict()
    assert all(torch.equal(v, expected[k]) for k, v in module.decoder.state_dict().items())


def test_a_folder_that_is_not_a_finished_decoder_or_does_not_fit_is_refused(finished, tiny_decoder_config, tmp_path):
    with pytest.raises(InputError, match="not a finished stage-1 folder.*DONE"):
        warm_start(AutoDecoderModule(decoder=tiny_decoder_config, num_shapes=1, latent_size=8), tmp_path, ["x"])
    wider = {**tiny_decoder_config, "hidden_dims": [d * 2 for d in tiny_decoder_config["hidden_dims"]]}
    with pytest.raises(InputError, match="another network"):
        warm_start(AutoDecoderModule(decoder=wider, num_shapes=1, latent_size=8), finished, ["x"])
    save_codes(finished / codes_file("train"), CodeTable(["x"], torch.zeros(1, 4)))
    with pytest.raises(InputError, match="4 dimensions, this run's 8"):
        warm_start(AutoDecoderModule(decoder=tiny_decoder_config, num_shapes=1, latent_size=8), finished, ["x"])


def test_a_warm_run_trains_from_the_folder_and_its_identity_names_the_weights_not_the_path(
    finished, sphere_world, tiny_decoder_config, tmp_path
):
    out = fit_decoder(
        sphere_world,
        tmp_path / "warm",
        tiny_decoder_config,
        trainer={**FAST_TRAINER, "max_epochs": 1},
        init_from=finished,
        **FAST_FIT,
    )
    assert (out / "DONE").is_file() and len(load_codes(out / codes_file("train")).shape_ids) == 4
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("decoder.pt", codes_file("train"), "DONE"):
        (copy / name).write_bytes((finished / name).read_bytes())
    assert init_fingerprint(copy) == init_fingerprint(finished)

    def folder(init_from):
        stage1 = {"epochs": 3, "init_from": None if init_from is None else str(init_from)}
        return decoder_dir_for(
            OmegaConf.create(
                {
                    "seed": 1,
                    "category": {"name": "chairs"},
                    "data": {"_target_": "ushape.data.world.SyntheticWorld", "n_train": 4, "root": "x"},
                    "decoder": {"_target_": "x"},
                    "stage1": stage1,
                    "paths": {"decoders_dir": str(tmp_path / "decoders")},
                }
            )
        )

    assert folder(copy) == folder(finished) != folder(None) != folder(out)
