"""The robot driver against the emulator: streaming, downloading, MotoROS, stop, cancel, errors."""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest

from client.driver import DriverError, ExecutionAborted, RobotDriver
from client.trajectory import Trajectory
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.loader import load_model
from simple_message.wire import BE32
from tests.stepped import advance_until, settle, stepped_emulator

MODEL = load_model("jibot_zxs")


@contextlib.asynccontextmanager
async def setup(**options: Any) -> AsyncIterator[tuple[Emulator, RobotDriver]]:
    wire = options.pop("wire", None)
    config = EmulatorConfig(motion_port=0, state_port=0, io_port=0, state_rate=100.0, **options)
    async with Emulator(config) as emu:
        driver = RobotDriver(
            motion_port=emu.ports["motion"],
            state_port=emu.ports["state"],
            profile=config.profile,
            model=MODEL,
            **({"wire": wire} if wire else {}),
        )
        async with driver:
            yield emu, driver


def line(start: list[float], end: list[float], seconds: float, n: int = 20) -> Trajectory:
    """A smooth (quintic-timed) straight joint move, sampled at n waypoints with velocities."""
    s = np.linspace(0.0, 1.0, n)
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / seconds
    a, b = np.array(start), np.array(end)
    return Trajectory(s * seconds, a + np.outer(blend, b - a), np.outer(rate, b - a))


TARGET = [0.3, -0.2, 0.4, 0.5, -0.3, 0.6]


@pytest.mark.parametrize("mode", ["stream", "download"])
async def test_generic_execute_reaches_the_goal(mode: str) -> None:
    async with setup(speedup=4.0) as (emu, driver):
        final = await driver.execute(line([0.0] * 6, TARGET, 3.0, n=8), mode)  # rest-to-rest quintic per point
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
        assert final.status is not None and final.status.in_motion == 0
        assert emu.cell.groups[0].trajectories == 1
        assert await driver.ping() > 0.0


async def test_big_endian_and_feedback_free_state() -> None:
    async with setup(speedup=4.0, byte_order="big", wire=BE32) as (_, driver):
        final = await driver.execute(line([0.0] * 6, TARGET, 3.0, n=8))
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance


async def test_motoros_execute_with_busy_retries() -> None:
    async with setup(profile="motoros", speedup=2.0) as (_, driver):
        final = await driver.execute(line([0.0] * 6, TARGET, 2.0, n=40))  # more than MotoROS buffers
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
        await driver.stop()  # STOP_MOTION while idle


async def test_stop_while_idle_and_cancel_stops_the_robot() -> None:
    """On a clock the test advances: the robot stands still from the moment the test sees it past
    0.05 rad until the cancelled execution's STOP is acknowledged, so where it stops does not
    depend on how fast the machine is."""
    async with contextlib.AsyncExitStack() as stack:
        emu, clock = await stack.enter_async_context(stepped_emulator(state_rate=100.0))
        ctl = emu.cell.groups[0]
        driver = RobotDriver(motion_port=emu.ports["motion"], state_port=emu.ports["state"], model=MODEL)
        await stack.enter_async_context(driver)
        await driver.stop()  # idle: STOP is sent and acknowledged
        task = asyncio.create_task(driver.execute(line([0.0] * 6, TARGET, 3.0, n=8)))
        await advance_until(clock, lambda: ctl.command.actual_position[5] > 0.05, what="moving")
        assert not task.done()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            async with asyncio.timeout(10.0):
                await task
        await settle(emu, clock)
        assert ctl.command.actual_position[5] < 0.55  # stopped short of the goal (0.6)
        assert ctl.trajectories == 1


async def test_refused_point_aborts_with_the_confirmed_index() -> None:
    async with setup(speedup=4.0) as (_, driver):
        driver.check_limits = False  # what the controller does with it
        bad = Trajectory(np.array([0.0, 0.5, 1.0]), np.array([[0.0] * 6, [0.1] * 6, [0.0, 3.0, 0, 0, 0, 0]]))
        with pytest.raises(ExecutionAborted, match="refused point 2") as info:
            await driver.execute(bad)
        assert info.value.confirmed == 1
        with pytest.raises(DriverError, match="starts"):
            await driver.execute(line([0.5] * 6, TARGET, 1.0))


async def test_estop_during_execution_aborts() -> None:
    async with setup() as (emu, driver):
        task = asyncio.create_task(driver.execute(line([0.0] * 6, TARGET, 3.0, n=8)))
        await emu.wait_until(lambda: emu.cell.in_motion, 10.0)
        emu.cell.estop()
        with pytest.raises(ExecutionAborted, match="e-stopped"):  # it says why the robot stopped
            await asyncio.wait_for(task, 80.0)


async def test_one_serial_link_carries_motion_and_state() -> None:
    """The driver over a pseudo-terminal pair (pyserial on the slave), the emulator on the master."""
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo before pyserial opens it
    try:
        config = EmulatorConfig(motion_port=0, state_port=0, state_rate=50.0, speedup=4.0)
        async with Emulator(config) as emu:
            serving = asyncio.get_running_loop().create_task(emu.serve_fd(master))
            driver = RobotDriver(serial=os.ttyname(slave), model=MODEL, reply_timeout=5.0, watchdog=2.0)
            async with driver:
                assert driver.state is driver.motion
                assert await driver.ping() > 0.0
                final = await driver.execute(line([0.0] * 6, TARGET, 2.0, n=6))
                assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
            serving.cancel()
            with contextlib.suppress(asyncio.CancelledError, OSError):
                await serving
    finally:
        os.close(slave)
        with contextlib.suppress(OSError):
            os.close(master)


@pytest.mark.parametrize("mode", ["stream", "download"])
async def test_a_path_back_to_its_start_is_done_only_once_it_has_run(mode: str) -> None:
    """At the goal before it starts: "done" must wait until the robot has been seen moving."""
    config = EmulatorConfig(motion_port=0, state_port=0, state_rate=100.0, simulated=True)
    async with Emulator(config) as emu:
        driver = RobotDriver(motion_port=emu.ports["motion"], state_port=emu.ports["state"], model=MODEL)
        async with driver:
            start = (await driver.wait_state()).positions[:6]
            away = start + np.array([0.3, -0.2, 0.2, 0.1, 0.0, 0.1])
            [record] = emu.record(60.0)
            trajectory = Trajectory(np.array([0.0, 1.0, 2.0]), np.stack([start, away, start]))
            final = await driver.execute(trajectory, mode)
            emu.stop_recording()
        assert np.max(np.abs(final.positions - start)) <= driver.goal_tolerance
        travelled = np.max(np.abs(record.get("command_position") - start))
        assert travelled > 0.25  # the robot went out to `away` before "done"
        assert emu.cell.groups[0].trajectories == 1 and not emu.in_motion
