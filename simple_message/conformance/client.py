"""The client suite (``simple-message conformance client``): play a controller, judge the client.

A PC-side client is only as good as what it does when the controller is *not* a happy path: the
reference streamer blocks forever without a reply (docs/reference/protocol.md §10 pitfall 5), ignores reply
codes (§3, industrial_core#118), may skip or repeat points across a reconnect (§7, PR #263), and a
client that gives up on MotoROS's BUSY cannot drive MotoROS at all (§8.1: the FS100 trace has 48
BUSY replies out of 58). So the suite does not just listen: it sits between the client and a real
controller and makes the controller's awkward answers happen.

**A proxy with an observer.** The suite listens on the profile's ports (motion, state, and io when
the profile has one). For each connection the client opens it opens one to the same port of an
upstream controller and forwards the bytes both ways unchanged, frame by frame, except for the
replies it injects (below). The client's frames, on every port, and the controller's on the motion
port are cut and fed to the rules (the controller's state and IO traffic passes as it comes: no rule
judges the controller). The cutter is the suites' tolerant one (:class:`~.cutter.FrameCutter`, the
server suite's links cut with it too): a frame in the other byte order is evidence, not the end of
the stream (§10 pitfall 1's rule: a length above 0xFFFF read one way is a frame of the other order),
and bytes that are no frame in either order are passed on uncut. Replies keep their order
(a reply answers the oldest request still waiting, §3): an injected reply waits behind the upstream
replies owed before it. The suite also keeps its own connection to the controller's state port,
so it always knows where the robot is (JOINT_POSITION, or JOINT_FEEDBACK of group 0 for MotoROS)
even when the client never subscribes: that is what a first point is compared with.

**The controller upstream** is given (``upstream={"motion": (host, port), "state": ...}``) or,
by default, started for the run: ``python -m robot_server`` (the project's emulator) on free ports,
its one ready line read from stdout (bounded), stopped with SIGINT at the end (then killed). It is
a *process* dependency, never an import: :mod:`simple_message` is the protocol package and imports
only the standard library and itself (the emulator needs numpy and ruckig; a user of the protocol
package needs neither), and a process is also exactly what a real controller is to the suite, so
any controller can take the emulator's place. Each profile is played by the emulator's profile of
the same name (``robot-server --profile abb|fanuc|generic|motoros|staubli``), which behaves as that
controller does (docs/vendors.md): one implementation, the proxy changes no byte of it. ABB's,
Fanuc's and Stäubli's state ports take one client: the suite's own state connection is that one,
and the client's state connections get what it reads, frame by frame.

**Injections** (each once, by trajectory count: a trajectory starts with a point of sequence 0, -1
or -2 streamed or downloaded by the client on the motion port):

* ``busy`` (MotoROS only), first trajectory: the point with sequence 2 (or sequence 1 if it comes to
  rest, i.e. is the last point of a two-point trajectory) is not forwarded; the suite answers it
  MOTO_MOTION_REPLY BUSY as MotoROS builds it (§8.1: groupNo, sequence, command = the request's type,
  subcode 0). The client must send the same point again.
* ``failure``, second trajectory: point 1 is not forwarded and is answered FAILURE in the profile's
  style (echo with reply_code FAILURE; Fanuc: JOINT_POSITION FAILURE; Stäubli: the point's type,
  zeroed, FAILURE; MotoROS: INVALID/3010 DATA). Not for ABB, whose RAPID server never answers
  FAILURE. The controller never got it, so any later point of that trajectory
  would leave a hole.
* ``drop``, third trajectory: right after the reply to point 1 reached the client, the suite closes
  the client's motion connection (and its own upstream one). The client may reconnect.

**The judging** is :mod:`.client_rules`'s: its :class:`~.client_rules.Observer` is told of each
connection, each frame the client sends, each reply once it reached the client, each injection and
each joint state, and gives the verdicts of the rules (``RULES``: ``client.byte-order``,
``client.stop-and-wait``, ``client.sequence``, ``client.point-fields``, ``client.first-point``,
``client.stop``, ``client.busy-reaction``, ``client.failure-reaction``, ``client.reconnect``) at the
end. Nothing a client sends can crash the suite (bad bytes are evidence), and nothing it sends grows
the suite's memory without bound: the proxy's cutters hold at most one incomplete frame each and it
reads no more from a client owed ``MAX_PENDING`` replies; the observer keeps a frame only while a
rule still needs it and caps its evidence.

This module holds the profiles, the options and :class:`ClientSuite`: its lifecycle, the spawned
controller, the listening ports and the connections accepted, the injections (which point gets
which, and the reply played), and the suite's own view of the robot. One connection's forwarding is
:mod:`.client_proxy`'s :class:`~.client_proxy.ProxyLink`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import re
import signal
import sys
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Final

from ..constants import (
    CommType,
    InvalidSubcode,
    MotoResult,
    ReplyCode,
    ValidFields,
)
from ..dialects import ABB, FANUC, GENERIC, MOTOROS, STAUBLI, Dialect, ReplyStyle
from ..framing import decode_or_error
from ..messages import (
    HeaderOnly,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotoMotionReply,
)
from ..wire import ByteOrder, WireFormat
from .client_proxy import READ, ProxyLink, nowhere
from .client_rules import RULES, SAME, Observer, Point, Positions
from .cutter import FrameCutter
from .report import Report

__all__ = [
    "INJECTIONS",
    "PROFILES",
    "RULES",
    "ClientSuite",
    "ClientSuiteOptions",
    "run_client_suite",
]

log = logging.getLogger(__name__)

#: what the suite can make the controller do, each once
INJECTIONS: Final = frozenset({"busy", "failure", "drop"})

#: bounds on a spawned robot-server: its ready line, and its exit after SIGINT
SPAWN_TIMEOUT = 30.0
STOP_TIMEOUT = 10.0
#: connecting to the upstream controller (per accepted client connection, and the suite's state watch)
CONNECT_TIMEOUT = 5.0
#: start() waits at most this long for the first joint state from the controller
FIRST_STATE_TIMEOUT = 5.0
#: what a client of a shared state port may leave unread before it is closed (a client that does
#: not read must not make the suite hold the controller's whole state stream)
_STATE_BACKLOG = 1024 * 1024
_READY = re.compile(r"\b(motion|state|io) (\S+):(\d+)")


# -- profiles and options -----------------------------------------------------------------------------


@dataclass(frozen=True)
class _Profile:
    """A controller family the suite plays: its dialect, and how robot-server is asked to play it."""

    name: str
    dialect: Dialect
    #: robot-server --profile
    emulator: str
    #: it has an IO port (MotoROS)
    io: bool = False
    #: its state port takes one client (ABB, Fanuc, Stäubli): the suite's own state connection is
    #: that one, and the client's state connections get what it reads, frame by frame
    shared_state: bool = False
    #: it never answers FAILURE (ABB's RAPID server answers every request SUCCESS): no failure injection
    never_fails: bool = False


PROFILES: Final[Mapping[str, _Profile]] = {
    p.name: p
    for p in (
        _Profile("abb", ABB, "abb", shared_state=True, never_fails=True),
        _Profile("fanuc", FANUC, "fanuc", shared_state=True),
        _Profile("generic", GENERIC, "generic"),
        _Profile("motoros", MOTOROS, "motoros", io=True),
        _Profile("staubli", STAUBLI, "staubli", shared_state=True),
    )
}


@dataclass(frozen=True)
class ClientSuiteOptions:
    """How the suite plays the controller (see the module doc)."""

    profile: str = "generic"
    host: str = "127.0.0.1"
    #: None: the profile's; 0: any free port
    motion_port: int | None = None
    state_port: int | None = None
    io_port: int | None = None
    #: "little" | "big" | None: the profile's
    byte_order: str | None = None
    float64: bool = False
    #: None: spawn robot-server
    upstream: Mapping[str, tuple[str, int]] | None = None
    inject: frozenset[str] = INJECTIONS
    start_tolerance: float = 0.001
    #: end after this many seconds
    duration: float | None = None
    #: end this long after the client's last connection closed (if it was closed by the client, not by
    #: the drop injection) with none open
    linger: float = 5.0

    def __post_init__(self) -> None:
        _check_options(self)  # ValueError at once, naming the option


def _number(value: object) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _check_options(options: ClientSuiteOptions) -> _Profile:
    """The profile, once every option is known to be usable; :class:`ValueError` says which is not."""
    profile = PROFILES.get(options.profile)
    if profile is None:
        raise ValueError(f"unknown profile {options.profile!r} (supported: {', '.join(sorted(PROFILES))})")
    if not isinstance(options.host, str) or not options.host:
        raise ValueError("host must be an address to listen on, e.g. 127.0.0.1")
    for role, port in (("motion", options.motion_port), ("state", options.state_port), ("io", options.io_port)):
        if port is not None and (isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535):
            raise ValueError(f"{role}_port must be 0..65535 (0: any free port) or None (the profile's), not {port!r}")
    if options.io_port is not None and not profile.io:
        raise ValueError(f"the {profile.name} profile has no IO port (only motoros has one)")
    if options.byte_order not in (None, "little", "big"):
        raise ValueError(f"byte_order must be 'little', 'big' or None (the profile's), not {options.byte_order!r}")
    unknown = set(options.inject) - INJECTIONS
    if unknown:
        raise ValueError(
            f"unknown injection {', '.join(sorted(map(repr, unknown)))} (known: {', '.join(sorted(INJECTIONS))})"
        )
    if not (_number(options.start_tolerance) and options.start_tolerance > 0):
        raise ValueError(f"start_tolerance must be a finite number of radians > 0, not {options.start_tolerance!r}")
    if options.duration is not None and not (_number(options.duration) and options.duration > 0):
        raise ValueError(f"duration must be > 0 s or None, not {options.duration!r}")
    if not (_number(options.linger) and options.linger >= 0):
        raise ValueError(f"linger must be >= 0 s, not {options.linger!r}")
    if options.upstream is not None:
        roles = set(options.upstream)
        missing = {"motion", "state"} - roles
        if missing:
            raise ValueError(f"upstream needs the {' and '.join(sorted(missing))} port(s) of the controller")
        extra = roles - {"motion", "state", "io"}
        if extra:
            raise ValueError(f"upstream roles are motion, state and io, not {', '.join(sorted(extra))}")
        if "io" in roles and not profile.io:
            raise ValueError(f"the {profile.name} profile has no IO port: give upstream motion and state only")
        for role, address in options.upstream.items():
            ok = (
                isinstance(address, tuple | list)
                and len(address) == 2
                and isinstance(address[0], str)
                and isinstance(address[1], int)
                and 0 < address[1] <= 65535
            )
            if not ok:
                raise ValueError(f"upstream[{role!r}] must be (host, port 1..65535), not {address!r}")
    return profile


# -- the suite ----------------------------------------------------------------------------------------


class ClientSuite:
    """The client suite (see the module doc): :meth:`start`, :meth:`wait`, :meth:`finish`.

    ``async with ClientSuite(options) as suite`` starts it and finishes it on the way out;
    :attr:`ports` are the listening ports by role once started, :attr:`report` the report once
    finished. Bad options raise :class:`ValueError` at once; :meth:`start` raises :class:`OSError`
    when a port cannot be bound and :class:`RuntimeError` when robot-server cannot be started.
    """

    def __init__(self, options: ClientSuiteOptions) -> None:
        self.profile = _check_options(options)
        self.options = options
        order = ByteOrder(options.byte_order) if options.byte_order else self.profile.dialect.wire.byte_order
        self.wire = WireFormat(order, 8 if options.float64 else 4)
        self.observer = Observer(
            self.profile.name,
            self.profile.dialect,
            self.wire,
            start_tolerance=options.start_tolerance,
            inject=options.inject,
            clock=self._now,
        )
        #: listening ports by role, once started
        self.ports: dict[str, int] = {}
        #: the controller's ports by role, once started
        self.upstream: dict[str, tuple[str, int]] = dict(options.upstream) if options.upstream else {}
        self.report: Report | None = None
        self._servers: list[asyncio.Server] = []
        self._process: asyncio.subprocess.Process | None = None
        self._readers: list[asyncio.Task[None]] = []
        self._stderr: deque[str] = deque(maxlen=20)
        self._handlers: set[asyncio.Task[None]] = set()
        self._state_task: asyncio.Task[None] | None = None
        self._first_state = asyncio.Event()
        #: the client connections of a shared state port (:attr:`_Profile.shared_state`)
        self._state_clients: set[asyncio.StreamWriter] = set()
        self._activity = asyncio.Event()
        self._open = 0
        self._last_close: float | None = None
        self._linger_armed = False
        self._started: float | None = None
        self._finishing = False
        self._next_link = 0
        self._injection_plan: dict[str, tuple[int, Callable[[Point], bool]]] = {
            "busy": (1, _busy_point),
            "failure": (2, lambda p: p.seq == 1),
            "drop": (3, lambda p: p.seq == 1),
        }

    @staticmethod
    def _now() -> float:
        return asyncio.get_running_loop().time()

    # -- lifecycle ----------------------------------------------------------------------------------

    async def start(self) -> dict[str, int]:
        """Start (or reach) the controller, bind the ports; the listening ports by role."""
        if self._started is not None:
            raise RuntimeError("the client suite is already started")
        self._started = self._now()
        self.observer.t0 = self._started
        try:
            if not self.upstream:
                self.upstream = await self._spawn()
            defaults = self.profile.dialect.ports
            wanted = {"motion": self.options.motion_port, "state": self.options.state_port}
            if self.profile.io and "io" in self.upstream:
                wanted["io"] = self.options.io_port
            for role, port in wanted.items():
                chosen = defaults[role] if port is None else port
                server = await asyncio.start_server(
                    functools.partial(self._accept, role), self.options.host, chosen, reuse_address=True
                )
                self._servers.append(server)
                self.ports[role] = int(server.sockets[0].getsockname()[1])
            self._state_task = asyncio.get_running_loop().create_task(self._watch_state(), name="client suite state")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._first_state.wait(), FIRST_STATE_TIMEOUT)
            if not self._first_state.is_set():
                log.warning("no joint state from the controller at %s yet", self._address("state"))
        except BaseException:
            await self._shutdown()
            raise
        log.info("client suite ready: %s", self.target)
        return dict(self.ports)

    @property
    def target(self) -> str:
        ports = ", ".join(f"{role} {self.options.host}:{port}" for role, port in self.ports.items())
        upstream = "robot-server (spawned)" if self._process is not None else "the controller"
        return (
            f"the client of {ports} ({self.profile.name} profile, {self.wire}; upstream {upstream} at "
            f"{self._address('motion')})"
        )

    def _address(self, role: str) -> str:
        host, port = self.upstream.get(role, ("?", 0))
        return f"{host}:{port}"

    async def wait(self) -> None:
        """Until ``duration`` has passed, or ``linger`` has after the client's last connection closed."""
        if self._started is None:
            raise RuntimeError("start the client suite first")
        duration, linger = self.options.duration, self.options.linger
        end = None if duration is None else self._started + duration
        while True:
            ends = [] if end is None else [end]
            if self._open == 0 and self._last_close is not None and self._linger_armed:
                ends.append(self._last_close + linger)
            now = self._now()
            stop = min(ends) if ends else None
            if stop is not None and now >= stop:
                return
            self._activity.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._activity.wait(), None if stop is None else stop - now)

    async def finish(self) -> Report:
        """Stop everything (connections, the spawned controller), judge, and return the report."""
        if self.report is not None:
            return self.report
        await self._shutdown()
        report = Report(suite="client", target=self.target)
        self.observer.judge(report)
        for line in self.observer.injections:
            log.debug("injection log: %s", line)
        self.report = report
        return report

    async def __aenter__(self) -> ClientSuite:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.finish()

    async def _shutdown(self) -> None:
        self._finishing = True
        for server in self._servers:
            server.close()
        tasks = [*self._handlers, *([self._state_task] if self._state_task is not None else [])]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for server in self._servers:
            with contextlib.suppress(TimeoutError, OSError):
                await asyncio.wait_for(server.wait_closed(), 2.0)
        self._servers.clear()
        await self._stop_process()

    # -- the spawned controller -----------------------------------------------------------------------

    def command(self) -> list[str]:
        """The robot-server command the suite starts when no upstream is given."""
        profile = self.profile
        args = [sys.executable, "-m", "robot_server", "--profile", profile.emulator, "--motion-port", "0"]
        args += ["--state-port", "0"]
        if profile.io:
            args += ["--io-port", "0"]
        args += ["--byte-order", self.wire.byte_order.value]
        if self.wire.real_size == 8:
            args.append("--float64")
        args.append("--no-stdin")
        return args

    async def _spawn(self) -> dict[str, tuple[str, int]]:
        args = self.command()
        log.info("starting %s", " ".join(args[1:]))
        # its own session: a Ctrl-C at the terminal reaches the suite only, which closes the client's
        # connections first and then stops the controller (so no connection ends "by the controller")
        process = await asyncio.create_subprocess_exec(
            *args,
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            start_new_session=True,
        )
        self._process = process
        assert process.stdout is not None and process.stderr is not None
        loop = asyncio.get_running_loop()
        self._readers.append(loop.create_task(self._drain(process.stderr, keep=True), name="robot-server stderr"))
        try:
            line = await asyncio.wait_for(process.stdout.readline(), SPAWN_TIMEOUT)
        except (TimeoutError, ValueError):  # ValueError: a "line" longer than the stream's limit
            await self._stop_process()
            raise RuntimeError(
                f"robot-server did not say it was ready within {SPAWN_TIMEOUT:g} s{self._last_words()}"
            ) from None
        self._readers.append(loop.create_task(self._drain(process.stdout, keep=False), name="robot-server stdout"))
        text = line.decode(errors="replace").strip()
        ports = {m.group(1): (m.group(2), int(m.group(3))) for m in _READY.finditer(text)}
        if "motion" not in ports or "state" not in ports:
            await self._stop_process(exiting=not line)
            why = f"it printed {text!r}" if text else "it exited without a ready line"
            raise RuntimeError(f"robot-server could not be started: {why}{self._last_words()}")
        log.info("upstream controller: %s", text)
        return ports

    def _last_words(self) -> str:
        if not self._stderr:
            return ""
        return "; its last lines: " + " | ".join(self._stderr)

    async def _drain(self, stream: asyncio.StreamReader, *, keep: bool) -> None:
        """Read a pipe of the spawned controller to its end (so it never blocks on a full pipe)."""
        with contextlib.suppress(OSError, ValueError):
            while True:
                line = await stream.readline()
                if not line:
                    return
                text = line.decode(errors="replace").rstrip()
                if keep:
                    self._stderr.append(text[:300])
                log.debug("robot-server: %s", text)

    async def _stop_process(self, *, exiting: bool = False) -> None:
        """Stop the spawned controller: SIGINT (it brings the robot to rest and exits), a bounded wait,
        then SIGKILL. ``exiting``: it closed its stdout, so it is on its way out: no signal (Popen's
        send_signal reaps an exited child before asyncio's child watcher sees its exit status)."""
        process = self._process
        if process is not None and process.returncode is None:
            if not exiting:
                with contextlib.suppress(ProcessLookupError):
                    process.send_signal(signal.SIGINT)
            try:
                await asyncio.wait_for(process.wait(), STOP_TIMEOUT)
            except TimeoutError:
                log.warning("robot-server did not exit within %g s: killed", STOP_TIMEOUT)
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        if self._readers:
            _, pending = await asyncio.wait(self._readers, timeout=STOP_TIMEOUT)
            for task in pending:
                task.cancel()
            await asyncio.gather(*self._readers, return_exceptions=True)
            self._readers.clear()

    # -- connections ----------------------------------------------------------------------------------

    async def _accept(self, role: str, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        if self._finishing:
            writer.close()
            return
        self._handlers.add(task)
        self._next_link += 1
        peer = writer.get_extra_info("peername")
        name = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        state = self.observer.link_opened(self._next_link, role, name)
        self._open += 1
        self._activity.set()
        by = "upstream"
        upstream: asyncio.StreamWriter | None = None
        try:
            if role == "state" and self.profile.shared_state:
                # a controller that takes one state client: this client gets what the suite's own
                # state connection reads (frame by frame), and what it sends goes nowhere (these
                # controllers never read their state socket)
                self._state_clients.add(writer)
                try:
                    by = await ProxyLink(self, state, (reader, writer), nowhere()).run()
                finally:
                    self._state_clients.discard(writer)
                return
            host, port = self.upstream[role]
            try:
                up = await asyncio.wait_for(asyncio.open_connection(host, port), CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                log.warning("%s: cannot reach the controller's %s port %s:%s: %s", state.name, role, host, port, exc)
                return
            upstream = up[1]
            by = await ProxyLink(self, state, (reader, writer), up).run()
        except asyncio.CancelledError:
            # the suite is finishing (it cancels its handlers). Not raised on: this is the stream
            # server's callback task, and asyncio logs a callback task that ends cancelled as an error
            by = "suite"
        finally:
            for w in (writer, upstream):
                if w is not None:
                    w.close()
            for w in (writer, upstream):
                if w is not None:
                    with contextlib.suppress(OSError, TimeoutError, asyncio.CancelledError):
                        await asyncio.wait_for(w.wait_closed(), 1.0)
            self.observer.link_closed(state, by)
            self._open -= 1
            self._last_close = self._now()
            self._linger_armed = by != "drop"
            self._activity.set()
            self._handlers.discard(task)
            log.debug("%s closed by the %s", state.name, by)

    # -- injections -----------------------------------------------------------------------------------

    def injection_for(self, point: Point) -> str | None:
        """Which injection, if any, this point request gets (each once, by trajectory count)."""
        if point.kind != "point" or point.seq is None or point.retry or not point.request:
            return None
        for kind in ("busy", "failure", "drop"):
            if kind not in self.options.inject or kind in self.observer.done:
                continue
            if kind == "busy" and not self.profile.dialect.motion_control:
                continue
            if kind == "failure" and self.profile.never_fails:
                continue
            trajectory, match = self._injection_plan[kind]
            if point.trajectory == trajectory and match(point):
                return kind
        return None

    def injected_reply(self, kind: str, request: Message) -> Message:
        """The reply the suite sends in the controller's place: BUSY, or FAILURE in the profile's style."""
        style = self.profile.dialect.reply_style
        if style is ReplyStyle.MOTO_MOTION_REPLY:
            group = request.robot_id if isinstance(request, JointTrajPtFull) else 0
            if isinstance(request, JointTrajPtFullEx) and request.valid_groups:
                group = request.valid_groups[0].group_no
            sequence = getattr(request, "sequence", -1)
            if kind == "busy":
                return MotoMotionReply(group, sequence, request.msg_type, MotoResult.BUSY, 0)
            return MotoMotionReply(group, sequence, request.msg_type, MotoResult.INVALID, InvalidSubcode.DATA)
        if style is ReplyStyle.HEADER_ONLY:
            return HeaderOnly(request.msg_type, reply_code=ReplyCode.FAILURE)
        if style is ReplyStyle.JOINT_POSITION_ACK and isinstance(request, JointTrajPt):
            return JointPosition(request.sequence, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.FAILURE)
        if style is ReplyStyle.ZEROED and isinstance(request, JointTrajPt):
            return JointTrajPt(request.sequence, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.FAILURE)
        return request.to_reply(ReplyCode.FAILURE)

    # -- the suite's own view of the robot ------------------------------------------------------------

    async def _watch_state(self) -> None:
        """Keep a state connection to the controller: where the robot is, whatever the client reads."""
        host, port = self.upstream["state"]
        delay = 0.1
        while True:
            try:
                reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                log.debug("state connection to %s:%s: %s", host, port, exc)
            else:
                delay = 0.1
                try:
                    await self._read_state(reader)
                finally:
                    writer.close()
                    with contextlib.suppress(OSError, TimeoutError):
                        await asyncio.wait_for(writer.wait_closed(), 1.0)
            await asyncio.sleep(delay)  # back-off before connecting again
            delay = min(delay * 2, 2.0)

    async def _read_state(self, reader: asyncio.StreamReader) -> None:
        cutter = FrameCutter(self.wire.byte_order)
        with contextlib.suppress(OSError):
            while True:
                data = await reader.read(READ)
                if not data:
                    return
                for frame, order in cutter.feed(data):
                    if order is not self.wire.byte_order:
                        return
                    for client in list(self._state_clients):  # a shared state port's clients
                        if client.is_closing():
                            continue
                        if client.transport.get_write_buffer_size() > _STATE_BACKLOG:
                            log.warning(
                                "a state client left %d bytes unread: closed", client.transport.get_write_buffer_size()
                            )
                            client.close()
                            continue
                        client.write(frame)
                    msg = decode_or_error(frame, self.wire)
                    if isinstance(msg, JointPosition) and msg.comm_type == CommType.TOPIC:
                        positions: Positions = msg.joint_data
                    elif (
                        isinstance(msg, JointFeedback) and msg.robot_id == 0 and msg.valid_fields & ValidFields.POSITION
                    ):
                        positions = msg.positions
                    else:
                        continue
                    self.observer.state_sample(positions)
                    self._first_state.set()


async def _until(event: asyncio.Event) -> None:
    await event.wait()


def _busy_point(point: Point) -> bool:
    """Point 2, or point 1 when it comes to rest (the last point of a two-point trajectory)."""
    if point.seq == 2:
        return True
    return point.seq == 1 and bool(point.groups) and all(abs(v) <= SAME for g in point.groups for v in g.velocities)


async def run_client_suite(
    options: ClientSuiteOptions,
    *,
    on_ready: Callable[[dict[str, int]], None] | None = None,
    stop: asyncio.Event | None = None,
) -> Report:
    """Start the suite, call ``on_ready(ports)``, wait until :meth:`ClientSuite.wait` ends or ``stop`` is
    set, finish and return the report."""
    suite = ClientSuite(options)
    await suite.start()
    try:
        if on_ready is not None:
            on_ready(dict(suite.ports))
        loop = asyncio.get_running_loop()
        waiting = [loop.create_task(suite.wait(), name="client suite wait")]
        if stop is not None:
            waiting.append(loop.create_task(_until(stop), name="client suite stop"))
        try:
            await asyncio.wait(waiting, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in waiting:
                task.cancel()
            await asyncio.gather(*waiting, return_exceptions=True)
    finally:
        report = await suite.finish()
    return report
