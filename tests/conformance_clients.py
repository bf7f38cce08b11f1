"""Helpers of the client-suite tests (tests/test_sm_conformance_client.py): an in-process emulator
to put behind the suite, a raw-stream client, and the broken clients each rule must catch.

The broken clients use raw asyncio streams and the project's message classes only to build and read
frames: what makes each one broken (two points in flight, a frame in the other byte order, a resend
after a reconnect...) is something a well-behaved client (``simple_message.endpoints.Client``, the
driver) refuses to do, so they write the bytes themselves.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import AsyncIterator, Sequence
from typing import Any

from robot_server.emulator import Emulator, EmulatorConfig
from simple_message.conformance.client import ClientSuiteOptions
from simple_message.constants import MotoCommand, MotoResult, ValidFields
from simple_message.messages import (
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Ping,
    decode,
)
from simple_message.wire import BE32, LE32, WireFormat

#: every wait of these helpers is bounded by this (s)
TIMEOUT = 10.0
HOST = "127.0.0.1"
Upstream = dict[str, tuple[str, int]]


@contextlib.asynccontextmanager
async def emulator(profile: str = "generic", **options: Any) -> AsyncIterator[tuple[Emulator, Upstream]]:
    """An in-process emulator playing the controller of ``profile``, on free ports, 4x real time
    (the generic and MotoROS ones publishing state at 100 Hz; the vendors at their own rates)."""
    config = EmulatorConfig(
        profile=profile,
        motion_port=0,
        state_port=0,
        io_port=0,
        state_rate=100.0 if profile in ("generic", "motoros") else None,
        speedup=4.0,
        **options,
    )
    async with Emulator(config) as emu:
        yield emu, {role: (HOST, port) for role, port in emu.ports.items()}


def options(profile: str, upstream: Upstream | None, **kwargs: Any) -> ClientSuiteOptions:
    """The suite's options for a test: free ports on loopback."""
    return ClientSuiteOptions(
        profile=profile,
        host=HOST,
        motion_port=0,
        state_port=0,
        io_port=0 if profile == "motoros" else None,
        upstream=upstream,
        **kwargs,
    )


class RawClient:
    """One TCP connection with raw streams: frames written as given, replies read by length prefix."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, wire: WireFormat) -> None:
        self.reader, self.writer, self.wire = reader, writer, wire

    @classmethod
    async def open(cls, port: int, wire: WireFormat = LE32) -> RawClient:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(HOST, port), TIMEOUT)
        return cls(reader, writer, wire)

    async def send(self, *items: Message | bytes) -> None:
        """Write each message (in this client's wire format) or raw frame, back to back."""
        self.writer.write(b"".join(i if isinstance(i, bytes) else i.encode(self.wire) for i in items))
        await self.writer.drain()

    async def reply(self) -> Message | None:
        """The next frame, decoded; None if the peer closed the connection."""
        try:
            async with asyncio.timeout(TIMEOUT):
                prefix = await self.reader.readexactly(4)
                (length,) = struct.unpack(self.wire.byte_order.struct_char + "i", prefix)
                body = await self.reader.readexactly(length)
        except (asyncio.IncompleteReadError, ConnectionError):
            return None
        return decode(prefix + body, self.wire)

    async def request(self, msg: Message) -> Message | None:
        await self.send(msg)
        return await self.reply()

    async def closed_by_peer(self) -> bool:
        """Whether the peer closes the connection (reading and dropping what comes first)."""
        with contextlib.suppress(ConnectionError):
            async with asyncio.timeout(TIMEOUT):
                while await self.reader.read(4096):
                    pass
        return True

    async def close(self) -> None:
        self.writer.close()
        with contextlib.suppress(ConnectionError):
            await asyncio.wait_for(self.writer.wait_closed(), TIMEOUT)


async def current_position(state_port: int, wire: WireFormat = LE32) -> tuple[float, ...]:
    """Where the robot is, read from a state port (JOINT_POSITION, or JOINT_FEEDBACK of group 0)."""
    client = await RawClient.open(state_port, wire)
    try:
        while True:
            msg = await client.reply()
            assert msg is not None, "the state port closed"
            if isinstance(msg, JointPosition):
                return msg.joint_data
            if isinstance(msg, JointFeedback) and msg.robot_id == 0:
                return msg.positions
    finally:
        await client.close()


def moved(here: Sequence[float], delta: float, joint: int = 0) -> tuple[float, ...]:
    q = list(here)
    q[joint] += delta
    return tuple(q)


def point(sequence: int, joints: Sequence[float], duration: float = 0.0) -> JointTrajPt:
    return JointTrajPt(sequence, tuple(joints), 0.0, duration)


def full_point(sequence: int, joints: Sequence[float], time: float, velocity: float = 0.0) -> JointTrajPtFull:
    fields = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
    velocities = (velocity,) + (0.0,) * 5
    return JointTrajPtFull(0, sequence, fields, time, tuple(joints), velocities)


# -- the broken clients -------------------------------------------------------------------------------


async def two_in_flight(ports: dict[str, int]) -> None:
    """Streams point 0 and point 1 back to back, without waiting for point 0's reply."""
    here = await current_position(ports["state"])
    client = await RawClient.open(ports["motion"])
    try:
        await client.send(point(0, here), point(1, moved(here, 0.02), 0.5))
        assert await client.reply() is not None
        assert await client.reply() is not None
    finally:
        await client.close()


async def sequence_gap(ports: dict[str, int]) -> None:
    """Streams points 0, 1 and then 3: point 2 is never sent."""
    here = await current_position(ports["state"])
    client = await RawClient.open(ports["motion"])
    try:
        for seq in (0, 1, 3):
            assert await client.request(point(seq, moved(here, 0.01 * seq), 0.3 if seq else 0.0)) is not None
    finally:
        await client.close()


async def far_first_point(ports: dict[str, int]) -> Message | None:
    """Starts a trajectory 0.05 rad away from where the robot is; returns the controller's reply."""
    here = await current_position(ports["state"])
    client = await RawClient.open(ports["motion"])
    try:
        return await client.request(point(0, moved(here, 0.05)))
    finally:
        await client.close()


async def other_byte_order(ports: dict[str, int]) -> bool:
    """A little-endian PING, then one big-endian PING; whether the controller then closed the connection."""
    client = await RawClient.open(ports["motion"])
    try:
        assert await client.request(Ping()) is not None
        await client.send(Ping().encode(BE32))
        return await client.closed_by_peer()
    finally:
        await client.close()


async def resends_after_reconnect(ports: dict[str, int]) -> Message | None:
    """Two one-point trajectories, then a third whose connection the suite drops after point 1's reply;
    on the new connection it sends point 1 again (the controller had acknowledged it)."""
    here = await current_position(ports["state"])
    client = await RawClient.open(ports["motion"])
    try:
        for _ in range(2):
            assert await client.request(point(0, here)) is not None
        assert await client.request(point(0, here)) is not None
        again = point(1, moved(here, 0.02), 0.5)
        assert await client.request(again) is not None
        assert await client.closed_by_peer()
    finally:
        await client.close()
    client = await RawClient.open(ports["motion"])
    try:
        return await client.request(again)
    finally:
        await client.close()


async def skips_busy(ports: dict[str, int]) -> MotoMotionReply:
    """MotoROS: points 0, 1, 2 of a trajectory; point 2 is answered BUSY and the client goes on with
    point 3 instead of sending 2 again. Returns the reply to point 2."""
    here = await current_position(ports["state"])
    client = await RawClient.open(ports["motion"])
    try:
        enable = await client.request(MotoMotionCtrl(0, 0, MotoCommand.START_TRAJ_MODE))
        assert isinstance(enable, MotoMotionReply) and enable.result == MotoResult.SUCCESS, enable
        replies = []
        for seq in range(4):
            msg = full_point(seq, moved(here, 0.01 * seq), 0.2 * seq, 0.05 if 0 < seq < 3 else 0.0)
            reply = await client.request(msg)
            assert isinstance(reply, MotoMotionReply), reply
            replies.append(reply)
        return replies[2]
    finally:
        await client.close()


async def ignores_failure(ports: dict[str, int], motoros: bool = False) -> list[Message | None]:
    """A one-point trajectory, then a second one streamed 0, 1, 2 whatever the replies say (the
    reference streamer's way, industrial_core#118); returns the replies of the second."""
    here = await current_position(ports["state"])
    client = await RawClient.open(ports["motion"])
    try:
        if motoros:
            assert await client.request(MotoMotionCtrl(0, 0, MotoCommand.START_TRAJ_MODE)) is not None
            points: list[Message] = [full_point(seq, moved(here, 0.01 * seq), 0.2 * seq) for seq in (0, 0, 1, 2)]
        else:
            points = [point(seq, moved(here, 0.01 * seq), 0.2 if seq else 0.0) for seq in (0, 0, 1, 2)]
        return [await client.request(msg) for msg in points][1:]
    finally:
        await client.close()
