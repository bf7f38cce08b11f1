"""Where the tool is: the TCP pose and linear speed the controller computes every interpolation
period, from the commanded and from the actual joint state.

The pose is the model's forward kinematics (base frame, joints, tool frame: the TCP in the cell);
the speed is ``|J_v q'|``, the linear rows of the geometric Jacobian at the TCP times the joint
velocities (exact, not a difference of positions). One generated pose-and-Jacobian call per state
(a few microseconds, :mod:`..kinematics.fk`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import mul
from typing import NamedTuple

from ..kinematics import chain_functions, quaternion_of
from ..kinematics._ops import SCALAR_OPS
from ..model import RobotModel

__all__ = ["ToolState", "ToolMeter", "TOOL_FIELDS"]

Vector = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]


class ToolState(NamedTuple):
    """The TCP at one interpolation instant (controller time ``time``): position (m, cell frame),
    orientation (unit quaternion ``(w, x, y, z)``) and linear speed (m/s), commanded and actual."""

    time: float
    command_position: Vector
    command_orientation: Quaternion
    command_speed: float
    actual_position: Vector
    actual_orientation: Quaternion
    actual_speed: float

    def values(self) -> tuple[float, ...]:
        """The 16 numbers after ``time``, in the order of :data:`TOOL_FIELDS`."""
        return (
            *self.command_position,
            *self.command_orientation,
            self.command_speed,
            *self.actual_position,
            *self.actual_orientation,
            self.actual_speed,
        )


#: the names of :meth:`ToolState.values`, as recorded (columns ``tool.<name>``)
TOOL_FIELDS = tuple(
    f"{side}_{name}" for side in ("command", "actual") for name in ("x", "y", "z", "qw", "qx", "qy", "qz", "speed")
)


class ToolMeter:
    """Computes :class:`ToolState` for one model."""

    def __init__(self, model: RobotModel) -> None:
        self._pose_and_jacobian = chain_functions(model).pose_and_jacobian

    def pose(self, q: Sequence[float], velocity: Sequence[float]) -> tuple[Vector, Quaternion, float]:
        """TCP position, orientation and linear speed of one joint state."""
        pose, jac = self._pose_and_jacobian(*q, SCALAR_OPS)
        # (sum of map: the same products added in the same order as a generator's, three times faster)
        vx = sum(map(mul, jac[0], velocity))
        vy = sum(map(mul, jac[1], velocity))
        vz = sum(map(mul, jac[2], velocity))
        rotation = (pose.r00, pose.r01, pose.r02, pose.r10, pose.r11, pose.r12, pose.r20, pose.r21, pose.r22)
        return (pose.px, pose.py, pose.pz), quaternion_of(rotation), math.sqrt(vx * vx + vy * vy + vz * vz)

    def measure(
        self,
        time: float,
        command: Sequence[float],
        command_velocity: Sequence[float],
        actual: Sequence[float],
        actual_velocity: Sequence[float],
    ) -> ToolState:
        cp, cr, cs = self.pose(command, command_velocity)
        ap, ar, a_s = self.pose(actual, actual_velocity)
        return ToolState(time, cp, cr, cs, ap, ar, a_s)
