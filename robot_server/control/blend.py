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

So: a point where the joint reverses (the slopes differ in sign) or where it holds still on either
side gets velocity 0, as a monotone spline does (Fritsch and Carlson's PCHIP); elsewhere the
estimate is clamped into the conditions of the segment ending here (its start is already fixed)
and of the segment starting here (of whose budget it takes at most :data:`RESERVE`, leaving the
rest to the next point's choice). ``v = a = 0`` always satisfies them, so a choice always exists.
The conditions are sufficient, not necessary: they only bite near reversals, at sharp corners of
sparse waypoints and in the last points before a stop. Everything is vectorised over joints and
invariant under uniform time scaling.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .points import State

__all__ = ["estimate", "shape_preserving", "through_state", "RESERVE"]

Array = NDArray[np.float64]

#: share of the next segment's monotonicity budget that the point at its start may use
RESERVE = 0.5
#: moves shorter than this (rad or m) count as holding still
_STILL = 1e-12


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
    acceleration: Array,
) -> tuple[Array, Array]:
    """``velocity`` and ``acceleration`` at ``position`` clamped so that the segment from ``start``
    (``duration`` long) and the one to ``after`` (``after_duration``) do not overshoot (module doc)."""
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
    # monotone points: speed u >= 0 and acceleration w in the s1 direction
    u_max = np.minimum.reduce(
        [
            -used * m1 / (4.0 * t1),
            5.0 * (1.0 - RESERVE) * m2 / t2,
            (room2 - low1) / (8.0 / t1 + 8.0 / t2),
        ]
    )
    u = np.clip(velocity * s1, 0.0, np.maximum(u_max, 0.0))
    w_lo = np.maximum(low1 + 8.0 * u / t1, -4.0 * u / t2)
    w_hi = np.minimum(4.0 * u / t1, room2 - 8.0 * u / t2)
    # reversals: u = 0; decelerate into the point (w <= 0) within both segments' budgets
    turn_lo = np.maximum(low1, -room2)
    w_lo = np.where(monotone, w_lo, turn_lo)
    w_hi = np.where(monotone, w_hi, 0.0)
    w = np.where(w_lo <= w_hi, np.clip(acceleration * s1, w_lo, w_hi), 0.0)  # empty: the start left no room
    v_out = np.where(monotone, u * s1, 0.0)
    a_out = np.where(still, 0.0, w * s1)
    return v_out, a_out


def through_state(
    start: State,
    duration: float,
    position: Array,
    *,
    after: Array,
    after_duration: float,
    before: Array,
    before_duration: float,
) -> State:
    """The state at ``position`` for a segment that starts at ``start`` (``duration`` before it)
    and goes on to ``after``: the estimate from the points ``before -> position -> after``
    (``before_duration`` is the full time of the segment from ``before``, which may have started
    earlier than ``start``), made shape-preserving."""
    v, a = estimate(before, before_duration, position, after_duration, after)
    v, a = shape_preserving(
        start, duration, position, after=after, after_duration=after_duration, velocity=v, acceleration=a
    )
    return State(position, v, a)
