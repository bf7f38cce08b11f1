"""Streaming benchmark: does the emulator move like a real controller when a ROS client streams a
MoveIt trajectory to it?

    python bench/streaming.py [--quick] [--cases NAME ...] [--policies NAME ...] [--cadence SECONDS] [--keep DIR]

Every run (one case, one interpolation policy) gets its own ``robot-server`` process (``python -m
robot_server``, as users run it: free loopback ports, ``--record`` of every servo tick, default model
``jibot_zxs``). The client here fills and paces the messages exactly as the real ROS clients do,
waits until the motion is over (STATUS on the state port: ``in_motion`` TRUE, then FALSE; at most
the planned time + 40 s), stops the server with SIGINT and analyses the record it writes. One
Markdown table per case, one row per policy; at the end, which targets the ``blend`` rows and the
JOINT_TRAJ_PT_FULL rows meet. Progress goes to stderr, the tables to stdout.

**The trajectory** is the shape of ``shared/ros/goal.py``'s ``plan()`` (what MoveIt's time
parametrisation produces): a trapezoidal path parameter s(t) (acceleration for T/4, cruise, deceleration
for T/4), ``q = q0 + s·DELTA + sin(πs)·BUMP``, with analytic velocities and accelerations, from the
position the state port publishes first. Cases: ``dense-2s`` and ``dense-1s`` (101 points over 2 s /
1 s), ``sparse`` (the same shape, 9 points over 4 s), ``over-fast`` (41 points, T chosen so that
the plan's peak joint acceleration is 1.8x the model's limit: 0.42 s for jibot_zxs, a point every
10.5 ms), all JOINT_TRAJ_PT under every policy;
``full-generic-2s``/``-1s`` and ``full-motoros-2s``/``-1s`` (101 JOINT_TRAJ_PT_FULL points), under the
server's default policy only. The vendor cases ``abb-``, ``fanuc-`` and ``staubli-dense-2s`` and ``-sparse``
send the dense 2 s and the sparse trajectory as the vendors' ROS drivers do to ``robot-server --profile
abb|fanuc|staubli``, which runs them as that controller does (robot_server/emulator/abb.py, fanuc.py,
staubli.py): their rows say what a real controller makes of them, against no target.

**The clients.** JOINT_TRAJ_PT as industrial_robot_client's streamer sends it
(joint_trajectory_interface.cpp, joint_trajectory_streamer.cpp): SERVICE_REQUESTs, one in flight;
sequence = point index; ``velocity`` = the largest |v_i| / v_max_i, or 0.1 when that is not > 0 (a
point at rest, or one without velocities), clipped to [0, 1]; ``duration`` = the difference of
consecutive times from start, and 10 s for the first point (``calc_duration`` keeps ``last_time`` in
a function-static variable, so every trajectory's first point gets ``default_duration_``). A FAILURE
reply counts as refused and the next point follows, as ``sendAndReceiveMsg`` succeeds on any valid
reply. JOINT_TRAJ_PT_FULL as motoman_driver fills it: robot_id 0, sequence i, valid_fields TIME |
POSITION | VELOCITY | ACCELERATION, time from start, positions, velocities, accelerations. On the
generic profile one request in flight, SUCCESS -> next point. For the vendors: abb_driver's downloader
(TOPICs -1, 1 ... n-2, -3 sent back to back, velocity 0, the same durations; abb_joint_downloader_node.cpp),
fanuc_driver's streamer (the stock one, big-endian, the controller's J3 = J3 - J2 as ``J23_factor`` 1
makes it), and for Stäubli the stock streamer itself (a FAILURE: the next point follows). On the MotoROS profile first
CHECK_MOTION_READY (FALSE: not started), START_TRAJ_MODE (SUCCESS), CHECK_MOTION_READY (TRUE), then
the points: BUSY -> the same point again 5 ms later, SUCCESS -> next, anything else -> refused and
the next point follows (motoman_driver would abort the trajectory instead; moving on shows how much
of it the controller takes). ``--cadence`` sleeps between points like the streamer's 5 ms loop
(default 0: back to back).

**The metrics**, from the record of motion group 0 (1 ms servo ticks; points are acted on at the
4 ms interpolation instants) and the client's counts:

* accepted: SUCCESS replies / points (MotoROS: points finally accepted, and the BUSY retries);
* start (ms): from the servo tick whose ``points`` column first counts the trajectory's first point
  to the first tick where the commanded position has moved (more than 1e-9 rad, any joint);
* executed (s): from that first motion to the tick where the command reaches its final value (stays
  within 1e-9 rad of it from then on); exec/plan divides it by the last time from start;
* deviation cmd / actual (mm): the largest distance of the flange (forward kinematics of the
  commanded, resp. actual, joint positions at every tick from the first motion to the end of the
  record) from the planned flange path: the plan sampled every 1 ms of plan time (at least 2000
  segments), through forward kinematics, as a polyline (point-to-segment distance);
* stops: intermediate stops, runs of ticks strictly between the first motion and the end of the
  motion in which every joint's commanded velocity (the record's ``command_velocity``) is below
  1e-4 rad/s plus a_max x 2 ms (half an interpolation period; 0.02 rad/s for jibot_zxs); runs
  touching either end are not counted. The margin is needed because the setpoint is sampled every
  4 ms: a stop between two instants is seen at most 2 ms away from it, where a joint within its
  acceleration limit may already be back at a_max x 2 ms (with 1e-4 rad/s alone, ruckig's 99 stops
  of the dense case count as about 13). The price: a motion that slow on every joint counts as
  stopped, which in these plans only the first and last few points are;
* peak acc (rad/s²) and peak jerk (rad/s³): second and third differences of the commanded positions
  at the interpolation instants (what the drives are asked to do), as ``client.demo.analyse``
  computes them; acc/plan divides the peak by the plan's own peak acceleration (case heading);
* final error (rad): the largest |final commanded position - last planned point|.

Last, **planning a streamed point**: in process, the controller's own work when a JOINT_TRAJ_PT arrives
(checks, through-state, segment, limits, slowing down), each ``add`` timed alone; median, p90, max.

A run that fails (server crash, timeout, refused handshake) prints its row with the reason; when the
record exists its metrics are still shown. Rows also note refusal reasons (from the server's log),
queues that ran dry and alarms. ``--keep DIR`` keeps each run's CSV record and server log.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import csv
import math
import re
import signal
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))
from codec import machine

from client.demo import distance_to_path
from robot_server import Array
from robot_server.cli import parser as server_parser
from robot_server.kinematics import fk_batch
from robot_server.loader import load_model
from robot_server.model import RobotModel
from simple_message import (
    BE32,
    LE32,
    InvalidSubcode,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    Message,
    MotoCommand,
    MotoMotionCtrl,
    MotoMotionReply,
    MotoResult,
    MsgType,
    NotReadySubcode,
    SimpleMessageError,
    Status,
    TriState,
    ValidFields,
)
from simple_message.connection import Connection
from simple_message.constants import CommType
from simple_message.errors import RequestFailed
from simple_message.transport import open_tcp
from simple_message.wire import WireFormat

MODEL = "jibot_zxs"
HOST = "127.0.0.1"
#: goal.py's plan: joint displacement along the path and the sideways bump (rad)
DELTA = np.array([1.2, 0.4, -0.5, 0.6, -0.4, 0.8]) * 0.5
BUMP = np.array([0.0, 0.15, 0.10, 0.0, 0.10, 0.0]) * 0.5
#: industrial_robot_client's defaults: first-point duration (s) and velocity ratio
DEFAULT_DURATION = 10.0
DEFAULT_VELOCITY_RATIO = 0.1
#: motoman_driver re-sends a BUSY point on its next 5 ms loop
BUSY_RETRY = 0.005
#: over-fast case: the plan's peak joint acceleration over the model's limit
OVER_FAST = 1.8
#: bound on each run: planned time plus this (s)
SLACK = 40.0
MOVED = 1e-9  # rad: the command has moved (beyond rounding: a smooth start from rest counts from its first tick)
ARRIVED = 1e-9  # rad: the command is at its final value
STILL = 1e-4  # rad/s: a joint's commanded speed counts as stopped below this (plus the sampling margin)
PATH_STEP = 0.001  # s of plan time between polyline vertices (at most)
PATH_MIN_SEGMENTS = 2000
CHUNK = 16384  # ticks per forward-kinematics / distance chunk
FULL_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY | ValidFields.ACCELERATION


# -- the trajectory ----------------------------------------------------------------------------------


def path_parameter(t: Array, duration: float) -> tuple[Array, Array, Array]:
    """goal.py's trapezoidal s(t) and its two derivatives (acceleration for T/4, then cruise)."""
    ta = 0.25 * duration
    vs = 1.0 / (duration - ta)
    a = vs / ta
    s = np.where(
        t < ta,
        0.5 * a * t**2,
        np.where(t <= duration - ta, 0.5 * a * ta**2 + vs * (t - ta), 1.0 - 0.5 * a * (duration - t) ** 2),
    )
    sd = np.where(t < ta, a * t, np.where(t <= duration - ta, vs, a * (duration - t)))
    sdd = np.where(t < ta, a, np.where(t <= duration - ta, 0.0, -a))
    return s, sd, sdd


def shape(q0: Array, t: Array, duration: float) -> tuple[Array, Array, Array]:
    """Positions, velocities and accelerations ``(len(t), 6)`` of goal.py's plan at times ``t``."""
    s, sd, sdd = (x[:, None] for x in path_parameter(t, duration))
    q = q0 + s * DELTA + np.sin(np.pi * s) * BUMP
    dq = DELTA + np.pi * np.cos(np.pi * s) * BUMP
    ddq = -(np.pi**2) * np.sin(np.pi * s) * BUMP
    return q, dq * sd, ddq * sd**2 + dq * sdd


def peak_acceleration(duration: float) -> Array:
    """The plan's peak |acceleration| per joint (it does not depend on q0)."""
    ta = 0.25 * duration
    # a fine grid, plus both sides of the acceleration steps at ta and T - ta
    t = np.concatenate([np.linspace(0.0, duration, 20_001), [ta * (1 - 1e-9), duration - ta * (1 - 1e-9)]])
    _, _, acc = shape(np.zeros(DELTA.size), t, duration)
    peak: Array = np.max(np.abs(acc), axis=0)
    return peak


def over_fast_duration(model: RobotModel) -> float:
    """T for which the plan's peak joint acceleration is OVER_FAST x the model's limit (it scales as 1/T²)."""
    worst = float(np.max(peak_acceleration(1.0) / model.max_acceleration))
    return math.sqrt(worst / OVER_FAST)


@dataclass(frozen=True)
class Trajectory:
    """What MoveIt sends: times from start and, per point, positions, velocities, accelerations."""

    times: Array
    positions: Array
    velocities: Array
    accelerations: Array
    duration: float
    q0: Array

    @classmethod
    def plan(cls, q0: Array, duration: float, points: int) -> Trajectory:
        t = np.linspace(0.0, duration, points)
        q, v, a = shape(q0, t, duration)
        return cls(t, q, v, a, duration, q0)

    def __len__(self) -> int:
        return int(self.times.size)

    def flange_path(self, model: RobotModel) -> Array:
        """The planned flange path: vertices ``(M, 3)`` every PATH_STEP s of plan time or finer."""
        segments = max(PATH_MIN_SEGMENTS, math.ceil(self.duration / PATH_STEP))
        q, _, _ = shape(self.q0, np.linspace(0.0, self.duration, segments + 1), self.duration)
        path: Array = fk_batch(model, q)[:, :3, 3]
        return path


# -- cases -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    slug: str
    title: str
    points: int
    duration: float | None  # None: over-fast, from the model's acceleration limit
    full: bool = False  # JOINT_TRAJ_PT_FULL (else JOINT_TRAJ_PT)
    profile: str = "generic"

    @property
    def dense(self) -> bool:
        return self.points > 20

    @property
    def message(self) -> str:
        return "JOINT_TRAJ_PT_FULL" if self.full else "JOINT_TRAJ_PT"

    def planned_duration(self, model: RobotModel) -> float:
        return self.duration if self.duration is not None else over_fast_duration(model)


CASES = (
    Case("dense-2s", "dense 2 s", 101, 2.0),
    Case("dense-1s", "dense 1 s", 101, 1.0),
    Case("sparse", "sparse", 9, 4.0),
    Case("over-fast", "over-fast", 41, None),
    Case("full-generic-2s", "FULL generic 2 s", 101, 2.0, full=True),
    Case("full-generic-1s", "FULL generic 1 s", 101, 1.0, full=True),
    Case("full-motoros-2s", "FULL MotoROS 2 s", 101, 2.0, full=True, profile="motoros"),
    Case("full-motoros-1s", "FULL MotoROS 1 s", 101, 1.0, full=True, profile="motoros"),
    Case("abb-dense-2s", "ABB dense 2 s", 101, 2.0, profile="abb"),
    Case("abb-sparse", "ABB sparse", 9, 4.0, profile="abb"),
    Case("fanuc-dense-2s", "Fanuc dense 2 s", 101, 2.0, profile="fanuc"),
    Case("fanuc-sparse", "Fanuc sparse", 9, 4.0, profile="fanuc"),
    Case("staubli-dense-2s", "Staubli dense 2 s", 101, 2.0, profile="staubli"),
    Case("staubli-sparse", "Staubli sparse", 9, 4.0, profile="staubli"),
)
#: the vendor profiles: each runs points its own way (no interpolation policy, no target)
VENDORS = ("abb", "fanuc", "staubli")
QUICK = ("dense-2s", "full-motoros-2s")


def server_option(dest: str) -> argparse.Action:
    """An option of ``robot-server``'s own parser (its choices and defaults are the truth)."""
    for action in server_parser()._actions:
        if action.dest == dest:
            return action
    raise LookupError(f"robot-server has no option {dest!r}")


def available_policies() -> list[str]:
    """The interpolation policies robot-server knows, ``blend`` first when it exists."""
    from robot_server.control import POLICIES

    return sorted(POLICIES, key=lambda name: name != "blend")


# -- the server --------------------------------------------------------------------------------------


class RunFailed(Exception):
    """A run could not complete; the message says why."""


def _create(path: Path) -> BinaryIO:
    """A new local log file for a child's stderr (instantaneous: no need for a thread)."""
    return open(path, "wb")


class ServerProcess:
    """One ``robot-server`` child: started, read for its ports, stopped with SIGINT (killed if need be)."""

    def __init__(self, proc: asyncio.subprocess.Process, ports: dict[str, int], log: Path) -> None:
        self.proc, self.ports, self.log = proc, ports, log
        self._drain: asyncio.Task[bytes] | None = None

    @classmethod
    async def start(cls, args: Sequence[str], log: Path) -> ServerProcess:
        with _create(log) as stderr:  # the child keeps its own descriptor
            proc = await asyncio.create_subprocess_exec(
                sys.executable,
                "-m",
                "robot_server",
                "--host",
                HOST,
                "--motion-port",
                "0",
                "--state-port",
                "0",
                "--no-stdin",
                "--log-level",
                "WARNING",
                *args,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.PIPE,
                stderr=stderr,
            )
        server = cls(proc, {}, log)
        try:
            assert proc.stdout is not None
            try:
                line = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).decode(errors="replace")
            except TimeoutError:
                raise RunFailed("robot-server printed no ready line within 30 s") from None
            server.ports = {name: int(port) for name, port in re.findall(r"(motion|state|io) [\d.]+:(\d+)", line)}
            if "motion" not in server.ports or "state" not in server.ports:
                if not line:  # it is exiting: let it finish, so that kill() does not race its reaping
                    await server.exited(10.0)
                raise RunFailed(f"robot-server did not start: {line.strip() or server.last_log_line()}")
            server._drain = asyncio.get_running_loop().create_task(proc.stdout.read())  # nothing more is expected
        except BaseException:
            await server.kill()
            raise
        return server

    def last_log_line(self) -> str:
        with contextlib.suppress(OSError):
            lines = self.log.read_text(errors="replace").strip().splitlines()
            if lines:
                return lines[-1]
        return "no output"

    async def exited(self, grace: float = 1.0) -> str | None:
        """Why the server is gone (waiting ``grace`` s for it to be), or None if it still runs."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.proc.wait(), grace)
        code = self.proc.returncode
        return None if code is None else f"robot-server exited with code {code}: {self.last_log_line()}"

    async def stop(self) -> None:
        """SIGINT (the server stops the robot, writes its record and exits 0), bounded."""
        if self.proc.returncode is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                await asyncio.wait_for(self.proc.wait(), 60.0)
            except TimeoutError:
                await self.kill()
                raise RunFailed("robot-server did not exit within 60 s of SIGINT") from None
        await self._finish_drain()
        if self.proc.returncode != 0:
            raise RunFailed(f"robot-server exited with code {self.proc.returncode}: {self.last_log_line()}")

    async def kill(self) -> None:
        if self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.kill()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.proc.wait(), 10.0)
        await self._finish_drain()

    async def _finish_drain(self) -> None:
        if self._drain is not None:
            self._drain.cancel()
            with contextlib.suppress(asyncio.CancelledError, OSError):
                await self._drain
            self._drain = None


# -- the state port ----------------------------------------------------------------------------------


class StateWatch:
    """Follows the state port: the first published position and STATUS ``in_motion``."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.sub = conn.subscribe(64, (MsgType.STATUS, MsgType.JOINT_POSITION, MsgType.JOINT_FEEDBACK))
        self.position: Array | None = None
        self.in_motion = False
        self.statuses = 0
        self._event = asyncio.Event()
        loop = asyncio.get_running_loop()
        self._task = loop.create_task(self._run())
        self._closing = loop.create_task(self._end_with_connection())

    async def _run(self) -> None:
        try:
            async for msg in self.sub:
                if isinstance(msg, Status):
                    self.in_motion = msg.in_motion == TriState.TRUE
                    self.statuses += 1
                elif isinstance(msg, JointPosition | JointFeedback) and self.position is None:
                    data = msg.joint_data if isinstance(msg, JointPosition) else msg.positions
                    self.position = np.array(data, dtype=float)
                self._event.set()
        finally:
            self._event.set()  # wakes _until, which sees the end

    async def _end_with_connection(self) -> None:
        await self.conn.wait_closed()
        self.sub.close()  # subscriptions outlive connections; this one ends with its connection

    async def _until(self, condition: Callable[[], bool]) -> None:
        while not condition():
            if self._task.done():
                raise RunFailed("the state connection closed")
            self._event.clear()
            await self._event.wait()

    async def first_position(self, dof: int) -> Array:
        try:
            async with asyncio.timeout(10.0):
                await self._until(lambda: self.position is not None)
        except TimeoutError:
            raise RunFailed("no joint position on the state port within 10 s") from None
        assert self.position is not None
        return self.position[:dof].copy()

    async def motion_over(self) -> None:
        """Two fresh STATUS messages (so they reflect the last point), then one with in_motion FALSE."""
        seen = self.statuses
        await self._until(lambda: self.statuses >= seen + 2)
        await self._until(lambda: not self.in_motion)

    async def close(self) -> None:
        self.conn.unsubscribe(self.sub)
        for task in (self._task, self._closing):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        await self.conn.close()


async def connect(port: int, name: str, wire: WireFormat = LE32) -> Connection:
    return Connection(await open_tcp(HOST, port, timeout=10.0), wire, name=name).start()


def fanuc_joints(q: Array) -> Array:
    """fanuc_driver with ``J23_factor`` 1: the controller's J3 is J3 - J2 (what it sends)."""
    c = np.array(q, dtype=float)
    c[..., 2] = q[..., 2] - q[..., 1]
    return c


def ros_joints(c: Array) -> Array:
    """... and J3 + J2 of what the controller publishes."""
    q = np.array(c, dtype=float)
    q[..., 2] = c[..., 2] + c[..., 1]
    return q


async def abb_download(conn: Connection, traj: Trajectory, model: RobotModel, out: Streamed) -> None:
    """abb_driver's downloader: every point a TOPIC, -1 first and -3 last, velocity 0, no replies."""
    messages = list(traj_pt_messages(traj, model))
    for i, msg in enumerate(messages):
        sequence = -1 if i == 0 else -3 if i == len(messages) - 1 else i
        await conn.send(JointTrajPt(sequence, msg.joint_data, 0.0, msg.duration, comm_type=CommType.TOPIC))
        out.accepted += 1
    out.notes.append("TOPICs: no replies")


# -- the clients -------------------------------------------------------------------------------------


@dataclass
class Streamed:
    """The client's side of a run."""

    points: int
    accepted: int = 0
    refused: int = 0
    busy: int = 0
    reasons: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)


def velocity_ratio(velocities: Array, max_velocity: Array) -> float:
    """industrial_robot_client's ``calc_velocity``: the critical joint's |v| / v_max, 0.1 if not > 0."""
    ratio = float(np.max(np.abs(velocities) / max_velocity)) if velocities.size else 0.0
    if not ratio > 0.0:
        ratio = DEFAULT_VELOCITY_RATIO
    return min(1.0, max(0.0, ratio))


def traj_pt_messages(traj: Trajectory, model: RobotModel) -> Iterator[JointTrajPt]:
    """JOINT_TRAJ_PT as industrial_robot_client fills them (``create_message``, ``calc_speed``)."""
    last_time = 0.0  # the C++ function-static: 0 before the first point, so it gets DEFAULT_DURATION
    for i in range(len(traj)):
        this_time = float(traj.times[i])
        duration = DEFAULT_DURATION if this_time <= last_time else this_time - last_time
        last_time = this_time
        ratio = velocity_ratio(traj.velocities[i], model.max_velocity)
        yield JointTrajPt(i, tuple(traj.positions[i]), ratio, duration)


def full_point(traj: Trajectory, i: int) -> JointTrajPtFull:
    """A JOINT_TRAJ_PT_FULL as motoman_driver's ``create_message`` fills it."""
    return JointTrajPtFull(
        0,
        i,
        FULL_FIELDS,
        float(traj.times[i]),
        tuple(traj.positions[i]),
        tuple(traj.velocities[i]),
        tuple(traj.accelerations[i]),
    )


async def stop_and_wait(conn: Connection, messages: Iterable[Message], cadence: float, out: Streamed) -> None:
    """The generic streamers: one request in flight; SUCCESS or FAILURE, the next point follows."""
    for msg in messages:
        try:
            await conn.request(msg, timeout=None)  # bounded by the run's deadline
            out.accepted += 1
        except RequestFailed:
            out.refused += 1
        if cadence:
            await asyncio.sleep(cadence)


async def moto_ctrl(conn: Connection, command: MotoCommand) -> MotoMotionReply:
    reply = await conn.request(MotoMotionCtrl(0, 0, command), timeout=10.0)
    if not isinstance(reply, MotoMotionReply):
        raise RunFailed(f"{command.name} answered with {reply.name}, not MOTO_MOTION_REPLY")
    return reply


def moto_outcome(reply: MotoMotionReply) -> str:
    result = _enum_name(MotoResult, reply.result)
    if reply.result == MotoResult.NOT_READY:
        return f"{result}/{_enum_name(NotReadySubcode, reply.subcode)}"
    if reply.result == MotoResult.INVALID:
        return f"{result}/{_enum_name(InvalidSubcode, reply.subcode)}"
    return result if not reply.subcode else f"{result}/{reply.subcode}"


def _enum_name(enum: type[IntEnum], value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return str(value)


async def stream_full_motoros(conn: Connection, traj: Trajectory, cadence: float, out: Streamed) -> None:
    """motoman_driver's sequence: check, start trajectory mode, check, then the points (BUSY: again)."""
    reply = await moto_ctrl(conn, MotoCommand.CHECK_MOTION_READY)
    if (reply.result, reply.subcode) != (MotoResult.FALSE, NotReadySubcode.NOT_STARTED):
        out.notes.append(f"first CHECK_MOTION_READY: {moto_outcome(reply)} (expected FALSE/NOT_STARTED)")
    reply = await moto_ctrl(conn, MotoCommand.START_TRAJ_MODE)
    if reply.result != MotoResult.SUCCESS:
        raise RunFailed(f"START_TRAJ_MODE answered {moto_outcome(reply)}")
    reply = await moto_ctrl(conn, MotoCommand.CHECK_MOTION_READY)
    if reply.result != MotoResult.TRUE:
        raise RunFailed(f"CHECK_MOTION_READY after START_TRAJ_MODE answered {moto_outcome(reply)}")
    for i in range(len(traj)):
        msg = full_point(traj, i)
        while True:
            try:
                answer = await conn.request(msg, timeout=None)
            except RequestFailed:
                out.refused += 1
                out.reasons["header FAILURE"] += 1
                break
            result = answer.result if isinstance(answer, MotoMotionReply) else -1
            if result == MotoResult.SUCCESS:
                out.accepted += 1
                break
            if result == MotoResult.BUSY:
                out.busy += 1
                await asyncio.sleep(BUSY_RETRY)
                continue
            out.refused += 1
            out.reasons[moto_outcome(answer) if isinstance(answer, MotoMotionReply) else answer.name] += 1
            break
        if cadence:
            await asyncio.sleep(cadence)


# -- the record --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Record:
    """The columns of a ``--record`` CSV this benchmark uses (group 0)."""

    time: Array
    command: Array  # (ticks, dof) commanded positions
    command_velocity: Array
    actual: Array
    points: NDArray[np.int64]

    @classmethod
    def load(cls, path: Path, joint_names: Sequence[str]) -> Record:
        if not path.exists():
            raise RunFailed(f"no record was written ({path.name})")
        with open(path, newline="") as f:
            header = next(csv.reader(f))
        index = {name: i for i, name in enumerate(header)}

        def columns(suffix: str) -> list[int]:
            return [index[f"{name}{suffix}"] for name in joint_names]

        wanted = [
            index["record.controller_time"],
            *columns(".command_position"),
            *columns(".command_velocity"),
            *columns(""),  # the actual position
            index["record.points"],
        ]
        data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=wanted, ndmin=2)
        if data.shape[0] < 8:
            raise RunFailed(f"the record has only {data.shape[0]} ticks")
        n = len(joint_names)
        return cls(
            time=data[:, 0],
            command=data[:, 1 : 1 + n],
            command_velocity=data[:, 1 + n : 1 + 2 * n],
            actual=data[:, 1 + 2 * n : 1 + 3 * n],
            points=data[:, -1].astype(np.int64),
        )


@dataclass(frozen=True)
class Metrics:
    start: float  # s
    executed: float  # s
    deviation_command: float  # m
    deviation_actual: float  # m
    stops: int
    peak_acceleration: float  # rad/s², all joints
    peak_acceleration_joint: Array  # rad/s², per joint
    peak_jerk: float  # rad/s³
    final_error: float  # rad
    ends_in_motion: bool


def interpolation_rows(times: Array, servo_period: float, ticks_per_interpolation: int) -> NDArray[np.bool_]:
    """The ticks at the interpolation instants (as ``client.demo._interpolation_rows``)."""
    index = np.rint(times / servo_period).astype(np.int64)
    rows: NDArray[np.bool_] = index % ticks_per_interpolation == 0
    return rows


def command_peaks(command: Array, period: float) -> tuple[Array, float]:
    """Peak |acceleration| per joint and peak |jerk| of positions sampled every ``period`` s: the
    differences ``client.demo.analyse`` takes."""
    velocity = np.diff(command, axis=0) / period
    acceleration = np.diff(velocity, axis=0) / period
    jerk = np.diff(acceleration, axis=0) / period
    peak: Array = np.max(np.abs(acceleration), axis=0) if acceleration.size else np.zeros(command.shape[1])
    return peak, float(np.max(np.abs(jerk))) if jerk.size else 0.0


def deviation(model: RobotModel, joints: Array, path: Array) -> float:
    """The largest distance (m) of the flange at ``joints`` from the polyline ``path``, in chunks."""
    worst = 0.0
    for start in range(0, joints.shape[0], CHUNK):
        flange = fk_batch(model, joints[start : start + CHUNK])[:, :3, 3]
        worst = max(worst, float(np.max(distance_to_path(flange, path))))
    return worst


def count_stops(velocity: Array, still: Array) -> int:
    """Runs of ticks with every joint slower than ``still`` (rad/s, per joint), runs at either end
    not counted."""
    slow = np.all(np.abs(velocity) < still, axis=1)
    moving = np.flatnonzero(~slow)
    if moving.size < 2:
        return 0
    inner = slow[moving[0] : moving[-1] + 1]
    return int(np.count_nonzero(inner[1:] & ~inner[:-1]))


class NoMotion(Exception):
    """The command never moved: nothing to measure (not a failure of the run)."""


def analyse(record: Record, traj: Trajectory, path: Array, model: RobotModel, periods: tuple[float, int]) -> Metrics:
    """The metrics of the module doc from one run's record."""
    servo_period, ticks = periods
    t, command = record.time, record.command
    still = STILL + model.max_acceleration * servo_period * ticks / 2
    if record.points[0] != 0:
        raise RunFailed("the record does not start with the server (raise --record-seconds)")
    counted = np.flatnonzero(record.points > 0)
    if not counted.size:
        raise RunFailed("the controller accepted no point")
    first = int(counted[0])
    moved = np.flatnonzero(np.max(np.abs(command[first:] - command[first]), axis=1) > MOVED)
    if not moved.size:
        raise NoMotion("the command never moved")
    move = first + int(moved[0])
    away = np.flatnonzero(np.max(np.abs(command - command[-1]), axis=1) > ARRIVED)
    end = min(int(away[-1]) + 1, t.size - 1) if away.size else move
    ends_in_motion = bool(away.size and away[-1] == t.size - 1)
    rows = interpolation_rows(t, servo_period, ticks)
    peak_joint, peak_jerk = command_peaks(command[rows], servo_period * ticks)
    return Metrics(
        start=float(t[move] - t[first]),
        executed=float(t[end] - t[move]),
        deviation_command=deviation(model, command[move:], path),
        deviation_actual=deviation(model, record.actual[move:], path),
        stops=count_stops(record.command_velocity[move : end + 1], still),
        peak_acceleration=float(np.max(peak_joint)),
        peak_acceleration_joint=peak_joint,
        peak_jerk=peak_jerk,
        final_error=float(np.max(np.abs(command[-1] - traj.positions[-1]))),
        ends_in_motion=ends_in_motion,
    )


def log_notes(log: Path) -> list[str]:
    """Refusal reasons, queues run dry and alarms, from the server's log (WARNING and up)."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return []
    notes = [f"{n}x {reason}" for reason, n in Counter(re.findall(r"refused: ([a-z_]+):", text)).most_common()]
    dry = text.count("ran dry")
    if dry:
        notes.append(f"queue ran dry {dry}x")
    alarms = re.findall(r"alarm (\d+):", text)
    if alarms:
        notes.append("alarm " + ", ".join(sorted(set(alarms))))
    tracebacks = text.count("Traceback")
    if tracebacks:
        notes.append(f"{tracebacks} traceback(s) in the server log")
    return notes


# -- one run -----------------------------------------------------------------------------------------


@dataclass
class Row:
    case: Case
    policy: str
    streamed: Streamed | None = None
    metrics: Metrics | None = None
    error: str | None = None
    notes: list[str] = field(default_factory=list)
    wall: float = 0.0
    trajectory: Trajectory | None = None


@dataclass(frozen=True)
class Settings:
    model: RobotModel
    workdir: Path
    cadence: float
    periods: tuple[float, int]  # servo period (s), servo ticks per interpolation period


def server_args(case: Case, policy: str | None, record: Path, record_seconds: float) -> list[str]:
    args = ["--record", str(record), "--record-seconds", f"{record_seconds:g}"]
    if policy is not None:
        args += ["--interpolation", policy]
    if case.profile == "motoros":
        args += ["--profile", "motoros", "--io-port", "0"]
    elif case.profile in VENDORS:
        args += ["--profile", case.profile]
    return args


async def run_case(case: Case, policy: str, explicit_policy: bool, settings: Settings) -> Row:
    """One server, one trajectory, one row (see the module doc); a failed run is a row with its error."""
    model = settings.model
    row = Row(case, policy, Streamed(case.points))
    stem = f"{case.slug}_{policy}"
    record_path, log_path = settings.workdir / f"{stem}.csv", settings.workdir / f"{stem}.log"
    duration = case.planned_duration(model)
    budget = duration + SLACK
    began = time.perf_counter()
    server: ServerProcess | None = None
    record_path.unlink(missing_ok=True)  # never analyse an older run's record
    try:
        args = server_args(case, policy if explicit_policy else None, record_path, max(120.0, budget + 60.0))
        server = await ServerProcess.start(args, log_path)
        await drive(server, row, duration, settings, budget)
    except TimeoutError:
        row.error = f"timed out after {time.perf_counter() - began:.1f} s (planned {duration:.3f} s + {SLACK:g} s)"
    except (RunFailed, OSError, SimpleMessageError) as exc:  # also refused or closed connections, odd replies
        gone = await server.exited() if server is not None else None  # a crash is the root cause
        row.error = gone or (str(exc) if isinstance(exc, RunFailed) else f"{type(exc).__name__}: {exc}")
    finally:
        if server is not None:
            try:
                await server.stop()
            except RunFailed as exc:
                row.error = row.error or str(exc)
            finally:
                await server.kill()
    row.wall = time.perf_counter() - began
    if server is not None:
        row.notes += log_notes(log_path)
    if row.trajectory is not None:
        traj = row.trajectory
        try:
            record = Record.load(record_path, model.joint_names)
            row.metrics = analyse(record, traj, traj.flange_path(model), model, settings.periods)
        except NoMotion as exc:
            row.notes.insert(0, str(exc))
        except (RunFailed, ValueError, KeyError) as exc:
            row.error = row.error or f"record: {exc}"
    return row


async def drive(server: ServerProcess, row: Row, duration: float, settings: Settings, budget: float) -> None:
    """Connect, plan from the published position, stream, and wait until the motion is over."""
    model, case, out = settings.model, row.case, row.streamed
    assert out is not None
    wire = BE32 if case.profile == "fanuc" else LE32
    state = StateWatch(await connect(server.ports["state"], "state", wire))
    motion: Connection | None = None
    try:
        q0 = await state.first_position(model.dof)
        if case.profile == "fanuc":
            q0 = ros_joints(q0)
        traj = row.trajectory = Trajectory.plan(q0, duration, case.points)
        motion = await connect(server.ports["motion"], "motion", wire)
        async with asyncio.timeout(budget):
            if case.profile == "abb":
                await abb_download(motion, traj, model, out)
            elif case.profile == "fanuc":
                sent = (
                    JointTrajPt(
                        m.sequence, tuple(fanuc_joints(np.array(m.joint_data[: model.dof]))), m.velocity, m.duration
                    )
                    for m in traj_pt_messages(traj, model)
                )
                await stop_and_wait(motion, sent, settings.cadence, out)
            elif case.profile == "motoros":
                await stream_full_motoros(motion, traj, settings.cadence, out)
            elif case.full:
                await stop_and_wait(motion, (full_point(traj, i) for i in range(len(traj))), settings.cadence, out)
            else:
                await stop_and_wait(motion, traj_pt_messages(traj, model), settings.cadence, out)
            if out.accepted:
                await state.motion_over()
        await asyncio.sleep(0.2)  # a little settled record after the motion
    finally:
        if motion is not None:
            await motion.close()
        await state.close()


# -- output ------------------------------------------------------------------------------------------

COLUMNS = (
    "policy",
    "accepted",
    "start (ms)",
    "executed (s)",
    "exec/plan",
    "dev cmd (mm)",
    "dev actual (mm)",
    "stops",
    "peak acc (rad/s²)",
    "acc/plan",
    "peak jerk (rad/s³)",
    "final error (rad)",
    "notes",
)


def accepted_text(streamed: Streamed | None) -> str:
    if streamed is None:
        return "-"
    text = f"{streamed.accepted}/{streamed.points}"
    if streamed.busy:
        text += f", {streamed.busy} BUSY"
    return text


def row_cells(row: Row, planned: float, planned_peak: float) -> list[str]:
    notes = list(row.notes)
    if row.streamed is not None:
        notes = row.streamed.notes + [f"{n}x {r}" for r, n in row.streamed.reasons.most_common()] + notes
    if row.error:
        notes.insert(0, f"**failed: {row.error}**")
    m = row.metrics
    if m is None:
        return [row.policy, accepted_text(row.streamed), *["-"] * (len(COLUMNS) - 3), "; ".join(notes)]
    if m.ends_in_motion:
        notes.append("record ends in motion")
    return [
        row.policy,
        accepted_text(row.streamed),
        f"{m.start * 1e3:.0f}",
        f"{m.executed:.3f}",
        f"{m.executed / planned:.3f}",
        f"{m.deviation_command * 1e3:.3f}",
        f"{m.deviation_actual * 1e3:.3f}",
        str(m.stops),
        f"{m.peak_acceleration:.2f}",
        f"{m.peak_acceleration / planned_peak:.2f}",
        f"{m.peak_jerk:,.0f}",
        f"{m.final_error:.1e}",
        "; ".join(notes),
    ]


def markdown(header: Sequence[str], rows: Sequence[Sequence[str]], left: int = 1) -> str:
    lines = ["| " + " | ".join(header) + " |"]
    lines.append("|" + "|".join("---" if i < left or h == "notes" else "---:" for i, h in enumerate(header)) + "|")
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return "\n".join(lines)


def heading(case: Case, model: RobotModel) -> str:
    duration = case.planned_duration(model)
    peak = float(np.max(peak_acceleration(duration)))
    text = (
        f"### {case.title}: {case.points} {case.message} points over {duration:.3f} s, "
        f"planned peak acceleration {peak:.2f} rad/s²"
    )
    if case.duration is None:
        text += f" ({OVER_FAST:g}x the {float(np.min(model.max_acceleration)):g} rad/s² limit)"
    if case.profile == "motoros":
        text += ", MotoROS profile"
    elif case.profile in VENDORS:
        text += f", {case.profile} profile as its ROS driver sends it (no target: what that controller does)"
    speeds = np.max(np.abs(shape(np.zeros(DELTA.size), np.linspace(0, duration, 2001), duration)[1]), axis=0)
    if np.any(speeds > model.max_velocity):
        text += f" (peak speed {float(np.max(speeds)):.2f} rad/s: over the velocity limit)"
    return text


# -- targets -----------------------------------------------------------------------------------------

TARGET_COLUMNS = (
    "case",
    "policy",
    "all SUCCESS",
    "start ≤ 10 ms",
    "duration",
    "deviation",
    "0 stops",
    "peak acc",
    "met",
)


def check(ok: bool, value: str) -> str:
    return "✓" if ok else f"✗ {value}"


def target_cells(row: Row, model: RobotModel) -> list[str]:
    """Which targets one row meets (see ``--help``), as table cells."""
    case, m, s = row.case, row.metrics, row.streamed
    planned = case.planned_duration(model)
    planned_peak = float(np.max(peak_acceleration(planned)))
    cells = [case.title, row.policy]
    all_ok = s is not None and s.accepted == s.points
    cells.append(check(all_ok, accepted_text(s)))
    if m is None or row.error:
        cells += [f"✗ {row.error or 'no metrics'}"] + ["-"] * 4 + ["no"]
        return cells
    checks = [all_ok]
    ok = m.start <= 0.010
    checks.append(ok)
    cells.append(check(ok, f"{m.start * 1e3:.0f} ms"))
    ratio = m.executed / planned
    within_limit = bool(np.all(m.peak_acceleration_joint <= model.max_acceleration * 1.001))
    if case.duration is None:
        ok = ratio <= 1.6 and within_limit
        cells.append(check(ok, f"{ratio:.3f}" + ("" if within_limit else ", over the acc limit")))
    else:
        ok = abs(ratio - 1.0) <= 0.02
        cells.append(check(ok, f"{ratio:.3f}"))
    checks.append(ok)
    limit_cmd, limit_act = (0.05e-3, 0.3e-3) if case.dense else (1e-3, 1e-3)
    ok = m.deviation_command <= limit_cmd and m.deviation_actual <= limit_act
    checks.append(ok)
    cells.append(check(ok, f"{m.deviation_command * 1e3:.3f} / {m.deviation_actual * 1e3:.3f} mm"))
    ok = m.stops == 0
    checks.append(ok)
    cells.append(check(ok, str(m.stops)))
    acc_ratio = m.peak_acceleration / planned_peak
    ok = abs(acc_ratio - 1.0) <= 0.05 if case.profile == "motoros" else acc_ratio <= 1.5
    checks.append(ok)
    cells.append(check(ok, f"{acc_ratio:.2f}x planned"))
    cells.append(f"{sum(checks)}/{len(checks)}")
    return cells


TARGETS_TEXT = """\
Targets (blend rows and JOINT_TRAJ_PT_FULL rows): every point SUCCESS; start ≤ 10 ms; executed / planned
within 2 % (over-fast: ≤ 1.6 and the peak acceleration within the model's limit); deviation ≤ 0.05 mm
commanded and ≤ 0.3 mm actual on dense cases, ≤ 1 mm both on the sparse one; no intermediate stop; peak
acceleration ≤ 1.5x the plan's (MotoROS: within 5 % of it)."""


# -- main --------------------------------------------------------------------------------------------


def plan_runs(cases: Sequence[Case], policies: Sequence[str], default_policy: str) -> Iterator[tuple[Case, str, bool]]:
    """(case, policy, whether the policy is passed explicitly) for every run."""
    for case in cases:
        if case.full or case.profile in VENDORS:
            yield case, "-" if case.profile in VENDORS else default_policy, False
        else:
            for policy in policies:
                yield case, policy, True


async def run(cases: Sequence[Case], policies: Sequence[str], cadence: float, workdir: Path) -> None:
    model = load_model(MODEL)
    servo_period = float(server_option("servo_period").default)
    interpolation_period = float(server_option("interpolation_period").default)
    default_policy = str(server_option("interpolation").default)
    settings = Settings(model, workdir, cadence, (servo_period, round(interpolation_period / servo_period)))
    print(f"# streaming benchmark: robot-server over loopback TCP ({machine()})")
    print()
    print(
        f"Model {model.name}; policies {', '.join(policies)} (server default: {default_policy}); "
        f"cadence {cadence * 1e3:g} ms between points; {interpolation_period * 1e3:g} ms interpolation, "
        f"{servo_period * 1e3:g} ms servo ticks."
    )
    rows: list[Row] = []
    current: Case | None = None
    table: list[list[str]] = []
    for case, policy, explicit in plan_runs(cases, policies, default_policy):
        if case is not current:
            if current is not None:
                print(markdown(COLUMNS, table), flush=True)
            current, table = case, []
            print()
            print(heading(case, model))
            print()
        sys.stdout.flush()  # the tables and the progress lines may share a terminal or a pipe
        print(f"{case.slug} / {policy} ...", file=sys.stderr, flush=True)
        row = await run_case(case, policy, explicit, settings)
        print(
            f"{case.slug} / {policy}: {row.wall:.1f} s{f' ({row.error})' if row.error else ''}",
            file=sys.stderr,
            flush=True,
        )
        rows.append(row)
        duration = case.planned_duration(model)
        table.append(row_cells(row, duration, float(np.max(peak_acceleration(duration)))))
    if current is not None:
        print(markdown(COLUMNS, table))
    checked = [r for r in rows if (r.policy == "blend" or r.case.full) and r.case.profile not in VENDORS]
    print()
    print("### targets")
    print()
    print(TARGETS_TEXT)
    print()
    if "blend" not in available_policies():
        print("(this robot-server has no `blend` policy: only the JOINT_TRAJ_PT_FULL rows are checked)")
        print()
    if checked:
        print(markdown(TARGET_COLUMNS, [target_cells(r, model) for r in checked], left=2))
    else:
        print("(no blend or JOINT_TRAJ_PT_FULL row in this run)")


def planning_table(cases: Sequence[Case], model: RobotModel, passes: int = 3) -> None:
    """Planning a streamed point: the controller's own work when a JOINT_TRAJ_PT arrives (checks,
    through-state, segment, limits, slowing down), timed in process under the default policy.
    Each point's time is its best of ``passes`` identical runs (this VM steals time in bursts,
    which moved plain single timings by 1.5x from run to run)."""
    from robot_server.control import Controller, ControllerConfig, Point

    print("### planning a streamed point (target: median <= 250 us)")
    print()
    print("In process, each point of the case handed to a controller with the default policy as soon as it")
    print(f"arrives (a queue large enough for all), every `add` timed alone; a point's time is its best of {passes}")
    print("identical runs.")
    print()
    print("| case | points | median (us) | p90 (us) | max (us) |")
    print("|---|---:|---:|---:|---:|")
    for case in cases:
        if case.full or case.profile in VENDORS:
            continue
        traj = Trajectory.plan(np.zeros(model.dof), case.planned_duration(model), case.points)
        messages = list(traj_pt_messages(traj, model))
        points = [
            Point(np.array(m.joint_data[: model.dof]), duration=float(m.duration), velocity_ratio=float(m.velocity))
            for m in messages
        ]
        runs = []
        for _ in range(passes):
            controller = Controller(model, ControllerConfig(queue_capacity=len(points) + 1))
            controller.start(points[0])
            times = []
            for point in points[1:]:
                begin = time.perf_counter()
                controller.add(point)
                times.append(time.perf_counter() - begin)
            runs.append(times)
        us = np.min(np.array(runs), axis=0) * 1e6
        print(f"| {case.title} | {len(points)} | {np.median(us):.0f} | {np.percentile(us, 90):.0f} | {us.max():,.0f} |")
    print()


def main() -> None:
    policies = available_policies()
    slugs = [c.slug for c in CASES]
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help=f"only {' and '.join(QUICK)}")
    parser.add_argument("--cases", nargs="+", choices=slugs, metavar="NAME", help=f"cases to run: {', '.join(slugs)}")
    parser.add_argument(
        "--policies",
        nargs="+",
        choices=policies,
        metavar="NAME",
        help=f"policies for JOINT_TRAJ_PT: {', '.join(policies)}",
    )
    parser.add_argument("--cadence", type=float, default=0.0, metavar="SECONDS", help="sleep between points (0)")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep each run's CSV record and server log here")
    args = parser.parse_args()
    if args.cadence < 0:
        parser.error("--cadence must be >= 0")
    chosen = args.cases or (QUICK if args.quick else slugs)
    cases = [c for c in CASES if c.slug in chosen]
    selected = [p for p in policies if p in (args.policies or policies)]
    try:
        if args.keep is not None:
            args.keep.mkdir(parents=True, exist_ok=True)
            asyncio.run(run(cases, selected, args.cadence, args.keep))
            planning_table(cases, load_model(MODEL))
            return
        with tempfile.TemporaryDirectory(prefix="bench-streaming-") as tmp:
            asyncio.run(run(cases, selected, args.cadence, Path(tmp)))
        planning_table(cases, load_model(MODEL))
    except KeyboardInterrupt:  # the running server was stopped on the way out
        print("interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
