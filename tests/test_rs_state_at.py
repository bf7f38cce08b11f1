"""A segment's state at one time (``state_at``: what the controller samples every interpolation
period, on plain floats) is ``sample``'s at that time, bit for bit, for every kind of segment:
quintics and cubics (Horner's scheme unrolled joint by joint) and ruckig's (the phase found by
bisection), at random times, at the ends, before and after the segment, and on phase boundaries."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_server.control import RuckigSegment
from robot_server.control.segments import Segment, cubic_hermite, quintic_hermite

REAL = st.floats(-3.0, 3.0, allow_nan=False)
DOF = 6


def _same(segment: Segment, t: float) -> None:
    fast = segment.state_at(t)
    slow = segment.sample(t)
    for name, a, b in zip(("position", "velocity", "acceleration"), fast, slow[:3], strict=True):
        assert a.dtype == np.float64 and a.shape == (segment.dof,)
        assert a.tobytes() == np.asarray(b).tobytes(), f"{name} at t={t!r}: {a!r} != {b!r}"


def _times(segment: Segment, fractions: list[float]) -> list[float]:
    d = segment.duration
    return [-1.0, 0.0, d, d + 1.0, *(f * d for f in fractions)]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.lists(REAL, min_size=DOF, max_size=DOF), min_size=6, max_size=6),
    st.floats(0.004, 5.0),
    st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8),
)
def test_a_polynomials_state_at_one_time_is_its_sample(
    rows: list[list[float]], duration: float, fr: list[float]
) -> None:
    quintic = quintic_hermite((rows[0], rows[1], rows[2]), (rows[3], rows[4], rows[5]), duration)
    cubic = cubic_hermite(rows[0], rows[1], rows[3], rows[4], duration)
    for segment in (quintic, cubic):
        for t in _times(segment, fr):
            _same(segment, t)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=DOF, max_size=DOF),
    st.lists(st.floats(-1.0, 1.0), min_size=DOF, max_size=DOF),
    st.lists(st.floats(-0.5, 0.5), min_size=DOF, max_size=DOF),
    st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8),
)
def test_a_ruckig_segments_state_at_one_time_is_its_sample(
    start: list[float], target: list[float], velocity: list[float], fr: list[float]
) -> None:
    zero = [0.0] * DOF
    segment = RuckigSegment.plan((start, velocity, zero), (target, zero, zero), [2.0] * DOF, [8.0] * DOF, [80.0] * DOF)
    times = _times(segment, fr)
    times += segment._starts.ravel().tolist()  # every phase boundary of every joint
    for t in times:
        _same(segment, t)
