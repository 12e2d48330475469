"""Re-coded training shapes: the latent optimisation that made val/test codes, written once beside stage 1."""

import torch
from sphere_world import SPLITS, read_json  # noqa: F401

from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.artifacts import DONE_FILE, codes_file, load_codes, load_decoder
from ushape.decoder.recode import ensure_codes

LATENT_OPTIM = {"iterations": 200, "lr_drop_at": 150, "samples_per_iter": 2000}


def _sdf_error(decoder, world, table) -> float:
    data = SDFSamplesDataset(world, "train", samples_per_shape=2)
    errors = []
    for i, shape_id in enumerate(data.shape_ids):
        pos, neg = data.samples(i)
        rows = torch.cat([pos, neg])
        with torch.no_grad():
            pred = decoder(rows[None, :, :3], table.lookup(shape_id)[None, None, :])[0]
        errors.append((pred.clamp(-0.1, 0.1) - rows[:, 3].clamp(-0.1, 0.1)).abs().mean())
    return float(torch.stack(errors).mean())


def test_reoptimised_codes_fit_the_training_shapes_and_leave_the_rest(fitted_sphere_folder, sphere_world):
    out = ensure_codes(fitted_sphere_folder, "reoptimised", sphere_world, LATENT_OPTIM)
    assert out == fitted_sphere_folder / "codes_reoptimised" and (out / DONE_FILE).is_file()
    for split in ("val", "test"):
        assert torch.equal(
            load_codes(out / codes_file(split)).codes, load_codes(fitted_sphere_folder / codes_file(split)).codes
        )
    original, recoded = load_codes(fitted_sphere_folder / codes_file("train")), load_codes(out / codes_file("train"))
    assert recoded.shape_ids == original.shape_ids and not torch.equal(recoded.codes, original.codes)
    decoder = load_decoder(out)
    assert all(
        torch.equal(a, b)
        for a, b in zip(decoder.state_dict().values(), load_decoder(fitted_sphere_folder).state_dict().values())
    )
    # The re-optimised codes describe the same spheres about as well as the auto-decoded ones.
    assert _sdf_error(decoder, sphere_world, recoded) < max(0.01, 1.5 * _sdf_error(decoder, sphere_world, original))
    assert read_json(out / DONE_FILE)["latent_optim"] == LATENT_OPTIM
    stamp = (out / codes_file("train")).stat().st_mtime_ns
    assert ensure_codes(fitted_sphere_folder, "reoptimised", sphere_world, LATENT_OPTIM) == out
    assert (out / codes_file("train")).stat().st_mtime_ns == stamp  # written once


def test_autodecoder_codes_are_the_folder_itself_and_unknown_sources_fail(fitted_sphere_folder, sphere_world):
    import pytest

    assert ensure_codes(fitted_sphere_folder, "autodecoder", sphere_world) == fitted_sphere_folder
    with pytest.raises(ValueError, match="reoptimised"):
        ensure_codes(fitted_sphere_folder, "learnt", sphere_world)
