"""Numeric inverse kinematics for any chain: Levenberg-Marquardt with restarts.

Each iteration solves ``(J^T J + lambda I) dq = J^T e`` (as ``dq = J^T (J J^T + lambda I)^-1 e``,
the same step through a 6x6 system) where e stacks the position error (m) and the orientation
error (the rotation vector of ``R_target R^T``, rad), and lambda follows Sugihara's rule
(proportional to ``e^T e`` plus a small bias): large far from the goal, vanishing near it, so the
last iterations are Gauss-Newton steps with quadratic convergence. Steps are capped at 2 rad per
joint. The iterations ignore the position limits: clamping a joint at its limit was the main cause
of stalled attempts (most random targets lie across a limit from a random seed, measured on the
shipped models). The limits are enforced on the result instead: a converged configuration has its
revolute joints moved by multiples of 2 pi into the limits, and if it cannot be, the search goes on
from a new random configuration inside the limits, as it does when an attempt stops improving (the
error falls by less than 2% over six steps) or runs out of iterations.

Tolerances are checked on the true errors, not on a cost: the result is ``success`` only if the
position error is within ``position_tolerance`` (default 1e-6 m) *and* the orientation error
within ``orientation_tolerance`` (default 1e-6 rad). Otherwise it says so and reports the best
configuration found with its residuals.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..model import JointType, RobotModel
from ._trace import SCALAR_OPS
from .fk import _chain

__all__ = ["NumericIKResult", "ik_numeric", "rotation_error"]

# Damping lambda = _DAMPING * |e|^2 + _BIAS (Sugihara's rule, scaled down), and the largest joint
# change per step (rad or m): tuned on the shipped models from random seeds (fewest iterations).
_DAMPING = 0.05
_BIAS = 1e-9
_MAX_STEP = 2.0
#: an attempt restarts when the error has not fallen by 2% over this many iterations
_PATIENCE = 6

try:  # numpy's own gufunc behind np.linalg.solve, without the wrapper's checks (5x faster at 6x6)
    from numpy.linalg import _umath_linalg

    _solve: Any = _umath_linalg.solve1
except (ImportError, AttributeError):  # pragma: no cover - other numpy layouts
    _solve = np.linalg.solve


@dataclass(frozen=True)
class NumericIKResult:
    """The outcome of :func:`ik_numeric`: ``q`` is the best configuration found (the solution if
    ``success``), with its position (m) and orientation (rad) errors."""

    q: tuple[float, ...]
    success: bool
    position_error: float
    orientation_error: float
    iterations: int
    attempts: int


def rotation_error(r: list[list[float]], values: tuple[float, ...] | list[float]) -> tuple[float, float, float]:
    """The rotation vector (axis times angle, rad) of ``R_target R^T``, where ``r`` is R_target and
    R the 3x3 block of the 3x4 row-major ``values``; exact up to pi."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = r
    b00, b01, b02, _, b10, b11, b12, _, b20, b21, b22 = values[:11]
    # E = R_target R^T: e_ij = sum_k a_ik b_jk
    e00 = a00 * b00 + a01 * b01 + a02 * b02
    e11 = a10 * b10 + a11 * b11 + a12 * b12
    e22 = a20 * b20 + a21 * b21 + a22 * b22
    e01 = a00 * b10 + a01 * b11 + a02 * b12
    e10 = a10 * b00 + a11 * b01 + a12 * b02
    e02 = a00 * b20 + a01 * b21 + a02 * b22
    e20 = a20 * b00 + a21 * b01 + a22 * b02
    e12 = a10 * b20 + a11 * b21 + a12 * b22
    e21 = a20 * b10 + a21 * b11 + a22 * b12
    vx, vy, vz = e21 - e12, e02 - e20, e10 - e01
    s = 0.5 * math.sqrt(vx * vx + vy * vy + vz * vz)  # sin(angle)
    c = 0.5 * (e00 + e11 + e22 - 1.0)  # cos(angle)
    angle = math.atan2(s, c)
    if s > 1e-6 or c > 0.0:
        k = 0.5 if s < 1e-12 else angle / (2.0 * s)  # small angles: the vector is v / 2
        return vx * k, vy * k, vz * k
    # near pi: the axis from the symmetric part, E + I = 2 a a^T (sign from the skew part)
    rows = (
        (e00 + 1.0, (e01 + e10) / 2, (e02 + e20) / 2),
        ((e01 + e10) / 2, e11 + 1.0, (e12 + e21) / 2),
        ((e02 + e20) / 2, (e12 + e21) / 2, e22 + 1.0),
    )
    col = max(rows, key=lambda row: row[0] * row[0] + row[1] * row[1] + row[2] * row[2])
    norm = math.sqrt(col[0] * col[0] + col[1] * col[1] + col[2] * col[2])
    sign = -1.0 if col[0] * vx + col[1] * vy + col[2] * vz < 0.0 else 1.0
    k = sign * angle / norm
    return col[0] * k, col[1] * k, col[2] * k


def ik_numeric(
    model: RobotModel,
    pose: ArrayLike,
    seed: ArrayLike | None = None,
    *,
    position_tolerance: float = 1e-6,
    orientation_tolerance: float = 1e-6,
    max_iterations: int = 60,
    attempts: int = 100,
    rng: np.random.Generator | None = None,
) -> NumericIKResult:
    """A configuration reaching ``pose`` (4x4), starting from ``seed`` (default: the middle of
    the limits), then from random configurations; see the module doc."""
    t = np.asarray(pose, dtype=float)
    rows4 = t.tolist() if t.shape == (4, 4) else []
    if not rows4 or not math.isfinite(sum(x for row in rows4 for x in row)):
        raise ValueError(f"a pose is a finite 4x4 homogeneous matrix, not {t.shape} / non-finite")
    terms, lo, hi, revolute = _context(model)
    n = len(lo)
    if seed is None:
        q = [(a + b) / 2.0 for a, b in zip(lo, hi, strict=True)]
    else:
        given = np.asarray(seed, dtype=float).reshape(n).tolist()
        q = [min(b, max(a, x)) for x, a, b in zip(given, lo, hi, strict=True)]
    r_target = [row[:3] for row in rows4[:3]]
    px, py, pz = rows4[0][3], rows4[1][3], rows4[2][3]
    rows = 6 * n
    best: tuple[float, list[float], float, float] = (math.inf, q, math.inf, math.inf)
    total = 0
    for attempt in range(1, attempts + 1):
        history = [math.inf] * _PATIENCE
        for _ in range(max_iterations):
            total += 1
            values = terms(*q, SCALAR_OPS)
            ex, ey, ez = px - values[3], py - values[7], pz - values[11]
            rx, ry, rz = rotation_error(r_target, values)
            pos2 = ex * ex + ey * ey + ez * ez
            ori2 = rx * rx + ry * ry + rz * rz
            cost = pos2 + ori2
            if pos2 <= position_tolerance**2 and ori2 <= orientation_tolerance**2:
                inside = _into_limits(q, lo, hi, revolute)
                if inside is not None:
                    return NumericIKResult(tuple(inside), True, math.sqrt(pos2), math.sqrt(ori2), total, attempt)
                break  # a solution, but outside the limits: look for another
            if cost < best[0]:
                best = (cost, q, math.sqrt(pos2), math.sqrt(ori2))
            if cost > 0.98 * history[-_PATIENCE] and cost > 1e-10:
                break  # not converging from here: restart
            history.append(cost)
            # (J J^T + lambda I) y = e, dq = J^T y: the step of (J^T J + lambda I) dq = J^T e
            packed = np.array((*values[12:], ex, ey, ez, rx, ry, rz))
            jac = packed[:rows].reshape(6, n)
            gram = jac @ jac.T
            gram.flat[::7] += _DAMPING * cost + _BIAS
            step = (_solve(gram, packed[rows:]) @ jac).tolist()
            largest = max(map(abs, step))
            scale = _MAX_STEP / largest if largest > _MAX_STEP else 1.0
            q = [a + scale * d for a, d in zip(q, step, strict=True)]
        if rng is None:
            rng = np.random.default_rng()
        q = [rng.uniform(a, b) for a, b in zip(lo, hi, strict=True)]
    _, q_best, pos, ori = best
    return NumericIKResult(tuple(q_best), False, pos, ori, total, attempts)


_CONTEXTS: weakref.WeakKeyDictionary[RobotModel, tuple[Any, list[float], list[float], list[bool]]] = (
    weakref.WeakKeyDictionary()
)


def _context(model: RobotModel) -> tuple[Any, list[float], list[float], list[bool]]:
    """Per model, once: the generated pose-and-Jacobian function, the limits, which joints turn."""
    context = _CONTEXTS.get(model)
    if context is None:
        revolute = [j.type is JointType.REVOLUTE for j in model.joints]
        context = _CONTEXTS[model] = (_chain(model).jacobian, model.lower.tolist(), model.upper.tolist(), revolute)
    return context


def _into_limits(q: list[float], lo: list[float], hi: list[float], revolute: list[bool]) -> list[float] | None:
    """q with revolute joints moved by multiples of 2 pi into the limits, or None."""
    out = []
    for value, low, high, turn in zip(q, lo, hi, revolute, strict=True):
        if not low <= value <= high:
            if turn:
                value = low + (value - low) % (2.0 * math.pi)
            if not low - 1e-12 <= value <= high + 1e-12:
                return None
            value = min(high, max(low, value))
        out.append(value)
    return out
