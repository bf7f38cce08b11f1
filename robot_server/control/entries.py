"""The motion queue's data: queued points (knots), the segments ending at them (entries), the
trajectory's book-keeping and the immutable snapshot of it all (:class:`Plan`).

Everything here is a frozen value (compared by identity: they hold arrays, which the planning
never writes into): the planning functions (:mod:`.building`, :mod:`.checks`, :mod:`.scaling`,
:mod:`.braking`, :mod:`.planning`) take a snapshot and a point and return a new snapshot;
:class:`.motion.MotionQueue` keeps the current one and samples it. :class:`Context` is what they
need besides: the queue's fixed settings and the controller's clock and setpoint now.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, fields
from enum import Enum, Flag
from typing import Any

import numpy as np

from ..arrays import Array
from .points import Limits, State
from .policies import Policy
from .segments import Segment, cubic_hermite, linear, quintic_hermite

#: the motion queue's logger: every planning module writes to it, so one name filters them all
log = logging.getLogger(__package__ + ".motion")

#: re-planning the rest of a segment needs at least this much of it left (s)
MIN_REMAINDER = 1e-6


class Kind(Enum):
    """How a point's state is decided (module doc of :mod:`.motion`)."""

    GIVEN = "given"
    ESTIMATED = "estimated"
    REST = "rest"


class Phase(Flag):
    """Where a segment stands against the client's plan (several may hold at once)."""

    #: as the plan leads to it
    PLANNED = 0
    #: starts from a state the client's plan did not lead to (rest, after the queue ran dry): its
    #: limits are met locally (a jerk-limited segment, however long), never by slowing the rest of
    #: the trajectory down
    TRANSIENT = 1
    #: a transient from rest whose end state was slowed down to be reachable
    #: (:func:`.building.reachable`): the next segment starts from a state the plan did not lead to
    SLOWED = 2
    #: ends at rest because no next point was queued when it started
    DRY = 4


@dataclass(frozen=True, slots=True, eq=False)
class Knot:
    """A queued point."""

    position: Array
    #: unscaled seconds from the previous point (None: the rest-to-rest policy decides)
    duration: float | None
    kind: Kind
    trajectory: int
    #: 1, 2, ... within its trajectory (the first point, the start, is 0)
    index: int
    velocity: Array | None = None
    acceleration: Array | None = None
    ratio: float = 0.0
    #: its JOINT_TRAJ_PT_FULL time
    time: float | None = None
    #: a rest point with positions only from a JOINT_TRAJ_PT_FULL: joined linearly (ros2_control)
    linear: bool = False


@dataclass(frozen=True, slots=True, eq=False)
class Entry:
    """A segment of the queue, ending at ``knot`` (None: a stop)."""

    knot: Knot | None
    #: the previous point and the scaled time from it (for estimates)
    before: Array
    before_duration: float
    start: State
    #: the segment's time (scaled; what is left of it after a re-plan)
    duration: float
    end: State | None = None
    segment: Segment | None = None
    #: derivatives the start and end states carry: 1 velocity, 2 velocity and acceleration
    start_order: int = 2
    end_order: int = 2
    #: controller time at which the point was queued
    queued: float = 0.0
    phase: Phase = Phase.PLANNED
    #: the state at its point before it was slowed down to be able to stop at the next point, the
    #: last one queued (:func:`.braking.braking`): restored if a further point comes in time
    unbraked: State | None = None

    @property
    def trajectory(self) -> int:
        return self.knot.trajectory if self.knot is not None else -1

    @property
    def index(self) -> int:
        return self.knot.index if self.knot is not None else 0

    # the phases read as bits of the flag's value: ``Phase.X in phase`` costs a microsecond, and the
    # planning asks several times per point

    @property
    def transient(self) -> bool:
        return bool(self.phase._value_ & _TRANSIENT)

    @property
    def slowed(self) -> bool:
        return bool(self.phase._value_ & _SLOWED)

    @property
    def dry(self) -> bool:
        return bool(self.phase._value_ & _DRY)

    def is_kind(self, kind: Kind) -> bool:
        return self.knot is not None and self.knot.kind is kind

    def marked(self, phase: Phase, on: bool = True, **changes: object) -> Entry:
        """This entry with ``phase`` set (``on``) or cleared, and ``changes`` to its fields."""
        return self.evolve(phase=self.phase | phase if on else self.phase & ~phase, **changes)

    def evolve(self, **changes: Any) -> Entry:
        """This entry with ``changes`` to its fields: :func:`dataclasses.replace`, at a third of its
        cost (it runs several times per planned point)."""
        if not changes.keys() <= _ENTRY_FIELDS:
            raise TypeError(f"Entry has no field {sorted(changes.keys() - _ENTRY_FIELDS)[0]!r}")
        get = changes.get
        return Entry(
            get("knot", self.knot),
            get("before", self.before),
            get("before_duration", self.before_duration),
            get("start", self.start),
            get("duration", self.duration),
            get("end", self.end),
            get("segment", self.segment),
            get("start_order", self.start_order),
            get("end_order", self.end_order),
            get("queued", self.queued),
            get("phase", self.phase),
            get("unbraked", self.unbraked),
        )


_TRANSIENT, _SLOWED, _DRY = Phase.TRANSIENT.value, Phase.SLOWED.value, Phase.DRY.value
_ENTRY_FIELDS = frozenset(f.name for f in fields(Entry))


@dataclass(frozen=True, slots=True, eq=False)
class TrajectoryBook:
    """Book-keeping of the trajectory that points are added to."""

    number: int = 0
    open: bool = False
    scale: float = 1.0
    points: int = 0
    #: time of the last JOINT_TRAJ_PT_FULL point
    time: float = 0.0
    last_position: Array | None = None
    warned_scale: bool = False
    #: the scale last logged (further slowing down is logged once per 10 %)
    logged_scale: float = 1.0
    warned_dry: bool = False
    #: the largest acceleration (x the limit) reported of a given segment run beyond it
    #: (:attr:`Settings.follow_given_acceleration`; 0: none)
    reported_acceleration: float = 0.0
    #: controller time its first point was planned at
    opened: float = 0.0

    def evolve(self, **changes: Any) -> TrajectoryBook:
        """This book with ``changes`` to its fields: :func:`dataclasses.replace`, at a third of its
        cost (once per planned point)."""
        if not changes.keys() <= _BOOK_FIELDS:
            raise TypeError(f"TrajectoryBook has no field {sorted(changes.keys() - _BOOK_FIELDS)[0]!r}")
        get = changes.get
        return TrajectoryBook(
            get("number", self.number),
            get("open", self.open),
            get("scale", self.scale),
            get("points", self.points),
            get("time", self.time),
            get("last_position", self.last_position),
            get("warned_scale", self.warned_scale),
            get("logged_scale", self.logged_scale),
            get("warned_dry", self.warned_dry),
            get("reported_acceleration", self.reported_acceleration),
            get("opened", self.opened),
        )


_BOOK_FIELDS = frozenset(f.name for f in fields(TrajectoryBook))


@dataclass(frozen=True, slots=True, eq=False)
class Plan:
    """The queue after accepting one point (:meth:`.MotionQueue.plan`), applied by :meth:`.MotionQueue.commit`."""

    running: Entry | None
    started: float
    pending: tuple[Entry, ...]
    trajectory: TrajectoryBook
    messages: tuple[tuple[int, str], ...] = ()
    #: the controller time the plan was made at (a plan is good only until the queue is sampled)
    at: float = 0.0
    #: by how much the trajectory must still slow down (plans made with the slowing down deferred)
    needed: float = 1.0
    #: (trajectory, point) where the robot came to rest for want of the next point (the queue's
    #: record, in the snapshot it plans from)
    stopped_dry: tuple[int, int] | None = None

    @property
    def scale(self) -> float:
        """The trajectory's time scale once committed (1: as the client timed it)."""
        return self.trajectory.scale


@dataclass(frozen=True, eq=False)
class Settings:
    """A queue's fixed settings. Compared by identity: segments keep their limit checks per
    settings object (:func:`.checks.excess`)."""

    limits: Limits
    policy: Policy
    capacity: int = 64
    start_tolerance: float | None = 0.01
    max_duration: float = 3600.0
    lookahead_wait: float = 0.008
    #: given segments (velocities given) beyond the acceleration limit are run as given and reported
    #: once per trajectory, not slowed down for: MotoROS checks the points' speeds only
    follow_given_acceleration: bool = False
    #: the keys under which the checks keep their findings for these settings in a segment's memo
    #: (:func:`.checks.end_need`, :func:`.checks.acceleration_ratio`): made once, not one per
    #: segment, which would stay in the collector's scans while its segment lives. They name this
    #: object: a shallow copy (``copy.copy``) would share them, and its segments' findings with them
    #: (``dataclasses.replace`` and ``deepcopy`` make their own); nothing copies settings
    end_need_key: tuple[str, Settings] = field(init=False, repr=False)
    ratio_key: tuple[str, Settings] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.limits.rows  # noqa: B018 - computed now, with the queue, rather than at its first point
        object.__setattr__(self, "end_need_key", ("end need", self))
        object.__setattr__(self, "ratio_key", ("acceleration ratio", self))


@dataclass(frozen=True, slots=True)
class Context:
    """What planning needs besides the snapshot: the settings, and the controller's time and
    setpoint at the instant the queue was last sampled."""

    settings: Settings
    at: float
    state: State

    @property
    def limits(self) -> Limits:
        return self.settings.limits


def connect(start: State, start_order: int, end: State, end_order: int, duration: float) -> Segment:
    """The segment between two states with the derivatives both carry (ros2_control's rule)."""
    order = min(start_order, end_order)
    if order >= 2:
        return quintic_hermite(start, end, duration)
    if order == 1:
        return cubic_hermite(start.position, start.velocity, end.position, end.velocity, duration)
    return linear(start.position, end.position, duration)


def overshoot(entry: Entry) -> float:
    """How far the segment goes beyond its two end positions (the largest over the joints)."""
    assert entry.segment is not None and entry.end is not None
    lo, hi = entry.segment.extremes(0)
    p0, p1 = entry.start.position, entry.end.position
    return float(max(np.max(np.minimum(p0, p1) - lo), np.max(hi - np.maximum(p0, p1)), 0.0))


def overshoots(entry: Entry, tolerance: float) -> bool:
    """``overshoot(entry) > tolerance``, the same answer, decided from the segment's cheap position
    bounds (:meth:`.Segment.bound_lists`, which contain its extremes) when they keep within the
    tolerance of the two end positions with room to spare (:data:`_HULL_MARGIN`), else from the
    exact extremes (polynomial roots: the larger part of a segment's checks)."""
    segment = entry.segment
    assert segment is not None and entry.end is not None
    if not tolerance >= 0.0:  # (overshoot is never below 0: a segment within bounds can still exceed it)
        return overshoot(entry) > tolerance
    low, high = segment.bound_lists(0)
    starts, ends = entry.start.position.tolist(), entry.end.position.tolist()
    for lo, hi, p0, p1 in zip(low, high, starts, ends, strict=True):
        near, far = (p1, p0) if p1 < p0 else (p0, p1)
        room = tolerance - _HULL_MARGIN * (1.0 + abs(near) + abs(far))
        if not (near - lo <= room and hi - far <= room):  # (NaN: not decided here)
            return overshoot(entry) > tolerance
    return False


#: how far inside the tolerance (relative to the positions' size) a segment's bounds must keep for
#: :func:`overshoots` to decide from them: far beyond the rounding of the bounds and of the exact
#: extremes (about 1e-16 of the positions), so either way gives the same answer
_HULL_MARGIN = 1e-9


def knot_of(entry: Entry) -> Knot:
    """The point an entry ends at (it is not a stop)."""
    assert entry.knot is not None
    return entry.knot


def need(duration: float | None) -> float:
    """A duration that must be known by now."""
    assert duration is not None and math.isfinite(duration)
    return duration


def at_rest(state: State) -> bool:
    """No velocity and no acceleration (beyond floating-point noise)."""
    return not (moving(state.velocity) or moving(state.acceleration))


def moving(values: Array) -> bool:
    """Not at rest: velocities or accelerations beyond floating-point noise."""
    return any(abs(value) > 1e-9 for value in values.tolist())
