"""The controller: motion queue, interpolation clock, servo drives, stop and alarms.

A :class:`Controller` is a sans-I/O state machine. Its verbs take received points (SI units,
:mod:`.points`): :meth:`~Controller.start` a trajectory with its first point, :meth:`~Controller.add`
the next ones, or :meth:`~Controller.start_download` ... :meth:`~Controller.finish_download` a whole
trajectory; :meth:`~Controller.stop` aborts. What points mean over time (look-ahead, slowing down,
a queue that runs dry) is :mod:`.motion`'s; how they are joined is the policy's (:mod:`.policies`).
:meth:`~Controller.step` advances one servo period and :meth:`~Controller.run_for` many at once;
nothing here waits or reads a clock: :class:`.loop.ControlLoop` drives controllers from a
:mod:`.clock`. :func:`submit_together` accepts points for several controllers (motion groups) all
together or not at all.

**Timing.** Every interpolation period (default 4 ms, as MotoROS) the queued motion is sampled on
one continuous timeline, so a segment ending between two samples hands over to the next one at the
right place (MotoROS carries partial periods over the same way). Between two samples the servo
ticks (default 1 ms) interpolate the setpoint linearly, as a drive does with the increments it
receives. Controller time is ``tick x servo_period`` with an integer tick count; points act at the
next interpolation instant, so the controller time at which they arrive decides the motion.

**The queue.** Streamed points are queued at once; :attr:`Controller.queue_fill` is how many are
still to run, out of :attr:`Controller.queue_capacity` (a point beyond it is refused with
:attr:`~.Reason.QUEUE_FULL`, which the emulator turns into a delayed reply or BUSY). A download is
checked point by point into a bounded buffer and queued whole when it is finished.

**Stop.** :meth:`Controller.stop` replaces everything queued with ruckig's time-optimal
jerk-limited motion from the current setpoint (position, velocity and acceleration) to rest,
within the velocity, acceleration and jerk limits: no position jump, no unbounded deceleration.
The next point then starts a new trajectory.

**Drives.** :meth:`Controller.power_off` removes drive power (an emergency stop, servos off):
motion is abandoned at once, the holding brakes keep every joint where it is, and points are
refused until :meth:`Controller.power_on`.

**Alarms.** A following error beyond a joint's limit raises alarm ``4100 + joint number``, and a
command beyond a joint's position limit (the soft limit: a motion that could not stop in time, as
when a stream ends with the robot racing towards a limit) raises ``4200 + joint number`` instead of
being commanded: the queue is emptied, the command is set to the actual position (the drives brake
at full torque under their own loops) and new points are refused until :meth:`Controller.reset`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from simple_message.lograte import lane

from ..model import RobotModel
from .motion import MotionQueue, Plan
from .points import Limits, Point, PointRejected, Reason, State, check_point
from .policies import DEFAULT_POLICY, policy
from .recorder import Recorder
from .servo import ServoDrives

__all__ = [
    "Controller",
    "ControllerConfig",
    "Tick",
    "FOLLOWING_ERROR_ALARM",
    "SOFT_LIMIT_ALARM",
    "MOTION_ALARM",
    "submit_together",
]

log = logging.getLogger(__name__)
#: the lines that say the robot stopped or may not move: a lane of their own under a log ceiling
SAFETY = lane("safety")

#: alarm code of a following-error alarm is this plus the joint number (1-based)
FOLLOWING_ERROR_ALARM = 4100
#: alarm code of a soft-limit alarm (a command beyond a joint's position limit) is this plus the joint number
SOFT_LIMIT_ALARM = 4200
#: alarm code of a failure to compute the motion (a defect: logged with its traceback)
MOTION_ALARM = 4300


@dataclass(frozen=True)
class ControllerConfig:
    """Controller settings (SI units)."""

    #: interpolation policy, a name of :data:`~.policies.POLICIES`
    policy: str = DEFAULT_POLICY
    interpolation_period: float = 0.004
    servo_period: float = 0.001
    queue_capacity: int = 64
    #: points a download holds; it is planned when its last point arrives (about 0.2 ms a point,
    #: more when it must be slowed down), all at once, so this bounds that pause too
    download_capacity: int = 1_000
    #: a trajectory's first point must be this close to the current position (None: no check)
    start_tolerance: float | None = 0.01
    #: the longest segment a point may ask for (s); longer ones are refused
    max_segment_time: float = 3600.0
    #: a segment from rest waits this long at most for the point after its own, to pass through it
    lookahead_wait: float = 0.008
    #: in_motion stays TRUE until every joint is this close to the command (rad or m; at most half
    #: ``start_tolerance``, so a trajectory can always start from the rest the robot reports) ...
    settle_position: float = 1e-3
    #: ... and this slow (rad/s or m/s)
    settle_velocity: float = 1e-3
    #: where the robot starts (default: 0, moved into the limits)
    initial_position: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        ratio = self.interpolation_period / self.servo_period
        if not (self.servo_period > 0 and self.interpolation_period > 0) or abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(
                f"the interpolation period ({self.interpolation_period} s) must be a whole multiple "
                f"of the servo period ({self.servo_period} s)"
            )
        if self.queue_capacity < 1 or self.download_capacity < 2:
            raise ValueError("queue_capacity must be >= 1 and download_capacity >= 2")
        if not self.max_segment_time > 0.0:
            raise ValueError(f"max_segment_time must be > 0, not {self.max_segment_time}")
        object.__setattr__(self, "policy", policy(self.policy).name)
        if self.start_tolerance is not None and self.settle_position > self.start_tolerance / 2:
            object.__setattr__(self, "settle_position", self.start_tolerance / 2)


class Tick(NamedTuple):
    """One servo tick: commanded and actual state per joint, the following error (command - actual),
    and how many points the controller had accepted by then (a count that steps when points arrive)."""

    time: float
    command_position: list[float]
    command_velocity: list[float]
    command_acceleration: list[float]
    actual_position: list[float]
    actual_velocity: list[float]
    actual_acceleration: list[float]
    following_error: list[float]
    points: int = 0


class Controller:
    """One robot's motion controller (see the module doc)."""

    def __init__(self, model: RobotModel, config: ControllerConfig | None = None) -> None:
        self.model = model
        self.config = config = config if config is not None else ControllerConfig()
        self.limits = Limits.from_model(model)
        n = model.dof
        if config.initial_position is not None:
            start = np.array(config.initial_position, dtype=float)
            if start.shape != (n,) or not model.within_limits(start):
                raise ValueError(f"initial position {config.initial_position} is not {n} values within the limits")
        else:
            start = np.clip(np.zeros(n), self.limits.lower, self.limits.upper)
        self.policy = policy(config.policy)
        slack = 1e-9 * np.maximum(1.0, np.abs(self.limits.lower)), 1e-9 * np.maximum(1.0, np.abs(self.limits.upper))
        self._lower, self._upper = self.limits.lower - slack[0], self.limits.upper + slack[1]
        self.queue = MotionQueue(
            self.limits,
            self.policy,
            State.rest(start),
            capacity=config.queue_capacity,
            start_tolerance=config.start_tolerance,
            max_duration=config.max_segment_time,
            lookahead_wait=config.lookahead_wait,
        )
        self.servo = ServoDrives([model.motor(i) for i in range(n)], config.servo_period, start.tolist())
        self._sub = round(config.interpolation_period / config.servo_period)
        self._tick = 0
        self._download: list[Point] | None = None
        hold = start.tolist()
        zeros = [0.0] * n
        self._previous = (hold, zeros, zeros)  # setpoint at the last interpolation instant
        self._next = (hold, zeros, zeros)  # setpoint at the next one
        self.command = Tick(0.0, hold, zeros, zeros, list(hold), list(zeros), list(zeros), list(zeros))
        self.error_code = 0
        self.error_message = ""
        #: points accepted so far (first points and downloaded points included)
        self.points_accepted = 0
        self._powered = True
        self._settled = True

    # -- state ---------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        return self._tick * self.config.servo_period

    @property
    def dof(self) -> int:
        return self.model.dof

    @property
    def servo_ticks_per_interpolation(self) -> int:
        return self._sub

    @property
    def queue_fill(self) -> int:
        """Points queued and not yet reached (the running one included)."""
        return self.queue.fill

    @property
    def queue_capacity(self) -> int:
        return self.config.queue_capacity

    @property
    def trajectories(self) -> int:
        """Trajectories started so far."""
        return self.queue.trajectories

    @property
    def in_error(self) -> bool:
        return self.error_code != 0

    @property
    def moving(self) -> bool:
        """Commanded motion is queued or under way (a stop included)."""
        return self.queue.moving

    @property
    def in_motion(self) -> bool:
        """TRUE from the first commanded motion until the robot has settled after the last point
        (every joint within ``settle_position`` of the command and slower than ``settle_velocity``),
        then FALSE until the next motion: a drive's residual ringing does not flip it back."""
        return self.queue.moving or not self._settled

    def _check_settled(self, tick: Tick) -> None:
        cfg = self.config
        if not any(abs(e) > cfg.settle_position for e in tick.following_error) and not any(
            abs(v) > cfg.settle_velocity for v in tick.actual_velocity
        ):
            self._settled = True

    @property
    def downloading(self) -> bool:
        return self._download is not None

    @property
    def drives_powered(self) -> bool:
        return self._powered

    @property
    def remaining(self) -> float:
        """Seconds of queued motion still to run (0 when nothing is queued)."""
        return self.queue.remaining

    # -- commands ------------------------------------------------------------------------------

    def start(self, point: Point) -> None:
        """``point`` starts a trajectory: it is the start itself (within the start tolerance of
        where the queued motion ends), whatever its duration. Raises :class:`PointRejected`."""
        self.commit(self.prepare(point, first=True))

    def add(self, point: Point) -> None:
        """The next point: of the open download (a refused one drops the download), else of the
        streamed trajectory (the first point after a stop or an alarm starts one). Raises
        :class:`PointRejected` (QUEUE_FULL while streaming: try again when there is room)."""
        if self._download is not None:
            self._check_ready()
            try:
                if len(self._download) >= self.config.download_capacity:
                    raise PointRejected(
                        Reason.QUEUE_FULL, f"the download buffer holds {self.config.download_capacity} points at most"
                    )
                check_point(point, self.limits, self.config.max_segment_time)
            except PointRejected as exc:
                self._drop_download(exc)
                raise
            self._download.append(point)
            self.points_accepted += 1
            return
        self.commit(self.prepare(point, first=False))

    def prepare(self, point: Point, *, first: bool, min_scale: float = 1.0) -> Plan:
        """Check a streamed point and plan it without changing anything (:meth:`commit` applies
        it, before the next step): several controllers can accept points all together or not at
        all. ``min_scale``: slow the trajectory down to at least this time scale."""
        self._check_ready()
        return self.queue.plan(point, first=first, min_scale=min_scale)

    def commit(self, plan: Plan) -> None:
        """Apply a plan of :meth:`prepare` (before the next :meth:`step`)."""
        self.queue.commit(plan)
        self.points_accepted += 1
        if self.queue.moving:
            self._settled = False

    @staticmethod
    def plan_scale(plan: Plan) -> float:
        """The time scale of the trajectory once ``plan`` is committed (1: as the client timed it;
        2: slowed down to twice its time). Controllers that move together compare it to share one
        scale (:func:`submit_together`)."""
        return plan.scale

    def start_download(self, point: Point) -> None:
        """Open a download with its first point (within the start tolerance of where the queued
        motion ends); the points that follow are buffered until :meth:`finish_download`."""
        self._check_ready()
        self.queue.check_start(point)
        self._download = [point]
        self.points_accepted += 1

    def finish_download(self, point: Point) -> None:
        """The download's last point: the whole trajectory is planned and queued, or, if any point
        is refused, dropped whole (a trajectory with a hole in it never runs)."""
        if self._download is None:
            raise PointRejected(Reason.SEQUENCE, "the end of a download that was never started")
        self.add(point)
        points, self._download = self._download, None
        try:
            self.queue.add_all(points)
        except PointRejected as exc:
            self._drop_download(exc)
            raise
        if self.queue.moving:
            self._settled = False
        log.info("downloaded trajectory of %d points queued", len(points))

    def _drop_download(self, exc: PointRejected) -> None:
        self.abandon_download(str(exc))

    def abandon_download(self, reason: str) -> None:
        """Drop the download being received, if any (its end never came); queued motion runs on."""
        if self._download is not None:
            self._download = None
            log.warning("download abandoned: %s", reason)

    def _check_ready(self) -> None:
        if not self._powered:
            raise PointRejected(Reason.NOT_READY, "the drives are not powered")
        if self.in_error:
            raise PointRejected(Reason.NOT_READY, f"the controller is in alarm {self.error_code}: {self.error_message}")

    def stop(self) -> float:
        """Abort: decelerate to rest (jerk-limited, within the limits) and empty the queue.
        Returns the time the deceleration takes (0 if already at rest)."""
        had = self.queue.fill
        self._download = None
        duration = self.queue.stop()
        if had or duration:
            log.info("stop: %d queued points dropped, decelerating for %.3f s", had, duration)
        return duration

    def raise_alarm(self, code: int, message: str) -> None:
        """Enter alarm ``code``: motion is abandoned where the robot actually is, points are refused."""
        if self.in_error:
            return
        self.error_code, self.error_message = code, message
        log.warning("alarm %d: %s", code, message, extra=SAFETY)
        self._abandon()

    def reset(self) -> None:
        """Clear the alarm (the robot is held where it is)."""
        if self.in_error:
            log.info("alarm %d reset", self.error_code, extra=SAFETY)
        self.error_code, self.error_message = 0, ""

    def power_off(self) -> None:
        """Remove drive power: motion is abandoned at once and the brakes hold every joint."""
        if self._powered:
            self._abandon()
            self.servo.brake()
            self._powered = False
            self._settled = True  # the brakes hold every joint: nothing moves from this instant
            log.info("drives off", extra=SAFETY)

    def power_on(self) -> None:
        """Power the drives: they hold the position the brakes kept."""
        if not self._powered:
            self._powered = True
            log.info("drives on", extra=SAFETY)

    # -- stepping ------------------------------------------------------------------------------

    def step(self) -> Tick:
        """Advance one servo period; returns the tick's command and actual state."""
        if not self._powered:
            self._tick += 1
            p = list(self.servo.position)
            zeros = [0.0] * self.dof
            self.command = tick = Tick(
                self._tick * self.config.servo_period, p, zeros, zeros, p, zeros, zeros, zeros, self.points_accepted
            )
            self._settled = True
            return tick
        i = self._tick % self._sub
        if i == 0:
            self._previous = self._next
            try:
                state = self.queue.sample((self._tick + self._sub) * self.config.servo_period)
            except Exception:  # a defect must not end the control loop: the motion stops with an alarm
                log.exception("the motion could not be sampled")
                state = State.rest(np.array(self.servo.position))
                self.raise_alarm(MOTION_ALARM, "internal motion planning failure (see the log)")
            beyond = np.flatnonzero((state.position < self._lower) | (state.position > self._upper))
            if self.in_error:
                pass
            elif beyond.size:
                j = int(beyond[0])
                self.raise_alarm(
                    SOFT_LIMIT_ALARM + j + 1,
                    f"soft limit: joint {j + 1} ({self.model.joints[j].name}) commanded to "
                    f"{state.position[j]:.6g}, limits {self.limits.lower[j]:.6g}..{self.limits.upper[j]:.6g}",
                )
            else:
                self._next = (state.position.tolist(), state.velocity.tolist(), state.acceleration.tolist())
        self._tick += 1
        f = (i + 1) / self._sub
        g = 1.0 - f
        (p0, v0, a0), (p1, v1, a1) = self._previous, self._next
        cmd_p = [g * x + f * y for x, y in zip(p0, p1, strict=True)]
        cmd_v = [g * x + f * y for x, y in zip(v0, v1, strict=True)]
        cmd_a = [g * x + f * y for x, y in zip(a0, a1, strict=True)]
        servo = self.servo
        servo.step(cmd_p, cmd_v)
        actual = list(servo.position)
        error = [c - a for c, a in zip(cmd_p, actual, strict=True)]
        tick = self.command = Tick(
            self._tick * self.config.servo_period,
            cmd_p,
            cmd_v,
            cmd_a,
            actual,
            list(servo.velocity),
            list(servo.acceleration),
            error,
            self.points_accepted,
        )
        if not self._settled and not self.queue.moving:
            self._check_settled(tick)
        for j, (e, limit) in enumerate(zip(error, servo.following_error_limit, strict=True)):
            if abs(e) > limit:
                self.raise_alarm(
                    FOLLOWING_ERROR_ALARM + j + 1,
                    f"following error of joint {j + 1} ({self.model.joints[j].name}) is {e:.4g}, limit {limit:g}",
                )
                break
        return tick

    def run_for(self, seconds: float, recorder: Recorder | None = None) -> None:
        """Step for ``seconds`` of controller time at once (simulated time, no clock)."""
        for _ in range(round(seconds / self.config.servo_period)):
            tick = self.step()
            if recorder is not None:
                recorder.add(tick)

    # -- internals -----------------------------------------------------------------------------

    def _abandon(self) -> None:
        """Drop all motion and command the actual position (alarm, emergency stop)."""
        self._download = None
        actual = list(self.servo.position)
        zeros = [0.0] * self.dof
        self._previous = self._next = (actual, zeros, zeros)
        self._settled = False  # the drives still brake the joints to a halt
        self.servo.hold()
        self.queue.abandon(np.array(actual))


def submit_together(pairs: Sequence[tuple[Controller, Point]], *, first: bool = False) -> None:
    """Streamed points for several controllers that move as one (the motion groups of a MotoROS
    JOINT_TRAJ_PT_FULL_EX; ``first``: they start a trajectory): every point is accepted, or none is
    and nothing changes. They share one time scale: when one group must slow down, all do, so
    that they stay together."""
    plans = [ctl.prepare(point, first=first) for ctl, point in pairs]
    for _ in range(3):  # a group slowed down to the shared scale may ask for a little more
        scales = [Controller.plan_scale(plan) for plan in plans]
        scale = max(scales)
        if all(s >= scale * (1.0 - 1e-9) for s in scales):
            break
        plans = [
            plan if s >= scale else ctl.prepare(point, first=first, min_scale=scale)
            for (ctl, point), plan, s in zip(pairs, plans, scales, strict=True)
        ]
    for (ctl, _), plan in zip(pairs, plans, strict=True):
        ctl.commit(plan)
