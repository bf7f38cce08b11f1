"""A recording replays as recorded (issue 36, item 4): ``robot-client record``'s files, run back
through the client's driver on a clock the test advances, take their recorded time within 2 %;
and what the driver does to a trajectory for MotoROS (its millisecond grid, measured speeds a
hair over the limit)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
from pathlib import Path

import numpy as np
import pytest

from client.driver import RobotDriver
from client.errors import DriverError
from client.limits import MEASURED_OVERSHOOT, cubic_accelerations, within_cubics, within_speeds
from client.planner import Planner
from client.sending import _on_milliseconds
from client.trajectory import Trajectory, recording
from robot_server import load_model
from robot_server.emulator.motoros import motoros_milliseconds
from tests.stepped import advance_until, settle, stepped_emulator

DATA = Path(__file__).parent / "data"
PUMA = load_model("puma560")


class _Done(logging.Handler):
    """The controller's own account of a trajectory: ``group 0: trajectory N done: ..., settled after T s``
    (robot_server/emulator/cell.py), from its first point to the robot at rest after the last."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.settled: list[float] = []

    def emit(self, record: logging.LogRecord) -> None:
        found = re.search(r"trajectory \d+ done: .*, settled after ([0-9.]+) s", record.getMessage())
        if found:
            self.settled.append(float(found.group(1)))


async def replay(path: Path, profile: str, model: str = "puma560") -> tuple[float, float]:
    """The recording's duration and the time the controller took for it (its log's "settled after")."""
    recorded = Trajectory.load(path)
    done = _Done()
    cell = logging.getLogger("robot_server.emulator.cell")
    level = cell.level
    cell.addHandler(done)
    cell.setLevel(logging.INFO)
    try:
        async with contextlib.AsyncExitStack() as stack:
            emu, clock = await stack.enter_async_context(
                stepped_emulator(profile=profile, models=(model,), queue_capacity=400, state_rate=40.0)
            )
            driver = RobotDriver(
                motion_port=emu.ports["motion"], state_port=emu.ports["state"], profile=profile, model=load_model(model)
            )
            await stack.enter_async_context(driver)
            task = asyncio.create_task(driver.execute(recorded))
            await advance_until(clock, task.done, limit=30.0, what="the replay")
            await task
            await settle(emu, clock)
    finally:
        cell.removeHandler(done)
        cell.setLevel(level)
    assert len(done.settled) == 1, done.settled
    return recorded.duration, done.settled[0]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "profile", "model"),
    [
        # two joint moves at --speed 1 (the controller's full acceleration), states stamped (JOINT_FEEDBACK time)
        ("recording_generic_puma560.csv", "generic", "puma560"),
        # the same moves at --speed 0.5 from MotoROS: no sample time, velocity-timed (client.trajectory.recording)
        ("recording_motoros_puma560.csv", "motoros", "puma560"),
        # issue 36's own: a Cartesian move at the default speed; a wrist joint breaks away from rest (the
        # motor model's friction), a kink the three-point estimate's quintic passed the limit at (x1.042)
        ("recording_generic_jibot_zxs.csv", "generic", "jibot_zxs"),
    ],
)
async def test_a_recording_replays_in_its_recorded_time(
    name: str, profile: str, model: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="robot_server.control.motion")
    recorded, replayed = await replay(DATA / name, profile, model)
    assert abs(replayed / recorded - 1.0) <= 0.02, (recorded, replayed)
    assert not [r for r in caplog.records if "too fast" in r.getMessage()]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "followed"),
    [
        # full-speed moves of many points (the Planner's): timed by the fastest joint, they replayed x1.15 slower
        ("motoros_states_puma560.npz", False),
        # rest-to-rest moves at full speed, two points each (robot-client move's): the estimated times and the
        # measured velocities make cubics beyond the acceleration limit, which MotoROS runs as they are; slowed
        # down for them, the replay took x1.63 its time
        ("motoros_states_move_puma560.npz", True),
    ],
)
async def test_motoros_states_as_received_replay_in_their_time(
    name: str, followed: bool, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The states a client received from a MotoROS emulator (positions and velocities, no time; a
    separate process moved the robot), made a recording as ``robot-client record`` makes it, replay
    within 2 %. Cubics beyond the acceleration limit are run as given, said once by the controller."""
    caplog.set_level(logging.WARNING, logger="robot_server.control.motion")
    data = np.load(DATA / name)
    states = recording(
        data["received"].tolist(),
        data["positions"].astype(float).tolist(),
        data["velocities"].astype(float).tolist(),
        PUMA.joint_names,
    )
    path = tmp_path / "states.csv"
    states.save(path)
    recorded, replayed = await replay(path, "motoros")
    assert abs(replayed / recorded - 1.0) <= 0.02, (recorded, replayed)
    records = [r for r in caplog.records if r.name == "robot_server.control.motion"]
    lines = [r.getMessage() for r in records]
    warned = [r.getMessage() for r in records if r.levelno == logging.WARNING and "run as given" in r.getMessage()]
    assert len(warned) == (1 if followed else 0), lines
    # a cubic passing a joint's speed limit between its points is still slowed down for (x1.014 once here)
    assert [line for line in lines if "too fast" in line and "x1.014" not in line] == [], lines


@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_a_recording_cut_off_mid_motion_runs_to_rest_at_its_last_state(profile: str, tmp_path: Path) -> None:
    """``record --duration`` (or Ctrl-C) while the robot moves: the last state is moving. The robot
    comes to rest there (MotoROS gets the last point's velocity as 0: with a velocity it would run
    dry and brake past it), and the run succeeds."""
    whole = Trajectory.load(DATA / f"recording_{profile}_puma560.csv")
    keep = 40  # well inside the first move
    assert whole.velocities is not None and float(np.max(np.abs(whole.velocities[keep - 1]))) > 0.5
    cut = Trajectory(whole.times[:keep], whole.positions[:keep], whole.velocities[:keep], joint_names=whole.joint_names)
    path = tmp_path / "cut.csv"
    cut.save(path)
    async with contextlib.AsyncExitStack() as stack:
        emu, clock = await stack.enter_async_context(
            stepped_emulator(profile=profile, models=("puma560",), queue_capacity=400, state_rate=40.0)
        )
        driver = RobotDriver(
            motion_port=emu.ports["motion"], state_port=emu.ports["state"], profile=profile, model=PUMA
        )
        await stack.enter_async_context(driver)
        task = asyncio.create_task(driver.execute(cut))
        await advance_until(clock, task.done, limit=30.0, what="the replay")
        final = await task
        await settle(emu, clock)
        end = np.array(emu.cell.groups[0].command.command_position)
    assert np.max(np.abs(end - cut.positions[-1])) < 1e-6
    assert np.max(np.abs(final.positions - cut.positions[-1])) <= driver.goal_tolerance


def test_motoros_points_go_on_its_millisecond_grid_on_the_trajectorys_own_curve() -> None:
    """MotoROS truncates a time to whole milliseconds (MotionServer.c:2094): points off the grid
    move to their nearest millisecond, with the state the trajectory's cubics give there, so the
    cubics MotoROS runs are the trajectory's own."""
    t = np.array([0.0, 0.0241, 0.0483, 0.0767, 0.1004])
    q = np.column_stack([np.sin(3 * t), t**3])
    v = np.column_stack([3 * np.cos(3 * t), 3 * t**2])
    times, positions, velocities = _on_milliseconds(t, q, v)
    assert [motoros_milliseconds(float(np.float32(x))) for x in times] == [0, 24, 48, 77, 101]
    assert times[0] == 0.0 and np.array_equal(positions[0], q[0]) and np.array_equal(positions[-1], q[-1])
    np.testing.assert_allclose(positions[1:-1, 0], np.sin(3 * times[1:-1]), atol=2e-6)
    np.testing.assert_allclose(positions[1:-1, 1], times[1:-1] ** 3, atol=1e-12)  # a cubic is kept exactly
    np.testing.assert_allclose(velocities[1:-1, 1], 3 * times[1:-1] ** 2, atol=1e-9)
    # already on the grid: unchanged
    same = _on_milliseconds(times, positions, velocities)
    assert np.array_equal(same[1], positions) and np.array_equal(same[2], velocities)


def test_measured_speeds_a_hair_over_the_limit_are_sent_at_it_and_more_is_refused() -> None:
    vmax = PUMA.max_velocity
    q = np.zeros((3, 6))
    v = np.zeros((3, 6))
    v[1, 5] = -vmax[5] * (1 + 0.0006)  # a drive's overshoot, as the emulator's motor model measures it
    capped = within_speeds(Trajectory(np.array([0.0, 0.025, 0.05]), q, v), PUMA)
    assert capped.velocities is not None
    # within the limit once on the wire (float32)
    assert abs(float(np.float32(capped.velocities[1, 5]))) <= vmax[5]
    assert capped.velocities[1, 5] < 0.0 and np.array_equal(capped.velocities[0], v[0])
    v[1, 5] = vmax[5] * (1 + 2 * MEASURED_OVERSHOOT)
    with pytest.raises(
        DriverError,
        match=r"point 1: joint 6 \(joint_6\) has the velocity 3\.267 rad/s, beyond its maximum 3\.142 rad/s",
    ):
        within_speeds(Trajectory(np.array([0.0, 0.025, 0.05]), q, v), PUMA)
    plain = Trajectory(np.array([0.0, 0.025, 0.05]), q, np.zeros((3, 6)))
    assert within_speeds(plain, PUMA) is plain


def test_a_segment_a_hair_faster_than_a_joint_takes_the_time_its_maximum_needs() -> None:
    """A joint that cruised at its maximum speed is measured a hair above it, and so is its mean speed
    over the segments its velocities time: such a segment takes the time the maximum needs (the
    points after it move later by as much); one beyond by more is still refused."""
    from client.limits import check_limits

    vmax = float(PUMA.max_velocity[5])
    times = np.array([0.0, 0.025, 0.05, 0.075])
    q = np.zeros((4, 6))
    q[:, 5] = [0.0, 0.01, 0.01 + 0.025 * vmax * 1.0005, 0.02 + 0.025 * vmax * 1.0005]
    fixed = within_speeds(Trajectory(times, q), PUMA)
    need = 0.025 * 1.0005 / (1.0 - 1e-6)
    assert fixed.times.tolist() == pytest.approx([0.0, 0.025, 0.025 + need, 0.05 + need], abs=1e-12)
    check_limits(fixed, PUMA)  # within now
    q[2:, 5] += 0.025 * vmax * 0.05
    too_fast = within_speeds(Trajectory(times, q), PUMA)
    assert too_fast.times.tolist() == times.tolist()
    with pytest.raises(DriverError, match=r"segment 1->2: joint 6 \(joint_6\) would move at"):
        check_limits(too_fast, PUMA)


def test_the_driver_says_when_motoros_cubics_would_be_too_fast(caplog: pytest.LogCaptureFixture) -> None:
    """A MotoROS recording of a move at the acceleration limit: its estimated times and measured
    velocities make cubics beyond the limit, which MotoROS runs as they are; the client says so
    before sending (client.sending._warn_cubics)."""
    from client.sending import _warn_cubics

    t = np.array([0.0, 0.024, 0.048])
    q = np.array([[0.0] * 6, [0.0024] * 6, [0.012] * 6])
    v = np.array([[0.1] * 6, [0.1] * 6, [0.5] * 6])  # the second segment's do not match its positions
    with caplog.at_level(logging.WARNING, logger="client.driver"):
        _warn_cubics(t, q, v, PUMA.max_acceleration)
    assert "accelerate joint 1 up to" in caplog.text and "segment 1->2" in caplog.text
    caplog.clear()
    s = np.linspace(0, 1, 11)
    smooth_q = np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, np.full(6, 0.2))
    smooth_v = np.outer((30 * s**2 - 60 * s**3 + 30 * s**4) / 1.0, np.full(6, 0.2))
    with caplog.at_level(logging.WARNING, logger="client.driver"):
        _warn_cubics(s, smooth_q, smooth_v, PUMA.max_acceleration)
    assert caplog.text == ""
    # from rest to rest in one segment: MotoROS runs that cubic too (6 d / T^2 at both ends)
    with caplog.at_level(logging.WARNING, logger="client.driver"):
        _warn_cubics(np.array([0.0, 0.3]), np.array([[0.0] * 6, [0.5] * 6]), np.zeros((2, 6)), PUMA.max_acceleration)
    assert "segment 0->1" in caplog.text


def test_the_client_s_own_plan_is_kept_within_motoros_s_cubics() -> None:
    """A joint move at the full acceleration sent to MotoROS as its two points would be one cubic
    from rest to rest at 1.5x the limit and more, which MotoROS runs as given: the client slows its
    own plan down uniformly until every cubic is within (client.limits.within_cubics); a plan within
    is sent as it is."""
    planner = Planner(PUMA, velocity_scale=1.0, acceleration_scale=1.0, jerk_scale=1.0, joint_spacing=2 * np.pi)
    motion = planner.joint_move(np.zeros(6), np.array([1.2, 0.3, -0.6, 1.0, 0.8, -1.5])).sparse()
    v = motion.velocities
    assert v is not None
    before = cubic_accelerations(motion.times, motion.positions, v) / PUMA.max_acceleration
    assert before.max() > 1.3
    kept = within_cubics(motion, PUMA)
    assert kept.velocities is not None
    after = cubic_accelerations(kept.times, kept.positions, kept.velocities) / PUMA.max_acceleration
    assert 0.98 <= after.max() <= 0.99 + 1e-9
    assert kept.duration == pytest.approx(motion.duration * np.sqrt(before.max() / 0.99))
    slow = Planner(PUMA, velocity_scale=0.3, acceleration_scale=0.3, jerk_scale=0.3).joint_move(
        np.zeros(6), np.full(6, 0.5)
    )
    gentle = slow.sparse()
    assert within_cubics(gentle, PUMA) is gentle
