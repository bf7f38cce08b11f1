"""Interpolation policies: how the controller joins points that carry positions only (JOINT_TRAJ_PT,
and JOINT_TRAJ_PT_FULL without velocities). Every policy lives in :data:`POLICIES`; adding one
means adding a class here (and its tests): the command line, the emulator and the docs take their
choices from this table.

* ``blend`` (the default): the robot passes through the points, as real controllers do with
  streamed points (MotoROS's cubic segments, ABB's zones, Fanuc's CNT, ros2_control's splines).
  The velocity and acceleration at a point come from its neighbours (:mod:`.blend`), segments
  are quintic Hermite (C2), and a segment too fast for the joints is slowed down, not refused
  (:mod:`.motion` says how).
* ``linear``, ``cubic``, ``quintic``: the paper's shapes, each point reached at rest (linear:
  constant speed, the velocity jumps at every point; cubic: the acceleration jumps; quintic: zero
  velocity and acceleration at every point).
* ``ruckig``: the time-optimal jerk-limited motion to rest at each point.

Under the rest-to-rest policies a point whose segment leaves a limit is refused, as in the
paper's experiment (which these policies reproduce). Their segment time, when a point has no
duration, makes the critical joint peak at ``velocity_ratio`` times its maximum speed within the
acceleration limit; ``blend`` takes it as the mean speed of the critical joint.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from .points import Limits, PointRejected, Reason, State
from .segments import PlanningError, RuckigSegment, Segment, cubic, hold, linear, quintic

__all__ = ["Policy", "POLICIES", "DEFAULT_POLICY", "policy"]

Array = NDArray[np.float64]


class Policy(ABC):
    """One way of joining points (see the module doc)."""

    name: ClassVar[str]
    summary: ClassVar[str]
    #: True: points are passed through and limits slow the motion down (``blend``);
    #: False: every point is reached at rest and a segment beyond a limit is refused
    passes_through: ClassVar[bool] = False
    #: derivatives checked against the limits (rest-to-rest policies)
    checked_orders: ClassVar[tuple[int, ...]] = (1, 2)

    @abstractmethod
    def segment_time(self, delta: Array, ratio: float, limits: Limits) -> float | None:
        """The time of a segment covering ``delta`` (per joint) when the point has no duration,
        or None when the segment's own planning decides it (ruckig)."""

    def to_rest(
        self, start: State, target: Array, duration: float | None, ratio: float, limits: Limits
    ) -> Segment | None:
        """The segment from ``start`` to rest at ``target`` (rest-to-rest policies), None if there
        is nothing to do (already there, no time given). Raises :class:`PointRejected`."""
        raise NotImplementedError(f"the {self.name} policy does not plan segments to rest point by point")


class _PeakShape(Policy):
    """A rest-to-rest polynomial whose peak speed and acceleration are multiples of D/T and D/T^2."""

    speed_factor: ClassVar[float]
    accel_factor: ClassVar[float]

    def segment_time(self, delta: Array, ratio: float, limits: Limits) -> float:
        times = self.speed_factor * np.abs(delta) / (ratio * limits.velocity)
        if self.accel_factor:
            times = np.maximum(times, np.sqrt(self.accel_factor * np.abs(delta) / limits.acceleration))
        return float(times.max())

    def to_rest(
        self, start: State, target: Array, duration: float | None, ratio: float, limits: Limits
    ) -> Segment | None:
        delta = target - start.position
        if duration is None:
            if not np.any(delta):
                return None
            duration = self.segment_time(delta, _ratio(ratio), limits)
        if not np.any(delta):
            return hold(target, duration)
        return self._shape(start.position, target, duration)

    @staticmethod
    @abstractmethod
    def _shape(start: Array, target: Array, duration: float) -> Segment: ...


class Linear(_PeakShape):
    name = "linear"
    summary = "constant speed between points; the velocity jumps at each point (the paper's baseline)"
    checked_orders = (1,)
    speed_factor, accel_factor = 1.0, 0.0

    @staticmethod
    def _shape(start: Array, target: Array, duration: float) -> Segment:
        return linear(start, target, duration)


class Cubic(_PeakShape):
    name = "cubic"
    summary = "the rest-to-rest cubic (the acceleration jumps at each point)"
    speed_factor, accel_factor = 1.5, 6.0

    @staticmethod
    def _shape(start: Array, target: Array, duration: float) -> Segment:
        return cubic(start, target, duration)


class Quintic(_PeakShape):
    name = "quintic"
    summary = "the paper's rest-to-rest quintic (zero velocity and acceleration at each point)"
    # peak speed 1.875 D/T, peak acceleration (10 / sqrt 3) D/T^2 (motion.md §4)
    speed_factor, accel_factor = 1.875, 10.0 / math.sqrt(3.0)

    @staticmethod
    def _shape(start: Array, target: Array, duration: float) -> Segment:
        return quintic(start, target, duration)


class Ruckig(Policy):
    name = "ruckig"
    summary = "time-optimal jerk-limited motion to rest at each point (speed limit scaled by the ratio)"

    def segment_time(self, delta: Array, ratio: float, limits: Limits) -> None:
        return None

    def to_rest(
        self, start: State, target: Array, duration: float | None, ratio: float, limits: Limits
    ) -> Segment | None:
        if duration is None and not np.any(target - start.position):
            return None
        speed = limits.velocity * (_ratio(ratio) if duration is None else ratio or 1.0)
        rest = np.zeros_like(target)
        try:
            return RuckigSegment.plan(
                start, (target, rest, rest), speed, limits.acceleration, limits.jerk, minimum_duration=duration
            )
        except PlanningError as exc:
            raise PointRejected(Reason.TIMING, str(exc)) from None


class Blend(Policy):
    name = "blend"
    summary = "passes through the points: C2 quintic blends, velocities from the neighbours, slowed down at the limits"
    passes_through = True
    checked_orders = (1, 2, 3)

    def segment_time(self, delta: Array, ratio: float, limits: Limits) -> float:
        return float((np.abs(delta) / (_ratio(ratio) * limits.velocity)).max())


def _ratio(ratio: float) -> float:
    if not 0.0 < ratio <= 1.0:
        raise PointRejected(Reason.TIMING, f"the point has no duration and its velocity ratio is {ratio:g}")
    return ratio


#: every policy, by name; the first is the default
POLICIES: dict[str, Policy] = {p.name: p for p in (Blend(), Linear(), Cubic(), Quintic(), Ruckig())}
DEFAULT_POLICY = "blend"


def policy(name: str | Policy) -> Policy:
    """The policy called ``name`` (ValueError naming the known ones otherwise)."""
    if isinstance(name, Policy):
        return name
    try:
        return POLICIES[name]
    except KeyError:
        raise ValueError(f"unknown interpolation policy {name!r} (known: {', '.join(POLICIES)})") from None
