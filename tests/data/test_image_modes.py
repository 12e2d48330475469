"""Images of every mode Pillow reads come in with their real content, or are refused by name."""

import numpy as np
import pytest
from PIL import Image

from ushape.data.augment import load_rgba, read_image
from ushape.evaluation.views import load_view

GRADIENT = np.linspace(0, 1, 12, dtype=np.float64)[None, :].repeat(6, axis=0)  # [6, 12], black to white


def test_16bit_grey_png_keeps_its_grey_levels(tmp_path):
    """Pillow clips I;16 at 255 when converting to RGBA: the whole gradient used to read as white."""
    Image.fromarray((GRADIENT * 65535).round().astype(np.uint16)).save(tmp_path / "g16.png")
    rgba = load_rgba(tmp_path / "g16.png")
    assert rgba.shape == (4, 6, 12)
    np.testing.assert_allclose(rgba[0].numpy(), GRADIENT, atol=1e-4)
    np.testing.assert_allclose(rgba[1].numpy(), rgba[0].numpy())
    assert (rgba[3] == 1).all()
    # The "no mask" evaluation input reads the same pixels.
    np.testing.assert_allclose(load_view(tmp_path / "g16.png", "none")[0].numpy(), GRADIENT, atol=1e-4)


def _rgb_reference() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (8, 10, 3), dtype=np.uint8)


@pytest.mark.parametrize("mode", ["P", "LA", "L", "CMYK", "1"])
def test_other_modes_read_like_pillows_own_rgba(tmp_path, mode):
    source = Image.fromarray(_rgb_reference(), "RGB").convert(mode)
    path = tmp_path / ("x.jpg" if mode == "CMYK" else "x.png")
    source.save(path, **({"quality": 100} if mode == "CMYK" else {}))
    expected = np.asarray(Image.open(path).convert("RGBA"), dtype=np.float32) / 255.0
    np.testing.assert_allclose(read_image(path), expected, atol=1e-6)


def test_exif_orientation_is_applied(tmp_path):
    """A phone photo stored sideways with orientation 6 (rotate 90 degrees clockwise to view) comes in upright."""
    stored = np.zeros((10, 20, 3), np.uint8)
    stored[:, :5] = 255  # a white band on the stored image's left edge
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(stored).save(tmp_path / "phone.jpg", exif=exif, quality=100)
    rgba = load_rgba(tmp_path / "phone.jpg")
    assert rgba.shape == (4, 20, 10)  # upright: taller than wide
    assert rgba[0, :5].mean() > 0.9 and rgba[0, -5:].mean() < 0.1  # the left edge is now the top


def test_float_images_are_refused_by_name(tmp_path):
    Image.fromarray(np.full((4, 4), 0.5, np.float32), "F").save(tmp_path / "f.tif")
    with pytest.raises(ValueError, match=r"f\.tif.*mode F"):
        load_rgba(tmp_path / "f.tif")
