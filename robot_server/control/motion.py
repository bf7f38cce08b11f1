"""The motion queue: what received points mean over time.

Points arrive one by one (streaming) or as a whole (a download); the controller samples the motion
at its interpolation instants (:meth:`MotionQueue.sample`). In between, the queue holds the
*running* segment and the *pending* ones, each ending at a point (a knot).

**Trajectories.** :meth:`MotionQueue.plan` with ``first=True`` starts a trajectory. Its first point
is the start itself, whatever its duration or time (industrial_robot_client gives it 10 s): it
must lie within ``start_tolerance`` of where everything queued ends (MotoROS refuses it
otherwise, simple-message.md §8.1), and the motion goes on from that state, never with a jump. A
JOINT_TRAJ_PT_FULL first point's time is the origin of the times after it. After a stop or an
alarm, the next point starts a trajectory whatever it says.

**Three kinds of points.**

* *Given*: a JOINT_TRAJ_PT_FULL point with velocities (and maybe accelerations): its end state is
  what it says. Segments follow the fields both ends have, as ros2_control's joint trajectory
  controller and MotoROS do (motion.md §3.3, §3.5): velocities give a cubic Hermite (C1), velocities
  and accelerations a quintic (C2).
* *Estimated*: positions only, under a policy that passes through points (``blend``). The point's
  velocity and acceleration come from its neighbours (:mod:`.blend`), so **its state is fixed when
  the next point is queued**; a segment that starts while no next point is queued ends at rest
  there. If the next point then arrives while that segment runs, the rest of it is re-planned from
  the current setpoint to the new end state over its remaining time (when that stays within the
  limits): a stream that is late by a few milliseconds costs no stop. Arrival times in controller
  time decide all of this, so the same arrivals give the same motion, bit for bit.
* *Rest*: positions only under a rest-to-rest policy: the policy plans the segment when the point
  arrives and a segment beyond a limit is refused (:mod:`.policies`).

**Slowing down.** Given and estimated segments are checked against the velocity, acceleration
and jerk limits (exact extremes), and a segment beyond them is not refused:

* beyond the velocity or acceleration limit (a point's state included: the speed its acceleration
  still adds, and the room to brake before the position limit it heads for, :func:`_state_need`),
  the trajectory is too fast for the robot: the part
  not yet executed (the rest of the running segment and everything pending) is time-scaled
  uniformly (velocities / k, accelerations / k^2) until everything fits, and one WARNING says by how
  much. The scale only grows within a trajectory; the next one starts at 1. (The running segment
  keeps its speed at the instant of the change, so the first re-planned segment absorbs the
  difference.)
* beyond the jerk limit only, the segment alone is replaced by ruckig's jerk-limited motion to the
  same state (when that takes at most 1.5x the segment plus 10 ms and stays within the position
  limits; otherwise the segment keeps its jerk, beyond the limit). Time-optimal planners
  without a jerk limit (MoveIt's TOTG, IPTP) step the acceleration at the start, the end and
  every phase change; blending such a step within the jerk limit needs a few milliseconds more
  than one dense segment has. Stretching that segment costs the robot a few milliseconds of lag
  there, as a real controller's command smoothing does; scaling the whole trajectory for such a
  transient would lengthen it by 20 % and more.

**Points the robot could pass.** Two rules keep it from going beyond monotone points it cannot
stop at. A segment from rest to a point where the plan is already moving fast gets a slower end
state that the robot can reach going forward only (:func:`_reachable`), not one it would back up
for to take a run-up; the next segment is then a transient too. And when the robot sets off to a
point whose next point is the last one queued, with no more in sight (:meth:`MotionQueue._coming`:
the points came all at once, slower than the robot runs through them, or the next one is overdue),
or whose next point has joints at rest (holding still or turning there), the point's state is
slowed down as much as it takes for those joints to come to rest at that next point without
passing it (:meth:`MotionQueue._braking`). A stream whose points come in time and then stop, the
last one just as the robot sets off to the point before it, while the plan is still fast, can
still end beyond its last point: one point of look-ahead cannot tell the last point from the next.

**A queue that runs dry.** When a segment ends in motion (a given velocity) and nothing follows,
the robot decelerates with the jerk-limited stop of :meth:`MotionQueue.stop`; when an estimated
point's segment to rest would exceed the limits, the robot goes to rest at the point time-optimally
within them (ruckig). Either way it goes on when points arrive, from its state at that instant. A
WARNING says so once per trajectory.

Everything here is sans-I/O and deterministic; the controller owns the clock.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from . import blend
from .points import MIN_DURATION, SLACK, Limits, Point, PointRejected, Reason, State, check_point, within
from .policies import Policy
from .segments import (
    PlanningError,
    RuckigSegment,
    Segment,
    cubic_hermite,
    hold,
    launch,
    linear,
    quintic_hermite,
    run_up,
    stop_travel,
)

__all__ = ["MotionQueue", "Plan"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

#: a re-scale slows down by this much more than the limits need
_RESCALE_MARGIN = 1.01
#: how many times a trajectory is re-scaled for one point before the point is refused
_MAX_RESCALES = 12
#: a jerk-limited replacement may take at most this factor times the segment's time plus _MAX_LAG (s)
_MAX_LAG_FACTOR = 1.5
_MAX_LAG = 0.01
#: re-planning the rest of a segment needs at least this much of it left (s)
_MIN_REMAINDER = 1e-6
#: a point's state is slowed down at most this much to be reachable or to let the robot stop at
#: the last queued point (then: at rest)
_MAX_SLOWING = 1024.0
#: with the start check off, a first point farther than this (rad or m) is a move to it
_SAME_PLACE = 1e-9


class _Kind(Enum):
    GIVEN = "given"
    ESTIMATED = "estimated"
    REST = "rest"


@dataclass(frozen=True, slots=True)
class _Knot:
    """A queued point."""

    position: Array
    #: unscaled seconds from the previous point (None: the rest-to-rest policy decides)
    duration: float | None
    kind: _Kind
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


@dataclass(frozen=True, slots=True)
class _Entry:
    """A segment of the queue, ending at ``knot`` (None: a stop)."""

    knot: _Knot | None
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
    #: ends at rest because no next point was queued when it started
    dry: bool = False
    #: controller time at which the point was queued
    queued: float = 0.0
    #: starts from a state the client's plan did not lead to (rest, after the queue ran dry):
    #: its limits are met locally (a jerk-limited segment, however long), never by slowing the
    #: rest of the trajectory down
    transient: bool = False
    #: a transient from rest whose end state was slowed down to be reachable (:func:`_reachable`):
    #: the next segment starts from a state the plan did not lead to either
    slowed: bool = False
    #: the state at its point before it was slowed down to be able to stop at the next point, the
    #: last one queued (:meth:`MotionQueue._braking`): restored if a further point comes in time
    unbraked: State | None = None

    @property
    def trajectory(self) -> int:
        return self.knot.trajectory if self.knot is not None else -1

    @property
    def index(self) -> int:
        return self.knot.index if self.knot is not None else 0

    def is_kind(self, kind: _Kind) -> bool:
        return self.knot is not None and self.knot.kind is kind


@dataclass(frozen=True, slots=True)
class _Trajectory:
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
    #: controller time its first point was planned at
    opened: float = 0.0


@dataclass(frozen=True, slots=True)
class Plan:
    """The queue after accepting one point (:meth:`MotionQueue.plan`), applied by :meth:`MotionQueue.commit`."""

    running: _Entry | None
    started: float
    pending: tuple[_Entry, ...]
    trajectory: _Trajectory
    messages: tuple[tuple[int, str], ...] = ()
    #: the controller time the plan was made at (a plan is good only until the queue is sampled)
    at: float = 0.0
    #: by how much the trajectory must still slow down (plans made with the slowing down deferred)
    needed: float = 1.0

    @property
    def scale(self) -> float:
        """The trajectory's time scale once committed (1: as the client timed it)."""
        return self.trajectory.scale


class MotionQueue:
    """Received points as motion over time (see the module doc)."""

    def __init__(
        self,
        limits: Limits,
        policy: Policy,
        start: State,
        *,
        capacity: int = 64,
        start_tolerance: float | None = 0.01,
        max_duration: float = 3600.0,
        lookahead_wait: float = 0.008,
    ) -> None:
        self.limits = limits
        self.lookahead_wait = lookahead_wait
        self.policy = policy
        self.capacity = capacity
        self.start_tolerance = start_tolerance
        self.max_duration = max_duration
        self._t = 0.0
        self._state = start
        self._running: _Entry | None = None
        self._started = 0.0
        self._pending: tuple[_Entry, ...] = ()
        self._trajectory = _Trajectory()
        #: (trajectory, point) where the robot came to rest for want of the next point
        self._stopped_dry: tuple[int, int] | None = None

    # -- state ---------------------------------------------------------------------------------

    @property
    def state(self) -> State:
        """The setpoint at the last sampled instant."""
        return self._state

    @property
    def moving(self) -> bool:
        """Motion is queued or under way (a stop included)."""
        return self._running is not None or bool(self._pending)

    @property
    def fill(self) -> int:
        """Points queued and not yet reached (the running one included)."""
        running = 1 if self._running is not None and self._running.knot is not None else 0
        return running + len(self._pending)

    @property
    def remaining(self) -> float:
        """Seconds of queued motion still to run."""
        total = sum(e.duration for e in self._pending)
        if self._running is not None:
            total += max(0.0, self._started + self._running.duration - self._t)
        return total

    @property
    def trajectories(self) -> int:
        """Trajectories started so far."""
        return self._trajectory.number

    @property
    def scale(self) -> float:
        """The current trajectory's time scale (1: as the client timed it)."""
        return self._trajectory.scale

    def segments(self) -> list[Segment]:
        """The queued segments already decided, the running one first (an estimated point's
        segment is decided when the next point is queued, or when it starts)."""
        entries = [self._running, *self._pending] if self._running is not None else list(self._pending)
        return [e.segment for e in entries if e.segment is not None]

    def planned_end(self) -> State:
        """Where everything queued ends, the open trajectory's last point at rest (the current
        setpoint if nothing is queued)."""
        if self._pending:
            last = self._pending[-1]
            return last.end if last.end is not None else State.rest(_knot(last).position)
        if self._running is not None and self._running.end is not None:
            return self._running.end
        return self._state

    # -- points --------------------------------------------------------------------------------

    def plan(self, point: Point, *, first: bool, min_scale: float = 1.0, bounded: bool = True) -> Plan:
        """The queue with ``point`` added (``first``: it starts a trajectory; ``bounded``: refuse it
        when the queue is full), without changing anything; raises :class:`PointRejected`. Apply
        the result with :meth:`commit` before the queue is sampled again. ``min_scale``: slow the
        trajectory down to at least this time scale (motion groups that move together share one)."""
        with _typed():
            return self._plan_scaled(point, first=first, min_scale=min_scale, bounded=bounded)

    def _plan_scaled(self, point: Point, *, first: bool, min_scale: float, bounded: bool) -> Plan:
        plan = self._plan(point, first=first, bounded=bounded, defer=False)
        if min_scale > plan.trajectory.scale * (1.0 + SLACK):
            running, started, pending, trajectory = self._rescale(
                plan.running,
                plan.started,
                list(plan.pending),
                plan.trajectory,
                needed=min_scale / (plan.trajectory.scale * _RESCALE_MARGIN),
                knot=None,
                messages=(messages := list(plan.messages)),
            )
            plan = Plan(running, started, tuple(pending), trajectory, tuple(messages), self._t)
        return plan

    def _plan(self, point: Point, *, first: bool, bounded: bool, defer: bool) -> Plan:
        positions = check_point(point, self.limits, self.max_duration)
        trajectory = self._trajectory
        if first or not trajectory.open:
            return self._plan_start(point, positions)
        if bounded and self.fill >= self.capacity:
            raise PointRejected(Reason.QUEUE_FULL, f"the point queue is full ({self.capacity} points)")
        base = Plan(self._running, self._started, self._pending, trajectory, at=self._t)
        return self._plan_point(point, positions, base, defer=defer)

    def commit(self, plan: Plan) -> None:
        """Apply a :class:`Plan` of :meth:`plan` (made since the last commit or sample)."""
        if plan.at != self._t:
            raise RuntimeError("a plan made before the queue was sampled again: plan the point again")
        self._running, self._started, self._pending, self._trajectory = (
            plan.running,
            plan.started,
            plan.pending,
            plan.trajectory,
        )
        for level, message in plan.messages:
            log.log(level, message)

    def add_all(
        self, points: Sequence[Point], *, min_scale: float = 1.0, check: Callable[[], None] | None = None
    ) -> None:
        """A downloaded trajectory: its first point starts it, the others follow; all are accepted
        or none is (and nothing changes). The trajectory is slowed down, if it must be, once at
        the end (not at every point that asks for more, which re-plans everything each time), to
        at least ``min_scale``. ``check`` runs on the queued result: an exception it raises undoes
        everything (and propagates)."""
        saved = (self._running, self._started, self._pending, self._trajectory)
        try:
            with _typed():
                self._add_all(points, min_scale)
            if check is not None:
                check()
        except BaseException:
            self._running, self._started, self._pending, self._trajectory = saved
            raise

    def _add_all(self, points: Sequence[Point], min_scale: float) -> None:
        needed = min_scale
        for i, point in enumerate(points):
            plan = self._plan(point, first=i == 0, bounded=False, defer=True)
            self.commit(plan)
            needed = max(needed, plan.needed)
        if needed > 1.0:
            messages: list[tuple[int, str]] = []
            running, started, pending, trajectory = self._rescale(
                self._running,
                self._started,
                list(self._pending),
                self._trajectory,
                needed=needed,
                knot=None,
                messages=messages,
            )
            self.commit(Plan(running, started, tuple(pending), trajectory, tuple(messages), self._t))

    def check_start(self, point: Point) -> None:
        """Refuse ``point`` as the first point of a trajectory starting now (PointRejected)."""
        self._check_start(check_point(point, self.limits, self.max_duration), self.planned_end())

    def path(self, plan: Plan | None = None, step: float = 0.004) -> tuple[Array, Array]:
        """The joint path still to run (of ``plan`` if given, else of the queue): controller times
        ``(m,)`` and positions ``(m, dof)``, every ``step`` seconds or closer, each segment's ends
        included. A point whose segment is not decided yet (it waits for the next point) counts
        as it would run if it started now (to rest, when it is the last one)."""
        if plan is None:
            running, started, pending, at = self._running, self._started, self._pending, self._t
        else:
            running, started, pending, at = plan.running, plan.started, plan.pending, plan.at
        pieces = ([(running, at - started)] if running is not None else []) + [(e, 0.0) for e in pending]
        times: list[Array] = [np.array([at])]
        positions: list[Array] = [self._state.position[None, :]]
        clock = at
        for entry, begin in pieces:
            segment = entry.segment
            if segment is None:  # not decided yet: as it would be if it started now
                if entry.end is None:
                    entry = self._to_rest(entry, [])
                    segment = entry.segment
                else:
                    segment = _connect(entry.start, entry.start_order, entry.end, entry.end_order, entry.duration)
            duration = segment.duration if segment is not None else entry.duration
            left = max(duration - begin, 0.0)
            local = np.linspace(begin, begin + left, max(2, math.ceil(left / step) + 1))
            if segment is not None:
                q = segment.sample(local).position
            else:
                a, b = entry.start.position, _knot(entry).position
                f = (local - begin) / left if left > 0.0 else np.ones_like(local)
                q = a[None, :] + (b - a)[None, :] * f[:, None]
            times.append(clock + local - begin)
            positions.append(q)
            clock += left
        return np.concatenate(times), np.concatenate(positions)

    # -- stop, abandon, sampling -----------------------------------------------------------------

    def stop(self) -> float:
        """Replace everything queued with a jerk-limited deceleration to rest from the current
        setpoint; the next point starts a trajectory. Returns the deceleration's time."""
        self._pending = ()
        self._running = None
        self._trajectory = replace(self._trajectory, open=False)
        state = self._state
        if _at_rest(state):
            return 0.0
        entry = self._stop_entry(state)
        self._running, self._started = entry, self._t
        return entry.duration

    def abandon(self, position: Array) -> None:
        """Drop all motion at once and hold ``position`` (alarm, e-stop)."""
        self._pending = ()
        self._running = None
        self._trajectory = replace(self._trajectory, open=False)
        self._state = State.rest(position)

    def sample(self, t: float) -> State:
        """The setpoint at controller time ``t`` (increasing from call to call); segments that end
        before ``t`` hand over to the next ones on one continuous timeline."""
        if self._running is None and self._pending and not self._waiting(self._pending[0]):
            self._start_next(self._t)
        while self._running is not None and t >= self._started + self._running.duration:
            done = self._running
            end_time = self._started + done.duration
            self._running = None
            assert done.end is not None
            if done.dry and _moving(done.start.velocity):
                self._stopped_dry = (done.trajectory, done.index)
            if self._pending:
                self._start_next(end_time)
            elif _moving(done.end.velocity):
                self._warn_dry(f"nothing followed point {done.index}, which the robot passes moving")
                self._running, self._started = self._stop_entry(done.end), end_time
            elif _moving(done.end.acceleration):  # at rest, but still accelerating: settle on the point
                self._running, self._started = self._stop_entry(done.end, at=done.end.position), end_time
            else:
                self._state = State.rest(done.end.position)
        running = self._running
        if running is not None:
            assert running.segment is not None
            s = running.segment.sample(t - self._started)
            self._state = State(s.position, s.velocity, s.acceleration)
        self._t = t
        return self._state

    def _waiting(self, entry: _Entry) -> bool:
        """A segment from rest to a point whose next point is not queued yet waits a little
        (``lookahead_wait``) for it, so that it can pass through the point: a streaming client
        sends one point at a time (industrial_robot_client: one per 5 ms), and without the next
        one the robot would have to stop at the first point."""
        return entry.end is None and _at_rest(entry.start) and self._t < entry.queued + self.lookahead_wait - 1e-12

    # -- planning --------------------------------------------------------------------------------

    def _check_start(self, positions: Array, origin: State) -> None:
        if self.start_tolerance is None:
            return
        gap = np.abs(positions - origin.position)
        worst = int(np.argmax(gap))
        if gap[worst] > self.start_tolerance:
            raise PointRejected(
                Reason.START_MISMATCH,
                f"the first point is {gap[worst]:.6g} from the current position of joint {worst + 1} "
                f"(tolerance {self.start_tolerance:g})",
                worst,
            )

    def _plan_start(self, point: Point, positions: Array) -> Plan:
        pending = list(self._pending)
        messages: list[tuple[int, str]] = []
        if pending and pending[-1].end is None:  # the previous trajectory's last point ends at rest
            pending[-1] = self._to_rest(pending[-1], messages)
        origin = self.planned_end() if not pending else pending[-1].end
        assert origin is not None
        self._check_start(positions, origin)
        away = self.start_tolerance is None and bool(np.any(np.abs(positions - origin.position) > _SAME_PLACE))
        trajectory = _Trajectory(
            number=self._trajectory.number + 1,
            open=True,
            points=0 if away else 1,
            time=point.time if point.time is not None and not away else 0.0,
            last_position=origin.position,
            opened=self._t,
        )
        opened = Plan(self._running, self._started, tuple(pending), trajectory, tuple(messages), self._t)
        if away:  # no start check: the robot goes to the first point from where it is
            if point.time is not None and point.time <= 0.0:
                raise PointRejected(
                    Reason.TIMING, "the first point is away from the robot and its time is 0: no time to get there"
                )
            return self._plan_point(point, positions, opened, defer=False)
        return opened

    def _plan_point(self, point: Point, positions: Array, base: Plan, *, defer: bool) -> Plan:
        knot = self._knot(point, positions, base.trajectory)
        if knot is None:  # already there and no time to spend: nothing to do
            return replace(base, trajectory=replace(base.trajectory, points=base.trajectory.points + 1))
        return self._plan_knot(knot, base, defer=defer)

    def _knot(self, point: Point, positions: Array, trajectory: _Trajectory) -> _Knot | None:
        """The queued form of a point after the first (None: nothing to do)."""
        policy = self.policy
        before = trajectory.last_position
        assert before is not None
        ratio = point.velocity_ratio if point.velocity_ratio is not None else 0.0
        number, index = trajectory.number, trajectory.points
        if point.time is not None:
            duration = point.time - trajectory.time
            if not duration >= MIN_DURATION:
                raise PointRejected(
                    Reason.TIMING,
                    f"time {point.time:g} s does not follow the previous point's time {trajectory.time:g} s "
                    f"(by {MIN_DURATION:g} s at least)",
                )
            if duration > self.max_duration:
                raise PointRejected(
                    Reason.TIMING,
                    f"{duration:g} s after the previous point is beyond the maximum segment time "
                    f"({self.max_duration:g} s)",
                )
            if point.velocities is not None:
                kind = _Kind.GIVEN
            else:
                kind = _Kind.ESTIMATED if policy.passes_through else _Kind.REST
            return _Knot(
                positions,
                duration,
                kind,
                number,
                index,
                point.velocities,
                point.accelerations,
                ratio,
                time=point.time,
                linear=kind is _Kind.REST,
            )
        duration_or_none = point.duration if point.duration else None
        if not policy.passes_through:
            return _Knot(positions, duration_or_none, _Kind.REST, number, index, ratio=ratio)
        if duration_or_none is None:
            delta = positions - before
            if not np.any(delta):
                return None
            computed = policy.segment_time(delta, ratio, self.limits)
            assert computed is not None
            self._check_duration(computed, "the time the velocity ratio gives this segment")
            duration_or_none = max(computed, MIN_DURATION)
        return _Knot(positions, duration_or_none, _Kind.ESTIMATED, number, index, ratio=ratio)

    def _check_duration(self, duration: float, what: str) -> None:
        if duration > self.max_duration:
            raise PointRejected(
                Reason.TIMING,
                f"{what} would be {duration:g} s, beyond the maximum segment time ({self.max_duration:g} s)",
            )

    def _plan_knot(self, knot: _Knot, base: Plan, *, defer: bool) -> Plan:
        trajectory = base.trajectory
        scale = trajectory.scale
        pending = list(base.pending)
        running, started = base.running, base.started
        messages = list(base.messages)
        built: list[_Entry] = []  # segments decided now: checked against the limits below
        # set when the robot stands where the client's plan has it moving (the first segment of a
        # trajectory from rest: the plan may start accelerating at once; or after the queue ran
        # dry): this point's segment starts from a state the plan did not lead to (a transient)
        transient = False
        # 1. the point before this one passes through it, now that it is known
        if pending and pending[-1].end is None:
            if len(pending) == 1 and running is not None and running.unbraked is not None:
                # the point it slowed down for is not the last after all: back to the points' state
                restored = self._unbraked(running, started)
                if restored is not None:
                    assert restored.end is not None
                    running, started = restored, self._t
                    pending[-1] = replace(pending[-1], start=restored.end, start_order=2, transient=running.slowed)
            pending[-1] = self._determine(pending[-1], knot.position, _need(knot.duration) * scale)
            built.append(pending[-1])
        elif running is not None and running.dry and running.trajectory == knot.trajectory and not pending:
            late = self._replan_running(running, knot.position, _need(knot.duration) * scale)
            if late is not None:
                running, started = late, self._t
                built.append(running)
            else:
                transient = True
                if _moving(running.start.velocity):
                    messages.append(
                        self._dry_message(
                            trajectory, f"point {knot.index} came too late to pass through point {running.index}"
                        )
                    )
                    trajectory = replace(trajectory, warned_dry=True)
        elif running is not None and running.knot is None and not pending:
            running, started = None, self._t  # a dry stop is under way: go on from the current setpoint
            transient = True
        elif running is None and not pending and self._stopped_dry == (knot.trajectory, knot.index - 1):
            transient = True
            messages.append(self._dry_message(trajectory, f"point {knot.index} came after the robot stopped"))
            trajectory = replace(trajectory, warned_dry=True)
        # 2. this point's segment, from where the one before ends
        if pending:
            start, order = pending[-1].end, pending[-1].end_order
        elif running is not None:
            start, order = running.end, running.end_order
        else:
            start, order = self._state, 2
        assert start is not None and trajectory.last_position is not None
        before = pending[-1] if pending else running
        if (knot.index == 1 and _at_rest(start)) or (before is not None and before.slowed):
            transient = True
        if knot.kind is _Kind.REST:
            segment = self._rest_segment(knot, start)
            if segment is None:
                return Plan(
                    running,
                    started,
                    tuple(pending),
                    replace(trajectory, points=trajectory.points + 1),
                    tuple(messages),
                    self._t,
                )
            entry = _Entry(
                knot,
                trajectory.last_position,
                segment.duration,
                start,
                segment.duration,
                State.rest(knot.position),
                segment,
                start_order=order,
                end_order=0 if knot.linear else 2,  # a linear segment's end carries its position only
            )
        else:
            duration = _need(knot.duration) * scale
            self._check_duration(duration, "slowed down as the trajectory is, this segment")
            entry = _Entry(
                knot,
                trajectory.last_position,
                duration,
                start,
                duration,
                start_order=order,
                queued=self._t,
                transient=transient,
            )
            if knot.kind is _Kind.GIVEN:
                entry = self._stretched(self._given(entry, scale))
                built.append(entry)
        pending.append(entry)
        trajectory = replace(
            trajectory,
            points=trajectory.points + 1,
            last_position=knot.position,
            time=knot.time if knot.time is not None else trajectory.time,
        )
        # 3. the limits: slow the trajectory down rather than refuse the point
        for e in built:
            self._check_position(e)
        if defer:  # what the points' states ask for; the re-scale at the end settles the segments
            needed = max((self._end_need(e) for e in built), default=1.0)
            return Plan(running, started, tuple(pending), trajectory, tuple(messages), self._t, needed)
        needed = max((self._uniform_need(e) for e in built), default=1.0)
        if needed > 1.0:
            running, started, pending, trajectory = self._rescale(
                running, started, pending, trajectory, needed=needed, knot=knot, messages=messages
            )
        return Plan(running, started, tuple(pending), trajectory, tuple(messages), self._t)

    # -- entries -----------------------------------------------------------------------------------

    def _through(self, entry: _Entry, duration: float, after: Array, after_duration: float) -> State:
        """The state at an estimated point for a segment from ``entry.start`` taking ``duration``,
        with the next point ``after`` (:func:`.blend.through_state`)."""
        lim = self.limits
        return blend.through_state(
            entry.start,
            duration,
            _knot(entry).position,
            after=after,
            after_duration=after_duration,
            before=entry.before,
            before_duration=entry.before_duration,
            jerk=lim.jerk,
            acceleration=None if entry.transient else lim.acceleration,  # a transient is met locally anyway
            lower=lim.lower,
            upper=lim.upper,
        )

    def _determine(self, entry: _Entry, after: Array, after_duration: float) -> _Entry:
        """An estimated point's state, now that the next point is known, and the segment to it
        (within the jerk limit: :meth:`_stretched`). A transient from rest (a trajectory's first
        segment, a restart after the queue ran dry) starts as the client's plan does, with an
        acceleration (:func:`.segments.launch`); the quintic from rest would start as t^3 and
        trail a plan over a long first segment by a tenth of a second and more. When the plan
        is moving too fast at the point for the robot to get there from rest without first
        backing up to take a run-up, the point's state is slower (:func:`_reachable`)."""
        end = self._through(entry, entry.duration, after, after_duration)
        if not (entry.transient and _at_rest(entry.start)):
            return self._stretched(
                replace(entry, end=end, segment=_connect(entry.start, entry.start_order, end, 2, entry.duration))
            )
        launched = self._launched(entry, end)
        if _overshoot(launched) <= blend.OVERSHOOT:
            return launched
        reachable = _reachable(entry.start.position, end, self.limits)
        if reachable is end:
            return launched
        slower = replace(self._launched(entry, reachable), slowed=True)
        return slower if _overshoot(slower) < _overshoot(launched) else launched

    def _launched(self, entry: _Entry, end: State) -> _Entry:
        segment = launch(entry.start.position, end, entry.duration, self.limits.jerk)
        if segment is None:
            segment = _connect(entry.start, entry.start_order, end, 2, entry.duration)
        return self._stretched(replace(entry, end=end, segment=segment, slowed=False))

    def _given(self, entry: _Entry, scale: float) -> _Entry:
        """A given point's state at the trajectory's time scale, and the segment to it."""
        knot = _knot(entry)
        assert knot.velocity is not None
        velocity = knot.velocity / scale
        if not _moving(knot.velocity):
            # a point the robot reaches at rest (a trajectory's end: MoveIt's plans stop with the
            # deceleration still on) is reached at rest, not still accelerating
            end, order = State.rest(knot.position), 2
        elif knot.acceleration is not None:
            end, order = State(knot.position, velocity, knot.acceleration / (scale * scale)), 2
        else:
            end, order = State(knot.position, velocity, np.zeros_like(velocity)), 1
        segment = _connect(entry.start, entry.start_order, end, order, entry.duration)
        return replace(entry, end=end, end_order=order, segment=segment)

    def _stretched(self, entry: _Entry) -> _Entry:
        """``entry`` within the jerk limit: a segment beyond it is replaced by ruckig's time-optimal
        jerk-limited motion to the same end state, at least as long as planned. A client's plan
        whose acceleration steps (every time-optimal planner's does) cannot be blended within the
        jerk limit in one segment costs the robot a few milliseconds of lag there, as a real
        controller's command smoothing does, instead of slowing the whole trajectory down. A
        transient (a segment from rest where the plan has the robot moving) gets the same for its
        velocity and acceleration too, however long it takes: the plan is not too fast, the robot
        is late. So does a polynomial that would swing beyond its points by more than the robot
        needs to brake (a fast start over a long segment): ruckig's motion stays within that."""
        excess = self._excess(entry)
        swings = not entry.is_kind(_Kind.GIVEN) and self._swings(entry)
        if entry.transient or swings:
            if max(excess) <= 1.0 and not swings:
                return entry
        elif entry.is_kind(_Kind.GIVEN) or excess[1] <= 1.0:
            return entry  # given states are followed as given (ros2_control, MotoROS)
        assert entry.end is not None
        try:
            segment = self._jerk_limited(entry.start, entry.end, entry.duration)
        except PlanningError as exc:  # an end state beyond the limits: keep the polynomial
            log.debug("point %d: no jerk-limited motion to its state (%s)", entry.index, exc)
            return entry
        if not (entry.transient or swings) and segment.duration > _MAX_LAG_FACTOR * entry.duration + _MAX_LAG:
            # synchronising all joints on moving end states can take ruckig much longer than the
            # segment; a lag that long would distort the path more than the jerk matters
            log.debug("point %d: a jerk-limited segment would take %.3f s", entry.index, segment.duration)
            return entry
        if segment.duration > self.max_duration:
            return entry
        replaced = replace(entry, segment=segment, duration=segment.duration)
        if not self._within_positions(replaced):
            # ruckig knows no position limits: its motion would leave them; the polynomial stays
            # (beyond the velocity or acceleration limit it slows the trajectory down)
            log.debug("point %d: a jerk-limited segment would leave the position limits", entry.index)
            return entry
        return replaced

    def _to_rest(self, entry: _Entry, messages: list[tuple[int, str]]) -> _Entry:
        """An estimated point reached with no next point queued: it ends at rest, within the
        limits (time-optimally, with ruckig, if the planned segment cannot do it)."""
        knot = _knot(entry)
        end = State.rest(knot.position)
        segment = _connect(entry.start, entry.start_order, end, 2, entry.duration)
        candidate = replace(entry, end=end, segment=segment)
        fits = max(self._excess(candidate)) <= 1.0 and self._within_positions(candidate)
        if not fits or self._swings(candidate) or _overshoot(candidate) > blend.OVERSHOOT:
            try:
                segment = self._jerk_limited(entry.start, end, entry.duration)
            except PlanningError as exc:  # a start beyond the limits: the polynomial stands
                log.warning("point %d: no motion to rest there within the limits (%s)", knot.index, exc)
            else:
                if fits and _overshoot(replace(candidate, segment=segment)) >= _overshoot(candidate):
                    # the robot cannot stop short of the point from where it is: of the two, the
                    # motion that goes least beyond it
                    return replace(candidate, dry=True)
                messages.append(
                    (
                        logging.INFO,
                        f"trajectory {knot.trajectory}: coming to rest at point {knot.index} takes "
                        f"{segment.duration:.3f} s within the limits ({entry.duration:.3f} s planned)",
                    )
                )
        return replace(entry, end=end, segment=segment, duration=segment.duration, dry=True)

    def _jerk_limited(self, start: State, end: State, duration: float) -> RuckigSegment:
        """ruckig's time-optimal, jerk-limited motion from ``start`` to ``end`` taking ``duration`` at least."""
        lim = self.limits
        return RuckigSegment.plan(start, end, lim.velocity, lim.acceleration, lim.jerk, minimum_duration=duration)

    def _replan_running(self, running: _Entry, after: Array, after_duration: float) -> _Entry | None:
        """The rest of a segment heading for rest at its point, re-planned to pass through it now
        that the next point is known (None: too late, or beyond the limits)."""
        remaining = self._started + running.duration - self._t
        if remaining < _MIN_REMAINDER:
            return None
        start = self._state
        # the point's state as if the segment had known the next point from its start (its
        # original start and time), then the rest of it from where the robot is now
        end = self._through(running, running.before_duration, after, after_duration)
        segment = _connect(start, 2, end, 2, remaining)
        entry = replace(
            running,
            start=start,
            duration=remaining,
            end=end,
            segment=segment,
            start_order=2,
            dry=False,
        )
        entry = self._stretched(entry)
        if self._excess(entry)[0] > 1.0 or not self._within_positions(entry):
            return None
        return entry

    def _rest_segment(self, knot: _Knot, start: State) -> Segment | None:
        """A rest-to-rest policy's segment; refused beyond the limits."""
        lim = self.limits
        if knot.linear:
            segment: Segment | None = linear(start.position, knot.position, _need(knot.duration))
            orders: tuple[int, ...] = (1,)
        else:
            segment = self.policy.to_rest(start, knot.position, knot.duration, knot.ratio, lim)
            orders = self.policy.checked_orders
        if segment is None:
            return None
        self._check_duration(segment.duration, "this segment")
        for order in (0, *orders):
            lower, upper = (lim.lower, lim.upper) if order == 0 else (-_limit(lim, order), _limit(lim, order))
            lo, hi = segment.bounds(order)  # cheap; the exact extremes only when the bounds do not settle it
            if np.all(lo >= lower) and np.all(hi <= upper):
                continue
            lo, hi = segment.extremes(order)
            reason, what = _REFUSALS[order]
            within(lo, lower, upper, reason, what)
            within(hi, lower, upper, reason, what)
        return segment

    def _stop_entry(self, state: State, at: Array | None = None) -> _Entry:
        """The jerk-limited way to rest from ``state``: wherever it ends, or at ``at``."""
        lim = self.limits
        rest = np.zeros_like(state.position)
        target = (state.position if at is None else at, rest, rest)
        try:
            segment: Segment = RuckigSegment.plan(
                state, target, lim.velocity, lim.acceleration, lim.jerk, velocity_interface=at is None
            )
        except PlanningError:  # pragma: no cover - ruckig plans a stop from any finite state
            log.exception("no jerk-limited stop from %s; holding", state)
            segment = hold(state.position, 1e-3)
        end = State.rest(segment.end().position)
        return _Entry(None, state.position, segment.duration, state, segment.duration, end, segment)

    def _start_next(self, at: float) -> None:
        entry, self._pending = self._pending[0], self._pending[1:]
        if entry.end is None:
            messages: list[tuple[int, str]] = []
            entry = self._to_rest(entry, messages)
            for level, message in messages:
                log.log(level, message)
        elif self._pending and entry.is_kind(_Kind.ESTIMATED):
            after = self._pending[0]
            if after.end is None:
                if len(self._pending) == 1 and not self._coming(entry, after, at):
                    braking = self._braking(entry, after, np.ones(after.start.position.shape, dtype=bool))
                    if braking is not entry:
                        entry = braking
                        assert entry.end is not None
                        self._pending = (replace(after, start=entry.end, start_order=2, transient=True),)
            elif np.any(holds := after.end.velocity == 0.0):
                # joints that hold still or turn at the point after this one: decided, so the
                # robot must be able to stop there (a burst: the points all queued at once)
                braking = self._braking(entry, after, holds)
                if braking is not entry:
                    entry = replace(braking, unbraked=None)
                    assert entry.end is not None
                    segment = _connect(entry.end, 2, after.end, after.end_order, after.duration)
                    after = replace(after, start=entry.end, start_order=2, segment=segment, transient=True)
                    self._pending = (self._stretched(after), *self._pending[1:])
        self._running, self._started = entry, at

    def _coming(self, entry: _Entry, last: _Entry, at: float) -> bool:
        """The point after ``last`` will likely be queued before the robot sets off to ``last``
        (``entry`` starting ``at``): the trajectory is open and its points keep coming at the
        pace they have come so far. Points all queued at once (a download, a burst) say nothing
        of more to come, and nor does a stream whose next point is overdue by more than its
        pace (the client has likely sent its last point; if one still comes, the robot gets
        the state back, :meth:`_unbraked`)."""
        trajectory = self._trajectory
        if not trajectory.open or last.trajectory != trajectory.number or last.index < 1:
            return False
        gap = (last.queued - trajectory.opened) / last.index
        expected = last.queued + gap
        return gap > 0.0 and expected <= at + entry.duration and at <= expected + gap

    def _braking(self, entry: _Entry, last: _Entry, stops: NDArray[np.bool_]) -> _Entry:
        """``entry``, about to run, when the joints ``stops`` may have to come to rest at the
        point after its own, ``last``: it is the last one queued and no next one is in sight
        (:meth:`_coming`; all joints), or its state has them at rest (holding still, turning).
        A state at ``entry``'s point from which those joints can still come to rest at ``last``
        without going beyond it (their fastest stop ends short of it). The state the neighbours
        gave is kept when it allows that; otherwise its velocity (and acceleration) is scaled
        down as little as needed.
        The next segment then starts from a state the plan did not lead to (a transient: the
        robot catches up within its limits, a little late)."""
        end = entry.end
        assert end is not None
        lim = self.limits
        ahead = _knot(last).position - end.position

        def stop_overshoots(f: float) -> bool:
            # where each joint's fastest stop from the slower state ends (closed form: this runs
            # in the controller's tick): beyond the last point, or back before this one, by more
            # than OVERSHOOT
            travel = stop_travel(
                end.velocity / f, end.acceleration / (f * f), limits=(lim.velocity, lim.acceleration, lim.jerk)
            )
            beyond = np.maximum(travel - np.maximum(ahead, 0.0), np.minimum(ahead, 0.0) - travel)
            return bool(np.max(np.where(stops, beyond, 0.0)) > blend.OVERSHOOT)

        if not stop_overshoots(1.0):
            return entry
        # within 0.4 % of the least slowing down (this runs in a tick); at rest when the last point
        # is too close for any speed
        slower = _slowed(end, _least_slowing(lambda f: not stop_overshoots(f), steps=8))
        candidate = self._stretched(
            replace(entry, end=slower, segment=_connect(entry.start, entry.start_order, slower, 2, entry.duration))
        )
        if (
            self._excess(candidate)[0] > 1.0
            or not self._within_positions(candidate)
            or _overshoot(candidate) > max(blend.OVERSHOOT, _overshoot(entry))
        ):
            return entry  # it cannot brake that much on the way to its own point: as planned
        log.debug("point %d: slower through it, to be able to stop at point %d", entry.index, last.index)
        return replace(candidate, unbraked=end)

    def _unbraked(self, running: _Entry, started: float) -> _Entry | None:
        """The rest of a running segment slowed down to be able to stop at the next point
        (:meth:`_braking`), re-planned to the state the points give its own now that a further
        point has come (None: too late, or beyond the limits)."""
        end = running.unbraked
        assert end is not None
        remaining = started + running.duration - self._t
        if remaining < _MIN_REMAINDER:
            return None
        segment = _connect(self._state, 2, end, 2, remaining)
        entry = self._stretched(
            replace(
                running, start=self._state, start_order=2, duration=remaining, end=end, segment=segment, unbraked=None
            )
        )
        if (
            entry.duration > _MAX_LAG_FACTOR * remaining + _MAX_LAG  # as late as a jerk replacement may be
            or self._excess(entry)[0] > 1.0
            or not self._within_positions(entry)
            or _overshoot(entry) > blend.OVERSHOOT
        ):
            return None
        return entry

    # -- limits ------------------------------------------------------------------------------------

    def _excess(self, entry: _Entry) -> tuple[float, float]:
        """By how much the segment's time must grow for its velocity and acceleration, and for its
        jerk, to be within the limits (1: they are); uniform time scaling divides the k-th
        derivative by factor^k."""
        segment = entry.segment
        assert segment is not None
        cached = segment.memo.get(self)
        if cached is not None:
            return cached  # type: ignore[return-value]
        lim = self.limits
        needed = [1.0, 1.0, 1.0, 1.0]
        for order in range(1, min(segment.bounded_order, 3) + 1):
            limit = _limit(lim, order)
            lo, hi = segment.bounds(order)
            if np.all(np.maximum(-lo, hi) <= limit):
                continue
            lo, hi = segment.extremes(order)
            excess = float(np.max(np.maximum(-lo, hi) / limit))
            if excess > 1.0 + SLACK:
                needed[order] = excess ** (1.0 / order)
        result = max(needed[1], needed[2]), needed[3]
        segment.memo[self] = result
        return result

    def _swings(self, entry: _Entry) -> bool:
        """The segment goes beyond its two points by more than OVERSHOOT plus what the robot needs
        to brake from its start (its Bezier hull says so: cheap, and exact enough to flag a fast
        start over a long segment, which a quintic turns into a long excursion)."""
        segment = entry.segment
        assert segment is not None and entry.end is not None
        lo, hi = segment.bounds(0)
        lim = self.limits
        v0, a0 = np.abs(entry.start.velocity), np.abs(entry.start.acceleration)
        ramp = (a0 + lim.acceleration) / lim.jerk  # time to turn the acceleration round
        fastest = v0 + a0 * ramp
        braking = fastest * ramp + fastest * fastest / (2.0 * lim.acceleration) + blend.OVERSHOOT
        p0, p1 = entry.start.position, entry.end.position
        return bool(np.any(lo < np.minimum(p0, p1) - braking) or np.any(hi > np.maximum(p0, p1) + braking))

    def _uniform_need(self, entry: _Entry) -> float:
        """By how much the whole trajectory must slow down for this segment: its velocity and
        acceleration excess; for a transient first its end state's (the start is the robot being
        late, met locally; an end state beyond the limits is a plan too fast from there on), then,
        if the local fix failed, its own."""
        if not entry.transient:
            return max(self._excess(entry)[0], self._end_need(entry) if entry.end is not None else 1.0)
        need = self._end_need(entry)
        if need > 1.0:
            return need
        # an end state within the limits that the local fix could still not reach (it would have
        # to go faster than the limits to get there in time): the segment's own excess
        return self._excess(entry)[0]

    def _end_need(self, entry: _Entry) -> float:
        """By how much the trajectory must slow down for the segment's end state to be within the
        velocity and acceleration limits (1: it is), :func:`_state_need`; kept with the segment
        built to that state (a re-scale asks again for every pending segment)."""
        end, segment = entry.end, entry.segment
        assert end is not None
        if segment is None:
            return _state_need(end, self.limits)
        key = ("end need", self)
        cached = segment.memo.get(key)
        if cached is None:
            cached = segment.memo[key] = _state_need(end, self.limits)
        return cached  # type: ignore[return-value]

    def _within_positions(self, entry: _Entry) -> bool:
        segment = entry.segment
        assert segment is not None
        lim = self.limits
        lo, hi = segment.bounds(0)
        if np.all(lo >= lim.lower) and np.all(hi <= lim.upper):
            return True
        lo, hi = segment.extremes(0)
        slack = SLACK * np.maximum(1.0, np.abs(lim.upper))
        return bool(np.all(lo >= lim.lower - slack) and np.all(hi <= lim.upper + slack))

    def _check_position(self, entry: _Entry) -> None:
        """Refuse a segment that leaves the position limits (a given velocity can swing it out)."""
        if not self._within_positions(entry):
            assert entry.segment is not None
            lo, hi = entry.segment.extremes(0)
            lim = self.limits
            within(lo, lim.lower, lim.upper, Reason.POSITION_LIMIT, "the segment's position")
            within(hi, lim.lower, lim.upper, Reason.POSITION_LIMIT, "the segment's position")

    def _rescale(
        self,
        running: _Entry | None,
        started: float,
        pending: list[_Entry],
        trajectory: _Trajectory,
        *,
        needed: float,
        knot: _Knot | None,
        messages: list[tuple[int, str]],
    ) -> tuple[_Entry | None, float, list[_Entry], _Trajectory]:
        """Time-scale what is not yet executed of the trajectory until it fits the limits (``knot``:
        the point that asks for it; None: a download as a whole, or motion groups that share one
        time scale)."""
        was = trajectory.scale
        cause = f"point {knot.index}" if knot is not None else "the trajectory"
        for _ in range(_MAX_RESCALES):
            # a margin: points rounded to float32 on the wire would otherwise put the next ones a
            # hair over the limit, and every re-scale disturbs the segment under way
            factor = needed * _RESCALE_MARGIN
            trajectory = replace(trajectory, scale=trajectory.scale * factor)
            for e in pending:  # refused before the segments are built: they could overflow
                if e.trajectory == trajectory.number and e.knot is not None and e.knot.duration is not None:
                    self._check_duration(
                        e.knot.duration * trajectory.scale,
                        f"slowed down to fit the limits, the segment to point {e.index}",
                    )
            running, started, pending = self._scaled(running, started, pending, trajectory, factor)
            mine = [e for e in [running, *pending] if e is not None and e.segment is not None]
            mine = [e for e in mine if e.trajectory == trajectory.number]
            needed = max((self._uniform_need(e) for e in mine), default=1.0)
            if needed <= 1.0:
                break
        else:
            raise PointRejected(Reason.TIMING, f"{cause}: the trajectory cannot be slowed down to fit the limits")
        for e in mine:
            self._check_position(e)
        for e in pending:  # decided or not
            if e.trajectory == trajectory.number:
                self._check_duration(e.duration, f"slowed down to fit the limits, the segment to point {e.index}")
        text = (
            f"trajectory {trajectory.number}: {cause} is too fast for the joints' limits: the rest of "
            f"the trajectory is slowed down to x{trajectory.scale:.3f} its time ({(trajectory.scale - 1) * 100:.1f}% "
            f"longer)"
        )
        if not trajectory.warned_scale:
            messages.append((logging.WARNING, text))
            trajectory = replace(trajectory, warned_scale=True, logged_scale=trajectory.scale)
        elif trajectory.scale >= 1.1 * trajectory.logged_scale:  # more: at INFO, once per 10 % (no flood)
            messages.append((logging.INFO, f"{text}, was x{was:.3f}"))
            trajectory = replace(trajectory, logged_scale=trajectory.scale)
        else:
            messages.append((logging.DEBUG, f"{text}, was x{was:.3f}"))
        return running, started, pending, trajectory

    def _scaled(
        self, running: _Entry | None, started: float, pending: list[_Entry], trajectory: _Trajectory, factor: float
    ) -> tuple[_Entry | None, float, list[_Entry]]:
        """The trajectory's part not yet executed, ``factor`` times slower: the rest of the running
        segment (when that stays within the limits) and its pending segments."""
        number, scale = trajectory.number, trajectory.scale
        mine = [e.trajectory == number and not e.is_kind(_Kind.REST) for e in pending]
        # the first pending segment starts from the running one's end: at the old speed unless the
        # rest of the running segment is re-planned at the new scale (then a transient)
        transition = running is not None and running.trajectory == number
        if running is not None and running.trajectory == number and not running.is_kind(_Kind.REST):
            remaining = (started + running.duration - self._t) * factor
            if remaining >= _MIN_REMAINDER:
                successor = pending[0] if pending and mine[0] else None
                candidate = self._rebuilt(
                    replace(
                        running,
                        start=self._state,
                        start_order=2,
                        duration=remaining,
                        before_duration=running.before_duration * factor,
                        unbraked=None,
                    ),
                    successor,
                    scale,
                )
                if candidate.segment is not None:
                    candidate = self._stretched(candidate)
                if (
                    candidate.segment is not None
                    and self._excess(candidate)[0] <= 1.0
                    and self._within_positions(candidate)
                ):
                    running, started, transition = candidate, self._t, False
        end, order = (running.end, running.end_order) if running is not None else (self._state, 2)
        slowed = running is not None and running.slowed
        out: list[_Entry] = []
        for i, entry in enumerate(pending):
            if mine[i]:
                duration = _need(_knot(entry).duration) * scale
                assert end is not None
                moved = replace(entry, start=end, start_order=order, duration=duration, before_duration=duration)
                if transition or slowed:
                    moved = replace(moved, transient=True)
                    transition = False
                successor = pending[i + 1] if i + 1 < len(pending) and mine[i + 1] else None
                entry = self._rebuilt(moved, successor, scale)
                if entry.segment is not None:
                    entry = self._stretched(entry)
            out.append(entry)
            end, order, slowed = entry.end, entry.end_order, entry.slowed
        return running, started, out

    def _rebuilt(self, entry: _Entry, successor: _Entry | None, scale: float) -> _Entry:
        """``entry`` planned again from its start at ``scale``: an estimated point without a next
        one stays undecided."""
        if entry.is_kind(_Kind.GIVEN):
            return self._given(entry, scale)
        if entry.dry:
            end = State.rest(_knot(entry).position)
            return replace(entry, end=end, segment=_connect(entry.start, entry.start_order, end, 2, entry.duration))
        if successor is None:
            return replace(entry, end=None, segment=None)
        return self._determine(entry, _knot(successor).position, _need(_knot(successor).duration) * scale)

    # -- messages ----------------------------------------------------------------------------------

    def _warn_dry(self, text: str) -> None:
        trajectory = self._trajectory
        if not trajectory.warned_dry:
            log.warning(
                "trajectory %d: the point queue ran dry: %s: decelerating to rest, going on when points arrive",
                trajectory.number,
                text,
            )
            self._trajectory = replace(trajectory, warned_dry=True)

    @staticmethod
    def _dry_message(trajectory: _Trajectory, text: str) -> tuple[int, str]:
        level = logging.DEBUG if trajectory.warned_dry else logging.WARNING
        return level, f"trajectory {trajectory.number}: the point queue ran dry: {text}: the robot went on from there"


_REFUSALS = {
    0: (Reason.POSITION_LIMIT, "the segment's position"),
    1: (Reason.VELOCITY_LIMIT, "the segment's velocity"),
    2: (Reason.ACCELERATION_LIMIT, "the segment's acceleration"),
    3: (Reason.TIMING, "the segment's jerk"),
}


def _limit(limits: Limits, order: int) -> Array:
    return {1: limits.velocity, 2: limits.acceleration, 3: limits.jerk}[order]


@contextlib.contextmanager
def _typed() -> Iterator[None]:
    """Planning failures of the numbers themselves (a point so extreme that a polynomial
    overflows, ruckig giving up) become a refused point with a reason, never an untyped error."""
    try:
        yield
    except (PlanningError, ArithmeticError, np.linalg.LinAlgError) as exc:
        log.debug("a point could not be planned", exc_info=True)
        raise PointRejected(Reason.TIMING, f"the point cannot be planned ({exc})") from None


def _connect(start: State, start_order: int, end: State, end_order: int, duration: float) -> Segment:
    """The segment between two states with the derivatives both carry (ros2_control's rule)."""
    order = min(start_order, end_order)
    if order >= 2:
        return quintic_hermite(start, end, duration)
    if order == 1:
        return cubic_hermite(start.position, start.velocity, end.position, end.velocity, duration)
    return linear(start.position, end.position, duration)


def _state_need(state: State, limits: Limits) -> float:
    """By how much a trajectory must slow down (velocities / k, accelerations / k^2) for one of its
    states to be within the velocity and acceleration limits (1: it is), counting the speed a joint
    still gains while its acceleration is brought to 0 at the jerk limit (a^2 / 2 J, when the
    acceleration speeds it up): from a state beyond that, every motion leaves the velocity limit,
    the controller's stop included."""
    speed = np.abs(state.velocity)
    direction = np.sign(state.velocity)
    push = state.acceleration * direction
    gain = np.where(push > 0.0, push * push / (2.0 * limits.jerk), 0.0)  # at k = 1; / k^4 when scaled
    need = max(1.0, float(np.max(speed / limits.velocity)))
    need = max(need, math.sqrt(float(np.max(np.abs(state.acceleration) / limits.acceleration))))
    # room to brake before the position limit the joint heads for
    room = np.where(direction > 0.0, limits.upper - state.position, state.position - limits.lower)

    def fits(k: float) -> bool:
        v, a = speed / k, np.maximum(push, 0.0) / (k * k)
        if not np.all(v + gain / k**4 <= limits.velocity * (1.0 + SLACK)):
            return False
        ramp = (a + limits.acceleration) / limits.jerk  # to turn the acceleration round
        fastest = v + a * ramp
        braking = fastest * ramp + fastest * fastest / (2.0 * limits.acceleration)
        return bool(np.all(braking <= room + SLACK))

    if not fits(need):
        # both terms fall with k: at ``high`` each is at most half the limit
        low, high = need, max(need, float(np.max(2.0 * speed / limits.velocity)))
        high = max(high, float(np.max(2.0 * gain / limits.velocity) ** 0.25))
        while not fits(high):  # braking room: the braking distance falls as 1 / k (at least)
            if high > 1e6:
                return high  # no room at all (a joint at its limit, moving on): slowing cannot help
            high *= 2.0
        for _ in range(48):
            middle = 0.5 * (low + high)
            low, high = (low, middle) if fits(middle) else (middle, high)
        need = high
    return need if need > 1.0 + SLACK else 1.0


def _reachable(start: Array, state: State, limits: Limits) -> State:
    """``state``, or the same state slower (velocities / k, accelerations / k^2, for all joints
    alike) so that every joint can reach it from rest at ``start`` without first moving away from
    it: the shortest way to its speed and acceleration (:func:`.segments.run_up`) fits in the
    distance. A plan that is already moving fast at its first point (one that starts at speed, or
    a point far too soon for its distance) would otherwise have the robot back up to take a run-up."""
    distance = state.position - start
    direction = np.sign(distance)
    speed = state.velocity * direction
    room = np.abs(distance)
    concerned = (speed > 0.0) & (room > 0.0)
    if not np.any(concerned):
        return state
    zero = np.zeros_like(speed)

    def fits(k: float) -> bool:
        target = np.where(concerned, speed / k, 0.0)
        target_acc = np.where(concerned, state.acceleration * direction / (k * k), 0.0)
        needed = run_up(zero, zero, target, target_acc, limits=(limits.velocity, limits.acceleration, limits.jerk))
        return bool(np.all(np.where(concerned, needed <= room * (1.0 + SLACK) + 1e-12, True)))

    if fits(1.0):
        return state
    k = _least_slowing(fits, steps=24)
    # within the limits too: slowing the trajectory down would not change a state chosen here
    return _slowed(state, None if k is None else max(k, _state_need(state, limits) * (1.0 + SLACK)))


def _least_slowing(fits: Callable[[float], bool], *, steps: int) -> float | None:
    """About the least factor k > 1 for which ``fits(k)`` (which must hold from some k on):
    doubling, then ``steps`` bisections; None beyond :data:`_MAX_SLOWING`."""
    low, high = 1.0, 2.0
    while not fits(high):
        if high >= _MAX_SLOWING:
            return None
        low, high = high, 2.0 * high
    for _ in range(steps):
        middle = 0.5 * (low + high)
        low, high = (low, middle) if fits(middle) else (middle, high)
    return high


def _slowed(state: State, k: float | None) -> State:
    """``state`` as a trajectory k times slower passes it (None: at rest)."""
    if k is None:
        return State.rest(state.position)
    return State(state.position, state.velocity / k, state.acceleration / (k * k))


def _overshoot(entry: _Entry) -> float:
    """How far the segment goes beyond its two end positions (the largest over the joints)."""
    assert entry.segment is not None and entry.end is not None
    lo, hi = entry.segment.extremes(0)
    p0, p1 = entry.start.position, entry.end.position
    return float(max(np.max(np.minimum(p0, p1) - lo), np.max(hi - np.maximum(p0, p1)), 0.0))


def _knot(entry: _Entry) -> _Knot:
    assert entry.knot is not None
    return entry.knot


def _need(duration: float | None) -> float:
    assert duration is not None and math.isfinite(duration)
    return duration


def _at_rest(state: State) -> bool:
    """No velocity and no acceleration (beyond floating-point noise)."""
    return not (_moving(state.velocity) or _moving(state.acceleration))


def _moving(values: Array) -> bool:
    """Not at rest: velocities or accelerations beyond floating-point noise."""
    return bool(np.any(np.abs(values) > 1e-9))
