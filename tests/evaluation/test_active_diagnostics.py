"""Known answers for the linear-Gaussian model behind the score-vs-latent-drop ceiling (Table A-why)."""

import torch

from ushape.evaluation.active_diagnostics import ideal_rank_correlation, simulated_drops


def _problem(gains):
    cov = torch.tensor([[0.5, 0.1, 0.0], [0.1, 0.3, 0.05], [0.0, 0.05, 0.2]], dtype=torch.float64)
    direction = torch.tensor([1.0, -0.5, 0.25], dtype=torch.float64)
    informations = torch.stack(
        [g * (torch.eye(3, dtype=torch.float64) + torch.outer(direction, direction)) for g in gains]
    )
    return cov, informations


def test_simulated_drops_average_to_the_expected_trace_drop_and_vanish_without_information():
    cov, informations = _problem([0.0, 1.0, 10.0])
    generator = torch.Generator().manual_seed(0)
    L = torch.linalg.cholesky(cov)
    drops = torch.stack(
        [
            simulated_drops(cov, informations, L @ torch.randn(3, generator=generator, dtype=torch.float64), generator)
            for _ in range(5000)
        ]
    )
    expected = torch.stack([torch.trace(cov - torch.linalg.inv(torch.linalg.inv(cov) + A)) for A in informations])
    assert drops[:, 0].abs().max() < 1e-12  # a view that constrains nothing leaves the error as it was
    standard_error = drops.std(dim=0) / 5000**0.5
    assert torch.all((drops.mean(dim=0) - expected).abs() < 4 * standard_error + 1e-12)
    assert expected[2] > expected[1] > 0


def test_the_ideal_correlation_is_high_when_candidates_differ_and_near_zero_when_they_do_not():
    cov, informations = _problem([0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0])
    expected = torch.stack([torch.trace(cov - torch.linalg.inv(torch.linalg.inv(cov) + A)) for A in informations])
    assert ideal_rank_correlation(cov, informations, expected, draws=100) > 0.6
    same = informations[[4] * 8]
    assert abs(ideal_rank_correlation(cov, same, torch.arange(8.0), draws=400)) < 0.05
