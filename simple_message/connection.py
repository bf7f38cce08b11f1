"""One simple_message connection over any byte stream: send, receive, request/reply, topics.

The asyncio layer over the sans-I/O :class:`~.link.Link`, which owns the protocol's rules (frames,
byte order, which reply answers which request, requests given up on). A :class:`Connection`
moves bytes and time. It is the asyncio :class:`~asyncio.Protocol` of its transport (TCP, serial,
pty, memory pair): what arrives is fed to the link in the transport's own callback and the
events are acted on there, with no task and no stream buffer in between; a reply computed at once
goes out in the same loop iteration as the request that asked for it.

* A reply that answers a request completes its caller's future; a reply that cannot answer it
  (another type, reply_code INVALID, a malformed body) fails it with
  :class:`~.errors.UnexpectedReply`. Which replies may answer which requests is the peer's
  dialect (``answers``; :mod:`.dialects`).
* Anything else goes to the connection's message handler (servers; a body that does not decode
  arrives as the :class:`~.errors.MalformedMessage` itself) and to every subscription.

A message handler may return an awaitable (back-pressure, e.g. a server whose request queue is
full): reading pauses until it is done, and the messages after it wait in the link, in order.

Subscriptions are bounded: a subscriber that does not keep up loses its *oldest* messages, and the
loss is counted (:attr:`Subscription.dropped`). It never blocks the reader or grows memory.

Writes are bounded too: :meth:`Connection.send` waits for the peer at most ``drain_timeout``
seconds once ``max_write_buffer`` bytes are queued, then closes the connection; the non-waiting
:meth:`Connection.send_nowait` (for broadcasting topics) closes it as soon as the buffer is over the
limit, and so does :meth:`Connection.flush` of frames gathered with :meth:`Connection.queue_frame`
(a server's broadcast: one write per connection for the topics of one loop iteration). A stalled
peer therefore costs at most one buffer of memory and never delays anyone else.

When the connection ends for any reason, every pending request fails at once with
:class:`~.errors.ConnectionClosed`. Nothing is ever re-sent by this layer.

A :class:`Tap` (``tap=``; e.g. :class:`~.capture.CaptureWriter`) sees the connection open,
every chunk of bytes as it is handed to the transport or received from it (before it is acted on:
a request comes before the reply it causes), and the end. Unset, it costs one ``is not None`` per
write and read; a tap that raises is logged once and dropped for that connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import inspect
import logging
import socket
import time
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol, cast

from .constants import ReplyCode
from .dialects import any_dialect_answers
from .errors import (
    ConnectionClosed,
    IncompleteFrame,
    MalformedMessage,
    RequestFailed,
    RequestTimeout,
    UnexpectedReply,
)
from .fixed_reads import FixedReads
from .framing import DEFAULT_MAX_LENGTH
from .link import (
    NEED_DATA,
    Answered,
    Ended,
    LateReply,
    Link,
    Malformed,
    Received,
    ReplyRule,
    Request,
    StrayReply,
    Unanswerable,
)
from .lograte import LogBudget
from .messages import Message, type_name
from .transport import StreamPair, set_nodelay, take_over, unread_by_peers
from .wire import DEFAULT_FORMAT, WireFormat

__all__ = ["Connection", "ConnectionState", "Subscription", "MessageHandler", "Tap", "TapLink", "TapTee"]

log = logging.getLogger(__name__)
frames_log = logging.getLogger(__name__ + ".frames")

#: Called by the reader for every message that is not a SERVICE_REPLY, in arrival order (a body
#: that does not decode: the MalformedMessage). It may return an awaitable, which the reader
#: awaits before reading on (back-pressure).
MessageHandler = Callable[[Message | MalformedMessage], Awaitable[None] | None]


@dataclass(frozen=True, eq=False)
class TapLink:
    """What a :class:`Tap` is told about one connection (each connection has its own: compared by
    identity). ``local`` and ``peer`` are the socket addresses ``(host, port)`` of a TCP connection
    (IPv4 or IPv6), ``None`` for a serial port, a pty or a memory pair. ``accepted``: the peer
    opened the connection (a server's); else this end did (a client's)."""

    name: str
    local: tuple[str, int] | None
    peer: tuple[str, int] | None
    accepted: bool


class Tap(Protocol):
    """Sees a connection's traffic (``Connection(tap=...)``, ``Server.tap``, ``Client(tap=...)``).
    Called on the event loop; ``time_ns`` is ``time.time_ns()``. Must not block."""

    def opened(self, link: TapLink, time_ns: int) -> None:
        """The connection exists (called once, first)."""

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        """Bytes written to the transport (``outgoing``) or received from it, in order."""

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        """The connection is over (called once, last); ``by_peer``: the peer's input had ended
        (EOF, reset) before this end closed."""


class TapTee:
    """Several taps seen as one: each is told everything, in the order given (e.g. a capture file
    and a live traffic display on the same server)."""

    def __init__(self, taps: Sequence[Tap]) -> None:
        self.taps = tuple(taps)

    def opened(self, link: TapLink, time_ns: int) -> None:
        for tap in self.taps:
            tap.opened(link, time_ns)

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        for tap in self.taps:
            tap.data(link, outgoing, data, time_ns)

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        for tap in self.taps:
            tap.closed(link, by_peer, time_ns)


class ConnectionState(enum.Enum):
    """Observable state of a connection or a reconnecting client."""

    CONNECTING = "connecting"
    CONNECTED = "connected"
    RECONNECTING = "reconnecting"
    CLOSED = "closed"


class Subscription:
    """A bounded stream of received messages (topics, and requests on a server).

    Iterate with ``async for``, or call :meth:`get` with a timeout. When full, the oldest message is
    dropped and :attr:`dropped` counts it.
    """

    def __init__(self, maxsize: int = 256, msg_types: Iterable[int] | None = None) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self.maxsize = maxsize
        self.msg_types = frozenset(msg_types) if msg_types is not None else None
        self.dropped = 0
        self.received = 0
        self._items: deque[Message] = deque(maxlen=maxsize)
        self._event = asyncio.Event()
        self._closed = False

    def wants(self, msg: Message) -> bool:
        return self.msg_types is None or msg.msg_type in self.msg_types

    def put(self, msg: Message) -> None:
        if self._closed:
            return
        if len(self._items) == self.maxsize:
            self.dropped += 1
        self._items.append(msg)
        self.received += 1
        self._event.set()

    def __len__(self) -> int:
        return len(self._items)

    def get_nowait(self) -> Message | None:
        return self._items.popleft() if self._items else None

    async def get(self, timeout: float | None = None) -> Message:
        """The next message; raises :class:`TimeoutError` after ``timeout`` s, or
        :class:`~.errors.ConnectionClosed` once the subscription is closed and drained."""
        async with asyncio.timeout(timeout):
            while not self._items:
                if self._closed:
                    raise ConnectionClosed("subscription closed")
                self._event.clear()
                await self._event.wait()
        return self._items.popleft()

    def close(self) -> None:
        self._closed = True
        self._event.set()

    @property
    def closed(self) -> bool:
        return self._closed

    def __aiter__(self) -> AsyncIterator[Message]:
        return self

    async def __anext__(self) -> Message:
        try:
            return await self.get()
        except ConnectionClosed:
            raise StopAsyncIteration from None


class Connection(asyncio.Protocol):
    """A simple_message link over one transport (TCP socket, serial port, pty, memory pair).

    ``streams``: the stream pair of an opened link (:mod:`.transport`; the connection takes its
    transport over, with whatever was already read), or an asyncio transport (a server's accepted
    socket). ``autodetect`` detects the byte order from the peer's first frame (servers); until
    then, and for everything sent, ``wire`` applies. ``answers``: which replies may answer which
    requests (the peer's dialect, :meth:`.dialects.Dialect.answers`; default: what any dialect may
    send). ``frame_timeout``: a peer that begins a frame and sends nothing more for that long (s)
    is closed with :class:`~.errors.IncompleteFrame` (servers; ``None``: wait for ever). Call
    :meth:`start` (or use ``async with``) to begin acting on what arrives; what arrives before is
    kept.
    """

    def __init__(
        self,
        streams: StreamPair | asyncio.BaseTransport,
        wire: WireFormat = DEFAULT_FORMAT,
        *,
        autodetect: bool = False,
        max_length: int = DEFAULT_MAX_LENGTH,
        name: str | None = None,
        on_message: MessageHandler | None = None,
        subscriptions: list[Subscription] | None = None,
        drain_timeout: float = 5.0,
        max_write_buffer: int = 256 * 1024,
        answers: ReplyRule = any_dialect_answers,
        frame_timeout: float | None = None,
        tap: Tap | None = None,
        accepted: bool = False,
        reader: FixedReads | None = None,
        write_split: Callable[[bytes], Sequence[bytes]] | None = None,
    ) -> None:
        #: the protocol state (sans-I/O): frames, byte order, requests and replies
        self.link = Link(wire, autodetect=autodetect, max_length=max_length, answers=answers, reader=reader)
        #: how each frame is written: in one write (``None``), or in the pieces this returns, one
        #: write each (a controller that sends a message's parts with separate calls)
        self.write_split = write_split
        self._autodetect = autodetect
        self.drain_timeout = drain_timeout
        self.max_write_buffer = max_write_buffer
        #: close the connection when a frame was begun and nothing more came for this long (s)
        self.frame_timeout = frame_timeout
        self._partial_timer: asyncio.TimerHandle | None = None
        #: ``time.monotonic()`` of the last bytes received (or of the connection)
        self.last_input = time.monotonic()
        self.on_message = on_message
        #: Shared with a reconnecting client, so subscriptions outlive one connection.
        self.subscriptions: list[Subscription] = subscriptions if subscriptions is not None else []
        self._futures: dict[Request, asyncio.Future[Message]] = {}
        self._closed = asyncio.Event()
        self.state = ConnectionState.CONNECTED
        #: Why the connection ended (``None`` for a clean close or EOF).
        self.close_reason: BaseException | None = None
        self._inbox: Subscription | None = None
        #: If set, called when reading ends (EOF or a frame error) instead of closing at once, so a
        #: server can still answer the requests it already read; it must close the connection.
        self.on_read_end: Callable[[BaseException | None], None] | None = None
        self._started = False
        #: bytes and the end of input that arrived before start(), acted on by start()
        self._early: list[bytes] | None = []
        self._early_end: tuple[BaseException | None] | None = None
        #: a handler's awaitable is pending: events wait in the link, reading is paused
        self._blocked = False
        self._resume_task: asyncio.Task[None] | None = None
        self._awaited: Awaitable[None] | None = None
        self._reading = True
        self._read_done = False
        self._lost_reason: BaseException | None = None
        self._transport_lost = asyncio.Event()
        self._write_paused = False
        self._drain_waiters: list[asyncio.Future[None]] = []
        #: frames queued by queue_frame(), written together by flush()
        self._queued: list[bytes] = []
        #: the stream pair given, kept only because a StreamWriter closes its transport when collected
        self._streams: StreamPair | None = None
        if isinstance(streams, tuple):
            self._streams = streams
            transport, early, end, gone = take_over(streams, self)
            if early:
                self._early.append(early)
            if end is not None:
                self._early_end = end
            if gone:
                self._transport_lost.set()
        else:
            transport = streams
            transport.set_protocol(self)
        #: the transport this connection is the protocol of
        self.transport = cast(asyncio.Transport, transport)
        set_nodelay(transport)
        self.name = name or str(transport.get_extra_info("peername") or "link")
        #: the log lines this peer may cause (:mod:`.lograte`)
        self.log_budget = LogBudget(self.name)
        #: sees the traffic (:class:`Tap`): given to the constructor; ``None`` once it failed, and
        #: once the connection is closed
        self.tap: Tap | None = None
        #: what the tap is told about this connection
        self.tap_link = TapLink(self.name, *_addresses(transport), accepted=accepted)
        #: the peer's input ended (EOF, lost transport) before this end closed (for the tap)
        self._input_over = False
        if tap is not None:
            self.tap = tap
            self._tap_call(tap.opened, self.tap_link, time.time_ns())

    @property
    def wire(self) -> WireFormat:
        """The wire format spoken: as given, or as detected from the peer's first frame."""
        return self.link.wire

    @wire.setter
    def wire(self, wire: WireFormat) -> None:
        self.link.wire = wire

    # -- lifecycle -----------------------------------------------------------------------------

    def start(self) -> Connection:
        """Begin acting on what arrives (including what arrived before)."""
        if self._started:
            return self
        self._started = True
        log.info("%s: connected (%s)", self.name, self.wire)
        if frames_log.isEnabledFor(logging.DEBUG):
            self.link.on_frame = lambda frame: frames_log.debug("%s <- %s", self.name, frame.hex())
        early, self._early = self._early, None
        end, self._early_end = self._early_end, None
        if self.state is ConnectionState.CLOSED:
            return self
        for data in early or ():
            self.data_received(data)
        if end is not None:
            self._input_ended(end[0])
        elif not self._reading and not self._blocked and not self._read_done:
            self._set_reading(True)
        return self

    async def __aenter__(self) -> Connection:
        return self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def closed(self) -> bool:
        return self.state is ConnectionState.CLOSED

    async def wait_closed(self) -> None:
        await self._closed.wait()

    async def close(self) -> None:
        """Close the connection, fail pending requests, and wait (at most 1 s) for the transport."""
        self._shutdown(None)
        task = self._resume_task
        if task is not None and task is not asyncio.current_task():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._transport_lost.wait(), 1.0)

    def abort(self, reason: BaseException | None = None) -> None:
        """Close without waiting (usable from callbacks)."""
        self._shutdown(reason)

    def _shutdown(self, reason: BaseException | None) -> None:
        if self.state is ConnectionState.CLOSED:
            return
        self.state = ConnectionState.CLOSED
        self.close_reason = reason
        if self._partial_timer is not None:
            self._partial_timer.cancel()
            self._partial_timer = None
        self.log_budget.flush()
        if reason is None or _hang_up(reason):
            # the peer hung up (cleanly or not): normal life of a connection, not a warning
            log.info("%s: disconnected%s", self.name, f" ({reason})" if reason else "")
            if self._queued and not self.transport.is_closing():  # queued goes out before the close
                data = b"".join(self._queued)
                self.transport.write(data)
                if self.tap is not None:
                    self._tapped(True, data)
                self._queued.clear()
            self.transport.close()
        else:
            log.warning("%s: disconnected: %s", self.name, reason)
            # Drop what is buffered: a stalled peer would otherwise hold the close for ever.
            self._queued.clear()
            self.transport.abort()
        tap = self.tap
        if tap is not None:
            self.tap = None  # nothing more: the tap's record of the connection ends here
            self._tap_call(tap.closed, self.tap_link, self._input_over, time.time_ns())
        error = ConnectionClosed(f"{self.name}: connection closed" + (f" ({reason})" if reason else ""))
        self.link.close()
        futures, self._futures = self._futures, {}
        for future in futures.values():
            if not future.done():
                future.set_exception(error)
        self._wake_drainers(error)
        if self._inbox is not None:
            self._inbox.close()
        task = self._resume_task
        if task is not None and task is not asyncio.current_task():
            task.cancel()
            awaited = self._awaited
            if inspect.iscoroutine(awaited) and inspect.getcoroutinestate(awaited) == inspect.CORO_CREATED:
                awaited.close()  # the task never started: nobody will await it
        self._closed.set()

    # -- the transport's callbacks (asyncio.Protocol) ---------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Not called: the connection is made with its transport (see the constructor)."""

    def data_received(self, data: bytes) -> None:
        link = self.link
        if self._read_done or link.ended or self.state is ConnectionState.CLOSED:
            return  # reading is over (what is still in flight from a thread or a memory pair)
        if self._early is not None:  # not started: keep it, and stop reading until start()
            self._early.append(data)
            self._set_reading(False)
            return
        if self.tap is not None:
            self._tapped(False, data)
        if self._autodetect:
            detected = link.detected
            link.receive_data(data)
            if link.detected and not detected:
                log.info("%s: detected %s byte order", self.name, link.wire.byte_order.value)
        else:
            link.receive_data(data)
        if self.frame_timeout is not None:
            self.last_input = time.monotonic()
        if not self._blocked:
            self._process()
        if self.frame_timeout is not None and (link.buffered or self._partial_timer is not None):
            self._watch_partial()  # new bytes: the peer gets a fresh frame_timeout for its frame

    def _watch_partial(self) -> None:
        """(Re)start the incomplete-frame timer while a frame is incomplete; stop it between frames."""
        timer = self._partial_timer
        if timer is not None:
            timer.cancel()
            self._partial_timer = None
        if self.link.buffered and self.frame_timeout is not None and self.state is not ConnectionState.CLOSED:
            loop = asyncio.get_running_loop()
            self._partial_timer = loop.call_later(self.frame_timeout, self._partial_expired)

    def _partial_expired(self) -> None:
        self._partial_timer = None
        if self._blocked or not self._reading:  # we stopped reading it: the peer is not to blame
            self._watch_partial()
            return
        buffered = self.link.buffered
        if buffered and self.frame_timeout is not None and self.state is not ConnectionState.CLOSED:
            self.abort(IncompleteFrame(buffered, self.frame_timeout))

    def eof_received(self) -> bool:
        self._input_ended(None)
        return True  # keep the transport open: what was read is still answered

    def connection_lost(self, exc: Exception | None) -> None:
        self._transport_lost.set()
        self._lost_reason = exc
        self._input_ended(exc)
        if self.state is not ConnectionState.CLOSED and self._read_done and self.on_read_end is None:
            self._shutdown(exc)
        self._wake_drainers(ConnectionClosed(f"{self.name}: connection lost"))

    def pause_writing(self) -> None:
        self._write_paused = True

    def resume_writing(self) -> None:
        self._write_paused = False
        self._wake_drainers(None)

    # -- receiving -------------------------------------------------------------------------------

    def _input_ended(self, reason: BaseException | None) -> None:
        """No more bytes will come (EOF, or the transport is gone): the link ends after what it holds."""
        self._input_over = True
        if self._early is not None:
            if self._early_end is None:
                self._early_end = (reason,)
            return
        link = self.link
        if link.ended:
            return
        if reason is not None:
            self._lost_reason = reason
        link.receive_data(b"")
        if not self._blocked:
            self._process()

    def _set_reading(self, on: bool) -> None:
        if on == self._reading:
            return
        self._reading = on
        transport = self.transport
        if transport.is_closing():
            return
        with contextlib.suppress(NotImplementedError, RuntimeError):
            transport.resume_reading() if on else transport.pause_reading()

    def _process(self) -> None:
        """Act on the link's events, in order, until it needs data, the input ended, a handler's
        awaitable must be waited for, or the connection closed."""
        link = self.link
        try:
            while True:
                event = link.next_event()
                if event is NEED_DATA:
                    return
                if isinstance(event, Received):
                    msg = event.message
                    on_message = self.on_message
                    if on_message is not None:
                        result = on_message(msg)
                        if result is not None:
                            self._wait_for(result, msg)
                            return
                    self._deliver(msg)
                elif isinstance(event, Answered):
                    future = self._futures.pop(event.request, None)
                    if future is not None and not future.done():
                        future.set_result(event.reply)
                elif isinstance(event, Unanswerable):
                    self._unanswerable(event)
                elif isinstance(event, Malformed):
                    if self.on_message is not None:
                        result = self.on_message(event.error)
                        if result is not None:
                            self._wait_for(result, None)
                            return
                    else:
                        log.warning("%s: dropped malformed message: %s", self.name, event.error)
                elif isinstance(event, LateReply):
                    log.info("%s: late reply to an abandoned request consumed: %s", self.name, event.reply.name)
                elif isinstance(event, StrayReply):
                    stray = event.reply.name if event.reply else event.error
                    log.debug("%s: stray reply ignored: %s", self.name, stray)
                else:
                    assert isinstance(event, Ended)
                    self._read_ended(event.error or self._lost_reason)
                    return
                if self.state is ConnectionState.CLOSED:
                    return
        except Exception as exc:  # a bug in a handler must not leave the peer hanging
            log.exception("%s: reader failed", self.name)
            self._read_ended(exc)

    def _deliver(self, msg: Message) -> None:
        for sub in self.subscriptions:
            if sub.wants(msg):
                sub.put(msg)
        if self._inbox is not None:
            self._inbox.put(msg)

    def _unanswerable(self, event: Unanswerable) -> None:
        future = self._futures.pop(event.request, None)
        if future is not None and not future.done():
            future.set_exception(
                UnexpectedReply(
                    f"{self.name}: {event.describe()} cannot answer a {_type_name(event.request.msg_type)} request",
                    event.reply,
                )
            )

    def _wait_for(self, awaitable: Awaitable[None], msg: Message | None) -> None:
        """A handler's back-pressure: stop reading until ``awaitable`` is done, then go on."""
        if self.closed:  # the handler closed the connection: nothing is waited for any more
            if inspect.iscoroutine(awaitable):
                awaitable.close()
            return
        self._blocked = True
        self._set_reading(False)
        self._awaited = awaitable
        self._resume_task = asyncio.get_running_loop().create_task(
            self._resume(awaitable, msg), name=f"sm-wait {self.name}"
        )

    async def _resume(self, awaitable: Awaitable[None], msg: Message | None) -> None:
        try:
            await awaitable
        except asyncio.CancelledError:
            self._blocked = False
            self._shutdown(None)
            return
        except Exception as exc:
            self._blocked = False
            log.exception("%s: reader failed", self.name)
            self._read_ended(exc)
            return
        self._blocked = False
        self._resume_task = None
        self._awaited = None
        if self.closed:
            return
        if msg is not None:
            self._deliver(msg)
        self._process()
        if self.frame_timeout is not None and (self.link.buffered > 0) != (self._partial_timer is not None):
            self._watch_partial()  # the backlog is decoded down to a frame begun: its clock starts now
        if not (self._blocked or self._read_done or self.closed):
            self._set_reading(True)

    def _read_ended(self, reason: BaseException | None) -> None:
        """Reading is over (EOF, a frame error, a lost transport, a failed handler)."""
        if self._read_done:
            return
        self._read_done = True
        self._set_reading(False)
        if self.state is ConnectionState.CLOSED:
            return
        if self.on_read_end is not None:
            if reason is not None:
                level = logging.INFO if _hang_up(reason) else logging.WARNING
                log.log(level, "%s: %s; answering what was read, then closing", self.name, reason)
            self.on_read_end(reason)
        else:
            self._shutdown(reason)

    def subscribe(self, maxsize: int = 256, msg_types: Iterable[int] | None = None) -> Subscription:
        """A new bounded subscription to received topics (``msg_types``: only these types)."""
        sub = Subscription(maxsize, msg_types)
        self.subscriptions.append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        with contextlib.suppress(ValueError):
            self.subscriptions.remove(sub)
        sub.close()

    def __aiter__(self) -> AsyncIterator[Message]:
        """Every message that is not a reply, received from the first call on, through one
        bounded inbox of 1024 (oldest dropped first, like any :class:`Subscription`)."""
        if self._inbox is None:
            self._inbox = Subscription(1024)
            if self.closed:
                self._inbox.close()
        return self._inbox

    # -- the tap ---------------------------------------------------------------------------------

    def _tapped(self, outgoing: bool, data: bytes | bytearray | memoryview) -> None:
        tap = self.tap
        if tap is not None:
            self._tap_call(tap.data, self.tap_link, outgoing, bytes(data), time.time_ns())

    def _tap_call(self, method: Callable[..., None], *args: object) -> None:
        """Call the tap; one that raises is logged once and dropped (never raised into the I/O)."""
        try:
            method(*args)
        except Exception:
            self.tap = None
            log.error("%s: the tap failed and is dropped for this connection", self.name, exc_info=True)

    # -- sending ---------------------------------------------------------------------------------

    def _write_frame(self, frame: bytes) -> None:
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", self.name, frame.hex())
        if self._queued:  # what was queued goes first
            self._queued.append(frame)
            frame = b"".join(self._queued)
            self._queued.clear()
        if not self.transport.is_closing():  # lost under us: connection_lost is on its way
            self._write(frame)

    def _write(self, data: bytes) -> None:
        """Hand ``data`` to the transport: in one write, or split as :attr:`write_split` says."""
        if self.write_split is None:
            self.transport.write(data)
        else:
            for piece in self.write_split(data):
                self.transport.write(piece)
        if self.tap is not None:
            self._tapped(True, data)

    def queue_frame(self, frame: bytes) -> bool:
        """Queue a frame in this connection's :attr:`wire` format, to be written with the others
        queued, in one write, by :meth:`flush` (which the queuer calls, e.g. a server's broadcast at
        the end of the loop iteration); anything sent meanwhile goes out after them. Returns whether
        the frame was queued (not on a closed connection)."""
        if self.state is ConnectionState.CLOSED:
            return False
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", self.name, frame.hex())
        self._queued.append(frame)
        return True

    def flush(self) -> bool:
        """Write what :meth:`queue_frame` queued; a peer with more than ``max_write_buffer`` bytes
        unread is closed then. Returns whether the connection is still open."""
        queued = self._queued
        if not queued or self.state is ConnectionState.CLOSED:
            queued.clear()
            return self.state is not ConnectionState.CLOSED
        data = queued[0] if len(queued) == 1 else b"".join(queued)
        queued.clear()
        transport = self.transport
        if transport.is_closing():  # lost under us: connection_lost is on its way
            return False
        self._write(data)
        if transport.get_write_buffer_size() > self.max_write_buffer:
            self.abort(ConnectionClosed(f"peer fell {transport.get_write_buffer_size()} bytes behind"))
            return False
        return True

    def write_buffer_size(self) -> int:
        """Bytes queued in the transport, not yet taken by the peer (or the kernel)."""
        return self.transport.get_write_buffer_size()

    @property
    def is_socket(self) -> bool:
        """The link is a network socket (not a serial port or a pipe)."""
        return self.transport.get_extra_info("socket") is not None

    def unread_bytes(self) -> int:
        """Bytes sent that the peer has not taken yet: our buffer plus, where the OS says, what its
        sockets hold for the peer (:func:`.transport.unread_by_peers`)."""
        unread = self.transport.get_write_buffer_size()
        sock = self.transport.get_extra_info("socket")
        if sock is not None:
            unread += unread_by_peers([sock])[0]
        return unread

    async def send(self, msg: Message) -> None:
        """Send ``msg``; if the peer lets ``max_write_buffer`` bytes pile up, wait at most
        ``drain_timeout`` s for it, then close the connection and raise ConnectionClosed."""
        if self.state is ConnectionState.CLOSED:
            raise ConnectionClosed(f"{self.name}: connection closed")
        self._write_frame(self.link.send(msg))
        if self.transport.get_write_buffer_size() > self.max_write_buffer:
            await self._drained()

    async def _drained(self) -> None:
        """Wait for the transport to take the buffer down (at most ``drain_timeout`` s)."""
        if not self._write_paused or self.state is ConnectionState.CLOSED:
            return
        waiter: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._drain_waiters.append(waiter)
        try:
            await asyncio.wait_for(waiter, self.drain_timeout)
        except (TimeoutError, ConnectionError) as exc:
            self.abort(ConnectionClosed(f"peer did not read for {self.drain_timeout} s"))
            raise ConnectionClosed(f"{self.name}: peer stalled, connection closed") from exc
        finally:
            with contextlib.suppress(ValueError):
                self._drain_waiters.remove(waiter)

    def _wake_drainers(self, error: BaseException | None) -> None:
        waiters, self._drain_waiters = self._drain_waiters, []
        for waiter in waiters:
            if not waiter.done():
                if error is None:
                    waiter.set_result(None)
                else:
                    waiter.set_exception(error)

    def send_nowait(self, msg: Message) -> bool:
        """Send without waiting (topic broadcast). A peer with more than ``max_write_buffer`` bytes
        unread is closed. Returns whether the message was queued."""
        if self.state is ConnectionState.CLOSED:
            return False
        return self.send_frame_nowait(self.link.send(msg))

    def send_frame_nowait(self, frame: bytes) -> bool:
        """:meth:`send_nowait` of a frame already encoded in this connection's :attr:`wire` format
        (a broadcast encodes each message once per wire format, not once per peer)."""
        if self.state is ConnectionState.CLOSED:
            return False
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", self.name, frame.hex())
        transport = self.transport
        if transport.is_closing():  # lost under us (a reset): writing on would only log warnings
            self._queued.clear()
            return False
        if self._queued:
            self._queued.append(frame)
            frame = b"".join(self._queued)
            self._queued.clear()
        self._write(frame)
        if transport.get_write_buffer_size() > self.max_write_buffer:
            self.abort(ConnectionClosed(f"peer fell {transport.get_write_buffer_size()} bytes behind"))
            return False
        return True

    async def request(self, msg: Message, timeout: float | None = 5.0) -> Message:
        """Send a SERVICE_REQUEST and return its SUCCESS reply.

        Raises :class:`~.errors.RequestFailed` on FAILURE, :class:`~.errors.RequestTimeout`,
        :class:`~.errors.UnexpectedReply`, :class:`~.errors.ConnectionClosed`, and
        :class:`~.errors.LocalProtocolError` for a message that is not a request. MotoROS replies
        (MOTO_MOTION_REPLY) are returned as they are: their outcome is in the body's ``result``.
        """
        if self.state is ConnectionState.CLOSED or self.link.ended:
            raise ConnectionClosed(f"{self.name}: connection closed")
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Message] = loop.create_future()
        request, frame = self.link.send_request(msg)
        self._futures[request] = future
        # A timer on the future itself, not wait_for(): no extra task per request on the hot path.
        timer = loop.call_later(timeout, _expire, future) if timeout is not None else None
        try:
            self._write_frame(frame)
            if self.transport.get_write_buffer_size() > self.max_write_buffer:
                await self._drained()
            reply = await future
        except asyncio.CancelledError:
            self._give_up(request)
            if future.cancelled() and getattr(future, "expired", False):
                raise RequestTimeout(f"{self.name}: no reply to {msg.name} within {timeout} s") from None
            raise
        except BaseException:
            self._give_up(request)
            raise
        finally:
            if timer is not None:
                timer.cancel()
        code = reply.reply_code
        if code == _SUCCESS:
            return reply
        if code == _FAILURE:
            raise RequestFailed(f"{self.name}: {msg.name} request answered FAILURE", reply)
        raise UnexpectedReply(f"{self.name}: reply to {msg.name} has reply_code {code}", reply)

    def _give_up(self, request: Request) -> None:
        # keep its place in the FIFO: a late reply must not go to the next request
        if self._futures.pop(request, None) is not None:
            self.link.abandon(request)

    @property
    def pending_requests(self) -> int:
        return self.link.pending_requests


_SUCCESS = int(ReplyCode.SUCCESS)
_FAILURE = int(ReplyCode.FAILURE)


def _expire(future: asyncio.Future[Message]) -> None:
    """The request timer fired: mark the future, so request() can tell a timeout from a cancel."""
    if not future.done():
        future.expired = True  # type: ignore[attr-defined]
        future.cancel()


def _type_name(msg_type: int) -> str:
    return type_name(msg_type) or f"type {msg_type}"


def _addresses(transport: asyncio.BaseTransport) -> tuple[tuple[str, int] | None, tuple[str, int] | None]:
    """A TCP transport's local and peer ``(host, port)``; ``(None, None)`` for anything else."""
    sock = transport.get_extra_info("socket")
    if sock is None or sock.family not in (socket.AF_INET, socket.AF_INET6):
        return None, None
    local, peer = transport.get_extra_info("sockname"), transport.get_extra_info("peername")
    if not isinstance(local, tuple) or not isinstance(peer, tuple):
        return None, None
    return (str(local[0]), int(local[1])), (str(peer[0]), int(peer[1]))


def _hang_up(reason: BaseException) -> bool:
    """The peer went away (normal life of a connection, not a warning)."""
    return isinstance(reason, BrokenPipeError | ConnectionResetError)
