"""report.html in a real browser: headless Chromium opens a reconstruction's page from a tiny world and
screenshots it. The mesh must be drawn coloured by its std, the toggle must change the picture to plain
shading, and the page must log no console error. Skips (saying so) where Chromium is not installed;
.ci/run installs it."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ushape import cli

BROWSER = next(
    (shutil.which(name) for name in ("chromium", "chromium-browser", "google-chrome") if shutil.which(name)), None
)
FLAGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--window-size=800,900",
    "--virtual-time-budget=20000",
    "--enable-logging=stderr",
    "--v=0",
]
VIEWER_BOX = (20, 105, 735, 635)  # the <model-viewer> element's pixels in an 800 x 900 screenshot


def screenshot(page: Path, out: Path, hash_: str = "") -> tuple[np.ndarray, str]:
    """(RGB [H, W, 3] of the page's viewer, the browser's log) after the page has loaded and drawn."""
    result = subprocess.run(
        [BROWSER, *FLAGS, f"--screenshot={out}", f"{page.as_uri()}{hash_}"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert result.returncode == 0 and out.is_file(), result.stderr[-3000:]
    left, top, right, bottom = VIEWER_BOX
    return np.asarray(Image.open(out).convert("RGB"))[top:bottom, left:right].astype(float), result.stderr


def console_errors(log: str) -> list[str]:
    return [
        line for line in log.splitlines() if ("CONSOLE" in line and "INFO:CONSOLE" not in line) or "Uncaught" in line
    ]


def object_pixels(rgb: np.ndarray) -> np.ndarray:
    """The viewer's pixels that are not its white background."""
    return rgb[rgb.min(axis=-1) < 235]


@pytest.mark.skipif(BROWSER is None, reason="no Chromium installed: apt-get install chromium (.ci/run does)")
def test_the_report_shows_the_mesh_coloured_by_its_std_and_the_toggle_greys_it(
    tiny_run, sphere_predictor, tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr("ushape.reconstruction.cli.open_model", lambda *args, **kwargs: sphere_predictor)
    view = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[0]
    out = tmp_path / "out"
    args = ["reconstruct", str(view), "--run", str(tiny_run["run"]), "--out", str(out), "--resolution", "32"]
    assert cli.main([*args, "--depth-size", "8", "--refine", "masks", "--refine-size", "8"]) == 0, capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    page = Path(summary["files"]["report"])
    assert page == out / "report.html" and (out / "model-viewer-umd.min.js").is_file()
    assert "http://" not in page.read_text() and "https://" not in page.read_text()  # nothing fetched at view time
    coloured, log = screenshot(page, tmp_path / "coloured.png")
    plain, log_plain = screenshot(page, tmp_path / "plain.png", "#toggle")
    assert not console_errors(log) and not console_errors(log_plain), console_errors(log + log_plain)
    drawn = object_pixels(coloured)
    assert len(drawn) > 2000, "the viewer shows no mesh"
    # Coloured by the std (inferno): the mesh's pixels span hues, not one grey.
    chroma = drawn.max(axis=-1) - drawn.min(axis=-1)
    assert np.percentile(chroma, 75) > 60 and drawn.std(axis=0).max() > 20
    # The toggle: plain grey shading where the std colours were.
    grey = object_pixels(plain)
    grey_chroma = grey.max(axis=-1) - grey.min(axis=-1)
    assert np.percentile(grey_chroma, 50) < 25 and np.abs(coloured - plain).mean() > 5
    if os.environ.get("USHAPE_SCREENSHOT_DIR"):  # how docs/figures/report_screenshot.png was made
        shutil.copy(tmp_path / "coloured.png", Path(os.environ["USHAPE_SCREENSHOT_DIR"]) / "report_screenshot.png")
