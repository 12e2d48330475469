"""ushape built as a wheel and installed without -e runs its commands from anywhere (no checkout paths).

The wheel is installed with --no-deps into a folder put first on PYTHONPATH, so the dependencies
come from the test's environment and `ushape` itself from the wheel; the commands run in an empty
folder outside the checkout.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from eval_world import build_sphere_world, fit_sphere_run

ROOT = Path(__file__).resolve().parents[2]


def _pip(*args: str, cwd: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "pip", "--disable-pip-version-check", *args], cwd=cwd, capture_output=True, text=True
    )
    if result.returncode != 0 and "No module named pip" in result.stderr:
        pytest.skip("this environment has no pip")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(site folder holding the installed wheel, an empty working folder) for running `ushape`."""
    base = tmp_path_factory.mktemp("installed")
    source = base / "source"  # a copy, so that building leaves no build/ folder in the checkout
    for name in ("ushape", "conf"):
        shutil.copytree(ROOT / name, source / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    _pip("wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(base / "wheel"), str(source), cwd=base)
    wheel = next((base / "wheel").glob("ushape-*.whl"))
    _pip("install", "--no-deps", "-q", "--target", str(base / "site"), str(wheel), cwd=base)
    work = base / "work"
    work.mkdir()
    return base / "site", work


def _ushape(installed, *args: str) -> subprocess.CompletedProcess:
    site, work = installed
    # tests/ too: the run's decoder is the analytic test double (analytic_decoder.EllipsoidDecoder).
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT / "tests")]), "USHAPE_ROOT": str(work)}
    code = "import sys, ushape; from ushape.cli import main; print('ushape from', ushape.__file__); sys.exit(main())"
    result = subprocess.run(
        [sys.executable, "-c", code, *args], cwd=work, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, f"ushape {' '.join(args)} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    assert f"ushape from {site}" in result.stdout, "the checkout's ushape ran instead of the installed wheel"
    return result


def test_the_wheel_carries_the_configs_and_the_shipped_models(installed):
    site, _ = installed
    configs = {p.relative_to(site / "ushape" / "conf") for p in (site / "ushape" / "conf").rglob("*.yaml")}
    assert configs == {p.relative_to(ROOT / "conf") for p in (ROOT / "conf").rglob("*.yaml")}
    assert not (site / "ushape" / "conf").is_symlink()
    shipped = {p.relative_to(ROOT / "ushape" / "pretrained") for p in (ROOT / "ushape" / "pretrained").rglob("*.*")}
    assert shipped and shipped == {
        p.relative_to(site / "ushape" / "pretrained") for p in (site / "ushape" / "pretrained").rglob("*.*")
    }


RENDER = ROOT.parent / "shared/data/real_sample/ShapeNetRendering/03001627/1a6f615e8b1b5ae4dbbc9440457e303e/rendering"


@pytest.mark.slow  # ~20 s: a real R2N2 render through the wheel's own chairs model
@pytest.mark.skipif(not RENDER.is_dir(), reason="needs ../shared/data/real_sample")
def test_the_installed_wheel_reconstructs_from_its_shipped_model(installed):
    _, work = installed
    result = _ushape(installed, "reconstruct", str(RENDER / "00.png"), "--model", "chairs", "--refine", "masks",
                     "--resolution", "32", "--out", str(work / "shipped"))  # fmt: skip
    summary = (work / "shipped" / "summary.json").read_text()
    assert '"model": "chairs"' in summary and str(installed[0]) in summary, result.stdout[-2000:]


@pytest.mark.slow  # 57 s on 2 cores: whole commands end to end; `make test-slow` and CI run it
def test_reconstruct_eval_and_bench_run_from_the_installed_package(installed, tmp_path):
    _, work = installed
    world = build_sphere_world(tmp_path / "world")
    run = fit_sphere_run(world, tmp_path)  # an encoder trained a few steps; its decoder: analytic ellipsoids
    view = next(world.root.rglob("*.png"))
    _ushape(
        installed,
        "reconstruct",
        str(view),
        "--run",
        str(run),
        "--out",
        str(work / "rec"),
        "--resolution",
        "16",
        "--depth-size",
        "8",
        "--fusion",
        "bayesian_k",
        "--k",
        "1",
    )
    assert (work / "rec" / "mesh.ply").is_file() and (work / "rec" / "summary.json").is_file()

    _ushape(
        installed,
        "eval",
        f"runs=[{run}]",
        "protocols=[single_view]",
        "tensorboard=false",
        f"cache_dir={work / 'cache'}",
        "protocol.resolution=16",
        "protocol.n_points=64",
        "protocol.single_view_views=1",
        f"out_dir={work / 'eval'}",
    )
    assert "Table 1" in (work / "eval" / "tables.md").read_text()

    _ushape(installed, "bench", "--quick", "--decoders", "small", "--depth-views", "0", "--out", str(work / "bench.md"))
    assert "decoder field fp32" in (work / "bench.md").read_text()
