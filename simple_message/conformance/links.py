"""What the server suite sees: TCP links that cut frames tolerantly and keep every frame with its
time, byte order and decoded form, so that a rule can cite it as evidence.

The project's own :class:`~simple_message.connection.Connection` is made to *speak* the protocol:
it closes a link on a bad length and hides a frame in the wrong byte order behind an error. A
conformance probe must instead *describe* what the peer did, so a link cuts what it reads with the
suites' tolerant :class:`~.cutter.FrameCutter`: a frame whose length prefix reads as a plausible
length only in the other byte order is kept, marked ``swapped`` and decoded in that order
(docs/reference/protocol.md §10 pitfall 1, the dissector's heuristic); a prefix plausible in neither order
ends the link with the bytes shown. What is wrong with a frame or with how a link ended is a
:class:`Fault`, beside the text shown. Nothing here judges: the server suite's rules do
(:mod:`.server`, :mod:`.server_checks`, :mod:`.server_probes`, :mod:`.server_motion`).
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

from ..constants import LENGTH_SIZE
from ..errors import MalformedMessage
from ..framing import decode_or_error
from ..messages import Message
from ..wire import ByteOrder, WireFormat
from .cutter import MAX_FRAME, FrameCutter, other_order, prefix_order, read_length
from .report import Evidence

__all__ = ["Seen", "ProbeLink", "Fault", "MAX_FRAME", "other_order", "prefix_order"]

log = logging.getLogger(__name__)

#: frames and bytes a link keeps (its reader goes on, the oldest are dropped)
KEEP = 20_000
KEEP_BYTES = 8 * 1024 * 1024
#: bytes read at a time
_READ = 65536
#: bytes shown after a length prefix that is no length in either byte order
_SHOWN_AFTER_BAD_PREFIX = 60


class Fault(enum.Enum):
    """What is wrong with what the server sent, as the framing rules tell it apart (a frame's
    :attr:`Seen.fault`, a link's :attr:`ProbeLink.fault`); the text shown is beside it."""

    #: a length prefix that is no length in either byte order: the link could not be cut further
    PREFIX = "prefix"
    #: a body that fits no layout of its type in the float size read
    LAYOUT = "layout"
    #: the stream ended inside a frame
    CUT_SHORT = "cut short"


@dataclass(frozen=True)
class Seen:
    """One frame on a link: ``outgoing`` (the suite sent it) or received, at ``time`` (monotonic).
    ``swapped``: its length prefix was plausible only in the other byte order, and it was decoded in
    that order. ``message`` is its decoded form; ``fault`` what is wrong with it when it does not
    decode, and ``problem`` that said in words."""

    role: str
    outgoing: bool
    time: float
    raw: bytes
    order: ByteOrder
    swapped: bool = False
    message: Message | None = None
    problem: str | None = None
    fault: Fault | None = None

    def evidence(self, real_size: int = 4) -> Evidence:
        direction = f"{self.role} sent" if self.outgoing else f"{self.role} received"
        if self.swapped:
            direction += f" ({self.order.value}-endian)"
        ev = Evidence.frame(direction, self.raw, self.message, real_size)
        if self.problem and self.message is None:
            ev = Evidence(ev.kind, f"{ev.text}  [{self.problem}]")
        return ev


class ProbeLink:
    """One TCP connection to a port of the server under test.

    Frames are read by a background task into :attr:`frames`; :meth:`next_frame` waits for the
    next one. ``wire`` is the byte order and float size frames are read in; ``None`` until
    :meth:`set_wire` (the first received frame then decides the order, as the dissector does).
    """

    def __init__(self, role: str, wire: WireFormat | None, on_frame: Callable[[Seen], None] | None = None) -> None:
        self.role = role
        self.wire = wire
        self.frames: list[Seen] = []  # received
        self.sent: list[Seen] = []
        self.closed_by_peer = False
        self.closed_at: float | None = None  # monotonic time the peer closed it
        self.close_reason: str | None = None
        #: what was wrong when the link ended (a bad prefix, or the stream cut inside a frame)
        self.fault: Fault | None = None
        self._on_frame = on_frame
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._arrived = asyncio.Event()
        self._cutter = FrameCutter(wire.byte_order if wire is not None else ByteOrder.LITTLE)
        self._read = 0  # frames handed out by next_frame
        self._bytes = 0  # in self.frames

    async def open(self, host: str, port: int, timeout: float) -> ProbeLink:
        self._reader, self._writer = await asyncio.wait_for(asyncio.open_connection(host, port), timeout)
        self._task = asyncio.get_running_loop().create_task(self._run(), name=f"conformance {self.role} reader")
        return self

    @property
    def alive(self) -> bool:
        return self._task is not None and not self._task.done()

    def set_wire(self, wire: WireFormat) -> None:
        """Read frames in ``wire`` from now on, and decode those kept again in its float size (the
        bytes after a bad length prefix are no frame of any size: they stay as they are)."""
        self.wire = wire
        self._cutter.order = wire.byte_order
        for i, seen in enumerate(self.frames):
            if seen.fault is Fault.PREFIX:
                continue
            decoded = decode_or_error(seen.raw, WireFormat(seen.order, wire.real_size))
            if isinstance(decoded, MalformedMessage):
                self.frames[i] = replace(seen, message=None, problem=str(decoded), fault=Fault.LAYOUT)
            else:
                self.frames[i] = replace(seen, message=decoded, problem=None, fault=None)

    def send(self, data: bytes, message: Message | None = None) -> Seen:
        """Write ``data`` (one frame or any bytes) and keep it as sent."""
        assert self._writer is not None
        wire = self.wire
        order = wire.byte_order if wire else ByteOrder.LITTLE
        seen = Seen(self.role, True, time.monotonic(), bytes(data), order, message=message)
        if len(self.sent) < KEEP:
            self.sent.append(seen)
        with contextlib.suppress(ConnectionError, RuntimeError):
            self._writer.write(data)
        return seen

    def send_message(self, message: Message) -> Seen:
        assert self.wire is not None, "the wire format is decided before a message is sent"
        return self.send(message.encode(self.wire), message)

    async def next_frame(self, timeout: float) -> Seen | None:
        """The next frame not yet handed out, or ``None`` when none came within ``timeout`` or the
        link ended."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while self._read >= len(self.frames):
            if not self.alive:
                return None
            self._arrived.clear()
            remaining = deadline - loop.time()
            if remaining <= 0:
                return None
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), remaining)
        seen = self.frames[self._read]
        self._read += 1
        return seen

    def skip_pending(self) -> None:
        """Forget frames received but not handed out (before a fresh exchange)."""
        self._read = len(self.frames)

    async def wait_closed(self, timeout: float) -> bool:
        """Whether the peer closed the link within ``timeout``."""
        if self._task is None:
            return True
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.shield(self._task), timeout)
        return self._task.done()

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._writer.wait_closed(), 1.0)
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task

    async def _run(self) -> None:
        assert self._reader is not None
        try:
            while True:
                data = await self._reader.read(_READ)
                if not data:
                    self.closed_by_peer = True
                    # the part being read when the stream ended: the prefix, or once it is whole the body
                    held = self._cutter.held
                    partial = held - LENGTH_SIZE if held >= LENGTH_SIZE else held
                    if partial:
                        self.close_reason = f"closed in the middle of a frame ({partial} bytes)"
                        self.fault = Fault.CUT_SHORT
                    return
                for raw, order in self._cutter.feed(data):
                    if order is None:
                        await self._bad_prefix(raw)
                        return
                    self._keep(self._frame(raw, order))
        except (ConnectionError, OSError) as exc:
            self.closed_by_peer = True
            self.close_reason = f"connection error: {exc}"
        finally:
            if self.closed_by_peer:
                self.closed_at = time.monotonic()
            self._arrived.set()

    def _frame(self, raw: bytes, order: ByteOrder) -> Seen:
        # before the order is known, the first frame decides it; after, another order is a finding
        swapped = self.wire is not None and order is not self.wire.byte_order
        real_size = self.wire.real_size if self.wire else 4
        decoded = decode_or_error(raw, WireFormat(order, real_size))
        if isinstance(decoded, MalformedMessage):
            return Seen(
                self.role, False, time.monotonic(), raw, order, swapped, problem=str(decoded), fault=Fault.LAYOUT
            )
        return Seen(self.role, False, time.monotonic(), raw, order, swapped, message=decoded)

    async def _bad_prefix(self, rest: bytes) -> None:
        """A length prefix that is no length in either byte order: kept, with what follows it, as
        the link's last frame; the link reads no further."""
        assert self._reader is not None
        expected = self._cutter.order
        prefix, after = rest[:LENGTH_SIZE], rest[LENGTH_SIZE : LENGTH_SIZE + _SHOWN_AFTER_BAD_PREFIX]
        if not after:
            after = await _read_some(self._reader, _SHOWN_AFTER_BAD_PREFIX)
        problem = f"length prefix {read_length(prefix, expected)}"
        self._keep(
            Seen(self.role, False, time.monotonic(), prefix + after, expected, problem=problem, fault=Fault.PREFIX)
        )
        self.close_reason = f"a length prefix that is no length in either byte order ({prefix.hex()})"
        self.fault = Fault.PREFIX

    def _keep(self, seen: Seen) -> None:
        if len(self.frames) >= KEEP or self._bytes > KEEP_BYTES:
            drop = len(self.frames) // 2
            self._bytes -= sum(len(f.raw) for f in self.frames[:drop])
            del self.frames[:drop]
            self._read = max(0, self._read - drop)
        self.frames.append(seen)
        self._bytes += len(seen.raw)
        self._arrived.set()
        if self._on_frame is not None:
            self._on_frame(seen)


async def _read_some(reader: asyncio.StreamReader, n: int) -> bytes:
    with contextlib.suppress(Exception):
        return await asyncio.wait_for(reader.read(n), 0.05)
    return b""


#: the name this link had before the suites named their links for what they are (issue 37)
Link = ProbeLink
