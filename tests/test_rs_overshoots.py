"""``overshoots(entry, tolerance)`` (the planning's test of a segment against a tolerance, decided from
the segment's cheap position bounds when they are clear of it) gives ``overshoot(entry) >
tolerance``'s answer: random quintic, cubic and linear segments of a six-joint robot, tolerances
at the exact overshoot and a hair either side of it, the planning's own 0.1 mrad; and the bounds
do decide most of the plain cases (else there would be nothing to gain)."""

from __future__ import annotations

import numpy as np
import pytest

from robot_server.control import entries
from robot_server.control.blend import OVERSHOOT
from robot_server.control.entries import Entry, connect, overshoot, overshoots
from robot_server.control.points import State

DOF = 6


def _entry(rng: np.random.Generator, order: int, scale: float) -> Entry:
    start = State(
        rng.uniform(-2, 2, DOF) * scale,
        rng.uniform(-1, 1, DOF) * rng.choice([0.0, 0.01, 1.0]),
        rng.uniform(-5, 5, DOF) * rng.choice([0.0, 1.0]),
    )
    end_position = start.position + rng.uniform(-0.3, 0.3, DOF) * rng.choice([0.0, 1e-6, 1.0], size=DOF)
    end = State(end_position, rng.uniform(-1, 1, DOF) * rng.choice([0.0, 1.0]), np.zeros(DOF))
    duration = float(rng.choice([0.004, 0.05, 0.5, 2.0]))
    segment = connect(start, order, end, order, duration)
    return Entry(None, start.position, duration, start, duration, end=end, segment=segment)


@pytest.mark.parametrize("order", [2, 1, 0], ids=["quintic", "cubic", "linear"])
@pytest.mark.parametrize("scale", [1.0, 1e3], ids=["rad", "far"])
def test_overshoots_answers_as_the_exact_overshoot(order: int, scale: float, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(order * 10 + int(scale))
    exact_calls = 0
    exact = entries.overshoot

    def counted(entry: Entry) -> float:
        nonlocal exact_calls
        exact_calls += 1
        return exact(entry)

    monkeypatch.setattr(entries, "overshoot", counted)
    by_bounds = 0
    for _ in range(1500):
        entry = _entry(rng, order, scale)
        value = overshoot(entry)
        for tolerance in (value, value * (1 + 1e-12), value * (1 - 1e-12), value + 1e-9, 0.0, 1e-12):
            assert overshoots(entry, tolerance) == (value > tolerance), (tolerance, value)
        before = exact_calls
        assert overshoots(entry, OVERSHOOT) == (value > OVERSHOOT)
        by_bounds += exact_calls == before
    assert by_bounds > 150, "the planning's tolerance is often decided by the bounds alone"


def test_the_bounds_decide_a_segment_well_inside_the_tolerance(monkeypatch: pytest.MonkeyPatch) -> None:
    """A slow quintic to rest ahead of its start (what a trajectory's last point gets): no roots solved."""
    start = State(np.zeros(DOF), np.full(DOF, 0.01), np.zeros(DOF))
    end = State(np.full(DOF, 0.1), np.zeros(DOF), np.zeros(DOF))
    entry = Entry(None, start.position, 2.0, start, 2.0, end=end, segment=connect(start, 2, end, 2, 2.0))

    def refused(entry: Entry) -> float:
        raise AssertionError("the exact extremes were computed")

    monkeypatch.setattr(entries, "overshoot", refused)
    assert overshoots(entry, OVERSHOOT) is False
    assert entry.segment is not None and ("extremes", 0) not in entry.segment.memo


def test_a_negative_tolerance_is_always_exceeded() -> None:
    """overshoot is never below 0, so any segment exceeds a negative tolerance, even one whose bounds
    lie strictly between its entry's end positions (an entry whose positions are not its segment's)."""
    start = State(np.zeros(DOF), np.zeros(DOF), np.zeros(DOF))
    end = State(np.ones(DOF), np.zeros(DOF), np.zeros(DOF))
    inner = connect(
        State(np.full(DOF, 0.4), start.velocity, start.acceleration),
        0,
        State(np.full(DOF, 0.6), end.velocity, end.acceleration),
        0,
        1.0,
    )
    entry = Entry(None, start.position, 1.0, start, 1.0, end=end, segment=inner)
    assert overshoot(entry) == 0.0
    assert overshoots(entry, -0.1) is True and overshoots(entry, 0.0) is False
