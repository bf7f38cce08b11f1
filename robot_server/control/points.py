"""Trajectory points as the controller receives them (SI units), and what it refuses.

The controller knows nothing of wire messages or sequence numbers: the emulator turns a
JOINT_TRAJ_PT, a JOINT_TRAJ_PT_FULL or a downloaded point into a :class:`Point` and calls the
controller's verbs (start a trajectory, add a point, download, stop).

A point carries positions and either a ``duration`` (the segment time from the previous point,
JOINT_TRAJ_PT) with a ``velocity_ratio`` (the fraction of the maximum joint speed, used when the
duration is 0), or a ``time`` from the trajectory's start (JOINT_TRAJ_PT_FULL) with optional
``velocities`` and ``accelerations``.

:func:`check_point` refuses only what a real controller refuses (docs/reference/protocol.md §8.1 for
MotoROS's checks): the wrong number of joints, NaN or infinity, positions outside the limits,
explicit velocities above the maximum (a velocity ratio above 1 included), a negative duration or
time, a segment shorter than :data:`MIN_DURATION` (1 us) or longer than the documented maximum
(``ControllerConfig.max_segment_time``, 3600 s: also after a segment's time is computed from the
velocity ratio or stretched to slow the trajectory down). A segment that is merely too fast for the
joints' acceleration or jerk is not a reason to refuse under the ``blend`` policy: it is slowed
down (:mod:`.motion`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from ..arrays import Array
from ..model import RobotModel

__all__ = ["Point", "State", "Limits", "Reason", "PointRejected", "check_point", "within", "MIN_DURATION"]

#: relative slack on limit checks (floating-point noise of exact-at-the-limit values)
SLACK = 1e-9


class Reason(StrEnum):
    """Why a point was refused."""

    JOINT_COUNT = "joint_count"
    NOT_FINITE = "not_finite"
    POSITION_LIMIT = "position_limit"
    VELOCITY_LIMIT = "velocity_limit"
    ACCELERATION_LIMIT = "acceleration_limit"
    START_MISMATCH = "start_mismatch"
    TIMING = "timing"
    MISSING_FIELDS = "missing_fields"
    SEQUENCE = "sequence"
    QUEUE_FULL = "queue_full"
    NOT_READY = "not_ready"
    #: another kind of motion is under way (a straight line while joints move, or the reverse)
    BUSY = "busy"
    #: a malformed target (not a unit quaternion, a speed <= 0, a negative blend radius)
    INVALID = "invalid"
    #: a straight line leaves the reachable space
    UNREACHABLE = "unreachable"
    #: a straight line passes a singularity (the configuration's branch cannot be continued)
    SINGULAR = "singular"
    #: the tool would leave the allowed space (a workspace zone, the floor)
    WORKSPACE = "workspace"
    #: the tool would be faster than the active TCP speed limit
    TCP_SPEED = "tcp_speed"


class PointRejected(ValueError):
    """A point the controller refuses; nothing changed because of it."""

    def __init__(self, reason: Reason, message: str, joint: int | None = None) -> None:
        super().__init__(f"{reason.value}: {message}")
        self.reason = reason
        self.joint = joint


@dataclass(frozen=True)
class Point:
    """A received point in SI units, for ``dof`` joints (see the module doc)."""

    positions: Array | None
    velocities: Array | None = None
    accelerations: Array | None = None
    #: seconds from the trajectory's start (JOINT_TRAJ_PT_FULL)
    time: float | None = None
    #: seconds from the previous point (JOINT_TRAJ_PT); 0: from the velocity ratio
    duration: float | None = None
    #: fraction of the maximum joint speed, 0..1 (JOINT_TRAJ_PT)
    velocity_ratio: float | None = None


class State(NamedTuple):
    position: Array
    velocity: Array
    acceleration: Array

    @classmethod
    def rest(cls, position: ArrayLike) -> State:
        p = np.array(position, dtype=float)
        return cls(p, np.zeros_like(p), np.zeros_like(p))


@dataclass(frozen=True)
class Limits:
    """The joints' limits, one value per joint, named as :class:`.RobotModel` names them."""

    lower: Array
    upper: Array
    max_velocity: Array
    max_acceleration: Array
    max_jerk: Array

    @classmethod
    def from_model(cls, model: RobotModel) -> Limits:
        return cls(model.lower, model.upper, model.max_velocity, model.max_acceleration, model.max_jerk)

    @property
    def dof(self) -> int:
        return int(self.lower.size)

    @cached_property
    def rows(self) -> LimitRows:
        """The same limits as lists of floats, and the bounds :func:`within` checks positions and
        velocities against: for the planning, which works joint by joint on plain floats (numpy's
        cost per call on arrays of six is several times the arithmetic)."""
        position_low, position_high = _slackened(self.lower, self.upper)
        velocity_low, velocity_high = _slackened(-self.max_velocity, self.max_velocity)
        return LimitRows(
            self.lower.tolist(),
            self.upper.tolist(),
            self.max_velocity.tolist(),
            self.max_acceleration.tolist(),
            self.max_jerk.tolist(),
            position_low.tolist(),
            position_high.tolist(),
            velocity_low.tolist(),
            velocity_high.tolist(),
            bool(np.isfinite(position_low).all() and np.isfinite(position_high).all()),
        )


class LimitRows(NamedTuple):
    """:class:`Limits` as lists of floats (:attr:`Limits.rows`)."""

    lower: list[float]
    upper: list[float]
    max_velocity: list[float]
    max_acceleration: list[float]
    max_jerk: list[float]
    #: the positions :func:`check_point` accepts (``lower`` and ``upper`` widened by :data:`SLACK`)
    position_low: list[float]
    position_high: list[float]
    #: the velocities it accepts
    velocity_low: list[float]
    velocity_high: list[float]
    #: the accepted positions are finite (a position within them is)
    bounded: bool


#: the shortest segment a point may ask for (s): a non-zero duration or time step below it is refused
MIN_DURATION = 1e-6


def check_point(point: Point, limits: Limits, max_duration: float) -> Array:
    """Refuse a point a real controller refuses (module doc); returns its positions."""
    rows = limits.rows
    dof = len(rows.lower)
    positions = point.positions
    if positions is None:
        raise PointRejected(Reason.MISSING_FIELDS, "a point needs positions (velocity-only points are not supported)")
    inside = False  # the positions within the (finite) limits: finite too, so not checked again
    for what, array in (
        ("positions", positions),
        ("velocities", point.velocities),
        ("accelerations", point.accelerations),
    ):
        if array is None:
            continue
        if array.shape != (dof,):
            raise PointRejected(Reason.JOINT_COUNT, f"{what} has {array.size} values; this robot has {dof}")
        if array is positions and rows.bounded:
            inside = _inside(positions.tolist(), rows.position_low, rows.position_high)
            if inside:
                continue
        if not np.isfinite(array).all():
            raise PointRejected(Reason.NOT_FINITE, f"{what} contains NaN or infinity")
    for what, number in (("time", point.time), ("duration", point.duration), ("velocity ratio", point.velocity_ratio)):
        if number is None:
            continue
        if not math.isfinite(number):
            raise PointRejected(Reason.NOT_FINITE, f"the {what} is {number}")
        if number < 0.0:
            raise PointRejected(Reason.TIMING, f"the {what} cannot be negative ({number:g})")
    if point.duration is not None and 0.0 < point.duration < MIN_DURATION:
        raise PointRejected(
            Reason.TIMING, f"the duration {point.duration:g} s is shorter than the minimum ({MIN_DURATION:g} s)"
        )
    if point.duration is not None and point.duration > max_duration:
        raise PointRejected(
            Reason.TIMING, f"the duration {point.duration:g} s is beyond the maximum segment time ({max_duration:g} s)"
        )
    if point.velocity_ratio is not None and point.velocity_ratio > 1.0:
        raise PointRejected(
            Reason.VELOCITY_LIMIT, f"the velocity ratio {point.velocity_ratio:g} asks for more than the maximum speed"
        )
    if not inside and not _inside(positions.tolist(), rows.position_low, rows.position_high):
        within(positions, limits.lower, limits.upper, Reason.POSITION_LIMIT, "position")
    if point.velocities is not None and not _inside(point.velocities.tolist(), rows.velocity_low, rows.velocity_high):
        within(point.velocities, -limits.max_velocity, limits.max_velocity, Reason.VELOCITY_LIMIT, "velocity")
    return positions


def _inside(values: list[float], low: list[float], high: list[float]) -> bool:
    """Every value within its bounds (the check of :func:`within`, on floats: NaN is not inside)."""
    return all(lo <= value <= hi for value, lo, hi in zip(values, low, high, strict=True))


def _slackened(lower: Array, upper: Array) -> tuple[Array, Array]:
    """The bounds :func:`within` compares values with: ``lower`` and ``upper`` widened by :data:`SLACK`."""
    return lower - SLACK * np.maximum(1.0, np.abs(lower)), upper + SLACK * np.maximum(1.0, np.abs(upper))


def within(values: Array, lower: Array, upper: Array, reason: Reason, what: str) -> None:
    """Refuse with ``reason`` unless ``lower <= values <= upper`` (to :data:`SLACK`)."""
    low, high = _slackened(lower, upper)
    bad = np.flatnonzero((values < low) | (values > high))
    if bad.size:
        j = int(bad[0])
        raise PointRejected(
            reason, f"{what} of joint {j + 1} is {values[j]:.6g}, outside {lower[j]:.6g}..{upper[j]:.6g}", j
        )
