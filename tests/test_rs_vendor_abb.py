"""The ABB profile against raw sockets, on a stepped clock: what abb_driver's RAPID servers do
(robot_server/emulator/abb.py has the rules, docs/vendors.md their file:line)."""

from __future__ import annotations

import logging
import math
import struct

import numpy as np
import pytest

from robot_server.emulator import EmulatorConfig
from robot_server.emulator.abb import ABB_BUFFER
from tests.rawpeer import joint_traj_pt, vectors
from tests.stepped import step
from tests.vendor import connect, logged, until, vendor_emulator, written

V = vectors("<")
JTP = V["JOINT_TRAJ_PT_REQUEST_SEQ3"]
TOPIC = V["JOINT_TRAJ_PT_TOPIC_SEQ3"]
PING = V["PING_REQUEST"]
ACK = bytes.fromhex("0c0000000b0000000300000001000000")  # JOINT_TRAJ_PT, SERVICE_REPLY, SUCCESS, no body
START, END, STOP = -1, -3, -4


def point(seq: int, q: list[float], duration: float, *, topic: bool = False, velocity: float = 0.7) -> bytes:
    return joint_traj_pt(TOPIC if topic else JTP, seq, q, velocity, duration)


def ramp(a: list[float], b: list[float], n: int) -> list[list[float]]:
    return [[x + (y - x) * k / (n - 1) for x, y in zip(a, b, strict=True)] for k in range(n)]


def download(path: list[list[float]], duration: float, *, topic: bool = False) -> list[bytes]:
    """What abb_driver's downloader sends: -1, 1..n-2, -3, each point's duration."""
    out = []
    for k, q in enumerate(path):
        seq = START if k == 0 else END if k == len(path) - 1 else k
        out.append(point(seq, q, 0.0 if k == 0 else duration, topic=topic))
    return out


def position(emu: object) -> np.ndarray:
    return np.array(emu.cell.groups[0].command.command_position)  # type: ignore[attr-defined]


HOME = [0.0] * 6
GOAL = [0.3, -0.2, 0.25, 0.4, -0.3, 0.5]


async def test_a_download_runs_on_its_durations_and_every_request_gets_a_header_only_success() -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        path = ramp(HOME, GOAL, 11)
        for frame in download(path, 0.2):
            await motion.send(frame)
        await until(clock, lambda: len(written(wire, "motion")) == 11, what="11 replies")
        assert [f for _, f in written(wire, "motion")] == [ACK] * 11
        begun = emu.cell.time
        # the robot runs the ten 0.2 s segments: at the goal 2 s after the hand-over, not before
        await until(clock, lambda: not emu.cell.in_motion, limit=10.0, what="the motion's end")
        assert np.max(np.abs(position(emu) - GOAL)) < 1e-6
        assert 2.0 - 0.01 <= emu.cell.time - begun <= 2.0 + 0.15  # + the settling of the drives


async def test_a_topic_gets_no_reply_and_nothing_runs_before_the_end_point() -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        path = ramp(HOME, GOAL, 4)
        frames = download(path, 0.25, topic=True)
        for frame in frames[:-1]:
            await motion.send(frame)
        await motion.send(point(7, GOAL, 0.25))  # a request: the first (and only) reply is its
        await until(clock, lambda: len(written(wire, "motion")) == 1, what="the request's reply")
        await step(clock, 0.5)
        assert not emu.cell.in_motion  # without -3 nothing runs, whatever the sequence numbers
        await motion.send(frames[-1])
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        await until(clock, lambda: not emu.cell.in_motion, limit=10.0, what="the end")
        assert len(written(wire, "motion")) == 1
        assert np.max(np.abs(position(emu) - GOAL)) < 1e-6  # -1, 1, 2, 7 (GOAL), -3: ends at the last point


async def test_more_than_100_points_run_the_first_100_and_one_warning_says_so(caplog: pytest.LogCaptureFixture) -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        path = ramp(HOME, GOAL, ABB_BUFFER + 5)
        with caplog.at_level(logging.WARNING, "robot_server.emulator.abb"):
            for frame in download(path, 0.01):
                await motion.send(frame)
            await until(clock, lambda: len(written(wire, "motion")) == ABB_BUFFER + 5, what="every reply")
            await until(clock, lambda: not emu.cell.in_motion, limit=20.0, what="the end")
        assert [f for _, f in written(wire, "motion")] == [ACK] * (ABB_BUFFER + 5)  # all SUCCESS, all the same
        assert np.max(np.abs(position(emu) - np.array(path[ABB_BUFFER - 1]))) < 1e-6  # point 100, not the goal
        assert np.max(np.abs(position(emu) - np.array(GOAL))) > 1e-3
        assert logged(caplog, "holds 100 points (MAX_TRAJ_LENGTH): 5 points") == 1


async def test_the_end_point_adds_to_the_old_buffer_unless_a_start_came() -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        first = ramp(HOME, GOAL, 3)
        for frame in download(first, 0.3):
            await motion.send(frame)
        await until(clock, lambda: not emu.cell.in_motion and len(written(wire, "motion")) == 3, limit=10.0)
        # two more points and an END, no -1: the buffer is HOME, mid, GOAL, GOAL2, GOAL3: it runs from HOME again
        goal2 = [x + 0.1 for x in GOAL]
        await motion.send(point(5, goal2, 0.3))
        await motion.send(point(END, HOME, 0.3))
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        seen = []
        while emu.cell.in_motion:
            await step(clock, 0.02)
            seen.append(position(emu))
            assert emu.cell.time < 60.0
        # it went back to HOME (the first point, 10 s away at its duration 0: as fast as the joints
        # allow), through GOAL and goal2, and ended at HOME
        assert min(np.max(np.abs(p - np.array(goal2))) for p in seen) < 0.02
        assert np.max(np.abs(position(emu))) < 1e-6


async def test_stop_decelerates_empties_the_buffer_and_does_not_latch() -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        for frame in download(ramp(HOME, GOAL, 5), 1.0):
            await motion.send(frame)
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.05, what="the motion")
        await motion.send(point(STOP, [9.0] * 6, 0.0))  # its point is not added (nor checked)
        await until(clock, lambda: len(written(wire, "motion")) == 6, what="STOP's reply")
        assert written(wire, "motion")[-1][1] == ACK
        await until(clock, lambda: not emu.cell.in_motion, what="the stop")
        stopped = position(emu)
        assert np.max(np.abs(stopped - np.array(GOAL))) > 0.1
        # a new download runs (its first point is where the robot stopped: skipped)
        back = ramp(list(stopped), HOME, 3)
        for frame in download(back, 0.4):
            await motion.send(frame)
        await until(clock, lambda: not emu.cell.in_motion and np.max(np.abs(position(emu))) < 1e-6, limit=10.0)


async def test_a_new_end_pre_empts_the_running_trajectory_from_where_it_stopped() -> None:
    async with vendor_emulator("abb") as (emu, clock, _wire):
        motion = await connect(emu, "motion")
        for frame in download(ramp(HOME, GOAL, 5), 1.0):
            await motion.send(frame)
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.1, what="the motion")
        other = [-0.2, 0.1, -0.1, 0.0, 0.2, -0.3]
        here = list(position(emu))
        for frame in download([here, other], 1.5):  # its first point: where the robot is as it arrives
            await motion.send(frame)
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0, what="the new trajectory's end")
        assert np.max(np.abs(position(emu) - np.array(other))) < 1e-6


async def test_a_first_point_within_a_tenth_of_a_degree_is_skipped_else_reached_in_its_duration() -> None:
    async with vendor_emulator("abb") as (emu, clock, _wire):
        motion = await connect(emu, "motion")
        near = [math.radians(0.09)] * 6  # within 0.1 degree: the start itself
        await motion.send(point(START, near, 5.0))
        await motion.send(point(END, GOAL, 1.0))
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        begun = emu.cell.time
        await until(clock, lambda: not emu.cell.in_motion, limit=10.0)
        assert emu.cell.time - begun < 1.2  # the first point's 5 s did not count
        far = [x + math.radians(0.2) for x in GOAL]  # 0.2 degree away: MoveAbsJ there in its 2 s
        await motion.send(point(START, far, 2.0))
        await motion.send(point(END, HOME, 1.0))
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        begun = emu.cell.time
        await until(clock, lambda: np.max(np.abs(position(emu) - np.array(far))) < 1e-4, limit=10.0)
        assert emu.cell.time - begun >= 1.9
        await until(clock, lambda: not emu.cell.in_motion, limit=10.0)
        assert emu.cell.time - begun >= 2.9


@pytest.mark.parametrize("bad", [-0.5, math.nan], ids=["negative", "nan"])
async def test_a_point_whose_duration_movabsj_cannot_take_aborts_the_trajectory_there(
    bad: float, caplog: pytest.LogCaptureFixture
) -> None:
    path = ramp(HOME, GOAL, 5)
    frames = download(path, 0.5)
    frames[3] = point(3, path[3], bad)
    async with vendor_emulator("abb") as (emu, clock, _wire):
        motion = await connect(emu, "motion")
        with caplog.at_level(logging.WARNING):
            for frame in frames:
                await motion.send(frame)
            await until(clock, lambda: emu.cell.in_motion, what="the motion")
            await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - np.array(path[2]))) < 1e-6  # the points before it ran
        assert logged(caplog, "point 4 of 5") == 1


async def test_a_lost_motion_client_does_not_stop_the_motion_and_the_buffer_is_kept() -> None:
    async with vendor_emulator("abb") as (emu, clock, _wire):
        motion = await connect(emu, "motion")
        for frame in download(ramp(HOME, GOAL, 4), 0.5):
            await motion.send(frame)
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        await motion.close()
        await until(clock, lambda: not emu.motion_server.sessions, what="the session's end")
        await until(clock, lambda: not emu.cell.in_motion, limit=10.0)
        assert np.max(np.abs(position(emu) - np.array(GOAL))) < 1e-6  # it ran to the goal
        # the next client's END runs the kept buffer plus its point
        again = await connect(emu, "motion")
        await again.send(point(END, HOME, 0.5))
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu))) < 1e-6


async def test_an_unexpected_message_stops_the_rapid_server_until_the_operators_reset(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        with caplog.at_level(logging.INFO):
            await motion.send(PING)
            await motion.send(point(0, HOME, 0.0))
            await step(clock, 0.5)
            waiting = await connect(emu, "motion")  # a second client: in the backlog, unserved
            await waiting.send(point(0, HOME, 0.0))
            await step(clock, 0.5)
            assert written(wire, "motion") == []  # nothing answered: the PING, the point, the newcomer
            assert logged(caplog, "the RAPID motion server stops", logging.ERROR) == 1
            await motion.close()
            await step(clock, 0.5)
            assert written(wire, "motion") == []  # the task is still stopped: nothing is read
            emu.command("reset")  # the operator restarts the program: its UNDO closes the sockets
            assert await waiting.closed()
            again = await connect(emu, "motion")  # the new listening socket serves a new connect
            await again.send(point(0, HOME, 0.0))
            await until(clock, lambda: len(written(wire, "motion")) == 1, what="the new client's reply")
        assert written(wire, "motion")[0][1] == ACK


async def test_lenient_drops_the_unexpected_message_and_goes_on(caplog: pytest.LogCaptureFixture) -> None:
    async with vendor_emulator("abb", lenient=True) as (emu, clock, wire):
        motion = await connect(emu, "motion")
        with caplog.at_level(logging.WARNING):
            await motion.send(PING)
            await motion.send(point(0, HOME, 0.0))
            await until(clock, lambda: len(written(wire, "motion")) == 1, what="the point's reply")
        assert logged(caplog, "dropped (--lenient)") == 1


async def test_a_length_rapid_cannot_read_stops_the_server_too(caplog: pytest.LogCaptureFixture) -> None:
    async with vendor_emulator("abb") as (emu, clock, _wire):
        motion = await connect(emu, "motion")
        with caplog.at_level(logging.ERROR):
            await motion.send(struct.pack("<i", 2000) + bytes(100))
            await step(clock, 0.2)
        assert logged(caplog, "length prefix 2000", logging.ERROR) == 1


async def test_state_joint_position_then_status_every_tenth_of_a_second_one_write_each() -> None:
    async with vendor_emulator("abb") as (emu, _clock, wire):
        assert emu.config.rate == 10.0
        state = await connect(emu, "state")
        kinds = []
        for _ in range(6):
            frame = await state.frame()
            kinds.append(frame.msg_type)
            if frame.msg_type == 10:
                assert frame.ints(1)[0] == 0 and frame.length == 56  # sequence 0
            else:
                assert frame.length == 40
        start = kinds.index(10)
        assert kinds[start : start + 4] == [10, 13, 10, 13]
        assert all(len(chunk) in (60, 44) for _, chunk in wire.out("state"))  # one message per write


async def test_one_motion_client_a_second_waits_and_is_reset_when_the_first_goes(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with vendor_emulator("abb") as (emu, clock, wire):
        first = await connect(emu, "motion")
        second = await connect(emu, "motion")
        await second.send(point(0, HOME, 0.0))
        await first.send(point(0, HOME, 0.0))
        await until(clock, lambda: len(written(wire, "motion")) == 1, what="the first client's reply")
        await step(clock, 0.2)
        assert len(written(wire, "motion")) == 1  # the second is not served
        with caplog.at_level(logging.WARNING):
            await first.close()
            assert await second.closed()  # the old listening socket's backlog is gone
        assert logged(caplog, "closes its listening socket") == 1
        third = await connect(emu, "motion")
        await third.send(point(0, HOME, 0.0))
        await until(clock, lambda: len(written(wire, "motion")) == 2, what="a new client served")


async def test_the_state_port_serves_the_waiting_client_when_the_first_goes() -> None:
    async with vendor_emulator("abb") as (emu, clock, _wire):
        first = await connect(emu, "state")
        second = await connect(emu, "state")
        await first.frame()
        await first.close()
        await step(clock, 0.2)
        assert (await second.frame()).msg_type in (10, 13)  # RAPID's state server keeps its socket


@pytest.mark.parametrize("options", [{"byte_order": "big"}, {"float64": True}, {"reply_style": "echo"}])
def test_the_wire_is_rapids_own(options: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="abb controller"):
        EmulatorConfig(profile="abb", **options)  # type: ignore[arg-type]


def test_one_robot_only() -> None:
    from robot_server.emulator import Emulator

    with pytest.raises(ValueError, match="one robot"):
        Emulator(EmulatorConfig(profile="abb", models=("jibot_zxs", "puma560")))
