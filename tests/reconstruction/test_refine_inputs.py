"""reconstruct.py --refine checks its inputs before any work and says per view what it refined on.

Each case was found by a new user's probe: a NaN camera, a mask of another size or an all-white mask ran and
was reported "refined" with the fused code unchanged, or fitted to the wrong pixels; --refine-size 0 crashed.
Bad input is one `error:` line naming the file and the view (exit 2, nothing written); a view that carries no
information is a named, counted fallback, never "refined".
"""

import json
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock
from PIL import Image

from ushape import cli
from ushape.reconstruction.out_dir import LOCK_FILE, claimed

SMALL = ["--resolution", "20", "--depth-size", "8", "--refine-size", "8"]


@pytest.fixture
def render(tiny_run, tmp_path):
    """One render of the tiny world copied out as a plain image, and its camera (K, world_to_cam) from views.npz."""
    folder = tiny_run["world"] / "renders" / "test_0"
    image = tmp_path / "photo.png"
    image.write_bytes(sorted(folder.glob("*.png"))[0].read_bytes())
    with np.load(folder / "views.npz") as data:
        return image, data["K"][:1].copy(), data["world_to_cam"][:1].copy()


@pytest.fixture
def run(tiny_run, sphere_predictor, monkeypatch):
    monkeypatch.setattr("ushape.reconstruction.cli.open_model", lambda *args, **kwargs: sphere_predictor)
    return tiny_run["run"]


def reconstruct(run, tmp_path, *args, capsys):
    """(exit code, what it printed (stdout and stderr), summary or None) of `ushape reconstruct` in this process."""
    out = tmp_path / "out"
    code = cli.main(["reconstruct", "--run", str(run), "--out", str(out), *SMALL, *map(str, args)])
    printed = capsys.readouterr()
    err = printed.out + printed.err
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").is_file() else None
    return code, err, summary


def error_line(code: int, err: str) -> str:
    assert code == 2, err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, err
    return lines[0]


def camera_file(path: Path, K: np.ndarray, w2c: np.ndarray, **extra: np.ndarray) -> Path:
    np.savez(path, K=K, world_to_cam=w2c, **extra)
    return path


def broken(K, w2c, case):
    K, w2c = K.copy(), w2c.copy()
    if case == "nan K":
        K[0, 0, 0] = np.nan
    elif case == "nan world_to_cam":
        w2c[0, 1, 3] = np.nan
    elif case == "behind":
        w2c[0, 2, 3] = -2.0
    elif case == "zero K":
        K[:] = 0
    elif case == "not a rotation":
        w2c[0, :3, :3] *= 2
    return K, w2c


@pytest.mark.parametrize(
    "case, named",
    [
        ("nan K", "K holds NaN or inf values"),
        ("nan world_to_cam", "world_to_cam holds NaN or inf values"),
        ("behind", "the object is behind the camera"),
        ("zero K", "K is singular"),
        ("not a rotation", "is not a rotation"),
    ],
)
def test_a_camera_no_view_could_use_is_one_error_naming_the_file_and_view(run, render, tmp_path, capsys, case, named):
    image, K, w2c = render
    cameras = camera_file(tmp_path / "cams.npz", *broken(K, w2c, case))
    line = error_line(*reconstruct(run, tmp_path, image, "--refine", "masks", "--cameras", cameras, capsys=capsys)[:2])
    assert f"camera file {cameras}, view 0 (photo.png)" in line and named in line, line
    assert not (tmp_path / "out").exists()  # nothing was run


def test_camera_files_of_the_wrong_layout_are_named(run, render, tmp_path, capsys):
    image, K, w2c = render
    text = tmp_path / "cams.txt"
    text.write_text("K = 1 0 0\n")
    wrong_k = camera_file(tmp_path / "k4.npz", np.tile(np.eye(4), (1, 1, 1)), w2c)
    wrong_w2c = camera_file(tmp_path / "w34.npz", K, w2c[:, :3])
    for path, named in [
        (text, "is not a readable .npz archive"),
        (wrong_k, "K must be [V, 3, 3], got (1, 4, 4)"),
        (wrong_w2c, "world_to_cam must be [V, 4, 4], got (1, 3, 4)"),
    ]:
        code, err, _ = reconstruct(run, tmp_path, image, "--refine", "masks", "--cameras", path, capsys=capsys)
        line = error_line(code, err)
        assert f"camera file {path}" in line and named in line, line
        assert "allow_pickle" not in line


def test_masks_and_images_of_another_size_than_the_camera_are_refused(run, render, tmp_path, capsys):
    image, K, w2c = render
    side = Image.open(image).size[0]
    small_mask = tmp_path / "mask50.png"
    Image.fromarray(np.full((50, 50), 255, np.uint8)).save(small_mask)
    cameras = camera_file(tmp_path / "cams.npz", K, w2c)
    code, err, _ = reconstruct(
        run, tmp_path, image, "--refine", "masks", "--cameras", cameras, "--masks", small_mask, capsys=capsys
    )
    line = error_line(code, err)
    assert f"the mask ({small_mask}) is 50x50 pixels, the image {side}x{side}" in line and "view 0" in line, line
    stored = camera_file(tmp_path / "stored.npz", K, w2c, masks=np.ones((1, 20, 20), np.float32))
    line = error_line(*reconstruct(run, tmp_path, image, "--refine", "masks", "--cameras", stored, capsys=capsys)[:2])
    assert "masks[0]" in line and "is 20x20 pixels" in line, line
    tiny = tmp_path / "tiny.png"
    Image.fromarray(np.full((1, 1, 4), 255, np.uint8), "RGBA").save(tiny)
    line = error_line(*reconstruct(run, tmp_path, tiny, "--refine", "masks", "--cameras", cameras, capsys=capsys)[:2])
    assert "principal point" in line and "outside the 1x1 image" in line, line


@pytest.mark.parametrize("size", ["0", "-4", "2"])
def test_refine_size_below_four_rays_is_refused(run, render, tmp_path, capsys, size):
    image, K, w2c = render
    cameras = camera_file(tmp_path / "cams.npz", K, w2c)
    code, err, _ = reconstruct(
        run, tmp_path, image, "--refine", "masks", "--cameras", cameras, "--refine-size", size, capsys=capsys
    )
    assert "--refine-size" in error_line(code, err)


def test_an_all_white_or_all_black_mask_is_a_named_fallback_not_refined(run, render, tmp_path, capsys):
    image, K, w2c = render
    side = Image.open(image).size[0]
    # the masks passed win over masks stored in the camera file (here good ones, which would refine)
    outline = np.asarray(Image.open(image).convert("RGBA"))[None, ..., 3] > 0
    cameras = camera_file(tmp_path / "cams.npz", K, w2c, masks=outline)
    for level, named in [(255, "% object: it draws no outline"), (0, "empty mask")]:
        mask = tmp_path / f"mask{level}.png"
        Image.fromarray(np.full((side, side), level, np.uint8)).save(mask)
        code, err, summary = reconstruct(
            run, tmp_path, image, "--refine", "masks", "--cameras", cameras, "--masks", mask, capsys=capsys
        )
        assert code == 0, err
        record = summary["refinement"]
        assert record["fallback"].startswith("no view has a usable mask (view 0: ") and named in record["fallback"]
        assert record["mu"] == summary["fused"]["mu"]
        view = summary["views"][0]["refined_on"]
        assert view["used"] is None and named in view["fallback"]
        assert "not refined, the fused code is kept" in err and ": refined" not in err


def test_depth_asked_without_depth_refines_on_masks_and_says_so_per_view(run, render, tmp_path, capsys):
    image, K, w2c = render
    for name, extra in [("none", {}), ("nan", {"depth": np.full((1, *Image.open(image).size[::-1]), np.nan)})]:
        cameras = camera_file(tmp_path / f"{name}.npz", K, w2c, **extra)
        code, err, summary = reconstruct(run, tmp_path, image, "--refine", "depth", "--cameras", cameras, capsys=capsys)
        assert code == 0, err
        assert summary["refinement"]["rows"]["depth"] == 0
        expected = "no depth: masks only" if name == "none" else "depth holds NaN or inf: masks only"
        assert summary["views"][0]["refined_on"] == {"used": "masks", "fallback": expected}
        assert f"refined on 1 of 1 views, depth from 0 (view 0: {expected})" in err, err


def test_a_damaged_refinement_calibration_is_named_before_any_fit(run, render, tiny_run, tmp_path, capsys):
    damaged = tiny_run["checkpoint"].parent / "refinement_calibration.json"
    damaged.write_text('{"masks": {"information_scale": 0.5, "size": "8')
    try:
        image, K, w2c = render
        cameras = camera_file(tmp_path / "cams.npz", K, w2c)
        code, err, _ = reconstruct(run, tmp_path, image, "--refine", "masks", "--cameras", cameras, capsys=capsys)
        line = error_line(code, err)
        assert f"{damaged} is damaged (Unterminated string" in line and "--fit-refinement" in line, line
        code = cli.main(["reconstruct", "--fit-refinement", "masks", "--run", str(run), "--fit-shapes", "1"])
        line = error_line(code, capsys.readouterr().err)
        assert f"{damaged} is damaged" in line
        assert damaged.read_text() == '{"masks": {"information_scale": 0.5, "size": "8'  # left for the user to see
    finally:
        damaged.unlink()


def test_out_that_is_a_file_is_refused_up_front(run, render, tmp_path, capsys):
    image = render[0]
    blocker = tmp_path / "taken"
    blocker.write_text("")
    for out, named in [
        (blocker, "is a file, not a folder"),
        (blocker / "sub", "is a file, so the folder cannot be made"),
        # writable to os.access as root, yet nothing can be made there: found by a real write
        *([(Path("/proc/ushape-out"), "/proc is not writable")] if Path("/proc/self").exists() else []),
    ]:
        code = cli.main(["reconstruct", str(image), "--run", str(run), "--out", str(out), *SMALL])
        line = error_line(code, capsys.readouterr().err)
        assert named in line and str(out) in line, line


def test_one_out_folder_is_written_by_one_run_and_never_mixes_two(run, render, tmp_path, capsys):
    image = render[0]
    out = tmp_path / "out"
    out.mkdir()
    for stale in ("depth_05.png", "depth_05.npz", "summary.json"):
        (out / stale).write_text("an earlier run's")
    (out / "notes.txt").write_text("the user's")
    code, err, summary = reconstruct(run, tmp_path, image, capsys=capsys)
    assert code == 0, err
    assert not (out / "depth_05.png").exists() and not (out / "depth_05.npz").exists()
    assert (out / "notes.txt").read_text() == "the user's" and not (out / LOCK_FILE).exists()
    with FileLock(str(out / LOCK_FILE)):  # another run holds the folder
        code = cli.main(["reconstruct", str(image), "--run", str(run), "--out", str(out), *SMALL])
        assert "another reconstruction is writing" in error_line(code, capsys.readouterr().err)
        with pytest.raises(ValueError, match="another reconstruction is writing"):
            with claimed(out):
                pass
    assert json.loads((out / "summary.json").read_text()) == summary  # the refused run changed nothing


def test_ctrl_c_is_one_line_and_exit_130(monkeypatch, capsys):
    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setattr("ushape.reconstruction.cli.main", interrupted)
    assert cli.main(["reconstruct", "x.png"]) == 130
    err = capsys.readouterr().err.strip()
    assert err.startswith("interrupted: ushape reconstruct stopped") and "\n" not in err
