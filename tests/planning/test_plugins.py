"""Every strategy and observer is a YAML file that builds its class; the sequence's context reaches those that
need it; a name that is not there is refused with the names that are."""

import pytest
import torch

from ushape.planning.plugins import (
    SequenceContext,
    build_observer,
    build_strategy,
    is_oracle,
    observer_names,
    predicts_rows,
    strategy_names,
)

FLOORS = {"sdf_temperature": 1.0, "floor_seen": 0.01, "floor_unseen": 0.1}


@pytest.mark.parametrize("name", strategy_names())
def test_every_strategy_file_builds_a_strategy_for_a_sequence(name):
    context = SequenceContext(seed=3, true_code=torch.zeros(4), size=12)
    strategy = build_strategy(name, context, **({"floors": FLOORS} if name == "information-seen" else {}))
    assert strategy.name == name and callable(strategy.scores)
    assert getattr(strategy, "seed", 3) == 3 and getattr(strategy, "size", 12) == 12  # the sequence's


def test_oracles_and_predicted_rows_are_what_the_classes_say():
    assert [n for n in strategy_names() if is_oracle(n)] == ["oracle-occupancy", "oracle"]
    assert sorted(n for n in strategy_names() if predicts_rows(n)) == [
        "information",
        "information-seen",
        "information-surface",
    ]
    with pytest.raises(ValueError, match="own code"):
        build_strategy("oracle", SequenceContext())


@pytest.mark.parametrize("name", observer_names())
def test_every_observer_file_builds_an_observer_with_the_sequence_settings(name):
    observer = build_observer(name, SequenceContext(size=10, iterations=4))
    assert observer.name == name
    if name != "none":
        assert (observer.settings.observation.size, observer.settings.iterations) == (10, 4)


def test_unknown_names_are_refused_with_the_known_ones(tmp_path):
    with pytest.raises(ValueError, match=r"unknown strategy 'closest'; choose one of \[.*'farthest'"):
        build_strategy("closest")
    with pytest.raises(ValueError, match="unknown observer 'normals'"):
        build_observer("normals")
    (tmp_path / "broken.yaml").write_text("prefer: highest\n")
    with pytest.raises(ValueError, match="must be a mapping with a `_target_`"):
        build_strategy("broken", dirs=[tmp_path])
