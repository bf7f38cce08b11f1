"""Straight lines run by the controller, from the PC side: the driver's ``supports_lines`` and
``move_lines`` and its TOOL_POSE subscription, and ``robot-client move --pose ... --linear`` and
``status`` in process, against an emulator on free loopback ports (127.0.0.1) or the scripted fake
controller (tests/fakecontroller.py) for peers that do not know CARTESIAN_LINE."""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest

from client import cli
from client.demo import distance_to_path
from client.driver import DriverError, ExecutionAborted, LineGoal, LineRefused, RobotDriver
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.kinematics import fk, quaternion_angle, rotation_to_quaternion
from robot_server.loader import load_model
from simple_message.connection import ConnectionState
from simple_message.constants import LineResult
from tests.fakecontroller import SILENT, FakeController, Reply
from tests.rawpeer import Frame
from tests.stepped import settle, stepped_emulator

MODEL = load_model("jibot_zxs")
#: a configuration away from the singularities, the flange pointing down and tilted
START = (0.0, 0.3, -0.6, 0.0, 0.8, 0.0)
LINE = 65001
#: bound of one command in a worker thread (s of wall time)
COMMAND_TIMEOUT = 60.0


def tcp_of(q: tuple[float, ...] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The TCP position and orientation (w, x, y, z) at joint positions ``q``."""
    t = fk(MODEL, q)
    return t[:3, 3], rotation_to_quaternion(t)


@contextlib.asynccontextmanager
async def emulator(**options: Any) -> AsyncIterator[Emulator]:
    """An emulator on free loopback ports, the robot at START, 8x real time."""
    options.setdefault("speedup", 8.0)
    options.setdefault("initial_position", START)
    config = EmulatorConfig(motion_port=0, state_port=0, io_port=0, state_rate=100.0, **options)
    async with Emulator(config) as emu:
        yield emu


def driver_for(emu: Emulator, **options: Any) -> RobotDriver:
    return RobotDriver(
        motion_port=emu.ports["motion"],
        state_port=emu.ports["state"],
        profile=emu.config.profile,
        model=MODEL,
        **options,
    )


# -- supports_lines -----------------------------------------------------------------------------------


async def test_the_generic_emulator_runs_lines_and_sends_tool_pose() -> None:
    async with emulator() as emu, driver_for(emu) as driver:
        assert driver.tool_pose is None  # not asked for yet
        pose = await driver.subscribe_tool_pose()
        assert pose is not None and driver.tool_pose is not None
        position, orientation = tcp_of(START)
        assert np.allclose((pose.x, pose.y, pose.z), position, atol=1e-6)
        assert quaternion_angle((pose.qw, pose.qx, pose.qy, pose.qz), orientation) < 1e-5
        assert await driver.supports_lines()
        assert await driver.supports_lines()  # the answer is kept
        assert not emu.cell.in_motion and emu.cell.groups[0].points_accepted == 0  # the probe only stops


async def test_the_motoros_profile_has_no_lines_and_no_tool_pose() -> None:
    async with emulator(profile="motoros") as emu, driver_for(emu) as driver:
        assert await driver.subscribe_tool_pose() is None
        assert not await driver.supports_lines()
        assert await driver.ping() > 0.0  # the link is still in step
        with pytest.raises(DriverError, match="no straight-line motion"):
            await driver.move_lines([LineGoal(*tcp_of(START))], speed=0.1)


def probe_answered(kind: Reply) -> Any:
    """A fake controller's script: CARTESIAN_LINE gets ``kind``, anything else the echo (SUCCESS)."""

    def script(frame: Frame, _count: int) -> Reply:
        return kind if frame.msg_type == LINE else Reply("success")

    return script


@pytest.mark.parametrize(
    "kind",
    [Reply("failure"), Reply("success"), SILENT],
    ids=["header-only FAILURE (the C++ library)", "echoed request body", "no reply"],
)
async def test_a_peer_that_does_not_know_cartesian_line_has_no_lines(kind: Reply) -> None:
    async with FakeController(probe_answered(kind)) as fake:
        driver = RobotDriver(motion_port=fake.ports["motion"], state_port=fake.ports["state"], reply_timeout=0.5)
        async with driver:
            assert not await driver.supports_lines()
            assert not await driver.supports_lines()  # kept: asked once
            assert len(fake.frames(LINE)) == 1
            probe = fake.frames(LINE)[0]
            assert probe.comm_type == 2 and probe.ints(2) == (0, -4)  # a STOP request, group 0
            if kind is SILENT:  # a lost reply resets the link: it comes back by itself
                await driver.motion.wait_for(ConnectionState.CONNECTED, 10.0)
            assert await driver.ping() > 0.0  # the next request gets its own reply


# -- move_lines ---------------------------------------------------------------------------------------


async def test_move_lines_runs_a_square_and_ends_at_its_last_corner() -> None:
    async with emulator() as emu, driver_for(emu) as driver:
        p0, r0 = tcp_of(START)
        corners = [p0 + d for d in ([0.05, 0.0, 0.0], [0.05, 0.05, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.0])]
        [record] = emu.record(30.0)
        before = await driver.subscribe_tool_pose()
        assert before is not None
        final = await driver.move_lines([LineGoal(c, r0) for c in corners], speed=0.2)
        emu.stop_recording()
        assert np.linalg.norm(np.array([final.x, final.y, final.z]) - p0) <= driver.tcp_tolerance
        assert quaternion_angle((final.qw, final.qx, final.qy, final.qz), r0) <= driver.orientation_tolerance
        assert final.time - before.time >= 4 * 0.05 / 0.2  # it ran the square (controller time), not stood at p0
        status = driver.status
        assert status is not None and status.in_motion == 0
        # the TCP went along the square's edges
        tool = record.tool()
        actual = tool[~np.isnan(tool[:, 8]), 8:11]
        assert float(np.max(distance_to_path(actual, np.array([p0, *corners])))) < 1e-3
        assert float(np.max(np.linalg.norm(actual - p0, axis=1))) > 0.07  # to the far corner (70.7 mm)


async def test_a_refused_line_names_the_reason_and_nothing_moves() -> None:
    async with emulator() as emu, driver_for(emu) as driver:
        p0, r0 = tcp_of(START)
        assert await driver.supports_lines()  # asked (a STOP) before the count below
        stops = emu.cell.interruptions
        with pytest.raises(LineRefused, match=r"refused line 0: UNREACHABLE \(") as info:
            await driver.move_lines([LineGoal(p0 + np.array([2.0, 0.0, 0.0]), r0)], speed=0.2)
        assert info.value.result == LineResult.UNREACHABLE and info.value.line == 0 and info.value.confirmed == -1
        ctl = emu.cell.groups[0]
        assert ctl.points_accepted == 0 and not emu.cell.in_motion
        assert emu.cell.interruptions == stops  # nothing was accepted, so no STOP either
        assert np.allclose(ctl.command.actual_position, START, atol=1e-9)
        with pytest.raises(DriverError, match="not a unit quaternion"):  # refused before anything is sent
            await driver.move_lines([LineGoal(p0, 2 * r0)], speed=0.2)
        with pytest.raises(DriverError, match="speed"):
            await driver.move_lines([LineGoal(p0, r0)], speed=0.0)


async def test_a_line_refused_after_others_were_accepted_stops_them() -> None:
    """On a clock the test advances: the lines accepted before the refusal have not begun when
    the driver's STOP arrives, so the robot must not move at all."""
    async with contextlib.AsyncExitStack() as stack:
        emu, clock = await stack.enter_async_context(stepped_emulator(initial_position=START, state_rate=100.0))
        driver = await stack.enter_async_context(driver_for(emu))
        p0, r0 = tcp_of(START)
        goals = [
            LineGoal(p0 + np.array([0.05, 0.0, 0.0]), r0),
            LineGoal(p0 + np.array([0.05, 0.05, 0.0]), r0),
            LineGoal(p0 + np.array([2, 0, 0]), r0),
        ]
        assert await driver.supports_lines()  # asked (a STOP) before the count below
        stops = emu.cell.interruptions
        with pytest.raises(LineRefused, match="refused line 2: UNREACHABLE") as info:
            await driver.move_lines(goals, speed=0.2)
        assert info.value.confirmed == 1
        ctl = emu.cell.groups[0]
        assert ctl.points_accepted == 2 and emu.cell.interruptions == stops + 1  # the STOP
        await settle(emu, clock)
        # the accepted lines were stopped before they began: the TCP never left the start (the
        # category-2 stop still moves it a few hundredths of a millimetre)
        assert float(np.linalg.norm(np.array(ctl.tool.command_position) - p0)) < 1e-4


async def test_an_estop_during_the_lines_aborts_and_says_why() -> None:
    async with emulator(speedup=1.0) as emu, driver_for(emu) as driver:
        p0, r0 = tcp_of(START)
        task = asyncio.create_task(driver.move_lines([LineGoal(p0 + np.array([0.1, 0.0, 0.0]), r0)], speed=0.05))
        await emu.wait_until(lambda: emu.cell.in_motion, 10.0)
        emu.cell.estop()
        with pytest.raises(ExecutionAborted, match="e-stopped"):
            await asyncio.wait_for(task, 30.0)


async def test_cancelling_move_lines_stops_the_robot() -> None:
    async with emulator(speedup=1.0) as emu, driver_for(emu) as driver:
        p0, r0 = tcp_of(START)
        goal = p0 + np.array([0.1, 0.0, 0.0])
        task = asyncio.create_task(driver.move_lines([LineGoal(goal, r0)], speed=0.05))  # 2 s
        await emu.wait_until(lambda: emu.cell.in_motion, 10.0)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            async with asyncio.timeout(10.0):
                await task
        await emu.settle(10.0)
        assert float(np.linalg.norm(np.array(emu.cell.groups[0].tool.command_position) - goal)) > 0.05


# -- robot-client --------------------------------------------------------------------------------------


async def client(*argv: str) -> tuple[int, str]:
    """``robot-client argv`` in a worker thread (it runs its own event loop): exit status, output."""
    out = io.StringIO()
    async with asyncio.timeout(COMMAND_TIMEOUT):
        code = await asyncio.to_thread(cli.main, list(argv), out)
    return code, out.getvalue()


def ports(emu: Emulator) -> list[str]:
    return [
        "--motion-port",
        str(emu.ports["motion"]),
        "--state-port",
        str(emu.ports["state"]),
        "--profile",
        emu.config.profile,
    ]


@pytest.mark.parametrize(
    ("profile", "says"),
    [
        ("generic", "the controller runs the straight line (CARTESIAN_LINE)\n"),
        ("motoros", "the controller has no straight-line motion: planned on the PC\n"),
    ],
)
async def test_move_linear_uses_the_controllers_line_or_plans_it_on_the_pc(
    profile: str, says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    async with emulator(profile=profile) as emu:
        p0, r0 = tcp_of(START)
        target = p0 + np.array([0.03, 0.04, -0.02])
        code, out = await client("move", "--pose", *map(str, target), "--linear", "--tcp-speed", "0.1", *ports(emu))
        assert code == 0, capsys.readouterr().err
        assert out.startswith(says) and "\ndone: " in out, out
        if profile == "generic":
            assert emu.cell.groups[0].points_accepted == 1  # one line, no joint points
        position, orientation = tcp_of(np.array(emu.cell.groups[0].command.actual_position))
        assert np.linalg.norm(position - target) < 2e-3
        assert quaternion_angle(orientation, r0) < 0.01  # the orientation kept


async def test_move_linear_says_why_the_controller_refused_the_line(capsys: pytest.CaptureFixture[str]) -> None:
    async with emulator() as emu:
        code, _ = await client("move", "--pose", "0.9", "0", "0.1", "--linear", *ports(emu))
        err = capsys.readouterr().err
        assert code == 1 and err.count("\n") == 1, err
        assert err.startswith("robot-client: the controller refused line 0: UNREACHABLE ("), err
        assert emu.cell.groups[0].points_accepted == 0


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["move", "--joints", *["0"] * 6, "--linear"], "--linear needs --pose"),
        (["move", "--pose", "0.3", "0", "0.1", "--tcp-speed", "0.1"], "--tcp-speed needs --linear"),
        (["move", "--pose", "0.3", "0", "0.1", "--linear", "--tcp-speed", "0"], "--tcp-speed must be > 0"),
        (["move", "--pose", "0.3", "0", "0.1", "--linear", "--tcp-speed", "nan"], "--tcp-speed must be > 0"),
    ],
)
def test_bad_line_arguments_exit_2_before_connecting(
    argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(argv, io.StringIO()) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("robot-client: ") and words in err, err


@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_status_prints_the_tool_when_the_controller_sends_it(profile: str) -> None:
    async with emulator(profile=profile) as emu:
        code, out = await client("status", *ports(emu))
        assert code == 0, out
        state = json.loads(out)
        assert state["positions"] == pytest.approx(list(START), abs=1e-6)
        if profile == "motoros":
            assert state["tool"] is None  # it never sends TOOL_POSE
            return
        tool = state["tool"]
        assert set(tool) == {"x", "y", "z", "qx", "qy", "qz", "qw", "speed", "time"}
        p0, r0 = tcp_of(START)
        assert np.allclose([tool["x"], tool["y"], tool["z"]], p0, atol=1e-5) and tool["speed"] == 0.0
        assert quaternion_angle([tool["qw"], tool["qx"], tool["qy"], tool["qz"]], r0) < 1e-4


async def test_monitor_shows_the_tcp() -> None:
    async with emulator() as emu:
        code, out = await client("monitor", "--duration", "1.2", *ports(emu))
        assert code == 0, out
        p0, _ = tcp_of(START)
        x, y, z = (f"{v * 1000:+.1f}" for v in p0)
        assert f"tcp=[{x} {y} {z}] mm 0.0 mm/s  in_motion=FALSE" in out, out
