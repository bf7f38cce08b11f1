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
still on either side gets velocity and acceleration 0. Where the joint reverses (the slopes differ
in sign), the points are not monotone and the estimate stands: the data's own smooth curve turns
between the samples, and forcing the velocity to 0 at the sample nearest the turn (as Fritsch and
Carlson's PCHIP does) would put a kink in the acceleration there.

The conditions are sufficient, not necessary, so they are applied only where the plain
estimate's control points show an overshoot beyond :data:`OVERSHOOT` (a tenth of a milliradian):
at sharp corners of sparse waypoints and in the last points before a stop. Near a joint's turn,
dense points leave tiny segments, and clamping there would force hard decelerations for a gain
nobody could see. Everything is vectorised over joints and invariant under uniform time scaling.

**Jerk.** Within what the shape allows, the end acceleration is chosen to keep the segment's jerk
within the limit (the jerk is linear in it, :func:`jerk_limited`): the parabola estimate is off
where the client's plan steps its acceleration (time-optimal planners without a jerk limit step it
at the start, the end and every phase change), and a quintic through slightly inconsistent states
pays for it in jerk.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .points import State

__all__ = ["estimate", "shape_preserving", "jerk_limited", "through_state", "RESERVE"]

Array = NDArray[np.float64]

#: share of the next segment's monotonicity budget that the point at its start may use
RESERVE = 0.25
#: moves shorter than this (rad or m) count as holding still
_STILL = 1e-12
#: an overshoot this small (rad or m: 0.1 mrad is 0.05 mm at half a metre) is not worth a clamp
OVERSHOOT = 1e-4


def estimate(before: Array, h1: float, position: Array, h2: float, after: Array) -> tuple[Array, Array]:
    """The parabola estimate of the velocity and acceleration at ``position`` (module doc)."""
    d1 = (position - before) / h1
    d2 = (after - position) / h2
    total = h1 + h2
    return (h2 * d1 + h1 * d2) / total, 2.0 * (d2 - d1) / total


def shape_preserving(
    start: State,
    duration: float,
    position: Array,
    *,
    after: Array,
    after_duration: float,
    velocity: Array,
) -> tuple[Array, Array, Array]:
    """The velocity at ``position`` clamped so that the segment from ``start`` (``duration`` long)
    and the one to ``after`` (``after_duration``) need not overshoot, and the interval
    ``[low, high]`` the acceleration must lie in for them not to (module doc)."""
    t1, t2 = duration, after_duration
    delta1, delta2 = position - start.position, after - position
    m1, m2 = np.abs(delta1), np.abs(delta2)
    s1 = np.sign(delta1)
    still = (m1 <= _STILL) | (m2 <= _STILL)
    safe1 = np.where(still, 1.0, m1)
    # the fixed start in the first segment's normalised frame, and how much of its budget it left
    alpha = start.velocity * s1 * t1 / safe1
    curvature = start.acceleration * s1 * t1 * t1 / safe1
    used = curvature + 8.0 * alpha - 20.0  # <= 0 when the start leaves room
    low1 = used * m1 / (t1 * t1)  # the end acceleration (in the s1 direction) may not go below this + 8 u / t1
    room2 = 20.0 * (1.0 - RESERVE) * m2 / (t2 * t2)
    monotone = (np.sign(delta2) == s1) & ~still
    # speed u >= 0 and acceleration w in the s1 direction
    u_max = np.minimum.reduce(
        [
            -used * m1 / (4.0 * t1),
            5.0 * (1.0 - RESERVE) * m2 / t2,
            (room2 - low1) / (8.0 / t1 + 8.0 / t2),
        ]
    )
    # a start too fast for its segment (used > 0) leaves no monotone choice: the segment overshoots
    # the point whatever its state; arriving at rest keeps that overshoot smallest (a larger end
    # speed over the short remaining distance would first swing the joint back)
    u = np.clip(velocity * s1, 0.0, np.maximum(u_max, 0.0))
    w_lo = np.maximum(low1 + 8.0 * u / t1, -4.0 * u / t2)
    # with room, the interval is not empty (u <= u_max makes the four bounds compatible; at
    # u = u_max it is a single value, which rounding may invert); without room, any acceleration
    w_hi = np.maximum(np.minimum(4.0 * u / t1, room2 - 8.0 * u / t2), w_lo)
    empty = u_max < 0.0
    w_lo = np.where(empty, 0.0, w_lo)
    w_hi = np.where(empty, 0.0, w_hi)
    lo = np.where(s1 >= 0.0, w_lo, -w_hi)
    hi = np.where(s1 >= 0.0, w_hi, -w_lo)
    # a reversal (the joint turns between the neighbours): the smooth curve turns near the point,
    # so the estimate stands and the curve may pass the point slightly, as the data's own curve does
    v_out = np.where(monotone, u * s1, np.where(still, 0.0, velocity))
    lo = np.where(monotone, lo, np.where(still, 0.0, -np.inf))
    hi = np.where(monotone, hi, np.where(still, 0.0, np.inf))
    return v_out, lo, hi


#: where the jerk of a segment is sampled to choose the end acceleration (normalised time)
_JERK_SAMPLES = np.linspace(0.0, 1.0, 9)[:, None]


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
    """The end acceleration for the quintic from ``start`` to ``(position, velocity, .)`` over
    ``duration``: ``acceleration`` clamped into ``[low, high]`` and, where possible, to keep the
    segment's jerk within ``jerk`` (sampled at nine instants; the segment is checked exactly
    afterwards). The end acceleration enters the jerk linearly: ``j(s) = j0(s) + a1 (3 - 24 s +
    30 s^2) / T`` in normalised time."""
    t = duration
    p0, v0, a0 = start
    delta = position - p0
    c3 = (20.0 * delta - (8.0 * velocity + 12.0 * v0) * t - 3.0 * a0 * t * t) / 2.0
    c4 = (-30.0 * delta + (14.0 * velocity + 16.0 * v0) * t + 3.0 * a0 * t * t) / 2.0
    c5 = (12.0 * delta - 6.0 * (velocity + v0) * t - a0 * t * t) / 2.0
    s = _JERK_SAMPLES
    j0 = (6.0 * c3 + 24.0 * c4 * s + 60.0 * c5 * s * s) / t**3  # (samples, dof) with a1 = 0
    g = np.broadcast_to((3.0 - 24.0 * s + 30.0 * s * s) / t, j0.shape)  # d jerk / d a1
    with np.errstate(divide="ignore", invalid="ignore"):
        bound_a = (-jerk - j0) / g
        bound_b = (jerk - j0) / g
    lower = np.where(g > 0.0, bound_a, bound_b).max(axis=0)
    upper = np.where(g > 0.0, bound_b, bound_a).min(axis=0)
    lower, upper = np.maximum(lower, low), np.minimum(upper, high)
    # where no acceleration the shape allows keeps the jerk within the limit (a start from rest that
    # the plan wants faster than the jerk allows), the estimate stands: the segment is then
    # replaced by a jerk-limited one (motion.py) and should end in the state the data implies
    chosen = np.clip(acceleration, low, high)
    return np.where(lower <= upper, np.clip(chosen, lower, upper), chosen)


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
) -> State:
    """The state at ``position`` for a segment that starts at ``start`` (``duration`` before it)
    and goes on to ``after``: the estimate from the points ``before -> position -> after``
    (``before_duration`` is the full time of the segment from ``before``, which may have started
    earlier than ``start``), made shape-preserving, and with the jerk of the segment ending here
    within ``jerk`` where an acceleration allowed by the shape can do it."""
    v_est, a_est = estimate(before, before_duration, position, after_duration, after)
    v, low, high = shape_preserving(
        start, duration, position, after=after, after_duration=after_duration, velocity=v_est
    )
    # where the plain estimate overshoots by no more than OVERSHOOT (the convex hull of the Bezier
    # control points bounds it), the clamp would only cost smoothness: near a joint's turn, dense
    # points leave tiny segments, and clamping there forces hard decelerations
    overshoot = _hull_overshoot(
        start, duration, position, after=after, t2=after_duration, velocity=v_est, acceleration=a_est
    )
    harmless = overshoot <= OVERSHOOT
    # ... as long as it leaves the next point room to choose (else that one could not avoid a
    # large overshoot when the points go on the same way)
    m2 = np.abs(after - position)
    s2 = np.sign(after - position)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha2 = v_est * s2 * after_duration / m2
        curvature2 = a_est * s2 * after_duration**2 / m2
    harmless &= (m2 > _STILL) & (curvature2 + 8.0 * alpha2 - 20.0 <= 0.0)
    v = np.where(harmless, v_est, v)
    low = np.where(harmless, -np.inf, low)
    high = np.where(harmless, np.inf, high)
    if jerk is None:
        return State(position, v, np.clip(a_est, low, high))
    a = jerk_limited(start, duration, position, v, acceleration=a_est, low=low, high=high, jerk=jerk)
    return State(position, v, a)


def _hull_overshoot(
    start: State, t1: float, position: Array, *, after: Array, t2: float, velocity: Array, acceleration: Array
) -> Array:
    """Per joint, a bound on how far the segment ending at ``position`` with this state, and the
    start of the next one, go beyond their points: their Bezier control points' excursion."""
    p0, v0, a0 = start
    inner1 = np.stack(
        [
            p0 + v0 * t1 / 5.0,
            p0 + 2.0 * v0 * t1 / 5.0 + a0 * t1 * t1 / 20.0,
            position - 2.0 * velocity * t1 / 5.0 + acceleration * t1 * t1 / 20.0,
            position - velocity * t1 / 5.0,
        ]
    )
    inner2 = np.stack(
        [position + velocity * t2 / 5.0, position + 2.0 * velocity * t2 / 5.0 + acceleration * t2 * t2 / 20.0]
    )
    beyond1 = np.maximum(inner1 - np.maximum(p0, position), np.minimum(p0, position) - inner1).max(axis=0)
    beyond2 = np.maximum(inner2 - np.maximum(position, after), np.minimum(position, after) - inner2).max(axis=0)
    result: Array = np.maximum(np.maximum(beyond1, beyond2), 0.0)
    return result
