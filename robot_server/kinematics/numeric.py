"""Numeric inverse kinematics for any chain: Levenberg-Marquardt with restarts.

Each iteration solves ``(J^T J + lambda I) dq = J^T e`` where e stacks the position error (m) and
the orientation error (the rotation vector of ``R_target R^T``, rad), and lambda follows
Sugihara's rule (proportional to ``e^T e`` plus a small bias): large far from the goal, vanishing
near it, so the last iterations are Gauss-Newton steps with quadratic convergence. Steps are capped
at 0.5 rad per joint. An attempt that stops improving (the error falls by less than 2% over four steps)
or runs out of iterations restarts from a random configuration inside the limits. A converged
configuration has its revolute joints moved by multiples of 2 pi into the limits; if it cannot be,
the search goes on.

Tolerances are checked on the true errors, not on a cost: the result is ``success`` only if the
position error is within ``position_tolerance`` (default 1e-6 m) *and* the orientation error
within ``orientation_tolerance`` (default 1e-6 rad). Otherwise it says so and reports the best
configuration found with its residuals.
"""

from __future__ import annotations

import math
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
_MAX_STEP = 0.5
#: an attempt restarts when the error has not fallen by 2% over this many iterations
_PATIENCE = 4

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
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise ValueError(f"a pose is a finite 4x4 homogeneous matrix, not {t.shape}")
    n = model.dof
    lower, upper = model.lower, model.upper
    lo, hi = lower.tolist(), upper.tolist()
    if seed is None:
        q = ((lower + upper) / 2.0).tolist()
    else:
        q = np.clip(np.asarray(seed, dtype=float).reshape(n), lower, upper).tolist()
    rng = rng if rng is not None else np.random.default_rng()
    r_target = t[:3, :3].tolist()
    p_target = t[:3, 3].tolist()
    terms = _chain(model).jacobian
    revolute = [j.type is JointType.REVOLUTE for j in model.joints]
    best: tuple[float, list[float], float, float] = (math.inf, q, math.inf, math.inf)
    total = 0

    def evaluate(q: list[float]) -> tuple[float, float, float, tuple[float, ...], tuple[float, ...]]:
        values = terms(*q, SCALAR_OPS)
        ep = (p_target[0] - values[3], p_target[1] - values[7], p_target[2] - values[11])
        eo = rotation_error(r_target, values)
        pos = math.sqrt(ep[0] * ep[0] + ep[1] * ep[1] + ep[2] * ep[2])
        ori = math.sqrt(eo[0] * eo[0] + eo[1] * eo[1] + eo[2] * eo[2])
        return pos * pos + ori * ori, pos, ori, ep + eo, values

    for attempt in range(1, attempts + 1):
        history = [math.inf] * _PATIENCE
        for _ in range(max_iterations):
            total += 1
            cost, pos, ori, err, values = evaluate(q)
            if pos <= position_tolerance and ori <= orientation_tolerance:
                inside = _into_limits(q, lo, hi, revolute)
                if inside is not None:
                    return NumericIKResult(tuple(inside), True, pos, ori, total, attempt)
                break  # a solution, but outside the limits: look for another
            if cost < best[0]:
                best = (cost, q, pos, ori)
            if cost > 0.98 * history[-_PATIENCE] and cost > 1e-10:
                break  # not converging from here: restart
            history.append(cost)
            jac = np.array(values[12:]).reshape(6, n)
            normal = jac.T @ jac
            normal.flat[:: n + 1] += _DAMPING * cost + _BIAS
            step = _solve(normal, jac.T @ np.array(err))
            largest = max(abs(float(d)) for d in step)
            scale = _MAX_STEP / largest if largest > _MAX_STEP else 1.0
            q = [min(high, max(low, a + scale * d)) for a, d, low, high in zip(q, step.tolist(), lo, hi, strict=True)]
        q = rng.uniform(lower, upper).tolist()
    _, q_best, pos, ori = best
    return NumericIKResult(tuple(q_best), False, pos, ori, total, attempts)


def _into_limits(q: list[float], lo: list[float], hi: list[float], revolute: list[bool]) -> list[float] | None:
    """q with revolute joints moved by multiples of 2 pi into the limits, or None."""
    out = []
    for value, low, high, turn in zip(q, lo, hi, revolute, strict=True):
        if turn and not low <= value <= high:
            value = low + (value - low) % (2.0 * math.pi)
        if not low - 1e-12 <= value <= high + 1e-12:
            return None
        out.append(min(high, max(low, value)))
    return out
