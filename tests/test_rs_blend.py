"""The ``blend`` policy: passing through streamed points like a real controller, slowing down
instead of refusing, look-ahead decided by arrival times, a queue that runs dry.

Everything here runs the controller on its own clock (each test steps it), so arrival times are
controller times and every run is exactly repeatable; test_rs_streaming.py does the same over TCP.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_server.control import Controller, ControllerConfig, Point, Recorder, State, quintic_hermite
from robot_server.control.blend import OVERSHOOT, estimate, jerk_limited, shape_preserving, through_state
from robot_server.loader import load_model
from tests.streams import MONOTONE_JOINTS, Plan, full_points, measure, ros_points, stream

MODEL = load_model("jibot_zxs")
N = MODEL.dof
VMAX, AMAX, JMAX = MODEL.max_velocity, MODEL.max_acceleration, MODEL.max_jerk


def controller(**options: object) -> Controller:
    return Controller(MODEL, ControllerConfig(**options))  # type: ignore[arg-type]


def run_plan(plan: Plan, cadence: float = 0.0, **options: object) -> tuple[Controller, Recorder]:
    ctl = controller(**options)
    return ctl, stream(ctl, ros_points(plan, VMAX), cadence)


# -- the through-state --------------------------------------------------------------------------


def test_the_estimate_is_exact_for_a_parabola() -> None:
    h1, h2 = 0.02, 0.035
    t = np.array([-h1, 0.0, h2])
    p = 0.3 + 1.5 * t[:, None] * np.ones(N) - 2.0 * t[:, None] ** 2  # p(0) = 0.3, v = 1.5, a = -4
    v, a = estimate(p[0], h1, p[1], h2, p[2])
    assert np.allclose(v, 1.5) and np.allclose(a, -4.0)


def chain(positions: np.ndarray, durations: np.ndarray) -> list:
    """Quintic segments through ``positions`` (knots x joints) with blend's through-states, the
    last ending at rest, as the controller builds them."""
    state = State.rest(positions[0])
    segments = []
    for i in range(1, len(positions)):
        if i + 1 < len(positions):
            end = through_state(
                state,
                durations[i - 1],
                positions[i],
                after=positions[i + 1],
                after_duration=durations[i],
                before=positions[i - 1],
                before_duration=durations[i - 1],
            )
        else:
            end = State.rest(positions[i])
        segments.append(quintic_hermite(state, end, durations[i - 1]))
        state = end
    return segments


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=12),
    times=st.lists(st.floats(0.05, 2.0), min_size=12, max_size=12),
    sign=st.sampled_from([1.0, -1.0]),
)
def test_no_segment_overshoots_where_the_points_are_monotone(
    steps: list[float], times: list[float], sign: float
) -> None:
    """Any monotone sequence of points, any spacing: every segment stays between its two points
    (to within blend.OVERSHOOT, a tenth of a milliradian, where a clamp would only cost smoothness)."""
    positions = np.concatenate([[0.0], np.cumsum(steps)])[:, None] * sign * np.ones(2)
    durations = np.array(times[: len(positions) - 1])
    for k, segment in enumerate(chain(positions, durations)):
        lo, hi = segment.extremes(0)
        a, b = positions[k], positions[k + 1]
        tolerance = OVERSHOOT + 1e-9
        assert np.all(lo >= np.minimum(a, b) - tolerance) and np.all(hi <= np.maximum(a, b) + tolerance), k


def test_a_joint_that_holds_still_or_turns_back_is_reached_at_rest_unless_the_overshoot_is_negligible() -> None:
    start = State(np.array([0.0, 0.0]), np.array([0.5, 0.5]), np.zeros(2))
    position, after = np.array([0.1, 0.1]), np.array([0.1, 0.05])  # joint 1 holds, joint 2 turns back
    v, low, high = shape_preserving(
        start, 0.2, position, after=after, after_duration=0.2, velocity=np.array([0.3, 0.2])
    )
    assert v[0] == 0.0 and low[0] == high[0] == 0.0
    assert v[1] == 0.0 and low[1] < 0.0 and high[1] == 0.0  # decelerating into the turn
    # dense points of a smooth turn: the estimate stands (the curve turns between the samples)
    t = np.array([-0.01, 0.0, 0.01])
    q = 0.3 - 2.0 * (t - 0.002) ** 2  # the top at t = 2 ms, just after the middle sample
    state = through_state(
        State(np.array([q[0]]), np.array([-4.0 * (t[0] - 0.002)]), np.array([-4.0])),
        0.01,
        np.array([q[1]]),
        after=np.array([q[2]]),
        after_duration=0.01,
        before=np.array([q[0]]),
        before_duration=0.01,
    )
    assert state.velocity[0] == pytest.approx(0.008) and state.acceleration[0] == pytest.approx(-4.0)


def test_the_end_acceleration_keeps_the_jerk_within_the_limit_when_it_can() -> None:
    """From constant speed to the same speed over 10 ms, the jerk is 900 |a1| at most, so the
    estimate a1 = 3 is cut to 5/9 (to the sampling accuracy); an impossible case keeps it."""
    start = State(np.zeros(2), np.ones(2), np.zeros(2))
    duration, position, velocity = 0.01, np.full(2, 0.01), np.ones(2)
    low, high = np.array([-np.inf, 0.7]), np.array([np.inf, np.inf])  # the shape allows >= 0.7 for joint 2
    estimate_ = np.array([3.0, 3.0])
    chosen = jerk_limited(
        start, duration, position, velocity, acceleration=estimate_, low=low, high=high, jerk=np.full(2, 500.0)
    )
    assert chosen[0] == pytest.approx(5.0 / 9.0, rel=0.02) and chosen[1] == 3.0
    segment = quintic_hermite(start, (position, velocity, chosen), duration)
    lo, hi = segment.extremes(3)
    assert max(-lo[0], hi[0]) <= 500.0 * 1.02 and max(-lo[1], hi[1]) > 500.0


# -- streamed trajectories ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("duration", "cadence"),
    [(2.0, 0.0), (1.0, 0.0), (2.0, 0.005), (1.0, 0.005)],
    ids=["2s", "1s", "2s-ros-cadence", "1s-ros-cadence"],
)
def test_a_dense_trajectory_runs_as_planned(duration: float, cadence: float) -> None:
    """101 points of a MoveIt-like plan as industrial_robot_client fills them (10 s first point),
    at once or one per 5 ms (its streaming loop): every point accepted, no wait, the planned time,
    the planned path, no stop, and within the limits."""
    plan = Plan.make(duration, 101)
    ctl, record = run_plan(plan, cadence)
    m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
    assert m.start <= (0.010 if cadence == 0.0 else 0.020)
    assert abs(m.executed / duration - 1.0) <= 0.02
    assert m.stops == 0
    assert m.deviation_command <= 0.05e-3 and m.deviation_actual <= 0.3e-3
    assert m.peak_acceleration <= 1.5 * plan.peak_acceleration
    assert np.all(m.peak_jerk <= JMAX * (1 + 1e-6))
    assert m.final_error == 0.0 and not ctl.in_motion
    assert np.all(np.abs(record.get("command_velocity")) <= VMAX * (1 + 1e-9))


def test_sparse_waypoints_are_blended_without_overshoot() -> None:
    plan = Plan.make(4.0, 9)
    ctl, record = run_plan(plan)
    m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
    assert m.stops == 0 and m.deviation_command <= 1e-3 and abs(m.executed / 4.0 - 1.0) <= 0.02
    # joints whose waypoints are monotone never turn back
    command = record.get("command_position")[:, MONOTONE_JOINTS]
    steps = np.diff(command, axis=0) * np.sign(plan.position[-1] - plan.position[0])[MONOTONE_JOINTS]
    assert np.all(steps >= -1e-12)


def test_a_trajectory_too_fast_for_the_joints_is_slowed_down_not_refused(caplog: pytest.LogCaptureFixture) -> None:
    """Timed 1.8x faster than the acceleration limit allows: every point accepted, the rest of the
    trajectory slowed down uniformly (one WARNING saying by how much), within the limit."""
    plan = Plan.with_peak_acceleration(1.8 * float(AMAX.min()), 41)  # 0.42 s: a point every 10.5 ms
    with caplog.at_level(logging.WARNING, logger="robot_server.control.motion"):
        ctl, record = run_plan(plan)
    m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
    assert 1.0 < m.executed / plan.duration <= 1.6
    assert np.all(np.abs(record.get("command_acceleration")) <= AMAX * (1 + 1e-9))
    assert m.stops == 0 and m.deviation_command <= 0.05e-3 and m.final_error == 0.0
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "slowed down" in warnings[0] and "longer" in warnings[0], warnings
    assert ctl.queue.scale > 1.0


def test_full_points_follow_the_given_states() -> None:
    for duration in (2.0, 1.0):
        plan = Plan.make(duration, 101)
        ctl = controller()
        record = stream(ctl, full_points(plan), 0.0)
        m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
        assert abs(m.executed / duration - 1.0) <= 0.02 and m.deviation_command <= 0.05e-3
        # the robot starts at rest while the plan starts accelerating: the first segment catches up
        assert m.peak_acceleration <= 1.5 * plan.peak_acceleration


def test_a_point_arriving_while_its_predecessor_runs_is_passed_through() -> None:
    """The next point comes 10 ms into a 100 ms segment that was heading for rest: the rest of
    the segment is re-planned through the point; no stop, same arrival time."""
    ctl = controller()
    z = np.zeros(N)
    ctl.start(Point(z, duration=0.0))
    ctl.add(Point(np.full(N, 0.05), duration=0.1))
    ctl.run_for(0.02)  # waits 8 ms for the next point, then starts towards rest at point 1
    assert ctl.moving and np.all(np.array(ctl.command.command_velocity) > 0.0)
    ctl.add(Point(np.full(N, 0.15), duration=0.1))
    record = Recorder(N, capacity=400)
    ctl.run_for(0.4, record)
    speed = np.max(np.abs(record.get("command_velocity")), axis=1)
    assert np.all(speed[: np.flatnonzero(speed > 1e-4)[-1]] > 1e-4)  # moving all the way to the end
    assert np.allclose(ctl.command.command_position, 0.15, atol=1e-12)


def test_a_queue_that_runs_dry_decelerates_within_the_limits_and_goes_on(caplog: pytest.LogCaptureFixture) -> None:
    """The stream stops at point 40 of 101 for 0.5 s: the robot comes to rest there within its
    limits (one WARNING), then goes on from where it is when the points come again; never a jump."""
    plan = Plan.make(2.0, 101)
    points = ros_points(plan, VMAX)
    ctl = controller()
    record = Recorder(N, capacity=6000)
    with caplog.at_level(logging.WARNING, logger="robot_server.control.motion"):
        ctl.start(points[0])
        for p in points[1:41]:
            ctl.add(p)
        ctl.run_for(1.5, record)
        assert not ctl.moving
        for p in points[41:]:
            ctl.add(p)
        ctl.run_for(2.5, record)
    command = record.get("command_position")
    assert np.allclose(command[-1], plan.position[-1], atol=1e-12)
    instants = slice(3, None, 4)
    acceleration = record.get("command_acceleration")[instants]
    assert np.all(np.abs(acceleration) <= AMAX * (1 + 1e-9))
    assert np.all(np.abs(np.diff(acceleration, axis=0)) / 0.004 <= JMAX * (1 + 1e-6))
    assert np.all(np.abs(np.diff(command, axis=0)) <= VMAX * 0.001 * (1 + 1e-9))  # no jump
    # it stood still at point 40 (not beyond), then went on
    still = np.max(np.abs(record.get("command_velocity")), axis=1) < 1e-9
    first_stop = np.flatnonzero(still & (np.arange(len(still)) > 100))[0]
    assert np.allclose(command[first_stop], plan.position[40], atol=1e-9)
    assert np.flatnonzero(~still)[-1] > first_stop + 500
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "ran dry" in warnings[0], warnings


def scripted(cadence: float) -> Recorder:
    plan = Plan.make(1.0, 101)
    return stream(controller(), ros_points(plan, VMAX), cadence)


def test_the_same_arrivals_give_the_same_motion_bit_for_bit() -> None:
    for cadence in (0.0, 0.005):
        a, b = scripted(cadence), scripted(cadence)
        assert len(a) == len(b)
        for quantity in ("command_position", "command_acceleration", "actual_position", "following_error"):
            assert np.array_equal(a.get(quantity), b.get(quantity))
        assert np.array_equal(a.points(), b.points())


def test_the_paper_policies_stay_rest_to_rest() -> None:
    """linear, cubic and quintic still stop at every point (the paper's experiment)."""
    plan = Plan.make(6.0, 11)
    for policy in ("cubic", "quintic"):
        ctl = controller(policy=policy)
        record = stream(ctl, ros_points(plan, VMAX), 0.0)
        m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
        assert m.stops == plan.count - 2, policy
