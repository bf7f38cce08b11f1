"""The emulator process: a :class:`RobotCell` on a control loop behind simple_message servers.

:class:`Emulator` wires the pieces together: the cell's control loop on a real-time clock (sped up
by ``speedup``), the profile's motion server, the state server publishing at ``state_rate`` on
absolute deadlines of the wall clock (so its period does not drift and does not depend on the
number of clients), the MotoROS IO server, and optionally one serial link that carries motion and
state together. Use it from tests and programs::

    async with Emulator(EmulatorConfig(motion_port=0, state_port=0)) as emu:
        print(emu.ports)          # {"motion": ..., "state": ...}
        emu.cell.estop()          # fault injection

``close()`` stops the robot with a controlled deceleration, waits (bounded) until it has settled,
then closes every connection.

With ``capture`` set, every connection of every port (and the serial link) is recorded to that
pcapng file (:mod:`simple_message.capture.writer`: opened by ``start()``, closed by ``close()``
after the connections, bounded by ``capture_max_bytes``).
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import dataclasses
import functools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from simple_message.capture import DEFAULT_MAX_BYTES, CaptureWriter
from simple_message.connection import Tap, TapTee
from simple_message.constants import MAX_JOINTS
from simple_message.dialects import ReplyStyle, reply_style_of
from simple_message.endpoints import DEFAULT_IDLE_AFTER, Server, Session
from simple_message.fixed_reads import FixedReads
from simple_message.lograte import BudgetFilter, LogBudget
from simple_message.wire import ByteOrder, WireFormat

from ..control import (
    DEFAULT_POLICY,
    Clock,
    ControllerConfig,
    ControlLoop,
    RealTimeClock,
    Recorder,
    SimulatedClock,
    policy,
)
from ..control.loop import overrun_times
from ..loader import load_model, load_supervision
from ..model import ModelError, RobotModel
from . import abb, fanuc, motoros, staubli  # noqa: F401 - register the vendors' profiles
from .cell import RobotCell, apply_fault_command
from .generic import GENERIC_PROFILE
from .io_table import IoTable
from .owner import MotionOwner, OnDisconnect
from .profiles import ROLES, STATE_LINK, Behaviour, EmulatorProfile, ProfileContext, ReaderFactory, profile_named
from .shared import Shared
from .ticker import Ticker

__all__ = ["Emulator", "EmulatorConfig", "PeriodStats"]

log = logging.getLogger(__name__)

#: the loggers whose lines peers cause (and the running profile's module logger): connections, the
#: profiles' per-connection lines, the controller's and the cell's lines. One connection's budget
#: does not bound them all: a client connecting and leaving a thousand times a second, or starting
#: and stopping trajectories as fast as it can.
PEER_LOGGERS = (
    "simple_message.connection",
    "simple_message.endpoints",
    "robot_server.control.controller",
    "robot_server.control.motion",
    "robot_server.emulator.cell",
    "robot_server.emulator.owner",
    "robot_server.emulator.generic",
    "robot_server.emulator.motoros",
    "robot_server.emulator.abb",
    "robot_server.emulator.fanuc",
    "robot_server.emulator.staubli",
)
#: what those loggers may write together while an emulator runs: a burst, then lines per second
PEER_LOG_BURST = 100
PEER_LOG_RATE = 20.0
#: the same for the lines that say the robot stopped or may not move (``lograte.lane("safety")``)
SAFETY_LOG_BURST = 20
SAFETY_LOG_RATE = 5.0

ByteOrderChoice = Literal["little", "big", "auto"]
MAX_STATE_RATE = 1000.0


@dataclass(frozen=True)
class EmulatorConfig:
    """Everything the ``robot-server`` command sets (SI units; ports ``None`` = the profile's
    well-known port, 0 = a free one; byte order, float size and reply style ``None`` = the
    profile's dialect's)."""

    #: one model (shipped name or file) per motion group
    models: tuple[str | Path, ...] = ("jibot_zxs",)
    #: the controller family played (a name in :data:`~.profiles.PROFILES`)
    profile: str = GENERIC_PROFILE.name
    host: str = "127.0.0.1"
    motion_port: int | None = None
    state_port: int | None = None
    io_port: int | None = None
    byte_order: ByteOrderChoice | None = None
    float64: bool | None = None
    reply_style: ReplyStyle | str | None = None
    #: state rounds per second (None: the profile's: 40 generic and motoros, 10 abb, ~41.7 fanuc, 50 staubli)
    state_rate: float | None = None
    #: generic profile: JOINT_FEEDBACK to every state client (else only to those that ask)
    feedback: bool = False
    #: interpolation policy (a name of ``robot_server.control.POLICIES``)
    interpolation: str = DEFAULT_POLICY
    interpolation_period: float = 0.004
    servo_period: float = 0.001
    speedup: float = 1.0
    #: run the controller on a simulated clock: as fast as the computer can (for tests and
    #: experiments; the state topics still go out on wall-clock time). Stream points only
    #: with care: time runs on while a client waits for replies, so a stream runs dry
    #: between points; a download is queued whole and runs as planned.
    simulated: bool = False
    #: points the controller queues (streaming); a full queue delays the generic reply
    queue_capacity: int = 64
    #: serve one link over this serial port (pyserial URL) as well
    serial: str | None = None
    #: connections per port where the profile sets no limit of its own (the state port: a hundred
    #: monitoring clients is normal in a lab)
    max_connections: int = 128
    #: what the robot does when its motion client goes away while it is busy (:mod:`.owner`; None:
    #: the profile's: stop, but abb and fanuc let the motion run on)
    on_disconnect: OnDisconnect | str | None = None
    #: close a connection that began a frame and sent nothing more for this long (s)
    frame_timeout: float = 5.0
    #: a cell file (shipped name or path) whose [supervision] replaces the models' own: TCP speed
    #: limits and workspace zones (:mod:`robot_server.workspace`)
    cell: str | Path | None = None
    #: MANUAL mode accepts motion at the reduced TCP speed (ABB; Fanuc T1), instead of refusing it
    manual_motion: bool = False
    #: where every motion group starts (joint values, SI; default: 0, moved into the limits)
    initial_position: tuple[float, ...] | None = None
    #: record every connection's traffic to this pcapng file (:mod:`simple_message.capture.writer`)
    capture: str | Path | None = None
    #: the bound of the capture's files together (bytes; the file rotates, see capture.writer)
    capture_max_bytes: int = DEFAULT_MAX_BYTES
    #: do not reproduce the controller's harsh quirks (see :class:`~.profiles.ProfileContext`)
    lenient: bool = False
    #: the profile's own settings (``--profile-option KEY=VALUE``; :attr:`EmulatorProfile.options`)
    profile_options: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        emulated = profile_named(self.profile)
        dialect = emulated.dialect
        if emulated.fixed_wire:
            _check_fixed_wire(self, emulated)
        known = emulated.options
        for key, _ in self.profile_options:
            if key not in known:
                choices = ", ".join(sorted(known)) or "none"
                raise ValueError(f"the {self.profile} profile has no option {key!r} (its options: {choices})")
        if self.state_rate is None:
            object.__setattr__(self, "state_rate", emulated.state_rate)
        if self.on_disconnect is None:
            object.__setattr__(self, "on_disconnect", emulated.on_disconnect)
        if self.byte_order is None:
            object.__setattr__(self, "byte_order", dialect.wire.byte_order.value)
        if self.byte_order not in ("little", "big", "auto"):
            raise ValueError(f"unknown byte order {self.byte_order!r} (little, big or auto)")
        if self.float64 is None:
            object.__setattr__(self, "float64", dialect.wire.real_size == 8)
        style = dialect.reply_style if self.reply_style is None else reply_style_of(self.reply_style)
        if style not in (ReplyStyle.ECHO, ReplyStyle.HEADER_ONLY) and style is not dialect.reply_style:
            raise ValueError(f"the {self.profile} profile cannot reply {style.value} (echo or header-only)")
        object.__setattr__(self, "reply_style", style)
        if not 0.0 < self.rate <= MAX_STATE_RATE:
            raise ValueError(f"the state rate must be in (0, {MAX_STATE_RATE:g}] Hz, not {self.state_rate}")
        if not self.speedup > 0.0:
            raise ValueError(f"the speed-up factor must be > 0, not {self.speedup}")
        if not self.models:
            raise ValueError("at least one model is needed")
        object.__setattr__(self, "interpolation", policy(self.interpolation).name)
        try:
            object.__setattr__(self, "on_disconnect", OnDisconnect(str(self.on_disconnect)))
        except ValueError:
            choices = ", ".join(o.value for o in OnDisconnect)
            raise ValueError(f"on_disconnect must be one of {choices}, not {self.on_disconnect!r}") from None
        if self.max_connections < 1:
            raise ValueError(f"max_connections must be at least 1, not {self.max_connections}")
        if not self.frame_timeout > 0.0:
            raise ValueError(f"the frame timeout must be > 0 s, not {self.frame_timeout}")
        if self.capture_max_bytes < 1:
            raise ValueError(f"the capture's size bound must be at least 1 byte, not {self.capture_max_bytes}")

    @property
    def rate(self) -> float:
        """State rounds per second (resolved: the option's, else the profile's)."""
        return self.state_rate if self.state_rate is not None else self.emulated.state_rate

    @property
    def wire(self) -> WireFormat:
        order = ByteOrder.BIG if self.byte_order == "big" else ByteOrder.LITTLE
        return WireFormat(order, 8 if self.float64 else 4)

    @property
    def replies(self) -> ReplyStyle:
        """The reply style resolved (the option's, else the dialect's; set once built)."""
        return reply_style_of(self.reply_style or self.emulated.dialect.reply_style)

    @property
    def emulated(self) -> EmulatorProfile:
        """The profile played."""
        return profile_named(self.profile)

    def port(self, name: str) -> int | None:
        """The port to bind for ``name`` (motion, state, io), or None if the profile has none."""
        default = self.emulated.default_port(name)
        if default is None:
            return None
        chosen = {"motion": self.motion_port, "state": self.state_port, "io": self.io_port}[name]
        return default if chosen is None else chosen


def _reader(make: ReaderFactory, lenient: bool, wire: WireFormat) -> FixedReads:
    """A connection's frame cutter, as the profile makes it."""
    return make(wire, lenient=lenient)


def _check_fixed_wire(config: EmulatorConfig, profile: EmulatorProfile) -> None:
    """A controller whose byte order, float size and reply style are its own: refuse others."""
    dialect = profile.dialect
    order = dialect.wire.byte_order.value
    if config.byte_order not in (None, order):
        raise ValueError(f"the {profile.name} controller speaks {order}-endian only, not {config.byte_order}")
    if config.float64 not in (None, dialect.wire.real_size == 8):
        raise ValueError(f"the {profile.name} controller speaks float{dialect.wire.real_size * 8} only")
    if config.reply_style is not None and reply_style_of(config.reply_style) is not dialect.reply_style:
        raise ValueError(f"the {profile.name} controller replies its own way ({dialect.reply_style.value}) only")


@dataclass
class PeriodStats:
    """How punctually the state topics went out (wall clock): the rounds' lateness, its maximum
    and its distribution in :data:`LATENESS_BIN` steps (the last bin holds all later ones)."""

    period: float
    sent: int = 0
    max_lateness: float = 0.0
    skipped: int = 0
    #: rounds by lateness, :data:`LATENESS_BIN` wide each
    histogram: list[int] = field(default_factory=lambda: [0] * LATENESS_BINS)

    def add(self, lateness: float) -> None:
        self.sent += 1
        self.max_lateness = max(self.max_lateness, lateness)
        self.histogram[min(LATENESS_BINS - 1, max(0, int(lateness / LATENESS_BIN)))] += 1

    def quantile(self, q: float) -> float:
        """The lateness that ``q`` of the rounds were within (the upper edge of its bin, s)."""
        return lateness_quantile(self.histogram, q)


#: the lateness histogram's bins: 20 us wide up to 10 ms
LATENESS_BIN = 20e-6
LATENESS_BINS = 500


def lateness_quantile(histogram: Sequence[int], q: float) -> float:
    """The lateness within which ``q`` of the rounds of ``histogram`` (:class:`PeriodStats`'s, or
    several added up) went out (s, the upper edge of the bin; 0 with no rounds)."""
    total = sum(histogram)
    if total == 0:
        return 0.0
    needed, seen = q * total, 0
    for index, count in enumerate(histogram):
        seen += count
        if seen >= needed:
            return (index + 1) * LATENESS_BIN
    return len(histogram) * LATENESS_BIN


class Emulator:
    """A robot controller emulator serving simple_message (see the module doc)."""

    def __init__(
        self,
        config: EmulatorConfig | None = None,
        models: Sequence[RobotModel] | None = None,
        *,
        clock: Clock | None = None,
        shared: Shared | None = None,
    ) -> None:
        self.config = config = config if config is not None else EmulatorConfig()
        #: what this emulator shares with the others of its process (a fleet): then its clock,
        #: servo wake-ups and state ticker are those, and the fleet sets the log ceiling
        self.shared = shared
        if shared is not None:
            if clock is not None and clock is not shared.clock:
                raise ValueError("an emulator that shares its process's clock takes no clock of its own")
            clock = shared.clock
        if models is None:
            models = [load_model(m) for m in config.models]
        for model in models:
            if model.dof > MAX_JOINTS:  # the state topics could not carry it
                raise ModelError(f"{model.name} has {model.dof} joints; simple_message carries at most {MAX_JOINTS}")
        profile = config.emulated
        controller_config = ControllerConfig(
            policy=config.interpolation,
            interpolation_period=config.interpolation_period,
            servo_period=config.servo_period,
            queue_capacity=config.queue_capacity,
            supervision=None if config.cell is None else load_supervision(config.cell),
            initial_position=config.initial_position,
            follow_given_acceleration=profile.follow_given_acceleration,
            increment_feedforward=profile.increment_feedforward,
        )
        if profile.start_tolerance is not None:
            controller_config = dataclasses.replace(controller_config, start_tolerance=profile.start_tolerance)
        self.cell = RobotCell(models, controller_config, manual_motion=config.manual_motion)
        self.io_table = IoTable()
        #: one server per port the profile serves, by role, made with the profile's rules
        self.servers: dict[str, Server] = {}
        for role in ROLES:
            rules = profile.ports.get(role)
            if rules is None:
                continue
            reader = rules.reader
            self.servers[role] = Server(
                config.wire,
                name=role,
                autodetect=config.byte_order == "auto",
                reply_style=config.replies,
                max_connections=config.max_connections if rules.max_connections is None else rules.max_connections,
                answer_topics=rules.answer_topics,
                # a controller that reads fixed sizes waits for ever for the rest of a read
                frame_timeout=config.frame_timeout if reader is None or config.lenient else None,
                idle_after=None if rules.listen_only else DEFAULT_IDLE_AFTER,
                batch_topics=profile.batch_topics,
                reader=None if reader is None else functools.partial(_reader, reader, config.lenient),
                write_split=rules.write_split,
                validate_headers=reader is None,
                excess=rules.excess,
            )
        self.motion_server = self.servers["motion"]
        # a profile without a state port still has one server for the serial link's state topics
        self.state_server = self.servers.get("state") or Server(config.wire, name="state", max_connections=0)
        self.io_server: Server | None = self.servers.get("io")
        #: one motion client at a time, and what a lost one leaves behind (:mod:`.owner`)
        assert config.on_disconnect is not None  # resolved by the config
        self.owner = MotionOwner(self.cell, config.on_disconnect)
        self.owner.install(self.motion_server)
        #: the profile's handlers and state topics
        self.behaviour: Behaviour = profile.build(
            ProfileContext(
                self.cell,
                self.io_table,
                config.feedback,
                owner=self.owner,
                lenient=config.lenient,
                options=dict(config.profile_options),
            )
        )
        self.behaviour.install(self.servers)
        if clock is None:
            clock = SimulatedClock() if config.simulated else RealTimeClock(config.speedup)
        #: the controller's clock (a test may pass a ``SteppedClock`` and advance it itself)
        self.clock: Clock = clock
        self.control = ControlLoop(
            self.cell.groups[0],
            self.clock,
            others=self.cell.groups[1:],
            on_wake=self.cell.tick,
            on_failure=self._control_failed,
            idle=self.cell.idle,
        )
        # read or changed from outside the loop, the controllers first come up to now (in a fleet,
        # a controller at rest is left out of its shared loop's periods until then: ControlLoop.park)
        self.cell.sync = self.control.unpark
        self.state_stats = PeriodStats(1.0 / config.rate)
        self.ports: dict[str, int] = {}
        self._tasks: list[asyncio.Task[None]] = []
        self._started = False
        self._closed = False
        #: the pcapng recording of every connection (``config.capture``), from ``start()`` on
        self.capture: CaptureWriter | None = None
        #: called right after each round of state topics (even with no state client): work that
        #: should not delay the next round is best done then (the web view samples then)
        self.after_state: list[Callable[[], None]] = []
        #: more taps told every connection's traffic, installed by :meth:`start` (e.g. the web view's
        #: traffic list; :class:`~simple_message.connection.Tap`)
        self.taps: list[Tap] = []
        #: the ceiling over :data:`PEER_LOGGERS` while the emulator runs
        self._log_ceiling: BudgetFilter | None = None

    # -- lifecycle ---------------------------------------------------------------------------------

    async def start(self) -> Emulator:
        """Bind the ports, start the control loop and the state topics."""
        if self._started:
            return self
        cfg = self.config
        if cfg.capture is not None:  # an OSError here: nothing is bound or started yet
            self.capture = CaptureWriter(
                cfg.capture, max_bytes=cfg.capture_max_bytes, application=f"robot-server ({cfg.profile} profile)"
            )
        taps: list[Tap] = [*([] if self.capture is None else [self.capture]), *self.taps]
        if taps:
            tap = taps[0] if len(taps) == 1 else TapTee(taps)
            for server in {*self.servers.values(), self.state_server}:
                server.tap = tap
        self._started = True
        try:
            for name, server in self.servers.items():
                port = cfg.port(name)
                if port is not None:
                    self.ports[name] = await server.serve_tcp(cfg.host, port)
        except BaseException:  # e.g. a port taken: nothing stays bound
            for server in self.servers.values():
                await server.close()
            if self.capture is not None:
                self.capture.close()
            raise
        loop = asyncio.get_running_loop()
        if self.shared is not None:  # the fleet bounds the log; the shared loop steps the controller
            self.control.context = contextvars.copy_context()  # as this task's: the log names the controller
            self.shared.join(self.control)
            self.shared.state_rounds(self.state_stats.period).add(self._state_round, self._skip_rounds)
            for server in self.servers.values():  # the periods due run before any request is handled
                server.before_handler = self._catch_up
            if cfg.serial is not None:
                self.motion_server.start_serving(self.motion_server.serve_serial(cfg.serial, data={STATE_LINK: True}))
            return self
        for server in self.servers.values():  # the period due runs before any request is handled
            server.before_handler = self.control.catch_up
        # installed once nothing can fail any more (close takes it off again)
        self._log_ceiling = BudgetFilter(
            LogBudget("emulator", rate=PEER_LOG_RATE, burst=PEER_LOG_BURST),
            # the robot stopping, faults, alarms: a flood of other lines cannot crowd them out
            {"safety": LogBudget("emulator safety", rate=SAFETY_LOG_RATE, burst=SAFETY_LOG_BURST)},
        )
        profile_logger = type(self.behaviour).__module__  # a profile of one's own logs there
        self._log_ceiling.install(*PEER_LOGGERS, *([] if profile_logger in PEER_LOGGERS else [profile_logger]))
        self._tasks.append(loop.create_task(self._run_control(), name="emulator control loop"))
        self._tasks.append(loop.create_task(self._run_state(), name="emulator state topics"))
        if cfg.serial is not None:
            self.motion_server.start_serving(self.motion_server.serve_serial(cfg.serial, data={STATE_LINK: True}))
        return self

    async def serve_fd(self, fd: int, name: str = "pty") -> None:
        """Serve one link over an open descriptor (a pty), carrying motion and state like ``--serial``."""
        await self.motion_server.serve_fd(fd, name=name, data={STATE_LINK: True})

    async def _run_control(self) -> None:
        try:
            await self.control.run()
        except Exception:  # pragma: no cover - a bug; the servers must not hang on it
            self._control_failed()
            raise

    def _control_failed(self) -> None:
        """The control loop failed (a defect, in an ``except`` block): e-stop, the traceback logged."""
        log.exception("the control loop failed: e-stop")
        self.cell.estop()

    async def _run_state(self) -> None:
        period = self.state_stats.period
        # The precise ticker wants an idle loop to hand its wake-ups to: on a simulated or stepped
        # clock the control loop keeps the event loop (and the GIL) busy, and the ticker's thread
        # would starve the topics; the loop's own timers serve those clocks.
        ticker = Ticker() if self.clock.realtime else None
        origin = time.monotonic()
        k = 0
        try:
            while True:
                k += 1
                deadline = origin + k * period
                if ticker is not None:
                    await ticker.sleep_until(deadline)
                else:
                    await asyncio.sleep(max(0.0, deadline - time.monotonic()))
                late = time.monotonic() - deadline
                if late > period:  # fell behind (a stalled machine): skip, never burst
                    missed = int(late // period)
                    self._skip_rounds(missed)
                    k += missed
                    deadline += missed * period
                self._state_round(deadline)
        finally:
            if ticker is not None:
                ticker.close()

    def _skip_rounds(self, count: int) -> None:
        self.state_stats.skipped += count

    def _catch_up(self) -> None:
        """(In a fleet) the periods due before a request is handled: every controller's, and this
        one's left out while it rested."""
        assert self.shared is not None
        self.shared.catch_up()
        self.control.unpark()

    def _state_round(self, deadline: float) -> None:
        """One round of state topics, due at ``deadline`` (``time.monotonic()``), then the hooks."""
        self.state_stats.add(max(0.0, time.monotonic() - deadline))
        try:
            sessions = self.state_sessions()
            reading = bool(sessions or self.after_state)
            if reading:  # someone reads the controllers: up to now first
                self.control.unpark()
            self.publish_state(sessions)
            for hook in self.after_state:
                hook()
            if reading:  # read, not changed: a controller at rest is left out again at once
                self.control.rest_again()
        except Exception:  # pragma: no cover - a bug must not end the topics
            log.exception("publishing state failed")

    def state_sessions(self) -> list[Session]:
        """Everyone who gets state topics: state-port clients and serial links."""
        extra = [s for s in self.motion_server.sessions if s.data.get(STATE_LINK)]
        return [*self.state_server.sessions, *extra]

    def publish_state(self, sessions: list[Session] | None = None) -> None:
        """Send one round of state topics now (to ``sessions``, :meth:`state_sessions` when None)."""
        if sessions is None:
            sessions = self.state_sessions()
        if not sessions:
            return
        if self.config.byte_order == "auto":
            spoken = [s.wire for s in self.motion_server.sessions if s.spoke]
            if spoken:  # clients that never speak get the order the motion port was spoken in
                for s in sessions:
                    s.assume_wire(spoken[-1])
        self.behaviour.publish(self.state_server, sessions)

    async def close(self, settle_timeout: float = 10.0) -> None:
        """Stop the robot (controlled), wait until it has settled (at most ``settle_timeout`` s of
        wall time), then close every connection."""
        if self._closed:
            return
        self._closed = True
        close_behaviour = getattr(self.behaviour, "close", None)
        if close_behaviour is not None:  # its own tasks end first: none hands over a move meanwhile
            close_behaviour()
        if self._started and self.cell.in_motion:
            duration = self.cell.stop()
            log.info("shutting down: decelerating to rest (%.3f s)", duration)
            with contextlib.suppress(TimeoutError):
                await self.wait_until(lambda: not self.cell.in_motion, settle_timeout)
        self.control.stop()
        if self.shared is not None:
            self.shared.leave(self.control)
            self.shared.state_rounds(self.state_stats.period).remove(self._state_round)
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        stats = self.control.stats
        if self.clock.realtime and stats.wakes and self.shared is None:  # a fleet reports its own
            log.info(
                "control loop: %d wake-ups, %d overruns (a wake-up more than one interpolation period late), "
                "latest %.3f ms; state topics: %d rounds, %d skipped, latest %.3f ms",
                stats.wakes,
                stats.overruns,
                stats.max_lateness * 1e3,
                self.state_stats.sent,
                self.state_stats.skipped,
                self.state_stats.max_lateness * 1e3,
            )
            if stats.late_wakes:
                log.info(
                    "control loop overruns, the last %d (time.monotonic() of the late wake-up, lateness): %s",
                    len(stats.late_wakes),
                    overrun_times(stats),
                )
        for server in {*self.servers.values(), self.state_server}:
            await server.close()
        if self.capture is not None:  # after the connections: their ends are in the file
            self.capture.close()
        if self._log_ceiling is not None:
            self._log_ceiling.remove()
        log.info("emulator closed")

    async def __aenter__(self) -> Emulator:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # -- helpers -----------------------------------------------------------------------------------

    def record(self, seconds: float) -> list[Recorder]:
        """Record every servo tick of every motion group from now on, keeping the last ``seconds``
        of controller time (a bounded ring buffer), until :meth:`stop_recording`; returns one
        recorder per group (a recording already running ends)."""
        if not seconds > 0.0:
            raise ValueError(f"the record length must be > 0 s, not {seconds}")
        self.cell.sync()  # the record starts now, not where a controller at rest was left
        period = self.cell.config.servo_period
        capacity = max(1, round(seconds / period))
        instants = capacity // self.cell.groups[0].servo_ticks_per_interpolation + 2  # (one per period)
        recorders = [Recorder(g.dof, capacity, tool_meter=g.tool_meter, instants=instants) for g in self.cell.groups]
        self.control.recorder = recorders[0]
        self.control.other_recorders = list(recorders[1:])
        return recorders

    def stop_recording(self) -> None:
        """End the recording :meth:`record` started (the recorders keep what they hold)."""
        self.control.recorder = None
        self.control.other_recorders = []

    def command(self, line: str) -> str:
        """Apply one fault command (``estop``, ``reset``, ... :data:`~.cell.FAULT_COMMANDS`): the
        same for stdin, ``--fault`` and the web view's buttons. Returns what was done; raises
        :class:`~.cell.FaultError` for an unknown or malformed command."""
        return apply_fault_command(self.cell, line)

    @property
    def in_motion(self) -> bool:
        """Some motion group is moving (or has points to run)."""
        return self.cell.in_motion

    async def settle(self, timeout: float) -> None:
        """Wait until every motion group is at rest (:class:`TimeoutError` after ``timeout`` s)."""
        await self.wait_until(lambda: not self.cell.in_motion, timeout)

    async def wait_until(self, predicate: Callable[[], bool], timeout: float) -> None:
        """Wait until ``predicate()`` holds, checked after every control-loop wake-up."""
        async with asyncio.timeout(timeout):
            await self.cell.until(predicate)

    def describe(self) -> str:
        """The one-line summary printed when the emulator is ready."""
        cfg = self.config
        ports = ", ".join(f"{name} {cfg.host}:{port}" for name, port in self.ports.items())
        if cfg.serial:
            ports += f", serial {cfg.serial}"
        order = "auto-detected byte order" if cfg.byte_order == "auto" else f"{cfg.byte_order}-endian"
        timing = "real time" if cfg.speedup == 1.0 else f"{cfg.speedup:g}x real time"
        if not self.clock.realtime:
            timing = "simulated time"
        models = " + ".join(g.model.name for g in self.cell.groups)
        return (
            f"robot-server ready: {cfg.profile} profile, {models}, {ports}, {order} float{64 if cfg.float64 else 32}, "
            f"{cfg.replies.value} replies, "
            f"{self.config.emulated.motion or f'{cfg.interpolation} interpolation'}, {timing}"
        )
