"""Streaming over TCP as the ROS clients do it, against the emulator on a clock the test advances
(so arrival times are controller times and two runs give the same trace, bit for bit), and once
in real time; MotoROS's timing, queue count, DH reply and joint slots."""

from __future__ import annotations

import contextlib
import logging
import math
import struct
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest

from robot_server.control import Recorder, SteppedClock
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.emulator.motoros import motoros_milliseconds
from robot_server.loader import load_model
from tests.rawpeer import RawPeer, joint_traj_pt, joint_traj_pt_full, vectors
from tests.stepped import settle, step, stepped_emulator
from tests.streams import Plan, measure, ros_points

MODEL = load_model("jibot_zxs")
VMAX, AMAX, JMAX = MODEL.max_velocity, MODEL.max_acceleration, MODEL.max_jerk
LE = vectors("<")
JTP, JTPF = LE["JOINT_TRAJ_PT_REQUEST_SEQ3"], LE["JOINT_TRAJ_PT_FULL_REQUEST"]
MOTO_CTRL, MOTO_REPLY = 2001, 2002
CHECK_MOTION_READY, CHECK_QUEUE_CNT, START_TRAJ_MODE = 200101, 200102, 200121
ALL_FIELDS = 0x0F


@contextlib.asynccontextmanager
async def stepped(**options: Any) -> AsyncIterator[tuple[Emulator, SteppedClock, Recorder]]:
    """An emulator whose controller time moves only when the test advances it, recording."""
    async with stepped_emulator(record=30.0, **options) as (emu, clock):
        assert emu.control.recorder is not None
        yield emu, clock, emu.control.recorder


def ros_frames(plan: Plan) -> list[bytes]:
    """JOINT_TRAJ_PT frames as industrial_robot_client fills them."""
    return [
        joint_traj_pt(JTP, i, p.positions.tolist(), float(p.velocity_ratio or 0.0), float(p.duration or 0.0))
        for i, p in enumerate(ros_points(plan, VMAX))
    ]


async def stream_generic(cadence: float, duration: float = 1.0) -> tuple[Recorder, Plan, int]:
    """A dense plan streamed as industrial_robot_client does (one request in flight, a point per
    ``cadence`` of controller time), on the stepped clock. Returns the record and the count of
    SUCCESS replies."""
    plan = Plan.make(duration, 101)
    async with stepped(queue_capacity=200) as (emu, clock, record):
        motion = await RawPeer.connect(emu.ports["motion"])
        accepted = 0
        for frame in ros_frames(plan):
            reply = await motion.request(frame)
            accepted += reply.reply_code == 1
            await step(clock, cadence)
        await settle(emu, clock)
        await motion.close()
    return record, plan, accepted


@pytest.mark.parametrize("cadence", [0.0, 0.004, 0.008], ids=["at-once", "4ms", "8ms"])
async def test_a_stream_over_tcp_on_a_stepped_clock_runs_as_planned_and_repeats_bit_for_bit(cadence: float) -> None:
    a, plan, accepted = await stream_generic(cadence)
    assert accepted == plan.count
    m = measure(a, MODEL, plan, 4)
    assert m.stops == 0 and abs(m.executed - plan.duration) <= 0.02 * plan.duration
    # moving within 10 ms of the point that gives it somewhere to go (the first point, sequence 0,
    # is the start; point 1 follows ``cadence`` later)
    assert m.start <= cadence + 0.010
    assert m.deviation_command <= 0.05e-3 and m.final_error <= 1e-7  # the float32 of the last point
    b, _, _ = await stream_generic(cadence)
    for quantity in ("command_position", "command_velocity", "actual_position", "following_error"):
        assert np.array_equal(a.get(quantity), b.get(quantity)), quantity
    assert np.array_equal(a.points(), b.points())


async def test_a_stream_over_real_tcp_in_real_time() -> None:
    """The same stream with the controller on the wall clock: every point accepted and the last one
    reached, within the limits all the way. How closely the path is followed depends on when the
    points arrive, so that is measured on the stepped clock above and in ``bench/streaming.py``,
    not here: nothing asserted here depends on how fast or loaded the machine is."""
    plan = Plan.make(1.0, 101)
    config = EmulatorConfig(motion_port=0, state_port=0)
    async with Emulator(config) as emu:
        record = emu.record(30.0)[0]
        motion = await RawPeer.connect(emu.ports["motion"])
        replies = [await motion.request(frame) for frame in ros_frames(plan)]
        await emu.wait_until(lambda: not emu.cell.in_motion, 30.0)
        await motion.close()
    assert all(r.reply_code == 1 for r in replies)
    command = record.get("command_position")
    assert np.allclose(command[-1], plan.position[-1], atol=1e-7)  # float32 on the wire
    assert np.all(np.abs(record.get("command_acceleration")) <= AMAX * (1 + 1e-9))
    assert np.all(np.abs(np.diff(command, axis=0)) <= VMAX * 0.001 * (1 + 1e-9))


# -- MotoROS -------------------------------------------------------------------------------------


def moto_ctrl(command: int) -> bytes:
    return struct.pack("<iiiiiii10f", 64, MOTO_CTRL, 2, 0, 0, 0, command, *[0.0] * 10)


def result(frame: Any) -> tuple[int, int]:
    assert frame.msg_type == MOTO_REPLY
    return frame.ints(5)[3:5]  # type: ignore[no-any-return]


async def stream_motoros(plan: Plan) -> tuple[Recorder, int, int]:
    """JOINT_TRAJ_PT_FULL as motoman_driver sends it (time, positions, velocities, accelerations);
    BUSY: the same point again one interpolation period later."""
    async with stepped(profile="motoros") as (emu, clock, record):
        motion = await RawPeer.connect(emu.ports["motion"])
        assert result(await motion.request(moto_ctrl(START_TRAJ_MODE))) == (0, 0)
        assert result(await motion.request(moto_ctrl(CHECK_MOTION_READY))) == (0, 0)
        accepted = busy = 0
        for i in range(plan.count):
            frame = joint_traj_pt_full(
                JTPF,
                0,
                i,
                ALL_FIELDS,
                float(plan.time[i]),
                plan.position[i].tolist(),
                plan.velocity[i].tolist(),
                accelerations=plan.acceleration[i].tolist(),
            )
            while True:
                code, subcode = result(await motion.request(frame))
                if code != 1:
                    break
                busy += 1
                await step(clock, 0.004)
            assert code == 0, (i, code, subcode)
            accepted += 1
            queued = result(await motion.request(moto_ctrl(CHECK_QUEUE_CNT)))
            assert queued[0] == 0 and 0 <= queued[1] <= 200
        await settle(emu, clock)
        await motion.close()
    return record, accepted, busy


@pytest.mark.parametrize("duration", [2.0, 1.0])
async def test_motoros_runs_a_full_stream_with_the_planned_accelerations(duration: float) -> None:
    plan = Plan.make(duration, 101)
    record, accepted, busy = await stream_motoros(plan)
    assert accepted == plan.count and busy > 0  # the 200-increment buffer fills: BUSY, as an FS100 says
    m = measure(record, MODEL, plan, 4)
    assert abs(m.executed - duration) <= 0.02 * duration and m.stops == 0 and m.final_error <= 1e-7
    assert m.deviation_command <= 0.05e-3 and m.start <= 0.010
    # MotoROS's cubic from positions and velocities: the planned accelerations, to 5 %
    assert abs(m.peak_acceleration / plan.peak_acceleration - 1.0) <= 0.05


async def test_motoros_runs_a_stream_too_fast_for_the_acceleration_limit_as_given_and_never_answers_3014(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """1.8x faster than the acceleration limit allows, on a whole-millisecond grid (MotoROS cuts
    times to whole milliseconds): MotoROS never refuses a point for its acceleration (3014 is
    defined and never sent) and runs the cubics between the points as they are (it checks their
    speeds only, MotionServer.c:1313); so does the emulator, in the plan's time, and says so once."""
    plan = Plan.make(0.42, 43)  # a point every 10 ms
    assert 1.79 < plan.peak_acceleration / float(AMAX.min()) < 1.83
    with caplog.at_level(logging.WARNING, logger="robot_server.control.motion"):
        record, accepted, _busy = await stream_motoros(plan)
    assert accepted == plan.count
    m = measure(record, MODEL, plan, 4)
    assert m.executed / plan.duration <= 1.02 and m.stops == 0
    peak = float(np.max(np.abs(record.get("command_acceleration")) / AMAX))
    assert 1.5 < peak < 3.0  # the cubics through the plan's points (1.8x at the points), beyond the limit
    lines = [r.getMessage() for r in caplog.records if r.name == "robot_server.control.motion"]
    assert len([line for line in lines if "run as given" in line]) == 1, lines
    assert not [line for line in lines if "too fast" in line], lines


async def test_motoros_drives_follow_the_increments_of_points_sent_without_velocities() -> None:
    """Points 4 ms apart with zero velocities (a rest-to-rest cubic each, hundreds of times the
    acceleration limit between instants that fall on the points): MotoROS sends the drives the
    increments only, 6 mrad every 4 ms, a steady 1.5 rad/s; the emulator's drives take their
    velocity from the increments too (``increment_feedforward``), so they follow without a
    following-error alarm, in the points' time."""
    n, step = 100, 0.006
    time = np.arange(n) * 0.004
    position = np.zeros((n, 6))
    position[:, 0] = np.arange(n) * step
    plan = Plan(float(time[-1]), n, np.zeros(6), time, position, np.zeros((n, 6)), np.zeros((n, 6)))
    record, accepted, _busy = await stream_motoros(plan)  # every point SUCCESS: no alarm refused one
    assert accepted == n
    assert float(np.max(np.abs(record.get("following_error")))) < 0.01
    command = record.get("command_position")
    moving = np.flatnonzero(np.any(np.abs(np.diff(command, axis=0)) > 1e-12, axis=1))
    assert (moving[-1] - moving[0] + 1) * 0.001 == pytest.approx(plan.duration, abs=0.005)


def test_motoros_milliseconds_truncate_as_motoros_and_are_exact_on_a_grid() -> None:
    """(int)(time * 1000) with a float time truncates; a time on a clean grid, rounded to float32 on
    the wire, is its whole millisecond, neither short nor long, up to MotoROS's 14400 s (MotoROS
    itself comes up a millisecond short on some: float32(16.06) * 1000 is 16059.999...)."""
    assert motoros_milliseconds(float(np.float32(0.02))) == 20
    assert math.floor(float(np.float32(0.02)) * 1000.0) == 19  # what truncating the double gives
    assert int(np.float32(16.06) * np.float32(1000.0)) == 16059  # what MotoROS computes
    assert motoros_milliseconds(float(np.float32(16.06))) == 16060
    assert motoros_milliseconds(float(np.float32(1.004))) == 1004
    # every 7 ms for an hour, every 997 ms up to MotoROS's 14400 s (float32 resolves 1 ms only just
    # there), and the 1 ms grid for 100 s
    for whole in (np.arange(0, 3_600_000, 7), np.arange(0, 14_400_000, 997), np.arange(100_000)):
        wire = np.float32(whole / 1000.0)
        got = np.array([motoros_milliseconds(float(t)) for t in wire])
        assert np.array_equal(got, whole)
    # anything else is truncated as MotoROS truncates it
    assert motoros_milliseconds(0.0199) == 19 and motoros_milliseconds(0.0199999) == 19
    assert motoros_milliseconds(1.5e-3) == 1 and motoros_milliseconds(0.0) == 0
    assert motoros_milliseconds(2.9999) == 2999


async def test_motoros_ignores_the_slots_beyond_the_group_and_the_generic_server_does_not() -> None:
    seven = [0.0] * 6 + [0.7]  # a value in slot 7 of a 6-axis group
    async with stepped(profile="motoros") as (emu, clock, _record):
        motion = await RawPeer.connect(emu.ports["motion"])
        assert result(await motion.request(moto_ctrl(START_TRAJ_MODE))) == (0, 0)
        frame = joint_traj_pt_full(JTPF, 0, 0, 7, 0.0, seven, [0.0] * 7)
        assert result(await motion.request(frame)) == (0, 0)
        # a point that moves, with garbage in slots 7-10: the robot goes to the 6 axes' target
        target = [0.1, -0.1, 0.05, 0.0, 0.2, -0.2]
        moving = joint_traj_pt_full(JTPF, 0, 1, 7, 0.5, [*target, 9.0, -9.0, 1e30, -1e30], [0.0] * 10)
        assert result(await motion.request(moving)) == (0, 0)
        await settle(emu, clock)
        assert np.allclose(emu.cell.groups[0].command.command_position, target, atol=1e-6)
        await motion.close()
    async with stepped() as (emu, _clock, _record):
        motion = await RawPeer.connect(emu.ports["motion"])
        assert (await motion.request(joint_traj_pt(JTP, 0, seven))).reply_code == 2  # FAILURE
        await motion.close()


async def test_motoros_dh_parameters_are_4_groups_of_8_axes() -> None:
    async with stepped(profile="motoros") as (emu, _clock, _record):
        motion = await RawPeer.connect(emu.ports["motion"])
        reply = await motion.request(struct.pack("<iiii", 12, 2020, 2, 0))
        await motion.close()
    assert reply.msg_type == 2020 and reply.reply_code == 1 and len(reply.body) == 4 * 8 * 16
    links = np.array(struct.unpack("<128f", reply.body)).reshape(4, 8, 4)  # theta, d, a, alpha
    assert np.allclose(links[0, 0], [0.0, 0.339, 0.0, 0.0]) and np.allclose(links[0, 2, 2], 0.25)
    assert not links[0, 6:].any() and not links[1:].any()
