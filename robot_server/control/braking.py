"""Look-ahead braking: keeping the robot from going beyond monotone points it cannot stop at
(module doc of :mod:`.motion`, "Points the robot could pass").

When the robot sets off to a point whose next point is the last one queued, with no more in
sight, or whose next point has joints at rest, the point's state is slowed down as much as it
takes for those joints to come to rest at that next point without passing it; if a further point
comes in time, the running segment gets the points' own state back. Functions of the queue's
:class:`.entries.Context` and the entries concerned.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..arrays import Array
from . import blend
from .building import MAX_LAG, MAX_LAG_FACTOR, least_slowing, slowed, stretched, to_rest
from .checks import excess, within_positions
from .entries import (
    MIN_REMAINDER,
    Context,
    Entry,
    Kind,
    Phase,
    Settings,
    TrajectoryBook,
    connect,
    knot_of,
    log,
    overshoot,
    overshoots,
)
from .points import State
from .segments import stop_travel, stop_travel_floats


def start_next(
    settings: Settings, pending: tuple[Entry, ...], trajectory: TrajectoryBook, at: float
) -> tuple[Entry, tuple[Entry, ...]]:
    """The first pending entry as it starts running ``at`` (to rest when its state is still
    undecided; slowed down when the robot may have to stop at the point after it), and the
    pending entries after it."""
    entry, pending = pending[0], pending[1:]
    if entry.end is None:
        messages: list[tuple[int, str]] = []
        entry = to_rest(settings, entry, messages)
        for level, message in messages:
            log.log(level, message)
    elif pending and entry.is_kind(Kind.ESTIMATED):
        after = pending[0]
        if after.end is None:
            if len(pending) == 1 and not coming(trajectory, entry, after, at):
                braked = braking(settings, entry, after, np.ones(after.start.position.shape, dtype=bool))
                if braked is not entry:
                    entry = braked
                    assert entry.end is not None
                    pending = (after.marked(Phase.TRANSIENT, start=entry.end, start_order=2),)
        elif np.any(holds := after.end.velocity == 0.0):
            # joints that hold still or turn at the point after this one: decided, so the
            # robot must be able to stop there (a burst: the points all queued at once)
            braked = braking(settings, entry, after, holds)
            if braked is not entry:
                entry = braked.evolve(unbraked=None)
                assert entry.end is not None
                segment = connect(entry.end, 2, after.end, after.end_order, after.duration)
                after = after.marked(Phase.TRANSIENT, start=entry.end, start_order=2, segment=segment)
                pending = (stretched(settings, after), *pending[1:])
    return entry, pending


def coming(trajectory: TrajectoryBook, entry: Entry, last: Entry, at: float) -> bool:
    """The point after ``last`` will likely be queued before the robot sets off to ``last``
    (``entry`` starting ``at``): the trajectory is open and its points keep coming at the
    pace they have come so far. Points all queued at once (a download, a burst) say nothing
    of more to come, and nor does a stream whose next point is overdue by more than its
    pace (the client has likely sent its last point; if one still comes, the robot gets
    the state back, :func:`unbraked`)."""
    if not trajectory.open or last.trajectory != trajectory.number or last.index < 1:
        return False
    gap = (last.queued - trajectory.opened) / last.index
    expected = last.queued + gap
    return gap > 0.0 and expected <= at + entry.duration and at <= expected + gap


def braking(settings: Settings, entry: Entry, last: Entry, stops: NDArray[np.bool_]) -> Entry:
    """``entry``, about to run, when the joints ``stops`` may have to come to rest at the
    point after its own, ``last``: it is the last one queued and no next one is in sight
    (:func:`coming`; all joints), or its state has them at rest (holding still, turning).
    A state at ``entry``'s point from which those joints can still come to rest at ``last``
    without going beyond it (their fastest stop ends short of it). The state the neighbours
    gave is kept when it allows that; otherwise its velocity (and acceleration) is scaled
    down as little as needed.
    The next segment then starts from a state the plan did not lead to (a transient: the
    robot catches up within its limits, a little late)."""
    end = entry.end
    assert end is not None
    lim = settings.limits
    ahead = knot_of(last).position - end.position
    limits = (lim.max_velocity, lim.max_acceleration, lim.max_jerk)
    # the float path's lists, made once for the bisection's calls
    state = (end.velocity.tolist(), end.acceleration.tolist())
    float_limits = (lim.max_acceleration.tolist(), lim.max_jerk.tolist())
    ahead_floats, stopping = ahead.tolist(), stops.tolist()

    def stop_overshoots(f: float) -> bool:
        found = stop_overshoots_floats(state, float_limits, ahead_floats, stopping, f)
        return found if found is not None else stop_overshoots_array(end, limits, ahead, stops, f)

    if not stop_overshoots(1.0):
        return entry
    # within 0.4 % of the least slowing down (this runs in a tick); at rest when the last point
    # is too close for any speed
    slower = slowed(end, least_slowing(lambda f: not stop_overshoots(f), steps=8))
    candidate = stretched(
        settings,
        entry.evolve(end=slower, segment=connect(entry.start, entry.start_order, slower, 2, entry.duration)),
    )
    if (
        excess(settings, candidate)[0] > 1.0
        or not within_positions(settings, candidate)
        or overshoots(candidate, max(blend.OVERSHOOT, overshoot(entry)))
    ):
        return entry  # it cannot brake that much on the way to its own point: as planned
    log.debug("point %d: slower through it, to be able to stop at point %d", entry.index, last.index)
    return candidate.evolve(unbraked=end)


def stop_overshoots_array(
    end: State, limits: tuple[Array, Array, Array], ahead: Array, stops: NDArray[np.bool_], f: float
) -> bool:
    """Whether the joints ``stops``' fastest stops from ``end`` made ``f`` times slower (closed
    form: this runs in the controller's tick) end beyond the point ``ahead`` of it, or back before
    this one, by more than :data:`.blend.OVERSHOOT`."""
    travel = stop_travel(end.velocity / f, end.acceleration / (f * f), limits=limits)
    beyond = np.maximum(travel - np.maximum(ahead, 0.0), np.minimum(ahead, 0.0) - travel)
    return bool(np.max(np.where(stops, beyond, 0.0)) > blend.OVERSHOOT)


def stop_overshoots_floats(
    state: tuple[list[float], list[float]],
    limits: tuple[list[float], list[float]],
    ahead: list[float],
    stops: list[bool],
    f: float,
) -> bool | None:
    """:func:`stop_overshoots_array` on floats, joint by joint (``state``: the velocities and
    accelerations, ``limits``: the acceleration and jerk limits): the same numbers, so the same
    answer (a segment start of every moving controller of a fleet runs it); None where
    :func:`.segments.stop_travel_floats` leaves it to the arrays."""
    velocity, acceleration = state
    travel = stop_travel_floats([v / f for v in velocity], [a / (f * f) for a in acceleration], *limits)
    if travel is None:
        return None
    worst = 0.0
    for t, ahead_i, stop in zip(travel, ahead, stops, strict=True):
        if stop:
            worst = max(worst, t - max(ahead_i, 0.0), min(ahead_i, 0.0) - t)
    return worst > blend.OVERSHOOT


def unbraked(context: Context, running: Entry, started: float) -> Entry | None:
    """The rest of a running segment slowed down to be able to stop at the next point
    (:func:`braking`), re-planned to the state the points give its own now that a further
    point has come (None: too late, or beyond the limits)."""
    settings = context.settings
    end = running.unbraked
    assert end is not None
    remaining = started + running.duration - context.at
    if remaining < MIN_REMAINDER:
        return None
    segment = connect(context.state, 2, end, 2, remaining)
    entry = stretched(
        settings,
        running.evolve(start=context.state, start_order=2, duration=remaining, end=end, segment=segment, unbraked=None),
    )
    if (
        entry.duration > MAX_LAG_FACTOR * remaining + MAX_LAG  # as late as a jerk replacement may be
        or excess(settings, entry)[0] > 1.0
        or not within_positions(settings, entry)
        or overshoots(entry, blend.OVERSHOOT)
    ):
        return None
    return entry
