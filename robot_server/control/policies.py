"""Interpolation policies: how the controller joins points that carry positions only (JOINT_TRAJ_PT,
and JOINT_TRAJ_PT_FULL without velocities). Every policy lives in :data:`POLICIES`, by name: the
controller, the emulator and the command line take their choices from this table. A new policy is
a :class:`Policy` subclass registered with :func:`register_policy`, in any module (no file of the
package is edited); :func:`unregister_policy` and :func:`scoped_policies` undo registrations
(tests). CONTRIBUTING.md, "Adding an interpolation policy", has the steps.

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

import re
from abc import ABC, abstractmethod
from contextlib import AbstractContextManager
from typing import ClassVar, TypeVar

import numpy as np

from simple_message.registry import Registry

from ..arrays import Array
from .peaks import CUBIC_PEAK_ACCELERATION, CUBIC_PEAK_VELOCITY, QUINTIC_PEAK_ACCELERATION, QUINTIC_PEAK_VELOCITY
from .points import Limits, PointRejected, Reason, State
from .segments import PlanningError, RuckigSegment, Segment, cubic, hold, linear, quintic

__all__ = [
    "Policy",
    "POLICIES",
    "DEFAULT_POLICY",
    "policy",
    "register_policy",
    "unregister_policy",
    "scoped_policies",
]


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
        times = self.speed_factor * np.abs(delta) / (ratio * limits.max_velocity)
        if self.accel_factor:
            times = np.maximum(times, np.sqrt(self.accel_factor * np.abs(delta) / limits.max_acceleration))
        return float(times.max())

    def to_rest(
        self, start: State, target: Array, duration: float | None, ratio: float, limits: Limits
    ) -> Segment | None:
        delta = target - start.position
        if duration is None:
            if not delta.any():
                return None
            duration = self.segment_time(delta, _ratio(ratio), limits)
        if not delta.any():
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
    speed_factor, accel_factor = CUBIC_PEAK_VELOCITY, CUBIC_PEAK_ACCELERATION

    @staticmethod
    def _shape(start: Array, target: Array, duration: float) -> Segment:
        return cubic(start, target, duration)


class Quintic(_PeakShape):
    name = "quintic"
    summary = "the paper's rest-to-rest quintic (zero velocity and acceleration at each point)"
    # peak speed 1.875 D/T, peak acceleration (10 / sqrt 3) D/T^2 (docs/reference/motion.md §4)
    speed_factor, accel_factor = QUINTIC_PEAK_VELOCITY, QUINTIC_PEAK_ACCELERATION

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
        speed = limits.max_velocity * (_ratio(ratio) if duration is None else ratio or 1.0)
        rest = np.zeros_like(target)
        try:
            return RuckigSegment.plan(
                start, (target, rest, rest), speed, limits.max_acceleration, limits.max_jerk, minimum_duration=duration
            )
        except PlanningError as exc:
            raise PointRejected(Reason.TIMING, str(exc)) from None


class Blend(Policy):
    name = "blend"
    summary = "passes through the points: C2 quintic blends, velocities from the neighbours, slowed down at the limits"
    passes_through = True
    checked_orders = (1, 2, 3)

    def segment_time(self, delta: Array, ratio: float, limits: Limits) -> float:
        return float((np.abs(delta) / (_ratio(ratio) * limits.max_velocity)).max())


def _ratio(ratio: float) -> float:
    if not 0.0 < ratio <= 1.0:
        raise PointRejected(Reason.TIMING, f"the point has no duration and its velocity ratio is {ratio:g}")
    return ratio


#: every policy, by name; the first is the default
POLICIES: Registry[Policy] = Registry("interpolation policy")
for _builtin in (Blend(), Linear(), Cubic(), Quintic(), Ruckig()):
    POLICIES.add(_builtin.name, _builtin)
DEFAULT_POLICY = "blend"


def policy(name: str | Policy) -> Policy:
    """The policy called ``name`` (ValueError naming the known ones otherwise)."""
    if isinstance(name, Policy):
        return name
    return POLICIES.named(name)


_P = TypeVar("_P", bound=Policy)
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]*")
_ORDERS = frozenset((1, 2, 3))  # velocity, acceleration, jerk: the limits a segment is checked against


def register_policy(entry: _P, *, replace: bool = False) -> _P:
    """Make ``entry`` selectable by its :attr:`~Policy.name` everywhere a policy is named
    (``ControllerConfig(policy=...)``, ``EmulatorConfig(interpolation=...)``, ``robot-server
    --import MODULE --interpolation NAME``) and return it.

    Registering the same policy again does nothing (importing its module twice is harmless). Raises
    :class:`ValueError` if the name is another policy's (unless ``replace``), or if ``entry`` is not
    well formed: a name of letters, digits, ``_`` and ``-``; a one-line ``summary``; ``checked_orders``
    within (1, 2, 3); and, for a rest-to-rest policy (``passes_through`` false), its own
    :meth:`~Policy.to_rest`. Nothing is changed then.
    """
    if not isinstance(entry, Policy):
        raise ValueError(f"an interpolation policy is a Policy instance, not {entry!r}")
    kind = type(entry).__name__
    name = getattr(entry, "name", None)
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(f"policy {kind}: its name must be letters, digits, '_' and '-', not {name!r}")
    summary = getattr(entry, "summary", None)
    if not isinstance(summary, str) or not summary.strip() or "\n" in summary:
        raise ValueError(f"policy {name!r}: its summary must be one line of text, not {summary!r}")
    if not isinstance(entry.passes_through, bool):
        raise ValueError(f"policy {name!r}: passes_through must be True or False")
    orders = entry.checked_orders
    if not isinstance(orders, tuple) or not set(orders) <= _ORDERS:
        raise ValueError(f"policy {name!r}: checked_orders must be a tuple of 1, 2 and 3, not {orders!r}")
    if not entry.passes_through and type(entry).to_rest is Policy.to_rest:
        raise ValueError(f"policy {name!r}: a rest-to-rest policy (passes_through False) must implement to_rest")
    POLICIES.add(name, entry, replace=replace)
    return entry


def unregister_policy(name: str) -> Policy:
    """Forget the policy called ``name`` and return it. The default policy stays (every
    configuration that names none uses it): :class:`ValueError`, as for a name not registered.
    Controllers built with the policy keep it. See also :func:`scoped_policies`."""
    if name == DEFAULT_POLICY:
        raise ValueError(f"{name!r} is the default interpolation policy: it can be replaced, not unregistered")
    entry = policy(name)
    del POLICIES[name]
    return entry


def scoped_policies() -> AbstractContextManager[Registry[Policy]]:
    """Undo, on leaving the block, every :func:`register_policy` and :func:`unregister_policy`
    made inside it (:data:`POLICIES` is left exactly as it was entered, the same dict; for tests)."""
    return POLICIES.scoped()
