"""Numeric inverse kinematics for any chain: Levenberg-Marquardt with restarts.

Each iteration solves ``(J^T J + lambda I) dq = J^T e`` (as ``dq = J^T (J J^T + lambda I)^-1 e``,
the same step through a 6x6 system) where e stacks the position error (m) and the orientation
error (the rotation vector of ``R_target R^T``, rad), and lambda follows Sugihara's rule
(proportional to ``e^T e`` plus a small bias): large far from the goal, vanishing near it, so the
last iterations are Gauss-Newton steps with quadratic convergence. In the steps (not in the
tolerances) a metre of position error weighs 3 / L, L the chain's length: about one iteration
fewer than weighing metres and radians alike, measured on the shipped models. Steps are capped
at 2 rad per joint. The iterations ignore the position limits: clamping a joint at its limit was the main cause
of stalled attempts (most random targets lie across a limit from a random seed, measured on the
shipped models). The limits are enforced on the result instead: a converged configuration has its
revolute joints moved by multiples of 2 pi into the limits, and if it cannot be, the search goes on
from a new random configuration inside the limits, as it does when an attempt stops improving (the
error falls by less than 2% over six steps) or runs out of iterations.

An iteration is one function per model, traced like forward kinematics (:mod:`._trace`): the
pose and Jacobian, the errors, the 6x6 system (an LDL^T factorisation written out) and the capped
step, as straight-line float arithmetic with the model's constants folded in. For a 6-axis arm
that is about 10 us, half of what numpy's small-matrix calls cost for the linear algebra alone.
After a step from very near the goal, the errors are checked first by a second function without
the Jacobian (2 us), which usually ends the search.

Tolerances are checked on the true errors, not on a cost: the result is ``success`` only if the
position error is within ``position_tolerance`` (default 1e-6 m) *and* the orientation error
within ``orientation_tolerance`` (default 1e-6 rad). Otherwise it says so and reports the best
configuration found with its residuals.
"""

from __future__ import annotations

import itertools
import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, NamedTuple, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from ..model import JointType, RobotModel
from ._chain import PoseBlock, chain, pose_and_jacobian
from ._ops import SCALAR_OPS, Ops
from ._trace import TRACE_OPS, Generated, Real, Var
from .fk import _compile, link_frames

__all__ = ["NumericIKResult", "ik_numeric", "rotation_error", "Step", "Errors"]

V = TypeVar("V")

# Damping lambda = _DAMPING * |e|^2 + _BIAS (Sugihara's rule, scaled down), and the largest joint
# change per step (rad or m): tuned on the shipped models from random seeds (fewest iterations).
_DAMPING = 0.05
_BIAS = 1e-9
_MAX_STEP = 2.0
#: an attempt restarts when the error has not fallen by 2% over this many iterations
_PATIENCE = 6
#: after a step from a squared error below this, the next errors are checked before the Jacobian
#: (quadratic convergence: the step has almost surely met the tolerances)
_NEARLY = 1e-9


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


def _rotation_vector(
    ops: Ops[Var], a: Sequence[Sequence[Real]], b: Sequence[Sequence[Real]]
) -> tuple[Real, Real, Real]:
    """The rotation vector (axis times angle, rad) of ``A B^T`` for 3x3 rotations given as rows;
    exact up to pi. Written against ``ops`` (no branches on values) so it is traced into the
    iteration of :func:`ik_numeric` and serves :func:`rotation_error` on floats (through
    :data:`._trace.TRACE_OPS`, which computes plain numbers right away)."""
    # E = A B^T: e_ij = sum_k a_ik b_jk
    e = [[a[i][0] * b[j][0] + a[i][1] * b[j][1] + a[i][2] * b[j][2] for j in range(3)] for i in range(3)]
    v = (e[2][1] - e[1][2], e[0][2] - e[2][0], e[1][0] - e[0][1])
    s = 0.5 * ops.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])  # sin(angle)
    c = 0.5 * (e[0][0] + e[1][1] + e[2][2] - 1.0)  # cos(angle)
    angle = ops.atan2(s, c)
    tiny = s < 1e-12
    k = ops.where(tiny, 0.5, angle / (2.0 * ops.where(tiny, 1.0, s)))  # small angles: the vector is v / 2
    # near pi: the axis from the symmetric part, E + I = 2 a a^T (its longest column; sign from v)
    cols = [[0.5 * (e[i][j] + e[j][i]) for i in range(3)] for j in range(3)]
    for j in range(3):
        cols[j][j] = e[j][j] + 1.0
    sizes = [col[0] * col[0] + col[1] * col[1] + col[2] * col[2] for col in cols]
    first = sizes[0] >= sizes[1]
    col = [ops.where(first, x, y) for x, y in zip(cols[0], cols[1], strict=True)]
    size = ops.where(first, sizes[0], sizes[1])
    third = sizes[2] > size
    col = [ops.where(third, z, x) for x, z in zip(col, cols[2], strict=True)]
    norm = ops.sqrt(ops.where(third, sizes[2], size))
    signed = ops.where(col[0] * v[0] + col[1] * v[1] + col[2] * v[2] < 0.0, -angle, angle)
    kp = signed / ops.where(norm > 1e-300, norm, 1.0)
    regular = (s > 1e-6) | (c > 0.0)
    return (
        ops.where(regular, v[0] * k, col[0] * kp),
        ops.where(regular, v[1] * k, col[1] * kp),
        ops.where(regular, v[2] * k, col[2] * kp),
    )


def rotation_error(r: list[list[float]], values: tuple[float, ...] | list[float]) -> tuple[float, float, float]:
    """The rotation vector (axis times angle, rad) of ``R_target R^T``, where ``r`` is R_target and
    R the 3x3 block of the 3x4 row-major ``values``; exact up to pi."""
    current = (values[0:3], values[4:7], values[8:11])
    x, y, z = _rotation_vector(TRACE_OPS, r, current)
    return float(x), float(y), float(z)


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
    context = _context(model)
    iteration, check, lo, hi, revolute = context
    n = len(lo)
    q: Sequence[float]
    if seed is None:
        q = [(a + b) / 2.0 for a, b in zip(lo, hi, strict=True)]
    else:
        given = np.asarray(seed, dtype=float).reshape(n).tolist()
        q = [min(b, max(a, x)) for x, a, b in zip(given, lo, hi, strict=True)]
    target = [x for row in rows4[:3] for x in row]  # the inputs _TARGET
    position_limit, orientation_limit = position_tolerance**2, orientation_tolerance**2
    best_q: Sequence[float] = q
    best_cost, best_pos2, best_ori2 = math.inf, math.inf, math.inf
    total = 0
    for attempt in range(1, attempts + 1):
        history = [math.inf] * _PATIENCE
        cost = math.inf
        for _ in range(max_iterations):
            total += 1
            done = False
            if cost < _NEARLY:  # the last step was a Gauss-Newton step this close: errors first
                errors = check(*q, *target, SCALAR_OPS)
                pos2, ori2 = errors.squared_position, errors.squared_orientation
                done = pos2 <= position_limit and ori2 <= orientation_limit
            if not done:
                step = iteration(*q, *target, SCALAR_OPS)
                pos2, ori2 = step.squared_position, step.squared_orientation
                done = pos2 <= position_limit and ori2 <= orientation_limit
            if done:
                inside = _into_limits(q, lo, hi, revolute)
                if inside is not None:
                    return NumericIKResult(tuple(inside), True, math.sqrt(pos2), math.sqrt(ori2), total, attempt)
                break  # a solution, but outside the limits: look for another
            cost = pos2 + ori2
            if cost < best_cost:
                best_cost, best_q, best_pos2, best_ori2 = cost, q, pos2, ori2
            elif not cost < math.inf:
                break  # a degenerate system (non-finite values): restart
            if cost > 0.98 * history[-_PATIENCE] and cost > 1e-10:
                break  # not converging from here: restart
            history.append(cost)
            q = step.q
        if rng is None:
            rng = np.random.default_rng()
        q = [a + u * (b - a) for u, a, b in zip(rng.random(n).tolist(), lo, hi, strict=True)]
    return NumericIKResult(tuple(best_q), False, math.sqrt(best_pos2), math.sqrt(best_ori2), total, attempts)


class Errors(NamedTuple, Generic[V]):
    """The squared errors of a configuration: position (m^2) and orientation (rad^2)."""

    squared_position: float | V
    squared_orientation: float | V


class Step(NamedTuple, Generic[V]):
    """One iteration: the squared errors at the configuration, and the next configuration."""

    squared_position: float | V
    squared_orientation: float | V
    q: tuple[float | V, ...]


class _Context(NamedTuple):
    iteration: Generated[Step[float]]  # f(q..., target..., ops)
    check: Generated[Errors[float]]  # f(q..., target..., ops)
    lower: list[float]
    upper: list[float]
    revolute: list[bool]


_CONTEXTS: weakref.WeakKeyDictionary[RobotModel, _Context] = weakref.WeakKeyDictionary()
#: the target pose's inputs to the generated functions: the rotation row-major, then the position
_TARGET = ("r00", "r01", "r02", "px", "r10", "r11", "r12", "py", "r20", "r21", "r22", "pz")


def _context(model: RobotModel) -> _Context:
    """Per model, once: the generated iteration and error check, the limits, which joints turn."""
    context = _CONTEXTS.get(model)
    if context is None:
        n = model.dof
        weight = _position_weight(model)
        context = _CONTEXTS[model] = _Context(
            _compile(model, lambda ops, x: _iteration(ops, model, x[:n], PoseBlock(*x[n:]), weight), extra=_TARGET),
            _compile(model, lambda ops, x: _check(ops, model, x[:n], PoseBlock(*x[n:])), extra=_TARGET),
            model.lower.tolist(),
            model.upper.tolist(),
            [j.type is JointType.REVOLUTE for j in model.joints],
        )
    return context


def _check(ops: Ops[Var], model: RobotModel, q: Sequence[Real], target: PoseBlock[Var]) -> Errors[Var]:
    """The squared errors at q only (no Jacobian, no step): to confirm a convergence."""
    _, _, pos2, ori2 = _errors(ops, chain(ops, model, q, with_axes=False).flange, target)
    return Errors(pos2, ori2)


def _position_weight(model: RobotModel) -> float:
    """How much a metre of position error counts against a radian of orientation error in the
    steps (not in the tolerances): 3 / (the chain's length at q = 0, base to flange through every
    joint origin), so that a robot of any size weighs them alike (3 per metre for a 1 m arm)."""
    points = [model.base[:3, 3]] + [frame[:3, 3] for frame in link_frames(model, [0.0] * model.dof)]
    length = sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(points))
    return 3.0 / max(length, 1e-3)


def _norm2(v: Sequence[Real]) -> Real:
    return v[0] * v[0] + v[1] * v[1] + v[2] * v[2]


def _errors(
    ops: Ops[Var], pose: PoseBlock[Var], target: PoseBlock[Var]
) -> tuple[tuple[Real, Real, Real], tuple[Real, Real, Real], Real, Real]:
    """The position error (m) and the rotation vector (rad) of ``pose`` from ``target``, and
    their squared norms."""
    position = (target.px - pose.px, target.py - pose.py, target.pz - pose.pz)
    rotation = _rotation_vector(ops, target.rotation, pose.rotation)
    return position, rotation, _norm2(position), _norm2(rotation)


def _iteration(ops: Ops[Var], model: RobotModel, q: Sequence[Real], target: PoseBlock[Var], weight: float) -> Step[Var]:
    """One Levenberg-Marquardt iteration at q, traced per model into one function: the squared
    position (m^2) and orientation (rad^2) errors at q, then the next q (the step capped at
    ``_MAX_STEP`` per joint, direction kept). Position rows count ``weight`` times (per metre)."""
    pose, jacobian = pose_and_jacobian(ops, model, q)
    position, rotation, pos2, ori2 = _errors(ops, pose, target)
    linear, angular = jacobian[:3], jacobian[3:]  # the rows of the linear and angular velocity
    jac = [[weight * x for x in row] for row in linear] + [list(row) for row in angular]
    e = [weight * x for x in position] + list(rotation)
    step = damped_step(ops, jac, e, _DAMPING * (weight * weight * pos2 + ori2) + _BIAS)
    scale = _MAX_STEP / ops.maximum(_MAX_STEP, *(abs(d) for d in step))
    return Step(pos2, ori2, tuple(qi + scale * d for qi, d in zip(q, step, strict=True)))


def damped_step(ops: Ops[Var], jac: Sequence[Sequence[Real]], e: Sequence[Real], damping: Real) -> list[Real]:
    """The dq minimising ``|J dq - e|^2 + damping |dq|^2``, through the smaller of the two
    symmetric positive definite systems: ``(J J^T + damping I) y = e, dq = J^T y`` when J has at
    least as many columns as rows, else ``(J^T J + damping I) dq = J^T e``."""
    rows, cols = len(jac), len(jac[0])
    if cols >= rows:
        gram = [[sum(jac[i][k] * jac[j][k] for k in range(cols)) for j in range(rows)] for i in range(rows)]
        y = _solve_spd(ops, gram, e, damping)
        return [sum(jac[i][k] * y[i] for i in range(rows)) for k in range(cols)]
    gram = [[sum(jac[k][i] * jac[k][j] for k in range(rows)) for j in range(cols)] for i in range(cols)]
    return _solve_spd(ops, gram, [sum(jac[k][i] * e[k] for k in range(rows)) for i in range(cols)], damping)


def _solve_spd(ops: Ops[Var], a: list[list[Real]], b: Sequence[Real], damping: Real) -> list[Real]:
    """x with ``(a + damping I) x = b`` by an LDL^T factorisation (no square roots); a pivot
    that rounding made non-positive is replaced by a tiny one, so the result stays finite or
    becomes infinite, never an exception."""
    m = len(a)
    low: list[list[Real]] = [[0.0] * m for _ in range(m)]  # L, unit diagonal
    ld: list[list[Real]] = [[0.0] * m for _ in range(m)]  # L D
    inverse: list[Real] = [0.0] * m  # 1 / D
    for j in range(m):
        d = a[j][j] + damping - sum(low[j][k] * ld[j][k] for k in range(j))
        inverse[j] = 1.0 / ops.where(d > 1e-300, d, 1e-300)
        for i in range(j + 1, m):
            ld[i][j] = a[i][j] - sum(ld[i][k] * low[j][k] for k in range(j))
            low[i][j] = ld[i][j] * inverse[j]
    z: list[Real] = []
    for i in range(m):
        z.append(b[i] - sum(low[i][k] * z[k] for k in range(i)))
    x: list[Real] = [0.0] * m
    for i in reversed(range(m)):
        x[i] = z[i] * inverse[i] - sum(low[k][i] * x[k] for k in range(i + 1, m))
    return x


def _into_limits(q: Sequence[float], lo: list[float], hi: list[float], revolute: list[bool]) -> list[float] | None:
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
