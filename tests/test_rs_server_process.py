"""End-to-end: a running ``robot-server`` process, driven with raw bytes of the reference vectors.

The frames come from ``vectors_le.txt`` (the C++ library's own bytes) with fields patched in place;
nothing of the project's codec or client is on the sending side (see tests/rawpeer.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import signal
import struct
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from robot_server.loader import load_model
from tests.rawpeer import Frame, RawPeer, joint_position, joint_traj_pt, status, vectors

pytestmark = pytest.mark.slow

V = vectors("<")
JTP = V["JOINT_TRAJ_PT_REQUEST_SEQ3"]
JTP_TOPIC = V["JOINT_TRAJ_PT_TOPIC_SEQ3"]
STOP = V["JOINT_TRAJ_PT_REQUEST_STOP_ALLZERO"]
PING = V["PING_REQUEST"]
MODEL = load_model("jibot_zxs")
SPEEDUP = 4.0
JOINT_POSITION, JOINT_TRAJ_PT, STATUS, JOINT_FEEDBACK = 10, 11, 13, 15


class ServerProcess:
    def __init__(self, proc: asyncio.subprocess.Process, log: Path, ports: dict[str, int], ready: str = "") -> None:
        self.proc, self.log, self.ports = proc, log, ports
        #: the ready line it printed
        self.ready = ready

    async def command(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line.encode() + b"\n")
        await self.proc.stdin.drain()

    async def exited(self) -> int:
        return await asyncio.wait_for(self.proc.wait(), 20.0)

    async def terminate(self) -> int:
        if self.proc.returncode is None:
            self.proc.send_signal(signal.SIGTERM)
        return await asyncio.wait_for(self.proc.wait(), 20.0)


@contextlib.asynccontextmanager
async def robot_server(tmp_path: Path, *args: str) -> AsyncIterator[ServerProcess]:
    log = tmp_path / "robot-server.log"
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "robot_server",
            "--motion-port",
            "0",
            "--state-port",
            "0",
            *args,
            stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
            stderr=err,
        )
    try:
        assert proc.stdout is not None
        line = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).decode()
        assert line.startswith("robot-server ready"), line + log.read_text()
        ports = {name: int(port) for name, port in re.findall(r"(motion|state|io) [\d.]+:(\d+)", line)}
        yield ServerProcess(proc, log, ports, line.strip())
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


class StateWatch:
    """Reads the state port: the latest joint position and STATUS."""

    def __init__(self, peer: RawPeer) -> None:
        self.peer = peer
        self.position: list[float] = []
        self.status: dict[str, int] = {}
        self.feedback: list[tuple[float, ...]] = []

    async def step(self) -> Frame:
        frame = await self.peer.frame()
        if frame.msg_type == JOINT_POSITION:
            self.position = joint_position(frame)[: MODEL.dof]
        elif frame.msg_type == STATUS:
            self.status = status(frame)
        elif frame.msg_type == JOINT_FEEDBACK:
            self.feedback.append(frame.reals(30, 12))
        return frame

    async def until(self, predicate: object, timeout: float = 20.0) -> None:
        async with asyncio.timeout(timeout):
            while not (self.status and self.position and predicate()):  # type: ignore[operator]
                await self.step()

    async def statuses(self, count: int) -> list[dict[str, int]]:
        seen = []
        while len(seen) < count:
            if (await self.step()).msg_type == STATUS:
                seen.append(dict(self.status))
        return seen


def ramp(start: list[float], end: list[float], n: int) -> list[list[float]]:
    return [[a + (b - a) * k / (n - 1) for a, b in zip(start, end, strict=True)] for k in range(n)]


async def stream(motion: RawPeer, points: list[list[float]], velocity: float = 0.5) -> list[Frame]:
    """Stop-and-wait: one JOINT_TRAJ_PT request in flight, sequence 0..n-1."""
    replies = []
    for seq, q in enumerate(points):
        replies.append(await motion.request(joint_traj_pt(JTP, seq, q, velocity, 0.0), timeout=30.0))
    return replies


GOOD = {"drives_powered": 1, "e_stopped": 0, "error_code": 0, "in_error": 0, "mode": 2, "motion_possible": 1}


def assert_fields(seen: dict[str, int], **expected: int) -> None:
    assert {k: seen[k] for k in expected} == expected, seen


async def test_generic_end_to_end(tmp_path: Path) -> None:
    async with robot_server(tmp_path, "--speedup", str(SPEEDUP)) as server:
        motion = await RawPeer.connect(server.ports["motion"])
        state = StateWatch(await RawPeer.connect(server.ports["state"]))
        await state.peer.send(V["JOINT_FEEDBACK_TOPIC"])  # ask for JOINT_FEEDBACK too

        # PING: the C++ library's exact reply bytes
        assert (await motion.request(PING)).raw == V["PING_REPLY_SUCCESS"]

        # idle: everything fine, nothing moving
        await state.until(lambda: True)
        for seen in await state.statuses(3):
            assert_fields(seen, in_motion=0, **GOOD)
        home = state.position
        assert max(abs(x) for x in home) < 1e-9

        # a 50-point stream reaches its last point; in_motion TRUE while moving, FALSE after
        target = [0.4, -0.3, 0.5, 0.6, -0.4, 0.8]
        replies = await stream(motion, ramp(home, target, 50))
        assert [r.msg_type for r in replies] == [JOINT_TRAJ_PT] * 50
        assert all(r.comm_type == 3 and r.reply_code == 1 for r in replies)
        assert [r.ints(1)[0] for r in replies] == list(range(50))  # echoed bodies, in order
        await state.until(lambda: state.status["in_motion"] == 1)
        assert_fields(state.status, **GOOD)
        await state.until(lambda: state.status["in_motion"] == 0, timeout=60.0)
        assert max(abs(a - b) for a, b in zip(state.position, target, strict=True)) < 1e-3

        # a STOP mid-stream: acknowledged at once, the robot comes to rest within the limits
        back = ramp(state.position, home, 50)
        await stream(motion, back, velocity=0.3)
        await state.until(lambda: max(abs(a - b) for a, b in zip(state.position, target, strict=True)) > 0.05)
        state.feedback.clear()
        stop_reply = await motion.request(STOP, timeout=2.0)
        assert stop_reply.raw[:16] == bytes.fromhex("400000000b0000000300000001000000")  # 11, reply, SUCCESS
        assert struct.unpack_from("<i", stop_reply.raw, 16)[0] == -4
        await state.until(lambda: state.status["in_motion"] == 0, timeout=30.0)
        stopped = state.position
        assert max(abs(a - b) for a, b in zip(stopped, home, strict=True)) > 0.1  # it did not go on
        assert MODEL.within_limits(np.array(stopped))
        speeds = [
            max(abs(v) / vmax for v, vmax in zip(f[10:16], MODEL.max_velocity, strict=True)) for f in state.feedback
        ]
        assert speeds and max(speeds) <= 1.0
        for seen in await state.statuses(3):  # at rest, and it stays there
            assert_fields(seen, in_motion=0, **GOOD)
        assert max(abs(a - b) for a, b in zip(state.position, stopped, strict=True)) < 1e-3  # the settle tolerance

        # download: TOPIC -1, 1..n-2, -3; no replies (a PING after it is answered first)
        here = state.position
        goal = [x + 0.2 for x in here]
        path = ramp(here, goal, 5)
        for k, q in enumerate(path):
            seq = -1 if k == 0 else -3 if k == len(path) - 1 else k
            await motion.send(joint_traj_pt(JTP_TOPIC, seq, q, 0.5, 0.0))
        assert (await motion.request(PING)).raw == V["PING_REPLY_SUCCESS"]
        await state.until(lambda: state.status["in_motion"] == 1)
        await state.until(lambda: state.status["in_motion"] == 0, timeout=30.0)
        assert max(abs(a - b) for a, b in zip(state.position, goal, strict=True)) < 1e-3

        # a point beyond the joint limits: FAILURE and no motion
        here = state.position
        assert (await motion.request(joint_traj_pt(JTP, 0, here, 0.5))).reply_code == 1
        beyond = [*here[:1], 2.5, *here[2:]]  # joint 2's limit is 2.09 rad
        failure = await motion.request(joint_traj_pt(JTP, 1, beyond, 0.5))
        assert (failure.msg_type, failure.comm_type, failure.reply_code) == (JOINT_TRAJ_PT, 3, 2)
        for seen in await state.statuses(5):
            assert_fields(seen, in_motion=0, **GOOD)
        assert max(abs(a - b) for a, b in zip(state.position, here, strict=True)) < 1e-3  # only the settle residual

        # faults from the command line (stdin)
        await server.command("estop")
        await state.until(lambda: state.status["e_stopped"] == 1)
        assert_fields(state.status, drives_powered=0, motion_possible=0, in_motion=0)
        refused = await motion.request(joint_traj_pt(JTP, 0, state.position, 0.5))
        assert refused.reply_code == 2
        await server.command("reset")
        await state.until(lambda: state.status["e_stopped"] == 0)
        assert_fields(state.status, **GOOD)
        await server.command("alarm 4321 overheated")
        await state.until(lambda: state.status["in_error"] == 1)
        assert_fields(state.status, error_code=4321, motion_possible=0, drives_powered=1)
        await server.command("reset")
        await state.until(lambda: state.status["in_error"] == 0)

        await motion.close()
        await state.peer.close()
        assert await server.terminate() == 0
    log = server.log.read_text()
    assert "trajectory 1 started" in log and "fault: emergency stop" in log and "fault: alarm 4321" in log


async def test_sigint_decelerates_to_rest_and_exits_0(tmp_path: Path) -> None:
    async with robot_server(tmp_path) as server:
        motion = await RawPeer.connect(server.ports["motion"])
        state = StateWatch(await RawPeer.connect(server.ports["state"]))
        await state.until(lambda: True)
        far = [1.0, 0.5, -1.0, 1.0, 0.5, 2.0]
        await stream(motion, [state.position, far], velocity=0.2)
        await state.until(lambda: state.status["in_motion"] == 1 and max(abs(x) for x in state.position) > 0.1)
        server.proc.send_signal(signal.SIGINT)
        # the state port keeps publishing while the robot decelerates, then the server closes it
        last = state.position
        with contextlib.suppress(asyncio.IncompleteReadError, ConnectionError):
            while True:
                await state.step()
                last = state.position
        assert await server.exited() == 0
        assert 0.1 < max(abs(x) for x in last) < max(abs(x) for x in far)
    assert "decelerating to rest" in server.log.read_text()


async def test_record_writes_every_servo_tick_on_exit(tmp_path: Path) -> None:
    record = tmp_path / "trace.csv"
    async with robot_server(tmp_path, "--speedup", str(SPEEDUP), "--record", str(record)) as server:
        motion = await RawPeer.connect(server.ports["motion"])
        state = StateWatch(await RawPeer.connect(server.ports["state"]))
        await state.until(lambda: True)
        target = [0.2, -0.1, 0.1, 0.2, -0.1, 0.3]
        await stream(motion, ramp(state.position, target, 10))
        await state.until(lambda: state.status["in_motion"] == 1)
        await state.until(lambda: state.status["in_motion"] == 0, timeout=60.0)
        server.proc.send_signal(signal.SIGINT)
        assert await server.exited() == 0
    lines = record.read_text().splitlines()
    header = lines[0].split(",")
    assert header[0] == "time" and header[-1] == "tool.time" and len(header) == 1 + 7 * MODEL.dof + 2 + 17
    rows = np.array([line.split(",") for line in lines[1:]], dtype=float)
    assert rows[0, 0] == 0.0 and np.allclose(np.diff(rows[:, 0]), 0.001)  # every servo tick, from 0
    points = header.index("record.points")
    assert rows[0, points] == 0 and rows[-1, points] == 10  # the points column counts the arrivals
    command = header.index(f"{MODEL.joint_names[0]}.command_position")
    assert np.allclose(rows[-1, command : command + MODEL.dof], target, atol=1e-6)  # the command reached the end
    assert "ticks written to" in server.log.read_text()


async def test_bad_arguments_fail_with_one_line(tmp_path: Path) -> None:
    """The installed command's exit status and message; every refused argument is tested in
    process in tests/test_rs_cli.py."""
    for args, words in (
        (["--model", "nosuchrobot"], "nosuchrobot"),
        (["--record", str(tmp_path / "missing" / "run.csv")], "no directory"),  # refused before, not after
    ):
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "robot_server", *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
        )
        out, err = await asyncio.wait_for(proc.communicate(), 30.0)
        assert proc.returncode == 2, (args, err)
        lines = err.decode().strip().splitlines()
        assert lines == [lines[0]] and words in lines[0] and not out  # one line, naming the problem
