"""A raw-bytes simple_message peer for end-to-end tests of the emulator.

It deliberately does not use the project's codec or client: requests are the reference vectors'
bytes with fields patched in place at their documented offsets (docs/reference/protocol.md §2.2), and
replies are cut and read with :mod:`struct`. A bug shared by our encoder and our server cannot hide.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from dataclasses import dataclass

from tests.refdata import load_vectors

PREFIX = 4
HEADER = 16  # prefix + msg_type + comm_type + reply_code


def vectors(order: str = "<") -> dict[str, bytes]:
    name = "vectors_le.txt" if order == "<" else "vectors_be.txt"
    return {v.name: v.frame for v in load_vectors(name)}


@dataclass(frozen=True)
class Frame:
    raw: bytes
    order: str

    @property
    def length(self) -> int:
        return int(struct.unpack_from(self.order + "i", self.raw, 0)[0])

    @property
    def msg_type(self) -> int:
        return int(struct.unpack_from(self.order + "i", self.raw, 4)[0])

    @property
    def comm_type(self) -> int:
        return int(struct.unpack_from(self.order + "i", self.raw, 8)[0])

    @property
    def reply_code(self) -> int:
        return int(struct.unpack_from(self.order + "i", self.raw, 12)[0])

    @property
    def body(self) -> bytes:
        return self.raw[HEADER:]

    def ints(self, count: int, offset: int = 0) -> tuple[int, ...]:
        return struct.unpack_from(f"{self.order}{count}i", self.raw, HEADER + offset)

    def reals(self, count: int, offset: int, real: str = "f") -> tuple[float, ...]:
        return struct.unpack_from(f"{self.order}{count}{real}", self.raw, HEADER + offset)


def status(frame: Frame) -> dict[str, int]:
    """STATUS (13) body as a dict."""
    names = ("drives_powered", "e_stopped", "error_code", "in_error", "in_motion", "mode", "motion_possible")
    return dict(zip(names, frame.ints(7), strict=True))


def joint_position(frame: Frame, real: str = "f") -> list[float]:
    """JOINT_POSITION (10): the 10 joint values after the sequence."""
    return list(frame.reals(10, 4, real))


def joint_traj_pt(
    template: bytes,
    sequence: int,
    joints: list[float],
    velocity: float = 0.0,
    duration: float = 0.0,
    *,
    order: str = "<",
    comm_type: int | None = None,
) -> bytes:
    """A JOINT_TRAJ_PT frame from a reference vector with its fields replaced (float32 layout)."""
    buf = bytearray(template)
    if comm_type is not None:
        struct.pack_into(order + "i", buf, 8, comm_type)
    padded = [*joints, *[0.0] * (10 - len(joints))]
    struct.pack_into(order + "i10fff", buf, HEADER, sequence, *padded, velocity, duration)
    return bytes(buf)


def joint_traj_pt_full(
    template: bytes,
    robot_id: int,
    sequence: int,
    valid_fields: int,
    time: float,
    positions: list[float],
    velocities: list[float] | None = None,
    *,
    accelerations: list[float] | None = None,
    order: str = "<",
) -> bytes:
    """A JOINT_TRAJ_PT_FULL frame from a reference vector with its fields replaced (float32)."""
    buf = bytearray(template)
    pos = [*positions, *[0.0] * (10 - len(positions))]
    vel = [*(velocities or []), *[0.0] * (10 - len(velocities or []))]
    acc = [*(accelerations or []), *[0.0] * (10 - len(accelerations or []))]
    struct.pack_into(order + "iiif10f10f10f", buf, HEADER, robot_id, sequence, valid_fields, time, *pos, *vel, *acc)
    return bytes(buf)


class RawPeer:
    """One TCP connection that sends bytes and cuts received bytes into frames."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, order: str = "<") -> None:
        self.reader, self.writer, self.order = reader, writer, order

    @classmethod
    async def connect(cls, port: int, order: str = "<") -> RawPeer:
        reader, writer = await asyncio.wait_for(asyncio.open_connection("127.0.0.1", port), 5.0)
        return cls(reader, writer, order)

    async def send(self, data: bytes) -> None:
        self.writer.write(data)
        await asyncio.wait_for(self.writer.drain(), 5.0)

    async def frame(self, timeout: float = 5.0) -> Frame:
        async with asyncio.timeout(timeout):
            prefix = await self.reader.readexactly(PREFIX)
            (length,) = struct.unpack(self.order + "i", prefix)
            assert 12 <= length <= 4096, f"implausible length {length} (byte order {self.order!r}?)"
            return Frame(prefix + await self.reader.readexactly(length), self.order)

    async def request(self, data: bytes, timeout: float = 5.0) -> Frame:
        await self.send(data)
        return await self.frame(timeout)

    async def reply_to(self, data: bytes, timeout: float = 5.0) -> Frame:
        """Send ``data`` and return the next SERVICE_REPLY (topics arriving meanwhile are skipped)."""
        await self.send(data)
        async with asyncio.timeout(timeout):
            while True:
                frame = await self.frame(timeout)
                if frame.comm_type == 3:
                    return frame

    async def next_of(self, msg_type: int, timeout: float = 5.0) -> Frame:
        """The next frame of ``msg_type`` (others are skipped)."""
        async with asyncio.timeout(timeout):
            while True:
                frame = await self.frame(timeout)
                if frame.msg_type == msg_type:
                    return frame

    async def closed(self, timeout: float = 5.0) -> bool:
        """Wait for the server to close the connection; True if it did (EOF)."""
        async with asyncio.timeout(timeout):
            while True:
                data = await self.reader.read(4096)
                if not data:
                    return True

    async def close(self) -> None:
        self.writer.close()
        with contextlib.suppress(OSError, TimeoutError):
            await asyncio.wait_for(self.writer.wait_closed(), 2.0)
