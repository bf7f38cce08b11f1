"""Replaying a captured session (`simple-message replay`): the FS100 capture against the emulator,
a session the project recorded itself, and what a mismatch, an unreachable target and a capture
with nothing to replay give."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from robot_server import Emulator, EmulatorConfig
from simple_message import cli
from simple_message.constants import CommType, ReplyCode
from simple_message.framing import FrameDecoder
from simple_message.messages import JointTrajPt, Ping, decode, encode
from simple_message.replay import exchanges, from_capture, replay, server_ports
from simple_message.wire import BE32, LE32

from .refdata import DATA

FS100 = str(DATA / "motoman_fs100_simple_move.pcapng")


@contextlib.asynccontextmanager
async def emulator(**options: Any) -> AsyncIterator[Emulator]:
    options.setdefault("motion_port", 0)
    options.setdefault("state_port", 0)
    async with Emulator(EmulatorConfig(**options)) as emu:
        yield emu


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_fs100_capture_holds_twelve_client_exchanges() -> None:
    items, wire, problems = from_capture(FS100, LE32, True)
    assert wire == BE32 and problems == []
    assert len(items) == 164 and server_ports(items) == [50240, 50241]
    plan = exchanges(items)
    # CHECK_MOTION_READY, START_TRAJ_MODE, ten points; the 48 BUSY retries fold into their point
    assert len(plan) == 12 and sum(e.busy for e in plan) == 48
    assert all(e.expected is not None for e in plan)


@pytest.mark.slow
async def test_the_fs100_capture_replayed_against_the_motoros_emulator_matches() -> None:
    items, wire, _ = from_capture(FS100, LE32, True)
    config = {"profile": "motoros", "byte_order": "big", "interpolation_period": 0.002, "io_port": 0, "speedup": 4.0}
    async with emulator(**config) as emu:
        ports = {50240: emu.ports["motion"], 50241: emu.ports["state"]}
        outcomes = await asyncio.wait_for(replay(exchanges(items), "127.0.0.1", ports, wire, remap=6), 60.0)
        await emu.settle(timeout=30.0)
    assert len(outcomes) == 12 and all(o.match for o in outcomes), [o.note for o in outcomes if not o.match]
    # the capture's CHECK_MOTION_READY FALSE (MotoROS before 1.9: subcode 0) matches the emulator's reason
    assert "before 1.9" in outcomes[0].note
    assert sum(o.busy for o in outcomes) > 0  # the emulator too answered BUSY while its queue was full


async def test_a_recorded_session_replays_against_the_emulator_and_a_mismatch_is_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The project's own capture: two PINGs and a first point away from the robot (refused)."""
    capture = tmp_path / "session.pcapng"
    away = (0.5,) * 6 + (0.0,) * 4
    frames = [encode(Ping(), LE32)] * 2 + [
        encode(JointTrajPt(0, away, 0.5, 0.0, comm_type=CommType.SERVICE_REQUEST), LE32)
    ]
    async with emulator(capture=str(capture)) as emu:
        reader, writer = await asyncio.open_connection("127.0.0.1", emu.ports["motion"])
        decoder = FrameDecoder(LE32.byte_order)
        codes = []
        for frame in frames:
            writer.write(frame)
            while (reply := decoder.next_frame()) is None:
                decoder.feed(await asyncio.wait_for(reader.read(4096), 5.0))
            codes.append(decode(reply, LE32).reply_code)
        writer.close()
        await writer.wait_closed()
        motion = emu.ports["motion"]
    assert codes == [ReplyCode.SUCCESS, ReplyCode.SUCCESS, ReplyCode.FAILURE]
    argv = ["replay", str(capture), "--port", str(motion), "--against"]
    # the same session against a fresh emulator: every reply alike
    async with emulator() as emu:
        code, out, err = await asyncio.to_thread(run_cli, [*argv, f"127.0.0.1:{emu.ports['motion']}"], capsys)
    assert code == 0, err
    assert "3 of 3 exchanges match" in out
    # against a robot that stands where the point is, the point is accepted: a mismatch, exit 1
    async with emulator(initial_position=away[:6]) as emu:
        code, out, err = await asyncio.to_thread(run_cli, [*argv, f"127.0.0.1:{emu.ports['motion']}"], capsys)
    assert code == 1
    assert "2 of 3 exchanges match (mismatches above)" in out
    assert "NO: expected JOINT_TRAJ_PT comm 3 reply 2" in out


async def test_replay_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.pcapng"
    bad.write_bytes(b"\x0a\x0d\x0d\x0a" + b"\x00" * 10)
    code, out, err = await asyncio.to_thread(run_cli, ["replay", str(bad), "--against", "127.0.0.1"], capsys)
    assert code == 1 and out == "" and len(err.strip().splitlines()) == 1 and "CaptureError" in err
    # nothing listens there: one line
    code, out, err = await asyncio.to_thread(run_cli, ["replay", FS100, "--against", "127.0.0.1:1,2"], capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1 and "cannot connect" in err
    # the wrong number of ports
    code, _, err = await asyncio.to_thread(run_cli, ["replay", FS100, "--against", "127.0.0.1:50240"], capsys)
    assert code == 2 and "give as many" in err


async def test_a_target_that_closes_or_speaks_another_byte_order_gives_a_table_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capture = tmp_path / "pings.pcapng"
    ping = encode(Ping(), LE32)
    async with emulator(capture=str(capture)) as emu:
        reader, writer = await asyncio.open_connection("127.0.0.1", emu.ports["motion"])
        for _ in range(3):
            writer.write(ping)
            await asyncio.wait_for(reader.readexactly(len(ping)), 5.0)
        writer.close()
        await writer.wait_closed()
        motion = emu.ports["motion"]
    argv = ["replay", str(capture), "--port", str(motion), "--reply-timeout", "2", "--against"]

    async def answer_once_then_close(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        frame = await r.readexactly(len(ping))
        w.write(decode(frame, LE32).to_reply(ReplyCode.SUCCESS).encode(LE32))
        await w.drain()
        w.close()

    server = await asyncio.start_server(answer_once_then_close, "127.0.0.1", 0)
    async with server:
        port = server.sockets[0].getsockname()[1]
        code, out, err = await asyncio.to_thread(run_cli, [*argv, f"127.0.0.1:{port}"], capsys)
    assert code == 1 and "Traceback" not in err
    assert "1 of 3 exchanges match" in out
    assert "the target closed the connection" in out or "Connection reset by peer" in out
    # a big-endian target: its replies cannot be framed as little-endian ones
    async with emulator(byte_order="big") as emu:
        code, out, err = await asyncio.to_thread(run_cli, [*argv, f"127.0.0.1:{emu.ports['motion']}"], capsys)
    assert code == 1 and "Traceback" not in err
    assert "0 of 3 exchanges match" in out  # it closes on our little-endian frames, or we cannot frame its
    assert "byte order" in out or "the target closed the connection" in out


def test_the_target_may_be_named_with_an_ipv6_address() -> None:
    from simple_message.cli import _host_and_ports

    assert _host_and_ports("127.0.0.1") == ("127.0.0.1", "")
    assert _host_and_ports("robot:50240,50241") == ("robot", "50240,50241")
    assert _host_and_ports("[::1]:50240,50241") == ("::1", "50240,50241")
    assert _host_and_ports("::1") == ("::1", "")
