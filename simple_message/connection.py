"""One simple_message connection over any byte stream: send, receive, request/reply, topics.

The asyncio layer over the sans-I/O :class:`~.link.Link`, which owns the protocol's rules (frames,
byte order, which reply answers which request, requests given up on). A :class:`Connection`
moves bytes and time: one reader task feeds what arrives to its link and acts on the events.

* A reply that answers a request completes its caller's future; a reply that cannot answer it
  (another type, reply_code INVALID, a malformed body) fails it with
  :class:`~.errors.UnexpectedReply`. Which replies may answer which requests is the peer's
  dialect (``answers``; :mod:`.dialects`).
* Anything else goes to the connection's message handler (servers; a body that does not decode
  arrives as the :class:`~.errors.MalformedMessage` itself) and to every subscription.

Subscriptions are bounded: a subscriber that does not keep up loses its *oldest* messages, and the
loss is counted (:attr:`Subscription.dropped`). It never blocks the reader or grows memory.

Writes are bounded too: :meth:`Connection.send` waits for the peer at most ``drain_timeout``
seconds once ``max_write_buffer`` bytes are queued, then closes the connection; the non-waiting
:meth:`Connection.send_nowait` (for broadcasting topics) closes it as soon as the buffer is over the
limit. A stalled peer therefore costs at most one buffer of memory and never delays anyone else.

When the connection ends for any reason, every pending request fails at once with
:class:`~.errors.ConnectionClosed`. Nothing is ever re-sent by this layer.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable

from .constants import ReplyCode
from .dialects import any_dialect_answers
from .errors import (
    ConnectionClosed,
    MalformedMessage,
    RequestFailed,
    RequestTimeout,
    UnexpectedReply,
)
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
from .messages import Message, type_name
from .transport import READ_SIZE, StreamPair, set_nodelay
from .wire import DEFAULT_FORMAT, WireFormat

__all__ = ["Connection", "ConnectionState", "Subscription", "MessageHandler"]

log = logging.getLogger(__name__)
frames_log = logging.getLogger(__name__ + ".frames")

#: Called by the reader for every message that is not a SERVICE_REPLY, in arrival order (a body
#: that does not decode: the MalformedMessage). It may return an awaitable, which the reader
#: awaits before reading on (back-pressure).
MessageHandler = Callable[[Message | MalformedMessage], Awaitable[None] | None]


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


class Connection:
    """A simple_message link over one stream pair (TCP socket, serial port, memory pair).

    ``autodetect`` detects the byte order from the peer's first frame (servers); until then, and for
    everything sent, ``wire`` applies. ``answers``: which replies may answer which requests (the
    peer's dialect, :meth:`.dialects.Dialect.answers`; default: what any dialect may send). Call
    :meth:`start` (or use ``async with``) to begin reading.
    """

    def __init__(
        self,
        streams: StreamPair,
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
    ) -> None:
        self.reader, self.writer = streams
        set_nodelay(self.writer)
        #: the protocol state (sans-I/O): frames, byte order, requests and replies
        self.link = Link(wire, autodetect=autodetect, max_length=max_length, answers=answers)
        self.name = name or str(self.writer.get_extra_info("peername") or "link")
        self.drain_timeout = drain_timeout
        self.max_write_buffer = max_write_buffer
        self.on_message = on_message
        #: Shared with a reconnecting client, so subscriptions outlive one connection.
        self.subscriptions: list[Subscription] = subscriptions if subscriptions is not None else []
        self._futures: dict[Request, asyncio.Future[Message]] = {}
        self._task: asyncio.Task[None] | None = None
        self._closed = asyncio.Event()
        self.state = ConnectionState.CONNECTED
        #: Why the connection ended (``None`` for a clean close or EOF).
        self.close_reason: BaseException | None = None
        self._inbox: Subscription | None = None
        #: If set, called when reading ends (EOF or a frame error) instead of closing at once, so a
        #: server can still answer the requests it already read; it must close the connection.
        self.on_read_end: Callable[[BaseException | None], None] | None = None

    @property
    def wire(self) -> WireFormat:
        """The wire format spoken: as given, or as detected from the peer's first frame."""
        return self.link.wire

    @wire.setter
    def wire(self, wire: WireFormat) -> None:
        self.link.wire = wire

    # -- lifecycle -----------------------------------------------------------------------------

    def start(self) -> Connection:
        if self._task is None:
            log.info("%s: connected (%s)", self.name, self.wire)
            self._task = asyncio.get_running_loop().create_task(self._read_loop(), name=f"sm-read {self.name}")
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
        """Close the connection, fail pending requests, and wait for the reader to finish."""
        self._shutdown(None)
        if self._task is not None and self._task is not asyncio.current_task():
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.writer.wait_closed(), 1.0)

    def abort(self, reason: BaseException | None = None) -> None:
        """Close without waiting (usable from callbacks)."""
        self._shutdown(reason)
        if self._task is not None and self._task is not asyncio.current_task():
            self._task.cancel()

    def _shutdown(self, reason: BaseException | None) -> None:
        if self.state is ConnectionState.CLOSED:
            return
        self.state = ConnectionState.CLOSED
        self.close_reason = reason
        if reason is None or _hang_up(reason):
            # the peer hung up (cleanly or not): normal life of a connection, not a warning
            log.info("%s: disconnected%s", self.name, f" ({reason})" if reason else "")
            self.writer.close()
        else:
            log.warning("%s: disconnected: %s", self.name, reason)
            # Drop what is buffered: a stalled peer would otherwise hold the close for ever.
            if self.writer.transport is not None:
                self.writer.transport.abort()
        error = ConnectionClosed(f"{self.name}: connection closed" + (f" ({reason})" if reason else ""))
        self.link.close()
        futures, self._futures = self._futures, {}
        for future in futures.values():
            if not future.done():
                future.set_exception(error)
        if self._inbox is not None:
            self._inbox.close()
        self._closed.set()

    # -- receiving -------------------------------------------------------------------------------

    async def _read_loop(self) -> None:
        reason: BaseException | None = None
        link = self.link
        if frames_log.isEnabledFor(logging.DEBUG):
            link.on_frame = lambda frame: frames_log.debug("%s <- %s", self.name, frame.hex())
        try:
            while True:
                data = await self.reader.read(READ_SIZE)
                detected = link.detected
                link.receive_data(data)
                if link.detected and not detected:
                    log.info("%s: detected %s byte order", self.name, link.wire.byte_order.value)
                ended = await self._events()
                if self.state is ConnectionState.CLOSED:
                    return
                if ended is not None:
                    reason = ended.error
                    break
        except (ConnectionError, OSError) as exc:
            reason = exc
        except asyncio.CancelledError:
            self._shutdown(None)
            return
        except Exception as exc:  # a bug in a handler must not leave the peer hanging
            log.exception("%s: reader failed", self.name)
            reason = exc
        if self.on_read_end is not None and self.state is not ConnectionState.CLOSED:
            if reason is not None:
                level = logging.INFO if _hang_up(reason) else logging.WARNING
                log.log(level, "%s: %s; answering what was read, then closing", self.name, reason)
            self.on_read_end(reason)
        else:
            self._shutdown(reason)

    async def _events(self) -> Ended | None:
        """Act on the link's events, in order, until it needs data (or the input ended)."""
        link = self.link
        while True:
            event = link.next_event()
            if event is NEED_DATA:
                return None
            if isinstance(event, Received):
                msg = event.message
                if self.on_message is not None:
                    await self._call(msg)
                for sub in self.subscriptions:
                    if sub.wants(msg):
                        sub.put(msg)
                if self._inbox is not None:
                    self._inbox.put(msg)
            elif isinstance(event, Answered):
                future = self._futures.pop(event.request, None)
                if future is not None and not future.done():
                    future.set_result(event.reply)
            elif isinstance(event, Unanswerable):
                future = self._futures.pop(event.request, None)
                if future is not None and not future.done():
                    future.set_exception(
                        UnexpectedReply(
                            f"{self.name}: {event.describe()} cannot answer a {_type_name(event.request.msg_type)} "
                            "request",
                            event.reply,
                        )
                    )
            elif isinstance(event, Malformed):
                if self.on_message is not None:
                    await self._call(event.error)
                else:
                    log.warning("%s: dropped malformed message: %s", self.name, event.error)
            elif isinstance(event, LateReply):
                log.info("%s: late reply to an abandoned request consumed: %s", self.name, event.reply.name)
            elif isinstance(event, StrayReply):
                log.debug("%s: stray reply ignored: %s", self.name, event.reply.name if event.reply else event.error)
            else:
                return event
            if self.state is ConnectionState.CLOSED:
                return None

    async def _call(self, msg: Message | MalformedMessage) -> None:
        assert self.on_message is not None
        result = self.on_message(msg)
        if result is not None:
            await result

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

    # -- sending ---------------------------------------------------------------------------------

    def _write(self, msg: Message) -> None:
        if self.state is ConnectionState.CLOSED:
            raise ConnectionClosed(f"{self.name}: connection closed")
        self._write_frame(self.link.send(msg))

    def _write_frame(self, frame: bytes) -> None:
        if frames_log.isEnabledFor(logging.DEBUG):
            frames_log.debug("%s -> %s", self.name, frame.hex())
        self.writer.write(frame)

    def write_buffer_size(self) -> int:
        transport = self.writer.transport
        return transport.get_write_buffer_size() if transport is not None else 0

    async def send(self, msg: Message) -> None:
        """Send ``msg``; if the peer lets ``max_write_buffer`` bytes pile up, wait at most
        ``drain_timeout`` s for it, then close the connection and raise ConnectionClosed."""
        self._write(msg)
        await self._drained()

    async def _send_frame(self, frame: bytes) -> None:
        if self.state is ConnectionState.CLOSED:
            raise ConnectionClosed(f"{self.name}: connection closed")
        self._write_frame(frame)
        await self._drained()

    async def _drained(self) -> None:
        if self.write_buffer_size() > self.max_write_buffer:
            try:
                await asyncio.wait_for(self.writer.drain(), self.drain_timeout)
            except (TimeoutError, ConnectionError) as exc:
                self.abort(ConnectionClosed(f"peer did not read for {self.drain_timeout} s"))
                raise ConnectionClosed(f"{self.name}: peer stalled, connection closed") from exc

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
        self._write_frame(frame)
        if self.write_buffer_size() > self.max_write_buffer:
            self.abort(ConnectionClosed(f"peer fell {self.write_buffer_size()} bytes behind"))
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
            await self._send_frame(frame)
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
        if reply.reply_code == ReplyCode.SUCCESS:
            return reply
        if reply.reply_code == ReplyCode.FAILURE:
            raise RequestFailed(f"{self.name}: {msg.name} request answered FAILURE", reply)
        raise UnexpectedReply(f"{self.name}: reply to {msg.name} has reply_code {reply.reply_code}", reply)

    def _give_up(self, request: Request) -> None:
        # keep its place in the FIFO: a late reply must not go to the next request
        if self._futures.pop(request, None) is not None:
            self.link.abandon(request)

    @property
    def pending_requests(self) -> int:
        return self.link.pending_requests


def _expire(future: asyncio.Future[Message]) -> None:
    """The request timer fired: mark the future, so request() can tell a timeout from a cancel."""
    if not future.done():
        future.expired = True  # type: ignore[attr-defined]
        future.cancel()


def _type_name(msg_type: int) -> str:
    return type_name(msg_type) or f"type {msg_type}"


def _hang_up(reason: BaseException) -> bool:
    """The peer went away (normal life of a connection, not a warning)."""
    return isinstance(reason, BrokenPipeError | ConnectionResetError)
