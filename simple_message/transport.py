"""Byte-stream transports: TCP, serial links and an in-process pair for tests.

Every opener returns an asyncio ``(StreamReader, StreamWriter)`` pair, usable as it is (tests and
tools speak raw bytes through it). A :class:`~.connection.Connection` given a pair takes its
transport over (:func:`take_over`, with whatever the reader had buffered) and is that transport's
protocol from then on: the bytes go from the transport's callback straight to the protocol state,
with no stream buffer and no task in between. Every transport here supports that hand-over
(``set_protocol``) and flow control both ways (``pause_reading``, ``pause_writing``). Framing never
happens here (pymodbus mixes the two; we do not).

* **TCP**: :func:`open_tcp` and the servers of :mod:`.endpoints` use asyncio streams; TCP_NODELAY is
  set on every socket (simple_message is request/reply with small frames; Nagle's algorithm would
  add up to 40 ms per exchange). IPv4 and IPv6.
* **Serial**: :func:`open_serial` opens any pyserial URL with ``serial_for_url`` (``/dev/tty*``,
  ``socket://host:port``, ``rfc2217://host:port``, ``loop://``). Ports with a file descriptor
  (posix serial devices, pseudo-terminals, ``socket://``) get a small non-blocking transport of our
  own driven by ``loop.add_reader``/``add_writer``: no threads, no extra dependency. We did not take
  pyserial-asyncio: it is the same add_reader design, it has had long gaps between releases and a
  fork (pyserial-asyncio-fast) to fill them, and it offers nothing for ports *without* a file
  descriptor. Those (``loop://``, and ``rfc2217://``, whose telnet option handling runs in
  pyserial's own thread) get a thread-backed transport: one reader thread polling with a short
  timeout and one writer thread, both handing data to the event loop thread-safely.
  :func:`open_fd` wraps a raw descriptor, e.g. the master side of ``os.openpty()``.
* **In-process pair**: :func:`memory_pair` connects two stream pairs in memory and can split,
  coalesce, delay and corrupt the bytes on purpose, to test framing and timeouts without sockets.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import queue
import socket
import struct
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any, cast

__all__ = [
    "StreamPair",
    "open_tcp",
    "set_nodelay",
    "unread_by_peers",
    "take_over",
    "open_serial",
    "open_fd",
    "memory_pair",
    "FaultSpec",
]

log = logging.getLogger(__name__)

StreamPair = tuple[asyncio.StreamReader, asyncio.StreamWriter]

#: Read size for every transport.
READ_SIZE = 65536
#: Write buffer size above which a transport asks its protocol to pause writing.
HIGH_WATER = 64 * 1024


def set_nodelay(writer: asyncio.StreamWriter | asyncio.BaseTransport) -> None:
    """Disable Nagle's algorithm on a TCP stream or transport (a no-op for other transports)."""
    sock = writer.get_extra_info("socket")
    if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


if sys.platform.startswith("linux"):
    import fcntl
    import termios

    #: the ioctl that reads a socket's unacknowledged send queue (Linux's SIOCOUTQ is TIOCOUTQ)
    _OUTQ: int | None = getattr(termios, "TIOCOUTQ", None)
else:  # pragma: no cover
    _OUTQ = None

#: the kernel's table of TCP sockets, by address family (Linux)
_PROC_TCP: dict[int, str] = {socket.AF_INET: "/proc/net/tcp", socket.AF_INET6: "/proc/net/tcp6"}


def unread_by_peers(socks: Sequence[Any]) -> list[int]:
    """For each TCP socket (a ``socket.socket`` or a transport's ``get_extra_info("socket")``), the
    bytes sent on it that its peer's program has not read, as far as the OS tells (0 where it tells
    nothing): the send queue not yet acknowledged (Linux ``SIOCOUTQ``) and, for a peer on this
    machine, what waits unread in the peer's own receive queue (``/proc/net/tcp``). The second
    matters: a peer on loopback that never reads acknowledges megabytes into its receive buffer
    while our side of the socket looks drained."""
    unread = [0] * len(socks)
    wanted: dict[tuple[int, str, str], int] = {}  # (family, peer's address, ours) -> index
    for i, sock in enumerate(socks):
        if _OUTQ is None:
            break
        with contextlib.suppress(OSError, ValueError):
            unread[i] = struct.unpack("i", fcntl.ioctl(sock.fileno(), _OUTQ, b"\0\0\0\0"))[0]
            if sock.family in _PROC_TCP:
                ours, peer = sock.getsockname(), sock.getpeername()
                wanted[(sock.family, _proc_address(sock.family, peer), _proc_address(sock.family, ours))] = i
    for family in {key[0] for key in wanted}:
        try:
            with open(_PROC_TCP[family], "rb") as table:
                lines = table.read().split(b"\n")[1:]
        except OSError:
            continue
        for line in lines:
            # sl local_address rem_address st tx_queue:rx_queue ...; the peer's socket has the
            # peer's address as its local one
            fields = line.split(None, 5)
            if len(fields) < 5:
                continue
            i = wanted.get((family, fields[1].decode(), fields[2].decode()), -1)
            if i >= 0:
                with contextlib.suppress(ValueError, IndexError):
                    unread[i] += int(fields[4].split(b":")[1], 16)
    return unread


def _proc_address(family: int, address: tuple[Any, ...]) -> str:
    """``address`` as /proc/net/tcp prints it: each 32-bit word of the IP in host order, in hex,
    then the port."""
    packed = socket.inet_pton(family, address[0])
    words = struct.unpack(f"={len(packed) // 4}I", packed)
    return "".join(f"{word:08X}" for word in words) + f":{address[1]:04X}"


async def open_tcp(host: str, port: int, *, timeout: float | None = 10.0) -> StreamPair:
    """Connect to ``host:port`` (IPv4 or IPv6) with TCP_NODELAY set."""
    reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), timeout)
    set_nodelay(writer)
    return reader, writer


def take_over(
    streams: StreamPair, protocol: asyncio.BaseProtocol
) -> tuple[asyncio.BaseTransport, bytes, tuple[BaseException | None] | None, bool]:
    """Make ``protocol`` the protocol of the stream pair's transport, from now on.

    Returns the transport; the bytes the reader had already buffered (nobody else must read the
    pair any more); the end of the input if the reader had seen it, as ``(exception or None,)``,
    else ``None``; and whether the transport is already closed (then ``protocol`` gets no
    ``connection_lost``).
    """
    reader, writer = streams
    # asyncio has no public way to take what a StreamReader holds without awaiting: its buffer,
    # end-of-input and pause flags are read directly. Should a Python release rename them, fail
    # here, loudly, rather than drop the buffered bytes.
    missing = [name for name in ("_buffer", "_eof", "_paused") if not hasattr(reader, name)]
    if missing:  # pragma: no cover - a future CPython
        raise RuntimeError(f"asyncio.StreamReader has no {', '.join(missing)}: take_over needs updating")
    transport = cast(asyncio.Transport, writer.transport)
    transport.set_protocol(protocol)
    buffer: bytearray = getattr(reader, "_buffer")  # noqa: B009 - private, checked above
    data = bytes(buffer)
    buffer.clear()
    error = reader.exception()
    end: tuple[BaseException | None] | None = None
    if error is not None or getattr(reader, "_eof"):  # noqa: B009
        end = (error,)
    if getattr(reader, "_paused") and not transport.is_closing():  # noqa: B009
        transport.resume_reading()  # the reader had paused it (its buffer was full)
    return transport, data, end, transport.is_closing()


def _streams(
    loop: asyncio.AbstractEventLoop, make_transport: Callable[[asyncio.Protocol], asyncio.Transport]
) -> StreamPair:
    reader = asyncio.StreamReader(limit=READ_SIZE, loop=loop)
    protocol = asyncio.StreamReaderProtocol(reader, loop=loop)
    transport = make_transport(protocol)
    writer = asyncio.StreamWriter(transport, protocol, reader, loop)
    return reader, writer


class _Base(asyncio.Transport):
    """What every transport below shares: a closing flag, its protocol (replaceable), no half-close."""

    _closing = False
    _protocol: asyncio.Protocol

    def is_closing(self) -> bool:
        return self._closing

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = protocol  # type: ignore[assignment]

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def can_write_eof(self) -> bool:
        return False


class _WriteFlow(_Base):
    """High/low water marks shared by the transports below (asyncio's flow-control contract)."""

    _high = HIGH_WATER
    _low = HIGH_WATER // 4
    _paused = False

    def _buffer_size(self) -> int:
        raise NotImplementedError

    def _maybe_pause(self) -> None:
        if not self._paused and self._buffer_size() > self._high:
            self._paused = True
            self._protocol.pause_writing()

    def _maybe_resume(self) -> None:
        if self._paused and self._buffer_size() <= self._low:
            self._paused = False
            self._protocol.resume_writing()


class _FdTransport(_WriteFlow):
    """A non-blocking transport over a file descriptor (serial device, pty, socket)."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        fd: int,
        protocol: asyncio.Protocol,
        *,
        on_close: Callable[[], None] | None = None,
        extra: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(extra)
        self._loop = loop
        self._fd = fd
        self._protocol = protocol
        self._on_close = on_close
        self._buffer = bytearray()
        self._closing = False
        self._reading = True
        os.set_blocking(fd, False)
        loop.add_reader(fd, self._read_ready)
        loop.call_soon(protocol.connection_made, self)

    def _buffer_size(self) -> int:
        return len(self._buffer)

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            # A pty master reads EIO once the slave side is closed: that is the peer hanging up.
            self._force_close(None if exc.errno == errno.EIO else exc)
            return
        if not data:
            self._force_close(None)
            return
        self._protocol.data_received(data)

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing or not data:
            return
        if not self._buffer:
            try:
                n = os.write(self._fd, data)
            except (BlockingIOError, InterruptedError):
                n = 0
            except OSError as exc:
                self._force_close(exc)
                return
            data = memoryview(data)[n:]
            if not data:
                return
            self._loop.add_writer(self._fd, self._write_ready)
        self._buffer += data
        self._maybe_pause()

    def _write_ready(self) -> None:
        try:
            n = os.write(self._fd, self._buffer)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._force_close(exc)
            return
        del self._buffer[:n]
        self._maybe_resume()
        if not self._buffer:
            self._loop.remove_writer(self._fd)
            if self._closing:
                self._finish(None)

    def get_write_buffer_size(self) -> int:
        return len(self._buffer)

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        self._high = HIGH_WATER if high is None else high
        self._low = self._high // 4 if low is None else low

    def pause_reading(self) -> None:
        if self._reading and not self._closing:
            self._reading = False
            self._loop.remove_reader(self._fd)

    def resume_reading(self) -> None:
        if not self._reading and not self._closing:
            self._reading = True
            self._loop.add_reader(self._fd, self._read_ready)

    def is_reading(self) -> bool:
        return self._reading and not self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        self._loop.remove_reader(self._fd)
        if not self._buffer:
            self._loop.call_soon(self._finish, None)

    def abort(self) -> None:
        self._force_close(None)

    def _force_close(self, exc: Exception | None) -> None:
        if self._fd < 0:
            return
        self._closing = True
        self._buffer.clear()
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._loop.call_soon(self._finish, exc)

    def _finish(self, exc: Exception | None) -> None:
        if self._fd < 0:
            return
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._fd = -1
        try:
            self._protocol.connection_lost(exc)
        finally:
            if self._on_close is not None:
                self._on_close()


class _ThreadTransport(_WriteFlow):
    """A transport for pyserial ports without a file descriptor (``loop://``, ``rfc2217://``)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, port: Any, protocol: asyncio.Protocol) -> None:
        super().__init__({"serial": port})
        self._loop = loop
        self._port = port
        self._protocol = protocol
        self._closing = False
        self._stop = threading.Event()
        self._may_read = threading.Event()
        self._may_read.set()
        self._pending = 0
        self._queue: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        port.timeout = 0.02
        self._reader = threading.Thread(target=self._read_loop, name=f"serial-read {port.port}", daemon=True)
        self._writer = threading.Thread(target=self._write_loop, name=f"serial-write {port.port}", daemon=True)
        loop.call_soon(protocol.connection_made, self)
        self._reader.start()
        self._writer.start()

    def _buffer_size(self) -> int:
        return self._pending

    def _read_loop(self) -> None:
        error: Exception | None = None
        try:
            while not self._stop.is_set():
                if not self._may_read.wait(0.1):  # reading paused (flow control)
                    continue
                data = self._port.read(max(1, self._port.in_waiting))
                if data:
                    self._loop.call_soon_threadsafe(self._deliver, bytes(data))
        except Exception as exc:  # a pyserial error ends the link
            error = exc
        if not self._stop.is_set():
            self._loop.call_soon_threadsafe(self._lost, error)

    def _deliver(self, data: bytes) -> None:
        if not self._closing:
            self._protocol.data_received(data)

    def _write_loop(self) -> None:
        while True:
            data = self._queue.get()
            if data is None:
                # Closing can block (rfc2217 negotiates and joins its thread): do it here, not
                # on the event loop.
                with contextlib.suppress(Exception):
                    self._port.close()
                return
            try:
                self._port.write(data)
            except Exception as exc:
                self._loop.call_soon_threadsafe(self._lost, exc)
                return
            self._loop.call_soon_threadsafe(self._written, len(data))

    def _written(self, n: int) -> None:
        self._pending -= n
        self._maybe_resume()

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing or not data:
            return
        self._pending += len(data)
        self._queue.put(bytes(data))
        self._maybe_pause()

    def get_write_buffer_size(self) -> int:
        return self._pending

    def pause_reading(self) -> None:
        self._may_read.clear()  # a read already handed over is still delivered

    def resume_reading(self) -> None:
        self._may_read.set()

    def is_reading(self) -> bool:
        return self._may_read.is_set() and not self._closing

    def close(self) -> None:
        self._lost(None)

    def abort(self) -> None:
        self._lost(None)

    def _lost(self, exc: Exception | None) -> None:
        if self._closing:
            return
        self._closing = True
        self._stop.set()
        self._may_read.set()
        self._queue.put(None)  # the writer thread closes the port after what is queued
        self._loop.call_soon(self._protocol.connection_lost, exc)


async def open_serial(url: str, **serial_options: Any) -> StreamPair:
    """Open a serial link by pyserial URL and return it as an asyncio stream pair.

    ``serial_options`` go to ``serial.serial_for_url`` (``baudrate``, ``bytesize``, ...). The port
    is closed when the writer is closed or the peer hangs up.
    """
    import serial  # imported here: only serial users need pyserial at import time

    loop = asyncio.get_running_loop()
    port = await loop.run_in_executor(None, lambda: serial.serial_for_url(url, **serial_options))
    fileno = None
    with contextlib.suppress(Exception):
        fileno = port.fileno()
    if isinstance(fileno, int) and fileno >= 0:
        port.timeout = 0
        port.write_timeout = 0
        return _streams(
            loop,
            lambda p: _FdTransport(loop, fileno, p, on_close=port.close, extra={"serial": port, "peername": url}),
        )
    return _streams(loop, lambda p: _ThreadTransport(loop, port, p))


async def open_fd(fd: int, *, close_fd: bool = True, name: str = "fd") -> StreamPair:
    """Wrap an open file descriptor (e.g. a pty master from ``os.openpty()``) as a stream pair."""
    loop = asyncio.get_running_loop()
    on_close = (lambda: os.close(fd)) if close_fd else None
    return _streams(loop, lambda p: _FdTransport(loop, fd, p, on_close=on_close, extra={"peername": name}))


# -------------------------------------------------------------------------------------------------
# In-process pair with fault injection
# -------------------------------------------------------------------------------------------------


class FaultSpec:
    """What a :func:`memory_pair` does to bytes in one direction.

    ``split``: deliver every write in pieces of at most this many bytes, one ``data_received`` each.
    ``coalesce``: hold writes and deliver everything written within one loop iteration at once.
    ``delay``: deliver each write this many seconds later (order is kept).
    ``corrupt``: a function applied to each write's bytes before delivery.
    """

    def __init__(
        self,
        *,
        split: int | None = None,
        coalesce: bool = False,
        delay: float = 0.0,
        corrupt: Callable[[bytes], bytes] | None = None,
    ) -> None:
        if split is not None and split < 1:
            raise ValueError("split must be at least 1 byte")
        self.split = split
        self.coalesce = coalesce
        self.delay = delay
        self.corrupt = corrupt


class _MemoryTransport(_Base):
    def __init__(
        self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol, faults: FaultSpec, name: str
    ) -> None:
        super().__init__({"peername": name})
        self._loop = loop
        self._protocol = protocol
        self._faults = faults
        self.peer: _MemoryTransport | None = None
        self._closing = False
        self._held = bytearray()
        #: pieces that arrived while reading was paused, delivered on resume
        self._paused_in: list[bytes] | None = None
        self._resuming = False
        loop.call_soon(protocol.connection_made, self)

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing or not data:
            return
        data = bytes(data)
        if self._faults.corrupt is not None:
            data = self._faults.corrupt(data)
        if self._faults.coalesce:
            if not self._held:
                self._loop.call_soon(self._flush_held)
            self._held += data
            return
        self._send(data)

    def _flush_held(self) -> None:
        data, self._held = bytes(self._held), bytearray()
        self._send(data)

    def _send(self, data: bytes) -> None:
        step = self._faults.split or len(data)
        pieces = [data[i : i + step] for i in range(0, len(data), step)]
        if self._faults.delay:
            self._loop.call_later(self._faults.delay, self._deliver, pieces)
        else:
            self._loop.call_soon(self._deliver, pieces)

    def _deliver(self, pieces: list[bytes]) -> None:
        peer = self.peer
        if peer is None:
            return
        peer._receive(pieces)

    def _receive(self, pieces: list[bytes]) -> None:
        for piece in pieces:
            if self._closing:
                return
            if self._paused_in is not None:
                self._paused_in.append(piece)
            else:
                self._protocol.data_received(piece)

    def pause_reading(self) -> None:
        if self._paused_in is None:
            self._paused_in = []
        self._resuming = False  # a release already scheduled finds reading paused again

    def resume_reading(self) -> None:
        if self._paused_in is not None and not self._resuming:
            # Delivered from the loop, not from inside the protocol's call; until then what
            # arrives keeps queueing behind what was held, so the order holds.
            self._resuming = True
            self._loop.call_soon(self._release)

    def _release(self) -> None:
        if not self._resuming:  # paused again meanwhile
            return
        self._resuming = False
        held, self._paused_in = self._paused_in, None
        if held:
            self._receive(held)  # pieces after a new pause_reading() are held again, in order

    def is_reading(self) -> bool:
        return self._paused_in is None and not self._closing

    def get_write_buffer_size(self) -> int:
        return len(self._held)

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        self._loop.call_soon(self._protocol.connection_lost, None)
        peer = self.peer
        if peer is not None and not peer._closing:
            # Deliver the hang-up after anything already in flight.
            delay = self._faults.delay
            self._loop.call_later(delay, peer._hang_up) if delay else self._loop.call_soon(peer._hang_up)

    def _hang_up(self) -> None:
        if not self._closing:
            held, self._paused_in = self._paused_in, None
            for piece in held or ():  # what arrived while paused comes before the end
                self._protocol.data_received(piece)
            self._closing = True
            self._protocol.eof_received()
            self._protocol.connection_lost(None)

    def abort(self) -> None:
        self.close()


def memory_pair(a_to_b: FaultSpec | None = None, b_to_a: FaultSpec | None = None) -> tuple[StreamPair, StreamPair]:
    """Two connected stream pairs in memory; must be called from a running event loop."""
    loop = asyncio.get_running_loop()
    transports: list[_MemoryTransport] = []

    def make(faults: FaultSpec, name: str) -> Callable[[asyncio.Protocol], asyncio.Transport]:
        def factory(protocol: asyncio.Protocol) -> asyncio.Transport:
            t = _MemoryTransport(loop, protocol, faults, name)
            transports.append(t)
            return t

        return factory

    a = _streams(loop, make(a_to_b or FaultSpec(), "memory-b"))
    b = _streams(loop, make(b_to_a or FaultSpec(), "memory-a"))
    transports[0].peer, transports[1].peer = transports[1], transports[0]
    return a, b
