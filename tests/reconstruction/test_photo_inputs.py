"""A photo in: cut out by its alpha or a mask, framed as the training renders frame the object, or refused
with what to pass."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from ushape import cli
from ushape.errors import InputError
from ushape.reconstruction.predictor import (
    FRAMED_SPAN,
    check_cut_out,
    cut_out,
    frame_object,
    is_render,
    pad_square,
)


def square_object(side: int, top: int, left: int, size: int) -> torch.Tensor:
    """Premultiplied RGBA [4, side, side]: an opaque red square of `size` at (top, left), transparent elsewhere."""
    rgba = torch.zeros(4, side, side)
    rgba[0, top : top + size, left : left + size] = 1.0
    rgba[3, top : top + size, left : left + size] = 1.0
    return rgba


def span_and_offset(rgba: torch.Tensor) -> tuple[float, float]:
    inside = rgba[3] > 0.5
    rows, cols = inside.any(1).nonzero()[:, 0], inside.any(0).nonzero()[:, 0]
    side = rgba.shape[-1]
    centre = (float(rows[0] + rows[-1]) + 1) / 2, (float(cols[0] + cols[-1]) + 1) / 2
    return (int(rows[-1] - rows[0]) + 1) / side, max(abs(c - side / 2) for c in centre) / side


def test_an_object_framed_as_the_renders_frame_it_is_left_as_it_is():
    rendered = square_object(137, 25, 30, 88)  # spans 0.64, near the centre: R2N2's framing
    # Exact on purpose: "left as it is" means frame_object returns pad_square's own result, no arithmetic.
    assert torch.equal(frame_object(rendered), pad_square(rendered))
    opaque = torch.ones(4, 60, 80)  # no alpha: the object is not marked, so nothing is re-framed
    assert torch.equal(frame_object(opaque), pad_square(opaque))


@pytest.mark.parametrize("top, left, size", [(10, 200, 40), (5, 5, 290), (100, 5, 150)])
def test_a_small_large_or_off_centre_object_is_cropped_to_the_renders_framing(top, left, size):
    photo = square_object(300, top, left, size)
    framed = frame_object(photo)
    span, offset = span_and_offset(framed)
    assert framed.shape[-1] == framed.shape[-2] and span == pytest.approx(FRAMED_SPAN, abs=0.02)
    assert offset <= 0.01  # centred to the pixel
    assert float(framed[3].sum()) == pytest.approx(size * size)  # the object whole, nothing invented


def test_a_photo_without_alpha_or_mask_is_refused_unless_its_background_is_plain():
    noisy = torch.cat([torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)), torch.ones(1, 64, 64)])
    with pytest.raises(InputError, match="no alpha channel and no mask.*--masks MASK.png"):
        check_cut_out(noisy, "photo.jpg")
    plain = torch.ones(4, 64, 64)
    plain[:3, 20:40, 20:40] = 0.2  # a dark object on white, as a render saved without alpha
    check_cut_out(plain, "render.png")
    masked = cut_out(noisy, torch.zeros(64, 64, dtype=torch.bool).index_fill_(0, torch.arange(10, 30), True), "m")
    check_cut_out(masked, "photo.jpg")
    # Exact on purpose: outside the mask the colour is multiplied by alpha 0, which is 0 in any rounding.
    assert float(masked[3].sum()) == 20 * 64 and torch.equal(masked[:3, :10], torch.zeros(3, 10, 64))


def test_renders_are_recognised_by_the_camera_file_beside_them(tmp_path):
    (tmp_path / "rendering").mkdir()
    (tmp_path / "rendering" / "rendering_metadata.txt").write_text("0 25 0 0.8 25\n")
    assert is_render(tmp_path / "rendering" / "00.png") and not is_render(tmp_path / "photo.png")


def test_a_photo_on_a_busy_background_needs_a_mask_and_runs_with_one(
    tiny_run, sphere_predictor, tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr("ushape.reconstruction.cli.open_model", lambda *args, **kwargs: sphere_predictor)
    rng = np.random.default_rng(0)
    photo = tmp_path / "photo.jpg"
    Image.fromarray(rng.integers(0, 255, (90, 120, 3), dtype=np.uint8)).save(photo)
    base = ["reconstruct", str(photo), "--run", str(tiny_run["run"]), "--resolution", "16", "--depth-size", "8"]
    assert cli.main([*base, "--out", str(tmp_path / "a")]) == 2
    assert "has no alpha channel and no mask" in capsys.readouterr().err
    mask = np.zeros((90, 120), np.uint8)
    mask[30:60, 50:80] = 255
    Image.fromarray(mask).save(tmp_path / "mask.png")
    assert cli.main([*base, "--out", str(tmp_path / "b"), "--masks", str(tmp_path / "mask.png")]) == 0
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["views"][0]["image"] == str(photo)
