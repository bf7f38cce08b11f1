"""Joint moves as a controller's own move instruction runs them: Fanuc's ``J P[] R% CNT c``, VAL3's movej.

A ROS streamer's points are a trajectory: each carries the time at which the robot is to be there.
Some controller-side servers do not run them as one. Fanuc's relay hands each point to a TP program
that moves there with ``J PR[2] R[1]% CNT R[2]`` (ros_movesm.ls), and Stäubli's VAL3 server calls
``movej`` for each (motionControl.pgx): a point is a move instruction, run at a share of the
joints' speed, and the time it carries is ignored. :class:`JointMoves` is that way of moving.

**A move** is joint-interpolated and synchronised: every joint starts and stops together, on one
jerk-limited rest-to-rest profile of the path parameter s from 0 to 1 (ruckig, one degree of
freedom), whose speed, acceleration and jerk are the tightest any joint allows: joint j covers
``delta_j`` at ``speed x max_velocity_j`` at most, ``acceleration x max_acceleration_j`` and
``max_jerk_j``. So the joint with the longest way at its speed limit sets the time, and the others
move proportionally slower, as a joint move's does on the real controllers. A move to where the
robot already is takes no time.

**Blending** (Fanuc's CNT; VAL3's blend, which the ROS server leaves off): the next move may begin
before the current one has ended, superposed on it (the position is the sum of both moves' shares
of their ways): during the overlap the robot runs the end of the current move's deceleration and
the start of the next one's acceleration at once, so it turns the corner without stopping and
passes near the point, not through it. The overlap is ``blend`` times the shorter of the current
move's deceleration and the next move's acceleration: 0 stops at every point (VAL3 with blend off;
Fanuc's CNT0), 1 overlaps them fully (CNT100). Superposition is how point-to-point moves are
commonly blended; a real controller's corner is its own (Fanuc's CNT also depends on speed), so in
a corner the path is close, not equal, to the real robot's; the time of each move, and so of the
motion, is the real one's as far as its speed and acceleration limits are the model's. A move that
comes after the current one's blending window has begun starts at once (a shorter overlap); one
that comes after the current one has ended starts from rest.

:meth:`JointMoves.ready_at` tells when the program running the moves could take the next one: a
TP program's ``J ... CNT`` line lets the program go on when the blending window begins (at once
for a move from rest). Where a joint turns back (its way in the next move is opposite to the
one in the current move), the current move's deceleration and the next one's acceleration have
the same sign for that joint and add up: the overlap is then at most the last jerk ramp of the
current move (its acceleration dying away) and the first of the next (building up), over which the
sum of the two ramps stays within the larger of them, so within the joint's acceleration limit.

A stop decelerates from the current setpoint to rest, jerk-limited within the full limits (as
:meth:`.motion.MotionQueue.stop`). A move that comes while a stop is under way is planned from
where the stop ends and begins when it has ended: a stop is never cut short, so the setpoint stays
continuous in velocity and acceleration. Sans-I/O and deterministic: the controller samples it at
its interpolation instants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..arrays import Array
from .points import Limits, PointRejected, Reason, State, within
from .segments import PlanningError, RuckigSegment

__all__ = ["JointMoves", "Move"]

#: joints that move less than this (rad or m) do not constrain a move's profile
_STILL = 1e-12


@dataclass(frozen=True)
class Move:
    """One planned move: from ``start`` to ``target`` on ``profile`` (s from 0 to 1), beginning at
    controller time ``begin``."""

    begin: float
    start: Array
    target: Array
    #: the rest-to-rest profile of the path parameter (None: a move of no length)
    profile: RuckigSegment | None
    #: how long the profile accelerates and decelerates (s)
    accelerating: float
    decelerating: float
    #: how long its acceleration takes to build up at the start and to die away at the end (s)
    ramp_in: float = 0.0
    ramp_out: float = 0.0

    @property
    def duration(self) -> float:
        return 0.0 if self.profile is None else self.profile.duration

    @property
    def end(self) -> float:
        return self.begin + self.duration


class JointMoves:
    """A sequence of joint moves, blended by superposition (see the module doc)."""

    def __init__(self, limits: Limits, start: Array) -> None:
        self.limits = limits
        #: where the moves not yet folded in begin (the robot's position before them)
        self._base = np.array(start, dtype=float)
        self._moves: list[Move] = []
        #: a deceleration to rest replacing the moves, and when it began
        self._stopping: tuple[float, RuckigSegment] | None = None
        self._state = State.rest(self._base)
        #: the last sampled instant (controller time): new moves act from here
        self._t = 0.0

    # -- state -----------------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        """Moves are queued or running, or a stop decelerates."""
        return bool(self._moves) or self._stopping is not None

    @property
    def stopping(self) -> bool:
        """A stop decelerates (moves queued meanwhile begin when it has ended)."""
        return self._stopping is not None

    @property
    def fill(self) -> int:
        """Moves not yet ended (the running ones included)."""
        return sum(1 for m in self._moves if m.end > self._t)

    def remaining(self) -> float:
        """Seconds until the last move (or the stop) ends."""
        ends = [m.end for m in self._moves]
        if self._stopping is not None:
            ends.append(self._stop_end())
        return max(0.0, max(ends) - self._t) if ends else 0.0

    @property
    def end_position(self) -> Array:
        """Where the queued moves end (the target of the last one), or the stop does."""
        if self._moves:
            return self._moves[-1].target
        if self._stopping is not None:
            return self._stop_position()
        return self._state.position

    def _stop_end(self) -> float:
        assert self._stopping is not None
        begin, segment = self._stopping
        return begin + segment.duration

    def _stop_position(self) -> Array:
        assert self._stopping is not None
        return self._stop_position_of(self._stopping[1])

    @staticmethod
    def _stop_position_of(segment: RuckigSegment) -> Array:
        return np.array(segment.sample(segment.duration).position, dtype=float)

    def ready_at(self, blend: float) -> float:
        """When a program running these moves one instruction at a time could take the next one:
        when the last move's blending window begins (``blend`` times its deceleration, as a TP
        program's CNT; the next move may still begin later, where a joint turns back), or now."""
        if not self._moves:
            return self._t
        last = self._moves[-1]
        return max(self._t, last.end - blend * last.decelerating)

    # -- planning --------------------------------------------------------------------------------

    def plan(
        self,
        target: Array,
        *,
        speed: float,
        blend: float = 0.0,
        acceleration: float = 1.0,
        rest: Array | None = None,
        now: float | None = None,
    ) -> Move:
        """A move to ``target`` at ``speed`` (a share of each joint's maximum speed, 0 < speed <= 1)
        and ``acceleration`` (a share of the maximum acceleration), blended into the last queued
        move by ``blend`` (0..1), or from ``rest`` (where the robot is) when none is queued, from
        controller time ``now`` at the earliest (default: the last sampled instant). Nothing
        changes until :meth:`commit`. Raises :class:`PointRejected` for a target outside the
        position limits or a share outside (0, 1]."""
        if now is not None and not self.active:
            self._t = now
        lim = self.limits
        target = np.array(target, dtype=float)
        if target.shape != lim.lower.shape:
            raise PointRejected(Reason.JOINT_COUNT, f"the target has {target.size} values; this robot has {lim.dof}")
        if not np.all(np.isfinite(target)):
            raise PointRejected(Reason.NOT_FINITE, "the target contains NaN or infinity")
        for what, fraction in (("speed", speed), ("acceleration", acceleration)):
            if not (math.isfinite(fraction) and 0.0 < fraction <= 1.0):
                raise PointRejected(Reason.VELOCITY_LIMIT, f"a move's {what} share must be in (0, 1], not {fraction:g}")
        if not 0.0 <= blend <= 1.0:
            raise ValueError(f"blend must be within 0..1, not {blend}")
        within(target, lim.lower, lim.upper, Reason.POSITION_LIMIT, "position")
        previous = self._moves[-1] if self._moves else None
        if previous is not None:
            start = previous.target
        elif self._stopping is not None:  # the stop runs to its end first
            start = self._stop_position()
        elif rest is not None:
            start = np.array(rest, dtype=float)
        else:
            start = self._state.position
        delta = target - start
        way = np.abs(delta)
        moving = way > _STILL
        earliest = self._t if self._stopping is None else max(self._t, self._stop_end())
        if not np.any(moving):
            begin = earliest if previous is None else max(earliest, previous.end)
            return Move(begin, start, target, None, 0.0, 0.0)
        share = way[moving]
        v = float(np.min(speed * lim.max_velocity[moving] / share))
        a = float(np.min(acceleration * lim.max_acceleration[moving] / share))
        j = float(np.min(lim.max_jerk[moving] / share))
        try:
            profile = RuckigSegment.plan(([0.0], [0.0], [0.0]), ([1.0], [0.0], [0.0]), [v], [a], [j])
        except PlanningError as exc:
            raise PointRejected(Reason.TIMING, f"the move cannot be planned: {exc}") from None
        t = profile.trajectory.profiles[0][0].t
        accelerating, decelerating = float(t[0] + t[1] + t[2]), float(t[4] + t[5] + t[6])
        begin = earliest
        if previous is not None:
            turning = bool(np.any((previous.target - previous.start) * delta < 0.0))
            window = min(previous.ramp_out, float(t[0])) if turning else min(previous.decelerating, accelerating)
            begin = max(begin, previous.end - blend * window)
        return Move(begin, start, target, profile, accelerating, decelerating, float(t[0]), float(t[6]))

    def commit(self, move: Move) -> None:
        """Queue a move of :meth:`plan` (after a stop under way, which runs to its end)."""
        if not self._moves:
            self._base = move.start.copy()
        self._moves.append(move)

    # -- running ---------------------------------------------------------------------------------

    def sample(self, t: float) -> State:
        """The setpoint at controller time ``t`` (increasing from call to call)."""
        self._t = t
        if self._stopping is not None:
            begin, segment = self._stopping
            if t < begin + segment.duration:
                s = segment.sample(t - begin)
                self._state = State(s.position, s.velocity, s.acceleration)
                return self._state
            self._stopping = None  # over: the moves queued meanwhile start where it ended
            if not self._moves:
                self._base = self._stop_position_of(segment)
                self._state = State.rest(self._base)
                return self._state
        position = self._base.copy()
        velocity = np.zeros_like(position)
        acceleration = np.zeros_like(position)
        done = 0
        for k, move in enumerate(self._moves):
            if move.profile is None or t >= move.end:
                position += move.target - move.start
                if done == k:
                    done += 1
                continue
            if t <= move.begin:
                continue
            s = move.profile.sample(t - move.begin)
            delta = move.target - move.start
            position += delta * float(s.position[0])
            velocity += delta * float(s.velocity[0])
            acceleration += delta * float(s.acceleration[0])
        if done:  # moves over at the front: folded into the base (each starts where the last ended)
            self._base = self._moves[done - 1].target.copy()
            del self._moves[:done]
            if not self._moves:
                position = self._base.copy()  # exactly the last target
        self._state = State(position, velocity, acceleration)
        return self._state

    def stop(self) -> float:
        """Replace the moves with a jerk-limited deceleration to rest from the current setpoint;
        returns its time (0 at rest)."""
        state = self._state
        self._moves.clear()
        self._base = state.position.copy()
        if not (np.any(np.abs(state.velocity) > 1e-12) or np.any(np.abs(state.acceleration) > 1e-9)):
            self._stopping = None
            self._state = State.rest(self._base)
            return 0.0
        lim = self.limits
        zero = np.zeros_like(state.position)
        segment = RuckigSegment.plan(
            (state.position, state.velocity, state.acceleration),
            (zero, zero, zero),
            lim.max_velocity,
            lim.max_acceleration,
            lim.max_jerk,
            velocity_interface=True,
        )
        self._stopping = (self._t, segment)
        return segment.duration

    def abandon(self, position: Array) -> None:
        """Drop every move at once and hold ``position`` (an alarm, an emergency stop)."""
        self._moves.clear()
        self._stopping = None
        self._base = np.array(position, dtype=float)
        self._state = State.rest(self._base)
