"""How the driver fails: the errors a user meets, each against the emulator on a clock the test
advances (so the robot is exactly where the test left it) or against the scripted fake controller.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest

from client.driver import DriverError, ExecutionAborted, RobotDriver
from client.trajectory import Trajectory
from robot_server.control import SteppedClock
from robot_server.emulator import Emulator
from robot_server.loader import load_model
from simple_message.wire import BE32
from tests.fakecontroller import JOINT_TRAJ_PT, MOTO_MOTION_CTRL, FakeController, Reply
from tests.rawpeer import Frame
from tests.stepped import advance_until, settle, stepped_emulator
from tests.test_client_driver import TARGET, line

MODEL = load_model("jibot_zxs")
#: wall-clock bound of a driver call that is expected to fail
FAIL_WITHIN = 20.0


@contextlib.asynccontextmanager
async def setup(
    profile: str = "generic", **driver_options: Any
) -> AsyncIterator[tuple[Emulator, SteppedClock, RobotDriver]]:
    async with contextlib.AsyncExitStack() as stack:
        emu, clock = await stack.enter_async_context(stepped_emulator(profile=profile, state_rate=100.0))
        driver_options.setdefault("model", MODEL)
        driver = RobotDriver(
            motion_port=emu.ports["motion"], state_port=emu.ports["state"], profile=profile, **driver_options
        )
        await stack.enter_async_context(driver)
        yield emu, clock, driver


async def bounded(call: Any) -> Any:
    async with asyncio.timeout(FAIL_WITHIN):
        return await call


async def test_an_alarm_during_the_motion_aborts_with_its_code() -> None:
    async with setup() as (emu, clock, driver):
        task = asyncio.create_task(driver.execute(line([0.0] * 6, TARGET, 3.0, n=8)))
        await advance_until(clock, lambda: emu.cell.groups[0].command.actual_position[5] > 0.05, what="moving")
        emu.cell.alarm(4321, "overheated")
        with pytest.raises(ExecutionAborted, match=r"in error \(code 4321\)") as info:
            await bounded(task)
        assert info.value.confirmed == 7  # every point had been acknowledged
        await settle(emu, clock)
        assert emu.cell.in_error and emu.cell.groups[0].command.actual_position[5] < 0.3


async def test_a_robot_that_stops_moving_short_of_the_goal_times_out() -> None:
    """The controller's time stands still mid-motion: in_motion stays TRUE, the goal never comes."""
    async with setup(goal_timeout=0.2) as (emu, clock, driver):
        task = asyncio.create_task(driver.execute(line([0.0] * 6, TARGET, 0.2, n=3)))
        await advance_until(clock, lambda: emu.cell.in_motion and emu.cell.groups[0].queue_fill == 0, what="moving")
        with pytest.raises(ExecutionAborted, match="did not reach the goal in time"):
            await bounded(task)


async def test_a_dropped_download_shows_as_a_robot_standing_still() -> None:
    """A download point beyond the limits: the controller drops the download without a word
    (TOPICs have no reply); the robot never moves and the driver says so after stall_timeout."""
    async with setup(stall_timeout=0.2) as (emu, _clock, driver):
        driver.check_limits = False  # what the controller does with it
        beyond = Trajectory(np.array([0.0, 0.5, 1.0]), np.array([[0.0] * 6, [0.1] * 6, [0.0, 3.0, 0, 0, 0, 0]]))
        with pytest.raises(ExecutionAborted, match="stands still") as info:
            await bounded(driver.execute(beyond, "download"))
        assert info.value.confirmed == 2  # every point was written (a download has no acknowledgements)
        assert emu.cell.groups[0].trajectories == 0


@pytest.mark.parametrize("mode", ["download", "stream"])
async def test_a_path_back_to_its_start_on_an_e_stopped_controller_is_not_done(mode: str) -> None:
    """At the goal before it begins, and a download has no replies: 'done' would be a lie (it was,
    after stall_timeout); the driver says why the robot did not move."""
    async with setup(stall_timeout=0.2) as (emu, _clock, driver):
        emu.cell.estop()
        loop = Trajectory(np.array([0.0, 1.0, 2.0]), np.array([[0.0] * 6, [0.3] + [0.0] * 5, [0.0] * 6]))
        with pytest.raises(ExecutionAborted, match="e-stopped"):
            await bounded(driver.execute(loop, mode))
        assert emu.cell.groups[0].trajectories == 0


async def test_a_single_point_download_is_sent_twice_as_the_reference_downloader_does() -> None:
    async with setup() as (emu, _clock, driver):
        final = await bounded(driver.execute(Trajectory(np.array([0.0]), np.zeros((1, 6))), "download"))
        assert np.all(final.positions == 0.0)
        assert emu.cell.groups[0].trajectories == 1


async def test_a_state_connection_the_controller_closed_is_said_so() -> None:
    async with setup(watchdog=0.3) as (emu, clock, driver):
        task = asyncio.create_task(driver.execute(line([0.0] * 6, TARGET, 3.0, n=8)))
        await advance_until(clock, lambda: emu.cell.in_motion, what="moving")
        await emu.state_server.close()  # the state port goes away
        with pytest.raises(ExecutionAborted, match=r"the controller closed the state connection .*no joint state"):
            await bounded(task)


async def test_no_joint_state_on_a_live_connection_is_the_watchdog() -> None:
    async with setup(watchdog=0.3) as (emu, clock, driver):
        task = asyncio.create_task(driver.execute(line([0.0] * 6, TARGET, 3.0, n=8)))
        await advance_until(clock, lambda: emu.cell.in_motion, what="moving")
        emu.publish_state = lambda: None  # type: ignore[method-assign]  # the topics stop, the connection stays
        with pytest.raises(ExecutionAborted, match=r"no joint state for 0.3 s \(watchdog\)"):
            await bounded(task)


async def test_trajectories_that_do_not_fit_the_robot_are_refused_before_anything_is_sent() -> None:
    async with setup() as (emu, _clock, driver):
        with pytest.raises(DriverError, match="the trajectory has 5 joints, the robot 6"):
            await driver.execute(Trajectory(np.array([0.0, 1.0]), np.zeros((2, 5))))
        with pytest.raises(DriverError, match=r"starts 0\.5 away"):
            await driver.execute(line([0.5] * 6, TARGET, 1.0))
        with pytest.raises(ValueError, match="sideways"):
            await driver.execute(line([0.0] * 6, TARGET, 1.0), "sideways")
        assert emu.cell.groups[0].trajectories == 0
    async with setup(model=None) as (_emu, _clock, driver):
        # without a model the driver knows only the joints the controller reports (10 on the wire)
        with pytest.raises(DriverError, match="the controller reports 10"):
            await driver.execute(line([0.0] * 6, TARGET, 1.0))


async def test_motoros_refuses_to_start_while_the_emergency_stop_is_engaged() -> None:
    async with setup("motoros") as (emu, _clock, driver):
        emu.cell.estop()
        with pytest.raises(
            ExecutionAborted,
            match=r"START_TRAJ_MODE refused: NOT_READY \(ESTOP, subcode 5003\); the controller is e-stopped",
        ) as info:
            await bounded(driver.execute(line([0.0] * 6, TARGET, 1.0, n=3)))
        assert info.value.confirmed == -1


async def test_motoros_refuses_a_point_beyond_the_limits() -> None:
    async with setup("motoros") as (emu, _clock, driver):
        driver.check_limits = False  # what the controller does with it
        beyond = Trajectory(np.array([0.0, 0.5]), np.array([[0.0] * 6, [0.0, 3.0, 0, 0, 0, 0]]))
        with pytest.raises(ExecutionAborted, match=r"refused point 1: INVALID \(\w+, subcode 3012\)") as info:
            await bounded(driver.execute(beyond))
        assert info.value.confirmed == 0
        assert emu.cell.groups[0].command.actual_position == [0.0] * 6


# -- controllers that refuse to stop (the scripted fake) ------------------------------------------------


async def test_a_generic_controller_that_answers_failure_to_stop() -> None:
    def script(frame: Frame, _count: int) -> Reply:
        return Reply("failure" if frame.msg_type == JOINT_TRAJ_PT else "success")

    async with FakeController(script) as fake:
        async with RobotDriver("127.0.0.1", fake.ports["motion"], fake.ports["state"], model=MODEL) as driver:
            with pytest.raises(DriverError, match="answered FAILURE to STOP"):
                await bounded(driver.stop())
        assert [f.ints(1)[0] for f in fake.frames(JOINT_TRAJ_PT)] == [-4]


async def test_a_motoros_controller_that_refuses_stop_motion() -> None:
    def script(frame: Frame, _count: int) -> Reply:
        return Reply("moto", result=3, subcode=3006) if frame.msg_type == MOTO_MOTION_CTRL else Reply("moto")

    async with FakeController(script, order=">") as fake:
        driver = RobotDriver(
            "127.0.0.1", fake.ports["motion"], fake.ports["state"], profile="motoros", wire=BE32, model=MODEL
        )
        async with driver:
            with pytest.raises(DriverError, match="STOP_MOTION refused: result 3, subcode 3006"):
                await bounded(driver.stop())
        assert len(fake.frames(MOTO_MOTION_CTRL)) == 1


# -- one sample per state round -------------------------------------------------------------------------


async def test_a_status_in_a_read_of_its_own_is_not_a_new_joint_state() -> None:
    """JOINT_POSITION and STATUS of a round arriving in two reads (a loaded machine, a busy
    network): one sample per round, as `record` and `monitor` count them (each STATUS used to be a
    sample of its own, a copy of the position 2 ms later)."""

    def script(frame: Frame, _count: int) -> Reply:
        return Reply("success")

    async with (
        FakeController(script, status_after=0.002, state_period=0.01) as fake,
        RobotDriver("127.0.0.1", fake.ports["motion"], fake.ports["state"], model=MODEL) as driver,
    ):
        samples = 0
        first = fake.rounds

        async def count() -> None:
            nonlocal samples
            async for _ in driver.states():
                samples += 1
                if fake.rounds - first >= 20:
                    return

        await bounded(count())
        assert samples <= fake.rounds - first + 1, (samples, fake.rounds - first)


async def test_a_controller_that_never_publishes_its_state_leaves_no_connection_open() -> None:
    """connect() waits for the first joint state; when none comes, it fails and closes what it
    opened (before, both connections stayed open behind the error, and a program retrying held
    more and more of the controller's connection slots)."""
    ended: list[bytes] = []
    both = asyncio.Event()

    async def silent(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        ended.append(await reader.read())  # b"" once the client closes
        if len(ended) == 2:
            both.set()
        writer.close()

    server = await asyncio.start_server(silent, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    state = await asyncio.start_server(silent, "127.0.0.1", 0)
    try:
        robot = RobotDriver("127.0.0.1", port, state.sockets[0].getsockname()[1])
        with pytest.raises(DriverError):
            await robot.connect(timeout=0.2)
        async with asyncio.timeout(10.0):
            await both.wait()  # both connections closed by the client
        assert ended == [b"", b""]
    finally:
        server.close()
        state.close()
