"""Planning one received point: the queue's snapshot and a point in, a new snapshot out.

:func:`plan` is what :meth:`.MotionQueue.plan` runs: a first point starts a trajectory
(:func:`plan_start`: the start check, MotoROS's rule); a later one becomes a knot
(:func:`.building.knot`) and :func:`plan_knot` adds it in three steps: the point before it learns
its successor (:func:`_pass_previous`), the new point's segment is built (:func:`_segment_to`),
and the trajectory is slowed down if it must be (:func:`_fit`). Nothing here changes the queue;
:meth:`.MotionQueue.commit` applies the result.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from ..arrays import Array
from .braking import unbraked
from .building import determine, given, knot, replan_running, rest_segment, stretched, to_rest
from .checks import acceleration_ratio, check_duration, check_position, end_need, follows, orders, uniform_need
from .entries import (
    Context,
    Entry,
    Kind,
    Knot,
    Phase,
    Plan,
    Settings,
    TrajectoryBook,
    at_rest,
    knot_of,
    moving,
    need,
)
from .points import SLACK, Point, PointRejected, Reason, State, check_point
from .scaling import RESCALE_MARGIN, rescale

#: with the start check off, a first point farther than this (rad or m) is a move to it
_SAME_PLACE = 1e-9


def fill(snapshot: Plan) -> int:
    """Points queued and not yet reached (the running one included)."""
    running = 1 if snapshot.running is not None and snapshot.running.knot is not None else 0
    return running + len(snapshot.pending)


def planned_end(snapshot: Plan, state: State) -> State:
    """Where everything queued ends, the open trajectory's last point at rest (``state``, the
    current setpoint, if nothing is queued)."""
    if snapshot.pending:
        last = snapshot.pending[-1]
        return last.end if last.end is not None else State.rest(knot_of(last).position)
    if snapshot.running is not None and snapshot.running.end is not None:
        return snapshot.running.end
    return state


def plan(
    context: Context,
    snapshot: Plan,
    point: Point,
    *,
    first: bool,
    bounded: bool,
    defer: bool,
) -> Plan:
    """The queue ``snapshot`` with ``point`` added (``first``: it starts a trajectory; ``bounded``:
    refuse it when the queue is full; ``defer``: leave the slowing down to the caller, saying in
    :attr:`.Plan.needed` how much it takes). Raises :class:`PointRejected`."""
    settings = context.settings
    positions = check_point(point, settings.limits, settings.max_duration)
    trajectory = snapshot.trajectory
    if first or not trajectory.open:
        return plan_start(context, snapshot, point, positions)
    if bounded and fill(snapshot) >= settings.capacity:
        raise PointRejected(Reason.QUEUE_FULL, f"the point queue is full ({settings.capacity} points)")
    base = Plan(
        snapshot.running,
        snapshot.started,
        snapshot.pending,
        trajectory,
        at=context.at,
        stopped_dry=snapshot.stopped_dry,
    )
    return plan_point(context, point, positions, base, defer=defer)


def plan_scaled(
    context: Context,
    snapshot: Plan,
    point: Point,
    *,
    first: bool,
    min_scale: float,
    bounded: bool,
) -> Plan:
    """:func:`plan`, slowed down to at least the time scale ``min_scale``."""
    planned = plan(context, snapshot, point, first=first, bounded=bounded, defer=False)
    if min_scale > planned.trajectory.scale * (1.0 + SLACK):
        planned = rescale(context, planned, needed=min_scale / (planned.trajectory.scale * RESCALE_MARGIN), knot=None)
    return report_acceleration(context.settings, planned)


def check_start(settings: Settings, positions: Array, origin: State) -> None:
    """Refuse a trajectory's first point farther than the start tolerance from ``origin``
    (as MotoROS does: module doc of :mod:`.motion`)."""
    if settings.start_tolerance is None:
        return
    gap = np.abs(positions - origin.position)
    worst = int(np.argmax(gap))
    if gap[worst] > settings.start_tolerance:
        raise PointRejected(
            Reason.START_MISMATCH,
            f"the first point is {gap[worst]:.6g} from the current position of joint {worst + 1} "
            f"(tolerance {settings.start_tolerance:g})",
            worst,
        )


def plan_start(context: Context, snapshot: Plan, point: Point, positions: Array) -> Plan:
    """A new trajectory, starting where everything queued ends."""
    settings = context.settings
    pending = list(snapshot.pending)
    messages: list[tuple[int, str]] = []
    if pending and pending[-1].end is None:  # the previous trajectory's last point ends at rest
        pending[-1] = to_rest(settings, pending[-1], messages)
    origin = planned_end(snapshot, context.state) if not pending else pending[-1].end
    assert origin is not None
    check_start(settings, positions, origin)
    away = settings.start_tolerance is None and bool(np.any(np.abs(positions - origin.position) > _SAME_PLACE))
    trajectory = TrajectoryBook(
        number=snapshot.trajectory.number + 1,
        open=True,
        points=0 if away else 1,
        time=point.time if point.time is not None and not away else 0.0,
        last_position=origin.position,
        opened=context.at,
    )
    opened = Plan(
        snapshot.running,
        snapshot.started,
        tuple(pending),
        trajectory,
        tuple(messages),
        context.at,
        stopped_dry=snapshot.stopped_dry,
    )
    if away:  # no start check: the robot goes to the first point from where it is
        if point.time is not None and point.time <= 0.0:
            raise PointRejected(
                Reason.TIMING, "the first point is away from the robot and its time is 0: no time to get there"
            )
        return plan_point(context, point, positions, opened, defer=False)
    return opened


def plan_point(
    context: Context,
    point: Point,
    positions: Array,
    base: Plan,
    *,
    defer: bool,
) -> Plan:
    """A point after a trajectory's first added to ``base``."""
    queued = knot(context.settings, point, positions, base.trajectory)
    if queued is None:  # already there and no time to spend: nothing to do
        return replace(base, trajectory=replace(base.trajectory, points=base.trajectory.points + 1))
    return plan_knot(context, queued, base, defer=defer)


@dataclass(frozen=True, slots=True)
class _Passed:
    """The snapshot after the point before the new one has learnt it (:func:`_pass_previous`)."""

    draft: Plan
    #: segments decided now: checked against the limits at the end
    built: tuple[Entry, ...]
    #: the new point's segment starts from a state the client's plan did not lead to
    transient: bool


def plan_knot(context: Context, point: Knot, base: Plan, *, defer: bool) -> Plan:
    """``point`` queued after ``base``: the point before passes through it, its own segment
    follows, and the trajectory slows down rather than refuse it."""
    passed = _pass_previous(context, point, base)
    draft, built = passed.draft, list(passed.built)
    trajectory = draft.trajectory
    entry = _segment_to(context, point, draft, passed.transient)
    if entry is None:  # a rest-to-rest policy with nothing to do
        return Plan(
            draft.running,
            draft.started,
            draft.pending,
            trajectory.evolve(points=trajectory.points + 1),
            draft.messages,
            context.at,
        )
    if entry.is_kind(Kind.GIVEN):
        built.append(entry)
    trajectory = trajectory.evolve(
        points=trajectory.points + 1,
        last_position=point.position,
        time=point.time if point.time is not None else trajectory.time,
    )
    draft = Plan(
        draft.running,
        draft.started,
        (*draft.pending, entry),
        trajectory,
        draft.messages,
        draft.at,
        draft.needed,
        draft.stopped_dry,
    )
    return _fit(context, point, draft, built, defer=defer)


def _pass_previous(context: Context, point: Knot, base: Plan) -> _Passed:
    """Step 1: the point before ``point`` passes through it, now that it is known; or the robot,
    come to rest (or on its way to rest) for want of this point, goes on from where it is."""
    settings = context.settings
    trajectory = base.trajectory
    scale = trajectory.scale
    pending = list(base.pending)
    running, started = base.running, base.started
    messages = list(base.messages)
    built: list[Entry] = []
    # set when the robot stands where the client's plan has it moving (the first segment of a
    # trajectory from rest: the plan may start accelerating at once; or after the queue ran
    # dry): this point's segment starts from a state the plan did not lead to (a transient)
    transient = False
    if pending and pending[-1].end is None:
        if len(pending) == 1 and running is not None and running.unbraked is not None:
            # the point it slowed down for is not the last after all: back to the points' state
            restored = unbraked(context, running, started)
            if restored is not None:
                assert restored.end is not None
                running, started = restored, context.at
                pending[-1] = pending[-1].marked(Phase.TRANSIENT, running.slowed, start=restored.end, start_order=2)
        pending[-1] = determine(settings, pending[-1], point.position, need(point.duration) * scale)
        built.append(pending[-1])
    elif running is not None and running.dry and running.trajectory == point.trajectory and not pending:
        late = replan_running(context, running, started, point.position, need(point.duration) * scale)
        if late is not None:
            running, started = late, context.at
            built.append(running)
        else:
            transient = True
            if moving(running.start.velocity):
                messages.append(
                    dry_message(trajectory, f"point {point.index} came too late to pass through point {running.index}")
                )
                trajectory = trajectory.evolve(warned_dry=True)
    elif running is not None and running.knot is None and not pending:
        running, started = None, context.at  # a dry stop is under way: go on from the current setpoint
        transient = True
    elif running is None and not pending and base.stopped_dry == (point.trajectory, point.index - 1):
        transient = True
        messages.append(dry_message(trajectory, f"point {point.index} came after the robot stopped"))
        trajectory = trajectory.evolve(warned_dry=True)
    draft = Plan(running, started, tuple(pending), trajectory, tuple(messages), context.at)
    return _Passed(draft, tuple(built), transient)


def _segment_to(context: Context, point: Knot, draft: Plan, transient: bool) -> Entry | None:
    """Step 2: ``point``'s segment, from where the one before ends (None: a rest-to-rest policy
    has nothing to do)."""
    settings = context.settings
    running, pending, trajectory = draft.running, draft.pending, draft.trajectory
    if pending:
        start, order = pending[-1].end, pending[-1].end_order
    elif running is not None:
        start, order = running.end, running.end_order
    else:
        start, order = context.state, 2
    assert start is not None and trajectory.last_position is not None
    before = pending[-1] if pending else running
    if (point.index == 1 and at_rest(start)) or (before is not None and before.slowed):
        transient = True
    if point.kind is Kind.REST:
        segment = rest_segment(settings, point, start)
        if segment is None:
            return None
        return Entry(
            point,
            trajectory.last_position,
            segment.duration,
            start,
            segment.duration,
            State.rest(point.position),
            segment,
            start_order=order,
            end_order=0 if point.linear else 2,  # a linear segment's end carries its position only
        )
    scale = trajectory.scale
    duration = need(point.duration) * scale
    check_duration(settings, duration, "slowed down as the trajectory is, this segment")
    entry = Entry(
        point,
        trajectory.last_position,
        duration,
        start,
        duration,
        start_order=order,
        queued=context.at,
        phase=Phase.TRANSIENT if transient else Phase.PLANNED,
    )
    if point.kind is Kind.GIVEN:
        entry = stretched(settings, given(entry, scale))
    return entry


def _fit(context: Context, point: Knot, draft: Plan, built: list[Entry], *, defer: bool) -> Plan:
    """Step 3: the limits. The segments decided now must stay within the position limits; beyond
    the velocity or acceleration limits the trajectory is slowed down rather than the point
    refused (with ``defer``, the plan only says by how much)."""
    settings = context.settings
    for e in built:
        check_position(settings, e)
    running, started, pending, trajectory = draft.running, draft.started, draft.pending, draft.trajectory
    messages = draft.messages
    if defer:  # what the points' states ask for; the re-scale at the end settles the segments
        needed = max((end_need(settings, e) for e in built), default=1.0)
        return Plan(running, started, pending, trajectory, messages, context.at, needed)
    needed = max((uniform_need(settings, e) for e in built), default=1.0)
    planned = Plan(running, started, pending, trajectory, messages, context.at)
    if needed > 1.0:
        return rescale(context, planned, needed=needed, knot=point)
    return planned


def report_acceleration(settings: Settings, planned: Plan) -> Plan:
    """``planned`` with a line saying which given segment of its trajectory is run beyond the
    acceleration limit (:attr:`.Settings.follow_given_acceleration`), once the trajectory's time
    scale is settled: a WARNING the first time, then at INFO when one asks 10 % more than the
    largest said so far (no flood)."""
    if not settings.follow_given_acceleration:
        return planned
    book = planned.trajectory
    entries = [planned.running, *planned.pending] if planned.running is not None else list(planned.pending)
    worst: tuple[float, int, int] | None = None
    for e in entries:
        if e.trajectory != book.number or e.segment is None or not follows(settings, e):
            continue
        if orders(settings, e)[1] <= 1.0:
            continue
        ratio, joint = acceleration_ratio(settings, e)
        if worst is None or ratio > worst[0]:
            worst = (ratio, e.index, joint)
    if worst is None or worst[0] < 1.1 * book.reported_acceleration:
        return planned
    ratio, index, joint = worst
    first = book.reported_acceleration == 0.0
    text = (
        f"trajectory {book.number}: the segment to point {index} accelerates joint {joint + 1} at {ratio:.3g} x its "
        f"limit{'' if first else ', the most so far'}: run as given, as MotoROS runs its points' cubics (it checks "
        "their speeds only); the drives lag where they cannot follow"
    )
    return replace(
        planned,
        messages=(*planned.messages, (logging.WARNING if first else logging.INFO, text)),
        trajectory=replace(book, reported_acceleration=ratio),
    )


def dry_message(trajectory: TrajectoryBook, text: str) -> tuple[int, str]:
    """What to log when the robot went on after the queue ran dry (a WARNING once per trajectory)."""
    level = logging.DEBUG if trajectory.warned_dry else logging.WARNING
    return level, f"trajectory {trajectory.number}: the point queue ran dry: {text}: the robot went on from there"
