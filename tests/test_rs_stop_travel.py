"""A joint's fastest stop on floats (``stop_travel_floats``: what the look-ahead braking check runs at
every segment start, joint by joint) is ``stop_travel``'s, bit for bit, or is left to it (None):
random states and limits of every sign and scale, states at rest, joints braking harder than the
closed form starts with (ruckig's), values that are not finite."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_server.control.segments import stop_travel, stop_travel_floats

DOF = 6
#: velocities and accelerations across the scales a controller meets (and exact zeros)
VALUE = st.one_of(
    st.just(0.0),
    st.floats(-5.0, 5.0, allow_nan=False),
    st.floats(-1e-6, 1e-6, allow_nan=False),
    st.floats(-200.0, 200.0, allow_nan=False),
)
LIMIT = st.floats(1e-3, 1e4, allow_nan=False)


def _same(velocity: list[float], acceleration: list[float], max_a: list[float], jerk: list[float]) -> None:
    floats = stop_travel_floats(velocity, acceleration, max_a, jerk)
    arrays = stop_travel(
        np.array(velocity), np.array(acceleration), limits=(np.full(DOF, 3.0), np.array(max_a), np.array(jerk))
    )
    if floats is None:  # left to stop_travel: a joint ruckig plans, or a value not finite
        return
    assert np.array(floats).tobytes() == arrays.tobytes(), f"{floats} != {arrays.tolist()}"


@settings(max_examples=400, deadline=None)
@given(
    st.lists(VALUE, min_size=DOF, max_size=DOF),
    st.lists(VALUE, min_size=DOF, max_size=DOF),
    st.lists(LIMIT, min_size=DOF, max_size=DOF),
    st.lists(LIMIT, min_size=DOF, max_size=DOF),
)
def test_the_fastest_stop_on_floats_is_stop_travels(
    velocity: list[float], acceleration: list[float], max_a: list[float], jerk: list[float]
) -> None:
    _same(velocity, acceleration, max_a, jerk)


def test_the_states_a_streaming_controller_meets_are_all_on_floats() -> None:
    """Random states within a robot's limits (the floats' path, not the fallback), many of them."""
    rng = np.random.default_rng(38)
    max_v, max_a, jerk = np.full(DOF, 2.0), np.full(DOF, 8.0), np.full(DOF, 80.0)
    on_floats = 0
    for _ in range(3000):
        v = rng.uniform(-1.0, 1.0, DOF) * max_v
        a = rng.uniform(-1.0, 1.0, DOF) * max_a * rng.choice([0.0, 0.1, 1.0])
        floats = stop_travel_floats(v.tolist(), a.tolist(), max_a.tolist(), jerk.tolist())
        arrays = stop_travel(v, a, limits=(max_v, max_a, jerk))
        if floats is not None:
            on_floats += 1
            assert np.array(floats).tobytes() == arrays.tobytes()
    assert on_floats > 1000, "the usual states go the floats' way"


def test_at_rest_and_the_cases_left_to_stop_travel() -> None:
    zero = [0.0] * DOF
    limits = [8.0] * DOF, [80.0] * DOF
    assert stop_travel_floats(zero, zero, *limits) == [0.0] * DOF
    # braking harder than the closed form's profile starts with: ruckig's
    assert stop_travel_floats([0.5, *zero[1:]], [-50.0, *zero[1:]], *limits) is None
    for bad in (math.inf, math.nan):
        assert stop_travel_floats([bad, *zero[1:]], zero, *limits) is None
        assert stop_travel_floats(zero, zero, [bad] * DOF, [80.0] * DOF) is None


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_joint_at_speed_stops_as_far_as_the_closed_form_says(sign: float) -> None:
    # at 1 rad/s with 8 rad/s^2 and 80 rad/s^3: 0.1 s up to the peak braking, 0.025 s at it... the
    # numbers are stop_travel's; checked here against it and for their sign
    travel = stop_travel_floats([sign] + [0.0] * 5, [0.0] * DOF, [8.0] * DOF, [80.0] * DOF)
    assert travel is not None
    assert travel[0] * sign > 0.0 and travel[1:] == [0.0] * 5
    _same([sign] + [0.0] * 5, [0.0] * DOF, [8.0] * DOF, [80.0] * DOF)


def test_the_braking_checks_answer_on_floats_is_the_arrays() -> None:
    """braking's check (do the stopping joints' fastest stops end beyond the next point?) on floats
    and on arrays, for random states, slowing factors and points ahead: the same answer."""
    from robot_server.control.braking import stop_overshoots_array, stop_overshoots_floats
    from robot_server.control.points import State

    rng = np.random.default_rng(7)
    max_v, max_a, jerk = np.full(DOF, 2.0), np.full(DOF, 8.0), np.full(DOF, 80.0)
    answers = {True: 0, False: 0}
    for _ in range(2000):
        end = State(rng.uniform(-1, 1, DOF), rng.uniform(-2, 2, DOF), rng.uniform(-8, 8, DOF) * rng.choice([0.0, 0.2]))
        ahead = rng.uniform(-0.3, 0.3, DOF)
        stops = rng.random(DOF) < 0.6
        f = float(rng.choice([1.0, 1.5, 3.0, 17.0]))
        on_floats = stop_overshoots_floats(
            (end.velocity.tolist(), end.acceleration.tolist()),
            (max_a.tolist(), jerk.tolist()),
            ahead.tolist(),
            stops.tolist(),
            f,
        )
        on_arrays = stop_overshoots_array(end, (max_v, max_a, jerk), ahead, stops, f)
        if on_floats is not None:
            assert on_floats == on_arrays
            answers[on_floats] += 1
    assert answers[True] > 100 and answers[False] > 100, answers
