"""The client side of one fuzz connection: its receiving end (:class:`Sink`: frames the replies
with :mod:`struct`, counts the answered PING markers, says when there is room to write), its
connection, and the PING that keeps the state monitor's connection alive.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
from collections import deque

from .protocol import MAX_LENGTH, PING

CONNECT_TIMEOUT = 5.0
_INT2 = {o: struct.Struct(o + "ii") for o in "<>"}


class Sink(asyncio.Protocol):
    """One fuzz connection's receiving side: frames the replies (struct) and counts PING replies.

    ``either``: frames may come in either byte order (an autodetecting server sends topics in the
    order of the last motion client until this connection's first frame is read): each frame's
    length prefix is read in ``order``, else in the other order when only that one is plausible.
    """

    def __init__(self, order: str, *, either: bool = False) -> None:
        self.order = order
        self.either = either
        self.transport: asyncio.Transport | None = None
        self.rbuf = b""
        self.type1 = 0
        self.bad = False
        self.outstanding: deque[int] = deque()  # frames sent up to each unanswered marker
        self.confirmed = 0
        self.closed = False
        self.paused = False
        self._wake: asyncio.Future[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def data_received(self, data: bytes) -> None:
        if self.bad:
            return
        buf = self.rbuf + data if self.rbuf else data
        pos, end = 0, len(buf)
        head = _INT2[self.order]
        other = _INT2[">" if self.order == "<" else "<"]
        woke = False
        while end - pos >= 8:
            length, msg_type = head.unpack_from(buf, pos)
            if not 12 <= length <= MAX_LENGTH and self.either:
                length, msg_type = other.unpack_from(buf, pos)
            if not 12 <= length <= MAX_LENGTH:
                self.bad = True
                break
            if pos + 4 + length > end:
                break
            if msg_type == PING:
                self.type1 += 1
                if self.outstanding:
                    self.confirmed = self.outstanding.popleft()
                    woke = True
            pos += 4 + length
        self.rbuf = buf[pos:]
        if woke:
            self.notify()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        self.notify()

    def alive(self) -> bool:
        return not self.closed

    def pause_writing(self) -> None:
        self.paused = True

    def resume_writing(self) -> None:
        self.paused = False
        self.notify()

    def notify(self) -> None:
        if self._wake is not None and not self._wake.done():
            self._wake.set_result(None)

    async def wait(self, timeout: float) -> bool:
        """Until something happens (a marker answered, room to write, closed); False on timeout."""
        self._wake = asyncio.get_running_loop().create_future()
        try:
            await asyncio.wait_for(self._wake, timeout)
        except TimeoutError:
            return False
        finally:
            self._wake = None
        return True


async def keep_alive(writer: asyncio.StreamWriter, frame: bytes, stop: asyncio.Event) -> None:
    while not stop.is_set() and not writer.is_closing():
        writer.write(frame)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 2.0)


async def connect(loop: asyncio.AbstractEventLoop, sink: Sink, host: str, port: int) -> asyncio.Transport:
    transport, _ = await asyncio.wait_for(loop.create_connection(lambda: sink, host, port), CONNECT_TIMEOUT)
    return transport
