"""Entry construction: from a received point to a queued knot, and from a knot and its neighbours
to the segment the robot runs (module doc of :mod:`.motion`: given, estimated and rest points,
transients from rest, the jerk limit met segment by segment, a queue that runs dry).

Functions of the queue's :class:`.entries.Context` and the entries concerned; nothing here keeps
state. The limit checks they rely on are in :mod:`.checks`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from ..arrays import Array
from . import blend
from .checks import (
    REFUSALS,
    check_duration,
    excess,
    follows,
    limit_of,
    state_need,
    swings,
    within_bounds,
    within_positions,
    within_symmetric,
)
from .entries import (
    MIN_REMAINDER,
    Context,
    Entry,
    Kind,
    Knot,
    Phase,
    Settings,
    TrajectoryBook,
    at_rest,
    connect,
    knot_of,
    log,
    moving,
    need,
    overshoot,
    overshoots,
)
from .points import MIN_DURATION, SLACK, Limits, Point, PointRejected, Reason, State, within
from .segments import PlanningError, RuckigSegment, Segment, hold, launch, linear, run_up

#: a jerk-limited replacement may take at most this factor times the segment's time plus MAX_LAG (s)
MAX_LAG_FACTOR = 1.5
MAX_LAG = 0.01
#: a point's state is slowed down at most this much to be reachable or to let the robot stop at
#: the last queued point (then: at rest)
_MAX_SLOWING = 1024.0


def knot(settings: Settings, point: Point, positions: Array, trajectory: TrajectoryBook) -> Knot | None:
    """The queued form of a point after the first (None: nothing to do)."""
    policy = settings.policy
    before = trajectory.last_position
    assert before is not None
    ratio = point.velocity_ratio if point.velocity_ratio is not None else 0.0
    number, index = trajectory.number, trajectory.points
    if point.time is not None:
        duration = point.time - trajectory.time
        if not duration >= MIN_DURATION:
            raise PointRejected(
                Reason.TIMING,
                f"time {point.time:g} s does not follow the previous point's time {trajectory.time:g} s "
                f"(by {MIN_DURATION:g} s at least)",
            )
        if duration > settings.max_duration:
            raise PointRejected(
                Reason.TIMING,
                f"{duration:g} s after the previous point is beyond the maximum segment time "
                f"({settings.max_duration:g} s)",
            )
        kind = Kind.GIVEN if point.velocities is not None else Kind.ESTIMATED if policy.passes_through else Kind.REST
        return Knot(
            positions,
            duration,
            kind,
            number,
            index,
            point.velocities,
            point.accelerations,
            ratio,
            time=point.time,
            linear=kind is Kind.REST,
        )
    duration_or_none = point.duration if point.duration else None
    if not policy.passes_through:
        return Knot(positions, duration_or_none, Kind.REST, number, index, ratio=ratio)
    if duration_or_none is None:
        delta = positions - before
        if not np.any(delta):
            return None
        computed = policy.segment_time(delta, ratio, settings.limits)
        assert computed is not None
        check_duration(settings, computed, "the time the velocity ratio gives this segment")
        duration_or_none = max(computed, MIN_DURATION)
    return Knot(positions, duration_or_none, Kind.ESTIMATED, number, index, ratio=ratio)


def through(limits: Limits, entry: Entry, duration: float, after: Array, after_duration: float) -> State:
    """The state at an estimated point for a segment from ``entry.start`` taking ``duration``,
    with the next point ``after`` (:func:`.blend.through_state`)."""
    return blend.through_state(
        entry.start,
        duration,
        knot_of(entry).position,
        after=after,
        after_duration=after_duration,
        before=entry.before,
        before_duration=entry.before_duration,
        jerk=limits.max_jerk,
        acceleration=None if entry.transient else limits.max_acceleration,  # a transient is met locally anyway
        lower=limits.lower,
        upper=limits.upper,
    )


def determine(settings: Settings, entry: Entry, after: Array, after_duration: float) -> Entry:
    """An estimated point's state, now that the next point is known, and the segment to it
    (within the jerk limit: :func:`stretched`). A transient from rest (a trajectory's first
    segment, a restart after the queue ran dry) starts as the client's plan does, with an
    acceleration (:func:`.segments.launch`); the quintic from rest would start as t^3 and
    trail a plan over a long first segment by a tenth of a second and more. When the plan
    is moving too fast at the point for the robot to get there from rest without first
    backing up to take a run-up, the point's state is slower (:func:`reachable`)."""
    end = through(settings.limits, entry, entry.duration, after, after_duration)
    if not (entry.transient and at_rest(entry.start)):
        return stretched(
            settings, entry.evolve(end=end, segment=connect(entry.start, entry.start_order, end, 2, entry.duration))
        )
    launched_entry = launched(settings, entry, end)
    if not overshoots(launched_entry, blend.OVERSHOOT):
        return launched_entry
    reachable_end = reachable(entry.start.position, end, settings.limits)
    if reachable_end is end:
        return launched_entry
    slower = launched(settings, entry, reachable_end).marked(Phase.SLOWED)
    return slower if overshoot(slower) < overshoot(launched_entry) else launched_entry


def launched(settings: Settings, entry: Entry, end: State) -> Entry:
    """The segment from rest to ``end`` starting as a plan does, with an acceleration."""
    segment = launch(entry.start.position, end, entry.duration, settings.limits.max_jerk)
    if segment is None:
        segment = connect(entry.start, entry.start_order, end, 2, entry.duration)
    return stretched(settings, entry.marked(Phase.SLOWED, False, end=end, segment=segment))


def given(entry: Entry, scale: float) -> Entry:
    """A given point's state at the trajectory's time scale, and the segment to it."""
    point = knot_of(entry)
    assert point.velocity is not None
    velocity = point.velocity / scale
    if not moving(point.velocity):
        # a point the robot reaches at rest (a trajectory's end: MoveIt's plans stop with the
        # deceleration still on) is reached at rest, not still accelerating
        end, order = State.rest(point.position), 2
    elif point.acceleration is not None:
        end, order = State(point.position, velocity, point.acceleration / (scale * scale)), 2
    else:
        end, order = State(point.position, velocity, np.zeros_like(velocity)), 1
    segment = connect(entry.start, entry.start_order, end, order, entry.duration)
    return entry.evolve(end=end, end_order=order, segment=segment)


def stretched(settings: Settings, entry: Entry) -> Entry:
    """``entry`` within the jerk limit: a segment beyond it is replaced by ruckig's time-optimal
    jerk-limited motion to the same end state, at least as long as planned. A client's plan
    whose acceleration steps (every time-optimal planner's does) cannot be blended within the
    jerk limit in one segment costs the robot a few milliseconds of lag there, as a real
    controller's command smoothing does, instead of slowing the whole trajectory down. A
    transient (a segment from rest where the plan has the robot moving) gets the same for its
    velocity and acceleration too, however long it takes: the plan is not too fast, the robot
    is late. So does a polynomial that would swing beyond its points by more than the robot
    needs to brake (a fast start over a long segment): ruckig's motion stays within that. A given
    segment under :attr:`.Settings.follow_given_acceleration` is run as given, as MotoROS runs its
    cubics (:func:`.checks.follows`)."""
    if follows(settings, entry):
        return entry
    over = excess(settings, entry)
    swinging = not entry.is_kind(Kind.GIVEN) and swings(settings, entry)
    if entry.transient or swinging:
        if max(over) <= 1.0 and not swinging:
            return entry
    elif entry.is_kind(Kind.GIVEN) or over[1] <= 1.0:
        return entry  # given states are followed as given (ros2_control, MotoROS)
    assert entry.end is not None
    try:
        segment = jerk_limited(settings.limits, entry.start, entry.end, entry.duration)
    except PlanningError as exc:  # an end state beyond the limits: keep the polynomial
        log.debug("point %d: no jerk-limited motion to its state (%s)", entry.index, exc)
        return entry
    if not (entry.transient or swinging) and segment.duration > MAX_LAG_FACTOR * entry.duration + MAX_LAG:
        # synchronising all joints on moving end states can take ruckig much longer than the
        # segment; a lag that long would distort the path more than the jerk matters
        log.debug("point %d: a jerk-limited segment would take %.3f s", entry.index, segment.duration)
        return entry
    if segment.duration > settings.max_duration:
        return entry
    replaced = entry.evolve(segment=segment, duration=segment.duration)
    if not within_positions(settings, replaced):
        # ruckig knows no position limits: its motion would leave them; the polynomial stays
        # (beyond the velocity or acceleration limit it slows the trajectory down)
        log.debug("point %d: a jerk-limited segment would leave the position limits", entry.index)
        return entry
    return replaced


def to_rest(settings: Settings, entry: Entry, messages: list[tuple[int, str]]) -> Entry:
    """An estimated point reached with no next point queued: it ends at rest, within the
    limits (time-optimally, with ruckig, if the planned segment cannot do it)."""
    point = knot_of(entry)
    end = State.rest(point.position)
    segment = connect(entry.start, entry.start_order, end, 2, entry.duration)
    candidate = entry.evolve(end=end, segment=segment)
    fits = max(excess(settings, candidate)) <= 1.0 and within_positions(settings, candidate)
    if not fits or swings(settings, candidate) or overshoots(candidate, blend.OVERSHOOT):
        try:
            segment = jerk_limited(settings.limits, entry.start, end, entry.duration)
        except PlanningError as exc:  # a start beyond the limits: the polynomial stands
            log.warning("point %d: no motion to rest there within the limits (%s)", point.index, exc)
        else:
            if fits and overshoot(candidate.evolve(segment=segment)) >= overshoot(candidate):
                # the robot cannot stop short of the point from where it is: of the two, the
                # motion that goes least beyond it
                return candidate.marked(Phase.DRY)
            messages.append(
                (
                    logging.INFO,
                    f"trajectory {point.trajectory}: coming to rest at point {point.index} takes "
                    f"{segment.duration:.3f} s within the limits ({entry.duration:.3f} s planned)",
                )
            )
    return entry.marked(Phase.DRY, end=end, segment=segment, duration=segment.duration)


def jerk_limited(limits: Limits, start: State, end: State, duration: float) -> RuckigSegment:
    """ruckig's time-optimal, jerk-limited motion from ``start`` to ``end`` taking ``duration`` at least."""
    return RuckigSegment.plan(
        start, end, limits.max_velocity, limits.max_acceleration, limits.max_jerk, minimum_duration=duration
    )


def replan_running(
    context: Context, running: Entry, started: float, after: Array, after_duration: float
) -> Entry | None:
    """The rest of a segment heading for rest at its point, re-planned to pass through it now
    that the next point is known (None: too late, or beyond the limits)."""
    settings = context.settings
    remaining = started + running.duration - context.at
    if remaining < MIN_REMAINDER:
        return None
    start = context.state
    # the point's state as if the segment had known the next point from its start (its
    # original start and time), then the rest of it from where the robot is now
    end = through(settings.limits, running, running.before_duration, after, after_duration)
    segment = connect(start, 2, end, 2, remaining)
    entry = running.marked(Phase.DRY, False, start=start, duration=remaining, end=end, segment=segment, start_order=2)
    entry = stretched(settings, entry)
    if excess(settings, entry)[0] > 1.0 or not within_positions(settings, entry):
        return None
    return entry


def rest_segment(settings: Settings, point: Knot, start: State) -> Segment | None:
    """A rest-to-rest policy's segment; refused beyond the limits."""
    lim = settings.limits
    if point.linear:
        segment: Segment | None = linear(start.position, point.position, need(point.duration))
        orders: tuple[int, ...] = (1,)
    else:
        segment = settings.policy.to_rest(start, point.position, point.duration, point.ratio, lim)
        orders = settings.policy.checked_orders
    if segment is None:
        return None
    check_duration(settings, segment.duration, "this segment")
    rows = lim.rows
    for order in (0, *orders):
        low, high = segment.bound_lists(order)  # cheap; the exact extremes only when the bounds do not settle it
        if order == 0:
            if within_bounds(low, high, rows.lower, rows.upper):
                continue
        elif within_symmetric(low, high, (rows.max_velocity, rows.max_acceleration, rows.max_jerk)[order - 1]):
            continue
        lower, upper = (lim.lower, lim.upper) if order == 0 else (-limit_of(lim, order), limit_of(lim, order))
        lo, hi = segment.extremes(order)
        reason, what = REFUSALS[order]
        within(lo, lower, upper, reason, what)
        within(hi, lower, upper, reason, what)
    return segment


def stop_entry(limits: Limits, state: State, at: Array | None = None) -> Entry:
    """The jerk-limited way to rest from ``state``: wherever it ends, or at ``at``."""
    rest = np.zeros_like(state.position)
    target = (state.position if at is None else at, rest, rest)
    try:
        segment: Segment = RuckigSegment.plan(
            state, target, limits.max_velocity, limits.max_acceleration, limits.max_jerk, velocity_interface=at is None
        )
    except PlanningError:  # pragma: no cover - ruckig plans a stop from any finite state
        log.exception("no jerk-limited stop from %s; holding", state)
        segment = hold(state.position, 1e-3)
    end = State.rest(segment.end().position)
    return Entry(None, state.position, segment.duration, state, segment.duration, end, segment)


def reachable(start: Array, state: State, limits: Limits) -> State:
    """``state``, or the same state slower (velocities / k, accelerations / k^2, for all joints
    alike) so that every joint can reach it from rest at ``start`` without first moving away from
    it: the shortest way to its speed and acceleration (:func:`.segments.run_up`) fits in the
    distance. A plan that is already moving fast at its first point (one that starts at speed, or
    a point far too soon for its distance) would otherwise have the robot back up to take a run-up."""
    distance = state.position - start
    direction = np.sign(distance)
    speed = state.velocity * direction
    room = np.abs(distance)
    concerned = (speed > 0.0) & (room > 0.0)
    if not np.any(concerned):
        return state
    zero = np.zeros_like(speed)

    def fits(k: float) -> bool:
        target = np.where(concerned, speed / k, 0.0)
        target_acc = np.where(concerned, state.acceleration * direction / (k * k), 0.0)
        needed = run_up(
            zero, zero, target, target_acc, limits=(limits.max_velocity, limits.max_acceleration, limits.max_jerk)
        )
        return bool(np.all(np.where(concerned, needed <= room * (1.0 + SLACK) + 1e-12, True)))

    if fits(1.0):
        return state
    k = least_slowing(fits, steps=24)
    # within the limits too: slowing the trajectory down would not change a state chosen here
    return slowed(state, None if k is None else max(k, state_need(state, limits) * (1.0 + SLACK)))


def least_slowing(fits: Callable[[float], bool], *, steps: int) -> float | None:
    """About the least factor k > 1 for which ``fits(k)`` (which must hold from some k on):
    doubling, then ``steps`` bisections; None beyond :data:`_MAX_SLOWING`."""
    low, high = 1.0, 2.0
    while not fits(high):
        if high >= _MAX_SLOWING:
            return None
        low, high = high, 2.0 * high
    for _ in range(steps):
        middle = 0.5 * (low + high)
        low, high = (low, middle) if fits(middle) else (middle, high)
    return high


def slowed(state: State, k: float | None) -> State:
    """``state`` as a trajectory k times slower passes it (None: at rest)."""
    if k is None:
        return State.rest(state.position)
    return State(state.position, state.velocity / k, state.acceleration / (k * k))
