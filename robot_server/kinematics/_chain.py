"""The kinematic chain of a model, written once for :mod:`._trace`: the flange pose, and each
joint's world axis and position (what the geometric Jacobian is made of).

Traced per model, the chain becomes straight-line code with the model's constants folded in: a
D-H or URDF chain is mostly twists of 0 or +-pi/2, zero offsets and unit axes, so most of the
4x4 products vanish at trace time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..model import JointType, RobotModel
from ._trace import snap

Block = list[list[Any]]  # the top 3x4 block of a homogeneous transform; last row 0 0 0 1


def _const(matrix: Any) -> Block:
    return [[snap(float(matrix[r, j])) for j in range(4)] for r in range(3)]


def _identity(block: Block) -> bool:
    return all(block[r][j] == (1.0 if r == j else 0.0) for r in range(3) for j in range(4))


def _times(a: Block, b: Block) -> Block:
    return [
        [a[r][0] * b[0][j] + a[r][1] * b[1][j] + a[r][2] * b[2][j] + (a[r][3] if j == 3 else 0.0) for j in range(4)]
        for r in range(3)
    ]


def _motion(ops: Any, kind: JointType, axis: Any, theta: Any) -> Block:
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


def chain(ops: Any, model: RobotModel, q: Sequence[Any], with_axes: bool) -> list[Any]:
    """The flange's 3x4 block row-major (12 values), then, if ``with_axes``, per joint its world
    axis and a point on it (ax, ay, az, px, py, pz)."""
    t = _const(model.base)
    axes: list[Any] = []
    for joint, value in zip(model.joints, q, strict=True):
        pre = _const(joint.pre)
        if not _identity(pre):
            t = _times(t, pre)
        if with_axes:
            x, y, z = (snap(float(v)) for v in joint.axis)
            axes += [t[r][0] * x + t[r][1] * y + t[r][2] * z for r in range(3)]
            axes += [t[r][3] for r in range(3)]
        t = _times(t, _motion(ops, joint.type, joint.axis, value + joint.offset))
        post = _const(joint.post)
        if not _identity(post):
            t = _times(t, post)
    tool = _const(model.tool)
    if not _identity(tool):
        t = _times(t, tool)
    return [t[r][j] for r in range(3) for j in range(4)] + axes


def pose_and_jacobian(ops: Any, model: RobotModel, q: Sequence[Any]) -> list[Any]:
    """The flange's 3x4 block (12 values), then the geometric Jacobian row-major (6 x dof): rows
    vx, vy, vz, wx, wy, wz in the base frame, at the flange point."""
    values = chain(ops, model, q, with_axes=True)
    p = (values[3], values[7], values[11])
    columns = []
    for i, joint in enumerate(model.joints):
        ax, ay, az, ox, oy, oz = values[12 + 6 * i : 18 + 6 * i]
        if joint.type is JointType.PRISMATIC:
            columns.append((ax, ay, az, 0.0, 0.0, 0.0))
        else:
            dx, dy, dz = p[0] - ox, p[1] - oy, p[2] - oz
            columns.append((ay * dz - az * dy, az * dx - ax * dz, ax * dy - ay * dx, ax, ay, az))
    return values[:12] + [column[r] for r in range(6) for column in columns]
