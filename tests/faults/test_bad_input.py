"""Bad input through the real command lines: exit code 2 and one line naming the key or file, no traceback.

Each case was found by a fault probe of a fresh checkout, run as a new user would: Hydra's composition
errors, and the data errors raised inside a Hydra job, came out as Hydra's text block (or a traceback)
with exit code 1; a corrupt views.npz beside a render and a 15000 x 15000 PNG gave raw tracebacks.
Every command here fails before any training; the files are tiny and synthetic. Each takes 2-10 s on
an idle 2-core machine (most of it starting Python, torch and Lightning), so all run in the default suite.
"""

import json
import os
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from analytic_decoder import run_with_ellipsoid
from PIL import Image
from repo_commands import run_command

from ushape.data.augment import read_image
from ushape.reconstruction.view_depth import view_camera

TESTS = Path(__file__).resolve().parents[1]
LATENT = 8  # the tiny_run fixture's code size


def error_line(result) -> str:
    """The one `error: ...` line of a refused command; fails on a traceback, Hydra's hint or a second error."""
    assert result.returncode == 2, result.stderr[-3000:]
    for text in ("Traceback", "HYDRA_FULL_ERROR", "Error executing job", "Error in call to target"):
        assert text not in result.stderr, result.stderr[-3000:]
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, result.stderr[-3000:]
    return errors[0]


def files_under(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.is_file()]


@pytest.mark.parametrize(
    "override, named",
    [
        ("loss=bogus", ["loss=bogus", "choose one of es, l2, nll", "conf/loss/<name>.yaml"]),
        ("category=sofas", ["category=sofas", "choose one of chairs, tables"]),
        ("loss=nl", ["loss=nl", "did you mean loss=nll?"]),
        ("stage2.max_epoch=3", ["stage2.max_epoch=3", "stage2 has no key max_epoch", "did you mean stage2.max_epochs"]),
    ],
)
def test_an_unknown_option_or_key_is_one_line_with_the_choices(tmp_path, override, named):
    """Hydra printed its block (`Could not find 'loss/bogus'`, `full_key: stage2.max_epoch`) and exited 1."""
    result = run_command(tmp_path, "train.py", override, timeout=300)
    line = error_line(result)
    assert result.stderr.strip() == line, result.stderr  # nothing but the line
    assert all(text in line for text in named), line
    assert files_under(tmp_path) == []


@pytest.mark.parametrize(
    "override, named",
    [
        ("data.n_train=0", "data.n_train=0 must be an integer >= 1"),
        ("encoder.latent_size=32", "encoder.latent_size=32 but decoder.latent_size=64"),
    ],
)
def test_a_bad_value_is_named_before_any_data_is_made(tmp_path, override, named):
    """data.n_train=0 came wrapped in Hydra's text; encoder.latent_size=32 trained stage 1 for minutes first."""
    line = error_line(run_command(tmp_path, "train.py", override, timeout=300))
    assert line.startswith("error: invalid config, nothing was run: ") and named in line, line
    assert files_under(tmp_path) == []


@pytest.mark.parametrize(
    "layout, named",
    [
        ("missing", "data.root={root} is not a folder: pass the dataset's folder"),
        ("empty", "{root} has no synset folder 03001627"),
        ("wrong", "found folders ['foo']. Point data.root at the folder that holds the synset folders"),
    ],
)
def test_a_shapenet_root_that_is_not_one_is_named(tmp_path, layout, named):
    root = tmp_path / "ShapeNetCore"
    if layout != "missing":
        root.mkdir()
    if layout == "wrong":
        (root / "foo").mkdir()
    result = run_command(tmp_path, "train.py", "data=shapenet", f"data.root={root}", timeout=300)
    line = error_line(result)
    prefix = "error: invalid config, nothing was run: " if layout == "missing" else "error: data: "
    assert line.startswith(prefix) and named.format(root=root) in line, line
    assert not (tmp_path / "outputs" / "runs").exists() or files_under(tmp_path / "outputs" / "runs") == []


def test_a_missing_data_root_says_to_give_it(tmp_path):
    """`data=shapenet` alone: OmegaConf's MissingMandatoryValue traceback."""
    line = error_line(run_command(tmp_path, "train.py", "data=shapenet", timeout=300))
    assert "data.root has no value" in line and "data.root=<value>" in line, line


def test_pix3d_is_refused_for_training(tmp_path):
    """Pix3D has test shapes only: training preprocessed all of it, then failed on an empty train split."""
    root = tmp_path / "pix3d"
    root.mkdir()
    line = error_line(run_command(tmp_path, "train.py", "data=pix3d", f"data.root={root}", timeout=300))
    assert "data=pix3d is for evaluation only" in line and "eval.py data=pix3d" in line, line
    assert files_under(tmp_path) == []


def test_hydra_full_error_keeps_the_traceback(tmp_path):
    """HYDRA_FULL_ERROR=1 is how a maintainer asks for the whole story: nothing is translated."""
    result = run_command(tmp_path, "train.py", "loss=bogus", env={"HYDRA_FULL_ERROR": "1"}, timeout=300)
    assert result.returncode == 1 and "Traceback" in result.stderr and "Could not find 'loss/bogus'" in result.stderr


@pytest.mark.parametrize(
    "args, named",
    [
        (["fusion=bogus"], "fusion=bogus: no such option of the config group fusion; choose one of average, bayesian"),
        (["sweep={missing}"], "sweep folder {missing} does not exist"),
    ],
)
def test_eval_refuses_bad_input_in_one_line(tmp_path, args, named):
    missing = tmp_path / "no_sweep"
    args = [a.format(missing=missing) for a in args]
    line = error_line(run_command(tmp_path, "eval.py", *args, timeout=300))
    assert named.format(missing=missing) in line, line


@pytest.fixture(scope="module")
def ellipsoid_run(tiny_run, tmp_path_factory):
    """tiny_run's encoder with the analytic ellipsoid as its decoder (a surface for every code), in a copy."""
    run = run_with_ellipsoid(tiny_run, tmp_path_factory.mktemp("ellipsoid_run"), LATENT)
    return {"run": run, "world": tiny_run["world"]}


def reconstruct(root: Path, run: Path, *inputs: Path):
    """reconstruct.py on the inputs, small grids; tests/ importable (the ellipsoid decoder lives there)."""
    args = ["--run", str(run), "--resolution", "16", "--depth-size", "8", "--out", str(root / "out")]
    env = {"PYTHONPATH": os.pathsep.join([str(TESTS.parent), str(TESTS), os.environ.get("PYTHONPATH", "")])}
    return run_command(root, "reconstruct.py", *map(str, inputs), *args, env=env, timeout=300)


def huge_png(path: Path, side: int = 15000) -> Path:
    """A black 1-bit PNG of side x side pixels in about 30 kB, written directly (Pillow would hold 225 MB)."""
    row = b"\x00" + bytes((side + 7) // 8)  # filter byte, then the row's packed bits

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", side, side, 1, 0, 0, 0, 0)  # 1 bit, greyscale
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(row * side, 9))
    path.write_bytes(png + chunk(b"IEND", b""))
    return path


def good_image(path: Path) -> Path:
    yy, xx = np.mgrid[:32, :32]
    disc = ((yy - 16) ** 2 + (xx - 16) ** 2 < 100).astype(np.uint8) * 255
    Image.fromarray(np.stack([disc, disc // 2, disc // 3, disc], -1), "RGBA").save(path)
    return path


def test_a_huge_image_alone_is_refused_by_name(ellipsoid_run, tmp_path):
    """Pillow's DecompressionBombError came out as a raw traceback with exit code 1."""
    huge = huge_png(tmp_path / "huge.png")
    line = error_line(reconstruct(tmp_path, ellipsoid_run["run"], huge))
    assert f"image {huge} has more than 89,478,485 pixels" in line and "downscale it" in line, line


def test_a_huge_image_beside_good_ones_is_skipped_and_they_go_on(ellipsoid_run, tmp_path):
    huge, good = huge_png(tmp_path / "huge.png"), good_image(tmp_path / "good.png")
    result = reconstruct(tmp_path, ellipsoid_run["run"], huge, good)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"skipped {huge}: image {huge} has more than" in result.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [v["image"] for v in summary["views"]] == [str(good)]
    assert [s["image"] for s in summary["skipped"]] == [str(huge)]


def test_a_render_with_a_corrupt_views_npz_is_reconstructed_from_the_canonical_camera(ellipsoid_run, tmp_path):
    """A truncated views.npz raised zipfile.BadZipFile; only the depth map needs the camera, so it is named
    in a warning and the view is traced from the canonical camera, as a photo is."""
    renders = shutil.copytree(sorted((ellipsoid_run["world"] / "renders").iterdir())[0], tmp_path / "renders")
    views = renders / "views.npz"
    views.write_bytes(views.read_bytes()[:200])
    image = sorted(renders.glob("*.png"))[0]
    result = reconstruct(tmp_path, ellipsoid_run["run"], image)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"camera file {views} of {image} cannot be read (BadZipFile" in result.stderr
    assert "traced from the canonical camera instead" in result.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [v["depth"]["camera"] for v in summary["views"]] == ["canonical"]


def test_read_image_refuses_a_huge_image_by_name_without_decoding_it(tmp_path):
    """In-process and fast: the limit check reads the header only (the 225-Mpx image is never decoded)."""
    huge = huge_png(tmp_path / "huge.png")
    with pytest.raises(ValueError, match=f"image {huge} has more than 89,478,485 pixels"):
        read_image(huge)
    over_the_warning = huge_png(tmp_path / "big.png", side=9500)  # Pillow only warns between 1x and 2x the limit
    with pytest.raises(ValueError, match="downscale it"):
        read_image(over_the_warning)


def test_view_camera_falls_back_to_the_canonical_camera_for_a_corrupt_views_npz(tmp_path, caplog):
    render = good_image(tmp_path / "00.png")
    (tmp_path / "views.npz").write_bytes(b"PK\x03\x04 truncated")
    with caplog.at_level("WARNING", logger="ushape.reconstruction.pipeline"):
        K, w2c, kind = view_camera(render, 8)
    assert kind == "canonical" and K.shape == (3, 3) and w2c.shape == (4, 4)
    assert f"camera file {tmp_path / 'views.npz'} of {render} cannot be read" in caplog.text
