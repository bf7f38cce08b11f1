"""Robot models: the kinematic chain and per-joint limits, as validated, immutable data.

The paper's point is control of *different* manipulators: the model is data, the kinematics are
general. A model is a serial chain of joints; each joint contributes

    T_i(q) = pre_i . motion_i(q_i) . post_i

where ``pre``/``post`` are fixed 4x4 transforms and ``motion`` is a rotation about, or a translation
along, the joint's unit ``axis``. The flange pose is ``base . T_1 ... T_n . tool``. Both D-H
conventions map onto this form exactly:

* standard D-H (``A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha)``): pre = I, motion about z, post =
  Tz(d) Tx(a) Rx(alpha) (for a prismatic joint the motion is along z and Rz(theta) moves into pre);
* Craig's modified D-H (``A_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta) Tz(d)``): pre =
  Rx(alpha_{i-1}) Tx(a_{i-1}), motion about z, post = Tz(d).

Joint offsets are added to the joint variable (``theta = q + offset``). Units inside are SI (m, rad);
model files state their units and are converted on load.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "JointType",
    "Joint",
    "RobotModel",
    "ModelError",
    "transform",
    "rot_x",
    "rot_z",
    "trans",
    "rpy_matrix",
]

Matrix = NDArray[np.float64]


class ModelError(ValueError):
    """A model file or definition is invalid; the message names the file and the field."""


class JointType(StrEnum):
    REVOLUTE = "revolute"
    PRISMATIC = "prismatic"


def rot_x(angle: float) -> Matrix:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=float)


def rot_z(angle: float) -> Matrix:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)


def trans(x: float, y: float, z: float) -> Matrix:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def rpy_matrix(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """URDF's fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def transform(
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0), rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> Matrix:
    """A 4x4 transform from a translation and URDF roll-pitch-yaw angles."""
    t = np.eye(4)
    t[:3, :3] = rpy_matrix(*rpy)
    t[:3, 3] = xyz
    return t


@dataclass(frozen=True, eq=False)
class Joint:
    """One actuated joint of a serial chain, in SI units.

    ``axis`` is a unit vector in the joint frame; ``offset`` is added to the joint variable.
    Limits: ``position`` (min, max), and the magnitudes ``velocity``, ``acceleration``, ``jerk``.
    """

    name: str
    type: JointType
    pre: Matrix
    axis: Matrix
    post: Matrix
    offset: float = 0.0
    position: tuple[float, float] = (-math.pi, math.pi)
    velocity: float = math.pi
    acceleration: float = 10.0
    jerk: float = 500.0
    #: D-H row as given (SI), for display and for GET_DH_PARAMETERS: (theta, d, a, alpha).
    dh: tuple[float, float, float, float] | None = None


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A serial manipulator: joints, base and tool transforms, and where it came from."""

    name: str
    joints: tuple[Joint, ...]
    base: Matrix = field(default_factory=lambda: np.eye(4))
    tool: Matrix = field(default_factory=lambda: np.eye(4))
    description: str = ""
    source: str = ""
    #: ``"standard"`` or ``"modified"`` for D-H models, ``"urdf"`` otherwise.
    convention: str = "urdf"
    #: Per-joint motor parameters (issue 5 fills these); empty if the file gives none.
    motors: tuple[dict[str, float], ...] = ()

    def __post_init__(self) -> None:
        if not self.joints:
            raise ModelError(f"model {self.name!r} has no joints")
        for matrix in (self.base, self.tool):
            matrix.setflags(write=False)
        for joint in self.joints:
            for matrix in (joint.pre, joint.axis, joint.post):
                matrix.setflags(write=False)
            lo, hi = joint.position
            if not (math.isfinite(lo) and math.isfinite(hi)) or lo >= hi:
                raise ModelError(f"model {self.name!r}: joint {joint.name!r} position limits {lo}..{hi} are invalid")
            for what in ("velocity", "acceleration", "jerk"):
                value = getattr(joint, what)
                if not (math.isfinite(value) and value > 0):
                    raise ModelError(f"model {self.name!r}: joint {joint.name!r} {what} limit {value} must be > 0")

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower(self) -> NDArray[np.float64]:
        return np.array([j.position[0] for j in self.joints])

    @property
    def upper(self) -> NDArray[np.float64]:
        return np.array([j.position[1] for j in self.joints])

    @property
    def max_velocity(self) -> NDArray[np.float64]:
        return np.array([j.velocity for j in self.joints])

    @property
    def max_acceleration(self) -> NDArray[np.float64]:
        return np.array([j.acceleration for j in self.joints])

    @property
    def max_jerk(self) -> NDArray[np.float64]:
        return np.array([j.jerk for j in self.joints])

    def within_limits(self, q: NDArray[np.float64], tol: float = 0.0) -> bool:
        q = np.asarray(q, dtype=float)
        return bool(np.all(q >= self.lower - tol) and np.all(q <= self.upper + tol))
