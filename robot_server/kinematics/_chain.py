"""The kinematic chain of a model, written once for :mod:`._trace`: the flange pose, and each
joint's world axis and position (what the geometric Jacobian is made of).

Traced per model, the chain becomes straight-line code with the model's constants folded in: a
D-H or URDF chain is mostly twists of 0 or +-pi/2, zero offsets and unit axes, so most of the
4x4 products vanish at trace time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Generic, NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from ..model import JointType, RobotModel
from ._ops import Ops
from ._trace import Real, Var, snap

__all__ = ["PoseBlock", "AxisLine", "ChainValues", "PoseJacobian", "chain", "pose_and_jacobian"]

V = TypeVar("V")

Block = list[list[Real]]  # the top 3x4 block of a homogeneous transform; last row 0 0 0 1


class PoseBlock(NamedTuple, Generic[V]):
    """The top 3x4 block of a homogeneous transform (its last row is 0 0 0 1), row-major: the
    fields are the first 12 entries of the row-major 4x4 matrix. Floats for one pose, numpy
    columns for a batch (a constant of the model stays a float), placeholders while tracing."""

    r00: float | V
    r01: float | V
    r02: float | V
    px: float | V
    r10: float | V
    r11: float | V
    r12: float | V
    py: float | V
    r20: float | V
    r21: float | V
    r22: float | V
    pz: float | V

    @property
    def rotation(self) -> tuple[tuple[float | V, float | V, float | V], ...]:
        """The 3x3 rotation, as rows."""
        return ((self.r00, self.r01, self.r02), (self.r10, self.r11, self.r12), (self.r20, self.r21, self.r22))

    @property
    def position(self) -> tuple[float | V, float | V, float | V]:
        return (self.px, self.py, self.pz)

    def matrix(self) -> NDArray[np.float64]:
        """The 4x4 homogeneous matrix of a pose of floats."""
        return np.array((*self, 0.0, 0.0, 0.0, 1.0), dtype=float).reshape(4, 4)


class AxisLine(NamedTuple, Generic[V]):
    """A joint's axis in the base frame: its unit direction and a point on it."""

    direction: tuple[float | V, float | V, float | V]
    point: tuple[float | V, float | V, float | V]


class ChainValues(NamedTuple, Generic[V]):
    """What :func:`chain` computes: the flange pose and (if asked for) each joint's axis."""

    flange: PoseBlock[V]
    axes: tuple[AxisLine[V], ...]


class PoseJacobian(NamedTuple, Generic[V]):
    """The flange pose and the geometric Jacobian (6 rows of ``dof`` values: vx, vy, vz, wx, wy,
    wz in the base frame, at the flange point)."""

    pose: PoseBlock[V]
    jacobian: tuple[tuple[float | V, ...], ...]


def _const(matrix: NDArray[np.float64]) -> Block:
    return [[snap(float(matrix[r, j])) for j in range(4)] for r in range(3)]


def _identity(block: Block) -> bool:
    return all(block[r][j] == (1.0 if r == j else 0.0) for r in range(3) for j in range(4))


def _times(a: Block, b: Block) -> Block:
    return [
        [a[r][0] * b[0][j] + a[r][1] * b[1][j] + a[r][2] * b[2][j] + (a[r][3] if j == 3 else 0.0) for j in range(4)]
        for r in range(3)
    ]


def _motion(ops: Ops[Var], kind: JointType, axis: NDArray[np.float64], theta: Real) -> Block:
    x, y, z = (snap(float(v)) for v in axis)
    if kind is JointType.PRISMATIC:
        return [[1.0, 0.0, 0.0, x * theta], [0.0, 1.0, 0.0, y * theta], [0.0, 0.0, 1.0, z * theta]]
    c, s = ops.cos(theta), ops.sin(theta)
    v = 1.0 - c
    # c + k^2 (1 - c) is exactly 1 about a coordinate axis (k = +-1): say so, do not compute it
    xx, yy, zz = (1.0 if k * k == 1.0 else c + k * k * v for k in (x, y, z))
    return [
        [xx, x * y * v - z * s, x * z * v + y * s, 0.0],
        [y * x * v + z * s, yy, y * z * v - x * s, 0.0],
        [z * x * v - y * s, z * y * v + x * s, zz, 0.0],
    ]


def chain(ops: Ops[Var], model: RobotModel, q: Sequence[Real], with_axes: bool) -> ChainValues[Var]:
    """The flange pose and, if ``with_axes``, each joint's world axis (through the joint's frame
    before its own motion). On plain floats (with :data:`._trace.TRACE_OPS`) this is evaluated
    right away."""
    t = _const(model.base)
    axes: list[AxisLine[Var]] = []
    for joint, value in zip(model.joints, q, strict=True):
        pre = _const(joint.pre)
        if not _identity(pre):
            t = _times(t, pre)
        if with_axes:
            x, y, z = (snap(float(v)) for v in joint.axis)
            direction = [t[r][0] * x + t[r][1] * y + t[r][2] * z for r in range(3)]
            axes.append(AxisLine((direction[0], direction[1], direction[2]), (t[0][3], t[1][3], t[2][3])))
        t = _times(t, _motion(ops, joint.type, joint.axis, value + joint.offset))
        post = _const(joint.post)
        if not _identity(post):
            t = _times(t, post)
    tool = _const(model.tool)
    if not _identity(tool):
        t = _times(t, tool)
    flange = PoseBlock(*t[0], *t[1], *t[2])
    return ChainValues(flange, tuple(axes))


def pose_and_jacobian(ops: Ops[Var], model: RobotModel, q: Sequence[Real]) -> PoseJacobian[Var]:
    """The flange pose and the geometric Jacobian at the flange point."""
    flange, axes = chain(ops, model, q, with_axes=True)
    px, py, pz = flange.position
    columns: list[tuple[Real, ...]] = []
    for joint, ((ax, ay, az), (ox, oy, oz)) in zip(model.joints, axes, strict=True):
        if joint.type is JointType.PRISMATIC:
            columns.append((ax, ay, az, 0.0, 0.0, 0.0))
        else:
            dx, dy, dz = px - ox, py - oy, pz - oz
            columns.append((ay * dz - az * dy, az * dx - ax * dz, ax * dy - ay * dx, ax, ay, az))
    rows = tuple(tuple(column[r] for column in columns) for r in range(6))
    return PoseJacobian(flange, rows)
