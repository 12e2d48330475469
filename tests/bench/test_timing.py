"""Interleaved timing: every computation once per round, min and median per computation."""

import pytest

from ushape.bench.timing import interleaved


def test_interleaved_rounds_call_each_in_turn_and_take_min_and_median():
    calls, ticks = [], iter(range(1000))
    durations = {"a": iter([5, 3, 4]), "b": iter([1, 2, 9])}  # seconds each timed call takes, per name

    clock_now = [0.0]

    def clock():
        next(ticks)
        return clock_now[0]

    def make(name):
        def fn():
            calls.append(name)
            if len(calls) > 2:  # the two untimed set-up calls take no time
                clock_now[0] += next(durations[name])
            return len(calls)

        return fn

    timings = interleaved({"a": make("a"), "b": make("b")}, repeats=3, clock=clock)
    assert calls == ["a", "b"] + ["a", "b"] * 3
    assert timings["a"].seconds == (5, 3, 4) and timings["b"].seconds == (1, 2, 9)
    assert (timings["a"].minimum, timings["a"].median) == (3, 4)
    assert (timings["b"].minimum, timings["b"].median) == (1, 2)
    assert (timings["a"].result, timings["b"].result) == (7, 8)


def test_interleaved_needs_a_repeat():
    with pytest.raises(ValueError, match="repeats"):
        interleaved({"a": lambda: None}, 0)
