"""An emulated controller as a ``robot-server`` process (``process=True``): what a client in
another language meets, exactly as a user would start it.

The process is ``python -m robot_server`` with the settings as options (:func:`.settings.command_line`),
its ports 0 (free ones) unless the settings say otherwise, read from its ready line. Fault commands
go to its standard input and its own parser answers them: the log line ``applied: ...`` or its
warning comes back on standard error, which is kept in a file beside the capture. Joints and STATUS
are read from its state port by a simple_message client, as any client reads them; the record of
its servo ticks is the file ``--record`` writes when the process exits, so a test reads it after
:meth:`Process.close` (``ctrl.stop()``). Closing sends SIGINT (the robot decelerates, the files are
written), waits a bounded time, then kills.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import re
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

from simple_message.connection import Subscription
from simple_message.constants import MsgType, TriState, ValidFields
from simple_message.endpoints import Client
from simple_message.messages import JointFeedback, JointPosition, Message, Status

from ..cli import record_path
from ..control import Recorder
from ..emulator import FaultError
from ..loader import load_model
from ..model import RobotModel
from .core import ControllerError, ControllerTimeout, describe_file, describe_joints, describe_status, loopback
from .records import read_npz
from .settings import Settings, command_line

__all__ = ["Process"]

#: wall-clock bounds (s): the ready line, a fault command's answer, the exit after SIGINT
READY_TIMEOUT = 60.0
ANSWER_TIMEOUT = 10.0
EXIT_TIMEOUT = 20.0
#: wall time (s) a wait for state rounds gives beyond its limit: the rounds' own delay, and (a
#: wait for time passing) a controller that cannot keep up with its speed-up
LATENCY = 1.0
GRACE = 10.0
#: the ready line's ports (the host may be an IPv6 address)
PORT = re.compile(r"\b(motion|state|io) (\S+):(\d+)")
#: the log lines of robot-server's fault commands (robot_server/cli.py: _apply)
APPLIED = re.compile(r" INFO robot_server\.cli: applied: (.*)$")
REFUSED = re.compile(r" WARNING robot_server\.cli: (.*)$")
#: the log's last lines kept for the report
TAIL = 20


class Process:
    """One ``robot-server`` process and a state-port client on the current loop (see the module doc)."""

    def __init__(self, settings: Settings, log_path: Path) -> None:
        self.settings = settings
        config = settings.spec.config
        self.host = loopback(config.host)
        self.ports: dict[str, int] = {}
        self.models: list[RobotModel] = [load_model(m) for m in config.models]
        self.capture_path: Path | None = None if config.capture is None else Path(config.capture)
        self.record_path = settings.spec.record
        self.log_path = log_path
        self.closed = False
        self.returncode: int | None = None
        self.proc: asyncio.subprocess.Process | None = None
        self.ready_line = ""
        self._log: IO[str] | None = None
        self._tail: collections.deque[str] = collections.deque(maxlen=TAIL)
        self._tasks: list[asyncio.Task[None]] = []
        self._client: Client | None = None
        self._answer: asyncio.Future[tuple[bool, str]] | None = None
        self._asked = ""
        self._lock = asyncio.Lock()
        self._joints: tuple[float, ...] | None = None
        self._status: Status | None = None
        self._statuses = 0
        self._changed = asyncio.Event()
        self._ready_at = 0.0
        #: the controller time of the last JOINT_FEEDBACK that carried one
        self._clock: float | None = None
        self._records: list[Recorder] | None = None

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    # -- lifecycle ---------------------------------------------------------------------------------

    async def start(self) -> None:
        argv = [sys.executable, "-m", "robot_server", *command_line(self.settings)]
        self._log = self.log_path.open("w", encoding="utf-8")
        self._log.write("$ " + " ".join(argv) + "\n")
        self.proc = proc = await asyncio.create_subprocess_exec(
            *argv, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
        )
        assert proc.stdout is not None and proc.stderr is not None
        name = self.settings.name
        loop = asyncio.get_running_loop()
        self._tasks.append(loop.create_task(self._read_log(proc.stderr), name=f"{name} stderr"))
        try:
            async with asyncio.timeout(READY_TIMEOUT):
                line = (await proc.stdout.readline()).decode(errors="replace").strip()
        except TimeoutError:
            raise ControllerError(f"{name}: robot-server printed no ready line within {READY_TIMEOUT:g} s") from None
        if not line.startswith("robot-server ready"):
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(EXIT_TIMEOUT):
                    await proc.wait()
                    await asyncio.gather(*self._tasks, return_exceptions=True)
            tail = "\n".join(self._tail)
            raise ControllerError(f"{name}: robot-server did not start (exit status {proc.returncode}):\n{tail}")
        self._ready_at = time.monotonic()
        self.ready_line = line
        self._note(line)
        self._tasks.append(loop.create_task(self._read_log(proc.stdout), name=f"{name} stdout"))
        self.ports = {role: int(port) for role, _, port in PORT.findall(line)}
        config = self.settings.spec.config
        if "state" in self.ports:
            client = Client.tcp(
                self.host,
                self.ports["state"],
                config.wire,
                reconnect=None,
                dialect=config.emulated.dialect,
                name=f"{name} state",
            )
            subscription = client.subscribe(msg_types=(MsgType.JOINT_POSITION, MsgType.JOINT_FEEDBACK, MsgType.STATUS))
            self._client = client
            await client.start(ANSWER_TIMEOUT)
            timed = config.profile == "generic"
            if timed:  # its state port sends JOINT_FEEDBACK, with the controller's time, when asked
                await client.send(JointFeedback())
            self._tasks.append(loop.create_task(self._read_state(subscription), name=f"{name} state"))
            try:  # usable at once: joints, STATUS (and the time) known
                async with asyncio.timeout(ANSWER_TIMEOUT):
                    while self._joints is None or self._status is None or (timed and self._clock is None):
                        await self._changed.wait()
            except TimeoutError:
                raise ControllerError(
                    f"{name}: robot-server's state port sent no joints and STATUS within {ANSWER_TIMEOUT:g} s"
                ) from None

    def _note(self, line: str) -> None:
        if self._log is not None:
            self._log.write(line + "\n")
            self._log.flush()
        self._tail.append(line)

    async def _read_log(self, stream: asyncio.StreamReader) -> None:
        """The process's output, line by line, into the log; fault commands' answers handed over."""
        while raw := await stream.readline():
            line = raw.decode(errors="replace").rstrip("\n")
            self._note(line)
            answer = self._answer
            if answer is None or answer.done():
                continue
            applied, refused = APPLIED.search(line), REFUSED.search(line)
            if applied is not None and applied.group(1).lower() == self._asked.lower():
                answer.set_result((True, applied.group(1)))
            elif refused is not None:  # (a scheduled --fault's answer names another command)
                answer.set_result((False, refused.group(1)))

    async def _read_state(self, subscription: Subscription) -> None:
        """The state port's messages into what the handle reads. A STATUS is taken in with the
        joints that follow it, which end its round where the round ends with JOINT_FEEDBACK
        (generic), so the controller time read with a STATUS is its round's: the state read
        changes only there, all at once, however late a waiting task looks at it."""
        dof = self.models[0].dof
        received: Status | None = None
        with contextlib.suppress(Exception):  # the connection closed: the last state stays
            while True:
                message: Message = await subscription.get()
                if isinstance(message, Status):
                    received = message
                    continue
                if isinstance(message, JointPosition):
                    self._joints = tuple(message.joint_data[:dof])
                elif isinstance(message, JointFeedback) and message.robot_id == 0:
                    self._joints = tuple(message.positions[:dof])
                    if message.valid_fields & ValidFields.TIME:
                        self._clock = message.time
                else:
                    continue
                if received is not None:
                    self._status, received = received, None
                    self._statuses += 1
                self._changed.set()
                self._changed = asyncio.Event()

    async def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            if self._client is not None:
                await self._client.close()
            proc = self.proc
            if proc is not None and proc.returncode is None:
                proc.send_signal(signal.SIGINT)
                try:
                    async with asyncio.timeout(EXIT_TIMEOUT):
                        await proc.wait()
                except TimeoutError:
                    self._note(f"(robot-server did not exit within {EXIT_TIMEOUT:g} s of SIGINT: killed)")
                    proc.kill()
                    await proc.wait()
            if proc is not None:
                if proc.stdin is not None:
                    proc.stdin.close()
                    with contextlib.suppress(OSError):
                        await proc.stdin.wait_closed()
                async with asyncio.timeout(EXIT_TIMEOUT):
                    await asyncio.gather(*self._tasks[:2], return_exceptions=True)
        finally:
            for task in self._tasks:
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            if self._log is not None:
                self._log.close()
        self.returncode = None if self.proc is None else self.proc.returncode
        if self.returncode not in (0, None):
            tail = "\n".join(self._tail)
            raise ControllerError(f"{self.settings.name}: robot-server exited with status {self.returncode}:\n{tail}")

    # -- reading -----------------------------------------------------------------------------------

    def joints(self, group: int = 0) -> tuple[float, ...]:
        if group != 0:
            raise ControllerError(f"{self.settings.name}: a process's joints are read for motion group 0 only")
        if self._joints is None:
            raise ControllerError(f"{self.settings.name}: the state port has sent no joints yet")
        return self._joints

    def status(self) -> Status:
        if self._status is None:
            raise ControllerError(f"{self.settings.name}: the state port has sent no STATUS yet")
        return self._status

    def time(self) -> float:
        """Controller time as of the last state round, where the state port says it (the generic
        profile's JOINT_FEEDBACK); else the wall time since the ready line times the speed-up (a
        controller that cannot keep up with its speed-up runs behind that estimate)."""
        if self._clock is not None:
            return self._clock
        speedup = self.settings.speedup
        assert isinstance(speedup, float)
        return (time.monotonic() - self._ready_at) * speedup

    def in_motion(self) -> bool:
        return self.status().in_motion == TriState.TRUE

    def records(self) -> list[Recorder]:
        if self._records is None:
            if not self.closed:
                raise ControllerError(
                    f"{self.settings.name}: a robot-server process writes its record when it exits: stop it first "
                    "(ctrl.stop()), then read ctrl.record"
                )
            target = self.record_path
            files = [] if target is None else [record_path(target, k) for k in range(len(self.models))]
            if not files or not all(f.exists() for f in files):
                raise ControllerError(f"{self.settings.name}: robot-server wrote no record")
            self._records = [read_npz(f, m.joint_names) for f, m in zip(files, self.models, strict=True)]
        return self._records

    # -- acting ------------------------------------------------------------------------------------

    async def fault(self, command: str) -> str:
        """Type ``command`` on the process's standard input; its answer (``applied: ...``) is
        returned, its refusal raised as :class:`~robot_server.emulator.FaultError`."""
        line = " ".join(command.split())
        if not line or "\n" in command.strip():
            raise FaultError(f"one fault command, not {command!r}")
        proc = self.proc
        if proc is None or proc.stdin is None or proc.returncode is not None or self.closed:
            raise ControllerError(f"{self.settings.name}: robot-server is not running")
        async with self._lock:
            answer: asyncio.Future[tuple[bool, str]] = asyncio.get_running_loop().create_future()
            self._answer, self._asked = answer, line
            try:
                try:
                    proc.stdin.write((line + "\n").encode())
                    await proc.stdin.drain()
                except OSError as exc:
                    raise ControllerError(f"{self.settings.name}: robot-server's input is closed: {exc}") from None
                async with asyncio.timeout(ANSWER_TIMEOUT):
                    applied, text = await answer
            except TimeoutError:
                raise ControllerError(
                    f"{self.settings.name}: robot-server did not answer {line!r} within {ANSWER_TIMEOUT:g} s"
                ) from None
            finally:
                self._answer = None
        if not applied:
            raise FaultError(text)
        return text

    async def _rounds(self, predicate: Callable[[], bool], seconds: float, what: str, grace: float = LATENCY) -> None:
        """Wait for state rounds until ``predicate()`` holds, at most ``seconds`` of the process's
        clock (wall time times the speed-up), and ``grace`` s of wall time more."""
        speedup = self.settings.speedup
        assert isinstance(speedup, float)
        try:
            async with asyncio.timeout(seconds / speedup + grace):
                while not predicate():
                    await self._changed.wait()
        except TimeoutError:
            raise self._timeout(what, seconds) from None

    async def advance(self, seconds: float) -> float:
        if not seconds >= 0.0:
            raise ValueError(f"time only moves forward, not by {seconds}")
        end = self.time() + seconds
        await self._rounds(lambda: self.time() >= end, seconds, f"{seconds:g} s passing", GRACE)
        return self.time()

    async def advance_until(self, predicate: Callable[[], bool], limit: float, dt: float | None, what: str) -> float:
        await self._rounds(predicate, limit, what)
        return self.time()

    async def wait_idle(self, timeout: float) -> float:
        """At rest by the state port: STATUS in_motion FALSE in a round that came after the
        call's first one (which may have been on its way already)."""
        first = self._statuses + 2
        await self._rounds(
            lambda: self._statuses >= first and self._status is not None and self._status.in_motion == TriState.FALSE,
            timeout,
            "the robot at rest",
        )
        return self.time()

    def _timeout(self, what: str, limit: float) -> ControllerTimeout:
        return ControllerTimeout(
            f"{self.settings.name}: {what}: not within {limit:g} s of the process's clock; "
            f"{describe_joints(self._joints)}; {describe_status(self._status)}"
        )

    # -- the report --------------------------------------------------------------------------------

    def describe(self) -> str:
        config = self.settings.spec.config
        models = " + ".join(m.name for m in self.models)
        ports = ", ".join(f"{role} {self.host}:{port}" for role, port in self.ports.items())
        running = "exited" if self.proc is not None and self.proc.returncode is not None else "running"
        lines = [
            f"{self.settings.name}: {config.profile} profile, {models}, robot-server process {self.pid} ({running}), "
            f"{self.settings.speedup:g}x real time; {ports}",
            f"controller time: about {self.time():.3f} s",
            describe_joints(self._joints) + " (group 0, as the state port sends them)",
            describe_status(self._status),
        ]
        for path, what in (
            (self.capture_path, "traffic (pcapng; Wireshark, or: simple-message decode FILE)"),
            (self.log_path, "log"),
        ):
            text = describe_file(path, what)
            if text is not None:
                lines.append(text)
        lines.append("the log's last lines:")
        lines += [f"  {line}" for line in self._tail]
        return "\n".join(lines)
