"""What a connection sends: frames handed to its transport, in order, in bounded memory.

A frame goes out at once (:meth:`Outbound.write_frame`, :meth:`Outbound.send_nowait`), or is queued
to be written with the others queued in one write (:meth:`Outbound.queue`, then
:meth:`Outbound.flush`: a server's broadcast, one write per connection for the topics of one loop
iteration); anything sent while frames are queued goes out after them. Each write is handed to the
transport whole, or in the pieces the connection's ``write_split`` cuts (a controller that sends a
message's parts with separate calls), and then to the tap.

Writes are bounded: a sender that waits (:meth:`.Connection.send`, requests) waits at most
``drain_timeout`` s for the peer once ``max_write_buffer`` bytes are queued, then the connection is
closed; the non-waiting ways close it as soon as the buffer is over the limit. A stalled peer
therefore costs at most one buffer of memory and never delays anyone else.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING

from ..errors import ConnectionClosed
from .taps import TapPoint

if TYPE_CHECKING:
    from . import Connection

__all__ = ["Outbound"]

#: every frame as hex at DEBUG (the name is what the log lines have always shown)
frames_log = logging.getLogger("simple_message.connection.frames")


class Outbound:
    """The sending side of one connection (see the module docstring). Each call is given the
    connection, whose transport, ``write_split`` and limits (``max_write_buffer``,
    ``drain_timeout``) it uses as they are then; it keeps no reference to it (no reference cycle)."""

    __slots__ = ("drain_waiters", "paused", "queued", "tap")

    def __init__(self, tap: TapPoint) -> None:
        self.tap = tap
        #: frames queued by queue(), written together by flush()
        self.queued: list[bytes] = []
        #: the transport asked us to stop writing (its buffer is over its high-water mark)
        self.paused = False
        #: senders waiting for the transport to take its buffer down
        self.drain_waiters: list[asyncio.Future[None]] = []

    def write_frame(self, connection: Connection, frame: bytes) -> None:
        """Write ``frame`` (after what is queued) unless the transport is closing."""
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", connection.name, frame.hex())
        if self.queued:  # what was queued goes first
            self.queued.append(frame)
            frame = b"".join(self.queued)
            self.queued.clear()
        if not connection.transport.is_closing():  # lost under us: connection_lost is on its way
            self.write(connection, frame)

    def write(self, connection: Connection, data: bytes) -> None:
        """Hand ``data`` to the transport: in one write, or split as ``write_split`` says."""
        transport = connection.transport
        write_split = connection.write_split
        if write_split is None:
            transport.write(data)
        else:
            for piece in write_split(data):
                transport.write(piece)
        if self.tap.tap is not None:
            self.tap.data(True, data)

    def queue(self, connection: Connection, frame: bytes) -> bool:
        """Queue ``frame`` for :meth:`flush`; whether it was queued (not on a closed connection)."""
        if connection.closed:
            return False
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", connection.name, frame.hex())
        self.queued.append(frame)
        return True

    def flush(self, connection: Connection) -> bool:
        """Write what is queued, in one write; a peer with more than ``max_write_buffer`` bytes
        unread is closed then. Whether the connection is still open."""
        queued = self.queued
        if not queued or connection.closed:
            queued.clear()
            return not connection.closed
        data = queued[0] if len(queued) == 1 else b"".join(queued)
        queued.clear()
        transport = connection.transport
        if transport.is_closing():  # lost under us: connection_lost is on its way
            return False
        self.write(connection, data)
        if transport.get_write_buffer_size() > connection.max_write_buffer:
            connection.abort(ConnectionClosed(f"peer fell {transport.get_write_buffer_size()} bytes behind"))
            return False
        return True

    def send_nowait(self, connection: Connection, frame: bytes) -> bool:
        """Write ``frame`` (after what is queued) without waiting; a peer with more than
        ``max_write_buffer`` bytes unread is closed. Whether the frame was written."""
        if connection.closed:
            return False
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", connection.name, frame.hex())
        transport = connection.transport
        if transport.is_closing():  # lost under us (a reset): writing on would only log warnings
            self.queued.clear()
            return False
        if self.queued:
            self.queued.append(frame)
            frame = b"".join(self.queued)
            self.queued.clear()
        if connection.write_split is None and self.tap.tap is None:
            transport.write(frame)  # what write() does then, one call less (a server's PING reply)
        else:
            self.write(connection, frame)
        if transport.get_write_buffer_size() > connection.max_write_buffer:
            connection.abort(ConnectionClosed(f"peer fell {transport.get_write_buffer_size()} bytes behind"))
            return False
        return True

    async def drained(self, connection: Connection) -> None:
        """Wait for the transport to take the buffer down (at most ``drain_timeout`` s); a peer that
        does not read by then is closed, and :class:`~..errors.ConnectionClosed` raised."""
        if not self.paused or connection.closed:
            return
        waiter: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.drain_waiters.append(waiter)
        try:
            await asyncio.wait_for(waiter, connection.drain_timeout)
        except (TimeoutError, ConnectionError) as exc:
            connection.abort(ConnectionClosed(f"peer did not read for {connection.drain_timeout} s"))
            raise ConnectionClosed(f"{connection.name}: peer stalled, connection closed") from exc
        finally:
            with contextlib.suppress(ValueError):
                self.drain_waiters.remove(waiter)

    def wake(self, error: BaseException | None) -> None:
        """The transport took its buffer down (``error`` ``None``), or never will: the waiting
        senders go on, or fail with ``error``."""
        waiters, self.drain_waiters = self.drain_waiters, []
        for waiter in waiters:
            if not waiter.done():
                if error is None:
                    waiter.set_result(None)
                else:
                    waiter.set_exception(error)

    def end(self, connection: Connection, graceful: bool) -> None:
        """The connection closes: what is queued goes out before the close (``graceful``, and the
        transport not closing already), or is dropped (a stalled peer would hold the close for ever)."""
        queued = self.queued
        if graceful and queued and not connection.transport.is_closing():
            data = b"".join(queued)
            connection.transport.write(data)
            if self.tap.tap is not None:
                self.tap.data(True, data)
        queued.clear()
