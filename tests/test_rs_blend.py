"""The ``blend`` policy: passing through streamed points like a real controller, slowing down
instead of refusing, look-ahead decided by arrival times, a queue that runs dry.

Everything here runs the controller on its own clock (each test steps it), so arrival times are
controller times and every run is exactly repeatable; test_rs_streaming.py does the same over TCP.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from robot_server.control import (
    SOFT_LIMIT_ALARM,
    Controller,
    ControllerConfig,
    Point,
    PointRejected,
    Reason,
    Recorder,
    State,
    quintic_hermite,
    submit_together,
)
from robot_server.control.blend import (
    OVERSHOOT,
    _jerk_limited,
    estimate,
    jerk_limited,
    shape_preserving,
    through_state,
)
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


def test_the_jerk_never_pushes_the_end_acceleration_past_the_acceleration_limit() -> None:
    """Dense points after a start state a little off the data (a jerk-limited segment before it, a
    kink in a recording): keeping the quintic's jerk would need an end acceleration of 10.9 where
    the estimate is 9.5 and the limit 10; the chain of such choices grew past the limit where the
    data never came near it (a recording at full speed replayed x1.084 slower). The acceleration
    limit stands; the jerk is met locally (a jerk-limited segment) as decided for the jerk."""
    start = (0.0, 0.5, 5.0)
    free = _jerk_limited(start, 0.024, (0.014, 0.7), 9.5, (-1e9, 1e9), jerk=500.0)
    capped = _jerk_limited(start, 0.024, (0.014, 0.7), 9.5, (-1e9, 1e9), jerk=500.0, acceleration=10.0)
    assert free == pytest.approx(10.889, abs=1e-3) and capped == 10.0
    # an estimate beyond the limit is not cut by it here (the whole trajectory slows down for it)
    assert _jerk_limited(start, 0.024, (0.014, 0.7), 12.0, (-1e9, 1e9), jerk=500.0, acceleration=10.0) <= 12.0
    # the cap applies on both sides
    mirrored = _jerk_limited((0.0, -0.5, -5.0), 0.024, (-0.014, -0.7), -9.5, (-1e9, 1e9), jerk=500.0, acceleration=10.0)
    assert mirrored == -10.0


def test_after_a_kink_the_through_state_keeps_the_segment_within_the_acceleration_limit() -> None:
    """A wrist joint breaking away from rest in a recording (the motor model's friction): 1.4 mrad in
    20 ms from nearly at rest. The three-point estimate's quintic peaks at 11 rad/s^2 between the
    points, though the points ask for far less; a slightly faster velocity at the point (the data's
    own speed rises faster than the estimate) keeps it within the 10 rad/s^2 limit, and the
    trajectory need not slow down for it. Without a limit given, the estimate stands."""
    start = State(np.array([0.0]), np.array([0.0038]), np.array([0.7536]))

    def through(acceleration: np.ndarray | None) -> State:
        return through_state(
            start,
            0.02,
            np.array([0.0014]),
            after=np.array([0.0063]),
            after_duration=0.0348,
            before=np.array([0.0]),
            before_duration=0.02,
            jerk=np.array([500.0]),
            acceleration=acceleration,
        )

    plain, kept = through(None), through(np.array([10.0]))
    peak = [max(-lo[0], hi[0]) for lo, hi in (quintic_hermite(start, s, 0.02).extremes(2) for s in (plain, kept))]
    assert peak[0] > 11.0 and peak[1] <= 10.0
    assert plain.velocity[0] == pytest.approx(0.0958, abs=1e-4) and 0.1 < kept.velocity[0] < 0.13


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


def test_a_long_first_segment_starts_as_the_plan_does() -> None:
    """``goal.py``'s sparse goal (4 points, 1.5 s apart): its plan accelerates from the first
    instant, so it moves 5 mrad in 0.25 s. The robot starts with an acceleration too (ramped at the
    jerk limit), not as the t^3 of a quintic from rest (0.30 s), and moves no later than the plan;
    the monotone joints never turn back and the jerk stays within the limit."""
    plan = Plan.make(4.5, 4)
    ctl, record = run_plan(plan)
    t, command = record.time(), record.get("command_position")
    arrived = t[np.flatnonzero(record.points() >= 1)[0]]
    moved = t[np.flatnonzero(np.max(np.abs(command - plan.start), axis=1) > 5e-3)[0]] - arrived
    fine = np.linspace(0.0, 1.0, 100_001)
    planned = fine[np.flatnonzero(np.max(np.abs(plan.dense(1e-5)[: fine.size] - plan.start), axis=1) > 5e-3)[0]]
    assert 0.24 < planned < 0.26
    assert moved <= planned + 0.005
    m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
    assert m.stops == 0 and m.final_error == 0.0 and abs(m.executed / 4.5 - 1.0) <= 0.02
    assert np.all(m.peak_jerk <= JMAX * (1 + 1e-6))
    steps = (
        np.diff(command[:, MONOTONE_JOINTS], axis=0) * np.sign(plan.position[-1] - plan.position[0])[MONOTONE_JOINTS]
    )
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
    """cubic and quintic still stop at every point (the paper's experiment; linear keeps its
    constant speed between points, its velocity stepping at each)."""
    plan = Plan.make(6.0, 11)
    for policy in ("cubic", "quintic"):
        ctl = controller(policy=policy)
        record = stream(ctl, ros_points(plan, VMAX), 0.0)
        m = measure(record, MODEL, plan, ctl.servo_ticks_per_interpolation)
        assert m.stops == plan.count - 2, policy


# -- robustness ------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(3, 25),
    spacing=st.sampled_from([0.005, 0.01, 0.02, 0.1, 0.5]),
    span=st.sampled_from([0.001, 0.05, 0.3, 1.5]),
    full=st.booleans(),
)
# found by hypothesis: point 1's through-state, slowed down, was at 0.99 of the velocity limit with
# the acceleration still speeding the joint up; braking that acceleration within the jerk limit
# took the robot to 1.007x the limit on its way to rest
@example(seed=4_294_967_295, count=3, spacing=0.005, span=1.5, full=False)
def test_any_stream_within_the_limits_moves_within_them(
    seed: int, count: int, spacing: float, span: float, full: bool
) -> None:
    """Random points inside the limits (a margin from them), random steps, streamed whole: every
    point accepted or refused with a reason, no alarm, and the command stays within every position,
    velocity and acceleration limit and ends on the last point."""
    rng = np.random.default_rng(seed)
    lower, upper = MODEL.lower + 0.3, MODEL.upper - 0.3
    ctl = controller()
    q = np.zeros(N)
    points = [Point(q.copy(), duration=0.0)]
    for i in range(1, count):
        q = np.clip(q + rng.uniform(-span, span, N), lower, upper)
        if full:
            points.append(Point(q.copy(), rng.uniform(-0.5, 0.5, N) * VMAX, time=i * spacing))
        else:
            points.append(Point(q.copy(), duration=spacing * rng.uniform(0.5, 1.5), velocity_ratio=0.5))
    record = stream(ctl, points, 0.0)
    assert not ctl.in_error, ctl.error_message
    command = record.get("command_position")
    assert np.all(command >= MODEL.lower - 1e-9) and np.all(command <= MODEL.upper + 1e-9)
    assert np.all(np.abs(record.get("command_velocity")) <= VMAX * (1 + 1e-6))
    assert np.all(np.abs(record.get("command_acceleration")) <= AMAX * (1 + 1e-6))
    if not full:  # (a given velocity at the last point makes the robot stop past it)
        assert np.allclose(command[-1], points[-1].positions, atol=1e-9)


def test_a_point_arriving_during_a_dry_stop_goes_on_from_where_the_robot_is() -> None:
    ctl = controller()
    z = np.zeros(N)
    ctl.start(Point(z, z, z, time=0.0))
    ctl.add(Point(np.full(N, 0.3), np.full(N, 0.8), time=0.5))  # ends moving: nothing follows
    record = Recorder(N, capacity=3000)
    ctl.run_for(0.52, record)  # the dry stop has begun
    moving = np.array(ctl.command.command_velocity)
    assert np.all(moving > 0.0) and ctl.moving
    ctl.add(Point(np.full(N, 0.6), np.full(N, 0.0), time=1.0))
    ctl.run_for(2.0, record)
    command = record.get("command_position")
    assert np.allclose(command[-1], 0.6, atol=1e-9)
    assert np.all(np.abs(np.diff(command, axis=0)) <= VMAX * 0.001 * (1 + 1e-9))  # no jump
    assert np.all(np.abs(record.get("command_acceleration")) <= AMAX * (1 + 1e-6))


def test_motion_groups_moving_together_share_one_time_scale() -> None:
    a, b = controller(), controller()
    z = np.zeros(N)
    submit_together([(a, Point(z, time=0.0)), (b, Point(z, time=0.0))], first=True)
    for i in range(1, 21):
        t = 0.02 * i
        fast = z + 0.8 * (t / 0.4) ** 2  # group a: 10 rad/s^2 over the limit
        slow = z + 0.05 * (t / 0.4)
        submit_together([(a, Point(fast, time=t)), (b, Point(slow, time=t))])
    assert a.queue.scale > 1.0 and a.queue.scale == pytest.approx(b.queue.scale, rel=1e-9)
    assert sum(s.duration for s in a.queue.segments()) > 0.4


def test_a_point_too_fast_to_stop_before_a_limit_slows_the_trajectory_down(caplog: pytest.LogCaptureFixture) -> None:
    """A given velocity towards a limit (0.9 of the maximum, 50 mrad before it) and then
    nothing: from that state no motion could stop before the limit. The trajectory is slowed
    down until the robot can (one WARNING), and it comes to rest within the limit, no alarm."""
    start = MODEL.upper.copy() - 0.2
    ctl = controller(initial_position=tuple(start))
    z = np.zeros(N)
    ctl.start(Point(start, z, z, time=0.0))
    near = start + 0.15
    with caplog.at_level(logging.WARNING, logger="robot_server.control.motion"):
        ctl.add(Point(near, VMAX * 0.9, time=0.1))
    assert ctl.queue.scale > 1.0
    assert [r for r in caplog.records if "slowed down" in r.getMessage()]
    record = Recorder(N, capacity=4000)
    ctl.run_for(3.0, record)
    assert not ctl.in_error and not ctl.in_motion
    assert np.all(record.get("command_position") <= MODEL.upper + 1e-9)


def test_points_inside_the_limits_never_end_in_a_soft_limit_alarm() -> None:
    """Three JOINT_TRAJ_PT points, the last 1 mrad inside joint 3's lower limit, timed too fast
    (slowed down x2.2): the through-state before the last point used to head for the limit too
    fast to stop (alarm 4203, the motion lost 76 mrad short). Now it is slowed down until the robot
    can brake before the limit, and the motion ends on the last point."""
    path = [
        np.zeros(N),
        np.array([0.224219, -0.245542, -0.298931, 0.177506, 0.166034, -0.052874]),
        np.array([0.354316, -0.314817, -0.352285, 0.225573, 0.383918, -0.093463]),
    ]
    shift = np.zeros(N)
    shift[2] = MODEL.lower[2] + 0.001 - path[2][2]
    path = [p + shift for p in path]
    ctl = controller(initial_position=tuple(path[0]))
    points = [Point(p, duration=d, velocity_ratio=0.5) for p, d in zip(path, [10.0, 0.0731, 0.0583], strict=True)]
    record = stream(ctl, points, 0.0)
    assert not ctl.in_error, ctl.error_message
    command = record.get("command_position")
    assert np.all(command >= MODEL.lower - 1e-9) and np.all(command <= MODEL.upper + 1e-9)
    assert np.allclose(command[-1], path[-1], atol=1e-12)


def test_a_command_beyond_a_position_limit_is_an_alarm_not_a_motion(monkeypatch: pytest.MonkeyPatch) -> None:
    """The supervisor behind the planner: a setpoint beyond a joint's limit (a planning defect)
    raises the soft-limit alarm instead of being commanded, and the motion stops there."""
    ctl = controller()
    ctl.start(Point(np.zeros(N), duration=0.0))
    ctl.add(Point(np.full(N, 0.1), duration=0.5))
    ctl.run_for(0.1)
    beyond = State(MODEL.upper + 0.01, np.zeros(N), np.zeros(N))
    monkeypatch.setattr(ctl.queue, "sample", lambda t: beyond)
    record = Recorder(N, capacity=1000)
    ctl.run_for(0.2, record)
    assert ctl.in_error and ctl.error_code == SOFT_LIMIT_ALARM + 1 and "soft limit" in ctl.error_message
    assert np.all(record.get("command_position") <= MODEL.upper + 1e-9)


def test_a_download_is_slowed_down_once_and_dropped_whole_when_a_point_cannot_be_planned(
    caplog: pytest.LogCaptureFixture,
) -> None:
    plan = Plan.with_peak_acceleration(1.8 * float(AMAX.min()), 41)
    points = ros_points(plan, VMAX)
    ctl = controller()
    with caplog.at_level(logging.WARNING, logger="robot_server.control.motion"):
        ctl.start_download(points[0])
        for p in points[1:-1]:
            ctl.add(p)
        ctl.finish_download(points[-1])
    assert 1.34 < ctl.queue.scale < 1.4
    assert len([r for r in caplog.records if "slowed down" in r.getMessage()]) == 1
    # a download whose slowing down would need segments beyond the maximum time: none of it runs
    # (each 10.5 ms segment may take at most 12 ms; the first point is where the robot is)
    other = controller(max_segment_time=0.012)
    other.start_download(replace(points[0], duration=0.0))
    for p in points[1:-1]:
        other.add(p)
    with pytest.raises(PointRejected) as err:
        other.finish_download(points[-1])
    assert err.value.reason is Reason.TIMING and not other.moving and other.queue_fill == 0


def test_a_plan_is_good_only_until_the_controller_steps() -> None:
    ctl = controller()
    ctl.start(Point(np.zeros(N), duration=0.0))
    plan = ctl.prepare(Point(np.full(N, 0.1), duration=0.5), first=False)
    ctl.step()
    ctl.step()
    ctl.step()
    ctl.step()  # an interpolation instant: the queue was sampled
    with pytest.raises(RuntimeError, match="plan the point again"):
        ctl.commit(plan)


def random_monotone_stream(seed: int) -> tuple[list[Point], float, np.ndarray]:
    """A few to thirty points, each joint moving one way (or holding) by random steps at random
    times: far too fast for the joints, far too slow, or anything between; the client's cadence
    in controller time; each joint's direction."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(3, 30))
    spacing = float(rng.choice([0.004, 0.005, 0.01, 0.02, 0.1, 0.5, 1.0]))
    span = float(rng.choice([0.0005, 0.005, 0.05, 0.3]))
    still = float(rng.choice([0.0, 0.2, 0.5]))
    cadence = float(rng.choice([0.0, 0.0, 0.005, 0.012]))
    q = np.zeros(N)
    sign = np.where(rng.uniform(size=N) < 0.5, -1.0, 1.0)
    points = [Point(q.copy(), duration=10.0)]
    for _ in range(1, count):
        q = np.clip(
            q + sign * rng.uniform(0, span, N) * (rng.uniform(size=N) > still), MODEL.lower + 0.01, MODEL.upper - 0.01
        )
        points.append(Point(q.copy(), duration=spacing * rng.uniform(0.3, 1.7), velocity_ratio=0.5))
    return points, cadence, sign


# streams where the robot used to back up before a run-up it had no room for (45: 7.3 mrad),
# swing past its last point (160: 4.2 mrad, 212: 1.5 mrad) or step back by 0.1 mrad and more;
# streams whose next point was long overdue when the robot set off to the one before the last
# (57, 129, 207, 295: 2.0, 0.15, 20 and 6.3 mrad past it); a burst with a joint holding still two
# points ahead (157: 1.5 mrad past the point it holds at)
@pytest.mark.parametrize("seed", [34, 45, 57, 103, 129, 157, 160, 168, 207, 212, 291, 295])
def test_monotone_points_are_followed_without_backing_up_even_when_far_too_fast(seed: int) -> None:
    points, cadence, sign = random_monotone_stream(seed)
    record = stream(controller(interpolation_period=0.004), points, cadence)
    command = record.get("command_position")
    steps = np.diff(command, axis=0) * sign
    assert float(np.max(-steps)) <= OVERSHOOT
    assert float(np.max((command - points[-1].positions) * sign)) <= OVERSHOOT
    assert np.array_equal(command[-1], points[-1].positions)
    assert np.all(np.abs(record.get("command_acceleration")) <= AMAX * (1 + 1e-6))


# a smooth curve whose turns fall between two samples: each sample nearest a turn used to force the
# through-velocity to its largest monotone value, whose acceleration was 2.5x the curve's, and the
# plan was slowed down by 1.43-1.45x
@pytest.mark.parametrize(("frequency", "phase"), [(1.0, 0.3), (1.5, 0.0), (1.5, 0.3)])
def test_a_curve_turning_between_samples_within_the_limits_is_not_slowed_down(frequency: float, phase: float) -> None:
    spacing, omega = 0.02, 2.0 * np.pi * frequency
    amplitude = 0.8 * float(AMAX.min()) / omega**2  # 80 % of the acceleration limit
    t = np.arange(0.0, 1.0 + 1e-9, spacing)
    q = amplitude * np.outer(1.0 - np.cos(omega * (t + phase * spacing)), np.ones(N))
    ctl = controller(interpolation_period=0.004)
    points = [Point(q[0], duration=10.0)] + [Point(q[i], duration=spacing) for i in range(1, len(t))]
    record = stream(ctl, points, 0.0)
    assert ctl.queue.scale == 1.0
    assert np.all(np.abs(record.get("command_acceleration")) <= AMAX * (1 + 1e-6))
    assert np.array_equal(record.get("command_position")[-1], q[-1])


def test_a_stream_that_starts_with_three_points_at_once_runs_as_planned() -> None:
    """Three points queued at once, then one per 5 ms: the first segment sets off slowed down to
    be able to stop at point 2 (perhaps the last); the points that follow in time cost nothing."""
    plan = Plan.make(1.0, 101)
    points = ros_points(plan, VMAX)
    ctl = controller()
    recorder = Recorder(ctl.dof, capacity=round(5.0 / ctl.config.servo_period))
    ctl.start(points[0])
    ctl.add(points[1])
    ctl.add(points[2])
    sent, next_time = 3, 0.006
    while ctl.time < 3.0 and (sent < len(points) or ctl.in_motion):
        if sent < len(points) and ctl.time >= next_time - 1e-12:
            ctl.add(points[sent])
            sent, next_time = sent + 1, ctl.time + 0.005
        recorder.add(ctl.step())
    assert sent == len(points) and not ctl.in_motion
    for _ in range(500):  # the drives settle
        recorder.add(ctl.step())
    m = measure(recorder, MODEL, plan, ctl.servo_ticks_per_interpolation)
    assert abs(m.executed / plan.duration - 1.0) <= 0.02 and m.stops == 0
    assert m.deviation_command <= 0.05e-3 and m.final_error == 0.0


def test_a_point_slowed_for_a_last_point_gets_its_own_state_back_when_the_next_one_comes() -> None:
    """The over-fast plan with its first two points in one servo tick and one per tick after (as
    over loopback): the first segment sets off slowed down to be able to stop at point 2, the only
    one after it so far; point 3 comes 1 ms later and the rest of the segment is planned again to
    point 1's own state. Left slowed, the robot needed 90 ms to catch up with the plan and took
    1.665x the planned time with a stop."""
    plan = Plan.with_peak_acceleration(1.8 * float(AMAX.min()), 41)
    points = ros_points(plan, VMAX)
    ctl = controller()
    recorder = Recorder(ctl.dof, capacity=round(5.0 / ctl.config.servo_period))
    ctl.start(points[0])
    ctl.add(points[1])
    for point in points[2:]:
        ctl.add(point)
        recorder.add(ctl.step())
    while ctl.in_motion and ctl.time < 3.0:
        recorder.add(ctl.step())
    for _ in range(300):  # the drives settle
        recorder.add(ctl.step())
    m = measure(recorder, MODEL, plan, ctl.servo_ticks_per_interpolation)
    assert m.executed / plan.duration <= 1.6 and m.stops == 0 and m.final_error == 0.0
    assert np.all(np.abs(recorder.get("command_acceleration")) <= AMAX * (1 + 1e-9))
