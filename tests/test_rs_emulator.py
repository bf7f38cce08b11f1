"""The emulator in process, driven with raw bytes: queue flow control, STOP, MotoROS, malformed
frames, byte orders, float64, serial links, multi-group, IO, faults and many state clients.

The controller runs on a clock the test advances (tests/stepped.py): what is asserted at a
controller time holds however fast or loaded the machine is."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import re
import struct
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest

from robot_server.control import SteppedClock
from robot_server.control import loop as loop_module
from robot_server.emulator import Emulator, EmulatorConfig, FaultError, IoTable, apply_fault_command
from simple_message.transport import open_fd
from tests.rawpeer import Frame, RawPeer, joint_position, joint_traj_pt, joint_traj_pt_full, status, vectors
from tests.refdata import load_segments
from tests.stepped import advance_until, poll, settle, step, stepped_emulator

LE = vectors("<")
BE = vectors(">")
PING_REPLY = LE["PING_REPLY_SUCCESS"]
JTP, STOP = LE["JOINT_TRAJ_PT_REQUEST_SEQ3"], LE["JOINT_TRAJ_PT_REQUEST_STOP_ALLZERO"]
JOINT_POSITION, JOINT_TRAJ_PT, STATUS, JTPF, JOINT_FEEDBACK = 10, 11, 13, 14, 15
MOTO_CTRL, MOTO_REPLY, FEEDBACK_EX = 2001, 2002, 2017
CHECK_MOTION_READY, CHECK_QUEUE_CNT, STOP_MOTION = 200101, 200102, 200111
START_SERVOS, STOP_SERVOS, RESET_ALARM = 200112, 200113, 200114
START_TRAJ_MODE, STOP_TRAJ_MODE, DISCONNECT = 200121, 200122, 200130


@contextlib.asynccontextmanager
async def emulator(**options: Any) -> AsyncIterator[tuple[Emulator, SteppedClock]]:
    async with stepped_emulator(**options) as (emu, clock):
        yield emu, clock


def moto_ctrl(command: int, group: int = 0, order: str = "<") -> bytes:
    return struct.pack(order + "iiiiiii10f", 64, MOTO_CTRL, 2, 0, group, 0, command, *[0.0] * 10)


def moto_reply(frame: Frame) -> tuple[int, int, int, int, int]:
    """(group, sequence, command, result, subcode) of a MOTO_MOTION_REPLY."""
    assert frame.msg_type == MOTO_REPLY and frame.comm_type == 3 and frame.reply_code == 1, frame.raw.hex()
    return frame.ints(5)  # type: ignore[return-value]


async def next_status(peer: RawPeer, **expected: int) -> dict[str, int]:
    """The first STATUS with the ``expected`` fields (earlier, buffered ones are skipped)."""
    async with asyncio.timeout(10.0):
        while True:
            seen = status(await peer.next_of(STATUS))
            if all(seen[k] == v for k, v in expected.items()):
                return seen


# -- generic profile ---------------------------------------------------------------------------------


async def test_full_queue_delays_the_reply_and_a_stop_still_gets_through() -> None:
    async with emulator(queue_capacity=3) as (emu, clock):
        ctl = emu.cell.groups[0]
        motion = await RawPeer.connect(emu.ports["motion"])
        other = await RawPeer.connect(emu.ports["state"])  # the motion port takes one client
        points = [[0.1 * k] * 6 for k in range(6)]
        assert (await motion.request(joint_traj_pt(JTP, 0, points[0]))).reply_code == 1
        for seq in (1, 2, 3):  # 1 s each: three fill the queue
            assert (await motion.request(joint_traj_pt(JTP, seq, points[seq], 0.0, 1.0))).reply_code == 1
        assert ctl.queue_fill == 3
        # the fourth waits for room: its reply comes only once the first segment has run
        await motion.send(joint_traj_pt(JTP, 4, points[4], 0.0, 1.0))
        reply = asyncio.ensure_future(motion.frame(timeout=30.0))
        await advance_until(clock, reply.done, limit=5.0, what="the reply to the fourth point")
        assert (await reply).reply_code == 1 and ctl.time >= 1.0
        # the fifth waits again; a STOP behind it is obeyed at once (no controller time passes
        # before both replies), and the waiting point is not run
        await motion.send(joint_traj_pt(JTP, 5, points[5], 0.0, 1.0))
        t_stop = ctl.time
        await motion.send(STOP)
        waiting, stopped = await motion.frame(), await motion.frame()
        assert (struct.unpack_from("<i", waiting.raw, 16)[0], waiting.reply_code) == (5, 2)
        assert (struct.unpack_from("<i", stopped.raw, 16)[0], stopped.reply_code) == (-4, 1)
        assert ctl.time == t_stop
        assert (await other.reply_to(LE["PING_REQUEST"])).raw == PING_REPLY  # the other client was never blocked
        await settle(emu, clock)
        assert ctl.queue_fill == 0
        assert np.all(np.array(ctl.command.actual_position) < points[4][0])  # stopped short of the queued points


async def test_a_refused_download_point_drops_the_whole_download() -> None:
    async with emulator() as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        topic = LE["JOINT_TRAJ_PT_TOPIC_SEQ3"]
        for seq, q in ((-1, [0.0] * 6), (1, [0.2] * 6), (2, [0.0, 3.0, 0, 0, 0, 0]), (3, [0.3] * 6), (-3, [0.4] * 6)):
            await motion.send(joint_traj_pt(topic, seq, q, 0.5))
        assert (await motion.request(LE["PING_REQUEST"])).raw == PING_REPLY  # no reply came to any topic
        await step(clock, 0.5)  # nothing starts later either
        assert not emu.cell.in_motion and not emu.cell.groups[0].downloading
        assert emu.cell.groups[0].queue_fill == 0 and emu.cell.groups[0].trajectories == 0
        assert emu.cell.groups[0].command.actual_position == [0.0] * 6


async def test_reply_style_header_is_abb_like() -> None:
    async with emulator(reply_style="header") as (emu, _clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        reply = await motion.request(joint_traj_pt(JTP, 0, [0.0] * 6, 0.5))
        assert reply.raw == LE["JOINT_TRAJ_PT_REPLY_SUCCESS"]
        unknown = struct.pack("<iiii", 12, 9999, 2, 0)
        assert (await motion.request(unknown)).raw == struct.pack("<iiii", 12, 9999, 3, 2)


async def test_faults_stop_motion_and_refuse_points_until_reset() -> None:
    async with emulator() as (emu, clock):
        cell, ctl = emu.cell, emu.cell.groups[0]
        motion = await RawPeer.connect(emu.ports["motion"])
        state = await RawPeer.connect(emu.ports["state"])
        await motion.request(joint_traj_pt(JTP, 0, [0.0] * 6))
        await motion.request(joint_traj_pt(JTP, 1, [1.0] * 6, 0.5))
        await advance_until(clock, lambda: ctl.command.actual_position[0] > 0.2, what="moving")
        apply_fault_command(cell, "estop")
        frozen = list(ctl.command.actual_position)
        t_estop = ctl.time
        await step(clock, 0.1)
        assert ctl.time >= t_estop + 0.1
        assert ctl.command.actual_position == frozen  # stopped at once: brakes, no deceleration ramp
        assert not cell.in_motion
        seen = await next_status(state, e_stopped=1)
        assert seen == {
            "drives_powered": 0,
            "e_stopped": 1,
            "error_code": 0,
            "in_error": 0,
            "in_motion": 0,
            "mode": 2,
            "motion_possible": 0,
        }
        assert (await motion.request(joint_traj_pt(JTP, 0, frozen[:6]))).reply_code == 2
        with pytest.raises(FaultError, match="emergency stop"):
            apply_fault_command(cell, "drives on")
        apply_fault_command(cell, "reset")
        assert (await motion.request(joint_traj_pt(JTP, 0, frozen[:6]))).reply_code == 1
        apply_fault_command(cell, "mode manual")
        await next_status(state, mode=1, motion_possible=0)
        assert (await motion.request(joint_traj_pt(JTP, 0, frozen[:6]))).reply_code == 2
        apply_fault_command(cell, "mode auto")
        apply_fault_command(cell, "drives off")
        await next_status(state, drives_powered=0, e_stopped=0, motion_possible=0)
        for bad in ("explode", "alarm x", "alarm -3", "drives sideways", ""):
            with pytest.raises(FaultError):
                apply_fault_command(cell, bad)


async def test_joint_feedback_for_clients_that_ask() -> None:
    async with emulator(state_rate=200.0) as (emu, clock):
        await step(clock, 0.25)
        plain = await RawPeer.connect(emu.ports["state"])
        asking = await RawPeer.connect(emu.ports["state"])
        request = bytearray(LE["JOINT_FEEDBACK_TOPIC"])
        struct.pack_into("<i", request, 8, 2)  # as a SERVICE_REQUEST: answered SUCCESS
        reply = await asking.reply_to(bytes(request))  # state topics flow meanwhile: skip them
        assert (reply.msg_type, reply.comm_type, reply.reply_code) == (JOINT_FEEDBACK, 3, 1)
        feedback = await asking.next_of(JOINT_FEEDBACK)
        assert feedback.ints(2) == (0, 0x0F)  # robot_id, valid_fields
        controller_time = emu.cell.groups[0].command.time
        assert feedback.reals(1, 8)[0] == np.float32(controller_time) and controller_time > 0.2
        kinds = {(await plain.frame()).msg_type for _ in range(10)}
        assert kinds == {JOINT_POSITION, STATUS}


async def test_fifty_state_clients_all_get_every_topic() -> None:
    async with emulator(state_rate=100.0) as (emu, _clock):
        peers = [await RawPeer.connect(emu.ports["state"]) for _ in range(50)]
        for peer in peers:
            kinds = [(await peer.frame()).msg_type for _ in range(6)]
            assert kinds.count(JOINT_POSITION) == 3 and kinds.count(STATUS) == 3
        assert len(emu.state_server.sessions) == 50  # nobody was dropped (the period is in bench/server.py)


# -- malformed input -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "garbage",
    [
        struct.pack("<i", 0) + bytes(12),  # length 0
        struct.pack("<i", -5) + bytes(12),  # negative
        struct.pack("<i", 7) + bytes(7),  # shorter than a header
        struct.pack("<i", 10_000_000) + bytes(64),  # beyond the maximum: never allocated
        bytes.fromhex("40000000") + bytes.fromhex("0b000000020000000000000001000000"),  # cut short, then EOF
    ],
    ids=["zero", "negative", "short", "huge", "truncated"],
)
async def test_malformed_frames_close_only_that_client_and_move_nothing(garbage: bytes) -> None:
    async with emulator() as (emu, clock):
        watcher = await RawPeer.connect(emu.ports["state"])
        bad = await RawPeer.connect(emu.ports["motion"])
        before = list(emu.cell.groups[0].command.actual_position)
        await bad.send(garbage)
        bad.writer.write_eof()
        assert await bad.closed()
        assert (await watcher.reply_to(LE["PING_REQUEST"])).raw == PING_REPLY  # still served
        good = await RawPeer.connect(emu.ports["motion"])
        assert (await good.request(LE["PING_REQUEST"])).raw == PING_REPLY
        assert (await good.request(joint_traj_pt(JTP, 0, [0.0] * 6))).reply_code == 1
        await step(clock, 0.1)
        assert not emu.cell.in_motion and emu.cell.groups[0].command.actual_position == before


async def test_malformed_bodies_and_bad_headers_get_failure_and_move_nothing() -> None:
    async with emulator() as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        short_body = struct.pack("<iiiii", 16, JOINT_TRAJ_PT, 2, 0, 1)  # a 4-byte JOINT_TRAJ_PT body
        assert (await motion.request(short_body)).reply_code == 2
        bad_header = bytearray(joint_traj_pt(JTP, 1, [0.5] * 6, 0.5))
        struct.pack_into("<i", bad_header, 12, 1)  # a request with reply_code SUCCESS (§1.2)
        assert (await motion.request(bytes(bad_header))).reply_code == 2
        nan = joint_traj_pt(JTP, 0, [float("nan")] * 6, 0.5)
        assert (await motion.request(nan)).reply_code == 2
        extra_joints = joint_traj_pt(JTP, 0, [0.0] * 6 + [0.3], 0.5)
        assert (await motion.request(extra_joints)).reply_code == 2
        assert (await motion.request(LE["PING_REQUEST"])).raw == PING_REPLY
        await step(clock, 0.1)
        assert not emu.cell.in_motion and emu.cell.groups[0].queue_fill == 0
        assert emu.cell.groups[0].command.actual_position == [0.0] * 6


# -- wire formats and links ------------------------------------------------------------------------------


async def _stream_and_watch(
    emu: Emulator, clock: SteppedClock, motion: RawPeer, state: RawPeer, jtp: bytes, order: str, real: str = "f"
) -> None:
    target = [0.2, -0.1, 0.3, 0.1, 0.2, -0.3]
    for seq, q in enumerate(([0.0] * 6, target)):
        reply = await motion.request(joint_traj_pt(jtp, seq, q, 1.0, order=order) if real == "f" else jtp_f64(seq, q))
        assert reply.reply_code == 1 and reply.msg_type == JOINT_TRAJ_PT
    position = await _watch_motion(emu, clock, state, real)
    assert max(abs(a - b) for a, b in zip(position, target, strict=True)) < 1e-3


async def _watch_motion(emu: Emulator, clock: SteppedClock, peer: RawPeer, real: str = "f") -> list[float]:
    """Run the motion through on the stepped clock, watching the state topics: while the robot
    stands frozen mid-motion a STATUS says in_motion TRUE; once it has settled a STATUS says
    FALSE, and the JOINT_POSITION after it is where it came to rest."""
    await advance_until(clock, lambda: emu.cell.in_motion, what="the motion starting")
    await next_status(peer, in_motion=1)
    await settle(emu, clock)
    await next_status(peer, in_motion=0)
    return joint_position(await peer.next_of(JOINT_POSITION), real)[:6]


def jtp_f64(seq: int, joints: list[float]) -> bytes:
    """A float64 JOINT_TRAJ_PT request, built by hand (no vector exists for that build)."""
    return struct.pack("<iiiii10ddd", 112, JOINT_TRAJ_PT, 2, 0, seq, *joints, *[0.0] * 4, 1.0, 0.0)


async def test_big_endian_end_to_end() -> None:
    async with emulator(byte_order="big") as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"], ">")
        state = await RawPeer.connect(emu.ports["state"], ">")
        assert (await motion.request(BE["PING_REQUEST"])).raw == BE["PING_REPLY_SUCCESS"]
        await _stream_and_watch(emu, clock, motion, state, BE["JOINT_TRAJ_PT_REQUEST_SEQ3"], ">")


async def test_float64_end_to_end() -> None:
    async with emulator(float64=True) as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        state = await RawPeer.connect(emu.ports["state"])
        status_frame = await state.next_of(STATUS)
        assert status_frame.length == 40  # STATUS has no reals
        position_frame = await state.next_of(JOINT_POSITION)
        assert position_frame.length == 12 + 4 + 80
        reply = await motion.request(jtp_f64(0, [0.0] * 6))
        assert reply.length == 112 and reply.reply_code == 1
        await _stream_and_watch(emu, clock, motion, state, b"", "<", real="d")


async def test_byte_order_autodetection_per_client() -> None:
    async with emulator(byte_order="auto") as (emu, clock):
        little = await RawPeer.connect(emu.ports["state"], "<")  # the motion port takes one client
        big = await RawPeer.connect(emu.ports["motion"], ">")
        assert (await little.request(LE["PING_REQUEST"])).raw == LE["PING_REPLY_SUCCESS"]
        assert (await big.request(BE["PING_REQUEST"])).raw == BE["PING_REPLY_SUCCESS"]
        await little.close()
        # a state client never speaks: it gets the order the motion port was last spoken in
        state = await RawPeer.connect(emu.ports["state"], ">")
        await _stream_and_watch(emu, clock, big, state, BE["JOINT_TRAJ_PT_REQUEST_SEQ3"], ">")


async def test_serial_link_over_a_pseudo_terminal() -> None:
    master, slave = os.openpty()
    try:
        async with emulator(serial=os.ttyname(slave), state_rate=50.0) as (emu, clock):
            # pyserial puts the port in raw mode when it opens it: until then the tty would echo
            await poll(lambda: bool(emu.motion_server.sessions))
            reader, writer = await open_fd(master, close_fd=False, name="pty master")
            link = RawPeer(reader, writer)
            await link.send(LE["PING_REQUEST"])
            assert (await link.next_of(1)).raw == PING_REPLY  # state topics share the link
            await link.send(joint_traj_pt(JTP, 0, [0.0] * 6))
            assert (await link.next_of(JOINT_TRAJ_PT)).reply_code == 1
            await link.send(joint_traj_pt(JTP, 1, [0.1] * 6, 1.0))
            assert (await link.next_of(JOINT_TRAJ_PT)).reply_code == 1
            position = await _watch_motion(emu, clock, link)
            assert max(abs(x - 0.1) for x in position) < 1e-3
            writer.close()
    finally:
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)


# -- MotoROS ----------------------------------------------------------------------------------------------


async def test_motoros_replays_the_fs100_capture() -> None:
    """The client side of a real FS100 session (big-endian, 7 axes), adapted to a 6-axis robot
    starting at zero: the same kinds of replies come back."""
    segments = load_segments()
    capture_kinds = set()
    client: list[bytes] = []
    for _, src, dst, payload in segments:
        frame = Frame(payload, ">")
        if src == 50240 and frame.msg_type == MOTO_REPLY:
            capture_kinds.add(frame.ints(5)[2:4])
        if dst == 50240 and (not client or client[-1] != payload):
            client.append(payload)  # a BUSY retry repeats the previous frame: replay adapts instead
    start = None
    # 200 increments of 2 ms: 0.4 s of buffer, which is what the FS100's BUSY pattern shows
    # (seq 1..4 accepted up to t = 0.436 s, seq 5 BUSY until the robot has moved on)
    async with emulator(profile="motoros", byte_order="big", interpolation_period=0.002) as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"], ">")
        state = await RawPeer.connect(emu.ports["state"], ">")
        kinds = set()
        last: list[float] = []
        for payload in client:
            frame = Frame(payload, ">")
            if frame.msg_type == JTPF:
                positions = list(frame.reals(10, 16))
                start = start or positions
                buf = bytearray(payload)
                adapted = [p - s for p, s in zip(positions[:6], start[:6], strict=True)] + [0.0] * 4
                struct.pack_into(">10f", buf, 16 + 16, *adapted)
                for offset in (16 + 16, 16 + 56, 16 + 96):  # drop the 7th axis
                    struct.pack_into(">f", buf, offset + 6 * 4, 0.0)
                payload, last = bytes(buf), adapted[:6]
            while True:
                reply = await motion.request(payload)
                _, _, command, result, _ = moto_reply(reply)
                kinds.add((command, result))
                if (command, result) != (JTPF, 1):
                    break
                await step(clock, 0.002)  # BUSY: retry once the robot has moved on (MotoROS's client retries too)
        assert kinds == capture_kinds == {(CHECK_MOTION_READY, 2), (START_TRAJ_MODE, 0), (JTPF, 0), (JTPF, 1)}
        feedback = await state.next_of(JOINT_FEEDBACK)
        assert feedback.ints(2) == (0, 0x06) and feedback.reals(1, 8) == (0.0,)  # MotoROS: no time
        await settle(emu, clock)
        reached = emu.cell.groups[0].command.actual_position
        assert max(abs(a - b) for a, b in zip(reached, last, strict=True)) < 1e-3


async def test_motoros_motion_control_and_point_checks() -> None:
    async with emulator(profile="motoros") as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        template = LE["JOINT_TRAJ_PT_FULL_REQUEST"]

        async def ctrl(command: int, group: int = 0) -> tuple[int, int]:
            return moto_reply(await motion.request(moto_ctrl(command, group)))[3:5]

        def point(seq: int, time: float, q: list[float], v: list[float] | None = None, vf: int = 7) -> bytes:
            return joint_traj_pt_full(template, 0, seq, vf, time, q, v or [0.0] * 6)

        async def send(data: bytes) -> tuple[int, int]:
            return moto_reply(await motion.request(data))[3:5]

        assert await ctrl(CHECK_MOTION_READY) == (2, 5008)  # FALSE: trajectory mode not started
        assert await send(point(0, 0.0, [0.0] * 6)) == (5, 5008)
        assert await ctrl(START_TRAJ_MODE) == (0, 0)
        assert await ctrl(CHECK_MOTION_READY) == (0, 0)
        assert await send(point(0, 0.0, [0.0] * 6, vf=3)) == (3, 3015)  # velocity required
        assert await send(point(0, 14400.0, [0.0] * 6)) == (3, 3016)
        for bad_time in (-math.inf, math.inf, math.nan, -3e38, 3e38):  # refused before any conversion
            assert await send(point(0, bad_time, [0.0] * 6)) == (3, 3016), bad_time
        assert await send(point(-4, 0.0, [0.0] * 6)) == (3, 3005)
        assert await send(point(0, 0.0, [0.01] + [0.0] * 5)) == (3, 3011)  # not where the robot is
        assert await send(point(0, 0.0, [0.0] * 6, [9.0] + [0.0] * 5)) == (3, 3013)  # beyond the speed limit
        assert await send(joint_traj_pt_full(template, 3, 0, 7, 0.0, [0.0] * 6)) == (3, 3004)
        assert await send(point(0, 0.0, [0.0] * 6)) == (0, 0)
        # 2 s of motion queued: more than 200 increments of 4 ms, so the next point is BUSY
        assert await send(point(1, 2.0, [0.5] * 6)) == (0, 0)
        assert await send(point(2, 2.5, [0.6] * 6)) == (1, 0)
        assert (await ctrl(CHECK_QUEUE_CNT))[1] == 200  # 2 s queued, but MotoROS's queue holds 200 increments
        assert await ctrl(CHECK_QUEUE_CNT, group=5) == (3, 3004)
        await advance_until(clock, lambda: emu.cell.groups[0].remaining < 0.8, what="the queue draining")
        assert await send(point(2, 2.5, [0.6] * 6)) == (0, 0)
        assert await ctrl(STOP_MOTION) == (0, 0)
        await settle(emu, clock)
        assert emu.cell.groups[0].command.actual_position[0] < 0.55
        assert await ctrl(STOP_SERVOS) == (0, 0)
        assert await ctrl(CHECK_MOTION_READY) == (2, 5006)
        assert await ctrl(START_SERVOS) == (0, 0)
        emu.cell.alarm(1234, "test")
        assert await ctrl(CHECK_MOTION_READY) == (2, 5001)
        assert await ctrl(RESET_ALARM) == (0, 0)
        emu.cell.estop()
        assert await ctrl(START_TRAJ_MODE) == (5, 5003)
        assert await ctrl(START_SERVOS) == (5, 5003)
        emu.cell.reset()
        assert await ctrl(999) == (3, 3006)
        assert await ctrl(STOP_TRAJ_MODE) == (0, 0)
        # unknown type: INVALID/3003 with group and sequence -1 (V20)
        unknown = struct.pack("<iiii", 12, 1234, 2, 0)
        assert (await motion.request(unknown)).raw[:36] == bytes.fromhex(
            "48000000d20700000300000001000000ffffffffffffffffd204000003000000bb0b0000"
        )
        # PING: header-only SUCCESS
        assert (await motion.request(LE["PING_REQUEST"])).raw == PING_REPLY
        # DISCONNECT: closed without a reply
        await motion.send(moto_ctrl(DISCONNECT))
        assert await motion.closed()


async def test_motoros_refused_types_close_the_connection_and_one_client_at_a_time() -> None:
    async with emulator(profile="motoros") as (emu, _clock):
        first = await RawPeer.connect(emu.ports["motion"])
        assert (await first.request(LE["PING_REQUEST"])).raw == PING_REPLY
        second = await RawPeer.connect(emu.ports["motion"])  # idle robot: the newcomer replaces the first
        assert await first.closed()
        await second.send(LE["STATUS_TOPIC"])  # STATUS on the motion port: closed, no reply
        assert await second.closed()


async def test_motoros_two_groups() -> None:
    async with emulator(profile="motoros", models=("jibot_zxs", "puma560")) as (emu, clock):
        motion = await RawPeer.connect(emu.ports["motion"])
        state = await RawPeer.connect(emu.ports["state"])
        assert moto_reply(await motion.request(moto_ctrl(START_TRAJ_MODE)))[3] == 0
        ex = await state.next_of(FEEDBACK_EX)
        assert ex.length == 544 and ex.ints(1) == (2,)
        ids = {(await state.next_of(JOINT_FEEDBACK)).ints(1)[0] for _ in range(4)}
        assert ids == {0, 1}
        puma_start = emu.cell.groups[1].command.actual_position

        def ex_point(seq: int, time: float, a: list[float], b: list[float]) -> bytes:
            body = struct.pack("<ii", 2, seq)
            for group, q in ((0, a), (1, b)):
                body += struct.pack("<iif10f10f10f", group, 7, time, *q, *[0.0] * 4, *[0.0] * 20)
            return struct.pack("<iiii", 12 + len(body), 2016, 2, 0) + body

        reply = moto_reply(await motion.request(ex_point(0, 0.0, [0.0] * 6, puma_start)))
        assert reply[2:4] == (2016, 0)
        target_b = [x + 0.2 for x in puma_start]
        assert moto_reply(await motion.request(ex_point(1, 0.5, [0.2] * 6, target_b)))[2:4] == (2016, 0)
        # one group's point beyond its limits: neither group takes the point
        assert moto_reply(await motion.request(ex_point(2, 1.0, [0.3] * 6, [9.0] * 6)))[3:5] == (3, 3012)
        await settle(emu, clock)
        assert max(abs(x - 0.2) for x in emu.cell.groups[0].command.actual_position) < 1e-3
        reached = emu.cell.groups[1].command.actual_position
        assert max(abs(a - b) for a, b in zip(reached, target_b, strict=True)) < 1e-3


async def test_motoros_io_port() -> None:
    async with emulator(profile="motoros") as (emu, _clock):
        io = await RawPeer.connect(emu.ports["io"])

        async def call(msg_type: int, *words: int) -> Frame:
            body = struct.pack(f"<{len(words)}I", *words)
            return await io.request(struct.pack("<iiii", 12 + len(body), msg_type, 2, 0) + body)

        ok = await call(2005, 10010, 1)  # write universal output #10010
        assert (ok.msg_type, ok.reply_code, ok.ints(1)) == (2006, 1, (0,))
        read = await call(2003, 10010)
        assert (read.msg_type, read.ints(2)) == (2004, (1, 0))
        assert (await call(2005, 10, 1)).ints(1) == (1002,)  # an input cannot be written
        assert (await call(2005, 10010, 2)).ints(1) == (1003,)
        assert (await call(2003, 18)).ints(2) == (0, 1001)  # the last digit must be 0..7
        bad = await call(2003, 18)
        assert bad.reply_code == 2
        assert (await call(2009, 1001, 0xA5)).ints(1) == (0,)  # group 1001 = bits 10010..10017
        assert (await call(2007, 1001)).ints(2) == (0xA5, 0)
        assert (await call(2003, 10017)).ints(2) == (1, 0)
        assert (await call(2009, 1001, 256)).ints(1) == (1003,)
        assert (await call(2013, 5, 65535)).msg_type == 2013
        assert (await call(2012, 5)).ints(2) == (65535, 0)
        assert (await call(2013, 600, 1)).ints(1) == (1002,)  # M560 and above are read-only
        assert (await call(2012, 999)).ints(2) == (0, 0)
        assert (await call(2012, 1000)).ints(2) == (0, 1001)
        weird = await call(9999)
        assert (weird.msg_type, weird.length, weird.ints(2)) == (2002, 72, (3, 3003))
        table = IoTable()
        table.set(20010, 1)
        assert table.read_bit(20010) == (1, 0)


async def test_a_lone_servers_exit_report_gives_its_overruns_and_their_times(caplog: pytest.LogCaptureFixture) -> None:
    """On the wall clock, a lone emulator's report at close: the count, then the overruns' times
    and lateness (put in its loop's stats as late wake-ups would: no wall-clock lateness waited for)."""
    emu = Emulator(EmulatorConfig(motion_port=0, state_port=0))
    caplog.set_level(logging.INFO, logger="robot_server.emulator.server")
    await emu.start()
    try:
        stats = emu.control.stats
        stats.wakes = max(stats.wakes, 10)
        loop_module._late(stats, 0.0073, 0.004)
    finally:
        await emu.close(settle_timeout=1.0)
    report = "\n".join(r.getMessage() for r in caplog.records if r.name == "robot_server.emulator.server")
    assert re.search(r"control loop: \d+ wake-ups, 1 overruns .*latest [\d.]+ ms", report), report
    times = re.search(r"control loop overruns, the last 1 \(.*?\): ([\d.]+) \+7\.300 ms$", report, re.M)
    assert times is not None, report
    assert float(times[1]) == pytest.approx(stats.late_wakes[0][0], abs=1e-5)
