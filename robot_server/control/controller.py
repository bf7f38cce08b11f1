"""The controller: motion queue, interpolation clock, servo drives, stop and alarms.

A :class:`Controller` is a sans-I/O state machine. Its verbs take received points (SI units,
:mod:`.points`): :meth:`~Controller.start` a trajectory with its first point, :meth:`~Controller.add`
the next ones, or :meth:`~Controller.start_download` ... :meth:`~Controller.finish_download` a whole
trajectory; :meth:`~Controller.stop` aborts. What points mean over time (look-ahead, slowing down,
a queue that runs dry) is :mod:`.motion`'s; how they are joined is the policy's (:mod:`.policies`).
Besides trajectories it runs the controller's own kinds of motion: straight lines of the tool
(:meth:`~Controller.add_line`, :mod:`.cartesian`) and joint moves at a share of the joints' speed
(:meth:`~Controller.add_move`, :mod:`.moves`: Fanuc's and Stäubli's move instructions), one kind at
a time.
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
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from simple_message.lograte import lane

from ..model import RobotModel
from ..workspace import TCP_SPEED_ALARM, Supervision, Violation, densify, first_violation, point_violation
from .cartesian import LineLimits, LineMotion, LineTarget
from .motion import MotionQueue, Plan
from .moves import JointMoves
from .points import Limits, Point, PointRejected, Reason, State, check_point
from .policies import DEFAULT_POLICY, policy
from .recorder import Recorder
from .rest import RestWatch
from .servo import ServoDrives
from .supervision import SLOWING_ROUNDS, SlowDown, Slowing, check_zones, path_slowing, tcp_path
from .supervision import slowed as slowed_point
from .tool import ToolMeter, ToolState

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
    #: JOINT_TRAJ_PT_FULL segments with velocities that pass the acceleration limit between their
    #: points are run as given (reported once per trajectory) instead of slowing the trajectory
    #: down: MotoROS checks the points' speeds only (the MotoROS profile sets it)
    follow_given_acceleration: bool = False
    #: the drives' velocity feedforward is the setpoint's change over each interpolation period, as
    #: a drive fed position increments only works it out (MotoROS: mpExRcsIncrementMove), instead of
    #: the planned velocity (the two differ where a cubic run as given turns within the period)
    increment_feedforward: bool = False
    #: in_motion stays TRUE until every joint is this close to the command (rad or m; at most half
    #: ``start_tolerance``, so a trajectory can always start from the rest the robot reports) ...
    settle_position: float = 1e-3
    #: ... and this slow (rad/s or m/s)
    settle_velocity: float = 1e-3
    #: where the robot starts (default: 0, moved into the limits)
    initial_position: tuple[float, ...] | None = None
    #: controller straight lines: TCP acceleration and jerk, tool rotation limits, check density
    line: LineLimits = field(default_factory=LineLimits)
    #: the Cartesian supervision (TCP speed limits, workspace zones); None: the model's own
    supervision: Supervision | None = None
    #: a motion is planned to at most this share of the TCP speed limit in force, so that the
    #: drives' overshoot does not trip the supervision of the actual speed
    speed_margin: float = 0.9

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
    #: the TCP at the last interpolation instant (commanded and actual pose and speed); None where
    #: :meth:`Controller.step_period` left it uncomputed (read :attr:`Controller.tool`; a recorder
    #: it was left to computes it when read)
    tool: ToolState | None = None


class Controller:
    """One robot's motion controller (see the module doc). Its methods are its verbs (points,
    lines, moves, downloads, stop, alarms, drives, step) and the read-only state the emulator
    publishes, each a few lines over one state machine (the queue, the lines, the moves, the
    drives and the alarm they share); the planning behind them lives in :mod:`.motion`,
    :mod:`.cartesian`, :mod:`.moves` and :mod:`.supervision`, so it stays whole past 30 methods."""

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
        self._lower = (self.limits.lower - slack[0]).tolist()
        self._upper = (self.limits.upper + slack[1]).tolist()
        self.queue = MotionQueue(
            self.limits,
            self.policy,
            State.rest(start),
            capacity=config.queue_capacity,
            start_tolerance=config.start_tolerance,
            max_duration=config.max_segment_time,
            lookahead_wait=config.lookahead_wait,
            follow_given_acceleration=config.follow_given_acceleration,
        )
        self.servo = ServoDrives([model.motor(i) for i in range(n)], config.servo_period, start.tolist())
        self._sub = round(config.interpolation_period / config.servo_period)
        self._tick = 0
        self._download: list[Point] | None = None
        hold = start.tolist()
        zeros = [0.0] * n
        self._previous = (hold, zeros, zeros)  # setpoint at the last interpolation instant
        self._next = (hold, zeros, zeros)  # setpoint at the next one
        #: the Cartesian supervision in force (TCP speed limits, workspace zones)
        self.supervision = config.supervision if config.supervision is not None else model.supervision
        #: MANUAL (teach) mode: the TCP speed limit is the supervision's manual speed
        self.manual = False
        self.tool_meter = ToolMeter(model)
        self._tool: ToolState | None = self.tool_meter.measure(0.0, hold, zeros, hold, zeros)
        #: what :attr:`tool` is computed from when it is read (the last instant's, see step_period)
        self._tool_inputs: tuple[float, list[float], list[float], list[float], list[float]] = (
            0.0, hold, zeros, hold, zeros
        )  # fmt: skip
        self._zone_clear = point_violation(self.supervision, *self.tool.actual_position) is None
        #: a stop is braking the robot: the TCP speed limit is not supervised until the next motion
        #: (switching to MANUAL stops a fast motion: its braking is not an excursion)
        self._stopping = False
        #: straight lines run by the controller (:mod:`.cartesian`)
        self.lines = LineMotion(
            model,
            self.limits,
            config.line,
            config.interpolation_period,
            capacity=config.queue_capacity,
            path_check=lambda positions: check_zones(self.supervision, positions),
        )
        #: joint moves at a share of the joints' speed (:mod:`.moves`)
        self.moves = JointMoves(self.limits, start)
        self.command = Tick(0.0, hold, zeros, zeros, list(hold), list(zeros), list(zeros), list(zeros), 0, self.tool)
        self.error_code = 0
        self.error_message = ""
        #: points accepted so far (first points and downloaded points included)
        self.points_accepted = 0
        self._powered = True
        self._settled = True
        #: recognises a period at rest that changed nothing, and replays it (:mod:`.rest`)
        self._rest = RestWatch()
        #: the resting period replayed in the current interpolation period (None: stepped)
        self._replaying: list[Tick] | None = None
        self._replay_key: tuple[object, ...] = ()

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
        """Points (or lines) queued and not yet reached (the running one included)."""
        return self.queue.fill + self.lines.fill + self.moves.fill

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
        return self.queue.moving or self.lines.active or self.moves.active

    @property
    def in_motion(self) -> bool:
        """TRUE from the first commanded motion until the robot has settled after the last point
        (every joint within ``settle_position`` of the command and slower than ``settle_velocity``),
        then FALSE until the next motion: a drive's residual ringing does not flip it back."""
        return self.moving or not self._settled

    @property
    def resting(self) -> bool:
        """Standing still with nothing queued, the last interpolation period a resting one replayed
        (:mod:`.rest`): every following period is the same again, its times aside, until something
        changes. What lets a fleet's shared loop leave this controller until it is next needed
        (:meth:`.loop.ControlLoop.park`)."""
        return (
            self._replaying is not None
            and self._tick % self._sub == 0
            and not self.moving
            and self._rest_key() == self._replay_key  # no verb since the instant (an alarm, drives off...)
        )

    def skip_resting(self, periods: int) -> None:
        """Pass ``periods`` resting periods at once (only while :attr:`resting`): the tick count and
        the replay count as replaying them one by one leaves them. Their ticks are not made (no one
        saw them); the next period, stepped, samples the motion at its own instant and makes its
        ticks, the same numbers as after every period had been stepped."""
        if periods > 0:
            self._tick += periods * self._sub
            self._rest.periods += periods

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
        return self.queue.remaining + self.lines.remaining(self.time) + self.moves.remaining()

    @property
    def speed_limit(self) -> float | None:
        """The TCP speed limit in force (m/s): the manual speed in MANUAL, else the optional AUTO one."""
        return self.supervision.speed_limit(self.manual)

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
        if self.lines.active:
            raise PointRejected(Reason.BUSY, "a straight line is under way: joint points wait until it ends")
        if self.moves.active:
            raise PointRejected(Reason.BUSY, "joint moves are under way: trajectory points wait until they end")
        plan = self.queue.plan(point, first=first, min_scale=min_scale)
        if self.speed_limit is None and not self.supervision.has_zones:
            return plan
        slowing, scale = Slowing(), plan.scale
        for _ in range(SLOWING_ROUNDS):
            slower = self._supervise_path(*self.queue.path(plan, self.config.interpolation_period))
            if slower is None:
                return plan
            slowing.step(slower)
            slowed = slowed_point(point, slowing.ratio)
            plan = self.queue.plan(slowed, first=first, min_scale=max(min_scale, scale * slowing.scale))
        raise PointRejected(Reason.TCP_SPEED, "the trajectory could not be slowed down to the TCP speed limit")

    def commit(self, plan: Plan) -> None:
        """Apply a plan of :meth:`prepare` (before the next :meth:`step`)."""
        self.queue.commit(plan)
        self.points_accepted += 1
        self._stopping = False
        if self.queue.moving:
            self._settled = False

    def add_line(self, target: LineTarget) -> None:
        """A straight line of the tool to ``target`` (:mod:`.cartesian`), after the lines queued,
        or from where the robot rests. Raises :class:`PointRejected` (nothing moves then)."""
        self._check_ready()
        if self.queue.moving or self._download is not None or self.moves.active:
            raise PointRejected(Reason.BUSY, "a joint trajectory is under way: lines wait until it ends")
        values = (*target.position, *target.orientation, target.speed, target.blend_radius)
        if not all(math.isfinite(v) for v in values):
            raise PointRejected(Reason.NOT_FINITE, "the line's target contains NaN or infinity")
        norm = math.sqrt(sum(x * x for x in target.orientation))
        if abs(norm - 1.0) > 1e-3:
            raise PointRejected(Reason.INVALID, f"the orientation is not a unit quaternion (norm {norm:.6g})")
        if target.speed <= 0.0 or target.blend_radius < 0.0:
            raise PointRejected(
                Reason.INVALID,
                f"a line needs a speed > 0 and a blend radius >= 0, not {target.speed:g} and {target.blend_radius:g}",
            )
        limit = self.speed_limit
        if limit is not None and not self.manual and target.speed > limit:
            raise PointRejected(
                Reason.TCP_SPEED, f"the line's speed {target.speed:.4g} m/s is over the AUTO limit {limit:.4g} m/s"
            )
        cap = None if limit is None else limit * self.config.speed_margin
        rest = np.array(self._next[0], dtype=float)
        line = self.lines.plan(target, now=self.time, rest=rest, speed_cap=cap)
        self.lines.commit(line)
        self.points_accepted += 1
        self._stopping = False
        self._settled = False

    def add_move(
        self,
        target: Sequence[float] | NDArray[np.float64],
        *,
        speed: float,
        blend: float = 0.0,
        acceleration: float = 1.0,
    ) -> float:
        """A joint move to ``target`` at ``speed`` (a share of the joints' maximum speed), blended
        into the last queued move by ``blend`` (:mod:`.moves`), or from where the robot rests.
        Returns the controller time at which it begins. Raises :class:`PointRejected` (nothing
        moves then)."""
        self._check_ready()
        if self.queue.moving or self._download is not None or self.lines.active:
            raise PointRejected(Reason.BUSY, "a trajectory or a line is under way: moves wait until it ends")
        rest = np.array(self._next[0], dtype=float)
        # moves act from the next interpolation instant on (the last one sampled)
        instant = (self._tick + (-self._tick) % self._sub) * self.config.servo_period
        move = self.moves.plan(
            np.asarray(target, dtype=float),
            speed=speed,
            blend=blend,
            acceleration=acceleration,
            rest=rest,
            now=instant,
        )
        self.moves.commit(move)
        self.points_accepted += 1
        self._stopping = self.moves.stopping  # a stop under way still brakes: it runs to its end
        self._settled = False
        return move.begin

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
        slowing = Slowing()
        try:
            for _ in range(SLOWING_ROUNDS):
                try:
                    slowed = [slowed_point(p, slowing.ratio) for p in points]
                    self.queue.add_all(slowed, min_scale=slowing.scale, check=self._check_download)
                    break
                except SlowDown as slow:
                    slowing.step(slow.factor)
            else:
                raise PointRejected(Reason.TCP_SPEED, "the trajectory could not be slowed down to the TCP speed limit")
        except PointRejected as exc:
            self._drop_download(exc)
            raise
        self._stopping = False
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
        """Abort: decelerate to rest (jerk-limited, within the limits) and empty the queue; a
        straight line brakes along its path. Returns the time the deceleration takes (0 if
        already at rest). A braking path that would take the tool into a zone raises the zone's
        alarm with the e-stop reaction (:meth:`safety_stop`)."""
        had = self.queue.fill + self.lines.fill
        self._download = None
        self._stopping = True
        if self.lines.active:
            duration = self.lines.stop(self.time)
        elif self.moves.active:
            had = self.moves.fill
            duration = self.moves.stop()
        else:
            duration = self.queue.stop()
            if duration and self.supervision.has_zones:
                times, q = self.queue.path(None, self.config.interpolation_period)
                positions = tcp_path(self.model, self.supervision.tolerance, times, q)[0]
                violation = first_violation(self.supervision, densify(positions, self.supervision.tolerance))
                if violation is not None and self._zone_clear:
                    self.safety_stop(violation, "the stop's braking path")
                    return 0.0
        if had or duration:
            log.info("stop: %d queued points dropped, decelerating for %.3f s", had, duration)
        return duration

    def safety_stop(self, violation: Violation, what: str) -> None:
        """A zone violation: its alarm, with the e-stop reaction (motion abandoned, drives off,
        brakes on: category 0)."""
        self._zone_clear = False
        self.raise_alarm(violation.code, f"{what}: {violation.message} (e-stop reaction: drives off)")
        self.power_off()

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
            self._replaying = None
            self._rest.forget()
            self._tick += 1
            p = list(self.servo.position)
            zeros = [0.0] * self.dof
            self.command = tick = Tick(
                self._tick * self.config.servo_period,
                p,
                zeros,
                zeros,
                p,
                zeros,
                zeros,
                zeros,
                self.points_accepted,
                self.tool,
            )
            self._settled = True
            return tick
        i = self._tick % self._sub
        if i == 0:
            self._instant()
        return self._servo_tick(i)

    def step_period(self, recorder: Recorder | None = None) -> Tick:
        """The servo ticks up to the next interpolation instant at once (a whole interpolation
        period from one); returns the last. At rest (:mod:`.rest`) only that one is made: the others
        would be the same ticks, their times aside, and no one sees them. With ``recorder``, every
        tick of the period is recorded, as :meth:`step` makes them one by one: at rest replayed,
        moving the drives' numbers of each tick handed over with the two setpoints it lies between
        (:meth:`Recorder.add_between`: no tick made), the period's last tick made whole; its TCP
        left to a recorder that takes it (:meth:`Recorder.takes_instants`: computed when read, the
        same numbers), computed here for one that does not."""
        sub = self._sub
        i = self._tick % sub
        if recorder is not None:
            self._tool_for(recorder)
        if i or not self._powered:
            for _ in range(sub - i):
                tick = self.step()
                if recorder is not None:
                    recorder.add(tick)
            return tick
        self._instant()
        replaying = self._replaying
        if replaying is not None:  # nothing can happen between the instant and its period
            if recorder is None:
                self._tick += sub - 1
                return self._replay(replaying[-1], sub - 1)
            for i in range(sub):
                tick = self._replay(replaying[i], i)
                recorder.add(tick)
            return tick
        for i in range(sub - 1):
            if self._replaying is None and not self._rest.watching and (self.moving or self._settled):
                self._unseen_tick(i, recorder)  # moving: no one needs this tick but the drives (and a recorder)
            else:
                tick = self._servo_tick(i)
                if recorder is not None:
                    recorder.add(tick)
        if recorder is None:
            return self._servo_tick(sub - 1, seen=False)
        if recorder.takes_instants(self.tool_meter):  # the TCP computed by the recorder when read, if ever
            tick = self._servo_tick(sub - 1, seen=False)
            config = self.config
            recorder.add(tick, instant_until=tick.time + config.interpolation_period - 0.5 * config.servo_period)
        else:
            tick = self._servo_tick(sub - 1)
            recorder.add(tick)
        return tick

    def _tool_for(self, recorder: Recorder) -> None:
        """Before ``recorder`` records ticks that hold the last instant's TCP: computed now unless
        this recorder was left it (another recorder was, or this one was cleared since)."""
        if self._tool is None and not recorder.holds_instant(self._tool_inputs[0]):
            self._tool = self.tool_meter.measure(*self._tool_inputs)

    def _unseen_tick(self, i: int, recorder: Recorder | None = None) -> None:
        """Servo tick ``i`` of the period (not its last) when no one sees its :class:`Tick`: the
        drives and their following-error supervision only, the same numbers as :meth:`_servo_tick`
        (which also makes the tick, and checks the robot settling: not while it moves). A
        ``recorder`` gets the tick's numbers (:meth:`Recorder.add_between`), as the tick has them
        before an alarm."""
        self._tick += 1
        ends = self._previous, self._next
        (p0, v0, _), (p1, v1, _) = ends
        config, servo = self.config, self.servo
        f = (i + 1) / self._sub
        j = servo.follow(
            p0, p1, v0, v1, f, increment_period=config.interpolation_period if config.increment_feedforward else None
        )
        if recorder is not None:
            recorder.add_between(
                self._tick * config.servo_period, f, ends, servo, points=self.points_accepted, tool=self._tool
            )
        if j >= 0:
            e = (1.0 - f) * p0[j] + f * p1[j] - servo.position[j]  # the command's own numbers
            self.raise_alarm(
                FOLLOWING_ERROR_ALARM + j + 1,
                f"following error of joint {j + 1} ({self.model.joints[j].name}) is {e:.4g}, "
                f"limit {servo.following_error_limit[j]:g}",
            )

    def _instant(self) -> None:
        """At an interpolation instant: sample the motion for the next one, or find the coming
        period the same as the last one (at rest, :mod:`.rest`)."""
        state = self._sample((self._tick + self._sub) * self.config.servo_period)
        self._replay_key = key = self._rest_key()
        self._replaying = self._rest.replay(key, state, self.servo)
        if self._replaying is None:
            self._previous = self._next
            self._command(state)
            self._rest.begin(self._rest_key(), state, self._previous == self._next, self.servo)

    @property
    def tool(self) -> ToolState:
        """The TCP at the last interpolation instant (computed when first read after it, unless
        the supervision or a recorder needs it at once: the same numbers either way)."""
        tool = self._tool
        if tool is None:
            tool = self._tool = self.tool_meter.measure(*self._tool_inputs)
        return tool

    def _servo_tick(self, i: int, *, seen: bool = True) -> Tick:
        """Servo tick ``i`` of the interpolation period (0-based). Unless ``seen`` (the last tick
        of :meth:`step_period`, which the emulator's state or a recorder reads), the TCP is computed when
        :attr:`tool` is read, not at the instant, and the tick's ``tool`` is None; the supervision
        still checks it at the instant."""
        replaying = self._replaying
        if replaying is not None:  # at rest: the last period again (:mod:`.rest`)
            if self._rest_key() == self._replay_key:
                return self._replay(replaying[i], i)
            self._replaying = None  # a verb between two ticks: step the rest of the period
            self._rest.forget()
        self._tick += 1
        f = (i + 1) / self._sub
        g = 1.0 - f
        (p0, v0, a0), (p1, v1, a1) = self._previous, self._next
        cmd_p = [g * x + f * y for x, y in zip(p0, p1, strict=True)]
        cmd_v = [g * x + f * y for x, y in zip(v0, v1, strict=True)]
        cmd_a = [g * x + f * y for x, y in zip(a0, a1, strict=True)]
        servo = self.servo
        if self.config.increment_feedforward:
            period = self.config.interpolation_period
            servo.step(cmd_p, [(y - x) / period for x, y in zip(p0, p1, strict=True)])
        else:
            servo.step(cmd_p, cmd_v)
        actual = list(servo.position)
        velocity = list(servo.velocity)
        error = [c - a for c, a in zip(cmd_p, actual, strict=True)]
        if i + 1 == self._sub:  # an interpolation instant: where the tool is, and is it allowed
            self._tool = None
            self._tool_inputs = (self._tick * self.config.servo_period, cmd_p, cmd_v, actual, velocity)
            if seen or self.supervision.watches(self.manual):
                self._supervise(self.tool)
        tick = self.command = Tick(
            self._tick * self.config.servo_period,
            cmd_p,
            cmd_v,
            cmd_a,
            actual,
            velocity,
            list(servo.acceleration),
            error,
            self.points_accepted,
            self._tool,
        )
        if not self._settled and not self.moving and cmd_p == self._next[0]:  # the last setpoint reached
            self._check_settled(tick)
        for j, (e, limit) in enumerate(zip(error, servo.following_error_limit, strict=True)):
            if abs(e) > limit:
                self.raise_alarm(
                    FOLLOWING_ERROR_ALARM + j + 1,
                    f"following error of joint {j + 1} ({self.model.joints[j].name}) is {e:.4g}, limit {limit:g}",
                )
                break
        rest = self._rest
        rest.add(tick)
        if i + 1 == self._sub:
            rest.end(self._rest_key(), servo)
        return tick

    def _sample(self, at: float) -> State:
        """The motion's setpoint at the next interpolation instant ``at``."""
        try:
            if self.lines.active:
                state = self.lines.sample(at)
                self.queue.sample(at)  # the joint queue's clock runs on
                if self.lines.fill == 0:  # the last line ended: joints start from there
                    self.queue.abandon(state.position)
            elif self.moves.active:
                moves = self.moves
                state = moves.sample(at)
                self.queue.sample(at)
                if not moves.active:  # the last move ended: trajectories start from there
                    self.queue.abandon(state.position)
            else:
                state = self.queue.sample(at)
        except Exception:  # a defect must not end the control loop: the motion stops with an alarm
            log.exception("the motion could not be sampled")
            state = State.rest(np.array(self.servo.position))
            self.raise_alarm(MOTION_ALARM, "internal motion planning failure (see the log)")
        return state

    def _command(self, state: State) -> None:
        """Command the sampled setpoint from the next interpolation instant on, unless it is beyond
        a joint's position limit (the soft-limit alarm) or an alarm holds the robot."""
        if self.in_error:
            return
        position = state.position.tolist()
        bounds = zip(position, self._lower, self._upper, strict=True)
        beyond = [j for j, (x, lo, hi) in enumerate(bounds) if x < lo or x > hi]
        if beyond:
            j = beyond[0]
            self.raise_alarm(
                SOFT_LIMIT_ALARM + j + 1,
                f"soft limit: joint {j + 1} ({self.model.joints[j].name}) commanded to "
                f"{state.position[j]:.6g}, limits {self.limits.lower[j]:.6g}..{self.limits.upper[j]:.6g}",
            )
        else:
            self._next = (position, state.velocity.tolist(), state.acceleration.tolist())

    def _rest_key(self) -> tuple[object, ...]:
        """Everything besides the drives and the setpoint that a servo period's outcome depends on
        (:mod:`.rest`): a verb called at rest changes one of these."""
        return (
            self.points_accepted,
            self.error_code,
            self._settled,
            self._stopping,
            self._zone_clear,
            self.manual,
            id(self.supervision),
            self._download is None,
            self._powered,
        )

    def _replay(self, resting: Tick, i: int) -> Tick:
        """One tick of a resting period again, at its new time (:mod:`.rest`). (The tuples are
        made directly: a NamedTuple's own constructor and ``_replace`` cost several times more,
        and this runs for every controller at rest every period.)"""
        self._tick += 1
        now = self._tick * self.config.servo_period
        if i + 1 == self._sub:
            self._tool = _new(ToolState, (now, *self.tool[1:]))
        tick = self.command = _new(Tick, (now, *resting[1:9], self._tool))
        return tick

    def run_for(self, seconds: float, recorder: Recorder | None = None) -> None:
        """Step for ``seconds`` of controller time at once (simulated time, no clock)."""
        if recorder is not None:
            self._tool_for(recorder)
        for _ in range(round(seconds / self.config.servo_period)):
            tick = self.step()
            if recorder is not None:
                recorder.add(tick)

    # -- Cartesian supervision -------------------------------------------------------------------

    def _supervise(self, tool: ToolState) -> None:
        """Every interpolation instant: the actual TCP speed against the limit in force (its alarm,
        the alarm reaction; not while a stop brakes the robot) and the commanded and actual TCP
        against the zones (the zone's alarm, the e-stop reaction). A zone alarm is raised when the
        tool gets into a violation, not again while it stays there (so that it can be moved out
        after a reset)."""
        limit = self.supervision.speed_limit(self.manual)
        if limit is not None and tool.actual_speed > limit and not self.in_error and not self._stopping:
            self.raise_alarm(
                TCP_SPEED_ALARM,
                f"TCP speed {tool.actual_speed * 1e3:.0f} mm/s over the "
                f"{'MANUAL' if self.manual else 'AUTO'} limit {limit * 1e3:.0f} mm/s",
            )
        sup = self.supervision
        if not sup.has_zones:
            return
        violation = point_violation(sup, *tool.command_position) or point_violation(sup, *tool.actual_position)
        if violation is None:
            self._zone_clear = True
        elif self._zone_clear:
            commanded = point_violation(sup, *tool.command_position) is not None
            self.safety_stop(violation, "commanded TCP" if commanded else "actual TCP")

    def _supervise_path(self, times: NDArray[np.float64], q: NDArray[np.float64]) -> float | None:
        """A planned joint path against the zones and the TCP speed limit in force
        (:func:`.supervision.path_slowing`)."""
        return path_slowing(
            self.model, self.supervision, manual=self.manual, margin=self.config.speed_margin, times=times, q=q
        )

    def _check_download(self) -> None:
        if self.speed_limit is None and not self.supervision.has_zones:
            return
        slower = self._supervise_path(*self.queue.path(None, self.config.interpolation_period))
        if slower is not None:
            raise SlowDown(slower)

    def _abandon(self) -> None:
        """Drop all motion and command the actual position (alarm, emergency stop)."""
        self._download = None
        self.lines.abandon()
        actual = list(self.servo.position)
        self.moves.abandon(np.array(actual))
        zeros = [0.0] * self.dof
        self._previous = self._next = (actual, zeros, zeros)
        self._settled = False  # the drives still brake the joints to a halt
        self.servo.hold()
        self.queue.abandon(np.array(actual))


_new = tuple.__new__


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
