"""The robot cell: the controllers of its motion groups, the safety state, faults and STATUS.

:class:`RobotCell` is what the protocol servers talk to. It owns one :class:`~..control.Controller`
per motion group (a robot, a positioner...), stepped together by one control loop, and the state a
real controller adds around them: the emergency stop, drive power, the operating mode and alarms.
It computes STATUS (docs/reference/protocol.md §5) from that state at the moment it is asked, so STATUS is
never stale. The fault injector of the tests and of the ``robot-server`` command drives it:

========================  =========================================================================
``estop()``               emergency stop: motion is abandoned at once (category 0: drive power off,
                          brakes hold), e_stopped TRUE, drives_powered FALSE
``drives_off()``          drive power off (motion abandoned at once, like an e-stop without the
                          e-stop); ``drives_on()`` powers them again (refused while e-stopped)
``alarm(code, text)``     an alarm: motion abandoned where the robot is, in_error TRUE, error_code
``reset()``               the operator's reset: releases the e-stop, clears alarms, powers the drives
``stop()``                a controlled stop: jerk-limited deceleration to rest, queue emptied
``set_mode(mode)``        MANUAL (teach) stops the motion; it then refuses points, or, in a cell
                          made with ``manual_motion`` (ABB, Fanuc T1: the operator holds the
                          enabling device), accepts them at the reduced TCP speed of the
                          supervision (250 mm/s by default); AUTO allows them at full speed
========================  =========================================================================

Until the cause is cleared, new points are refused (:attr:`~..control.Reason.NOT_READY`). Every
fault and every accepted trajectory is logged at INFO.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Sequence

from simple_message.constants import RobotMode, SpecialSeq, TriState
from simple_message.lograte import lane
from simple_message.messages import Status

from ..control import Controller, ControllerConfig, LineTarget, Point, PointRejected, Reason, submit_together
from ..model import RobotModel
from .points import STREAM_STARTS, dispatch

__all__ = ["RobotCell", "FaultError", "apply_fault_command", "FAULT_COMMANDS"]

#: the largest alarm code: STATUS carries it as a 32-bit integer
INT32_MAX = 2**31 - 1
log = logging.getLogger(__name__)
#: the lines that say the robot stopped or may not move: a lane of their own under a log ceiling
SAFETY = lane("safety")


class FaultError(ValueError):
    """A fault command that cannot be applied (unknown, malformed, or not possible now)."""


class RobotCell:
    """The motion groups of one controller and its safety state (see the module doc)."""

    def __init__(
        self, models: Sequence[RobotModel], config: ControllerConfig | None = None, *, manual_motion: bool = False
    ) -> None:
        if not models:
            raise ValueError("a robot cell needs at least one motion group")
        self.config = config if config is not None else ControllerConfig()
        self.groups = [Controller(model, self.config) for model in models]
        self.e_stopped = False
        self.mode = RobotMode.AUTO
        #: MANUAL accepts motion at the reduced TCP speed (else it refuses points)
        self.manual_motion = manual_motion
        #: the last line sequence number accepted per group (None: no series of lines open)
        self._line_sequence: list[int | None] = [None] * len(self.groups)
        #: counts stops and faults: a point that waited for queue room across one is not run
        self.interruptions = 0
        self._wakeup = Wakeup()
        self._was_moving = [False] * len(self.groups)
        self._points = [0] * len(self.groups)
        self._started = [0.0] * len(self.groups)
        #: a stop or a fault came while the group moved: its motion ends stopped, not done
        self._stopped = [False] * len(self.groups)
        #: what the group last set off to run: a "trajectory" (points), "joint moves" or "straight lines"
        self._kind = ["trajectory"] * len(self.groups)
        #: called with (group, point) for every joint point a controller accepted, in order (e.g. a
        #: display marking the waypoints); must not raise or block
        self.point_listeners: list[Callable[[int, Point], None]] = []
        #: called after every control-loop wake-up, before the waiting tasks are woken: a
        #: controller's own periodic tasks in lockstep with controller time (a program taking the
        #: next move, a motion task's tick); must not block
        self.tick_listeners: list[Callable[[], None]] = []
        #: called after the operator's :meth:`reset` (e.g. a controller program restarted)
        self.reset_listeners: list[Callable[[], None]] = []
        #: each tick listener's "nothing to do until something else happens" (:meth:`listen`)
        self._idle_of: dict[Callable[[], None], Callable[[], bool]] = {}
        #: brings the controllers up to now before they are read or changed from outside their
        #: control loop (the emulator's: a parked control loop's periods, :meth:`.ControlLoop.park`)
        self.sync: Callable[[], None] = _nothing

    # -- state -------------------------------------------------------------------------------------

    @property
    def models(self) -> list[RobotModel]:
        return [g.model for g in self.groups]

    @property
    def drives_powered(self) -> bool:
        return all(g.drives_powered for g in self.groups)

    @property
    def in_error(self) -> bool:
        return any(g.in_error for g in self.groups)

    @property
    def error_code(self) -> int:
        return next((g.error_code for g in self.groups if g.in_error), 0)

    @property
    def in_motion(self) -> bool:
        return any(g.in_motion for g in self.groups)

    @property
    def time(self) -> float:
        """Controller time (s): the first motion group's clock, which every group shares."""
        self.sync()
        return self.groups[0].time

    @property
    def motion_possible(self) -> bool:
        """A new trajectory could run now (drives on, no e-stop, no alarm, AUTO or MANUAL with
        ``manual_motion``)."""
        mode_allows = self.mode == RobotMode.AUTO or (self.manual_motion and self.mode == RobotMode.MANUAL)
        return self.drives_powered and not self.e_stopped and not self.in_error and mode_allows

    def status(self, *, motion_possible: bool | None = None) -> Status:
        """STATUS as of now (``motion_possible`` may be narrowed by a profile, e.g. MotoROS's
        trajectory mode)."""
        self.sync()
        possible = self.motion_possible if motion_possible is None else motion_possible
        return Status(
            drives_powered=_tri(self.drives_powered),
            e_stopped=_tri(self.e_stopped),
            error_code=self.error_code,
            in_error=_tri(self.in_error),
            in_motion=_tri(self.in_motion),
            mode=self.mode,
            motion_possible=_tri(possible),
        )

    # -- points ------------------------------------------------------------------------------------

    def group(self, index: int) -> Controller:
        if not 0 <= index < len(self.groups):
            raise PointRejected(Reason.JOINT_COUNT, f"motion group {index} does not exist (0..{len(self.groups) - 1})")
        return self.groups[index]

    def check_ready(self) -> None:
        if self.e_stopped:
            raise PointRejected(Reason.NOT_READY, "the emergency stop is engaged")
        if self.mode != RobotMode.AUTO and not (self.manual_motion and self.mode == RobotMode.MANUAL):
            raise PointRejected(Reason.NOT_READY, "the controller is in MANUAL (teach) mode")

    def submit(self, group: int, sequence: int, point: Point) -> None:
        """Hand one point to a group's controller, as its sequence number says
        (:func:`.points.dispatch`); raises :class:`PointRejected`."""
        self.sync()
        controller = self.group(group)
        if sequence == SpecialSeq.STOP_TRAJECTORY:  # a stop is always obeyed
            self._interrupted()
            controller.stop()
            return
        self.check_ready()
        before = controller.trajectories
        dispatch(controller, sequence, point)
        self._count(group, before)
        for listener in self.point_listeners:
            listener(group, point)

    def submit_together(self, sequence: int, points: Sequence[tuple[int, Point]]) -> None:
        """One streamed point per group, all accepted or none (sequence 0 starts a trajectory)."""
        self.sync()
        if sequence < 0:
            raise PointRejected(Reason.SEQUENCE, f"sequence {sequence}: only streamed points move together")
        self.check_ready()
        pairs = [(self.group(g), p) for g, p in points]
        before = [c.trajectories for c, _ in pairs]
        submit_together(pairs, first=sequence in STREAM_STARTS)
        for (g, p), n in zip(points, before, strict=True):
            self._count(g, n)
            for listener in self.point_listeners:
                listener(g, p)

    def submit_download(self, group: int, points: Sequence[Point]) -> None:
        """A whole trajectory for a group's controller at once (its first point the start, within
        the start tolerance of where the queued motion ends): queued whole, or refused whole
        (:class:`PointRejected`, nothing moves then). A controller that downloads this way: ABB."""
        self.sync()
        if not points:
            raise PointRejected(Reason.SEQUENCE, "a trajectory needs at least one point")
        controller = self.group(group)
        self.check_ready()
        before = controller.trajectories
        controller.start_download(points[0])
        if len(points) == 1:  # a trajectory of its start alone: nothing to move
            controller.abandon_download("a trajectory of one point: the robot is there")
            return
        for point in points[1:-1]:
            controller.add(point)
        controller.finish_download(points[-1])
        self._count(group, before)
        self._points[group] += len(points) - 1
        for point in points:
            for listener in self.point_listeners:
                listener(group, point)

    def submit_move(
        self, group: int, target: Point, *, speed: float, blend: float = 0.0, acceleration: float = 1.0
    ) -> float:
        """A joint move for a group's controller to ``target.positions`` at ``speed`` (a share of
        the joints' speed; :meth:`~..control.Controller.add_move`): a controller's own move
        instruction (Fanuc's J, Stäubli's movej). Returns the controller time it begins; raises
        :class:`PointRejected`."""
        self.sync()
        controller = self.group(group)
        self.check_ready()
        if target.positions is None:
            raise PointRejected(Reason.MISSING_FIELDS, "a move needs a target position")
        from_rest = not controller.in_motion
        begin = controller.add_move(target.positions, speed=speed, blend=blend, acceleration=acceleration)
        self._kind[group] = "joint moves"
        if from_rest:
            self._points[group] = 0
            self._started[group] = controller.time
            self._stopped[group] = False
            log.info("group %d: joint moves started", group)
        self._points[group] += 1
        for listener in self.point_listeners:
            listener(group, target)
        return begin

    def submit_line(self, group: int, sequence: int, target: LineTarget) -> None:
        """A straight line for a group's controller (:meth:`~..control.Controller.add_line`):
        sequence 0 starts a series of lines, each next one is the last + 1, -4 stops. Raises
        :class:`PointRejected`."""
        self.sync()
        controller = self.group(group)
        if sequence == SpecialSeq.STOP_TRAJECTORY:
            self._interrupted()
            controller.stop()
            return
        last = self._line_sequence[group]
        if sequence < 0 or (sequence > 0 and (last is None or sequence != last + 1)):
            expected = "0" if last is None else f"0 or {last + 1}"
            raise PointRejected(Reason.SEQUENCE, f"line sequence {sequence}: expected {expected}")
        self.check_ready()
        from_rest = not controller.in_motion
        controller.add_line(target._replace(sequence=sequence))
        self._line_sequence[group] = sequence
        self._kind[group] = "straight lines"
        if from_rest:
            self._points[group] = 0
            self._started[group] = controller.time
            self._stopped[group] = False
        self._points[group] += 1
        if sequence == 0:
            log.info("group %d: straight lines started", group)

    def _count(self, group: int, trajectories_before: int) -> None:
        controller = self.groups[group]
        self._kind[group] = "trajectory"
        if controller.trajectories != trajectories_before:
            self._points[group] = 0
            self._started[group] = controller.time
            self._stopped[group] = False
            log.info("group %d: trajectory %d started", group, controller.trajectories)
        self._points[group] += 1

    # -- faults ------------------------------------------------------------------------------------

    def stop(self) -> float:
        """Controlled stop of every group; returns the longest deceleration time."""
        self.sync()
        self._interrupted()
        return max(g.stop() for g in self.groups)

    def estop(self) -> None:
        self.sync()
        log.info("fault: emergency stop engaged", extra=SAFETY)
        self.e_stopped = True
        for g in self.groups:
            g.power_off()
        self._interrupted()

    def drives_off(self) -> None:
        self.sync()
        log.info("fault: drives off", extra=SAFETY)
        for g in self.groups:
            g.power_off()
        self._interrupted()

    def drives_on(self) -> None:
        self.sync()
        if self.e_stopped:
            raise FaultError("the drives cannot be powered while the emergency stop is engaged")
        log.info("drives on", extra=SAFETY)
        for g in self.groups:
            g.power_on()
        self._interrupted()

    def alarm(self, code: int, message: str = "") -> None:
        if not 0 < code <= INT32_MAX:
            raise FaultError(f"an alarm code is a number from 1 to {INT32_MAX}, not {code}")
        self.sync()
        log.info("fault: alarm %d %s", code, message, extra=SAFETY)
        for g in self.groups:
            g.raise_alarm(code, message or f"alarm {code}")
        self._interrupted()

    def reset_alarm(self) -> None:
        self.sync()
        if self.in_error:
            log.info("alarm %d reset", self.error_code, extra=SAFETY)
        for g in self.groups:
            g.reset()
        self._interrupted()

    def reset(self) -> None:
        """The operator's reset: e-stop released, alarms cleared, drives powered."""
        self.sync()
        log.info("reset: e-stop released, alarms cleared, drives on", extra=SAFETY)
        self.e_stopped = False
        self.reset_alarm()
        self.drives_on()
        for listener in self.reset_listeners:
            listener()

    def set_mode(self, mode: RobotMode) -> None:
        if mode not in (RobotMode.AUTO, RobotMode.MANUAL):
            raise FaultError(f"the mode must be AUTO or MANUAL, not {mode}")
        self.sync()
        log.info("mode %s", mode.name, extra=SAFETY)
        if mode != RobotMode.AUTO:
            for g in self.groups:
                g.stop()
        self.mode = mode
        for g in self.groups:
            g.manual = mode == RobotMode.MANUAL
        self._interrupted()

    def _interrupted(self) -> None:
        self.interruptions += 1
        for i, g in enumerate(self.groups):
            if g.in_motion:
                self._stopped[i] = True
        self._line_sequence = [None] * len(self.groups)  # the next line starts a series (0)
        self.notify()

    # -- waiting -----------------------------------------------------------------------------------

    def notify(self) -> None:
        """Wake everything waiting in :meth:`changed` (called after every control-loop wake-up)."""
        moving = [g.in_motion for g in self.groups]
        for i, (now, before) in enumerate(zip(moving, self._was_moving, strict=True) if any(self._was_moving) else ()):
            if before and not now:
                g = self.groups[i]
                kind = self._kind[i]
                what = f"trajectory {g.trajectories}" if kind == "trajectory" else kind
                count = self._points[i]
                noun = "line" if kind == "straight lines" else "point"
                log.info(
                    "group %d: %s %s: %d %s, %s after %.3f s",
                    i,
                    what,
                    "stopped" if self._stopped[i] else "done",
                    count,
                    (noun if count == 1 else noun + "s") + (" received" if self._stopped[i] else ""),
                    "at rest" if self._stopped[i] else "settled",
                    g.time - self._started[i],
                )
                self._stopped[i] = False
        self._was_moving = moving
        self._wakeup.wake()

    def listen(self, tick: Callable[[], None], idle: Callable[[], bool]) -> None:
        """Call ``tick`` after every control-loop wake-up (:attr:`tick_listeners`); ``idle`` says
        when it has nothing to do until something else happens (a request, a connection), so that
        the control loop may be left at rest (:meth:`idle`). A listener added to
        :attr:`tick_listeners` directly keeps the loop running."""
        self.tick_listeners.append(tick)
        self._idle_of[tick] = idle

    def idle(self) -> bool:
        """Nothing waits for this cell's control-loop wake-ups: no task in :meth:`changed` or
        :meth:`until`, every tick listener idle. With its controllers at rest, its control loop
        may then be left until something reads or changes them (:meth:`.ControlLoop.park`)."""
        if self._wakeup.waiting:
            return False
        idle_of = self._idle_of
        for listener in self.tick_listeners:
            idle = idle_of.get(listener)
            if idle is None or not idle():
                return False
        return True

    def tick(self) -> None:
        """After a control-loop wake-up: the :attr:`tick_listeners`, then :meth:`notify`."""
        for listener in self.tick_listeners:
            try:
                listener()
            except Exception:  # a defect in a profile's task must not end the control loop
                log.exception("a controller task failed")
        self.notify()

    async def changed(self) -> None:
        """Wait for the next control-loop wake-up, stop or fault."""
        self.sync()  # a parked control loop runs again: something waits for it (:meth:`idle`)
        await self._wakeup.wait()

    async def until(self, predicate: Callable[[], bool]) -> None:
        """Wait until ``predicate()`` holds, checked now and after every :meth:`changed` (no
        timeout of its own: a controller task waits as long as its controller would, and is
        cancelled with its connection; bound it with ``asyncio.timeout`` otherwise)."""
        self.sync()
        while not predicate():
            await self.changed()


class Wakeup:
    """Tasks waiting for the next time something happens: :meth:`wait` until the next :meth:`wake`
    (which wakes every one waiting then; none is woken by an earlier call)."""

    def __init__(self) -> None:
        self._waiters: list[asyncio.Future[None]] = []

    @property
    def waiting(self) -> bool:
        return any(not w.done() for w in self._waiters)

    async def wait(self) -> None:
        future: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiters.append(future)
        await future

    def wake(self) -> None:
        if not self._waiters:
            return
        waiters, self._waiters = self._waiters, []
        for w in waiters:
            if not w.done():  # not cancelled meanwhile
                w.set_result(None)


def _nothing() -> None:
    pass


def _tri(value: bool) -> int:
    return TriState.TRUE if value else TriState.FALSE


FAULT_COMMANDS = {
    "estop": "engage the emergency stop (motion abandoned at once, drives off)",
    "drives off": "remove drive power (motion abandoned at once)",
    "drives on": "power the drives",
    "alarm CODE [TEXT]": "raise an alarm (motion abandoned, in_error TRUE, error_code CODE)",
    "reset": "release the e-stop, clear alarms, power the drives",
    "stop": "controlled stop (decelerate to rest)",
    "mode auto|manual": "operating mode; MANUAL refuses points (or, with --manual-motion, slows them to its TCP speed)",
}


def apply_fault_command(cell: RobotCell, line: str) -> str:
    """Apply one fault command (see :data:`FAULT_COMMANDS`); returns what was done.
    Raises :class:`FaultError` for an unknown or malformed command."""
    words = line.split()
    if not words:
        raise FaultError("empty command")
    verb, args = words[0].lower(), [w.lower() for w in words[1:]]
    if verb == "estop" and not args:
        cell.estop()
    elif verb == "drives" and args in (["on"], ["off"]):
        (cell.drives_on if args == ["on"] else cell.drives_off)()
    elif verb == "alarm" and args:
        try:
            code = int(words[1])
        except ValueError:
            raise FaultError(f"alarm needs a numeric code, not {words[1]!r}") from None
        cell.alarm(code, " ".join(words[2:]))
    elif verb == "reset" and not args:
        cell.reset()
    elif verb == "stop" and not args:
        cell.stop()
    elif verb == "mode" and args in (["auto"], ["manual"]):
        cell.set_mode(RobotMode.AUTO if args == ["auto"] else RobotMode.MANUAL)
    else:
        known = "; ".join(FAULT_COMMANDS)
        raise FaultError(f"unknown fault command {line.strip()!r} (known: {known})")
    return " ".join(words)
