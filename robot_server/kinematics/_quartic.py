"""Real roots of a trigonometric quadratic: the one step of closed-form IK that is not a fixed
sequence of arithmetic (the general position case, see :mod:`.ik`).

Written once against an ``ops`` namespace (:class:`._ops.Ops`: cos, sin, atan2, where) and plain
operators, so the same code runs on floats (``complex`` for the intermediate roots) and on numpy
arrays. It is not traced: generated code calls it through ``ops.quartic``. Its values are floats,
complex numbers or arrays of either, which no type short of ``Any`` describes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Generic, NamedTuple, TypeVar

import numpy as np

if TYPE_CHECKING:
    from ._ops import Ops

__all__ = ["TrigRoot", "trig_quadratic_roots"]

V = TypeVar("V")


class TrigRoot(NamedTuple, Generic[V]):
    """One of the four roots of :func:`trig_quadratic_roots` (floats for one pose, arrays for a
    batch, placeholders while tracing)."""

    angle: float | V
    #: nearly real, and F vanishes there to ``QUARTIC_TOL``
    valid: bool | V
    #: a double root (F' vanishes there too): two branches meet
    double: bool | V


#: accepted |F| (m^2) at a polished root
QUARTIC_TOL = 1e-13
# tan-half-angle sample points and the inverse Vandermonde that turns samples into coefficients
_T_SAMPLES = (-2.0, -1.0, 0.0, 1.0, 2.0)
_VANDER_INV = np.linalg.inv(np.vander(np.array(_T_SAMPLES), 5)).tolist()
_SHIFTS = (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi)
_OMEGA = (1.0 + 0j, complex(-0.5, math.sqrt(3) / 2), complex(-0.5, -math.sqrt(3) / 2))
_TINY = 1e-300


def _cubic_largest_root(ops: Ops[Any], a: Any, b: Any, c: Any) -> Any:
    """The root of largest modulus of z^3 + a z^2 + b z + c (complex), by Cardano."""
    p = b - a * a / 3.0
    q = 2.0 * a * a * a / 27.0 - a * b / 3.0 + c
    root = (q * q / 4.0 + p * p * p / 27.0 + 0j) ** 0.5
    u1 = (-q / 2.0 + root) ** (1.0 / 3.0)
    u2 = (-q / 2.0 - root) ** (1.0 / 3.0)
    u = ops.where(abs(u1) >= abs(u2), u1, u2)
    u_safe = ops.where(abs(u) > _TINY, u, 1.0)
    best = 0.0 * u
    for w in _OMEGA:
        z = ops.where(abs(u) > _TINY, w * u - p / (3.0 * w * u_safe), 0.0) - a / 3.0
        best = ops.where(abs(z) > abs(best), z, best)
    return best


def _quartic_roots(ops: Ops[Any], *coefficients: Any) -> list[Any]:
    """The four complex roots of e4 t^4 + e3 t^3 + e2 t^2 + e1 t + e0 (e4 != 0), by Ferrari."""
    e4, e3, e2, e1, e0 = coefficients
    lead = ops.where(abs(e4) > _TINY, e4, _TINY)
    a, b, c, d = e3 / lead, e2 / lead, e1 / lead, e0 / lead
    p = b - 3.0 * a * a / 8.0
    q = c - a * b / 2.0 + a * a * a / 8.0
    r = d - a * c / 4.0 + a * a * b / 16.0 - 3.0 * a * a * a * a / 256.0
    # (y^2 + s y + u)(y^2 - s y + v) with z = s^2 a root of z^3 + 2p z^2 + (p^2 - 4r) z - q^2
    z = _cubic_largest_root(ops, 2.0 * p, p * p - 4.0 * r, -q * q)
    s = (z + 0j) ** 0.5
    s_safe = ops.where(abs(s) > 1e-150, s, 1.0)
    q_over_s = ops.where(abs(s) > 1e-150, q / s_safe, 0.0)
    u = (p + z - q_over_s) / 2.0
    v = (p + z + q_over_s) / 2.0
    d1 = (z - 4.0 * u + 0j) ** 0.5
    d2 = (z - 4.0 * v + 0j) ** 0.5
    shift = a / 4.0
    return [(-s + d1) / 2.0 - shift, (-s - d1) / 2.0 - shift, (s + d2) / 2.0 - shift, (s - d2) / 2.0 - shift]


def trig_quadratic_roots(ops: Ops[Any], *k: Any) -> tuple[TrigRoot[Any], ...]:
    """Roots q of ``F(q) = k0 + k1 c + k2 s + k3 c^2 + k4 s^2 + k5 c s = 0`` (c, s = cos q, sin q):
    four :class:`TrigRoot` (angle, valid, double).

    The substitution ``q = beta + 2 atan(t)`` makes F a quartic in t; beta is chosen so that
    t = infinity is not a root (the quartic's leading coefficient is F(beta + pi)). The quartic's
    roots come from Ferrari's formula and are polished by Newton steps on F itself; a root is valid
    if nearly real and F vanishes there to ``QUARTIC_TOL``.
    """
    k0, k1, k2, k3, k4, k5 = k

    def f(q: Any) -> Any:
        c, s = ops.cos(q), ops.sin(q)
        return k0 + k1 * c + k2 * s + k3 * c * c + k4 * s * s + k5 * c * s

    def df(q: Any) -> Any:
        c, s = ops.cos(q), ops.sin(q)
        return -k1 * s + k2 * c + 2.0 * (k4 - k3) * c * s + k5 * (c * c - s * s)

    beta: Any = 0.0
    largest: Any = -1.0
    for shift in _SHIFTS:
        value = abs(f(shift + math.pi + 0.0 * k0))
        beta = ops.where(value > largest, shift, beta)
        largest = ops.where(value > largest, value, largest)
    samples = [(1.0 + t * t) ** 2 * f(beta + 2.0 * math.atan(t)) for t in _T_SAMPLES]
    coef = [sum(row[j] * samples[j] for j in range(5)) for row in _VANDER_INV]  # highest power first
    angles, valid, double = [], [], []
    for t in _quartic_roots(ops, *coef):
        q = beta + 2.0 * ops.atan2(t.real, 1.0 + 0.0 * t.real)
        for _ in range(4):
            d = df(q)
            big = abs(d) > 1e-14
            q = q - ops.where(big, f(q) / ops.where(big, d, 1.0), 0.0)
        angles.append(q)
        valid.append((abs(t.imag) <= 1e-6 * (1.0 + abs(t))) & (abs(f(q)) <= QUARTIC_TOL))
        double.append(abs(df(q)) < 1e-7)
    return tuple(TrigRoot(a, v, d) for a, v, d in zip(angles, valid, double, strict=True))
