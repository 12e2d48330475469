"""Predictor: run resolution, image loading modes, encoding shapes, the temperature file."""

import json
import time

import numpy as np
import pytest
import torch
from PIL import Image

from ushape import atomic
from ushape.reconstruction.predictor import (
    collect_inputs,
    latest_run,
    load_predictor,
    pad_square,
    read_temperatures,
    temperature_path,
)

IMAGE_SIZE, LATENT = 16, 8  # the tiny_run fixture's sizes


@pytest.fixture(scope="module")
def predictor(tiny_run):
    return load_predictor(tiny_run["run"])


def test_latest_run_is_the_newest_encoder_run(tmp_path):
    with pytest.raises(FileNotFoundError, match="make demo"):
        latest_run(tmp_path)
    old, new, decoder_only = (tmp_path / "outputs" / "runs" / d for d in ("a", "b", "c"))
    for folder, stage in ((old, "encoder"), (new, "encoder"), (decoder_only, "decoder")):
        folder.mkdir(parents=True)
        atomic.write_json(folder / "run.json", {"stage": stage})
        time.sleep(0.02)
    assert latest_run(tmp_path) == new


def test_load_from_run_folder_or_checkpoint(tiny_run, predictor):
    assert predictor.image_size == IMAGE_SIZE and predictor.latent_size == LATENT
    assert predictor.world == tiny_run["world"] and predictor.temperature is None
    by_checkpoint = load_predictor(tiny_run["checkpoint"])
    assert by_checkpoint.run_dir == tiny_run["run"]
    assert load_predictor(None, root=tiny_run["root"]).checkpoint == tiny_run["checkpoint"]
    with pytest.raises(FileNotFoundError, match="neither a run folder"):
        load_predictor(tiny_run["root"] / "nope")


def _save(path, array, mode):
    Image.fromarray(array.astype(np.uint8), mode).save(path)
    return path


def test_image_modes_and_sizes_become_model_inputs(predictor, tmp_path):
    rng = np.random.default_rng(1)
    picture = np.full((30, 50, 3), 255)
    picture[10:20, 20:30] = rng.integers(0, 256, (10, 10, 3))  # an object on a plain background, no alpha
    rgb = _save(tmp_path / "rgb.png", picture, "RGB")
    gray = _save(tmp_path / "gray.png", np.full((7, 9), 128), "L")
    alpha = np.zeros((20, 20, 4))
    alpha[..., 0] = 255  # red, but fully transparent: must come out as the white background
    rgba = _save(tmp_path / "rgba.png", alpha, "RGBA")
    corrupt = tmp_path / "broken.png"
    corrupt.write_bytes(b"not a png at all")
    images, kept, skipped = predictor.load_images([rgb, gray, rgba, corrupt, tmp_path / "missing.png"])
    assert images.shape == (3, 3, IMAGE_SIZE, IMAGE_SIZE)
    assert kept == [rgb, gray, rgba]
    assert [p.name for p, _ in skipped] == ["broken.png", "missing.png"]
    assert "corrupt" in skipped[0][1] and "does not exist" in skipped[1][1]
    centre = images[1][:, IMAGE_SIZE // 2, IMAGE_SIZE // 2]
    assert torch.allclose(centre, torch.full((3,), 128 / 255), atol=0.01)
    assert torch.allclose(images[2], torch.ones_like(images[2]))
    # a 30x50 picture is padded top and bottom: the first row is background
    assert torch.allclose(images[0][:, 0], torch.ones(3, IMAGE_SIZE), atol=1e-4)
    with pytest.raises(ValueError, match="none of the 1 input"):
        predictor.load_images([corrupt])


def test_pad_square_centres_the_image():
    rgba = torch.ones(4, 2, 4)
    out = pad_square(rgba)
    assert out.shape == (4, 4, 4)
    assert out[:, 1:3].eq(1).all() and out[:, 0].eq(0).all() and out[:, 3].eq(0).all()


def test_collect_inputs_expands_folders(tmp_path):
    for name in ("b.png", "a.jpg", "notes.txt"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in collect_inputs([tmp_path])] == ["a.jpg", "b.png"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="holds no"):
        collect_inputs([tmp_path / "empty"])
    with pytest.raises(ValueError, match="no input images"):
        collect_inputs([])


def test_encode_gives_positive_variances_and_applies_temperature(tiny_run, predictor):
    images = torch.rand(2, 3, IMAGE_SIZE, IMAGE_SIZE)
    mu, var = predictor.encode(images)
    assert mu.shape == var.shape == (2, LATENT) and (var > 0).all()
    with pytest.raises(ValueError, match="load_images"):
        predictor.encode(torch.rand(1, 3, 8, 8))
    with pytest.raises(FileNotFoundError, match="--fit-temperature"):
        load_predictor(tiny_run["run"], temperature=True)
    path = temperature_path(tiny_run["checkpoint"])
    atomic.write_json(path, {"temperature": 2.5})
    try:
        scaled = load_predictor(tiny_run["run"], temperature=True)
        assert read_temperatures(tiny_run["checkpoint"]) == (2.5, None)  # no SDF temperature in this file
        mu2, var2 = scaled.encode(images)
        assert torch.allclose(mu2, mu) and torch.allclose(var2, 2.5 * var)
    finally:
        path.unlink()
    assert json.loads((tiny_run["run"] / "run.json").read_text())["stage"] == "encoder"


def test_tiny_inputs_are_read_with_a_warning(predictor, tmp_path, caplog):
    """A 1x1 picture says nothing about a shape: it is reconstructed, but the user is told why it looks vague."""
    dot = _save(tmp_path / "dot.png", np.full((1, 1, 3), 90), "RGB")
    fine = _save(tmp_path / "fine.png", np.full((IMAGE_SIZE, IMAGE_SIZE, 3), 90), "RGB")
    with caplog.at_level("WARNING", logger="ushape.reconstruction.predictor"):
        images, kept, _ = predictor.load_images([dot, fine])
    assert kept == [dot, fine] and images.shape[0] == 2
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and "dot.png is only 1x1 px" in warned[0]
