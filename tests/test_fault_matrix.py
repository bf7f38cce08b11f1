"""The fault matrix of issue 17: what the robot does when its clients or its operator misbehave.

Every cell asserts the robot's resulting motion as a client sees it, from the state port (the
joint positions of JOINT_POSITION or JOINT_FEEDBACK, and STATUS), read with raw bytes
(tests/rawpeer.py):

======================================  =========================================================
motion client vanishes (FIN, RST)       mid-stream (generic, MotoROS) and mid-download (generic):
                                        ``--on-disconnect stop`` brings the robot to rest well
                                        short of its goal, ``continue`` runs the queued motion to
                                        its end; a download cut before its end moves nothing
two motion clients                      a newcomer while the robot moves is closed at once and the
                                        owner's motion runs on unchanged; at rest it takes over
slow and stalled state subscribers      nobody else loses a state round; the stalled one is closed
                                        by the server's bounded write buffer; motion runs on
e-stop, drives off, alarm (stdin)       STATUS says so, the robot stops at once, points are
                                        refused until ``reset``
SIGTERM / SIGINT of robot-server        the robot decelerates to rest, the process exits 0
SIGTERM / SIGINT of robot-client        the robot comes to rest, a line says where, exit 143 / 130
======================================  =========================================================

The in-process cells run the controller on a clock the test advances (tests/stepped.py), so what
they assert does not depend on the machine's speed; the command-level cells run ``robot-server``
and ``robot-client`` as processes. Every wait is bounded; nothing asserts a wall-clock duration.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import socket
import struct
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from client.trajectory import Trajectory
from robot_server.control import SteppedClock
from robot_server.emulator import Emulator
from tests.rawpeer import Frame, RawPeer, joint_traj_pt, joint_traj_pt_full, status, vectors
from tests.stepped import TICK, advance_until, step, stepped_emulator
from tests.test_rs_server_process import ServerProcess, robot_server

V = vectors("<")
JTP, JTP_TOPIC, JTPF = V["JOINT_TRAJ_PT_REQUEST_SEQ3"], V["JOINT_TRAJ_PT_TOPIC_SEQ3"], V["JOINT_TRAJ_PT_FULL_REQUEST"]
PING, STOP = V["PING_REQUEST"], V["JOINT_TRAJ_PT_REQUEST_STOP_ALLZERO"]
PING_TYPE, JOINT_POSITION, STATUS, JOINT_FEEDBACK, MOTO_CTRL, MOTO_REPLY = 1, 10, 13, 15, 2001, 2002
SERVICE_REPLY, SUCCESS, FAILURE = 3, 1, 2
START_TRAJ_MODE, STOP_MOTION, CHECK_MOTION_READY = 200121, 200111, 200101
MOTO_SUCCESS, MOTO_BUSY, MOTO_NOT_READY = 0, 1, 5
MOTO_FALSE = 2  # CHECK_MOTION_READY's answer when not ready (ROS_RESULT_FALSE)
NOT_READY_ALARM, NOT_READY_ESTOP, NOT_READY_SERVO_OFF, NOT_READY_NOT_STARTED = 5001, 5003, 5006, 5008
TIME_POSITION_VELOCITY = 0x07

DOF = 6
HOME = [0.0] * DOF
#: the in-process trajectory: POINTS points from HOME to GOAL, SEGMENT s apart (1.5 s in all)
GOAL = [0.9, -0.6, 0.6, 0.9, -0.6, 1.2]
POINTS, SEGMENT = 11, 0.15
#: a mid-stream client has sent this many of them (the last one 60 % of the way)
PREFIX = 7
#: it vanishes once the robot is this far along (a share of HOME -> GOAL)
VANISH_AT = 0.2
#: a controlled stop from the trajectory's speed comes to rest within this much controller time
STOP_WITHIN = 0.5
#: the command-level cells move far and slowly, so a signal always finds the robot moving
FAR = [2.0, 0.0, 0.0, 0.0, 0.0, 2.5]
FAR_SECONDS = 4.0
#: rounds (100 a second in the command-level cells) a robot at rest must stand still
STEADY_ROUNDS = 40


def dist(a: list[float], b: list[float]) -> float:
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


def progress(q: list[float]) -> float:
    """How far along HOME -> GOAL ``q`` is (0 at HOME, 1 at GOAL)."""
    span = np.subtract(GOAL, HOME)
    return float(np.dot(np.subtract(q, HOME), span) / np.dot(span, span))


def ramp(count: int = POINTS) -> list[list[float]]:
    return [[h + (g - h) * k / (count - 1) for h, g in zip(HOME, GOAL, strict=True)] for k in range(count)]


def actual(emu: Emulator) -> list[float]:
    return list(emu.cell.groups[0].command.actual_position)


# -- the state port ------------------------------------------------------------------------------------


class Watch:
    """A raw state-port subscriber: the latest positions (JOINT_POSITION or, from MotoROS,
    JOINT_FEEDBACK), velocities (JOINT_FEEDBACK) and STATUS; one position per state round
    (``track``), every STATUS (``statuses``) and every speed (``speeds``) it read."""

    def __init__(self, peer: RawPeer) -> None:
        self.peer = peer
        self.position: list[float] | None = None
        self.status: dict[str, int] | None = None
        self.track: list[list[float]] = []
        self.statuses: list[dict[str, int]] = []
        self.speeds: list[float] = []

    @classmethod
    async def connect(cls, port: int, *, receive_buffer: int | None = None, limit: int = 2**16) -> Watch:
        """A subscriber; with ``receive_buffer`` and a small ``limit`` one whose slowness the server
        feels at once (a small SO_RCVBUF, set before connecting, and a small stream buffer)."""
        if receive_buffer is None:
            return cls(await RawPeer.connect(port))
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
            sock.setblocking(False)
            async with asyncio.timeout(5.0):
                await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
                reader, writer = await asyncio.open_connection(sock=sock, limit=limit)
        except BaseException:
            sock.close()
            raise
        return cls(RawPeer(reader, writer))

    @property
    def rounds(self) -> int:
        return len(self.statuses)

    def state(self, field: str) -> int:
        assert self.status is not None
        return self.status[field]

    @property
    def here(self) -> list[float]:
        assert self.position is not None
        return self.position

    async def read(self) -> Frame:
        frame = await self.peer.frame()
        if frame.msg_type == JOINT_POSITION:
            self.position = list(frame.reals(DOF, 4))
        elif frame.msg_type == JOINT_FEEDBACK and frame.ints(1)[0] == 0:  # group 0
            self.position = list(frame.reals(DOF, 12))
            self.speeds.append(max(abs(v) for v in frame.reals(DOF, 52)))
        elif frame.msg_type == STATUS:
            self.status = status(frame)
            self.statuses.append(self.status)
            if self.position is not None:
                self.track.append(self.position)
        return frame

    async def until(self, predicate: Callable[[], bool], timeout: float = 20.0, what: str = "the condition") -> None:
        """Read until ``predicate()`` holds (with a position and a STATUS known), at most ``timeout`` s."""
        try:
            async with asyncio.timeout(timeout):
                while self.position is None or self.status is None or not predicate():
                    await self.read()
        except TimeoutError:
            raise AssertionError(
                f"{what}: not seen on the state port within {timeout} s (last {self.status}, {self.position})"
            ) from None

    async def sync(self) -> None:
        """Catch up with the server: read everything it published until now (a PING's reply comes
        after the topics queued before it) and one whole state round after that."""
        await self.peer.send(PING)
        async with asyncio.timeout(10.0):
            while (await self.read()).msg_type != PING_TYPE:
                pass
        after = self.rounds
        await self.until(lambda: self.rounds > after + 1, what="a state round after the sync")

    async def at_rest(self, timeout: float = 20.0) -> list[float]:
        """Wait until STATUS says in_motion FALSE and the position has not moved (1e-5 rad) for
        STEADY_ROUNDS rounds; the position. STATUS alone is not enough to start the next move
        from: it turns FALSE within 1e-3 rad of the command, and a joint may still stick there
        for about 0.15 s (the servo model's static friction) before it settles, while a MotoROS
        start point must be within 5.2e-4 rad of the command (INVALID/3011 otherwise)."""

        def steady() -> bool:
            recent = self.track[-STEADY_ROUNDS:]
            return (
                len(recent) == STEADY_ROUNDS
                and all(s["in_motion"] == 0 for s in self.statuses[-STEADY_ROUNDS:])
                and all(dist(q, recent[0]) < 1e-5 for q in recent)
            )

        await self.until(steady, timeout, what="the robot at rest")
        return self.here

    async def next_round(self) -> None:
        start = self.rounds
        await self.until(lambda: self.rounds > start, what="a state round")

    async def away_from(self, start: list[float], by: float) -> None:
        """Wait until the robot is more than ``by`` from ``start`` (it moves)."""
        await self.until(lambda: dist(self.here, start) > by, what=f"moving {by} from {start}")

    async def showing(self, fields: dict[str, int], what: str) -> None:
        """Wait for a STATUS with these ``fields``."""
        await self.until(lambda: all(self.state(k) == v for k, v in fields.items()), what=what)

    async def rounds_from_now(self, count: int) -> list[list[float]]:
        """The positions of the next ``count`` state rounds."""
        start = self.rounds
        await self.until(lambda: len(self.track) >= start + count + 1, what=f"{count} state rounds")
        return self.track[-count:]

    async def close(self) -> None:
        await self.peer.close()


# -- motion clients ------------------------------------------------------------------------------------


def moto_ctrl(command: int) -> bytes:
    return struct.pack("<iiiiiii10f", 64, MOTO_CTRL, 2, 0, 0, 0, command, *[0.0] * 10)


def moto_result(frame: Frame) -> tuple[int, int]:
    """(result, subcode) of a MOTO_MOTION_REPLY."""
    assert frame.msg_type == MOTO_REPLY and frame.comm_type == SERVICE_REPLY, frame.raw.hex()
    return frame.ints(5)[3], frame.ints(5)[4]


def moto_point(sequence: int, time: float, q: list[float], v: list[float] | None = None) -> bytes:
    return joint_traj_pt_full(JTPF, 0, sequence, TIME_POSITION_VELOCITY, time, q, v or [0.0] * DOF)


async def stream_generic(motion: RawPeer, points: list[list[float]]) -> None:
    """JOINT_TRAJ_PT requests, one in flight, SEGMENT s apart; each must succeed."""
    for seq, q in enumerate(points):
        reply = await motion.request(joint_traj_pt(JTP, seq, q, 0.0, SEGMENT if seq else 0.0))
        assert reply.reply_code == SUCCESS, f"point {seq} refused"


async def stream_motoros(motion: RawPeer, points: list[list[float]], clock: SteppedClock) -> None:
    """START_TRAJ_MODE, then JOINT_TRAJ_PT_FULL SEGMENT s apart at the ramp's speed (at rest at
    HOME and GOAL), each BUSY answer retried one interpolation period later, as motoman_driver does."""
    assert moto_result(await motion.request(moto_ctrl(START_TRAJ_MODE))) == (MOTO_SUCCESS, 0)
    speed = [(g - h) / ((POINTS - 1) * SEGMENT) for h, g in zip(HOME, GOAL, strict=True)]
    for seq, q in enumerate(points):
        v = None if q in (HOME, GOAL) else speed
        while (result := moto_result(await motion.request(moto_point(seq, seq * SEGMENT, q, v))))[0] == MOTO_BUSY:
            await step(clock, TICK)
        assert result == (MOTO_SUCCESS, 0), f"point {seq} refused: {result}"


async def download(motion: RawPeer, points: list[list[float]], *, end: bool = True) -> None:
    """TOPICs -1, 1 ... n-2 and (with ``end``) -3, then a PING: its reply says they were all read."""
    for k, q in enumerate(points):
        last = k == len(points) - 1
        if last and not end:
            break
        seq = -1 if k == 0 else -3 if last else k
        await motion.send(joint_traj_pt(JTP_TOPIC, seq, q, 0.0, SEGMENT if k else 0.0))
    assert (await motion.request(PING)).msg_type == PING_TYPE


async def vanish(peer: RawPeer, how: str) -> None:
    """Close the client's socket: an orderly FIN, or a reset (SO_LINGER on, zero timeout)."""
    if how == "rst":
        peer.writer.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    await peer.close()


async def closed_by_server(peer: RawPeer, *, reset_ok: bool = False) -> None:
    """The server closed ``peer``'s connection: EOF (or, with ``reset_ok``, a reset) within 5 s."""
    try:
        assert await peer.closed(5.0)
    except ConnectionResetError:
        assert reset_ok, "reset instead of an orderly close"


def leaving(on_disconnect: str) -> dict[str, Any]:
    """The emulator's options for ``on_disconnect``: ``stop`` is what it does by default."""
    return {} if on_disconnect == "stop" else {"on_disconnect": on_disconnect}


def owner_gone(emu: Emulator) -> asyncio.Event:
    """Set once the emulator has dealt with the motion client's departure (stopped the robot or not)."""
    gone = asyncio.Event()
    emu.owner.when_gone(lambda _session: gone.set())
    return gone


async def wait(event: asyncio.Event, what: str) -> None:
    try:
        async with asyncio.timeout(5.0):
            await event.wait()
    except TimeoutError:
        raise AssertionError(f"{what} did not happen within 5 s") from None


# -- 1. the motion client vanishes -------------------------------------------------------------------


@pytest.mark.parametrize("how", ["fin", "rst"])
@pytest.mark.parametrize("on_disconnect", ["stop", "continue"])
@pytest.mark.parametrize(
    ("profile", "phase"),
    [("generic", "stream"), ("motoros", "stream"), ("generic", "download")],
    ids=["generic-stream", "motoros-stream", "generic-download"],
)
async def test_the_motion_client_vanishes_while_the_robot_moves(
    profile: str, phase: str, on_disconnect: str, how: str
) -> None:
    async with stepped_emulator(profile=profile, state_rate=100.0, **leaving(on_disconnect)) as (emu, clock):
        gone = owner_gone(emu)
        watch = await Watch.connect(emu.ports["state"])
        motion = await RawPeer.connect(emu.ports["motion"])
        if phase == "download":
            sent = ramp()
            await download(motion, sent)
        elif profile == "generic":
            sent = ramp()[:PREFIX]
            await stream_generic(motion, sent)
        else:
            sent = ramp()[:PREFIX]
            await stream_motoros(motion, sent, clock)
        await advance_until(clock, lambda: progress(actual(emu)) >= VANISH_AT, what="the robot under way")
        await vanish(motion, how)
        await wait(gone, "the motion client's departure")
        limit = STOP_WITHIN if on_disconnect == "stop" else POINTS * SEGMENT
        await advance_until(clock, lambda: not emu.cell.in_motion, limit=limit, what="the robot at rest")

        await watch.sync()
        assert watch.state("in_motion") == 0
        if on_disconnect == "stop":  # at rest well short of the last point it was sent
            assert VANISH_AT <= progress(watch.here) < progress(sent[-1]) - 0.2, watch.here
        elif profile == "motoros":  # the queued motion ran to its end, its last point passed moving
            # (the stream was cut with a velocity there: the controller decelerates beyond it)
            assert progress(sent[-1]) <= progress(watch.here) and dist(watch.here, sent[-1]) < 0.1, watch.here
        else:  # the queued motion ran to its end
            assert dist(watch.here, sent[-1]) < 1e-3, watch.here
        if profile == "motoros":  # trajectory mode ended with its client
            assert watch.state("motion_possible") == 0
        await watch.close()


@pytest.mark.parametrize("how", ["fin", "rst"])
@pytest.mark.parametrize("on_disconnect", ["stop", "continue"])
async def test_a_download_cut_before_its_end_moves_nothing(on_disconnect: str, how: str) -> None:
    async with stepped_emulator(state_rate=100.0, **leaving(on_disconnect)) as (emu, clock):
        gone = owner_gone(emu)
        watch = await Watch.connect(emu.ports["state"])
        motion = await RawPeer.connect(emu.ports["motion"])
        await download(motion, ramp(), end=False)  # -1, 1 ... 9: no -3
        await step(clock, 0.5)
        assert emu.cell.groups[0].downloading  # the robot is busy receiving it
        await vanish(motion, how)
        await wait(gone, "the motion client's departure")
        await step(clock, POINTS * SEGMENT)  # the whole trajectory's time: nothing starts
        await watch.sync()
        # rounds of the stopped controller to judge (a fast run may have read none before the sync)
        await watch.until(lambda: watch.rounds > 2, what="three state rounds")
        assert all(s["in_motion"] == 0 for s in watch.statuses)
        assert all(q == HOME for q in watch.track)
        # the dropped download does not linger: a new client's END_TRAJECTORY alone is refused
        again = await RawPeer.connect(emu.ports["motion"])
        reply = await again.request(joint_traj_pt(JTP, -3, GOAL, 0.0, 1.0))
        assert reply.reply_code == FAILURE
        await step(clock, 1.0)
        await watch.sync()
        assert watch.state("in_motion") == 0 and watch.here == HOME
        await again.close()
        await watch.close()


# -- 2. two motion clients ---------------------------------------------------------------------------------


async def start_moving(profile: str, motion: RawPeer, clock: SteppedClock) -> None:
    if profile == "generic":
        await stream_generic(motion, ramp())
    else:
        await stream_motoros(motion, ramp(), clock)


@pytest.mark.parametrize("newcomer_sends", ["nothing", "a stop"])
@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_a_second_motion_client_while_the_robot_moves_is_closed_and_changes_nothing(
    profile: str, newcomer_sends: str
) -> None:
    async with stepped_emulator(profile=profile, state_rate=100.0) as (emu, clock):
        watch = await Watch.connect(emu.ports["state"])
        owner = await RawPeer.connect(emu.ports["motion"])
        await start_moving(profile, owner, clock)
        await advance_until(clock, lambda: progress(actual(emu)) >= VANISH_AT, what="the robot under way")

        second = await RawPeer.connect(emu.ports["motion"])
        if newcomer_sends == "a stop":  # it never gets read: the connection is closed on arrival
            with contextlib.suppress(ConnectionError):
                await second.send(STOP if profile == "generic" else moto_ctrl(STOP_MOTION))
        await closed_by_server(second, reset_ok=newcomer_sends == "a stop")

        await advance_until(clock, lambda: not emu.cell.in_motion, limit=POINTS * SEGMENT, what="the goal")
        await watch.sync()
        assert watch.state("in_motion") == 0 and dist(watch.here, GOAL) < 1e-3, watch.here
        assert (await owner.request(PING)).msg_type == PING_TYPE  # still connected, still the owner
        assert emu.owner.refused == 1
        await second.close()
        await owner.close()
        await watch.close()


@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_a_second_motion_client_at_rest_takes_over(profile: str) -> None:
    async with stepped_emulator(profile=profile, state_rate=100.0) as (emu, clock):
        watch = await Watch.connect(emu.ports["state"])
        first = await RawPeer.connect(emu.ports["motion"])
        assert (await first.request(PING)).msg_type == PING_TYPE
        second = await RawPeer.connect(emu.ports["motion"])
        await closed_by_server(first)
        await start_moving(profile, second, clock)
        await advance_until(clock, lambda: not emu.cell.in_motion, limit=2 * POINTS * SEGMENT, what="the goal")
        await watch.sync()
        assert watch.state("in_motion") == 0 and dist(watch.here, GOAL) < 1e-3, watch.here
        await first.close()
        await second.close()
        await watch.close()


async def test_a_motoros_takeover_ends_the_first_clients_trajectory_mode() -> None:
    """As any departure of the motion client does (MotoROS's StopConnection): the newcomer must
    start trajectory mode itself, it does not inherit the first client's."""
    async with stepped_emulator(profile="motoros") as (emu, _clock):
        first = await RawPeer.connect(emu.ports["motion"])
        assert moto_result(await first.request(moto_ctrl(START_TRAJ_MODE))) == (MOTO_SUCCESS, 0)
        assert moto_result(await first.request(moto_ctrl(CHECK_MOTION_READY))) == (MOTO_SUCCESS, 0)
        second = await RawPeer.connect(emu.ports["motion"])
        await closed_by_server(first)
        assert moto_result(await second.request(moto_ctrl(CHECK_MOTION_READY))) == (
            MOTO_FALSE,
            NOT_READY_NOT_STARTED,
        )
        assert moto_result(await second.request(moto_ctrl(START_TRAJ_MODE))) == (MOTO_SUCCESS, 0)
        await first.close()
        await second.close()


async def test_motoros_starts_from_the_position_it_reports_as_soon_as_it_reports_rest() -> None:
    """An alarm mid-move, reset, and a new trajectory from the position the controller reports the
    moment in_motion turns FALSE: the start check (30 pulses) must accept it, so the robot cannot
    report rest while it is farther than that from its command."""
    async with stepped_emulator(profile="motoros") as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        here = [0.0] * DOF
        assert moto_result(await motion.request(moto_ctrl(START_TRAJ_MODE))) == (MOTO_SUCCESS, 0)
        assert moto_result(await motion.request(moto_point(0, 0.0, here))) == (MOTO_SUCCESS, 0)
        assert moto_result(await motion.request(moto_point(1, FAR_SECONDS, FAR))) == (MOTO_SUCCESS, 0)
        await advance_until(clock, lambda: dist(emu.cell.groups[0].command.actual_position, here) > 0.1, what="moving")
        emu.cell.alarm(42, "test")
        await advance_until(clock, lambda: not emu.cell.in_motion, what="the alarm's halt")
        emu.cell.reset_alarm()
        reported = [float(np.float32(x)) for x in emu.cell.groups[0].command.actual_position]  # as JOINT_FEEDBACK
        assert moto_result(await motion.request(moto_ctrl(START_TRAJ_MODE))) == (MOTO_SUCCESS, 0)
        assert moto_result(await motion.request(moto_point(0, 0.0, reported))) == (MOTO_SUCCESS, 0)
        assert moto_result(await motion.request(moto_point(1, 1.0, here))) == (MOTO_SUCCESS, 0)
        await advance_until(clock, lambda: not emu.cell.in_motion, limit=5.0, what="the way back")
        assert dist(emu.cell.groups[0].command.actual_position, here) < 1e-3
        await motion.close()


# -- 3. slow and stalled state subscribers ------------------------------------------------------------


async def test_slow_and_stalled_state_subscribers_delay_nobody(caplog: pytest.LogCaptureFixture) -> None:
    """A subscriber that never reads and one that reads in bursts, at 1000 state rounds a second
    (JOINT_FEEDBACK too): a third loses no round, the bursty one loses none either and stays
    connected, the stalled one is closed by the server's bounded write buffer, and a download
    runs to its goal meanwhile. Counts are compared, never times."""
    caplog.set_level(logging.INFO)
    async with stepped_emulator(state_rate=1000.0, feedback=True) as (emu, clock):
        # A small kernel send buffer, so a peer that does not read reaches the server's own bounded
        # buffer within a few hundred kilobytes instead of the megabytes the kernel would autotune.
        emu.state_server.socket_send_buffer = 8192
        port = emu.ports["state"]
        stalled = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.setblocking(False)
        try:
            async with asyncio.timeout(5.0):
                await asyncio.get_running_loop().sock_connect(stalled, ("127.0.0.1", port))
            stalled_address = stalled.getsockname()
            slow = await Watch.connect(port, receive_buffer=4096, limit=1024)
            healthy = await Watch.connect(port)
            motion = await RawPeer.connect(emu.ports["motion"])
            await download(motion, ramp())

            def stalled_served() -> bool:
                peers = [s.connection.transport.get_extra_info("peername") for s in emu.state_server.sessions]
                return stalled_address in peers

            await healthy.until(lambda: True)
            assert stalled_served()
            await slow.sync()
            healthy_mark, slow_mark, published = healthy.rounds, slow.rounds, emu.state_stats.sent
            async with asyncio.timeout(30.0):
                while emu.cell.in_motion or stalled_served():
                    await healthy.next_round()
                    if emu.cell.in_motion:
                        await step(clock, TICK)
                    if healthy.rounds % 25 == 0:  # the slow one reads what piled up, in a burst
                        await slow.sync()
            published = emu.state_stats.sent - published
            await healthy.sync()
            await slow.sync()
            # the stalled client sees its connection end once it reads what was left for it
            with contextlib.suppress(ConnectionResetError):
                async with asyncio.timeout(5.0):
                    while await asyncio.get_running_loop().sock_recv(stalled, 65536):
                        pass
        finally:
            stalled.close()
        assert published >= 200
        assert healthy.rounds - healthy_mark >= published  # not one round lost
        assert slow.rounds - slow_mark >= published  # nor by the slow one, which is still connected
        assert healthy.state("in_motion") == 0 and dist(healthy.here, GOAL) < 1e-3
        closed = [r.getMessage() for r in caplog.records if "bytes behind" in r.getMessage()]
        assert len(closed) == 1 and str(stalled_address) in closed[0], closed  # the stalled one, and only it
        await motion.close()
        await slow.close()
        await healthy.close()


# -- the command-level cells: robot-server and robot-client as processes ----------------------------------


@contextlib.asynccontextmanager
async def server(tmp_path: Path, profile: str = "generic", *args: str) -> AsyncIterator[ServerProcess]:
    """``robot-server`` on free ports (tests/test_rs_server_process.py), 100 state rounds a second."""
    extra = ["--io-port", "0"] if profile == "motoros" else []
    async with robot_server(tmp_path, "--profile", profile, "--state-rate", "100", *extra, *args) as proc:
        yield proc


async def start_far(profile: str, motion: RawPeer, here: list[float]) -> None:
    """A slow move from ``here`` towards FAR (FAR_SECONDS)."""
    if profile == "generic":
        assert (await motion.request(joint_traj_pt(JTP, 0, here))).reply_code == SUCCESS
        assert (await motion.request(joint_traj_pt(JTP, 1, FAR, 0.0, FAR_SECONDS))).reply_code == SUCCESS
    else:
        assert moto_result(await motion.request(moto_ctrl(START_TRAJ_MODE))) == (MOTO_SUCCESS, 0)
        assert moto_result(await motion.request(moto_point(0, 0.0, here))) == (MOTO_SUCCESS, 0)
        assert moto_result(await motion.request(moto_point(1, FAR_SECONDS, FAR))) == (MOTO_SUCCESS, 0)


#: fault command, the STATUS it brings, MotoROS's NOT_READY subcode, whether the brakes hold at once
FAULTS = [
    ("estop", {"e_stopped": 1, "drives_powered": 0, "motion_possible": 0}, NOT_READY_ESTOP, True),
    ("drives off", {"e_stopped": 0, "drives_powered": 0, "motion_possible": 0}, NOT_READY_SERVO_OFF, True),
    (
        "alarm 42 test",
        {"in_error": 1, "error_code": 42, "drives_powered": 1, "motion_possible": 0},
        NOT_READY_ALARM,
        False,
    ),
]
CLEAR = {"e_stopped": 0, "drives_powered": 1, "in_error": 0, "error_code": 0}


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_estop_drives_off_and_alarm_during_motion(tmp_path: Path, profile: str) -> None:
    """Each fault typed on robot-server's stdin while the robot moves: STATUS shows it, the robot
    stops where it is (e-stop and drives off: the brakes, the very next position; an alarm: the
    servos hold, a few millimetres of braking), points are refused until ``reset``, and accepted
    after it (the next fault's move)."""
    async with server(tmp_path, profile) as proc:
        watch = await Watch.connect(proc.ports["state"])
        motion = await RawPeer.connect(proc.ports["motion"])
        for fault, shows, subcode, brakes in FAULTS:
            start = await watch.at_rest()
            await start_far(profile, motion, start)
            await watch.away_from(start, 0.1)
            await proc.command(fault)
            await watch.showing(shows, fault)
            at_fault = watch.here
            if brakes:
                assert watch.state("in_motion") == 0
                first, second = await watch.rounds_from_now(2)
                assert first == second == at_fault, fault
            else:
                await watch.until(lambda: watch.state("in_motion") == 0, what="the alarm's halt")
                first, second = await watch.rounds_from_now(2)
                assert dist(first, at_fault) < 0.02 and dist(first, second) < 1e-3, fault  # no deceleration ramp
            assert dist(first, FAR) > 0.5
            # points are refused until the reset, and nothing moves
            if profile == "generic":
                assert (await motion.request(joint_traj_pt(JTP, 0, first))).reply_code == FAILURE
            else:
                assert moto_result(await motion.request(moto_point(0, 0.0, first))) == (MOTO_NOT_READY, subcode)
            assert all(s["in_motion"] == 0 for s in watch.statuses[-2:])
            assert dist((await watch.rounds_from_now(1))[0], first) < 1e-3
            await proc.command("reset")
            await watch.showing(CLEAR, "reset")
        # after the last reset too, a move is accepted and runs
        start = await watch.at_rest()
        await start_far(profile, motion, start)
        await watch.away_from(start, 0.1)
        await motion.close()
        await watch.close()
        assert await proc.terminate() == 0


SIGNALS = [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")]
SIGNAL_IDS = ["SIGTERM", "SIGINT"]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [s for s, _, _ in SIGNALS], ids=SIGNAL_IDS)
async def test_robot_server_signalled_during_motion_decelerates_to_rest_and_exits_0(
    tmp_path: Path, sig: signal.Signals
) -> None:
    async with server(tmp_path, "generic", "--feedback", "--no-stdin", "--state-rate", "250") as proc:
        watch = await Watch.connect(proc.ports["state"])
        motion = await RawPeer.connect(proc.ports["motion"])
        start = await watch.at_rest()
        await start_far("generic", motion, start)
        await watch.away_from(start, 0.3)
        signalled, at_signal = len(watch.speeds), watch.here
        proc.proc.send_signal(sig)
        # the state port publishes while the robot decelerates; then the server closes it
        with contextlib.suppress(asyncio.IncompleteReadError, ConnectionError):
            await watch.until(lambda: False, what="the server closing the state port")
        assert await proc.exited() == 0
        await motion.close()
        await watch.close()
    speeds = watch.speeds[signalled:]
    peak = max(speeds)
    after = speeds[speeds.index(peak) :]
    assert after[-1] < 0.1 * peak, after  # at rest (the last round goes out at most a period before)
    assert sum(0.1 * peak < v < 0.9 * peak for v in after) >= 3, after  # a ramp down, not a jump
    assert dist(watch.here, start) > dist(at_signal, start) and dist(watch.here, FAR) > 0.5
    assert "decelerating to rest" in proc.log.read_text()


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["generic", "motoros"])
@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS, ids=SIGNAL_IDS)
async def test_robot_client_signalled_during_motion_stops_the_robot(
    tmp_path: Path, sig: signal.Signals, code: int, word: str, profile: str
) -> None:
    path = tmp_path / "far.csv"
    Trajectory(np.array([0.0, FAR_SECONDS]), np.array([HOME, FAR])).save(path)
    # the server lets a departed client's motion run on: only the client's own STOP stops the robot
    async with server(tmp_path, profile, "--no-stdin", "--on-disconnect", "continue") as proc:
        watch = await Watch.connect(proc.ports["state"])
        ports = ["--motion-port", str(proc.ports["motion"]), "--state-port", str(proc.ports["state"])]
        client = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "client",
            "run",
            str(path),
            "--profile",
            profile,
            *ports,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        try:
            await watch.away_from(HOME, 0.1)
            client.send_signal(sig)
            _, err = await asyncio.wait_for(client.communicate(), 20.0)
        finally:
            if client.returncode is None:
                client.kill()
                await client.wait()
        said = err.decode()
        lines = said.splitlines()
        assert client.returncode == code, said
        # the client waited for the robot to come to rest before it left, and says where that is
        assert len(lines) == 2 and lines[1] == f"robot-client: {word}", said
        assert lines[0].startswith("robot-client: stopped: the robot is at rest at ["), said
        reported = [float(x) for x in lines[0].split("[", 1)[1].rstrip("]").split()]
        await watch.until(lambda: watch.state("in_motion") == 0, what="at rest")
        first, second = await watch.rounds_from_now(2)
        assert dist(first, second) < 1e-3 and dist(first, FAR) > 0.5, (first, second, proc.log.read_text()[-3000:])
        assert dist(reported, first) < 2e-3, (reported, first)
        assert "the motion client left with the robot busy" not in proc.log.read_text()  # not while it braked
        assert "the queued motion runs on" not in proc.log.read_text()
        await watch.close()
        assert await proc.terminate() == 0
