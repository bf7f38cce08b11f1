"""The robot driver against the vendor profiles (abb, fanuc, staubli): each controller taken the way
it takes trajectories (client/sending.py, client/driver.py; docs/vendors.md)."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest

from client.driver import DriverError, RobotDriver
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.loader import load_model
from tests.test_client_driver import line

MODEL = load_model("jibot_zxs")
TARGET = [0.3, -0.2, 0.4, 0.5, -0.3, 0.6]


@contextlib.asynccontextmanager
async def setup(profile: str, **options: Any) -> AsyncIterator[tuple[Emulator, RobotDriver]]:
    driver_options = options.pop("driver", {})
    options.setdefault("speedup", 4.0)
    if profile == "motoros":
        options.setdefault("io_port", 0)
    config = EmulatorConfig(profile=profile, motion_port=0, state_port=0, **options)
    async with Emulator(config) as emu:
        driver = RobotDriver(
            motion_port=emu.ports["motion"],
            state_port=emu.ports["state"],
            profile=profile,
            model=MODEL,
            **driver_options,
        )
        async with driver:
            yield emu, driver


def commanded(emu: Emulator) -> np.ndarray:
    return np.array(emu.cell.groups[0].command.command_position)


async def test_abb_downloads_each_point_as_a_request_and_reaches_the_goal() -> None:
    async with setup("abb") as (emu, driver):
        final = await driver.execute(line([0.0] * 6, TARGET, 1.0))
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
        assert emu.behaviour.motion.dropped == 0  # type: ignore[attr-defined]
        with pytest.raises(DriverError, match="takes trajectories downloaded, not streamed"):
            await driver.execute(line(list(final.positions), [0.0] * 6, 1.0), "stream")


async def test_motoros_has_one_way_whatever_mode_is_asked(caplog: pytest.LogCaptureFixture) -> None:
    async with setup("motoros") as (_emu, driver):
        with caplog.at_level(logging.WARNING, "client.driver"):
            final = await driver.execute(line([0.0] * 6, TARGET, 1.0, n=6), "download")
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
        assert "its trajectory mode: download is not a choice there" in caplog.text


async def test_abb_refuses_more_than_100_points_before_sending_any() -> None:
    async with setup("abb") as (emu, driver):
        with pytest.raises(DriverError, match="keeps 100 points of a trajectory"):
            await driver.execute(line([0.0] * 6, TARGET, 2.0, n=101))
        assert not emu.cell.in_motion and emu.behaviour.motion.buffer == []  # type: ignore[attr-defined]


@pytest.mark.parametrize("profile", ["abb", "fanuc", "staubli"])
async def test_no_ping_where_the_controller_answers_none(profile: str) -> None:
    async with setup(profile) as (emu, driver):
        with pytest.raises(DriverError, match="answers no PING"):
            await driver.ping()
        assert not await driver.supports_lines()  # and no CARTESIAN_LINE probe either
        if profile == "abb":
            assert emu.behaviour.motion.dead is None  # type: ignore[attr-defined]


async def test_abb_first_point_sent_where_the_robot_is() -> None:
    async with setup("abb") as (emu, driver):
        start = [0.005, 0.0, 0.0, 0.0, 0.0, 0.0]  # within the goal tolerance, beyond RAPID's 0.1 degree
        await driver.execute(line(start, TARGET, 1.0, n=10))
        assert np.max(np.abs(commanded(emu) - TARGET)) < 1e-6


async def test_fanuc_j2_j3_coupling_both_ways() -> None:
    async with setup("fanuc") as (emu, driver):
        assert driver.j23_factor == 1
        final = await driver.execute(line([0.0] * 6, TARGET, 0.5, n=6))
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance  # the model's joints
        assert np.max(np.abs(commanded(emu) - TARGET)) < 1e-5  # the emulator's model agrees


@pytest.mark.parametrize("profile", ["fanuc", "staubli"])
async def test_fanuc_and_staubli_take_their_own_time_without_a_deadline(profile: str) -> None:
    # a 0.2 s trajectory that Fanuc's 20 % moves, and Staubli's movej at the points' velocity
    # share, take well over a second for: the driver waits for the goal (no deadline from the
    # trajectory's times), and the goal_timeout does not cut it
    async with setup(profile, speedup=1.0, driver={"goal_timeout": 0.1}) as (emu, driver):
        began = emu.cell.time
        final = await driver.execute(line([0.0] * 6, TARGET, 0.2, n=4))
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
        assert emu.cell.time - began > 0.2 + 0.1 + 0.5  # far beyond the trajectory's time and the timeout


async def test_staubli_failure_while_moving_is_a_full_queue_sent_again(caplog: pytest.LogCaptureFixture) -> None:
    async with setup("staubli", profile_options=(("motion_stack", "2"),)) as (emu, driver):
        path = line([0.0] * 6, TARGET, 2.0, n=30)  # far more points than the queue and the stack hold
        with caplog.at_level(logging.WARNING, "robot_server.emulator.staubli"):
            final = await driver.execute(path)
        assert np.max(np.abs(final.positions - TARGET)) <= driver.goal_tolerance
        assert emu.cell.groups[0].points_accepted == 30  # every point moved to, none lost
        assert "the 10-entry queue is full" in caplog.text  # and the queue did fill


async def test_staubli_velocity_share_is_never_zero() -> None:
    async with setup("staubli") as (emu, driver):
        await driver.execute(line([0.0] * 6, [0.0] * 6, 1.0, n=3))  # a pause: VAL3 refuses velocity 0
        assert not emu.cell.in_motion
