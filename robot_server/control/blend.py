"""Through-states of the ``blend`` policy: the velocity and acceleration at a point the robot passes
through, from its neighbours, so that no segment overshoots its points.

**Estimate.** With the previous point ``p0``, this point ``p1`` and the next ``p2``, segment times
``h1`` (``p0 -> p1``) and ``h2`` (``p1 -> p2``) and slopes ``d1 = (p1 - p0) / h1``,
``d2 = (p2 - p1) / h2``, the parabola through the three points gives

    v = (h2 d1 + h1 d2) / (h1 + h2),    a = 2 (d2 - d1) / (h1 + h2)

(second order in the point spacing: dense points of a smooth trajectory are followed closely).

**Shape preservation.** Each segment is a quintic Hermite from its start state to its end state
(C2 when chained). A quintic can swing past its end points when the boundary velocities and
accelerations are large compared with the distance it covers, and a robot that overshoots its
waypoints invents motion. Per joint and segment, write the quintic in normalised form (distance
1, duration 1): start slope ``alpha``, start curvature ``A``, end slope ``beta``, end curvature ``B``.
Its Bezier control points are ``0, alpha/5, A/20 + 2 alpha/5, B/20 + 1 - 2 beta/5, 1 - beta/5, 1``;
when they increase, so does the segment (the derivative is a positive combination of their
differences). That gives four linear conditions:

    alpha >= 0,  beta >= 0,  A >= -4 alpha,  B <= 4 beta,  2 (alpha + beta) / 5 + (A - B) / 20 <= 1

So: where the points are monotone, the estimate is clamped into the conditions of the segment
ending here (its start is already fixed) and of the segment starting here (of whose budget it
takes at most :data:`RESERVE`, leaving the rest to the next point's choice); ``v = a = 0``
satisfies them whenever the start left room (it does when it was chosen the same way); when it
did not (a start too fast for its segment, given by the client or after a transient), the point
is reached at rest, which keeps the unavoidable overshoot smallest. A point where the joint holds
still on either side gets velocity and acceleration 0, and so does a point where it turns back (as
in Fritsch and Carlson's PCHIP), decelerating into it.

The conditions are sufficient, not necessary, so they are applied only where the plain
estimate's control points show an overshoot beyond :data:`OVERSHOOT` (a tenth of a milliradian),
or beyond a position limit: at sharp corners and turns of sparse waypoints and in the last points
before a stop. Near a joint's turn, dense points leave tiny segments; the data's own smooth curve
turns between two samples, and clamping there (zero velocity at the sample nearest the turn) would
put a kink in the acceleration for a gain nobody could see. Everything is vectorised over joints
and invariant under uniform time scaling.

**Jerk.** Within what the shape allows, the end acceleration is chosen to keep the segment's jerk
within the limit (the jerk is linear in it, :func:`jerk_limited`): the parabola estimate is off
where the client's plan steps its acceleration (time-optimal planners without a jerk limit step it
at the start, the end and every phase change), and a quintic through slightly inconsistent states
pays for it in jerk.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..arrays import Array
from .points import State

__all__ = ["estimate", "shape_preserving", "jerk_limited", "through_state", "RESERVE"]

#: share of the next segment's monotonicity budget that the point at its start may use
RESERVE = 0.25
#: moves shorter than this (rad or m) count as holding still
_STILL = 1e-12
#: an overshoot this small (rad or m: 0.1 mrad is 0.05 mm at half a metre) is not worth a clamp
OVERSHOOT = 1e-4


def estimate(before: Array, h1: float, position: Array, h2: float, after: Array) -> tuple[Array, Array]:
    """The parabola estimate of the velocity and acceleration at ``position`` (module doc), per joint."""
    pairs = [
        _estimate(b, h1, p, h2, a) for b, p, a in zip(before.tolist(), position.tolist(), after.tolist(), strict=True)
    ]
    v, acc = (np.array(column) for column in zip(*pairs, strict=True))
    return v, acc


def _estimate(before: float, h1: float, position: float, h2: float, after: float) -> tuple[float, float]:
    d1, d2 = (position - before) / h1, (after - position) / h2
    return (h2 * d1 + h1 * d2) / (h1 + h2), 2.0 * (d2 - d1) / (h1 + h2)


def through_state(
    start: State,
    duration: float,
    position: Array,
    *,
    after: Array,
    after_duration: float,
    before: Array,
    before_duration: float,
    jerk: Array | None = None,
    acceleration: Array | None = None,
    lower: Array | None = None,
    upper: Array | None = None,
) -> State:
    """The state at ``position`` for a segment that starts at ``start`` (``duration`` before it)
    and goes on to ``after``: the estimate from the points ``before -> position -> after``
    (``before_duration`` is the full time of the segment from ``before``, which may have started
    earlier than ``start``), made shape-preserving (never beyond the position limits ``lower``,
    ``upper``), and with the jerk of the segment ending here within ``jerk`` where an acceleration
    allowed by the shape and within ``acceleration`` can do it.

    Joint by joint on plain floats: for six joints that is several times faster than numpy on
    arrays of six (a point is planned while the controller runs)."""
    h1, t1, t2 = before_duration, duration, after_duration
    n = position.size
    jerks = jerk.tolist() if jerk is not None else [math.inf] * n
    accelerations = acceleration.tolist() if acceleration is not None else [math.inf] * n
    lows = lower.tolist() if lower is not None else [-math.inf] * n
    highs = upper.tolist() if upper is not None else [math.inf] * n
    # what every joint's segment shares: its duration's powers and the jerk's weights over it
    weights = _jerk_weights(t1)
    t1_2, t1_3 = t1 * t1, t1 * t1 * t1
    v_out, a_out = [], []
    for p0, v0, a0, p, p2, pb, j, a_limit, low_limit, high_limit in zip(
        start.position.tolist(),
        start.velocity.tolist(),
        start.acceleration.tolist(),
        position.tolist(),
        after.tolist(),
        before.tolist(),
        jerks,
        accelerations,
        lows,
        highs,
        strict=True,
    ):
        # _estimate, inline (the same operations)
        d1, d2 = (p - pb) / h1, (p2 - p) / t2
        v_est, a_est = (t2 * d1 + h1 * d2) / (h1 + t2), 2.0 * (d2 - d1) / (h1 + t2)
        first = (p0, v0, a0)
        if _harmless(p0, v0, a0, t1, p, p2, t2, v_est, a_est, low_limit, high_limit):
            v, low, high = v_est, -math.inf, math.inf
        else:
            v, low, high = _shape(first, t1, p, (p2, t2), v_est, a=a_est)
        c3, c4, c5 = _free(first, t1, (p, v))
        a = _jerk_clamped(a_est, low, high, j, a_limit, c3, c4, c5, t1_3, weights)
        if _within(a_est, a0, a_limit) and _beyond(a0, c3, c4, c5, t1_2, a, a_limit):
            # the points are within the limit here, the segment to them is not (after a kink in
            # the data): an end acceleration that keeps it within, at the nearest velocity the
            # shape allows that has one (the jerk then kept within what is left, where it can be)
            interval = _acceleration_interval(first, t1, (p, v), (low, high), a_limit)
            for factor in _VELOCITY_FACTORS if interval is None else ():
                v_c, low_c, high_c = _shape(first, t1, p, (p2, t2), v_est * factor, a=a_est)
                interval = _acceleration_interval(first, t1, (p, v_c), (low_c, high_c), a_limit)
                if interval is not None:
                    v = v_c
                    break
            if interval is not None:
                a = _jerk_limited(first, t1, (p, v), a_est, interval, jerk=j, acceleration=a_limit)
        v_out.append(v)
        a_out.append(a)
    return State(position, np.array(v_out), np.array(a_out))


def _shape(
    start: tuple[float, float, float],
    t1: float,
    p: float,
    after: tuple[float, float],
    v: float,
    *,
    a: float | None = None,
) -> tuple[float, float, float]:
    """One joint: the velocity clamped, and the acceleration's interval, for no overshoot
    (``start``: position, velocity, acceleration; ``after``: the next position and the time to it).
    With the estimated acceleration ``a``, the velocity (never above the estimate) is the one
    nearest the estimate for which ``a`` lies within the interval, when there is one: at the
    largest velocity the interval is a single value, far from the curve's acceleration where the
    next point is close (a joint about to turn between two samples), and the spike would slow the
    whole trajectory down."""
    p0, v0, a0 = start
    p2, t2 = after
    delta1, delta2 = p - p0, p2 - p
    m1, m2 = abs(delta1), abs(delta2)
    if m1 <= _STILL or m2 <= _STILL:
        return 0.0, 0.0, 0.0  # holds still on one side: at rest here
    s1 = 1.0 if delta1 > 0.0 else -1.0
    # the fixed start in the first segment's normalised frame, and how much of its budget it left
    alpha = v0 * s1 * t1 / m1
    curvature = a0 * s1 * t1 * t1 / m1
    used = curvature + 8.0 * alpha - 20.0  # <= 0 when the start leaves room
    low1 = used * m1 / (t1 * t1)
    room2 = 20.0 * (1.0 - RESERVE) * m2 / (t2 * t2)
    if used > 0.0:
        # a start too fast for its segment leaves no monotone choice: the segment overshoots the
        # point whatever its state; arriving at rest keeps that overshoot smallest
        return 0.0, 0.0, 0.0
    if (delta2 > 0.0) != (s1 > 0.0):
        # the joint turns back here: reached at rest (as a monotone spline does), decelerating into
        # the point within both segments' budgets
        lo, hi = max(low1, -room2), 0.0
        return (0.0, lo, hi) if s1 > 0.0 else (0.0, -hi, -lo)
    u_max = min(-used * m1 / (4.0 * t1), 5.0 * (1.0 - RESERVE) * m2 / t2, (room2 - low1) / (8.0 / t1 + 8.0 / t2))
    u = min(max(v * s1, 0.0), u_max)
    if a is not None:
        # the velocities for which a (in this frame) lies within [w_lo, w_hi] below
        a_n = a * s1
        least = max(0.0, a_n * t1 / 4.0, -a_n * t2 / 4.0)
        most = min(u_max, (room2 - a_n) * t2 / 8.0, (a_n - low1) * t1 / 8.0)
        if least <= most:
            u = min(max(u, least), most)
    w_lo = max(low1 + 8.0 * u / t1, -4.0 * u / t2)
    # u <= u_max makes the four bounds compatible; at u = u_max the interval is a single value,
    # which rounding may invert
    w_hi = max(min(4.0 * u / t1, room2 - 8.0 * u / t2), w_lo)
    if s1 > 0.0:
        return u, w_lo, w_hi
    return -u, -w_hi, -w_lo


def _harmless(  # noqa: PLR0917 - per joint, on the hot path
    p0: float,
    v0: float,
    a0: float,
    t1: float,
    p: float,
    p2: float,
    t2: float,
    v: float,
    a: float,
    lower: float,
    upper: float,
) -> bool:
    """One joint: the plain estimate (velocity ``v``, acceleration ``a`` at ``p``; the segment from
    ``p0, v0, a0`` over ``t1``, the next to ``p2`` over ``t2``) overshoots by no more than OVERSHOOT
    and not beyond the position limits ``lower``, ``upper`` (the convex hull of the Bezier control
    points of the segment ending here and the start of the next one), and it leaves the next point
    room to choose. (``x if x > y else y`` is ``max(y, x)``, at a fraction of a call's cost.)"""
    near, far = (p, p0) if p < p0 else (p0, p)
    lo1 = near - OVERSHOOT
    lo1 = lower if lower > lo1 else lo1
    hi1 = far + OVERSHOOT
    hi1 = upper if upper < hi1 else hi1
    for c in (
        p0 + v0 * t1 / 5.0,
        p0 + 2.0 * v0 * t1 / 5.0 + a0 * t1 * t1 / 20.0,
        p - 2.0 * v * t1 / 5.0 + a * t1 * t1 / 20.0,
        p - v * t1 / 5.0,
    ):
        if not lo1 <= c <= hi1:
            return False
    near, far = (p2, p) if p2 < p else (p, p2)
    lo2 = near - OVERSHOOT
    lo2 = lower if lower > lo2 else lo2
    hi2 = far + OVERSHOOT
    hi2 = upper if upper < hi2 else hi2
    for c in (p + v * t2 / 5.0, p + 2.0 * v * t2 / 5.0 + a * t2 * t2 / 20.0):
        if not lo2 <= c <= hi2:
            return False
    m2 = abs(p2 - p)
    if m2 <= _STILL:
        return False
    s2 = 1.0 if p2 > p else -1.0
    return a * s2 * t2 * t2 / m2 + 8.0 * v * s2 * t2 / m2 - 20.0 <= 0.0  # the next point keeps room


#: where the jerk of a segment is sampled to choose the end acceleration (normalised time), and
#: the end acceleration's weight in the jerk there: j(s) = j0(s) + a1 (3 - 24 s + 30 s^2) / T
_JERK_SAMPLES = [k / 6.0 for k in range(7)]
_JERK_WEIGHTS = [3.0 - 24.0 * s + 30.0 * s * s for s in _JERK_SAMPLES]
#: where the acceleration is sampled (not at the start, which is given; at the end, which is the
#: choice), and the end acceleration's weight in it there: a(s) = a0(s) + a1 (3 s - 12 s^2 + 10 s^3)
_ACCELERATION_SAMPLES = [k / 8.0 for k in range(1, 9)]
_ACCELERATION_WEIGHTS = [3.0 * s - 12.0 * s * s + 10.0 * s * s * s for s in _ACCELERATION_SAMPLES]
_ACCELERATION_TERMS = list(zip(_ACCELERATION_SAMPLES, _ACCELERATION_WEIGHTS, strict=True))
#: the share of the acceleration limit the samples are kept within
_ACCELERATION_MARGIN = 0.96
#: the velocities tried, as multiples of the estimate, when no end acceleration keeps a segment
#: within the acceleration limit at the estimate: nearest first, faster before slower (after a
#: joint breaks away from rest the data's velocity rises faster than the three-point estimate)
_VELOCITY_FACTORS = (1.1, 0.9, 1.2, 0.8, 1.35, 1.5, 0.65)


def _jerk_limited(
    start: tuple[float, float, float],
    t: float,
    end: tuple[float, float],
    a: float,
    bounds: tuple[float, float],
    *,
    jerk: float,
    acceleration: float = math.inf,
) -> float:
    """One joint: the end acceleration ``a`` clamped into ``[low, high]`` and, where some value
    there keeps the quintic's jerk within ``jerk`` (sampled at seven instants; the segment is
    checked exactly afterwards), into those values. Where none does (a start from rest that the
    plan wants faster than the jerk allows), the estimate stands: the segment is then replaced
    by a jerk-limited one (building.stretched) and should end in the state the data implies.

    The jerk never moves the acceleration beyond ``acceleration`` (nor beyond the estimate, when
    that is beyond it already): the jerk limit is met locally (a jerk-limited segment where the
    quintic cannot), the acceleration limit by slowing the whole trajectory down. On dense points a
    start state a little off the data (after a jerk-limited segment, a kink in a recording) asks
    each next quintic for a larger end acceleration to keep its jerk, and the chain would grow past
    the acceleration limit where the data never comes near it."""
    c3, c4, c5 = _free(start, t, end)
    return _jerk_clamped(a, *bounds, jerk, acceleration, c3, c4, c5, t * t * t, _jerk_weights(t))


@functools.lru_cache(maxsize=64)  # dense points share their durations
def _jerk_weights(t: float) -> tuple[tuple[float, float], ...]:
    """The jerk's samples and the end acceleration's weights in it over a segment of ``t`` seconds."""
    return tuple((s, g / t) for s, g in zip(_JERK_SAMPLES, _JERK_WEIGHTS, strict=True))


def _jerk_clamped(  # noqa: PLR0917 - per joint, on the hot path
    a: float,
    low: float,
    high: float,
    jerk: float,
    acceleration: float,
    c3: float,
    c4: float,
    c5: float,
    t3: float,
    weights: tuple[tuple[float, float], ...],
) -> float:
    """:func:`_jerk_limited`'s work, given the quintic's free coefficients (:func:`_free`), ``t``
    cubed and the weights (:func:`_jerk_weights`): what every joint of a point shares is computed
    once. (``x if x > y else y`` is ``max(y, x)``, ``x if x < y else y`` is ``min(y, x)``.)"""
    chosen = low if low > a else a
    chosen = high if high < chosen else chosen
    if math.isinf(jerk):
        return chosen
    k3, k4, k5 = 6.0 * c3, 24.0 * c4, 60.0 * c5
    lower, upper = low, high
    for s, g in weights:
        j0 = (k3 + k4 * s + k5 * s * s) / t3
        if g > 0.0:
            bound = (-jerk - j0) / g
            lower = bound if bound > lower else lower
            bound = (jerk - j0) / g
            upper = bound if bound < upper else upper
        elif g < 0.0:
            bound = (jerk - j0) / g
            lower = bound if bound > lower else lower
            bound = (-jerk - j0) / g
            upper = bound if bound < upper else upper
        elif abs(j0) > jerk:
            return chosen
    if lower > upper:
        return chosen
    cap = abs(chosen)
    cap = cap if cap > acceleration else acceleration
    kept = lower if lower > chosen else chosen
    kept = upper if upper < kept else kept
    kept = -cap if -cap > kept else kept
    return cap if cap < kept else kept


def _within(estimate: float, start: float, acceleration: float) -> bool:
    """The points are not too fast here: the estimated acceleration and the segment's start are
    within the limit (else the whole trajectory slows down for it, as before)."""
    return math.isfinite(acceleration) and abs(estimate) <= acceleration and abs(start) <= acceleration


def _free(start: tuple[float, float, float], t: float, end: tuple[float, float]) -> tuple[float, float, float]:
    """One joint: the quintic from ``start`` (position, velocity, acceleration) to ``end`` (position,
    velocity, acceleration 0) over ``t``, as ``p0 + v0 t s + a0 t^2 s^2 / 2 + c3 s^3 + c4 s^4 + c5 s^5``
    in normalised time ``s``: (c3, c4, c5). An end acceleration ``a1`` adds ``a1 t^2 (s^3/2 - s^4 + s^5/2)``."""
    p0, v0, a0 = start
    p, v = end
    delta = p - p0
    c3 = (20.0 * delta - (8.0 * v + 12.0 * v0) * t - 3.0 * a0 * t * t) / 2.0
    c4 = (-30.0 * delta + (14.0 * v + 16.0 * v0) * t + 3.0 * a0 * t * t) / 2.0
    c5 = (12.0 * delta - 6.0 * (v + v0) * t - a0 * t * t) / 2.0
    return c3, c4, c5


def _rest_accelerations(start: tuple[float, float, float], t: float, end: tuple[float, float]) -> list[float]:
    """One joint: the acceleration of the quintic from ``start`` to ``end`` (position, velocity) with
    end acceleration 0 over ``t``, at :data:`_ACCELERATION_SAMPLES`; an end acceleration ``a1`` adds
    ``a1`` times :data:`_ACCELERATION_WEIGHTS`."""
    a0 = start[2]
    c3, c4, c5 = _free(start, t, end)
    t2 = t * t
    return [a0 + (6.0 * c3 * s + 12.0 * c4 * s * s + 20.0 * c5 * s * s * s) / t2 for s in _ACCELERATION_SAMPLES]


def _beyond(a0: float, c3: float, c4: float, c5: float, t2: float, a: float, limit: float) -> bool:  # noqa: PLR0917 - per joint, on the hot path
    """One joint: the quintic from ``a0`` (start acceleration) with the free coefficients ``c3``,
    ``c4``, ``c5`` (:func:`_free`) and the end acceleration ``a`` (``t2``: its time squared)
    accelerates beyond ``limit`` at one of the eight instants sampled
    (:func:`_rest_accelerations`' numbers)."""
    q3, q4, q5 = 6.0 * c3, 12.0 * c4, 20.0 * c5
    for s, g in _ACCELERATION_TERMS:  # the largest |sample| is beyond the limit when one is
        value = a0 + (q3 * s + q4 * s * s + q5 * s * s * s) / t2 + a * g
        if value > limit or -value > limit:
            break
    else:
        return False
    return True


def _acceleration_interval(
    start: tuple[float, float, float],
    t: float,
    end: tuple[float, float],
    bounds: tuple[float, float],
    acceleration: float,
) -> tuple[float, float] | None:
    """One joint: the end accelerations within ``bounds`` for which the quintic from ``start`` to
    ``end`` (position, velocity) over ``t`` keeps its acceleration within :data:`_ACCELERATION_MARGIN`
    of ``acceleration`` at eight instants (the acceleration is linear in the end acceleration); None
    when there is none."""
    lower, upper = bounds
    bound = _ACCELERATION_MARGIN * acceleration  # the peak between two samples is a little higher
    for a_s, g in zip(_rest_accelerations(start, t, end), _ACCELERATION_WEIGHTS, strict=True):
        if g > 0.0:
            lower, upper = max(lower, (-bound - a_s) / g), min(upper, (bound - a_s) / g)
        elif g < 0.0:
            lower, upper = max(lower, (bound - a_s) / g), min(upper, (-bound - a_s) / g)
    return (lower, upper) if lower <= upper else None


def shape_preserving(
    start: State, duration: float, position: Array, *, after: Array, after_duration: float, velocity: Array
) -> tuple[Array, Array, Array]:
    """The velocity at ``position`` clamped so that the segment from ``start`` (``duration`` long)
    and the one to ``after`` (``after_duration``) need not overshoot, and the interval
    ``[low, high]`` the acceleration must lie in for them not to (module doc); per joint."""
    rows = [
        _shape((p0, v0, a0), duration, p, (p2, after_duration), v)
        for p0, v0, a0, p, p2, v in zip(
            start.position.tolist(),
            start.velocity.tolist(),
            start.acceleration.tolist(),
            position.tolist(),
            after.tolist(),
            velocity.tolist(),
            strict=True,
        )
    ]
    v_out, low, high = (np.array(column) for column in zip(*rows, strict=True))
    return v_out, low, high


def jerk_limited(
    start: State,
    duration: float,
    position: Array,
    velocity: Array,
    *,
    acceleration: Array,
    low: Array,
    high: Array,
    jerk: Array,
) -> Array:
    """The end acceleration of the quintic from ``start`` to ``(position, velocity, .)`` over
    ``duration``, per joint (:func:`_jerk_limited`)."""
    return np.array(
        [
            _jerk_limited((p0, v0, a0), duration, (p, v), a, (lo, hi), jerk=j)
            for p0, v0, a0, p, v, a, lo, hi, j in zip(
                start.position.tolist(),
                start.velocity.tolist(),
                start.acceleration.tolist(),
                position.tolist(),
                velocity.tolist(),
                acceleration.tolist(),
                low.tolist(),
                high.tolist(),
                jerk.tolist(),
                strict=True,
            )
        ]
    )
