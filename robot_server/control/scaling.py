"""Limit scaling: a trajectory too fast for the joints' velocity or acceleration limits is not
refused but slowed down, uniformly, from where the robot is (module doc of :mod:`.motion`,
"Slowing down").

The part not yet executed (the rest of the running segment and every pending one) is time-scaled
by a factor until every segment fits; the scale only grows within a trajectory. Functions of the
queue's :class:`.entries.Context` and a snapshot's parts.
"""

from __future__ import annotations

import logging
from dataclasses import replace

from .building import determine, given, stretched
from .checks import check_duration, check_position, speed_excess, uniform_need, within_positions
from .entries import (
    MIN_REMAINDER,
    Context,
    Entry,
    Kind,
    Knot,
    Phase,
    Plan,
    Settings,
    TrajectoryBook,
    connect,
    knot_of,
    need,
)
from .points import PointRejected, Reason, State

#: a re-scale slows down by this much more than the limits need
RESCALE_MARGIN = 1.01
#: how many times a trajectory is re-scaled for one point before the point is refused
_MAX_RESCALES = 12

Scaled = tuple[Entry | None, float, list[Entry], TrajectoryBook]


def rescale(context: Context, planned: Plan, *, needed: float, knot: Knot | None) -> Plan:
    """``planned`` with what is not yet executed of its trajectory time-scaled until it fits the
    limits (``knot``: the point that asks for it; None: a download as a whole, or motion groups
    that share one time scale), and the line that says so among its messages. Raises
    :class:`PointRejected` when no scale makes it fit."""
    messages = list(planned.messages)
    running, started, pending, trajectory = _rescale(
        context,
        planned.running,
        planned.started,
        list(planned.pending),
        planned.trajectory,
        needed=needed,
        knot=knot,
        messages=messages,
    )
    return replace(
        planned,
        running=running,
        started=started,
        pending=tuple(pending),
        trajectory=trajectory,
        messages=tuple(messages),
        at=context.at,
        needed=1.0,
    )


def _rescale(
    context: Context,
    running: Entry | None,
    started: float,
    pending: list[Entry],
    trajectory: TrajectoryBook,
    *,
    needed: float,
    knot: Knot | None,
    messages: list[tuple[int, str]],
) -> Scaled:
    """Time-scale what is not yet executed of the trajectory until it fits the limits (``knot``:
    the point that asks for it; None: a download as a whole, or motion groups that share one
    time scale). Returns the running entry, its start time, the pending entries and the
    trajectory's book; appends what to log to ``messages``."""
    settings = context.settings
    was = trajectory.scale
    cause = f"point {knot.index}" if knot is not None else "the trajectory"
    for _ in range(_MAX_RESCALES):
        # a margin: points rounded to float32 on the wire would otherwise put the next ones a
        # hair over the limit, and every re-scale disturbs the segment under way
        factor = needed * RESCALE_MARGIN
        trajectory = trajectory.evolve(scale=trajectory.scale * factor)
        for e in pending:  # refused before the segments are built: they could overflow
            if e.trajectory == trajectory.number and e.knot is not None and e.knot.duration is not None:
                check_duration(
                    settings,
                    e.knot.duration * trajectory.scale,
                    f"slowed down to fit the limits, the segment to point {e.index}",
                )
        running, started, pending = scaled(context, running, started, pending, trajectory, factor=factor)
        mine = [e for e in [running, *pending] if e is not None and e.segment is not None]
        mine = [e for e in mine if e.trajectory == trajectory.number]
        needed = max((uniform_need(settings, e) for e in mine), default=1.0)
        if needed <= 1.0:
            break
    else:
        raise PointRejected(Reason.TIMING, f"{cause}: the trajectory cannot be slowed down to fit the limits")
    for e in mine:
        check_position(settings, e)
    for e in pending:  # decided or not
        if e.trajectory == trajectory.number:
            check_duration(settings, e.duration, f"slowed down to fit the limits, the segment to point {e.index}")
    text = (
        f"trajectory {trajectory.number}: {cause} is too fast for the joints' limits: the rest of "
        f"the trajectory is slowed down to x{trajectory.scale:.3f} its time ({(trajectory.scale - 1) * 100:.1f}% "
        f"longer)"
    )
    if not trajectory.warned_scale:
        messages.append((logging.WARNING, text))
        trajectory = trajectory.evolve(warned_scale=True, logged_scale=trajectory.scale)
    elif trajectory.scale >= 1.1 * trajectory.logged_scale:  # more: at INFO, once per 10 % (no flood)
        messages.append((logging.INFO, f"{text}, was x{was:.3f}"))
        trajectory = trajectory.evolve(logged_scale=trajectory.scale)
    else:
        messages.append((logging.DEBUG, f"{text}, was x{was:.3f}"))
    return running, started, pending, trajectory


def scaled(
    context: Context,
    running: Entry | None,
    started: float,
    pending: list[Entry],
    trajectory: TrajectoryBook,
    *,
    factor: float,
) -> tuple[Entry | None, float, list[Entry]]:
    """The trajectory's part not yet executed, ``factor`` times slower: the rest of the running
    segment (when that stays within the limits) and its pending segments."""
    settings = context.settings
    number, scale = trajectory.number, trajectory.scale
    mine = [e.trajectory == number and not e.is_kind(Kind.REST) for e in pending]
    # the first pending segment starts from the running one's end: at the old speed unless the
    # rest of the running segment is re-planned at the new scale (then a transient)
    transition = running is not None and running.trajectory == number
    if running is not None and running.trajectory == number and not running.is_kind(Kind.REST):
        remaining = (started + running.duration - context.at) * factor
        if remaining >= MIN_REMAINDER:
            successor = pending[0] if pending and mine[0] else None
            candidate = rebuilt(
                settings,
                running.evolve(
                    start=context.state,
                    start_order=2,
                    duration=remaining,
                    before_duration=running.before_duration * factor,
                    unbraked=None,
                ),
                successor,
                scale,
            )
            if candidate.segment is not None:
                candidate = stretched(settings, candidate)
            if (
                candidate.segment is not None
                and speed_excess(settings, candidate) <= 1.0
                and within_positions(settings, candidate)
            ):
                running, started, transition = candidate, context.at, False
    end, order = (running.end, running.end_order) if running is not None else (context.state, 2)
    slowed = running is not None and running.slowed
    out: list[Entry] = []
    for i, entry in enumerate(pending):
        if mine[i]:
            duration = need(knot_of(entry).duration) * scale
            assert end is not None
            moved = entry.evolve(start=end, start_order=order, duration=duration, before_duration=duration)
            if transition or slowed:
                moved = moved.marked(Phase.TRANSIENT)
                transition = False
            successor = pending[i + 1] if i + 1 < len(pending) and mine[i + 1] else None
            entry = rebuilt(settings, moved, successor, scale)
            if entry.segment is not None:
                entry = stretched(settings, entry)
        out.append(entry)
        end, order, slowed = entry.end, entry.end_order, entry.slowed
    return running, started, out


def rebuilt(settings: Settings, entry: Entry, successor: Entry | None, scale: float) -> Entry:
    """``entry`` planned again from its start at ``scale``: an estimated point without a next
    one stays undecided."""
    if entry.is_kind(Kind.GIVEN):
        return given(entry, scale)
    if entry.dry:
        end = State.rest(knot_of(entry).position)
        return entry.evolve(end=end, segment=connect(entry.start, entry.start_order, end, 2, entry.duration))
    if successor is None:
        return entry.evolve(end=None, segment=None)
    return determine(settings, entry, knot_of(successor).position, need(knot_of(successor).duration) * scale)
