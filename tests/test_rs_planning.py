"""The motion queue's planning functions, one at a time (robot_server/control: entries, checks,
building, scaling, braking, planning): each is a function of a snapshot, a point and the queue's
context, so each is tested here directly, without a queue or a controller. The queue as a whole
is tested in test_rs_blend.py and test_rs_controller.py."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from robot_server.control import braking, building, checks, planning, scaling
from robot_server.control.entries import (
    Context,
    Entry,
    Kind,
    Knot,
    Phase,
    Plan,
    Settings,
    TrajectoryBook,
    at_rest,
    connect,
)
from robot_server.control.points import Limits, Point, PointRejected, Reason, State
from robot_server.control.policies import policy
from robot_server.control.segments import linear

#: two joints: ±3 rad, 1 rad/s, 2 rad/s², 20 rad/s³
LIMITS = Limits(
    np.array([-3.0, -3.0]), np.array([3.0, 3.0]), np.array([1.0, 1.0]), np.array([2.0, 2.0]), np.array([20.0, 20.0])
)
ZERO = np.zeros(2)


def settings(name: str = "blend", **kwargs: float) -> Settings:
    return Settings(LIMITS, policy(name), **kwargs)  # type: ignore[arg-type]


def context(s: Settings | None = None, at: float = 0.0, state: State | None = None) -> Context:
    return Context(s if s is not None else settings(), at, state if state is not None else State.rest(ZERO))


def knot(position: list[float], duration: float | None = 1.0, kind: Kind = Kind.ESTIMATED, index: int = 1) -> Knot:
    return Knot(np.array(position), duration, kind, 1, index)


def entry_to(end: list[float], duration: float, *, start: State | None = None, kind: Kind = Kind.ESTIMATED) -> Entry:
    """A decided entry from rest at the origin (or ``start``) to rest at ``end``, linear."""
    begin = start if start is not None else State.rest(ZERO)
    goal = State.rest(np.array(end))
    return Entry(
        knot(end, duration, kind),
        begin.position,
        duration,
        begin,
        duration,
        goal,
        linear(begin.position, goal.position, duration),
    )


# -- entries ---------------------------------------------------------------------------------------


def test_an_entry_s_phase_flags_set_and_clear_independently() -> None:
    e = entry_to([0.1, 0.0], 1.0)
    assert e.phase is Phase.PLANNED and not (e.transient or e.slowed or e.dry)
    both = e.marked(Phase.TRANSIENT).marked(Phase.DRY)
    assert both.transient and both.dry and not both.slowed
    cleared = both.marked(Phase.DRY, False, duration=2.0)
    assert cleared.transient and not cleared.dry and cleared.duration == 2.0
    assert e.phase is Phase.PLANNED  # frozen: marking makes a new entry


def test_connect_uses_the_derivatives_both_states_carry() -> None:
    a, b = State(ZERO, np.array([0.5, 0.0]), np.array([1.0, 0.0])), State.rest(np.array([1.0, 0.0]))
    assert connect(a, 2, b, 2, 1.0).bounded_order >= 3  # quintic: continuous acceleration
    cubic = connect(a, 2, b, 1, 1.0)
    assert cubic.sample(np.array([0.0])).velocity[0, 0] == pytest.approx(0.5)
    line = connect(a, 2, b, 0, 1.0)
    assert line.sample(np.array([0.5])).position[0, 0] == pytest.approx(0.5)


# -- checks ------------------------------------------------------------------------------------------


def test_excess_is_the_time_factor_the_velocity_needs_and_is_kept_per_settings() -> None:
    s = settings()
    fast = entry_to([2.0, 0.0], 1.0)  # 2 rad in 1 s linear: 2 rad/s for a 1 rad/s limit
    assert checks.excess(s, fast) == pytest.approx((2.0, 1.0))
    assert fast.segment is not None and s in fast.segment.memo  # a second settings object asks again
    assert checks.excess(s, entry_to([0.5, 0.0], 1.0)) == (1.0, 1.0)


def test_state_need_counts_speed_acceleration_and_braking_room() -> None:
    assert checks.state_need(State.rest(ZERO), LIMITS) == 1.0
    assert checks.state_need(State(ZERO, np.array([2.0, 0.0]), ZERO), LIMITS) == pytest.approx(2.0)
    assert checks.state_need(State(ZERO, ZERO, np.array([0.0, 8.0])), LIMITS) == pytest.approx(2.0)
    # 1 rad/s at 2 rad/s² needs 0.25 rad and more to stop: 0.01 rad before the limit is not enough
    near = State(np.array([2.99, 0.0]), np.array([0.9, 0.0]), ZERO)
    assert checks.state_need(near, LIMITS) > 2.0


def test_a_segment_leaving_the_position_limits_is_refused_with_the_reason() -> None:
    s = settings()
    out = entry_to([3.5, 0.0], 10.0)
    assert not checks.within_positions(s, out)
    with pytest.raises(PointRejected) as info:
        checks.check_position(s, out)
    assert info.value.reason is Reason.POSITION_LIMIT


def test_uniform_need_of_a_transient_is_its_end_state_first() -> None:
    s = settings()
    # a transient whose segment is too fast but whose end state is within: its own excess counts
    fast = entry_to([2.0, 0.0], 1.0).marked(Phase.TRANSIENT)
    assert checks.uniform_need(s, fast) == pytest.approx(2.0)
    # an end state beyond the limits: the end state's need, whatever the segment
    end = State(np.array([0.5, 0.0]), np.array([3.0, 0.0]), ZERO)
    moving_end = Entry(
        knot([0.5, 0.0]), ZERO, 1.0, State.rest(ZERO), 1.0, end, connect(State.rest(ZERO), 2, end, 2, 1.0)
    ).marked(Phase.TRANSIENT)
    assert checks.uniform_need(s, moving_end) == pytest.approx(3.0)


# -- building ------------------------------------------------------------------------------------------


def test_a_point_becomes_a_knot_of_its_kind() -> None:
    book = TrajectoryBook(number=1, open=True, points=1, time=0.0, last_position=ZERO)
    full = building.knot(settings(), Point(np.array([0.1, 0.0]), velocities=ZERO, time=0.5), np.array([0.1, 0.0]), book)
    assert full is not None and full.kind is Kind.GIVEN and full.duration == 0.5 and full.index == 1
    estimated = building.knot(settings(), Point(np.array([0.1, 0.0]), duration=0.2), np.array([0.1, 0.0]), book)
    assert estimated is not None and estimated.kind is Kind.ESTIMATED
    rest = building.knot(settings("quintic"), Point(np.array([0.1, 0.0]), duration=0.2), np.array([0.1, 0.0]), book)
    assert rest is not None and rest.kind is Kind.REST
    # no motion and no time: nothing to do
    assert building.knot(settings(), Point(ZERO, velocity_ratio=0.5), ZERO, book) is None


def test_a_time_that_does_not_follow_the_previous_one_is_refused() -> None:
    book = TrajectoryBook(number=1, open=True, points=2, time=1.0, last_position=ZERO)
    with pytest.raises(PointRejected) as info:
        building.knot(settings(), Point(ZERO, time=1.0), ZERO, book)
    assert info.value.reason is Reason.TIMING and "does not follow" in str(info.value)


def test_a_given_point_is_followed_at_the_trajectory_s_time_scale() -> None:
    given = Knot(np.array([0.5, 0.0]), 1.0, Kind.GIVEN, 1, 1, np.array([0.4, 0.0]), np.array([0.8, 0.0]))
    start = State.rest(ZERO)
    e = building.given(Entry(given, ZERO, 2.0, start, 2.0), scale=2.0)
    assert e.end is not None and e.end_order == 2
    assert e.end.velocity[0] == pytest.approx(0.2) and e.end.acceleration[0] == pytest.approx(0.2)
    at_rest_knot = Knot(np.array([0.5, 0.0]), 1.0, Kind.GIVEN, 1, 1, ZERO, np.array([0.8, 0.0]))
    e = building.given(Entry(at_rest_knot, ZERO, 1.0, start, 1.0), scale=1.0)
    assert e.end is not None and at_rest(e.end)  # a trajectory's end is reached at rest, not accelerating


def test_a_segment_beyond_the_jerk_limit_is_stretched_within_it() -> None:
    s = settings()
    # from rest to 0.02 rad at rest in 0.3 s: a quintic's jerk of 60 x 0.02 / 0.3^3 = 44 > 20, its
    # acceleration 5.77 x 0.02 / 0.3^2 = 1.3 < 2
    goal = State.rest(np.array([0.02, 0.0]))
    e = Entry(
        knot([0.02, 0.0], 0.3), ZERO, 0.3, State.rest(ZERO), 0.3, goal, connect(State.rest(ZERO), 2, goal, 2, 0.3)
    )
    assert checks.excess(s, e)[0] == 1.0 and checks.excess(s, e)[1] > 1.0
    out = building.stretched(s, e)
    assert out.segment is not e.segment and checks.excess(s, out)[1] == 1.0
    assert 0.3 <= out.duration <= 1.5 * 0.3 + 0.01 and np.allclose(out.segment.end().position, goal.position)  # type: ignore[union-attr]


def test_a_point_with_no_successor_ends_at_rest_and_says_when_it_takes_longer() -> None:
    s = settings()
    moving = State(ZERO, np.array([0.9, 0.0]), ZERO)
    e = Entry(knot([0.05, 0.0], 0.05), ZERO, 0.05, moving, 0.05)
    messages: list[tuple[int, str]] = []
    out = building.to_rest(s, e, messages)
    assert out.dry and out.end is not None and at_rest(out.end)
    assert out.duration > 0.05 and messages and messages[0][0] == logging.INFO
    assert "coming to rest at point 1" in messages[0][1]


def test_a_state_the_robot_cannot_reach_from_rest_going_forward_is_slowed() -> None:
    fast = State(np.array([0.01, 0.0]), np.array([0.9, 0.0]), ZERO)  # 0.9 rad/s only 0.01 rad away
    slower = building.reachable(ZERO, fast, LIMITS)
    assert slower is not fast and 0.0 < slower.velocity[0] < 0.9
    easy = State(np.array([1.0, 0.0]), np.array([0.5, 0.0]), ZERO)
    assert building.reachable(ZERO, easy, LIMITS) is easy


def test_least_slowing_finds_the_threshold_and_gives_up_past_the_maximum() -> None:
    k = building.least_slowing(lambda f: f >= 3.3, steps=20)
    assert k is not None and 3.3 <= k < 3.3 * 1.001
    assert building.least_slowing(lambda f: False, steps=4) is None
    assert at_rest(building.slowed(State(ZERO, np.ones(2), np.ones(2)), None))


def test_a_stop_entry_brings_the_robot_to_rest_within_the_limits() -> None:
    stop = building.stop_entry(LIMITS, State(ZERO, np.array([0.8, -0.5]), ZERO))
    assert stop.knot is None and stop.end is not None and at_rest(stop.end)
    assert max(checks.excess(settings(), stop)) == 1.0


# -- scaling ---------------------------------------------------------------------------------------------


def test_a_trajectory_too_fast_is_slowed_down_uniformly_and_warned_once() -> None:
    ctx = context()
    book = TrajectoryBook(number=1, open=True, points=2, last_position=np.array([2.0, 0.0]))
    # a given point at rest 2 rad away in 1 s: about twice too fast for 1 rad/s and 2 rad/s²
    reached = Entry(Knot(np.array([2.0, 0.0]), 1.0, Kind.GIVEN, 1, 1, ZERO), ZERO, 1.0, State.rest(ZERO), 1.0)
    pending = [building.given(reached, 1.0)]
    slowed = scaling.rescale(
        ctx, Plan(None, 0.0, tuple(pending), book), needed=checks.uniform_need(ctx.settings, pending[0]), knot=None
    )
    running, out, book, messages = slowed.running, list(slowed.pending), slowed.trajectory, list(slowed.messages)
    assert running is None and book.scale >= 1.875 and book.warned_scale
    assert max(checks.excess(ctx.settings, out[0])) == 1.0
    assert [level for level, _ in messages] == [logging.WARNING]
    assert "the trajectory is too fast" in messages[0][1]
    again = scaling.rescale(ctx, Plan(None, 0.0, tuple(out), book), needed=1.5, knot=None)
    assert [level for level, _ in again.messages] == [logging.INFO]  # further slowing: once per 10 %


# -- braking ---------------------------------------------------------------------------------------------


def test_points_keep_coming_at_their_pace_or_not() -> None:
    book = TrajectoryBook(number=1, open=True, points=3, opened=0.0)
    last = Entry(knot([0.2, 0.0], 0.1, index=2), ZERO, 0.1, State.rest(ZERO), 0.1, queued=0.02)
    running = entry_to([0.1, 0.0], 0.1)
    assert braking.coming(book, running, last, at=0.0)  # one every 10 ms: the next by 0.03 s
    assert not braking.coming(book, running, last, at=0.5)  # overdue by more than the pace
    assert not braking.coming(TrajectoryBook(number=1, open=False), running, last, at=0.0)


def test_a_point_is_passed_slower_when_the_robot_must_stop_at_the_next_close_one() -> None:
    s = settings()
    fast = State(np.array([0.5, 0.0]), np.array([0.9, 0.0]), ZERO)
    entry = Entry(
        knot([0.5, 0.0], 1.0), ZERO, 1.0, State.rest(ZERO), 1.0, fast, connect(State.rest(ZERO), 2, fast, 2, 1.0)
    )
    last = Entry(knot([0.52, 0.0], 0.02, index=2), np.array([0.5, 0.0]), 0.02, fast, 0.02)
    out = braking.braking(s, entry, last, np.ones(2, dtype=bool))
    assert out is not entry and out.unbraked is fast
    assert out.end is not None and out.end.velocity[0] < 0.9
    # a far last point: nothing to brake for
    far = Entry(knot([2.5, 0.0], 3.0, index=2), np.array([0.5, 0.0]), 3.0, fast, 3.0)
    assert braking.braking(s, entry, far, np.ones(2, dtype=bool)) is entry


# -- planning --------------------------------------------------------------------------------------------


def empty() -> Plan:
    return Plan(None, 0.0, (), TrajectoryBook())


def test_a_first_point_away_from_the_robot_is_refused_and_the_snapshot_untouched() -> None:
    snapshot = empty()
    with pytest.raises(PointRejected) as info:
        planning.plan(context(), snapshot, Point(np.array([0.5, 0.0])), first=True, bounded=True, defer=False)
    assert info.value.reason is Reason.START_MISMATCH and info.value.joint == 0
    assert snapshot.trajectory.number == 0 and not snapshot.pending and snapshot.running is None


def test_planning_a_point_returns_a_new_snapshot_and_changes_nothing() -> None:
    ctx = context()
    start = planning.plan(ctx, empty(), Point(ZERO), first=True, bounded=True, defer=False)
    assert start.trajectory.number == 1 and start.trajectory.open and not start.pending
    second = planning.plan(
        ctx, start, Point(np.array([0.2, 0.0]), duration=0.5), first=False, bounded=True, defer=False
    )
    assert planning.fill(second) == 1 and planning.fill(start) == 0
    assert second.pending[0].transient  # the first segment of a trajectory from rest
    end = planning.planned_end(second, ctx.state)
    assert at_rest(end) and end.position[0] == pytest.approx(0.2)


def test_a_full_queue_refuses_a_point_when_bounded() -> None:
    ctx = context(settings(capacity=1))
    start = planning.plan(ctx, empty(), Point(ZERO), first=True, bounded=True, defer=False)
    one = planning.plan(ctx, start, Point(np.array([0.1, 0.0]), duration=0.5), first=False, bounded=True, defer=False)
    later = Point(np.array([0.2, 0.0]), duration=0.5)
    with pytest.raises(PointRejected) as info:
        planning.plan(ctx, one, later, first=False, bounded=True, defer=False)
    assert info.value.reason is Reason.QUEUE_FULL
    assert planning.fill(planning.plan(ctx, one, later, first=False, bounded=False, defer=False)) == 2


def test_a_deferred_plan_says_how_much_slower_instead_of_slowing_down() -> None:
    ctx = context()
    start = planning.plan(ctx, empty(), Point(ZERO), first=True, bounded=True, defer=False)
    # a given state accelerating at 8 rad/s² for a 2 rad/s² limit: the trajectory must take twice the time
    fast = Point(np.array([0.5, 0.0]), velocities=np.array([0.5, 0.0]), accelerations=np.array([8.0, 0.0]), time=1.0)
    deferred = planning.plan(ctx, start, fast, first=False, bounded=True, defer=True)
    assert deferred.needed == pytest.approx(2.0) and deferred.scale == 1.0 and not deferred.messages
    slowed = planning.plan(ctx, start, fast, first=False, bounded=True, defer=False)
    assert slowed.needed == 1.0 and slowed.scale >= 2.0
    assert any(level == logging.WARNING for level, _ in slowed.messages)


def test_a_point_after_the_robot_stopped_dry_is_a_transient_and_warned() -> None:
    ctx = context()
    book = TrajectoryBook(number=1, open=True, points=2, last_position=np.array([0.1, 0.0]))
    base = Plan(None, 0.0, (), book, stopped_dry=(1, 1))
    after = planning.plan(ctx, base, Point(np.array([0.2, 0.0]), duration=0.5), first=False, bounded=True, defer=False)
    assert after.pending[-1].transient and after.trajectory.warned_dry
    assert any("came after the robot stopped" in text for _, text in after.messages)


def test_motoros_runs_a_given_cubic_beyond_the_acceleration_limit_and_says_so() -> None:
    """MotoROS checks the points' speeds only and runs the cubic between them as it is
    (MotionServer.c:1313, 1414-1505): with ``follow_given_acceleration`` the trajectory is not slowed
    down for a given segment's acceleration, and a WARNING says where and by how much (then INFO
    when a later one asks 10 % more); its velocity still counts. Without it (the generic
    controller) the trajectory is slowed down."""
    follow = Settings(LIMITS, policy("blend"), follow_given_acceleration=True)
    moving = State(np.array([0.1, 0.0]), np.array([0.5, 0.0]), ZERO)
    book = TrajectoryBook(number=1, open=True, points=2, time=1.0, last_position=moving.position)
    running = Entry(
        knot([0.1, 0.0]), ZERO, 1.0, State.rest(ZERO), 1.0, moving, connect(State.rest(ZERO), 1, moving, 1, 1.0)
    )
    base = Plan(running, 0.0, (), book)
    # from 0.5 rad/s to -0.5 rad/s in 0.25 s, back where it started: the cubic's acceleration is
    # (-4 v0 - 2 v1) / h = -4 rad/s² at the start, twice the 2 rad/s² limit
    sharp = Point(np.array([0.1, 0.0]), velocities=np.array([-0.5, 0.0]), time=1.25)
    generic = planning.plan_scaled(
        context(Settings(LIMITS, policy("blend"))),
        base,
        sharp,
        first=False,
        min_scale=1.0,
        bounded=True,
    )
    assert generic.scale > 1.0 and any("too fast" in text for _, text in generic.messages)
    planned = planning.plan_scaled(context(follow), base, sharp, first=False, min_scale=1.0, bounded=True)
    assert planned.scale == 1.0 and checks.acceleration_ratio(follow, planned.pending[-1]) == (pytest.approx(2.0), 0)
    assert [level for level, _ in planned.messages] == [logging.WARNING]
    assert "the segment to point 2 accelerates joint 1 at 2 x its limit: run as given" in planned.messages[0][1]
    assert planned.trajectory.reported_acceleration == pytest.approx(2.0)
    # a later segment asking less says nothing; one asking 10 % more says so at INFO
    gentle = Point(np.array([0.0, 0.0]), velocities=np.array([-0.5, 0.0]), time=1.45)
    again = planning.plan_scaled(context(follow), planned, gentle, first=False, min_scale=1.0, bounded=True)
    assert not again.messages
    sharper = Point(np.array([0.0, 0.0]), velocities=np.array([0.5, 0.0]), time=1.65)
    more = planning.plan_scaled(context(follow), again, sharper, first=False, min_scale=1.0, bounded=True)
    assert [level for level, _ in more.messages] == [logging.INFO] and "the most so far" in more.messages[0][1]
    # a segment beyond the velocity limit between its points is slowed down even when followed: 1.5 rad
    # in 1 s between two points at 0.5 rad/s peaks at about 2 rad/s for 1; slowed down for its speed,
    # its acceleration is within the limit too, and nothing is said of it
    fast = Point(np.array([1.6, 0.0]), velocities=np.array([0.5, 0.0]), time=2.0)
    far = planning.plan_scaled(context(follow), base, fast, first=False, min_scale=1.0, bounded=True)
    assert far.scale > 1.5 and checks.speed_excess(follow, far.pending[-1]) <= 1.0
    assert [text for _, text in far.messages if "run as given" in text] == []
    assert any("too fast" in text for _, text in far.messages)


def test_a_transient_after_the_queue_ran_dry_is_met_locally_even_on_motoros() -> None:
    """Only segments that start where the client's points lead (or at the trajectory's start) are
    run as given: a restart from rest mid-trajectory is no state MotoROS would be in."""
    follow = Settings(LIMITS, policy("blend"), follow_given_acceleration=True)
    given = Knot(np.array([0.05, 0.0]), 0.05, Kind.GIVEN, 1, 5, np.array([0.9, 0.0]))
    restart = building.given(Entry(given, ZERO, 0.05, State.rest(ZERO), 0.05).marked(Phase.TRANSIENT), 1.0)
    assert not checks.follows(follow, restart)
    assert building.stretched(follow, restart).segment is not restart.segment  # ruckig's, within the limits
    first = building.given(
        Entry(replace_index(given, 1), ZERO, 0.05, State.rest(ZERO), 0.05).marked(Phase.TRANSIENT), 1.0
    )
    assert checks.follows(follow, first) and building.stretched(follow, first) is first


def replace_index(point: Knot, index: int) -> Knot:
    return Knot(point.position, point.duration, point.kind, point.trajectory, index, point.velocity)


@pytest.mark.parametrize("follow", [False, True])
def test_a_download_whose_points_are_within_the_limits_is_checked_between_them_too(follow: bool) -> None:
    """A downloaded trajectory is slowed down once, at its end, for what its points' states ask;
    points within the limits do not make the segments between them so: a cubic that passes the
    speed limit between two points slows the download down too (on MotoROS as well)."""
    from robot_server.control.motion import MotionQueue

    queue = MotionQueue(LIMITS, policy("blend"), State.rest(ZERO), follow_given_acceleration=follow)
    points = [
        Point(ZERO.copy(), velocities=ZERO.copy(), time=0.0),
        Point(np.array([0.1, 0.0]), velocities=np.array([0.5, 0.0]), time=1.0),
        Point(np.array([1.6, 0.0]), velocities=np.array([0.5, 0.0]), time=2.0),  # peaks at about 2 rad/s (limit 1)
        Point(np.array([1.7, 0.0]), velocities=ZERO.copy(), time=3.0),
    ]
    queue.add_all(points)
    assert queue.scale > 1.5
    assert all(checks.speed_excess(queue.settings, e) <= 1.0 for e in queue._pending if e.segment is not None)


def test_an_estimated_point_passes_through_with_its_neighbours_velocity() -> None:
    """Three points on a line, 0.1 rad and 0.5 s apart: the middle one is passed at the line's
    speed (0.2 rad/s), and the segment ends there in that state."""
    s = settings()
    entry = Entry(knot([0.1, 0.0], 0.5), ZERO, 0.5, State(ZERO, np.array([0.2, 0.0]), ZERO), 0.5)
    out = building.determine(s, entry, np.array([0.2, 0.0]), 0.5)
    assert out.end is not None and out.segment is not None
    assert out.end.velocity[0] == pytest.approx(0.2, rel=1e-6) and out.end.velocity[1] == 0.0
    assert np.allclose(out.segment.end().position, [0.1, 0.0])


def test_a_transient_from_rest_passes_its_point_moving_within_the_limits() -> None:
    """A trajectory's first segment from rest ends at its point moving on towards the next one (no
    stop at the first point) and, a transient, is met locally within the limits."""
    s = settings()
    first = Entry(knot([0.02, 0.0], 0.2), ZERO, 0.2, State.rest(ZERO), 0.2).marked(Phase.TRANSIENT)
    out = building.determine(s, first, np.array([0.06, 0.0]), 0.2)
    assert out.transient and out.end is not None and out.end.velocity[0] > 0.05
    assert max(checks.excess(s, out)) <= 1.0
    assert out.segment is not None and np.allclose(out.segment.end().position, [0.02, 0.0])


def test_swings_flags_a_segment_that_wanders_far_beyond_its_points() -> None:
    s = settings()
    start = State(ZERO, np.array([0.9, 0.0]), ZERO)
    goal = State.rest(np.array([0.01, 0.0]))
    long = Entry(knot([0.01, 0.0], 3.0), ZERO, 3.0, start, 3.0, goal, connect(start, 2, goal, 2, 3.0))
    short = Entry(knot([0.01, 0.0], 0.02), ZERO, 0.02, start, 0.02, goal, connect(start, 2, goal, 2, 0.02))
    assert checks.swings(s, long) and not checks.swings(s, short)


def test_start_next_runs_an_undecided_last_point_to_rest() -> None:
    """The robot sets off to a point whose state is still undecided (no next point): it ends at
    rest there, and the pending entries after it are returned."""
    s = settings()
    undecided = Entry(knot([0.1, 0.0], 1.0), ZERO, 1.0, State.rest(ZERO), 1.0)
    running, pending = braking.start_next(s, (undecided,), TrajectoryBook(number=1, open=True), at=0.0)
    assert pending == () and running.dry and running.end is not None and at_rest(running.end)


def test_rebuilt_keeps_a_dry_point_at_rest_and_leaves_a_last_estimated_one_undecided() -> None:
    s = settings()
    start = State.rest(ZERO)
    dry = Entry(knot([0.1, 0.0], 1.0), ZERO, 2.0, start, 2.0).marked(Phase.DRY)
    again = scaling.rebuilt(s, dry, None, 2.0)
    assert again.end is not None and at_rest(again.end) and again.segment is not None
    open_end = Entry(knot([0.1, 0.0], 1.0), ZERO, 2.0, start, 2.0, again.end, again.segment)
    undecided = scaling.rebuilt(s, open_end, None, 2.0)
    assert undecided.end is None and undecided.segment is None
