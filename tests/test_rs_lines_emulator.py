"""The project's extensions on the emulator's ports, driven with raw bytes over loopback TCP:
CARTESIAN_LINE (65001) on the motion port, TOOL_POSE (65002) on the state port for the clients
that ask, the supervision of a cell file, and MANUAL mode with motion allowed.

The controller runs on a clock the test advances (tests/stepped.py)."""

from __future__ import annotations

import contextlib
import os
import struct

import numpy as np
import pytest

from robot_server.kinematics import fk, rotation_to_quaternion
from robot_server.loader import load_model
from robot_server.workspace import FORBIDDEN_ZONE_ALARM, Box, Supervision
from simple_message.constants import RobotMode
from simple_message.transport import open_fd
from tests.rawpeer import Frame, RawPeer, status
from tests.stepped import advance_until, poll, settle, step, stepped_emulator

MODEL = load_model("jibot_zxs")
LINE, TOOL_POSE, STATUS, JOINT_POSITION, PING = 65001, 65002, 13, 10, 1
REQUEST, REPLY, TOPIC = 2, 3, 1
SUCCESS, FAILURE = 1, 2
START = (0.0, 0.3, -0.6, 0.0, 0.8, 0.0)


def line(seq: int, position: object, quaternion_wxyz: object, speed: float = 0.2, blend: float = 0.0) -> bytes:
    x, y, z = (float(v) for v in np.asarray(position).reshape(3))
    w, qx, qy, qz = (float(v) for v in np.asarray(quaternion_wxyz).reshape(4))
    body = struct.pack("<ii9f", 0, seq, x, y, z, qx, qy, qz, w, speed, blend)
    return struct.pack("<iiii", 12 + len(body), LINE, REQUEST, 0) + body


def line_reply(frame: Frame) -> tuple[int, int, int, int]:
    """(reply_code, robot_id, sequence, result) of a CARTESIAN_LINE reply."""
    assert frame.msg_type == LINE and frame.comm_type == REPLY and len(frame.body) == 12, frame.raw.hex()
    return (frame.reply_code, *frame.ints(3))  # type: ignore[return-value]


def pose_of(q: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    t = fk(MODEL, q)
    return t[:3, 3], rotation_to_quaternion(t)


async def test_lines_are_run_answered_and_refused_with_their_reason() -> None:
    async with stepped_emulator(initial_position=START) as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        p0, r0 = pose_of(START)
        assert line_reply(await motion.request(line(0, p0 + np.array([0.05, 0.0, 0.0]), r0))) == (SUCCESS, 0, 0, 0)
        assert line_reply(await motion.request(line(1, p0 + np.array([0.05, 0.05, 0.0]), r0))) == (SUCCESS, 0, 1, 0)
        # out of order: SEQUENCE (4); out of reach: UNREACHABLE (10); a bad quaternion: INVALID (3)
        assert line_reply(await motion.request(line(5, p0, r0))) == (FAILURE, 0, 5, 4)
        assert line_reply(await motion.request(line(2, p0 + np.array([2.0, 0.0, 0.0]), r0))) == (FAILURE, 0, 2, 10)
        assert line_reply(await motion.request(line(2, p0, r0 * 3))) == (FAILURE, 0, 2, 3)
        await settle(emu, clock)
        tcp = emu.cell.groups[0].tool
        assert np.allclose(tcp.command_position, p0 + np.array([0.05, 0.05, 0.0]), atol=1e-9)
        await motion.close()


async def test_a_stop_brakes_a_line_at_once_and_joint_points_wait_for_lines_to_end() -> None:
    async with stepped_emulator(initial_position=START) as (emu, clock):
        ctl = emu.cell.groups[0]
        motion = await RawPeer.connect(emu.ports["motion"])
        p0, r0 = pose_of(START)
        assert line_reply(await motion.request(line(0, p0 + np.array([0.15, 0.0, 0.0]), r0, 0.25)))[0] == SUCCESS
        await step(clock, 0.3)
        assert ctl.moving
        # a joint point meanwhile is refused (FAILURE), nothing changes
        point = struct.pack("<iiii", 12 + 52, 11, REQUEST, 0) + struct.pack("<i10f2f", 0, *START, 0, 0, 0, 0, 0.5, 0)
        assert (await motion.request(point)).reply_code == FAILURE
        assert line_reply(await motion.request(line(-4, p0, r0))) == (SUCCESS, 0, -4, 0)
        await settle(emu, clock)
        stopped = np.array(ctl.tool.command_position)
        assert 0.01 < float(np.linalg.norm(stopped - p0)) < 0.15 - 1e-3  # short of the end
        assert np.allclose(stopped[1:], p0[1:], atol=1e-8)  # on the line
        # the next series starts at 0
        assert line_reply(await motion.request(line(1, p0, r0)))[3] == 4
        assert line_reply(await motion.request(line(0, p0, r0)))[0] == SUCCESS
        await motion.close()


async def test_tool_pose_goes_only_to_the_state_clients_that_ask() -> None:
    async with stepped_emulator(initial_position=START) as (emu, clock):
        plain = await RawPeer.connect(emu.ports["state"])
        asking = await RawPeer.connect(emu.ports["state"])
        subscribe = struct.pack("<iiii", 12 + 44, TOOL_POSE, REQUEST, 0) + struct.pack("<ii9f", *[0] * 11)
        reply = await asking.reply_to(subscribe)
        assert (reply.msg_type, reply.reply_code) == (TOOL_POSE, SUCCESS)
        await step(clock, 0.1)
        pose = await asking.next_of(TOOL_POSE)
        assert pose.comm_type == TOPIC and len(pose.body) == 44
        robot_id, tool = pose.ints(2)
        t, x, y, z, qx, qy, qz, qw, speed = pose.reals(9, 8)
        p0, r0 = pose_of(START)
        assert (robot_id, tool) == (0, 0) and t > 0.0 and speed == 0.0
        assert np.allclose((x, y, z), p0, atol=1e-6) and np.allclose((qw, qx, qy, qz), r0, atol=1e-6)
        # the plain client gets JOINT_POSITION and STATUS only
        for _ in range(6):
            assert (await plain.frame()).msg_type in (JOINT_POSITION, STATUS)
        for peer in (plain, asking):
            await peer.close()


async def test_the_motoros_profile_does_not_know_the_extension() -> None:
    async with stepped_emulator(profile="motoros") as (emu, _):
        motion = await RawPeer.connect(emu.ports["motion"])
        p0, r0 = pose_of(tuple([0.0] * 6))
        reply = await motion.request(line(0, p0, r0))
        assert reply.msg_type == 2002  # MotoROS's MOTO_MOTION_REPLY, not a CARTESIAN_LINE reply
        await motion.close()


async def test_a_cell_file_forbids_a_zone_and_its_alarm_reaches_status() -> None:
    async with stepped_emulator(initial_position=START) as (emu, clock):
        ctl = emu.cell.groups[0]
        p0, r0 = pose_of(START)
        ctl.supervision = Supervision(
            forbidden=(Box(tuple(p0 + np.array([0.04, -0.01, -0.01])), tuple(p0 + np.array([0.05, 0.01, 0.01]))),)
        )
        motion = await RawPeer.connect(emu.ports["motion"])
        state = await RawPeer.connect(emu.ports["state"])
        assert line_reply(await motion.request(line(0, p0 + np.array([0.1, 0, 0]), r0))) == (
            FAILURE,
            0,
            0,
            13,
        )  # WORKSPACE
        # the zone moves onto the tool (a wrong cell): alarm, drives off
        ctl.supervision = Supervision(forbidden=(Box(tuple(p0 - 0.01), tuple(p0 + 0.01), "cart"),))
        await step(clock, 0.01)
        seen = status(await state.next_of(STATUS))
        await advance_until(clock, lambda: emu.cell.error_code != 0)
        while seen["error_code"] == 0:
            seen = status(await state.next_of(STATUS))
        assert seen["error_code"] == FORBIDDEN_ZONE_ALARM + 1 and seen["in_error"] == 1 and seen["drives_powered"] == 0
        for peer in (motion, state):
            await peer.close()


@pytest.mark.parametrize("manual_motion", [False, True])
async def test_manual_mode_refuses_points_or_slows_them_to_the_reduced_speed(manual_motion: bool) -> None:
    async with stepped_emulator(initial_position=START, manual_motion=manual_motion, record=30.0) as (emu, clock):
        emu.cell.set_mode(RobotMode.MANUAL)
        motion = await RawPeer.connect(emu.ports["motion"])
        state = await RawPeer.connect(emu.ports["state"])
        await step(clock, 0.1)
        seen = status(await state.next_of(STATUS))
        assert seen["mode"] == 1 and seen["motion_possible"] == (1 if manual_motion else 0)
        p0, r0 = pose_of(START)
        reply = line_reply(await motion.request(line(0, p0 + np.array([0.1, 0.1, 0.0]), r0, speed=1.0)))
        if not manual_motion:
            assert reply == (FAILURE, 0, 0, 1)  # NOT_READY
            return
        assert reply == (SUCCESS, 0, 0, 0)
        await settle(emu, clock)
        recorder = emu.control.recorder
        assert recorder is not None
        tool = recorder.tool()
        assert 0.2 < float(np.nanmax(tool[:, 7])) <= 0.25 and float(np.nanmax(tool[:, 15])) <= 0.25
        for peer in (motion, state):
            await peer.close()


async def test_a_serial_link_subscribes_to_tool_pose_and_runs_lines() -> None:
    master, slave = os.openpty()
    try:
        async with stepped_emulator(serial=os.ttyname(slave), state_rate=50.0, initial_position=START) as (emu, clock):
            await poll(lambda: bool(emu.motion_server.sessions))
            reader, writer = await open_fd(master, close_fd=False, name="pty master")
            link = RawPeer(reader, writer)
            subscribe = struct.pack("<iiii", 12 + 44, TOOL_POSE, REQUEST, 0) + struct.pack("<ii9f", *[0] * 11)
            await link.send(subscribe)
            reply = await link.next_of(TOOL_POSE)
            assert (reply.comm_type, reply.reply_code) == (REPLY, SUCCESS)
            p0, r0 = pose_of(START)
            await link.send(line(0, p0 + np.array([0.02, 0.0, 0.0]), r0))
            answer = await link.next_of(LINE)
            assert line_reply(answer) == (SUCCESS, 0, 0, 0)
            await settle(emu, clock)
            await step(clock, 0.1)
            while True:  # the poses published before the line ended are skipped
                pose = await link.next_of(TOOL_POSE)
                if pose.comm_type == TOPIC and abs(pose.reals(1, 12)[0] - (p0[0] + 0.02)) < 1e-5:
                    break
            writer.close()
    finally:
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)


async def test_a_tcp_motion_client_cannot_subscribe_on_the_motion_port() -> None:
    async with stepped_emulator() as (emu, _):
        motion = await RawPeer.connect(emu.ports["motion"])
        subscribe = struct.pack("<iiii", 12 + 44, TOOL_POSE, REQUEST, 0) + struct.pack("<ii9f", *[0] * 11)
        reply = await motion.request(subscribe)
        assert (reply.msg_type, reply.comm_type, reply.reply_code, reply.body) == (TOOL_POSE, REPLY, FAILURE, b"")
        await motion.close()
