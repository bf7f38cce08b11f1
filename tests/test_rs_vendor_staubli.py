"""The Stäubli profile against raw sockets, on a stepped clock: what staubli_val3_driver's VAL3 server
does (robot_server/emulator/staubli.py has the rules, docs/vendors.md their file:line)."""

from __future__ import annotations

import asyncio
import itertools
import logging
import struct

import numpy as np
import pytest

from robot_server.control.moves import JointMoves
from robot_server.control.points import Limits
from robot_server.emulator.staubli import VAL3_QUEUE, VAL3_TICK, staubli_split
from robot_server.loader import load_model
from simple_message.connection import Connection
from tests.rawpeer import joint_traj_pt, joint_traj_pt_full, vectors
from tests.stepped import step
from tests.vendor import connect, logged, until, vendor_emulator, written

V = vectors("<")
JTP = V["JOINT_TRAJ_PT_REQUEST_SEQ3"]
TOPIC = V["JOINT_TRAJ_PT_TOPIC_SEQ3"]
FULL = V["JOINT_TRAJ_PT_FULL_REQUEST"]
PING = V["PING_REQUEST"]
STATUS_TOPIC = V["STATUS_TOPIC"]
MODEL = load_model("jibot_zxs")
A = [0.3, -0.2, 0.1, 0.4, -0.3, 0.5]
B = [0.5, 0.1, -0.2, 0.4, 0.3, 0.2]


def point(seq: int, q: list[float], velocity: float = 0.5, *, topic: bool = False, duration: float = 0.1) -> bytes:
    return joint_traj_pt(TOPIC if topic else JTP, seq, q, velocity, duration)


def reply(seq: int, code: int = 1) -> bytes:
    """VAL3's ack: JOINT_TRAJ_PT at its full length, the sequence, every other field zero."""
    return struct.pack("<iiiii", 64, 11, 3, code, seq) + bytes(48)


def replies(wire: object) -> list[bytes]:
    return [f for _, f in written(wire, "motion")]  # type: ignore[arg-type]


def position(emu: object) -> np.ndarray:
    return np.array(emu.cell.groups[0].command.command_position)  # type: ignore[attr-defined]


async def both(emu: object, clock: object) -> tuple[object, object]:
    """The motion and state clients, and the state client's second of grace gone."""
    motion = await connect(emu, "motion")  # type: ignore[arg-type]
    state = await connect(emu, "state")  # type: ignore[arg-type]
    await until(clock, emu.behaviour.motion.connected, limit=2.0, what="both sockets")  # type: ignore[attr-defined]
    return motion, state


async def test_a_request_is_answered_at_its_full_length_with_the_sequence_and_zeros_a_topic_not() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        await motion.send(point(4, A, topic=True))
        await motion.send(point(5, A))
        await until(clock, lambda: len(replies(wire)) == 1, what="the reply")
        assert replies(wire) == [reply(5)]


async def test_each_message_is_written_as_prefix_header_body() -> None:
    assert staubli_split(reply(3)) == (reply(3)[:4], reply(3)[4:16], reply(3)[16:])
    writes: list[bytes] = []

    class Transport(asyncio.Transport):
        def write(self, data: bytes | bytearray | memoryview) -> None:
            writes.append(bytes(data))

        def get_write_buffer_size(self) -> int:
            return 0

        def is_closing(self) -> bool:
            return False

        def get_extra_info(self, name: str, default: object = None) -> object:
            return default

        def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
            pass

    connection = Connection(Transport(), write_split=staubli_split)
    connection.send_frame_nowait(reply(3))
    assert writes == [reply(3)[:4], reply(3)[4:16], reply(3)[16:]]


async def test_a_point_is_a_movej_at_its_velocity_share_its_duration_ignored_stopping_at_each_point() -> None:
    async with vendor_emulator("staubli") as (emu, clock, _wire):
        recorders = emu.record(30.0)
        motion, _ = await both(emu, clock)
        await motion.send(point(0, A, velocity=0.3, duration=0.01))
        await motion.send(point(1, B, velocity=0.3, duration=0.01))
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        begun = emu.cell.time
        await until(clock, lambda: not emu.cell.groups[0].moving, limit=20.0, what="the end")
        ended = emu.cell.time
        await until(clock, lambda: not emu.cell.in_motion, limit=5.0, what="settling")
        moves = JointMoves(Limits.from_model(MODEL), np.zeros(6))
        first = moves.plan(np.array(A), speed=0.3)
        second = JointMoves(Limits.from_model(MODEL), np.array(A)).plan(np.array(B), speed=0.3)
        expected = first.duration + second.duration
        assert expected - 0.01 <= ended - begun <= expected + 2 * VAL3_TICK + 0.01
        speed = np.max(np.abs(recorders[0].get("command_velocity")), axis=1)
        times = recorders[0].time()
        at_a = np.argmin(np.max(np.abs(recorders[0].get("command_position") - np.array(A)), axis=1))
        assert speed[at_a] < 0.01 * 0.3 * MODEL.max_velocity.min()  # at rest on A, then off to B (blend off)
        assert times[at_a] > begun
        assert np.max(np.abs(position(emu) - np.array(B))) < 1e-6


async def test_no_motion_unless_both_sockets_are_connected_the_state_one_for_a_second() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion = await connect(emu, "motion")
        await motion.send(point(0, A))
        await until(clock, lambda: len(replies(wire)) == 1, what="the reply")
        assert replies(wire) == [reply(0)]  # SUCCESS, and then dropped
        await step(clock, 0.5)
        assert not emu.cell.in_motion
        state = await connect(emu, "state")
        await until(clock, lambda: bool(emu.state_server.sessions), what="the state client")
        connected_at = emu.cell.time
        await motion.send(point(1, A))  # in the state client's first second: SUCCESS, then dropped
        await until(clock, lambda: len(replies(wire)) == 2, what="the reply")
        await until(clock, emu.behaviour.motion.connected, limit=2.0, what="both sockets")
        assert emu.cell.time - connected_at >= 1.0 - VAL3_TICK
        assert not emu.cell.in_motion
        await motion.send(point(2, A))
        await until(clock, lambda: emu.cell.in_motion, limit=1.0, what="the motion")
        # losing the state client stops the robot and empties the queues
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.05, what="some motion")
        await state.close()
        await until(clock, lambda: not emu.cell.in_motion, limit=5.0, what="the stop")
        assert np.max(np.abs(position(emu) - np.array(A))) > 0.01


async def test_losing_the_motion_client_stops_the_robot() -> None:
    async with vendor_emulator("staubli") as (emu, clock, _wire):
        motion, _ = await both(emu, clock)
        await motion.send(point(0, A, velocity=0.2))
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.05, what="some motion")
        await motion.close()
        await until(clock, lambda: not emu.cell.in_motion, limit=5.0, what="the stop")
        assert np.max(np.abs(position(emu) - np.array(A))) > 0.01


async def test_failure_for_a_point_out_of_range_a_velocity_not_above_0_and_a_full_queue() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        await motion.send(point(0, [0.0, 3.0, 0, 0, 0, 0]))
        await motion.send(point(1, A, velocity=0.0))
        await motion.send(point(2, A, velocity=1.7))  # above 1: clamped to 100 %, not refused
        await until(clock, lambda: len(replies(wire)) == 3, what="three replies")
        assert replies(wire) == [reply(0, 2), reply(1, 2), reply(2)]
        # a stream far faster than moves that stop at each point: the queues and the motion stack
        # fill, then the queue is full: FAILURE (the stock streamer loses those points)
        path = [[0.3 + 0.05 * (k % 2), *A[1:]] for k in range(40)]
        for k, q in enumerate(path):
            await motion.send(point(10 + k, q, velocity=0.05))
        await until(clock, lambda: len(replies(wire)) == 43, limit=5.0, what="every reply")
        codes = [struct.unpack_from("<i", f, 12)[0] for f in replies(wire)[3:]]
        assert codes[: VAL3_QUEUE + 10] == [1] * (VAL3_QUEUE + 10)  # queue, one waiting movej, the stack: room
        assert 2 in codes


async def test_one_message_per_4_ms_tick() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        for k in range(5):
            await motion.send(point(k, A))
        await until(clock, lambda: len(replies(wire)) == 5, what="five replies")
        times = [t for t, _ in written(wire, "motion")]
        assert np.all(np.diff(times) >= VAL3_TICK - 1e-9)


async def test_stop_empties_the_queues_and_stops_at_the_next_tick() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        for k, q in enumerate([A, B, A]):
            await motion.send(point(k, q, velocity=0.2))
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.05, what="the motion")
        await motion.send(point(-4, [9.0] * 6))
        await until(clock, lambda: len(replies(wire)) == 4, what="STOP's reply")
        assert replies(wire)[-1] == reply(-4)
        await until(clock, lambda: not emu.cell.in_motion, limit=5.0)
        assert np.max(np.abs(position(emu) - np.array(A))) > 0.01
        assert not emu.behaviour.motion.queue and not emu.cell.groups[0].moves.active


async def test_another_type_is_unanswered_and_one_with_a_body_loses_the_framing(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        with caplog.at_level(logging.WARNING):
            await motion.send(PING)  # no body: consumed cleanly, not answered
            await motion.send(point(1, A))
            await until(clock, lambda: len(replies(wire)) == 1, what="the point's reply")
            assert replies(wire) == [reply(1)]
            await motion.send(STATUS_TOPIC)  # its 28-byte body is read as the next header and more
            await motion.send(point(2, A))
            await step(clock, 0.2)
        assert reply(2) not in replies(wire)
        assert logged(caplog, "framing is lost") >= 1


async def test_lenient_keeps_the_framing() -> None:
    async with vendor_emulator("staubli", lenient=True) as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        await motion.send(STATUS_TOPIC)
        await motion.send(point(2, A))
        await until(clock, lambda: len(replies(wire)) == 1, what="the point's reply")
        assert replies(wire) == [reply(2)]


async def test_joint_traj_pt_full_is_read_as_val3_reads_it() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        # robot_id 7 in the first four bytes: VAL3's "sequence"; speed: joint 1's velocity as a share;
        # acceleration: joint 1's acceleration as a percentage
        frame = joint_traj_pt_full(FULL, 7, 3, 7, 0.5, A, [0.4, 0, 0, 0, 0, 0], accelerations=[100.0] + [0.0] * 5)
        await motion.send(frame)
        await until(clock, lambda: len(replies(wire)) == 1, what="the reply")
        ack = replies(wire)[0]
        assert len(ack) == 152
        assert struct.unpack_from("<iiiiii", ack, 0) == (148, 14, 3, 1, 0, 7)  # robot_id 0, "sequence" 7
        assert ack[24:] == bytes(128)
        await until(clock, lambda: emu.cell.in_motion, what="the motion")
        begun = emu.cell.time
        await until(clock, lambda: not emu.cell.groups[0].moving, limit=20.0)
        expected = JointMoves(Limits.from_model(MODEL), np.zeros(6)).plan(np.array(A), speed=0.4).duration
        assert abs(emu.cell.time - begun - expected) <= 2 * VAL3_TICK


@pytest.mark.parametrize("where", ["robot_id", "sequence"])
async def test_a_full_point_stops_with_minus_4_in_its_robot_id_not_in_its_sequence(where: str) -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        motion, _ = await both(emu, clock)
        share = {"accelerations": [100.0] + [0.0] * 5}  # joint 1's acceleration: VAL3's percentage
        await motion.send(joint_traj_pt_full(FULL, 0, 0, 7, 0.5, A, [0.3] + [0.0] * 5, **share))
        await until(clock, lambda: emu.cell.in_motion, what="the move to A")
        robot_id, sequence = (-4, 1) if where == "robot_id" else (1, -4)
        stop = joint_traj_pt_full(FULL, robot_id, sequence, 7, 0.5, B, [0.3] + [0.0] * 5, **share)
        await motion.send(stop)
        await until(clock, lambda: len(replies(wire)) == 2, what="both replies")
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        if where == "robot_id":  # VAL3's "sequence" is -4: a STOP, the robot short of A
            assert np.max(np.abs(position(emu) - np.array(A))) > 0.01
        else:  # an ordinary point: the robot goes to A, then B
            assert np.max(np.abs(position(emu) - np.array(B))) < 1e-6


async def test_state_first_joint_position_a_second_after_connecting_status_with_every_fifth() -> None:
    async with vendor_emulator("staubli") as (emu, clock, wire):
        assert emu.config.rate == 50.0
        state = await connect(emu, "state")
        await until(clock, lambda: bool(emu.state_server.sessions), what="the state client")
        connected_at = emu.cell.time
        await step(clock, 0.9)
        assert wire.out("state") == []  # nothing in the first second
        await step(clock, 0.2)
        kinds = [(await state.frame()).msg_type for _ in range(17)]
        assert kinds[:6] == [10] * 5 + [10] and kinds[6] == 13  # STATUS with the sixth JOINT_POSITION
        statuses = [i for i, k in enumerate(kinds) if k == 13]
        assert [b - a for a, b in itertools.pairwise(statuses)] == [6]  # then every fifth
        first = wire.out("state")[0][0]
        assert first - connected_at >= 1.0 - 1e-9


@pytest.mark.parametrize("depth", ["0", "ten"])
def test_a_motion_stack_that_is_not_a_whole_number_of_moves_is_refused(depth: str) -> None:
    from robot_server.emulator import Emulator, EmulatorConfig

    with pytest.raises(ValueError, match="staubli profile option motion_stack"):
        Emulator(EmulatorConfig(profile="staubli", profile_options=(("motion_stack", depth),)))
