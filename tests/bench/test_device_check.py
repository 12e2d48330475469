"""The GPU device check runs end to end on CPU with tiny limits, and records what it measured or why not."""

import json
import os
from pathlib import Path

import pytest

from ushape.bench import device_check
from ushape.bench.cli import loader_section

_HERE = Path(os.path.dirname(os.path.abspath(__file__)))
SHARED = next((p / "shared" / "data" for p in _HERE.parents if (p / "shared" / "data").is_dir()), _HERE / "absent")
VOXELS = SHARED / "ShapeNetVox32"
TINY = ["--tiny", "--shapes", "3", "--held-out", "1", "--views", "2", "--build-workers", "0"]


@pytest.fixture
def voxels():
    if not (VOXELS / "03001627").is_dir():
        pytest.skip(f"shared voxels not present at {VOXELS}")
    return str(VOXELS)


def test_device_check_trains_both_stages_and_writes_one_json(voxels, tmp_path):
    out = tmp_path / "check.json"
    args = [*TINY, "--voxels-root", voxels, "--work", str(tmp_path), "--out", str(out), "--no-bench"]
    assert device_check.main([*args, "--stage1-steps", "5", "--stage2-steps", "2"]) == 0
    record = json.loads(out.read_text())
    assert record["errors"] == {} and record["machine"]["cpu_count"] >= 1
    assert record["world"]["splits"] == {"train": 3, "val": 1, "test": 1}
    # Every step timed (the first few are warm-up), with the wait for its batch beside it.
    assert record["stage1"]["steps"] == 5 and record["stage1"]["steps_per_s"] > 0
    assert record["stage2"]["steps"] == 2 and 0 <= record["stage2"]["wait_fraction"] < 1
    assert record["stage1"]["gpu"]["nvidia_smi"] in (True, False)
    rates = record["loaders"]["one_process"]
    assert rates[0]["units_per_s"] == pytest.approx(rates[0]["items_per_s"] * 256)  # tiny: 256 samples a shape
    assert "stage-2 views at 32 px" in record["loaders"]["table"]
    assert record["config"]["decoder"]["hidden_dims"] == [256] * 4  # --tiny: the small decoder
    # bench.py --loaders-world: the same rates for the paper's batch, as a section of its report.
    section = loader_section(record["world"]["root"], quick=True)
    assert section.startswith("| loader (one core) |") and section.count("\n") == 6


def test_a_spent_budget_skips_parts_and_says_so(voxels, tmp_path):
    out = tmp_path / "check.json"
    args = [*TINY, "--voxels-root", voxels, "--work", str(tmp_path), "--out", str(out), "--budget-s", "0"]
    assert device_check.main(args) == 1
    record = json.loads(out.read_text())
    assert set(record["errors"]) == {"world", "bench"} and "budget" in record["errors"]["world"]
    with pytest.raises(SystemExit, match="03001627"):
        device_check.main(["--voxels-root", str(tmp_path)])


def test_loader_report_counts_the_cores_a_gpu_step_rate_needs():
    from ushape.bench.loaders import STAGE1_STEPS_PER_S, LoaderRate, loader_report

    # 100 shapes/s of 16,384 samples on a core that was busy half the time: 3.3 M samples per CPU-second.
    one = LoaderRate("stage-1 SDF samples", 100.0, 100.0 * 16384, 5, 0, 0.5)
    two = LoaderRate("stage-2 views at 224 px", 200.0, 200.0, 2, 0, 1.0)
    table = loader_report(one, two)
    need = max(STAGE1_STEPS_PER_S.values()) * 64 * 16384
    assert f"| {need / 1e6:.1f} M | {need / (2 * 100 * 16384):.1f} |" in table  # 10 steps/s: 3.2 cores
    assert "| 2880 | 14.4 |" in table  # 45 steps of 64 views at 200 views/s a core
