"""The vendor profiles (abb, fanuc, staubli) on a clock the test advances, watched at the wire.

:func:`vendor_emulator` is :func:`tests.stepped.stepped_emulator` with a :class:`Wire` tap that
stamps every frame the emulator writes and reads with the *controller* time of that instant, so a
test asserts when a reply went out, or when a point was read, in controller time: the same on any
machine. The peers are :class:`tests.rawpeer.RawPeer` (raw bytes, not the project's codec).
"""

from __future__ import annotations

import contextlib
import logging
import struct
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any

from robot_server.control import SteppedClock
from robot_server.emulator import Emulator, EmulatorConfig
from simple_message.connection import TapLink
from tests.rawpeer import RawPeer
from tests.stepped import TICK, advance_until, settle, step

__all__ = ["Wire", "vendor_emulator", "connect", "written", "TICK"]


@dataclass
class Wire:
    """A tap: every chunk each connection wrote or read, with the controller time of that moment."""

    emu: Emulator | None = None
    #: (controller time, connection name, outgoing, bytes), in order
    chunks: list[tuple[float, str, bool, bytes]] = field(default_factory=list)
    closed_links: list[str] = field(default_factory=list)

    def opened(self, link: TapLink, time_ns: int) -> None:
        pass

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        assert self.emu is not None
        self.chunks.append((self.emu.cell.time, link.name, outgoing, bytes(data)))

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        self.closed_links.append(link.name)

    def out(self, port: str) -> list[tuple[float, bytes]]:
        """What the emulator wrote on connections of ``port`` ("motion", "state"), frame by frame
        as written, with controller times."""
        return [(t, b) for t, name, outgoing, b in self.chunks if outgoing and name.startswith(port + " ")]


def written(wire: Wire, port: str, order: str = "<") -> list[tuple[float, bytes]]:
    """The frames written on ``port``, cut by their length prefixes (a write may hold several)."""
    frames = []
    for t, chunk in wire.out(port):
        pos = 0
        while pos + 4 <= len(chunk):
            (length,) = struct.unpack_from(order + "i", chunk, pos)
            frames.append((t, chunk[pos : pos + 4 + length]))
            pos += 4 + length
    return frames


@contextlib.asynccontextmanager
async def vendor_emulator(profile: str, **options: Any) -> AsyncIterator[tuple[Emulator, SteppedClock, Wire]]:
    """An emulator playing ``profile`` on free loopback ports, controller time moved by the test,
    its traffic stamped by a :class:`Wire`."""
    options.setdefault("motion_port", 0)
    options.setdefault("state_port", 0)
    clock = SteppedClock()
    emu = Emulator(EmulatorConfig(profile=profile, **options), clock=clock)
    wire = Wire(emu)
    emu.taps.append(wire)
    await emu.start()
    try:
        await step(clock, 0.0)
        yield emu, clock, wire
        emu.cell.stop()
        await settle(emu, clock, limit=60.0)
    finally:
        await emu.close(settle_timeout=1.0)


async def connect(emu: Emulator, port: str, order: str = "<") -> RawPeer:
    return await RawPeer.connect(emu.ports[port], order)


async def until(clock: SteppedClock, predicate: Any, *, limit: float = 5.0, what: str = "it") -> None:
    await advance_until(clock, predicate, limit=limit, what=what)


def logged(caplog: Any, text: str, level: int = logging.WARNING) -> int:
    """How many records at ``level`` or above contain ``text``."""
    return sum(1 for r in caplog.records if r.levelno >= level and text in r.getMessage())
