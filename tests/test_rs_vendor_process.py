"""The vendor profiles as users run them: a ``robot-server --profile abb|fanuc|staubli`` process,
driven with raw bytes (the reference vectors' frames, fields patched in place: tests/rawpeer.py).
The timing rules are asserted on a stepped clock in tests/test_rs_vendor_*.py; here: the ready
line, the replies' exact bytes, the state topics, a small motion to its end, a clean exit."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from tests.rawpeer import RawPeer, joint_traj_pt, vectors
from tests.test_rs_server_process import robot_server

pytestmark = pytest.mark.slow

T = 30.0
TARGET = [0.1, -0.05, 0.08, 0.1, -0.1, 0.2]


async def at_target(state: RawPeer, order: str, controller_target: list[float]) -> None:
    """Read the state port until a JOINT_POSITION is at the target (bounded: the frame reads time out)."""
    for _ in range(2000):
        frame = await state.next_of(10, T)
        joints = struct.unpack_from(order + "6f", frame.raw, 20)
        if max(abs(a - b) for a, b in zip(joints, controller_target, strict=True)) < 1e-3:
            return
    pytest.fail(f"the robot never reached {controller_target}")


async def test_abb_process(tmp_path: Path) -> None:
    v = vectors("<")
    async with robot_server(tmp_path, "--profile", "abb", "--speedup", "4", "--no-stdin") as server:
        assert "abb profile" in server.ready and "header-only replies" in server.ready
        state = await RawPeer.connect(server.ports["state"])
        kinds = [(await state.frame(T)).msg_type for _ in range(4)]
        assert kinds in ([10, 13, 10, 13], [13, 10, 13, 10])
        motion = await RawPeer.connect(server.ports["motion"])
        template = v["JOINT_TRAJ_PT_REQUEST_SEQ3"]
        for seq, q, d in ((-1, [0.0] * 6, 0.0), (1, [x / 2 for x in TARGET], 0.5), (-3, TARGET, 0.5)):
            reply = await motion.request(joint_traj_pt(template, seq, q, 0.0, d), T)
            assert reply.raw == bytes.fromhex("0c0000000b0000000300000001000000")
        await at_target(state, "<", TARGET)
        assert await server.terminate() == 0


async def test_fanuc_process(tmp_path: Path) -> None:
    v = vectors(">")
    async with robot_server(tmp_path, "--profile", "fanuc", "--speedup", "4", "--no-stdin") as server:
        assert "fanuc profile" in server.ready and "big-endian" in server.ready
        state = await RawPeer.connect(server.ports["state"], ">")
        kinds = [(await state.frame(T)).msg_type for _ in range(24)]
        assert kinds.count(13) == 2 and kinds.count(10) == 22  # a STATUS after every 11th JOINT_POSITION
        motion = await RawPeer.connect(server.ports["motion"], ">")
        template = v["JOINT_TRAJ_PT_REQUEST_SEQ3"]
        reply = await motion.request(joint_traj_pt(template, 0, TARGET, 0.5, 0.1, order=">"), T)
        assert reply.raw == struct.pack(">iiiii", 56, 10, 3, 1, 0) + bytes(40)
        await at_target(state, ">", TARGET)  # the controller's joints: what was sent
        assert await server.terminate() == 0


async def test_staubli_process(tmp_path: Path) -> None:
    v = vectors("<")
    async with robot_server(tmp_path, "--profile", "staubli", "--speedup", "4", "--no-stdin") as server:
        assert "staubli profile" in server.ready and "zeroed replies" in server.ready
        state = await RawPeer.connect(server.ports["state"])
        kinds = [(await state.frame(T)).msg_type for _ in range(12)]  # the first a second after connecting
        assert kinds[:6] == [10] * 6 and kinds[6] == 13
        motion = await RawPeer.connect(server.ports["motion"])
        template = v["JOINT_TRAJ_PT_REQUEST_SEQ3"]
        reply = await motion.request(joint_traj_pt(template, 5, TARGET, 0.5, 0.1), T)
        assert reply.raw == struct.pack("<iiiii", 64, 11, 3, 1, 5) + bytes(48)
        await at_target(state, "<", TARGET)
        assert await server.terminate() == 0
