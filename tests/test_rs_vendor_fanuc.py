"""The Fanuc profile against raw sockets, on a stepped clock: what fanuc_driver's KAREL relay and TP
program do (robot_server/emulator/fanuc.py has the rules, docs/vendors.md their file:line)."""

from __future__ import annotations

import asyncio
import itertools
import logging
import socket
import struct

import numpy as np
import pytest

from robot_server.control.moves import JointMoves
from robot_server.control.points import Limits
from robot_server.emulator.fanuc import KAREL_PERIOD
from robot_server.loader import load_model
from tests.rawpeer import joint_traj_pt, vectors
from tests.stepped import step
from tests.vendor import connect, logged, until, vendor_emulator, written

V = vectors(">")
JTP = V["JOINT_TRAJ_PT_REQUEST_SEQ3"]
TOPIC = V["JOINT_TRAJ_PT_TOPIC_SEQ3"]
PING = V["PING_REQUEST"]
MODEL = load_model("jibot_zxs")


def point(seq: int, q: list[float], *, velocity: float = 0.5, duration: float = 0.1, topic: bool = False) -> bytes:
    return joint_traj_pt(TOPIC if topic else JTP, seq, q, velocity, duration, order=">")


def ack(seq: int, code: int = 1) -> bytes:
    """The relay's reply: JOINT_POSITION (10), SERVICE_REPLY, the code, the sequence, 10 zero joints."""
    return struct.pack(">iiiii", 56, 10, 3, code, seq) + bytes(40)


def position(emu: object) -> np.ndarray:
    return np.array(emu.cell.groups[0].command.command_position)  # type: ignore[attr-defined]


def replies(wire: object) -> list[bytes]:
    return [f for _, f in written(wire, "motion", ">")]  # type: ignore[arg-type]


A = [0.3, -0.2, 0.1, 0.4, -0.3, 0.5]  # the controller's joints (J3 relative to J2's: J23_factor 1)
B = [0.6, 0.1, -0.2, 0.4, 0.3, 0.5]


def model_joints(c: list[float]) -> np.ndarray:
    q = np.array(c)
    q[2] = c[2] + c[1]  # ROS J3 = controller J3 + J2
    return q


async def test_every_point_is_acknowledged_at_once_with_a_joint_position_whatever_its_comm_type() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, [0.0] * 6))
        await motion.send(point(1, A, topic=True))
        await until(clock, lambda: len(replies(wire)) == 2, what="two acks")
        assert replies(wire) == [ack(0), ack(1)]
        assert all(len(f) == 60 for f in replies(wire))


async def test_each_point_is_a_joint_move_at_20_percent_whatever_its_duration() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, _wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, A, duration=0.01))  # asks for 10 ms: the TP program takes its own time
        await until(clock, lambda: emu.cell.in_motion, what="the move")
        begun = emu.cell.time
        await until(clock, lambda: not emu.cell.groups[0].moving, limit=20.0, what="the move's end")
        took = emu.cell.time - begun
        moves = JointMoves(Limits.from_model(MODEL), np.zeros(6))
        expected = moves.plan(model_joints(A), speed=0.2).duration
        assert expected > 0.8  # 20 % of jibot's 3.14 rad/s: 0.8 s of cruise for 0.5 rad
        assert abs(took - expected) <= 0.01
        assert np.max(np.abs(position(emu) - model_joints(A))) < 1e-6


async def test_the_relay_reads_the_next_point_only_when_the_tp_program_has_taken_the_last() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        for seq, q in enumerate([A, B, A]):  # three points at once: the third waits in the socket
            await motion.send(point(seq, q))
        await until(clock, lambda: len(replies(wire)) == 2, what="two acks")
        first_move = emu.cell.groups[0].moves._moves[0]
        window = first_move.end - 0.5 * first_move.decelerating
        await until(clock, lambda: len(replies(wire)) == 3, limit=10.0, what="the third ack")
        acked = written(wire, "motion", ">")[2][0]
        assert window - 0.005 <= acked <= window + 0.01  # read once the TP took point 1, in move 0's CNT window
        assert acked > 0.5


#: onwards from A: no joint turns back at A
ONWARD = [0.6, -0.4, 0.1, 0.6, -0.5, 0.7]


@pytest.mark.parametrize("last", [ONWARD, B], ids=["onward", "turning-back"])
async def test_cnt50_blends_the_moves_within_the_limits_and_the_robot_ends_on_the_last_point(last: list[float]) -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        recorders = emu.record(30.0)
        motion = await connect(emu, "motion", ">")
        for seq, q in enumerate([A, last]):
            await motion.send(point(seq, q))
        await until(clock, lambda: len(replies(wire)) == 2 and not emu.cell.in_motion, limit=20.0)
        speed = np.max(np.abs(recorders[0].get("command_velocity")), axis=1)
        fast = np.flatnonzero(speed > 0.05)
        slowest = np.min(speed[fast[0] : fast[-1]])
        if last is ONWARD:
            assert slowest > 0.05  # the corner blended at speed
        else:  # joints 1 and 4 turn back: only the jerk ramps overlap, the robot slows but never stops
            assert 0.0 < slowest < 0.05
        acceleration = np.abs(recorders[0].get("command_acceleration"))
        assert np.all(acceleration <= MODEL.max_acceleration + 1e-6)
        assert np.max(np.abs(position(emu) - model_joints(last))) < 1e-6


async def test_start_download_and_end_points_get_no_reply_and_stop_stops_nothing(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        for seq in (-1, -2, -3):
            await motion.send(point(seq, A))
        await motion.send(point(0, A))
        await until(clock, lambda: len(replies(wire)) == 1, what="point 0's ack")
        assert replies(wire) == [ack(0)]  # the first reply is point 0's
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.05, what="the move")
        with caplog.at_level(logging.WARNING):
            await motion.send(point(-4, [0.0] * 6))
            await until(clock, lambda: len(replies(wire)) == 2, what="STOP's ack")
        assert replies(wire)[1] == ack(-4)
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - model_joints(A))) < 1e-6  # the move ran to its end
        assert logged(caplog, "CANCEL stops nothing") == 1


async def test_lenient_stop_stops() -> None:
    async with vendor_emulator("fanuc", lenient=True) as (emu, clock, _wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, A))
        await until(clock, lambda: np.max(np.abs(position(emu))) > 0.05, what="the move")
        await motion.send(point(-4, [0.0] * 6))
        await until(clock, lambda: not emu.cell.in_motion, limit=10.0)
        assert np.max(np.abs(position(emu) - model_joints(A))) > 0.05


async def test_an_out_of_range_point_is_acknowledged_then_failed_and_the_relay_hangs_up() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, [0.0, 3.0, 0.0, 0.0, 0.0, 0.0]))  # J2 beyond 2.09 rad
        await until(clock, lambda: len(replies(wire)) == 2, what="two replies")
        assert replies(wire) == [ack(0), ack(0, code=2)]
        assert await motion.closed()
        assert not emu.cell.in_motion


async def test_a_message_shorter_than_56_bytes_stalls_the_relay_and_misframes_what_follows(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        with caplog.at_level(logging.WARNING):
            await motion.send(PING)
            await step(clock, 0.2)
            assert replies(wire) == []  # never read, never answered
            assert logged(caplog, "16 bytes wait unread") == 1
            await motion.send(point(5, A))  # PING + the point's first 44 bytes are read as a point
            await until(clock, lambda: len(replies(wire)) >= 1, what="a reply")
        (seq,) = struct.unpack_from(">i", replies(wire)[0], 16)
        assert seq != 5  # the PING's bytes in its place: framing is lost
        assert logged(caplog, "is taken for a trajectory point") == 1


async def test_lenient_frames_by_the_length_prefix_and_drops_what_is_not_a_point() -> None:
    async with vendor_emulator("fanuc", lenient=True) as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(PING)
        await motion.send(point(5, A))
        await until(clock, lambda: len(replies(wire)) == 1, what="the point's ack")
        assert replies(wire) == [ack(5)]


async def test_the_j2_j3_coupling_the_state_port_speaks_the_controllers_joints() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, _wire):
        motion = await connect(emu, "motion", ">")
        state = await connect(emu, "state", ">")
        await motion.send(point(0, A))
        await until(clock, lambda: emu.cell.in_motion, what="the move")
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - model_joints(A))) < 1e-6  # the model's J3 = 0.1 + (-0.2)
        for _ in range(200):  # the frames queued before the move ended go first
            joints = np.array((await state.next_of(10)).reals(6, 4))
            if np.max(np.abs(joints - np.array(A))) < 1e-3:  # the model's J3 is -0.1: 0.2 away
                break
        else:
            pytest.fail(f"the state port never published the controller's joints {A}: last {joints}")


async def test_j23_factor_0_is_no_coupling() -> None:
    async with vendor_emulator("fanuc", profile_options=(("j23_factor", "0"),)) as (emu, clock, _wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, A))
        await until(clock, lambda: emu.cell.in_motion, what="the move")
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - np.array(A))) < 1e-6


async def test_state_status_after_every_eleventh_joint_position_count_kept_across_clients() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        assert abs(emu.config.rate - 1 / KAREL_PERIOD) < 1e-6
        state = await connect(emu, "state", ">")
        kinds = [(await state.frame()).msg_type for _ in range(40)]
        statuses = [i for i, k in enumerate(kinds) if k == 13]
        gaps = {b - a for a, b in itertools.pairwise(statuses)}
        assert gaps == {12}  # eleven JOINT_POSITIONs, then a STATUS, ...
        assert all(kinds[i - 1] == 10 for i in statuses)
        await state.close()
        await until(clock, lambda: not emu.state_server.sessions, what="the state client's end")
        again = await connect(emu, "state", ">")
        while (await again.frame()).msg_type != 13:  # the new client's first STATUS
            pass
        # every state message written, both clients', in order: the count went on across them
        everything = [struct.unpack_from(">i", f, 4)[0] for _, f in written(wire, "state", ">")]
        statuses = [i for i, k in enumerate(everything) if k == 13]
        assert len(statuses) >= 4  # three to the first client, one to the second
        assert {b - a for a, b in itertools.pairwise(statuses)} == {12}


async def test_a_lost_motion_client_does_not_stop_the_motion() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, _wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, A))
        await until(clock, lambda: emu.cell.in_motion, what="the move")
        await motion.close()
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - model_joints(A))) < 1e-6


@pytest.mark.parametrize("reset", [False, True], ids=["fin", "reset"])
async def test_a_hand_over_under_way_completes_after_the_client_is_lost_and_holds_the_next_client(reset: bool) -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        moves = emu.cell.groups[0].moves
        first = await connect(emu, "motion", ">")
        for seq, q in enumerate([A, B]):
            await first.send(point(seq, q))
        await until(clock, lambda: len(replies(wire)) == 2, what="both acks")  # B acked, waiting for the TP
        assert not np.allclose(moves.end_position, model_joints(B))
        if reset:  # the connection ends at once, with the relay's read still under way
            sock = first.writer.get_extra_info("socket")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        await first.close()
        second = await connect(emu, "motion", ">")
        await second.send(point(0, A))
        await until(clock, lambda: np.allclose(moves.end_position, model_joints(B)), limit=10.0, what="B handed over")
        handed_over = emu.cell.time
        assert len(replies(wire)) == 2  # the second client's point is not read before that
        await until(clock, lambda: len(replies(wire)) == 3, limit=10.0, what="the second client's ack")
        assert written(wire, "motion", ">")[2][0] >= handed_over - 1e-9
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - model_joints(A))) < 1e-6


async def test_closing_the_emulator_ends_a_hand_over_first_and_nothing_more_is_handed_over() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        for seq, q in enumerate([A, B]):
            await motion.send(point(seq, q))
        await until(clock, lambda: len(replies(wire)) == 2, what="both acks")  # B waits for the TP
        handover = emu.behaviour.relay._handover  # type: ignore[attr-defined]
        assert handover is not None and not handover.done()
        closing = asyncio.ensure_future(emu.close(settle_timeout=1.0))
        await until(clock, handover.done, what="the hand-over's end")
        assert handover.cancelled()
        await until(clock, lambda: not emu.cell.in_motion, what="the shutdown stop")
        await asyncio.wait_for(closing, 5.0)
        assert not np.allclose(emu.cell.groups[0].moves.end_position, model_joints(B))  # B never handed over


async def test_after_an_estop_and_reset_the_point_being_handed_over_runs_the_interrupted_move_does_not() -> None:
    async with vendor_emulator("fanuc") as (emu, clock, wire):
        motion = await connect(emu, "motion", ">")
        for seq, q in enumerate([A, B]):
            await motion.send(point(seq, q))
        await until(clock, lambda: len(replies(wire)) == 2, what="both acks")
        emu.command("estop")
        await step(clock, 0.5)
        assert not emu.cell.in_motion
        stopped = position(emu).copy()
        assert np.max(np.abs(stopped - model_joints(A))) > 0.01  # short of A: its move was abandoned
        emu.command("reset")
        await until(clock, lambda: emu.cell.in_motion, what="the move to B")
        await until(clock, lambda: not emu.cell.in_motion, limit=20.0)
        assert np.max(np.abs(position(emu) - model_joints(B))) < 1e-6


async def test_the_speed_and_cnt_registers_are_profile_options() -> None:
    async with vendor_emulator("fanuc", profile_options=(("speed", "100"), ("cnt", "0"))) as (emu, clock, _wire):
        motion = await connect(emu, "motion", ">")
        await motion.send(point(0, A))
        await until(clock, lambda: emu.cell.in_motion, what="the move")
        begun = emu.cell.time
        await until(clock, lambda: not emu.cell.groups[0].moving, limit=20.0)
        expected = JointMoves(Limits.from_model(MODEL), np.zeros(6)).plan(model_joints(A), speed=1.0).duration
        assert abs(emu.cell.time - begun - expected) <= 0.01


@pytest.mark.parametrize(
    ("options", "match"),
    [((("speed", "0"),), "speed"), ((("cnt", "101"),), "cnt"), ((("j23_factor", "2"),), "j23_factor")],
)
def test_bad_profile_options_are_refused(options: tuple[tuple[str, str], ...], match: str) -> None:
    from robot_server.emulator import Emulator, EmulatorConfig

    with pytest.raises(ValueError, match=match):
        Emulator(EmulatorConfig(profile="fanuc", profile_options=options))


def test_an_unknown_profile_option_is_refused() -> None:
    from robot_server.emulator import EmulatorConfig

    with pytest.raises(ValueError, match="has no option 'spede'"):
        EmulatorConfig(profile="fanuc", profile_options=(("spede", "20"),))
