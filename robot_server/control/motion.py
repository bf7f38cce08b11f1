"""The motion queue: what received points mean over time.

Points arrive one by one (streaming) or as a whole (a download); the controller samples the motion
at its interpolation instants (:meth:`MotionQueue.sample`). In between, the queue holds the
*running* segment and the *pending* ones, each ending at a point (a knot).

**Trajectories.** :meth:`MotionQueue.plan` with ``first=True`` starts a trajectory. Its first point
is the start itself, whatever its duration or time (industrial_robot_client gives it 10 s): it
must lie within ``start_tolerance`` of where everything queued ends (MotoROS refuses it
otherwise, docs/reference/protocol.md §8.1), and the motion goes on from that state, never with a jump. A
JOINT_TRAJ_PT_FULL first point's time is the origin of the times after it. After a stop or an
alarm, the next point starts a trajectory whatever it says.

**Three kinds of points.**

* *Given*: a JOINT_TRAJ_PT_FULL point with velocities (and maybe accelerations): its end state is
  what it says. Segments follow the fields both ends have, as ros2_control's joint trajectory
  controller and MotoROS do (docs/reference/motion.md §3.3, §3.5): velocities give a cubic Hermite (C1), velocities
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
  still adds, and the room to brake before the position limit it heads for, :func:`.checks.state_need`),
  the trajectory is too fast for the robot: the part
  not yet executed (the rest of the running segment and everything pending) is time-scaled
  uniformly (velocities / k, accelerations / k^2) until everything fits, and one WARNING says by how
  much. The scale only grows within a trajectory; the next one starts at 1. (The running segment
  keeps its speed at the instant of the change, so the first re-planned segment absorbs the
  difference.) A downloaded trajectory is slowed down once, when it is complete, for its points'
  states and the segments between them. One exception, MotoROS's: with
  ``follow_given_acceleration`` a given segment beyond the acceleration limit only is run as given
  (MotoROS checks its points' speeds only), and a WARNING says where and by how much
  (:func:`.planning.report_acceleration`).
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
state that the robot can reach going forward only (:func:`.building.reachable`), not one it would back up
for to take a run-up; the next segment is then a transient too. And when the robot sets off to a
point whose next point is the last one queued, with no more in sight (:func:`.braking.coming`:
the points came all at once, slower than the robot runs through them, or the next one is overdue),
or whose next point has joints at rest (holding still or turning there), the point's state is
slowed down as much as it takes for those joints to come to rest at that next point without
passing it (:func:`.braking.braking`). A stream whose points come in time and then stop, the
last one just as the robot sets off to the point before it, while the plan is still fast, can
still end beyond its last point: one point of look-ahead cannot tell the last point from the next.

**A queue that runs dry.** When a segment ends in motion (a given velocity) and nothing follows,
the robot decelerates with the jerk-limited stop of :meth:`MotionQueue.stop`; when an estimated
point's segment to rest would exceed the limits, the robot goes to rest at the point time-optimally
within them (ruckig). Either way it goes on when points arrive, from its state at that instant. A
WARNING says so once per trajectory.

Everything here is sans-I/O and deterministic; the controller owns the clock.

**Where it lives.** :class:`MotionQueue` keeps the queue's snapshot (:class:`.entries.Plan`) and
runs it: :meth:`~MotionQueue.plan` / :meth:`~MotionQueue.commit`, :meth:`~MotionQueue.sample`,
:meth:`~MotionQueue.stop`. The planning is functions of a snapshot, a point and the queue's
:class:`.entries.Context`: :mod:`.planning` (one point), :mod:`.building` (entries and their
segments), :mod:`.checks` (the limits), :mod:`.scaling` (slowing down), :mod:`.braking`
(look-ahead braking).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace

import numpy as np

from ..arrays import Array
from . import planning
from .braking import start_next
from .building import stop_entry, to_rest
from .checks import uniform_need
from .entries import Context, Entry, Plan, Settings, TrajectoryBook, at_rest, connect, knot_of, log, moving
from .points import Limits, Point, PointRejected, Reason, State, check_point
from .policies import Policy
from .scaling import rescale
from .segments import PlanningError, Segment

__all__ = ["MotionQueue", "Plan"]


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
        follow_given_acceleration: bool = False,
    ) -> None:
        self.settings = Settings(
            limits, policy, capacity, start_tolerance, max_duration, lookahead_wait, follow_given_acceleration
        )
        self._t = 0.0
        self._state = start
        self._running: Entry | None = None
        self._started = 0.0
        self._pending: tuple[Entry, ...] = ()
        self._trajectory = TrajectoryBook()
        #: (trajectory, point) where the robot came to rest for want of the next point
        self._stopped_dry: tuple[int, int] | None = None

    @property
    def limits(self) -> Limits:
        return self.settings.limits

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
        return planning.fill(self._snapshot())

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
        return planning.planned_end(self._snapshot(), self._state)

    def _snapshot(self) -> Plan:
        return Plan(
            self._running, self._started, self._pending, self._trajectory, at=self._t, stopped_dry=self._stopped_dry
        )

    def _context(self) -> Context:
        return Context(self.settings, self._t, self._state)

    # -- points --------------------------------------------------------------------------------

    def plan(self, point: Point, *, first: bool, min_scale: float = 1.0, bounded: bool = True) -> Plan:
        """The queue with ``point`` added (``first``: it starts a trajectory; ``bounded``: refuse it
        when the queue is full), without changing anything; raises :class:`PointRejected`. Apply
        the result with :meth:`commit` before the queue is sampled again. ``min_scale``: slow the
        trajectory down to at least this time scale (motion groups that move together share one)."""
        with _typed():
            return planning.plan_scaled(
                self._context(),
                self._snapshot(),
                point,
                first=first,
                min_scale=min_scale,
                bounded=bounded,
            )

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
            plan = planning.plan(
                self._context(),
                self._snapshot(),
                point,
                first=i == 0,
                bounded=False,
                defer=True,
            )
            self.commit(plan)
            needed = max(needed, plan.needed)
        if needed <= 1.0:  # the points' states are within the limits: the segments between them may not be
            number = self._trajectory.number
            mine = [e for e in (self._running, *self._pending) if e is not None and e.segment is not None]
            needed = max([1.0, *(uniform_need(self.settings, e) for e in mine if e.trajectory == number)])
        if needed > 1.0:
            self.commit(rescale(self._context(), self._snapshot(), needed=needed, knot=None))
        self.commit(planning.report_acceleration(self.settings, self._snapshot()))

    def check_start(self, point: Point) -> None:
        """Refuse ``point`` as the first point of a trajectory starting now (PointRejected)."""
        settings = self.settings
        positions = check_point(point, settings.limits, settings.max_duration)
        planning.check_start(settings, positions, self.planned_end())

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
                    entry = to_rest(self.settings, entry, [])
                    segment = entry.segment
                else:
                    segment = connect(entry.start, entry.start_order, entry.end, entry.end_order, entry.duration)
            duration = segment.duration if segment is not None else entry.duration
            left = max(duration - begin, 0.0)
            local = np.linspace(begin, begin + left, max(2, math.ceil(left / step) + 1))
            if segment is not None:
                q = segment.sample(local).position
            else:
                a, b = entry.start.position, knot_of(entry).position
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
        if at_rest(state):
            return 0.0
        entry = stop_entry(self.settings.limits, state)
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
            if done.dry and moving(done.start.velocity):
                self._stopped_dry = (done.trajectory, done.index)
            if self._pending:
                self._start_next(end_time)
            elif moving(done.end.velocity):
                self._warn_dry(f"nothing followed point {done.index}, which the robot passes moving")
                self._running, self._started = stop_entry(self.settings.limits, done.end), end_time
            elif moving(done.end.acceleration):  # at rest, but still accelerating: settle on the point
                self._running, self._started = (
                    stop_entry(self.settings.limits, done.end, at=done.end.position),
                    end_time,
                )
            else:
                self._state = State.rest(done.end.position)
        running = self._running
        if running is not None:
            assert running.segment is not None
            self._state = State(*running.segment.state_at(t - self._started))
        self._t = t
        return self._state

    def _start_next(self, at: float) -> None:
        entry, self._pending = start_next(self.settings, self._pending, self._trajectory, at)
        self._running, self._started = entry, at

    def _waiting(self, entry: Entry) -> bool:
        """A segment from rest to a point whose next point is not queued yet waits a little
        (``lookahead_wait``) for it, so that it can pass through the point: a streaming client
        sends one point at a time (industrial_robot_client: one per 5 ms), and without the next
        one the robot would have to stop at the first point."""
        return (
            entry.end is None and at_rest(entry.start) and self._t < entry.queued + self.settings.lookahead_wait - 1e-12
        )

    def _warn_dry(self, text: str) -> None:
        trajectory = self._trajectory
        if not trajectory.warned_dry:
            log.warning(
                "trajectory %d: the point queue ran dry: %s: decelerating to rest, going on when points arrive",
                trajectory.number,
                text,
            )
            self._trajectory = replace(trajectory, warned_dry=True)


@contextlib.contextmanager
def _typed() -> Iterator[None]:
    """Planning failures of the numbers themselves (a point so extreme that a polynomial
    overflows, ruckig giving up) become a refused point with a reason, never an untyped error."""
    try:
        yield
    except (PlanningError, ArithmeticError, np.linalg.LinAlgError) as exc:
        log.debug("a point could not be planned", exc_info=True)
        raise PointRejected(Reason.TIMING, f"the point cannot be planned ({exc})") from None
