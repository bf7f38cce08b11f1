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

from .workspace import Supervision

__all__ = [
    "JointType",
    "Joint",
    "RobotModel",
    "ModelError",
    "MotorParameters",
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


@dataclass(frozen=True)
class MotorParameters:
    """One joint's servo drive: a DC motor through a gear, under a cascaded position (P) /
    velocity (PI) loop with torque saturation. SI units; motor-side quantities are at the motor
    shaft, the load inertia and the gains at the joint.

    The defaults are not any real robot's: they describe a plausible 400 W class drive on a
    100:1 harmonic gear moving about 0.5 kg m^2, chosen so that the paper's robot at full speed
    (pi rad/s) follows with a joint error of about 5 mrad (a few millimetres at the flange), as
    an industrial arm does, and the torque allows about 40 times the default acceleration limit.
    """

    torque_constant: float = 0.45  # N m / A
    max_current: float = 8.0  # A (torque saturation = gear_ratio * torque_constant * max_current)
    rotor_inertia: float = 3.0e-5  # kg m^2, motor side
    load_inertia: float = 0.5  # kg m^2 (or kg for a prismatic joint), joint side
    gear_ratio: float = 100.0  # motor turns per joint turn (per metre x 2 pi for a prismatic joint)
    viscous_friction: float = 1.0e-4  # N m s / rad, motor side
    coulomb_friction: float = 0.02  # N m, motor side
    position_gain: float = 30.0  # 1/s: joint velocity command per unit of position error
    velocity_bandwidth: float = 150.0  # rad/s: velocity-loop gain = inertia * bandwidth
    velocity_integral_time: float = 0.02  # s
    velocity_feedforward: float = 0.95  # share of the commanded velocity fed forward, 0..1
    following_error_limit: float = 0.05  # rad (or m): more than this raises the alarm

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not math.isfinite(value) or value < 0:
                raise ModelError(f"motor parameter {name} = {value!r} must be a finite number >= 0")
        for name in ("torque_constant", "max_current", "gear_ratio", "position_gain", "velocity_bandwidth"):
            if getattr(self, name) <= 0:
                raise ModelError(f"motor parameter {name} must be > 0")
        if self.rotor_inertia + self.load_inertia <= 0:
            raise ModelError("motor parameters: rotor_inertia + load_inertia must be > 0")
        if self.velocity_feedforward > 1 or self.following_error_limit <= 0:
            raise ModelError("motor parameters: velocity_feedforward must be in 0..1 and following_error_limit > 0")


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A serial manipulator: joints, base and tool transforms, TCP supervision, and where it came from."""

    name: str
    joints: tuple[Joint, ...]
    base: Matrix = field(default_factory=lambda: np.eye(4))
    tool: Matrix = field(default_factory=lambda: np.eye(4))
    description: str = ""
    source: str = ""
    #: ``"standard"`` or ``"modified"`` for D-H models, ``"urdf"`` otherwise.
    convention: str = "urdf"
    #: Per-joint servo drives; empty if the file gives none (then :meth:`motor` gives defaults).
    motors: tuple[MotorParameters, ...] = ()
    #: Cartesian supervision of the TCP (speed limits, workspace zones; :mod:`.workspace`): from the
    #: model file's ``[supervision]`` table, or the defaults (250 mm/s in MANUAL mode, no zones).
    supervision: Supervision = field(default_factory=Supervision)

    def __post_init__(self) -> None:
        if not self.joints:
            raise ModelError(f"model {self.name!r} has no joints")
        if not isinstance(self.supervision, Supervision):
            raise ModelError(f"model {self.name!r}: supervision must be a Supervision, not {self.supervision!r}")
        for matrix in (self.base, self.tool):
            matrix.setflags(write=False)
        for joint in self.joints:
            for matrix in (joint.pre, joint.axis, joint.post):
                matrix.setflags(write=False)
            lo, hi = joint.position
            if not (math.isfinite(lo) and math.isfinite(hi)) or lo >= hi:
                raise ModelError(f"model {self.name!r}: joint {joint.name!r} position limits {lo}..{hi} are invalid")
            if self.motors and len(self.motors) != len(self.joints):
                raise ModelError(f"model {self.name!r}: {len(self.motors)} motors for {len(self.joints)} joints")
            for what in ("velocity", "acceleration", "jerk"):
                value = getattr(joint, what)
                if not (math.isfinite(value) and value > 0):
                    raise ModelError(f"model {self.name!r}: joint {joint.name!r} {what} limit {value} must be > 0")

    def motor(self, index: int) -> MotorParameters:
        """Joint ``index``'s drive: from the model file, or the defaults of :class:`MotorParameters`."""
        return self.motors[index] if self.motors else MotorParameters()

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
