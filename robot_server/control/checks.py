"""The motion queue's limit checks: by how much a segment, or a state, is beyond the joints' limits.

Pure functions of the queue's :class:`.entries.Settings` and one entry or state. A segment keeps
its results (``Segment.memo``, per settings object): a re-scale asks again for every pending
segment, and most have not changed. Uniform time scaling divides the k-th derivative by
factor^k, so every excess here is the factor by which time must grow.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..arrays import Array
from .blend import OVERSHOOT
from .entries import Entry, Kind, Settings
from .points import SLACK, Limits, PointRejected, Reason, State, within

#: what a rest-to-rest segment beyond a limit is refused as, per derivative order
REFUSALS = {
    0: (Reason.POSITION_LIMIT, "the segment's position"),
    1: (Reason.VELOCITY_LIMIT, "the segment's velocity"),
    2: (Reason.ACCELERATION_LIMIT, "the segment's acceleration"),
    3: (Reason.TIMING, "the segment's jerk"),
}


def limit_of(limits: Limits, order: int) -> Array:
    """The limit of the ``order``-th derivative (1 velocity, 2 acceleration, 3 jerk)."""
    return {1: limits.max_velocity, 2: limits.max_acceleration, 3: limits.max_jerk}[order]


def check_duration(settings: Settings, duration: float, what: str) -> None:
    """Refuse a segment longer than the queue's maximum segment time."""
    if duration > settings.max_duration:
        raise PointRejected(
            Reason.TIMING,
            f"{what} would be {duration:g} s, beyond the maximum segment time ({settings.max_duration:g} s)",
        )


def excess(settings: Settings, entry: Entry) -> tuple[float, float]:
    """By how much the segment's time must grow for its velocity and acceleration, and for its
    jerk, to be within the limits (1: they are)."""
    velocity, acceleration, jerk = orders(settings, entry)
    return max(velocity, acceleration), jerk


def speed_excess(settings: Settings, entry: Entry) -> float:
    """By how much the segment's time must grow for what the trajectory is slowed down for: its
    velocity and acceleration, or its velocity alone when a given segment is followed beyond the
    acceleration limit (:attr:`.Settings.follow_given_acceleration`)."""
    velocity, acceleration, _ = orders(settings, entry)
    return velocity if follows(settings, entry) else max(velocity, acceleration)


def follows(settings: Settings, entry: Entry) -> bool:
    """The segment is run as given beyond the acceleration limit (MotoROS's way): a given segment
    that starts where the client's points lead, or from the trajectory's start point. A transient
    later in a trajectory (after the queue ran dry, or a re-scale's hand-over) starts from a state
    MotoROS would never be in: it is met locally as on any controller."""
    return (
        settings.follow_given_acceleration and entry.is_kind(Kind.GIVEN) and (not entry.transient or entry.index == 1)
    )


def acceleration_ratio(settings: Settings, entry: Entry) -> tuple[float, int]:
    """The segment's largest |acceleration| / limit and its joint (0-based); kept with the segment."""
    segment = entry.segment
    assert segment is not None
    key = settings.ratio_key
    cached = segment.memo.get(key)
    if cached is None:
        lo, hi = segment.extremes(2)
        ratio = np.maximum(-lo, hi) / settings.limits.max_acceleration
        j = int(np.argmax(ratio))
        cached = segment.memo[key] = (float(ratio[j]), j)
    return cached  # type: ignore[return-value]


def orders(settings: Settings, entry: Entry) -> tuple[float, float, float]:
    """By how much the segment's time must grow for its velocity, its acceleration and its jerk,
    each, to be within the limits (1: it is)."""
    segment = entry.segment
    assert segment is not None
    cached = segment.memo.get(settings)
    if cached is not None:
        return cached  # type: ignore[return-value]
    lim = settings.limits
    rows = lim.rows
    needed = [1.0, 1.0, 1.0, 1.0]
    for order in range(1, min(segment.bounded_order, 3) + 1):
        low, high = segment.bound_lists(order)
        if within_symmetric(low, high, (rows.max_velocity, rows.max_acceleration, rows.max_jerk)[order - 1]):
            continue
        limit = limit_of(lim, order)
        lo, hi = segment.extremes(order)
        over = float(np.max(np.maximum(-lo, hi) / limit))
        if over > 1.0 + SLACK:
            needed[order] = over ** (1.0 / order)
    result = needed[1], needed[2], needed[3]
    segment.memo[settings] = result
    return result


def within_symmetric(low: Sequence[float], high: Sequence[float], limit: Sequence[float]) -> bool:
    """Every joint's ``[low, high]`` within ``[-limit, limit]`` (NaN is not)."""
    return all(-lo <= m and hi <= m for lo, hi, m in zip(low, high, limit, strict=True))


def swings(settings: Settings, entry: Entry) -> bool:
    """The segment goes beyond its two points by more than OVERSHOOT plus what the robot needs
    to brake from its start (its Bezier hull says so: cheap, and exact enough to flag a fast
    start over a long segment, which a quintic turns into a long excursion)."""
    segment = entry.segment
    assert segment is not None and entry.end is not None
    low, high = segment.bound_lists(0)
    rows = settings.limits.rows
    start = entry.start
    for lo, hi, v0, a0, p0, p1, max_a, max_j in zip(
        low,
        high,
        start.velocity.tolist(),
        start.acceleration.tolist(),
        start.position.tolist(),
        entry.end.position.tolist(),
        rows.max_acceleration,
        rows.max_jerk,
        strict=True,
    ):
        near, far = (p1, p0) if p1 < p0 else (p0, p1)  # min and max (equal values when p0 == p1)
        if lo >= near - OVERSHOOT and hi <= far + OVERSHOOT:
            continue  # within OVERSHOOT, so within OVERSHOOT plus the braking, whatever that is
        v0, a0 = abs(v0), abs(a0)
        ramp = (a0 + max_a) / max_j  # time to turn the acceleration round
        fastest = v0 + a0 * ramp
        braking = fastest * ramp + fastest * fastest / (2.0 * max_a) + OVERSHOOT
        if lo < near - braking or hi > far + braking:
            return True
    return False


def uniform_need(settings: Settings, entry: Entry) -> float:
    """By how much the whole trajectory must slow down for this segment: its velocity and
    acceleration excess; for a transient first its end state's (the start is the robot being
    late, met locally; an end state beyond the limits is a plan too fast from there on), then,
    if the local fix failed, its own."""
    if not entry.transient:
        return max(speed_excess(settings, entry), end_need(settings, entry) if entry.end is not None else 1.0)
    needed = end_need(settings, entry)
    if needed > 1.0:
        return needed
    # an end state within the limits that the local fix could still not reach (it would have
    # to go faster than the limits to get there in time): the segment's own excess
    return speed_excess(settings, entry)


def end_need(settings: Settings, entry: Entry) -> float:
    """By how much the trajectory must slow down for the segment's end state to be within the
    velocity and acceleration limits (1: it is), :func:`state_need`; kept with the segment
    built to that state (a re-scale asks again for every pending segment)."""
    end, segment = entry.end, entry.segment
    assert end is not None
    if segment is None:
        return state_need(end, settings.limits)
    key = settings.end_need_key
    cached = segment.memo.get(key)
    if cached is None:
        cached = segment.memo[key] = state_need(end, settings.limits)
    return cached  # type: ignore[return-value]


def within_positions(settings: Settings, entry: Entry) -> bool:
    """The segment stays within the position limits (up to SLACK)."""
    segment = entry.segment
    assert segment is not None
    lim = settings.limits
    if within_bounds(*segment.bound_lists(0), lim.rows.lower, lim.rows.upper):
        return True
    lo, hi = segment.extremes(0)
    slack = SLACK * np.maximum(1.0, np.abs(lim.upper))
    return bool(np.all(lo >= lim.lower - slack) and np.all(hi <= lim.upper + slack))


def within_bounds(low: Sequence[float], high: Sequence[float], lower: Sequence[float], upper: Sequence[float]) -> bool:
    """Every joint's ``[low, high]`` within ``[lower, upper]`` (NaN is not)."""
    return all(lo >= a and hi <= b for lo, hi, a, b in zip(low, high, lower, upper, strict=True))


def check_position(settings: Settings, entry: Entry) -> None:
    """Refuse a segment that leaves the position limits (a given velocity can swing it out)."""
    if not within_positions(settings, entry):
        assert entry.segment is not None
        lo, hi = entry.segment.extremes(0)
        lim = settings.limits
        within(lo, lim.lower, lim.upper, Reason.POSITION_LIMIT, "the segment's position")
        within(hi, lim.lower, lim.upper, Reason.POSITION_LIMIT, "the segment's position")


def state_need(state: State, limits: Limits) -> float:
    """By how much a trajectory must slow down (velocities / k, accelerations / k^2) for one of its
    states to be within the velocity and acceleration limits (1: it is), counting the speed a joint
    still gains while its acceleration is brought to 0 at the jerk limit (a^2 / 2 J, when the
    acceleration speeds it up): from a state beyond that, every motion leaves the velocity limit,
    the controller's stop included."""
    # joint by joint on floats: numpy's operations on the arrays, in the same order (the same
    # numbers), without its cost per call on arrays of six (this runs for every planned point)
    rows = limits.rows
    max_v, max_a, max_j = rows.max_velocity, rows.max_acceleration, rows.max_jerk
    speed: list[float] = []
    push: list[float] = []
    gain: list[float] = []
    room: list[float] = []
    # the largest speed and |acceleration| over their limits (np.max: the same value)
    fastest_joint = accelerating = -math.inf
    for v, a, p, low, high, top_v, top_a, jerk in zip(
        state.velocity.tolist(),
        state.acceleration.tolist(),
        state.position.tolist(),
        rows.lower,
        rows.upper,
        max_v,
        max_a,
        max_j,
        strict=True,
    ):
        direction = 1.0 if v > 0.0 else -1.0 if v < 0.0 else 0.0  # np.sign (v is finite)
        pushed = a * direction
        s = abs(v)
        speed.append(s)
        push.append(pushed)
        gain.append(pushed * pushed / (2.0 * jerk) if pushed > 0.0 else 0.0)  # at k = 1; / k^4 when scaled
        # room to brake before the position limit the joint heads for
        room.append(high - p if direction > 0.0 else p - low)
        ratio = s / top_v
        fastest_joint = ratio if ratio > fastest_joint else fastest_joint
        ratio = abs(a) / top_a
        accelerating = ratio if ratio > accelerating else accelerating
    needed = max(1.0, fastest_joint)
    needed = max(needed, math.sqrt(accelerating))
    speed_limit = [m * (1.0 + SLACK) for m in max_v]

    def fits(k: float) -> bool:
        k4, k2 = k**4, k * k
        for s, pushed, g, r, top, acc, jerk in zip(speed, push, gain, room, speed_limit, max_a, max_j, strict=True):
            v, a = s / k, (0.0 if pushed < 0.0 else pushed) / k2
            if not v + g / k4 <= top:
                return False
            ramp = (a + acc) / jerk  # to turn the acceleration round
            fastest = v + a * ramp
            braking = fastest * ramp + fastest * fastest / (2.0 * acc)
            if not braking <= r + SLACK:
                return False
        return True

    if not fits(needed):
        # both terms fall with k: at ``high`` each is at most half the limit
        doubled = max([2.0 * s / m for s, m in zip(speed, max_v, strict=True)])
        low, high = needed, max(needed, doubled)
        gained = max([2.0 * g / m for g, m in zip(gain, max_v, strict=True)])
        root: float = gained**0.25
        high = max(high, root)
        while not fits(high):  # braking room: the braking distance falls as 1 / k (at least)
            if high > 1e6:
                return high  # no room at all (a joint at its limit, moving on): slowing cannot help
            high *= 2.0
        for _ in range(48):
            middle = 0.5 * (low + high)
            low, high = (low, middle) if fits(middle) else (middle, high)
        needed = high
    return needed if needed > 1.0 + SLACK else 1.0
