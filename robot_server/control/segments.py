"""Segment interpolators: how the controller moves all joints from one state to the next.

Each segment is a small immutable value covering local time ``0 <= t <= duration``; outside that
range it holds its end state (times are clamped). :meth:`Segment.sample` is vectorised: a scalar
time gives arrays of shape ``(dof,)``, an array of m times gives ``(m, dof)``, for position,
velocity, acceleration and jerk.

Polynomial segments (``h_0 + h_1 t + ... + h_5 t^5`` per joint, local time):

* :func:`linear`: constant velocity, C0 at the joins (the jittery baseline the paper measures);
* :func:`cubic`: rest to rest; :func:`cubic_hermite`: boundary velocities (C1 when chained);
* :func:`quintic`: rest to rest (the paper's eq. 6-10); :func:`quintic_hermite`: boundary
  velocities and accelerations (C2 when chained);
* :func:`launch`: from rest to a moving state the way a plan starts, its acceleration ramped up at
  the jerk limit (a :class:`Chain` of two polynomials).

:class:`RuckigSegment` is the time-optimal jerk-limited state-to-state motion of ruckig (Community
features only: no intermediate waypoints, which go through a network service; no position limits,
which the PyPI build ignores: :meth:`Segment.extremes` lets the caller check them).
"""

from __future__ import annotations

import bisect
import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import numpy.polynomial  # loaded now: numpy imports it lazily, 5 ms inside a controller tick
import ruckig
from numpy.typing import ArrayLike

from ..arrays import Array

__all__ = [
    "Samples",
    "Segment",
    "PolynomialSegment",
    "RuckigSegment",
    "linear",
    "cubic",
    "cubic_hermite",
    "quintic",
    "quintic_hermite",
    "launch",
    "Chain",
    "run_up",
    "stop_travel",
    "stop_travel_floats",
    "hold",
    "PlanningError",
]


class PlanningError(ValueError):
    """A motion cannot be planned from these inputs.

    The project's one planning error: here a segment that cannot be built (ruckig refused the
    inputs, a duration <= 0); in the PC planner (:mod:`client.planner`, which re-exports it) a task
    that cannot be planned (unreachable, a singularity, a joint jump, a bad argument).
    """


class Samples(NamedTuple):
    """Position, velocity, acceleration and jerk; ``(dof,)`` per time, ``(m, dof)`` for m times."""

    position: Array
    velocity: Array
    acceleration: Array
    jerk: Array


class Segment(ABC):
    """A motion of all joints over ``duration`` seconds.

    ``kind`` names the shape (for people: logs, reprs); code asks :attr:`bounded_order` instead:
    the highest derivative that stays finite where segments of this shape join (1: the velocity of
    a linear segment steps, so its acceleration is unbounded at the joins; 2: a cubic's
    acceleration steps; 3: quintics and ruckig's profiles are C2, their jerk is bounded). Limits
    are checked up to that order.
    """

    kind: str
    duration: float
    dof: int
    bounded_order: int
    #: derived values computed once (extremes, bounds, what a controller checked of it)
    memo: dict[object, object]

    @abstractmethod
    def sample(self, t: ArrayLike) -> Samples:
        """The state at local time(s) ``t`` (clamped to ``[0, duration]``)."""

    @abstractmethod
    def extremes(self, order: int) -> tuple[Array, Array]:
        """Per joint, the exact minimum and maximum over the segment of position (``order`` 0),
        velocity (1), acceleration (2) or jerk (3)."""

    def end(self) -> Samples:
        return self.sample(self.duration)

    def state_at(self, t: float) -> tuple[Array, Array, Array]:
        """Position, velocity and acceleration at one local time ``t`` (clamped): what the
        controller samples every interpolation period; the same numbers as :meth:`sample`'s."""
        s = self.sample(t)
        return s.position, s.velocity, s.acceleration

    def bounds(self, order: int) -> tuple[Array, Array]:
        """Per joint, cheap bounds that contain :meth:`extremes` (by default the exact values)."""
        return self.extremes(order)

    def bound_lists(self, order: int) -> tuple[Sequence[float], Sequence[float]]:
        """:meth:`bounds` as lists of floats, for checks made joint by joint on plain floats (the
        planning's: numpy's cost per call on arrays of six is several times the arithmetic). The
        same numbers, but for the sign of a zero: for comparisons only."""
        lo, hi = self.bounds(order)
        return lo.tolist(), hi.tolist()

    def peak(self, order: int) -> Array:
        """Per joint, the largest magnitude of position, velocity or acceleration (``order``)."""
        lo, hi = self.extremes(order)
        return np.maximum(np.abs(lo), np.abs(hi))


def _vector(value: ArrayLike, name: str, dof: int | None = None) -> Array:
    array = np.array(value, dtype=float).reshape(-1)
    if dof is not None and array.shape != (dof,):
        raise PlanningError(f"{name} has {array.size} values, expected {dof}")
    return array


_FLOAT64 = np.dtype(np.float64)


def _floats(value: ArrayLike, name: str, dof: int | None = None) -> list[float]:
    """:func:`_vector` as a list of floats (the same values; a float64 vector is not copied first)."""
    if type(value) is np.ndarray and value.dtype is _FLOAT64 and value.ndim == 1:
        if dof is not None and value.shape[0] != dof:
            raise PlanningError(f"{name} has {value.size} values, expected {dof}")
        return value.tolist()  # type: ignore[no-any-return]
    return _vector(value, name, dof).tolist()  # type: ignore[no-any-return]


def _duration(duration: float) -> float:
    duration = float(duration)
    if not (math.isfinite(duration) and duration > 0.0):
        raise PlanningError(f"a segment duration must be a finite number > 0, not {duration}")
    return duration


#: phases of a RuckigSegment's joint: an optional two-phase brake, then ruckig's seven
_PHASES = 9

#: one phase of constant jerk: (duration, jerk, and the acceleration, velocity, position it starts with)
_Phase = tuple[float, float, float, float, float]


def _phases(profile: ruckig.Profile) -> list[_Phase]:
    """A ruckig profile's phases (its brake's first)."""
    if profile.accel.duration > 0.0:  # a post-profile only exists for targets beyond the limits
        raise PlanningError("ruckig returned a target post-profile: the target state exceeds the limits")
    parts = [(profile.brake, 2)] if profile.brake.duration > 0.0 else []
    return [(x.t[k], x.j[k], x.a[k], x.v[k], x.p[k]) for x, count in [*parts, (profile, 7)] for k in range(count)]


def run_up(
    v0: ArrayLike, a0: ArrayLike, v1: ArrayLike, a1: ArrayLike, *, limits: tuple[ArrayLike, ArrayLike, ArrayLike]
) -> Array:
    """How far each joint moves on its own fastest way from velocity and acceleration ``v0``,
    ``a0`` to ``v1``, ``a1`` within ``limits`` (velocity, acceleration, jerk): ruckig's velocity
    interface, unsynchronised; infinite where ruckig finds no way."""
    arrays = [_vector(x, "state") for x in (v0, a0, v1, a1, *limits)]
    n = arrays[0].size
    inp = ruckig.InputParameter(n)
    inp.current_position, inp.target_position = [0.0] * n, [0.0] * n
    inp.current_velocity, inp.current_acceleration, inp.target_velocity, inp.target_acceleration = (
        a.tolist() for a in arrays[:4]
    )
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = (a.tolist() for a in arrays[4:])
    inp.control_interface = ruckig.ControlInterface.Velocity
    inp.synchronization = ruckig.Synchronization.No
    try:
        trajectory = _calculate(inp)
        return np.array([_phase_end(_phases(profile)[-1])[2] for profile in trajectory.profiles[0]])
    except PlanningError:
        return np.full(n, np.inf)


def stop_travel(
    velocity: ArrayLike, acceleration: ArrayLike, *, limits: tuple[ArrayLike, ArrayLike, ArrayLike]
) -> Array:
    """How far each joint moves on its fastest stop from ``velocity`` and ``acceleration`` (to
    velocity and acceleration 0) within ``limits`` (velocity, acceleration, jerk): what
    :func:`run_up` gives for a stop, in closed form (the acceleration goes to its peak braking
    value at the jerk limit, may hold there at the acceleration limit, and comes back to 0), a
    tenth of ruckig's time; joints already braking harder than that profile starts with are left
    to ruckig."""
    v0, a0 = _vector(velocity, "velocity"), _vector(acceleration, "acceleration")
    max_a, jerk = (_vector(x, "limit", v0.size) for x in limits[1:])
    sign = np.where(v0 != 0.0, np.sign(v0), np.sign(a0))
    v, a = v0 * sign, a0 * sign  # moving forward (or at rest, pushed forward)
    peak = np.minimum(np.sqrt(np.maximum(jerk * v + a * a / 2.0, 0.0)), max_a)
    valid = (a >= -peak) & (jerk * v + a * a / 2.0 >= 0.0)
    t1 = np.maximum((a + peak) / jerk, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = np.where(peak > 0.0, np.maximum((v + a * a / (2.0 * jerk) - peak * peak / jerk) / peak, 0.0), 0.0)
    t3 = peak / jerk
    v1 = v + a * t1 - jerk * t1 * t1 / 2.0
    p1 = v * t1 + a * t1 * t1 / 2.0 - jerk * t1**3 / 6.0
    v2 = v1 - peak * t2
    p2 = v1 * t2 - peak * t2 * t2 / 2.0
    p3 = v2 * t3 - peak * t3 * t3 / 2.0 + jerk * t3**3 / 6.0
    travel = (p1 + p2 + p3) * sign
    if not np.all(valid):
        zero = np.zeros_like(v0)
        slow = run_up(v0, a0, zero, zero, limits=limits)
        travel = np.where(valid, travel, slow)
    return np.where((v0 == 0.0) & (a0 == 0.0), 0.0, travel)


def stop_travel_floats(
    velocity: list[float], acceleration: list[float], max_acceleration: list[float], max_jerk: list[float]
) -> list[float] | None:
    """:func:`stop_travel` on floats, joint by joint (a segment start runs it for every moving
    controller of a fleet): the same operations in the same order on the same IEEE doubles, the
    cubes by numpy's own ``power`` (which is not libm's ``pow`` everywhere), so the same numbers.
    None when :func:`stop_travel` would leave a joint to ruckig, or for a value that is not finite:
    call it then."""
    n = len(velocity)
    numbers = (*velocity, *acceleration, *max_acceleration, *max_jerk)
    if not all(map(math.isfinite, numbers)):
        return None
    signs, vs, as_, peaks, t1s, t2s, t3s = [], [], [], [], [], [], []
    for v0, a0, max_a, jerk in zip(velocity, acceleration, max_acceleration, max_jerk, strict=True):
        sign = _sign(v0) if v0 != 0.0 else _sign(a0)
        v, a = v0 * sign, a0 * sign
        q = jerk * v + a * a / 2.0
        peak = min(math.sqrt(max(q, 0.0)), max_a)
        if not (a >= -peak and q >= 0.0):
            return None  # braking harder than the profile starts with: ruckig's (stop_travel)
        signs.append(sign)
        vs.append(v)
        as_.append(a)
        peaks.append(peak)
        t1s.append(max((a + peak) / jerk, 0.0))
        t2s.append(max((v + a * a / (2.0 * jerk) - peak * peak / jerk) / peak, 0.0) if peak > 0.0 else 0.0)
        t3s.append(peak / jerk)
    # numpy's power, as stop_travel's t**3, on arrays of the same length (a vector routine may
    # treat a lane by where it falls in the array)
    cubes = (np.array(t1s) ** 3).tolist() + (np.array(t3s) ** 3).tolist()
    travel = []
    for i in range(n):
        v0, a0, jerk = velocity[i], acceleration[i], max_jerk[i]
        if v0 == 0.0 and a0 == 0.0:
            travel.append(0.0)
            continue
        v, a, peak, t1, t2, t3 = vs[i], as_[i], peaks[i], t1s[i], t2s[i], t3s[i]
        v1 = v + a * t1 - jerk * t1 * t1 / 2.0
        p1 = v * t1 + a * t1 * t1 / 2.0 - jerk * cubes[i] / 6.0
        v2 = v1 - peak * t2
        p2 = v1 * t2 - peak * t2 * t2 / 2.0
        p3 = v2 * t3 - peak * t3 * t3 / 2.0 + jerk * cubes[n + i] / 6.0
        travel.append((p1 + p2 + p3) * signs[i])
    if not all(map(math.isfinite, travel)):
        return None
    return travel


def _sign(x: float) -> float:
    """``np.sign`` of a finite float."""
    return 1.0 if x > 0.0 else -1.0 if x < 0.0 else 0.0


def _phase_end(phase: _Phase) -> tuple[float, float, float]:
    """The acceleration, velocity and position a phase ends with."""
    t, j, a, v, p = phase
    return a + j * t, v + (a + j * t / 2.0) * t, p + (v + (a / 2.0 + j * t / 6.0) * t) * t


def _calculate(inp: ruckig.InputParameter) -> ruckig.Trajectory:
    trajectory = ruckig.Trajectory(inp.degrees_of_freedom)
    try:
        result = ruckig.Ruckig(inp.degrees_of_freedom).calculate(inp, trajectory)
    # ruckig raises RuckigError or RuntimeError for input it cannot plan, and ValueError for a
    # result code its Python binding does not know (0.19.4: -101 for durations over 7600 s)
    except ValueError:
        raise PlanningError("ruckig cannot plan this motion (longer than it supports, about 7600 s?)") from None
    except (RuntimeError, ruckig.RuckigError) as exc:
        raise PlanningError(f"ruckig: {exc}") from None
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlanningError(f"ruckig could not plan this motion ({result.name})")
    return trajectory


class PolynomialSegment(Segment):
    """Per joint a polynomial of degree <= 5 in local time: ``coefficients[k, i]`` is h_k of joint i.

    Internally the polynomial is kept in normalised time ``s = t / duration`` (``c_k = h_k T^k``),
    which stays well conditioned for short segments (a 4 ms quintic has h_5 ~ 1e12 in seconds).
    """

    __slots__ = ("_normalised", "bounded_order", "dof", "duration", "kind", "memo")

    def __init__(
        self, coefficients: ArrayLike, duration: float, kind: str = "polynomial", bounded_order: int = 3
    ) -> None:
        h = np.array(coefficients, dtype=float)
        if h.ndim != 2 or not 1 <= h.shape[0] <= 6:
            raise PlanningError(f"polynomial coefficients must be (degree + 1, dof) with degree <= 5, not {h.shape}")
        tf = _duration(duration)
        scale = tf ** np.arange(h.shape[0])[:, None]
        self._setup(h * scale, tf, kind, bounded_order)

    @classmethod
    def normalised(
        cls, coefficients: ArrayLike, duration: float, kind: str, bounded_order: int = 3
    ) -> PolynomialSegment:
        """From coefficients in normalised time ``s = t / duration``."""
        segment = cls.__new__(cls)
        segment._setup(np.array(coefficients, dtype=float), _duration(duration), kind, bounded_order)
        return segment

    @classmethod
    def _from_rows(cls, rows: list[list[float]], duration: float, kind: str, bounded_order: int) -> PolynomialSegment:
        """From normalised coefficients as lists of floats, one per power of ``s`` (at most 6; the
        duration already checked): what the shapes below compute joint by joint."""
        n = len(rows[0])
        normalised = np.array(rows + [[0.0] * n] * (6 - len(rows)), dtype=float)
        # a finite sum has no infinity or NaN in it (a sum that overflows is checked value by value)
        if not math.isfinite(sum(map(sum, rows))) and not np.isfinite(normalised).all():
            raise PlanningError("polynomial coefficients must be finite")
        segment = cls.__new__(cls)
        segment._keep(normalised, duration, kind, bounded_order)
        return segment

    def _setup(self, c: Array, duration: float, kind: str, bounded_order: int) -> None:
        if not np.isfinite(c).all():
            raise PlanningError("polynomial coefficients must be finite")
        normalised = np.zeros((6, c.shape[1]))
        normalised[: c.shape[0]] = c
        self._keep(normalised, duration, kind, bounded_order)

    def _keep(self, normalised: Array, duration: float, kind: str, bounded_order: int) -> None:
        """Take ``normalised``, a new ``(6, dof)`` array in C order of finite numbers, as the coefficients."""
        self._normalised = normalised
        self.duration = duration
        self.dof = normalised.shape[1]
        self.kind = kind
        self.bounded_order = bounded_order
        self.memo: dict[object, object] = {}

    @property
    def _derivatives(self) -> list[Array]:
        """Coefficients of the position and its first four derivatives (computed when first needed:
        a segment planned and never sampled costs nothing more). d/ds sum c_k s^k = sum k c_k
        s^(k-1); each derivative in t adds a factor 1/T. Up to the snap (order 4): the extremes of
        the jerk are where the snap vanishes."""
        found = self.memo.get("derivatives")
        if found is None:
            derivatives = [self._normalised]
            for powers in _POWERS:
                derivatives.append(derivatives[-1][1:] * powers / self.duration)
            found = self.memo["derivatives"] = derivatives
        return found  # type: ignore[return-value]

    @property
    def coefficients(self) -> Array:
        """``(6, dof)``: h_k of each joint, in seconds."""
        return self._normalised / self.duration ** np.arange(6)[:, None]

    def sample(self, t: ArrayLike) -> Samples:
        s = np.clip(np.asarray(t, dtype=float) / self.duration, 0.0, 1.0)[..., None]
        out = []
        for coefficients in self._derivatives[:4]:
            value = np.broadcast_to(coefficients[-1], (*s.shape[:-1], self.dof)).copy()
            for h in coefficients[-2::-1]:
                value = value * s + h
            out.append(value)
        return Samples(*out)

    def state_at(self, t: float) -> tuple[Array, Array, Array]:
        # one time, three derivatives, on plain floats joint by joint: the operations of sample's
        # Horner scheme in the same order (the same numbers, bit for bit), without numpy's cost
        # per call on arrays of six (several times slower here), each joint's polynomial unrolled
        columns: tuple[tuple[tuple[float, ...], ...], ...] | None = self.memo.get("columns")  # type: ignore[assignment]
        if columns is None:
            # tuples: of floats only, the collector stops scanning them after one pass (lists it
            # scans at every collection while the segment lives: a streaming fleet's many segments)
            columns = self.memo["columns"] = tuple(tuple(map(tuple, d.T.tolist())) for d in self._derivatives[:3])
        p_columns, v_columns, a_columns = columns
        s = min(max(t / self.duration, 0.0), 1.0)
        p = [((((c5 * s + c4) * s + c3) * s + c2) * s + c1) * s + c0 for c0, c1, c2, c3, c4, c5 in p_columns]
        v = [(((c4 * s + c3) * s + c2) * s + c1) * s + c0 for c0, c1, c2, c3, c4 in v_columns]
        a = [((c3 * s + c2) * s + c1) * s + c0 for c0, c1, c2, c3 in a_columns]
        return np.array(p), np.array(v), np.array(a)

    def bounds(self, order: int) -> tuple[Array, Array]:
        # the convex hull of the Bezier control points: the curve of degree 5 in s = t / T has
        # control points B c (c: normalised coefficients); its derivatives are Bezier curves whose
        # control points are scaled differences of those (tight: a few per cent off the extremes)
        key = ("bounds", order)
        found = self.memo.get(key)
        if found is None:
            points = self._bezier()
            for _ in range(order):  # np.diff's differences, without its cost per call
                points = points[1:] - points[:-1]
            if order:
                points = points * (_FALLING[order] / self.duration**order)
            found = self.memo[key] = (points.min(axis=0), points.max(axis=0))
        return found  # type: ignore[return-value]

    def _bezier(self) -> Array:
        """``(6, dof)``: the Bezier control points of the position in normalised time."""
        points = self.memo.get("bezier")
        if points is None:
            points = self.memo["bezier"] = _TO_BERNSTEIN @ self._normalised
        return points  # type: ignore[return-value]

    def bound_lists(self, order: int) -> tuple[Sequence[float], Sequence[float]]:
        # orders 0 to 3 at once (the checks ask for all of them), joint by joint on floats:
        # :meth:`bounds`' operations on the same numbers, so the same values, where no difference
        # can overflow (control points within 1e300, no NaN, finite scale factors; else numpy's,
        # whose NaN the checks' comparisons then meet as before). Faster than numpy's dozen calls
        # on arrays of six, the more so between servo ticks, where numpy's code is out of cache.
        # The low and the high values are kept under keys of their own, not as a pair: a pair of
        # tuples stays in the collector's scans while its segment lives (its tuples are still
        # tracked when it is first scanned), and a fleet keeps hundreds of segments queued.
        if order > 3:
            return super().bound_lists(order)
        memo = self.memo
        low = memo.get(_LOW_KEYS[order])
        if low is None:
            if not self._fill_bound_lists():
                return super().bound_lists(order)
            low = memo[_LOW_KEYS[order]]
        return low, memo[_HIGH_KEYS[order]]  # type: ignore[return-value]

    def _fill_bound_lists(self) -> bool:
        duration = self.duration
        k1, k2, k3 = (_FALLING[order] / duration**order for order in (1, 2, 3))
        if not (math.isfinite(k1) and math.isfinite(k2) and math.isfinite(k3)):
            return False
        lo0: list[float] = []
        hi0: list[float] = []
        lo1: list[float] = []
        hi1: list[float] = []
        lo2: list[float] = []
        hi2: list[float] = []
        lo3: list[float] = []
        hi3: list[float] = []
        for b0, b1, b2, b3, b4, b5 in zip(*self._bezier().tolist(), strict=True):
            low, high = min(b0, b1, b2, b3, b4, b5), max(b0, b1, b2, b3, b4, b5)
            total = b0 + b1 + b2 + b3 + b4 + b5  # NaN if one is (min and max may pass it over)
            if not (low >= -_SAFE and high <= _SAFE and math.isfinite(total)):
                return False
            lo0.append(low)
            hi0.append(high)
            d0, d1, d2, d3, d4 = b1 - b0, b2 - b1, b3 - b2, b4 - b3, b5 - b4
            x0, x1, x2, x3, x4 = d0 * k1, d1 * k1, d2 * k1, d3 * k1, d4 * k1
            lo1.append(min(x0, x1, x2, x3, x4))
            hi1.append(max(x0, x1, x2, x3, x4))
            d0, d1, d2, d3 = d1 - d0, d2 - d1, d3 - d2, d4 - d3
            x0, x1, x2, x3 = d0 * k2, d1 * k2, d2 * k2, d3 * k2
            lo2.append(min(x0, x1, x2, x3))
            hi2.append(max(x0, x1, x2, x3))
            d0, d1, d2 = d1 - d0, d2 - d1, d3 - d2
            x0, x1, x2 = d0 * k3, d1 * k3, d2 * k3
            lo3.append(min(x0, x1, x2))
            hi3.append(max(x0, x1, x2))
        memo = self.memo  # kept as tuples: of floats only, the collector stops scanning them after one pass
        for order, low, high in ((0, lo0, hi0), (1, lo1, hi1), (2, lo2, hi2), (3, lo3, hi3)):
            memo[_LOW_KEYS[order]] = tuple(low)
            memo[_HIGH_KEYS[order]] = tuple(high)
        return True

    def extremes(self, order: int) -> tuple[Array, Array]:
        key = ("extremes", order)
        found = self.memo.get(key)
        if found is None:
            found = self.memo[key] = self._extremes(order)
        return found  # type: ignore[return-value]

    def _extremes(self, order: int) -> tuple[Array, Array]:
        coefficients = self._derivatives[order]
        # at both ends: what :meth:`sample` computes there (its normalised times are 0 and T / T = 1,
        # exactly), for this derivative only
        ends = coefficients[-1] * _ENDS + coefficients[-2]
        for h in coefficients[-3::-1]:
            ends = ends * _ENDS + h
        lo, hi = ends.min(axis=0), ends.max(axis=0)
        # inside, the extremes are where the next derivative vanishes: its real roots in (0, 1)
        roots = _unit_roots(self._derivatives[order + 1] * self.duration)
        if roots.shape[1]:
            values = np.zeros_like(roots)
            for h in coefficients[::-1]:
                values = values * roots + h[:, None]
            lo = np.minimum(lo, values.min(axis=1))
            hi = np.maximum(hi, values.max(axis=1))
        return lo, hi

    def __repr__(self) -> str:
        return f"PolynomialSegment(kind={self.kind!r}, duration={self.duration!r}, dof={self.dof})"


def _bernstein_matrix(degree: int) -> Array:
    """Power basis in s to Bernstein basis on [0, 1]: ``b_j = sum_{k<=j} C(j, k) / C(n, k) c_k``."""
    matrix = np.zeros((degree + 1, degree + 1))
    for j in range(degree + 1):
        for k in range(j + 1):
            matrix[j, k] = math.comb(j, k) / math.comb(degree, k)
    return matrix


_TO_BERNSTEIN = _bernstein_matrix(5)
#: the ends of a segment in normalised time, as :meth:`PolynomialSegment.sample` broadcasts them
_ENDS = np.array([[0.0], [1.0]])
#: the powers each derivative of the normalised coefficients multiplies by: 1..5, 1..4, 1..3, 1..2
_POWERS = [np.arange(1, n)[:, None] for n in (6, 5, 4, 3)]
#: control points within this bound (and not NaN): their differences up to the third cannot overflow
_SAFE = 1e300
#: the memo keys of a polynomial segment's bound lists per order (low and high values apart)
_LOW_KEYS = tuple(("bound lows", order) for order in range(4))
_HIGH_KEYS = tuple(("bound highs", order) for order in range(4))
#: the k-th derivative of a degree-5 Bezier curve scales the k-th differences by 5!/(5-k)!
_FALLING = (1.0, 5.0, 20.0, 60.0, 120.0)


def _unit_roots(slope: Array) -> Array:
    """``(dof, k)``: per joint the real roots in [0, 1] of ``sum_k slope[k] s^k`` (padded with 0,
    an end point, so the caller may evaluate them all). Joints sharing the full degree are solved
    together as companion-matrix eigenvalues."""
    degree = slope.shape[0] - 1
    while degree > 0 and not slope[degree].any():
        degree -= 1
    dof = slope.shape[1]
    if degree == 0:
        return np.zeros((dof, 0))
    found = np.zeros((dof, degree), dtype=complex)
    lead = slope[degree]
    scale = np.abs(slope[: degree + 1]).max(axis=0)
    full = np.abs(lead) > 1e-12 * scale
    if full.any():
        companion = np.repeat(_companion(degree)[None], int(full.sum()), axis=0)
        companion[:, :, -1] = -(slope[:degree, full] / lead[full]).T
        found[full] = np.linalg.eigvals(companion)
    for joint in np.flatnonzero(~full):  # lower degree for this joint (or no motion at all)
        column = np.trim_zeros(slope[: degree + 1, joint], "b")
        if column.size >= 2:
            r = np.polynomial.polynomial.polyroots(column)
            found[joint, : r.size] = r
    real = found.real
    usable = (np.abs(found.imag) <= 1e-9) & (real > 0.0) & (real < 1.0)
    return np.where(usable, real, 0.0)


@functools.cache
def _companion(degree: int) -> Array:
    """The companion matrix of a monic polynomial of ``degree`` but its last column (ones below the
    diagonal; read only, copied for use)."""
    matrix = np.zeros((degree, degree))
    matrix[np.arange(1, degree), np.arange(degree - 1)] = 1.0
    matrix.flags.writeable = False
    return matrix


def hold(position: ArrayLike, duration: float) -> PolynomialSegment:
    """Stand still at ``position``."""
    p = _floats(position, "position")
    return PolynomialSegment._from_rows([p], _duration(duration), "hold", 3)


# The shapes below compute their coefficients joint by joint on floats: the operations numpy would
# make on the arrays, in the same order (the same numbers), without its cost per call on arrays of
# six (a segment is built for every planned point).


def linear(start: ArrayLike, end: ArrayLike, duration: float) -> PolynomialSegment:
    """Constant velocity from ``start`` to ``end``: the velocity steps at every join."""
    p0 = _floats(start, "start")
    delta = [q1 - q0 for q0, q1 in zip(p0, _floats(end, "end", len(p0)), strict=True)]
    return PolynomialSegment._from_rows([p0, delta], _duration(duration), "linear", 1)


def cubic(start: ArrayLike, end: ArrayLike, duration: float) -> PolynomialSegment:
    """The rest-to-rest cubic: ``h0 = p0, h1 = 0, h2 = 3 D / T^2, h3 = -2 D / T^3`` (D = end - start).

    Derivation: p(t) = h0 + h1 t + h2 t^2 + h3 t^3 with p(0) = p0 and p'(0) = 0 gives h0 = p0,
    h1 = 0. At T: h2 T^2 + h3 T^3 = D and 2 h2 T + 3 h3 T^2 = 0, so h3 = -2 h2 / (3 T), and then
    h2 T^2 / 3 = D: h2 = 3 D / T^2, h3 = -2 D / T^3.

    The paper (its eq. 5) prints h0 = 0 and h2 = -3 D / T^2. Those coefficients reach p(T) = -5 D
    (from 0) with a velocity of -12 D / T at the end: they meet neither boundary condition
    (docs/reference/motion.md §4). These are the correct ones. The acceleration steps from 0 to 6 D / T^2 at both
    ends, which is the jitter that the quintic removes.
    """
    p0 = _floats(start, "start")
    delta = [q1 - q0 for q0, q1 in zip(p0, _floats(end, "end", len(p0)), strict=True)]
    rows = [p0, [0.0] * len(p0), [3.0 * d for d in delta], [-2.0 * d for d in delta]]
    return PolynomialSegment._from_rows(rows, _duration(duration), "cubic", 2)


def cubic_hermite(
    start: ArrayLike, start_velocity: ArrayLike, end: ArrayLike, end_velocity: ArrayLike, duration: float
) -> PolynomialSegment:
    """The cubic through two positions with two boundary velocities (what ros2_control's joint
    trajectory controller and MotoROS run): ``h0 = p0, h1 = v0, h2 = (3 D - (2 v0 + v1) T) / T^2,
    h3 = (-2 D + (v0 + v1) T) / T^3``, from p(T) = p1 and p'(T) = v1. With v0 = v1 = 0 it is
    :func:`cubic`."""
    p0 = _floats(start, "start")
    n = len(p0)
    v0, v1 = _floats(start_velocity, "start velocity", n), _floats(end_velocity, "end velocity", n)
    p1 = _floats(end, "end", n)
    tf = _duration(duration)
    c1, c2, c3 = [], [], []
    for q0, u0, q1, u1 in zip(p0, v0, p1, v1, strict=True):
        delta = q1 - q0
        c1.append(u0 * tf)
        c2.append(3.0 * delta - (2.0 * u0 + u1) * tf)  # = h2 T^2
        c3.append(-2.0 * delta + (u0 + u1) * tf)  # = h3 T^3
    return PolynomialSegment._from_rows([p0, c1, c2, c3], tf, "cubic", 2)


def quintic(start: ArrayLike, end: ArrayLike, duration: float) -> PolynomialSegment:
    """The rest-to-rest quintic of the paper (eq. 6-10): ``h0 = p0, h1 = h2 = 0, h3 = 10 D / T^3,
    h4 = -15 D / T^4, h5 = 6 D / T^5``; zero velocity and acceleration at both ends."""
    p0 = _vector(start, "start")
    zero = np.zeros_like(p0)
    return quintic_hermite((p0, zero, zero), (end, zero, zero), duration)


def quintic_hermite(
    start: tuple[ArrayLike, ArrayLike, ArrayLike], end: tuple[ArrayLike, ArrayLike, ArrayLike], duration: float
) -> PolynomialSegment:
    """The quintic between two states ``(position, velocity, acceleration)``: ``h0 = p0, h1 = v0,
    h2 = a0 / 2``, ``h3 = (20 D - (8 v1 + 12 v0) T - (3 a0 - a1) T^2) / (2 T^3)``,
    ``h4 = (-30 D + (14 v1 + 16 v0) T + (3 a0 - 2 a1) T^2) / (2 T^4)``,
    ``h5 = (12 D - 6 (v1 + v0) T - (a0 - a1) T^2) / (2 T^5)``.

    These solve p(T) = p1, p'(T) = v1, p''(T) = a1 for h3..h5, as docs/reference/motion.md §4
    gives them (its erratum: the fact sheet it replaces printed h5's acceleration term as
    ``- (af - a0) T^2``, which misses p(T) by ``(a0 - a1) T^2`` whenever the boundary accelerations
    differ; the tests check all six boundary conditions).
    """
    p0 = _floats(start[0], "start")
    n = len(p0)
    v0, a0 = _floats(start[1], "start velocity", n), _floats(start[2], "start acceleration", n)
    v1, a1 = _floats(end[1], "end velocity", n), _floats(end[2], "end acceleration", n)
    p1 = _floats(end[0], "end", n)
    tf = _duration(duration)
    t2 = tf * tf
    c1, c2, c3, c4, c5 = [], [], [], [], []
    for q0, u0, b0, q1, u1, b1 in zip(p0, v0, a0, p1, v1, a1, strict=True):
        delta = q1 - q0
        c1.append(u0 * tf)
        c2.append(b0 * t2 / 2.0)
        c3.append((20.0 * delta - (8.0 * u1 + 12.0 * u0) * tf - (3.0 * b0 - b1) * t2) / 2.0)  # = h3 T^3
        c4.append((-30.0 * delta + (14.0 * u1 + 16.0 * u0) * tf + (3.0 * b0 - 2.0 * b1) * t2) / 2.0)
        c5.append((12.0 * delta - 6.0 * (u1 + u0) * tf - (b0 - b1) * t2) / 2.0)
    return PolynomialSegment._from_rows([p0, c1, c2, c3, c4, c5], tf, "quintic", 3)


def launch(
    start: ArrayLike,
    end: tuple[ArrayLike, ArrayLike, ArrayLike],
    duration: float,
    jerk: ArrayLike,
    *,
    max_share: float = 0.25,
) -> Segment | None:
    """From rest at ``start`` to the state ``end`` as a plan starts: with an acceleration.

    Of the quintics from rest to ``end`` whose start acceleration is free, the one with the least
    integral of the squared jerk has zero jerk at the start (the natural boundary condition of that
    variational problem) and starts with ``a0 = (20 D - 8 v1 T + a1 T^2) / (3 T^2)`` (from
    p(T) = p1, p'(T) = v1, p''(T) = a1 with h3 = 0). A plan that starts with a constant acceleration
    (a time-optimal planner's: they step the acceleration at the start) is followed exactly, where
    the quintic from rest at zero acceleration starts as t^3 and lags it. In normalised form the
    segment is monotone under the same condition as that quintic (``a0`` has the sign of the move
    exactly when its start jerk has).

    The robot cannot step its acceleration: a constant-jerk ramp at the jerk limit (one ramp time
    for all joints, the slowest one's) brings it from rest to ``a0``, and the quintic from the
    state the ramp ends in reaches ``end`` over the rest of ``duration``. None when that ramp would
    take more than ``max_share`` of ``duration`` (the start is then no step at this time scale).
    """
    p0 = _vector(start, "start")
    n = p0.size
    v1, a1 = _vector(end[1], "end velocity", n), _vector(end[2], "end acceleration", n)
    delta = _vector(end[0], "end", n) - p0
    tf = _duration(duration)
    a0 = (20.0 * delta - 8.0 * v1 * tf + a1 * tf * tf) / (3.0 * tf * tf)
    limit = _vector(jerk, "jerk", n)
    ramp = float(np.max(np.abs(a0) / limit))
    if not math.isfinite(ramp) or ramp > max_share * tf:
        return None
    zero = np.zeros(n)
    if ramp <= _SHORTEST_RAMP * tf:  # no acceleration to speak of: the quintic from rest
        return quintic_hermite((p0, zero, zero), end, tf)
    up = PolynomialSegment.normalised([p0, zero, zero, a0 * ramp * ramp / 6.0], ramp, "ramp", 3)
    ramped = up.state_at(up.duration)  # what up.end() gives, without sampling the jerk too
    return Chain((up, quintic_hermite(ramped, end, tf - ramp)), "launch")


def _hull(ranges: list[tuple[Array, Array]]) -> tuple[Array, Array]:
    # np.min/np.max over the stacked parts, one part after the other, without the stacking
    return functools.reduce(np.minimum, [lo for lo, _ in ranges]), functools.reduce(
        np.maximum, [hi for _, hi in ranges]
    )


#: a launch ramp shorter than this share of its segment is no ramp (rounding noise)
_SHORTEST_RAMP = 1e-9


class Chain(Segment):
    """Segments run one after the other (each from the state the previous one ends in)."""

    __slots__ = ("_offsets", "bounded_order", "dof", "duration", "kind", "memo", "parts")

    def __init__(self, parts: tuple[Segment, ...], kind: str = "chain") -> None:
        if not parts or len({p.dof for p in parts}) != 1:
            raise PlanningError("a chain needs segments of the same number of joints")
        self.parts = parts
        self._offsets = np.cumsum([0.0, *(p.duration for p in parts)])
        self.duration = float(self._offsets[-1])
        self.dof = parts[0].dof
        self.kind = kind
        self.bounded_order = min(p.bounded_order for p in parts)
        self.memo: dict[object, object] = {}

    def sample(self, t: ArrayLike) -> Samples:
        times = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        which = np.clip(np.searchsorted(self._offsets, times, side="right") - 1, 0, len(self.parts) - 1)
        if times.ndim == 0:
            i = int(which)
            return self.parts[i].sample(times - self._offsets[i])
        flat, which = times.reshape(-1), which.reshape(-1)
        out = [np.zeros((flat.size, self.dof)) for _ in range(4)]
        for i, part in enumerate(self.parts):
            mask = which == i
            if np.any(mask):
                for values, part_values in zip(out, part.sample(flat[mask] - self._offsets[i]), strict=True):
                    values[mask] = part_values
        return Samples(*(values.reshape(*times.shape, self.dof) for values in out))

    def extremes(self, order: int) -> tuple[Array, Array]:
        key = ("extremes", order)
        found = self.memo.get(key)
        if found is None:
            found = self.memo[key] = _hull([p.extremes(order) for p in self.parts])
        return found  # type: ignore[return-value]

    def bounds(self, order: int) -> tuple[Array, Array]:
        key = ("bounds", order)
        found = self.memo.get(key)
        if found is None:
            found = self.memo[key] = _hull([p.bounds(order) for p in self.parts])
        return found  # type: ignore[return-value]

    def bound_lists(self, order: int) -> tuple[Sequence[float], Sequence[float]]:
        # the parts' lists, combined as _hull combines their arrays (np.minimum and np.maximum
        # choose the first of two values when it is NaN)
        # (kept as tuples of floats under keys of their own, as a polynomial segment keeps its own)
        low_key, high_key = ("bound lows", order), ("bound highs", order)
        found = self.memo.get(low_key)
        if found is None:
            ranges = [p.bound_lists(order) for p in self.parts]
            lo, hi = ranges[0]
            for low, high in ranges[1:]:
                lo = [x if x < y or math.isnan(x) else y for x, y in zip(lo, low, strict=True)]
                hi = [x if x > y or math.isnan(x) else y for x, y in zip(hi, high, strict=True)]
            found = self.memo[low_key] = tuple(lo)
            self.memo[high_key] = tuple(hi)
        return found, self.memo[high_key]  # type: ignore[return-value]

    def __repr__(self) -> str:
        return f"Chain(kind={self.kind!r}, duration={self.duration!r}, parts={list(self.parts)!r})"


class RuckigSegment(Segment):
    """A time-optimal, jerk-limited state-to-state motion computed offline by ruckig.

    **Public API** of :mod:`robot_server.control` (import it from there): the controller's
    ``ruckig`` policy and stops use it, and so may planners (the client's planner times its paths
    with it). Built with :meth:`plan`; once built it is an immutable value. It guarantees:

    * it starts exactly in the ``start`` state and ends exactly in the ``target`` state (position,
      velocity, acceleration per joint; with ``velocity_interface`` the target position is free);
    * every joint stays within ``max_velocity``, ``max_acceleration`` and ``max_jerk`` throughout
      when the start state is within them (one beyond them is first braked back within them at
      the jerk limit, ruckig's brake profile);
    * all joints finish together at :attr:`duration`: the least time in which the slowest joint
      can make its motion (and at least ``minimum_duration``);
    * :meth:`sample` evaluates ruckig's own piecewise-constant-jerk profiles exactly (an optional
      two-phase brake, then seven phases per joint), vectorised; times outside
      ``[0, duration]`` give the end states (:class:`Segment`); :meth:`extremes` are exact;
    * inputs it cannot plan (non-finite values, a target beyond the limits, a motion longer than
      ruckig supports) raise :class:`PlanningError`, never ruckig's own exceptions.

    Position limits are not enforced (the PyPI build of ruckig ignores them): check
    :meth:`extremes` (order 0).
    """

    __slots__ = (
        "_a",
        "_jerk",
        "_p",
        "_starts",
        "_v",
        "bounded_order",
        "dof",
        "duration",
        "kind",
        "memo",
        "trajectory",
    )

    def __init__(self, trajectory: ruckig.Trajectory, dof: int) -> None:
        self.kind = "ruckig"
        self.bounded_order = 3
        self.memo: dict[object, object] = {}
        self.trajectory = trajectory
        self.dof = dof
        self.duration = float(trajectory.duration)
        table = []
        for profiles in trajectory.profiles[0]:
            phases = _phases(profiles)
            # every joint gets as many phases: pad in front with empty ones holding the start state
            # (never selected, since the next phase starts at the same time)
            table.append([(0.0, 0.0, *phases[0][2:])] * (_PHASES - len(phases)) + phases)
        # (dof, _PHASES, 5): duration, jerk, acceleration, velocity, position; each joint's starts
        # are the running sums of its durations (np.cumsum adds along a row one after the other)
        columns = np.array(table).transpose(2, 0, 1)
        starts = np.zeros((len(table), _PHASES))
        starts[:, 1:] = np.cumsum(columns[0], axis=1)[:, :-1]
        self._starts = starts  # (dof, _PHASES)
        self._jerk, self._a, self._v, self._p = (np.ascontiguousarray(x) for x in columns[1:])

    @classmethod
    def plan(
        cls,
        start: tuple[ArrayLike, ArrayLike, ArrayLike],
        target: tuple[ArrayLike, ArrayLike, ArrayLike],
        max_velocity: ArrayLike,
        max_acceleration: ArrayLike,
        max_jerk: ArrayLike,
        *,
        minimum_duration: float | None = None,
        velocity_interface: bool = False,
    ) -> RuckigSegment:
        """From ``start`` to ``target`` (each ``(position, velocity, acceleration)``), all joints
        finishing together (time synchronisation). With ``velocity_interface`` only the target
        velocity and acceleration count (a stop: ``target`` velocity and acceleration 0)."""
        p0 = _floats(start[0], "start position")
        n = len(p0)
        lists = [p0, *(_floats(x, "start state", n) for x in start[1:])]
        lists += [_floats(x, "target state", n) for x in target]
        lists += [_floats(x, "limit", n) for x in (max_velocity, max_acceleration, max_jerk)]
        if not all(math.isfinite(x) for values in lists for x in values):
            raise PlanningError("ruckig inputs must be finite")
        inp = ruckig.InputParameter(n)
        inp.current_position, inp.current_velocity, inp.current_acceleration = lists[:3]
        inp.target_position, inp.target_velocity, inp.target_acceleration = lists[3:6]
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = lists[6:]
        if velocity_interface:
            inp.control_interface = ruckig.ControlInterface.Velocity
        if minimum_duration is not None:
            inp.minimum_duration = float(minimum_duration)
        return cls(_calculate(inp), n)

    def sample(self, t: ArrayLike) -> Samples:
        times = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        flat = times.reshape(-1)
        # per joint: the phase each time falls in, then the cubic of constant jerk from its start
        index = np.empty((flat.size, self.dof), dtype=np.intp)
        for joint in range(self.dof):
            index[:, joint] = np.searchsorted(self._starts[joint], flat, side="right") - 1
        cols = np.arange(self.dof)
        dt = flat[:, None] - self._starts[cols, index]
        j, a, v, p = self._jerk[cols, index], self._a[cols, index], self._v[cols, index], self._p[cols, index]
        acc = a + j * dt
        vel = v + (a + j * dt / 2.0) * dt
        pos = p + (v + (a / 2.0 + j * dt / 6.0) * dt) * dt
        shape = (*times.shape, self.dof)
        return Samples(pos.reshape(shape), vel.reshape(shape), acc.reshape(shape), j.reshape(shape))

    def state_at(self, t: float) -> tuple[Array, Array, Array]:
        # one time on plain floats joint by joint: sample's operations in the same order (the same
        # numbers, bit for bit; bisect_right finds the phase as searchsorted(side="right") does)
        rows = self.memo.get("rows")
        if rows is None:
            rows = self.memo["rows"] = [
                (self._starts[i].tolist(), self._jerk[i].tolist(), self._a[i].tolist(), self._v[i].tolist(),
                 self._p[i].tolist())
                for i in range(self.dof)
            ]  # fmt: skip
        t = min(max(float(t), 0.0), self.duration)
        pos, vel, acc = [], [], []
        for starts, jerks, accs, vels, poss in rows:  # type: ignore[attr-defined]
            k = bisect.bisect_right(starts, t) - 1
            dt = t - starts[k]
            j, a, v = jerks[k], accs[k], vels[k]
            acc.append(a + j * dt)
            vel.append(v + (a + j * dt / 2.0) * dt)
            pos.append(poss[k] + (v + (a / 2.0 + j * dt / 6.0) * dt) * dt)
        return np.array(pos), np.array(vel), np.array(acc)

    def _values(self, t: Array, order: int) -> Array:
        """:meth:`sample`'s position, velocity or acceleration (``order`` 0 to 2) at the times
        ``t`` (one axis), computed alone: the same operations for that one."""
        times = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        flat = times.reshape(-1)
        index = np.empty((flat.size, self.dof), dtype=np.intp)
        for joint in range(self.dof):
            index[:, joint] = np.searchsorted(self._starts[joint], flat, side="right") - 1
        cols = np.arange(self.dof)
        dt = flat[:, None] - self._starts[cols, index]
        j, a = self._jerk[cols, index], self._a[cols, index]
        if order == 2:
            values: Array = a + j * dt
        elif order == 1:
            values = self._v[cols, index] + (a + j * dt / 2.0) * dt
        else:
            values = self._p[cols, index] + (self._v[cols, index] + (a / 2.0 + j * dt / 6.0) * dt) * dt
        return values.reshape(*times.shape, self.dof)

    def extremes(self, order: int) -> tuple[Array, Array]:
        key = ("extremes", order)
        found = self.memo.get(key)
        if found is None:
            found = self.memo[key] = self._extremes(order)
        return found  # type: ignore[return-value]

    def _extremes(self, order: int) -> tuple[Array, Array]:
        if order == 3:  # constant in each phase: the phases that last
            lasting = np.diff(np.concatenate([self._starts, np.full((self.dof, 1), self.duration)], axis=1)) > 0.0
            jerk = np.where(lasting, self._jerk, 0.0)
            return jerk.min(axis=1), jerk.max(axis=1)
        # Inside a phase the position is extreme where the velocity (quadratic in time) crosses 0,
        # the velocity where the acceleration (linear) does; the acceleration is extreme at phase
        # boundaries. Evaluate at every boundary and every such crossing (ruckig's own
        # position_extrema misses the brake phase, so positions are found the same way).
        times: list[Array] = [self._starts.reshape(-1), np.array([self.duration])]
        with np.errstate(divide="ignore", invalid="ignore"):
            if order == 1:
                zero = self._starts - self._a / self._jerk
                times.append(zero[np.isfinite(zero)])
            elif order == 0:
                half_j, a, v = self._jerk / 2.0, self._a, self._v
                root = np.sqrt(np.maximum(a * a - 4.0 * half_j * v, 0.0))
                for dt in ((-a + root) / (2.0 * half_j), (-a - root) / (2.0 * half_j), -v / a):
                    zero = self._starts + dt
                    times.append(zero[np.isfinite(zero)])
        candidates: Array = np.clip(np.concatenate(times), 0.0, self.duration)
        values = self._values(candidates, order)
        return values.min(axis=0), values.max(axis=0)

    def __repr__(self) -> str:
        return f"RuckigSegment(duration={self.duration!r}, dof={self.dof})"
