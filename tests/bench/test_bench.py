"""bench.py in a tiny configuration: every row and ratio is present, numbers are positive, the file is written."""

import re

import pytest
import torch

from ushape.bench.cli import main
from ushape.bench.computation import Measurement, bench_decoder
from ushape.bench.report import DecoderBench, ratio_rows

DECODER_ROWS = [
    "decoder field fp32",
    "decoder field bf16",
    "marching cubes",
    "mesh dense (field + MC)",
    "mesh coarse-to-fine",
    "vertex uncertainty mc M=10",
    "vertex uncertainty linearised",
    "field uncertainty mc M=10",
    "field uncertainty linearised",
    "mesh with uncertainty (coarse-to-fine + vertex linearised)",
    "mesh with uncertainty (coarse-to-fine + vertex mc M=10)",
    "field uncertainty linearised narrow band",
    "field uncertainty mc M=10 narrow band",
    "depth uncertainty mc M=10 (2 views)",
    "depth uncertainty implicit (2 views)",
    "mesh with uncertainty (c2f + linearised), fp32",
    "mesh with uncertainty (c2f + linearised), bf16",
]


def _seconds(cell):
    value, unit = cell.split()
    return float(value) * (1e-3 if unit == "ms" else 1.0)


@pytest.mark.slow  # 46 s on 2 cores: whole commands end to end; `make test-slow` and CI run it
def test_quick_bench_writes_the_whole_table(tmp_path, capsys):
    out = tmp_path / "bench.md"
    assert (
        main(["--quick", "--resolution", "16", "--deepsdf-fraction", "0.25", "--depth-views", "2", "--out", str(out)])
        == 0
    )
    text = out.read_text()
    assert text in capsys.readouterr().out
    rows = {
        line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
        for line in text.splitlines()
        if line.startswith("| ") and not line.startswith("| step") and not line.startswith("| ratio")
    }
    for name in DECODER_ROWS:
        small, deepsdf = rows[name][:2]
        assert _seconds(small) > 0 and _seconds(deepsdf) > 0, name
    assert rows["decoder field fp32"][2] == "0.55 s" and rows["field uncertainty mc M=10"][2] == "5.45 s"
    assert "extrapolated from 25%" in rows["field uncertainty mc M=10"][3]
    assert _seconds(rows["fusion bayesian"][0]) > 0 and rows["fusion bayesian"][1] == "0.1 ms"
    assert re.search(r"< 0\.1 ms (pass|miss)", rows["fusion bayesian"][2])
    ratios = [line for line in text.splitlines() if line.startswith("| ") and "x |" in line]
    assert len(ratios) == 26  # 13 ratios x 2 decoders
    assert sum(("pass" in r) or ("miss" in r) for r in ratios) == 12  # 6 with a target x 2 decoders
    assert "fallback: None" in rows["refine masks (2 views, 16 px)"][3]
    assert "variance at" in rows["field uncertainty linearised narrow band"][3]
    assert "faster than MC M=10" in rows["depth uncertainty implicit (2 views)"][3]
    # auto beside fp32 and bf16, the resolved choice printed, the contract's figures in the notes
    auto = next(name for name in rows if name.startswith("mesh with uncertainty (c2f + linearised), auto (-> "))
    resolved = auto.removesuffix(")").rsplit(" ", 1)[-1]
    assert resolved in ("fp32", "bf16") and f"Precision `auto` on this machine: {resolved} (" in text
    assert _seconds(rows[auto][0]) > 0 and _seconds(rows[auto][1]) > 0
    assert "vs fp32: Chamfer" in rows["mesh with uncertainty (c2f + linearised), bf16"][3]
    assert "contract met" in rows["mesh with uncertainty (c2f + linearised), bf16"][3]


def test_ratios_and_verdicts_from_known_timings():
    bench = DecoderBench(
        "d",
        "test",
        1,
        [
            Measurement("decoder field fp32", 1.0),
            Measurement("decoder field bf16", 0.5),
            Measurement("mesh dense (field + MC)", 1.2),
            Measurement("mesh coarse-to-fine", 0.4),
            Measurement("vertex uncertainty mc M=10", 0.2),
            Measurement("vertex uncertainty linearised", 0.02, points=10),
            Measurement("field uncertainty mc M=10", 10.0),
            Measurement("field uncertainty linearised", 1.5, points=1000),
            Measurement("field uncertainty linearised narrow band", 0.15),
            Measurement("field uncertainty mc M=10 narrow band", 0.6),
            Measurement("depth uncertainty mc M=10 (12 views)", 9.0),
            Measurement("depth uncertainty implicit (12 views)", 1.0),
            Measurement("mesh with uncertainty (c2f + linearised), fp32", 2.0),
            Measurement("mesh with uncertainty (c2f + linearised), bf16", 0.8),
            Measurement("mesh with uncertainty (c2f + linearised), auto (-> bf16)", 0.9),
        ],
    )
    got = {name: (value, passed) for name, value, _, passed in ratio_rows(bench)}
    # Exact: Python float divisions (IEEE on any CPU) of the timings above, by 1.0, 2.0 or as written here.
    assert got["coarse-to-fine mesh / dense mesh"] == (0.4 / 1.2, None)
    assert got["field w/ unc (linearised) / field"] == (1.5, True)
    assert got["field w/ unc (MC M=10) / field"] == (10.0, None)
    assert got["narrow-band field w/ unc (linearised) / field"] == (0.15, True)
    assert got["narrow-band field w/ unc (MC M=10) / field"] == (0.6, None)
    assert got["depth unc MC M=10 / implicit (speed-up)"] == (9.0, False)
    assert got["mesh w/ unc (linearised) bf16 / fp32"] == (0.4, None)
    assert got["mesh w/ unc (linearised) auto / fp32"] == (0.45, None)
    assert got["vertex linearised per vertex / field linearised per point"][0] == pytest.approx(
        (0.02 / 10) / (1.5 / 1000)
    )
    assert got["mesh w/ unc (linearised) / mesh, coarse-to-fine"][1] is True  # 1.05x
    assert got["mesh w/ unc (MC M=10) / mesh, coarse-to-fine"][1] is False  # 1.5x
    assert got["field bf16 / field fp32"] == (0.5, None)


def test_random_decoder_is_shifted_to_have_a_surface():
    decoder, code, provenance = bench_decoder("small")
    from ushape.propagation.field import decode_field

    field = decode_field(decoder, code, 16)
    assert provenance == "random weights" and (field < 0).any() and (field > 0).any()
    assert abs(float(field.median())) < 0.05 and code.shape == (64,)


def test_fitted_decoder_has_the_chair_surface_and_is_cached(tmp_path):
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from ushape.bench.fitted import chair_samples, fitted_decoder

    config = OmegaConf.create(
        {
            "_target_": "ushape.decoder.network.DeepSDFDecoder",
            "latent_size": 4,
            "hidden_dims": [32, 32],
            "latent_in": [],
            "dropout": 0.0,
        }
    )
    code = torch.zeros(4)
    points, sdf = chair_samples(0)
    first, provenance = fitted_decoder(config, code, 150, tmp_path)
    assert "L1" in provenance and len(list(tmp_path.glob("fitted-*.pt"))) == 1
    with torch.no_grad():
        error = (first(points, code).clamp(-0.1, 0.1) - sdf.clamp(-0.1, 0.1)).abs().mean()
        torch.manual_seed(0)
        untrained = instantiate(config)
        error_before = (untrained(points, code).clamp(-0.1, 0.1) - sdf.clamp(-0.1, 0.1)).abs().mean()
    assert error < 0.5 * error_before
    again, provenance = fitted_decoder(config, code, 150, tmp_path)
    assert "cached" in provenance
    for a, b in zip(first.state_dict().values(), again.state_dict().values()):
        assert torch.equal(a, b)


@pytest.mark.slow  # 22 s on 2 cores: whole commands end to end; `make test-slow` and CI run it
def test_precision_only_bench_has_the_three_rows_per_decoder_and_their_ratios(tmp_path):
    out = tmp_path / "bench.md"
    argv = ["--quick", "--resolution", "16", "--precision-only", "--repeats", "2", "--depth-views", "2"]
    assert main([*argv, "--out", str(out)]) == 0
    text = out.read_text()
    rows = {
        line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
        for line in text.splitlines()
        if line.startswith("| ") and not line.startswith("| step") and not line.startswith("| ratio")
    }
    timed_rows = [name for name in rows if name.startswith("mesh with uncertainty (c2f + linearised), ")]
    assert len(timed_rows) == 3 and "decoder field fp32" not in rows and "fusion bayesian" not in rows
    for name in timed_rows:
        assert _seconds(rows[name][0]) > 0 and _seconds(rows[name][1]) > 0
        assert "min of 2 interleaved, median" in rows[name][3] and "load " in rows[name][3]
    ratios = [line for line in text.splitlines() if line.startswith("| mesh w/ unc (linearised)")]
    assert len(ratios) == 4 and all("not run" not in line for line in ratios)  # bf16 and auto, 2 decoders
