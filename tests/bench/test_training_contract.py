"""bench.py --training-contract: bf16 stage-1 training held to the spread of fp32 seeds (no time asserted)."""

import pytest

from ushape.bench.training import machine
from ushape.bench.training_contract import (
    ContractRun,
    ContractSettings,
    ContractVerdict,
    contract_report,
    run_contract,
    within_spread,
    write_contract_report,
)

TINY = ContractSettings(
    steps=2,
    train_shapes=2,
    test_shapes=1,
    shapes_per_batch=2,
    samples_per_shape=32,
    world_samples=2000,
    latent_iterations=2,
    latent_samples=64,
    iou_resolution=8,
    fp32_seeds=(0, 1),
)


def test_within_spread_includes_both_ends_and_nothing_outside():
    assert within_spread(0.5, [0.4, 0.6]) and within_spread(0.4, [0.4, 0.6]) and within_spread(0.6, [0.6, 0.4])
    assert not within_spread(0.61, [0.4, 0.6]) and not within_spread(0.39, [0.4, 0.6])
    assert within_spread(1.0, [1.0]) and not within_spread(1.0 + 1e-9, [1.0])
    with pytest.raises(ValueError, match="no reference"):
        within_spread(1.0, [])


def test_a_verdict_is_met_only_when_both_figures_sit_within_the_fp32_spread(tmp_path):
    runs = [ContractRun("fp32", 0, 0.02, 0.6, 1.0), ContractRun("fp32", 1, 0.03, 0.7, 1.0)]
    inside = ContractVerdict([*runs, ContractRun("bf16", 0, 0.025, 0.65, 1.0)], True, True, ["loss ok", "IoU ok"])
    outside = ContractVerdict([*runs, ContractRun("bf16", 0, 0.05, 0.65, 1.0)], False, True, ["loss bad"])
    assert inside.met and not outside.met
    about = machine()
    report = contract_report(outside, TINY, about)
    assert "contract missed" in report and about["cpu"] in report and report.count("\n| bf16 |") == 1
    write_contract_report(inside, TINY, about, tmp_path / "contract.md")
    assert "contract met" in (tmp_path / "contract.md").read_text() and (tmp_path / "contract.json").is_file()


def test_the_runs_train_each_seed_and_bf16_on_one_world_and_score_them(tmp_path):
    verdict = run_contract(tmp_path, TINY)
    assert [(r.precision, r.seed) for r in verdict.runs] == [("fp32", 0), ("fp32", 1), ("bf16", 0)]
    assert all(r.final_loss > 0 and 0 <= r.heldout_iou <= 1 for r in verdict.runs)
    fp32 = verdict.runs[:2]
    assert verdict.loss_within == within_spread(verdict.runs[2].final_loss, [r.final_loss for r in fp32])
    assert len(verdict.notes) == 2
