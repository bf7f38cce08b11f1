"""Forward kinematics, the geometric Jacobian and manipulability of any serial chain.

The flange pose is computed by code generated per model (:mod:`._chain`, :mod:`._trace`): one function of the
joint values that serves a single configuration (Python floats) and a batch (numpy columns, no
Python loop over configurations). ``link_frames`` is the plain matrix product, for display and
tests; it is independent of the generated code and the tests check one against the other.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model import JointType, RobotModel
from ._chain import PoseBlock, PoseJacobian, chain, pose_and_jacobian
from ._ops import ARRAY_OPS, SCALAR_OPS, Ops
from ._trace import TRACE_OPS, Generated, Tracer, Var

__all__ = [
    "fk",
    "fk_batch",
    "link_frames",
    "jacobian",
    "manipulability",
    "singularity_measure",
    "jacobian_batch",
    "singularity_measure_batch",
    "chain_functions",
    "ChainFunctions",
]

Matrix = NDArray[np.float64]


class ChainFunctions(NamedTuple):
    """A model's generated chain functions, ``f(q0, ..., q(dof-1), ops)`` (compiled once per
    model): the flange pose, the pose with the geometric Jacobian, and both again on numpy
    columns (``ops`` = :data:`._ops.ARRAY_OPS`)."""

    pose: Generated[PoseBlock[float]]
    pose_and_jacobian: Generated[PoseJacobian[float]]
    pose_batch: Generated[PoseBlock[NDArray[np.float64]]]
    pose_and_jacobian_batch: Generated[PoseJacobian[NDArray[np.float64]]]


def _compile(
    model: RobotModel,
    body: Callable[[Ops[Var], list[Var]], object],
    batch: bool = False,
    extra: Sequence[str] = (),
) -> Callable[..., Any]:
    """Trace ``body(ops, inputs)`` into ``f(q0, ..., q(dof-1), *extra, ops)``: the inputs are the
    joint values, then the ``extra`` names; it returns what ``body`` returns (a NamedTuple)."""
    tracer = Tracer()
    names = [f"q{i}" for i in range(model.dof)] + list(extra)
    outputs = body(TRACE_OPS, [tracer.input(n) for n in names])
    return tracer.compile("chain", names, outputs, f"kinematics of {model.name}", batch=batch)


def _build(model: RobotModel) -> ChainFunctions:
    return ChainFunctions(
        _compile(model, lambda ops, q: chain(ops, model, q, with_axes=False).flange),
        _compile(model, lambda ops, q: pose_and_jacobian(ops, model, q)),
        _compile(model, lambda ops, q: chain(ops, model, q, with_axes=False).flange, batch=True),
        _compile(model, lambda ops, q: pose_and_jacobian(ops, model, q), batch=True),
    )


_CHAINS: weakref.WeakKeyDictionary[RobotModel, ChainFunctions] = weakref.WeakKeyDictionary()


def chain_functions(model: RobotModel) -> ChainFunctions:
    """The model's generated functions (see :class:`ChainFunctions`; compiled once per model)."""
    compiled = _CHAINS.get(model)
    if compiled is None:
        compiled = _CHAINS[model] = _build(model)
    return compiled


def _values(model: RobotModel, q: ArrayLike) -> list[float]:
    try:
        values = [float(v) for v in q]  # type: ignore[union-attr, arg-type]
    except TypeError:
        raise ValueError(f"{model.name}: a configuration is a sequence of {model.dof} numbers, not {q!r}") from None
    if len(values) != model.dof:
        raise ValueError(f"{model.name} has {model.dof} joints; got {len(values)} values")
    return values


def fk(model: RobotModel, q: ArrayLike) -> Matrix:
    """The flange (tool) pose for one configuration, as a 4x4 homogeneous matrix."""
    return chain_functions(model).pose(*_values(model, q), SCALAR_OPS).matrix()


def fk_batch(model: RobotModel, q: ArrayLike) -> NDArray[np.float64]:
    """Flange poses for N configurations: ``(N, dof)`` in, ``(N, 4, 4)`` out, no loop over N."""
    values = np.asarray(q, dtype=float)
    if values.ndim != 2 or values.shape[1] != model.dof:
        raise ValueError(f"fk_batch takes an (N, {model.dof}) array for {model.name}, not shape {values.shape}")
    pose = chain_functions(model).pose_batch
    n = values.shape[0]
    out = np.zeros((n, 4, 4))
    out[:, 3, 3] = 1.0
    flat = out.reshape(n, 16)
    # Chunks small enough for the intermediate columns to stay in cache: about twice as fast as
    # whole-batch columns for N = 100,000 on the CI machine class.
    for start in range(0, n, _CHUNK):
        stop = min(n, start + _CHUNK)
        block = pose(*np.ascontiguousarray(values[start:stop].T), ARRAY_OPS)
        for column, value in enumerate(block):  # a PoseBlock's fields: the matrix's first 12 entries
            flat[start:stop, column] = value
    return out


_CHUNK = 8192


def jacobian(model: RobotModel, q: ArrayLike) -> Matrix:
    """The geometric Jacobian (6 x dof) in the base frame at the flange (tool) point: rows are the
    linear velocity (m/s) then the angular velocity (rad/s) per unit joint velocity."""
    result = chain_functions(model).pose_and_jacobian(*_values(model, q), SCALAR_OPS)
    return np.array(result.jacobian, dtype=float)


def jacobian_batch(model: RobotModel, q: ArrayLike) -> NDArray[np.float64]:
    """Geometric Jacobians for N configurations: ``(N, dof)`` in, ``(N, 6, dof)`` out, no loop over N."""
    values = np.asarray(q, dtype=float)
    if values.ndim != 2 or values.shape[1] != model.dof:
        raise ValueError(f"jacobian_batch takes an (N, {model.dof}) array for {model.name}, not shape {values.shape}")
    n = values.shape[0]
    out = np.empty((n, 6, model.dof))
    function = chain_functions(model).pose_and_jacobian_batch
    for start in range(0, n, _CHUNK):
        stop = min(n, start + _CHUNK)
        rows = function(*np.ascontiguousarray(values[start:stop].T), ARRAY_OPS).jacobian
        for r, row in enumerate(rows):
            for c, value in enumerate(row):
                out[start:stop, r, c] = value  # a constant entry (a float) broadcasts
    return out


def singularity_measure_batch(model: RobotModel, q: ArrayLike) -> NDArray[np.float64]:
    """:func:`singularity_measure` for N configurations ``(N, dof)``: ``(N,)`` values in [0, 1]."""
    sv = np.linalg.svd(jacobian_batch(model, q), compute_uv=False)
    largest = sv[:, 0]
    out: NDArray[np.float64] = np.divide(sv[:, -1], largest, out=np.zeros_like(largest), where=largest > 0)
    return out


def manipulability(model: RobotModel, q: ArrayLike) -> float:
    """Yoshikawa's manipulability sqrt(det(J J^T)); 0 at a singularity."""
    jac = jacobian(model, q)
    square = jac @ jac.T if model.dof >= 6 else jac.T @ jac
    return float(math.sqrt(max(np.linalg.det(square), 0.0)))


def singularity_measure(model: RobotModel, q: ArrayLike) -> float:
    """The inverse condition number of the Jacobian (smallest over largest singular value), in
    [0, 1]: 0 at a singularity, unit-free enough to threshold (lengths are in metres)."""
    sv = np.linalg.svd(jacobian(model, q), compute_uv=False)
    return float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0


def _axis_rotation(x: float, y: float, z: float, c: float, s: float) -> Matrix:
    v = 1.0 - c
    return np.array(
        [
            [c + x * x * v, x * y * v - z * s, x * z * v + y * s],
            [y * x * v + z * s, c + y * y * v, y * z * v - x * s],
            [z * x * v - y * s, z * y * v + x * s, c + z * z * v],
        ]
    )


def link_frames(model: RobotModel, q: ArrayLike) -> list[Matrix]:
    """The pose of every joint's frame after its motion (``T_0i``, base included), then the flange
    with the tool: ``dof + 1`` 4x4 matrices, by plain matrix products."""
    t = model.base.copy()
    frames = []
    for joint, value in zip(model.joints, _values(model, q), strict=True):
        motion = np.eye(4)
        theta = value + joint.offset
        if joint.type is JointType.PRISMATIC:
            motion[:3, 3] = joint.axis * theta
        else:
            x, y, z = (float(v) for v in joint.axis)
            motion[:3, :3] = _axis_rotation(x, y, z, math.cos(theta), math.sin(theta))
        t = t @ joint.pre @ motion @ joint.post
        frames.append(t)
    frames.append(t @ model.tool)
    return frames
