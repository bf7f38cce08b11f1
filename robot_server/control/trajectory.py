"""What a received trajectory point means: the one place where points become segments.

**JOINT_TRAJ_PT** (positions, a velocity ratio and a segment duration; simple-message.md §4.3): a
duration > 0 is the segment time. Otherwise the time follows from the ratio: the slowest joint
(the "critical" one) reaches ``ratio x`` its maximum speed at the segment's velocity peak, and no
joint exceeds its acceleration limit (for ``linear``, which has no finite acceleration, only the
speed counts). The interpolation :class:`Policy` decides the segment shape:

* ``linear``: constant velocity between points; the velocity jumps at each point (the jittery
  baseline the paper measures);
* ``cubic``: the rest-to-rest cubic (its acceleration steps at both ends);
* ``quintic``: the paper's rest-to-rest quintic (velocity and acceleration 0 at each point);
* ``ruckig``: the time-optimal jerk-limited motion to rest at the point, with the speed limit
  scaled by the ratio; a duration > 0 is its minimum duration (ruckig takes longer if the jerk
  and acceleration limits need it).

A JOINT_TRAJ_PT carries no velocities, so every point is reached at rest.

**JOINT_TRAJ_PT_FULL** (time from start plus the fields its ``valid_fields`` declares): TIME and
POSITION are required. The segment time is the difference of consecutive times. As in ros2_control's
joint trajectory controller (motion.md §3.3) the segment follows the fields both ends have:
positions only -> linear, plus velocities -> cubic Hermite (C1), plus accelerations -> quintic (C2).
The policy does not apply.

**The first point** of a trajectory (sequence 0, -1 or -2, or the first point after a stop) must
lie within ``start_tolerance`` of where the motion before it ends (MotoROS rejects it otherwise,
simple-message.md §8.1); ``None`` turns the check off. A first point with no time (time or
duration 0) is taken as the start itself: the motion continues from the actual state, never with a
jump; with a time it is a segment like any other.

Every point is checked before anything moves: joint count, finite values, position limits, its
velocities and accelerations, and then the whole segment (its position range, velocity and
acceleration extremes, computed exactly). A failure raises :class:`PointRejected` with a
:class:`Reason` and leaves the planner unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from simple_message.constants import SpecialSeq, ValidFields
from simple_message.messages import JointTrajPt, JointTrajPtFull, TrajPoint

from ..model import RobotModel
from .segments import (
    PlanningError,
    RuckigSegment,
    Segment,
    cubic,
    cubic_hermite,
    hold,
    linear,
    quintic,
    quintic_hermite,
)

__all__ = [
    "Policy",
    "Reason",
    "PointRejected",
    "Point",
    "Limits",
    "State",
    "TrajectoryPlanner",
    "point_from_message",
]

Array = NDArray[np.float64]

_ALL = ValidFields.POSITION | ValidFields.VELOCITY | ValidFields.ACCELERATION
#: relative slack on limit checks (floating-point noise of exact-at-the-limit segments)
_SLACK = 1e-9


class Policy(StrEnum):
    """How JOINT_TRAJ_PT points are joined (see the module doc)."""

    LINEAR = "linear"
    CUBIC = "cubic"
    QUINTIC = "quintic"
    RUCKIG = "ruckig"


# Peak speed and peak acceleration of each rest-to-rest shape, as multiples of D/T and D/T^2
# (motion.md §4): they turn a velocity ratio into a segment time.
_PEAKS = {
    Policy.LINEAR: (1.0, 0.0),
    Policy.CUBIC: (1.5, 6.0),
    Policy.QUINTIC: (1.875, 10.0 / math.sqrt(3.0)),
}


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


class PointRejected(ValueError):
    """A point the controller refuses; nothing moved because of it."""

    def __init__(self, reason: Reason, message: str, joint: int | None = None) -> None:
        super().__init__(f"{reason.value}: {message}")
        self.reason = reason
        self.joint = joint


@dataclass(frozen=True)
class Point:
    """A received point in SI units, for ``dof`` joints. ``time`` (from the trajectory start)
    comes with JOINT_TRAJ_PT_FULL; ``duration`` and ``velocity_ratio`` with JOINT_TRAJ_PT."""

    sequence: int
    positions: Array | None
    velocities: Array | None = None
    accelerations: Array | None = None
    time: float | None = None
    duration: float | None = None
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
    lower: Array
    upper: Array
    velocity: Array
    acceleration: Array
    jerk: Array

    @classmethod
    def from_model(cls, model: RobotModel) -> Limits:
        return cls(model.lower, model.upper, model.max_velocity, model.max_acceleration, model.max_jerk)


def point_from_message(message: Any, dof: int) -> Point:
    """A :class:`Point` from a JOINT_TRAJ_PT, a JOINT_TRAJ point or a JOINT_TRAJ_PT_FULL message.

    The messages carry 10 slots: slots beyond ``dof`` must be 0 (a point for a robot with more
    joints is refused, :attr:`Reason.JOINT_COUNT`). A STOP (sequence -4) needs no valid data.
    """
    if isinstance(message, JointTrajPt | TrajPoint):
        if message.sequence == SpecialSeq.STOP_TRAJECTORY:
            return Point(message.sequence, None)
        positions = _slots(message.joint_data, dof, "positions")
        return Point(
            message.sequence,
            positions,
            duration=float(message.duration),
            velocity_ratio=float(message.velocity),
        )
    if isinstance(message, JointTrajPtFull):
        if message.sequence == SpecialSeq.STOP_TRAJECTORY:
            return Point(message.sequence, None)
        valid = ValidFields(message.valid_fields)
        if ValidFields.TIME not in valid:
            raise PointRejected(Reason.MISSING_FIELDS, "a JOINT_TRAJ_PT_FULL point needs a time (valid_fields TIME)")
        return Point(
            message.sequence,
            _slots(message.positions, dof, "positions") if ValidFields.POSITION in valid else None,
            _slots(message.velocities, dof, "velocities") if ValidFields.VELOCITY in valid else None,
            _slots(message.accelerations, dof, "accelerations") if ValidFields.ACCELERATION in valid else None,
            time=float(message.time),
        )
    raise TypeError(f"not a trajectory point message: {type(message).__name__}")


def _slots(values: Any, dof: int, what: str) -> Array:
    array = np.array(values, dtype=float)
    extra = array[dof:]
    if np.any(extra != 0.0):
        used = dof + int(np.flatnonzero(extra)[-1]) + 1
        raise PointRejected(Reason.JOINT_COUNT, f"{what} has values for {used} joints; this robot has {dof}")
    return array[:dof].copy()


@dataclass
class TrajectoryPlanner:
    """Turns the points of one trajectory at a time into segments (see the module doc).

    :meth:`begin` starts a trajectory from the state where the motion before it ends; :meth:`plan`
    turns the next point into zero or one segment, or raises :class:`PointRejected` and changes
    nothing.
    """

    limits: Limits
    policy: Policy = Policy.QUINTIC
    start_tolerance: float | None = 0.01
    _end: State = field(init=False)
    _fields: ValidFields = field(
        init=False, default=ValidFields.POSITION | ValidFields.VELOCITY | ValidFields.ACCELERATION
    )
    _time: float = field(init=False, default=0.0)
    _first: bool = field(init=False, default=True)

    def __post_init__(self) -> None:
        self._end = State.rest(np.clip(np.zeros_like(self.limits.lower), self.limits.lower, self.limits.upper))

    @property
    def dof(self) -> int:
        return int(self.limits.lower.size)

    @property
    def end(self) -> State:
        """Where the points planned so far end."""
        return self._end

    def begin(self, state: State) -> None:
        """The next point is the first of a trajectory starting at ``state``."""
        self._end = state
        self._fields = _ALL
        self._time = 0.0
        self._first = True

    def plan(self, point: Point) -> Segment | None:
        """The segment to ``point`` (None if the point is the start itself), or PointRejected."""
        target = self._check_point(point)
        first = self._first
        if first and self.start_tolerance is not None:
            gap = np.abs(target - self._end.position)
            worst = int(np.argmax(gap))
            if gap[worst] > self.start_tolerance:
                raise PointRejected(
                    Reason.START_MISMATCH,
                    f"the first point is {gap[worst]:.6g} from the current position of joint {worst + 1} "
                    f"(tolerance {self.start_tolerance:g})",
                    worst,
                )
        if point.time is not None:
            segment, fields = self._plan_full(point, target, first)
        else:
            segment, fields = self._plan_simple(point, target, first), ValidFields.POSITION
        if segment is not None:
            self._check_segment(segment)
            end = segment.end()
            self._end = State(end.position, end.velocity, end.acceleration)
        self._fields = fields
        self._time = point.time if point.time is not None else 0.0
        self._first = False
        return segment

    # ------------------------------------------------------------------------------------------

    def _check_point(self, point: Point) -> Array:
        lim = self.limits
        if point.positions is None:
            raise PointRejected(
                Reason.MISSING_FIELDS, "a point needs positions (velocity-only points are not supported)"
            )
        values = (
            ("positions", point.positions),
            ("velocities", point.velocities),
            ("accelerations", point.accelerations),
        )
        for what, array in values:
            if array is None:
                continue
            if array.shape != (self.dof,):
                raise PointRejected(Reason.JOINT_COUNT, f"{what} has {array.size} values; this robot has {self.dof}")
            if not np.all(np.isfinite(array)):
                raise PointRejected(Reason.NOT_FINITE, f"{what} contains NaN or infinity")
        for what, number in (("time", point.time), ("duration", point.duration), ("velocity", point.velocity_ratio)):
            if number is not None and not math.isfinite(number):
                raise PointRejected(Reason.NOT_FINITE, f"the {what} is {number}")
        p = point.positions
        _within(p, lim.lower, lim.upper, Reason.POSITION_LIMIT, "position")
        if point.velocities is not None:
            _within(point.velocities, -lim.velocity, lim.velocity, Reason.VELOCITY_LIMIT, "velocity")
        if point.accelerations is not None:
            _within(point.accelerations, -lim.acceleration, lim.acceleration, Reason.ACCELERATION_LIMIT, "acceleration")
        return p

    def _check_segment(self, segment: Segment) -> None:
        lim = self.limits
        checks = [(0, lim.lower, lim.upper, Reason.POSITION_LIMIT, "the segment's position")]
        checks.append((1, -lim.velocity, lim.velocity, Reason.VELOCITY_LIMIT, "the segment's velocity"))
        if segment.kind != "linear":  # a linear segment's acceleration is infinite at its ends by design
            checks.append(
                (2, -lim.acceleration, lim.acceleration, Reason.ACCELERATION_LIMIT, "the segment's acceleration")
            )
        for order, lower, upper, reason, what in checks:
            lo, hi = segment.bounds(order)  # cheap; the exact extremes only when the bounds do not settle it
            if np.all(lo >= lower) and np.all(hi <= upper):
                continue
            lo, hi = segment.extremes(order)
            _within(lo, lower, upper, reason, what)
            _within(hi, lower, upper, reason, what)

    def _plan_simple(self, point: Point, target: Array, first: bool) -> Segment | None:
        start = self._end
        delta = np.abs(target - start.position)
        duration = point.duration if point.duration is not None and point.duration > 0.0 else None
        if first and duration is None:
            return None  # the start itself
        if self.policy is Policy.RUCKIG:
            ratio = self._ratio(point, duration is None)
            if duration is None and not np.any(delta):
                return None
            return _ruckig(start, State.rest(target), self.limits, ratio, duration)
        if duration is None:
            if not np.any(delta):
                return None  # already there
            ratio = self._ratio(point, True)
            speed_factor, accel_factor = _PEAKS[self.policy]
            times = speed_factor * delta / (ratio * self.limits.velocity)
            if accel_factor:
                times = np.maximum(times, np.sqrt(accel_factor * delta / self.limits.acceleration))
            duration = float(times.max())
        if not np.any(delta):
            return hold(target, duration)
        if self.policy is Policy.LINEAR:
            return linear(start.position, target, duration)
        if self.policy is Policy.CUBIC:
            return cubic(start.position, target, duration)
        return quintic(start.position, target, duration)

    def _ratio(self, point: Point, needed: bool) -> float:
        ratio = point.velocity_ratio
        if ratio is None or not 0.0 < ratio <= 1.0:
            if not needed and (ratio is None or ratio == 0.0):
                return 1.0
            raise PointRejected(
                Reason.TIMING if ratio is None or ratio <= 0.0 else Reason.VELOCITY_LIMIT,
                f"the velocity ratio {ratio} is not in (0, 1] and the point has no duration",
            )
        return ratio

    def _plan_full(self, point: Point, target: Array, first: bool) -> tuple[Segment | None, ValidFields]:
        assert point.time is not None
        fields = ValidFields.POSITION
        if point.velocities is not None:
            fields |= ValidFields.VELOCITY
            if point.accelerations is not None:
                fields |= ValidFields.ACCELERATION
        duration = point.time - (0.0 if first else self._time)
        if first and point.time <= 0.0:
            if point.time < 0.0:
                raise PointRejected(Reason.TIMING, f"a time from start cannot be negative ({point.time})")
            if np.any(np.abs(target - self._end.position) > (self.start_tolerance or 0.0)):
                raise PointRejected(Reason.TIMING, "the first point is away from the current position and has time 0")
            return None, _ALL
        if duration <= 0.0:
            raise PointRejected(
                Reason.TIMING, f"time {point.time} does not follow the previous point's time {self._time}"
            )
        start = self._end
        both = fields & self._fields
        zero = np.zeros_like(target)
        v1 = point.velocities if point.velocities is not None else zero
        a1 = point.accelerations if point.accelerations is not None else zero
        try:
            if ValidFields.ACCELERATION in both:
                return quintic_hermite(start, (target, v1, a1), duration), fields
            if ValidFields.VELOCITY in both:
                return cubic_hermite(start.position, start.velocity, target, v1, duration), fields
            return linear(start.position, target, duration), fields
        except PlanningError as exc:
            raise PointRejected(Reason.TIMING, str(exc)) from None


def _ruckig(start: State, target: State, limits: Limits, ratio: float, duration: float | None) -> Segment:
    try:
        return RuckigSegment.plan(
            start,
            target,
            limits.velocity * ratio,
            limits.acceleration,
            limits.jerk,
            minimum_duration=duration,
        )
    except PlanningError as exc:
        raise PointRejected(Reason.TIMING, str(exc)) from None


def _within(values: Array, lower: Array, upper: Array, reason: Reason, what: str) -> None:
    slack_lo = _SLACK * np.maximum(1.0, np.abs(lower))
    slack_hi = _SLACK * np.maximum(1.0, np.abs(upper))
    bad = np.flatnonzero((values < lower - slack_lo) | (values > upper + slack_hi))
    if bad.size:
        j = int(bad[0])
        raise PointRejected(
            reason, f"{what} of joint {j + 1} is {values[j]:.6g}, outside {lower[j]:.6g}..{upper[j]:.6g}", j
        )
