"""The driver against a scripted fake controller (tests/fakecontroller.py): the exact frames it sends
when acks are late, when the controller says BUSY or FAILURE, drops the connection mid-trajectory,
or never answers STOP."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
import pytest

from client.driver import DriverError, ExecutionAborted, RobotDriver
from client.trajectory import Trajectory
from robot_server.loader import load_model
from simple_message.wire import BE32
from tests.fakecontroller import (
    DROP,
    JOINT_TRAJ_PT,
    JOINT_TRAJ_PT_FULL,
    MOTO_MOTION_CTRL,
    PING,
    REQUEST,
    SILENT,
    FakeController,
    Reply,
)
from tests.rawpeer import Frame

MODEL = load_model("jibot_zxs")
CHECK_MOTION_READY, STOP_MOTION, START_TRAJ_MODE = 200101, 200111, 200121
MOTO_SUCCESS, MOTO_BUSY, MOTO_TRUE, MOTO_FALSE = 0, 1, 0, 1  # MotoROS: TRUE is 0, FALSE 1


def trajectory() -> Trajectory:
    t = np.array([0.0, 0.5, 1.0, 1.75, 2.5])
    q = np.zeros((5, 6))
    q[:, 0] = [0.0, 0.1, 0.3, 0.35, 0.4]
    q[:, 4] = [0.0, -0.05, -0.1, -0.2, -0.2]
    return Trajectory(t, q)


def driver(fake: FakeController, **options: object) -> RobotDriver:
    defaults: dict[str, object] = {"model": MODEL, "reply_timeout": 2.0, "watchdog": 2.0, "goal_tolerance": 1e-5}
    defaults.update(options)
    return RobotDriver("127.0.0.1", fake.ports["motion"], fake.ports["state"], **defaults)  # type: ignore[arg-type]


def points(frames: list[Frame]) -> list[tuple[int, list[float], float, float]]:
    """(sequence, joints, velocity ratio, duration) of each JOINT_TRAJ_PT, from the raw bytes."""
    out = []
    for f in frames:
        if f.msg_type == JOINT_TRAJ_PT:
            sequence = f.ints(1)[0]
            values = f.reals(12, 4)
            out.append((sequence, list(values[:6]), values[10], values[11]))
    return out


def generic_success(frame: Frame, _count: int) -> Reply:
    return Reply("success", delay=0.03)  # every ack arrives late


async def test_stream_with_late_acks_sends_exact_points_one_at_a_time() -> None:
    traj = trajectory()
    async with FakeController(generic_success) as fake:
        async with driver(fake) as d:
            final = await d.execute(traj)
        assert np.allclose(final.positions, traj.positions[-1], atol=1e-6)
        assert fake.overlapping == 0  # never a second point before the first one's reply
        sent = points(fake.frames())
        assert all(f.comm_type == REQUEST for f in fake.frames(JOINT_TRAJ_PT))
        assert [p[0] for p in sent] == [0, 1, 2, 3, 4]
        for k, (_, joints, ratio, duration) in enumerate(sent):
            assert np.allclose(joints, traj.positions[k], atol=1e-7)
            expected = 0.0 if k == 0 else traj.times[k] - traj.times[k - 1]
            assert duration == pytest.approx(expected, abs=1e-7)  # no 10 s first segment
            if k:
                mean = np.abs(traj.positions[k] - traj.positions[k - 1]) / expected
                assert ratio == pytest.approx(np.max(1.875 * mean / MODEL.max_velocity), rel=1e-6)
            else:
                assert ratio == 0.0


async def test_failure_aborts_with_the_confirmed_point_and_stops() -> None:
    def script(frame: Frame, _count: int) -> Reply:
        if frame.msg_type == JOINT_TRAJ_PT and frame.ints(1)[0] == 2:
            return Reply("failure")
        return Reply("success")

    async with FakeController(script) as fake:
        async with driver(fake) as d:
            with pytest.raises(ExecutionAborted, match="refused point 2") as info:
                await d.execute(trajectory())
        assert info.value.confirmed == 1
        # points 0..2, then STOP (-4) and nothing after it
        assert [p[0] for p in points(fake.frames())] == [0, 1, 2, -4]


async def test_download_sends_topics_then_a_ping() -> None:
    traj = trajectory()
    async with FakeController(generic_success) as fake:
        async with driver(fake) as d:
            await d.execute(traj, "download")
        frames = fake.frames()
        kinds = [(f.msg_type, f.comm_type) for f in frames]
        assert kinds == [(JOINT_TRAJ_PT, 1)] * 5 + [(PING, REQUEST)]
        assert [p[0] for p in points(frames)] == [-1, 1, 2, 3, -3]
        assert [p[3] for p in points(frames)] == pytest.approx([0.0, 0.5, 0.5, 0.75, 0.75])


async def test_connection_dropped_with_a_point_in_flight_aborts_without_resending() -> None:
    def script(frame: Frame, _count: int) -> Reply:
        if frame.msg_type == JOINT_TRAJ_PT and frame.ints(1)[0] == 3 and len(fake.connections) == 1:
            return DROP
        return Reply("success")

    async with FakeController(script) as fake:
        async with driver(fake, resume=True) as d:
            with pytest.raises(ExecutionAborted, match="point 3 awaiting its reply") as info:
                await d.execute(trajectory())
        assert info.value.confirmed == 2
        assert [p[0] for p in points(fake.frames(connection=0))] == [0, 1, 2, 3]
        # once reconnected the driver stopped the robot, and resent nothing
        assert [p[0] for p in points(fake.frames(connection=1))] == [-4]


async def test_stop_that_is_never_answered_times_out() -> None:
    def script(frame: Frame, _count: int) -> Reply:
        if frame.msg_type == JOINT_TRAJ_PT and frame.ints(1)[0] == -4:
            return SILENT
        return Reply("success")

    async with FakeController(script) as fake:
        async with driver(fake, reply_timeout=0.3) as d:
            with pytest.raises(DriverError, match="no reply to JOINT_TRAJ_PT"):
                await d.stop()
            # the link is reset (a late reply must not answer the next request) and still works
            await d.execute(trajectory())
        assert [p[0] for p in points(fake.frames(connection=0))] == [-4]
        assert [p[0] for p in points(fake.frames(connection=1))] == [0, 1, 2, 3, 4]


# -- MotoROS (big-endian, replies from the FS100 capture) ------------------------------------------------


def moto_command(frame: Frame) -> int:
    return frame.ints(3)[2]


def jtpf(frames: list[Frame]) -> list[tuple[int, int, float, list[float], list[float]]]:
    """(sequence, valid_fields, time, positions, velocities) of each JOINT_TRAJ_PT_FULL."""
    out = []
    for f in frames:
        if f.msg_type == JOINT_TRAJ_PT_FULL:
            _, sequence, fields = f.ints(3)
            out.append((sequence, fields, f.reals(1, 12)[0], list(f.reals(6, 16)), list(f.reals(6, 56))))
    return out


def motoros_script(busy_at: int, busy_times: int) -> tuple[list[int], Callable[[Frame, int], Reply]]:
    ready = [MOTO_FALSE]
    busy = [0]

    def script(frame: Frame, _count: int) -> Reply:
        if frame.msg_type == MOTO_MOTION_CTRL:
            command = moto_command(frame)
            if command == CHECK_MOTION_READY:
                return Reply("moto", result=ready[0], subcode=5001 if ready[0] == MOTO_FALSE else 0)
            if command == START_TRAJ_MODE:
                ready[0] = MOTO_TRUE
            return Reply("moto", result=MOTO_SUCCESS)
        sequence = frame.ints(2)[1]
        if sequence == busy_at and busy[0] < busy_times:
            busy[0] += 1
            return Reply("moto", result=MOTO_BUSY)
        return Reply("moto", result=MOTO_SUCCESS)

    return busy, script


async def test_motoros_sequence_with_busy_retries() -> None:
    traj = trajectory()
    busy, script = motoros_script(busy_at=2, busy_times=3)
    async with FakeController(script, order=">") as fake:
        async with driver(fake, profile="motoros", wire=BE32) as d:
            await d.execute(traj)
            await d.stop()
        frames = fake.frames()
        controls = [moto_command(f) for f in frames if f.msg_type == MOTO_MOTION_CTRL]
        assert controls == [CHECK_MOTION_READY, START_TRAJ_MODE, CHECK_MOTION_READY, STOP_MOTION]
        sent = jtpf(frames)
        assert [s[0] for s in sent] == [0, 1, 2, 2, 2, 2, 3, 4]  # point 2 resent after each BUSY
        assert busy[0] == 3
        unique = [s for i, s in enumerate(sent) if i == 0 or s[0] != sent[i - 1][0]]
        v = (traj.positions[2:] - traj.positions[:-2]) / (traj.times[2:] - traj.times[:-2])[:, None]
        velocities = np.vstack([np.zeros(6), v, np.zeros(6)])
        for k, (_, fields, time, positions, vel) in enumerate(unique):
            assert fields == 7  # TIME | POSITION | VELOCITY
            assert time == pytest.approx(traj.times[k], abs=1e-6)
            assert np.allclose(positions, traj.positions[k], atol=1e-7)
            assert np.allclose(vel, velocities[k], atol=1e-6)


async def test_motoros_resumes_after_a_reconnect_from_the_unsent_point(caplog: pytest.LogCaptureFixture) -> None:
    _, base = motoros_script(busy_at=-1, busy_times=0)

    def script(frame: Frame, count: int) -> Reply:
        if frame.msg_type == JOINT_TRAJ_PT_FULL and frame.ints(2)[1] == 2 and len(fake.connections) == 1:
            # answered (not accepted), then the link drops during the driver's back-off
            return Reply("moto", result=MOTO_BUSY, then_drop=True)
        return base(frame, count)

    async with FakeController(script, order=">") as fake:
        async with driver(fake, profile="motoros", wire=BE32, resume=True) as d:
            with caplog.at_level(logging.WARNING, "client.driver"):
                await d.execute(trajectory())
        first, second = fake.frames(connection=0), fake.frames(connection=1)
        assert [s[0] for s in jtpf(first)] == [0, 1, 2]
        # the new connection: ready checked again, then point 2 (never accepted) and the rest
        assert [moto_command(f) for f in second if f.msg_type == MOTO_MOTION_CTRL] == [CHECK_MOTION_READY]
        assert [s[0] for s in jtpf(second)] == [2, 3, 4]
        assert "resuming at point 2" in caplog.text


async def test_without_resume_a_lost_link_aborts_and_says_so() -> None:
    _, base = motoros_script(busy_at=-1, busy_times=0)

    def script(frame: Frame, count: int) -> Reply:
        if frame.msg_type == JOINT_TRAJ_PT_FULL and frame.ints(2)[1] == 2 and len(fake.connections) == 1:
            return Reply("moto", result=MOTO_BUSY, then_drop=True)
        return base(frame, count)

    async with FakeController(script, order=">") as fake:
        async with driver(fake, profile="motoros", wire=BE32) as d:
            with pytest.raises(ExecutionAborted, match=r"before point 2 was sent; not resuming") as info:
                await d.execute(trajectory())
        assert info.value.confirmed == 1
        # after the reconnection: only STOP_MOTION, no point
        second = fake.frames(connection=1)
        assert [moto_command(f) for f in second if f.msg_type == MOTO_MOTION_CTRL] == [STOP_MOTION]
        assert jtpf(second) == []
