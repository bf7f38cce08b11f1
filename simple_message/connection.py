"""One simple_message connection over any byte stream: send, receive, request/reply, topics.

The asyncio layer over the sans-I/O core, kept thin (architecture.md). A :class:`Connection` owns
one reader task that cuts frames, decodes them and routes each message:

* a SERVICE_REPLY answers the oldest pending request. simple_message has no correlation id, so
  replies are matched in order (FIFO). A request whose caller gave up (timeout, cancellation) keeps
  its place as a *tombstone* so that its late reply, if it comes, is consumed instead of being
  handed to the next request. A reply that cannot answer the head request (another type, reply_code
  INVALID, a malformed body) fails that request with :class:`~.errors.UnexpectedReply`: the
  reference client takes whatever arrives next as "the reply" (simple-message.md §0 item 5, §3);
  we check. Vendor shapes are accepted: same type header-only or echoed (ABB, C++), REP's
  dummy_data, Fanuc's JOINT_POSITION ack of a JOINT_TRAJ_PT, and MotoROS's MOTO_MOTION_REPLY (2002),
  which it sends for every request except PING (§3, §8.1).
* anything else goes to the connection's message handler (servers) and to every subscription.

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

from .constants import CommType, MsgType, ReplyCode
from .errors import (
    ConnectionClosed,
    FrameError,
    LocalProtocolError,
    MalformedMessage,
    RequestFailed,
    RequestTimeout,
    UnexpectedReply,
)
from .framing import DEFAULT_MAX_LENGTH, FrameDecoder
from .messages import Message, decode, encode
from .transport import READ_SIZE, StreamPair, set_nodelay
from .wire import DEFAULT_FORMAT, WireFormat

__all__ = ["Connection", "ConnectionState", "Subscription", "MessageHandler", "reply_matches", "malformed_error"]

log = logging.getLogger(__name__)
frames_log = logging.getLogger(__name__ + ".frames")

#: Called by the reader for every message that is not a SERVICE_REPLY, in arrival order. It may
#: return an awaitable, which the reader awaits before reading on (back-pressure).
MessageHandler = Callable[[Message], Awaitable[None] | None]


class ConnectionState(enum.Enum):
    """Observable state of a connection or a reconnecting client."""

    CONNECTING = "connecting"
    CONNECTED = "connected"
    RECONNECTING = "reconnecting"
    CLOSED = "closed"


def reply_matches(request_type: int, reply: Message) -> bool:
    """Whether ``reply`` can be the answer to a request of ``request_type`` (vendor shapes, §3)."""
    reply_type = reply.msg_type
    if reply_type in (request_type, MsgType.MOTO_MOTION_REPLY):
        return True
    return request_type == MsgType.JOINT_TRAJ_PT and reply_type == MsgType.JOINT_POSITION


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


class _Pending:
    __slots__ = ("future", "msg_type")

    def __init__(self, msg_type: int, future: asyncio.Future[Message] | None) -> None:
        self.msg_type = msg_type
        self.future = future  # None: a tombstone, the caller gave up


class Connection:
    """A simple_message link over one stream pair (TCP socket, serial port, memory pair).

    ``autodetect`` detects the byte order from the peer's first frame (servers); until then, and for
    everything sent, ``wire`` applies. Call :meth:`start` (or use ``async with``) to begin reading.
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
    ) -> None:
        self.reader, self.writer = streams
        set_nodelay(self.writer)
        self.wire = wire
        self.name = name or str(self.writer.get_extra_info("peername") or "link")
        self.decoder = FrameDecoder(None if autodetect else wire.byte_order, max_length=max_length)
        self.drain_timeout = drain_timeout
        self.max_write_buffer = max_write_buffer
        self.on_message = on_message
        #: Shared with a reconnecting client, so subscriptions outlive one connection.
        self.subscriptions: list[Subscription] = subscriptions if subscriptions is not None else []
        self._pending: deque[_Pending] = deque()
        self._task: asyncio.Task[None] | None = None
        self._closed = asyncio.Event()
        self.state = ConnectionState.CONNECTED
        #: Why the connection ended (``None`` for a clean close or EOF).
        self.close_reason: BaseException | None = None
        self._inbox: Subscription | None = None
        #: If set, called when reading ends (EOF or a frame error) instead of closing at once, so a
        #: server can still answer the requests it already read; it must close the connection.
        self.on_read_end: Callable[[BaseException | None], None] | None = None

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
        while self._pending:
            entry = self._pending.popleft()
            if entry.future is not None and not entry.future.done():
                entry.future.set_exception(error)
        if self._inbox is not None:
            self._inbox.close()
        self._closed.set()

    # -- receiving -------------------------------------------------------------------------------

    async def _read_loop(self) -> None:
        reason: BaseException | None = None
        try:
            while True:
                data = await self.reader.read(READ_SIZE)
                if not data:
                    break
                self.decoder.feed(data)
                if self.decoder.detected and self.decoder.byte_order is not self.wire.byte_order:
                    self.wire = self.wire.with_byte_order(self.decoder.byte_order)  # type: ignore[arg-type]
                    log.info("%s: detected %s byte order", self.name, self.wire.byte_order.value)
                for frame in self.decoder:
                    if frames_log.isEnabledFor(logging.DEBUG):
                        frames_log.debug("%s <- %s", self.name, frame.hex())
                    await self._route_frame(frame)
                    if self.state is ConnectionState.CLOSED:
                        return
        except FrameError as exc:
            reason = exc
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

    async def _route_frame(self, frame: bytes) -> None:
        try:
            msg = decode(frame, self.wire)
        except MalformedMessage as exc:
            if exc.comm_type == CommType.SERVICE_REPLY:
                self._on_reply(None, exc)
            elif self.on_message is not None:
                await self._call(_MalformedFrame(exc))
            else:
                log.warning("%s: dropped malformed message: %s", self.name, exc)
            return
        if msg.comm_type == CommType.SERVICE_REPLY:
            self._on_reply(msg, None)
            return
        if self.on_message is not None:
            await self._call(msg)
        for sub in self.subscriptions:
            if sub.wants(msg):
                sub.put(msg)
        if self._inbox is not None:
            self._inbox.put(msg)

    async def _call(self, msg: Message) -> None:
        assert self.on_message is not None
        result = self.on_message(msg)
        if result is not None:
            await result

    def _on_reply(self, reply: Message | None, error: MalformedMessage | None) -> None:
        while self._pending:
            head = self._pending[0]
            if reply is not None and reply_matches(head.msg_type, reply):
                self._pending.popleft()
                if head.future is None:
                    log.info("%s: late reply to an abandoned request consumed: %s", self.name, reply.name)
                elif not head.future.done():
                    head.future.set_result(reply)
                return
            if head.future is None:
                # The abandoned request's reply never came; this reply is for a later request.
                self._pending.popleft()
                continue
            self._pending.popleft()
            what = str(error) if error is not None else f"{reply.name if reply else '?'} reply"
            if not head.future.done():
                head.future.set_exception(
                    UnexpectedReply(f"{self.name}: {what} cannot answer a {_type_name(head.msg_type)} request", reply)
                )
            return
        log.debug("%s: stray reply ignored: %s", self.name, reply.name if reply else error)

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
        self._write_frame(encode(msg, self.wire))

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
        return self.send_frame_nowait(encode(msg, self.wire))

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
        :class:`~.errors.UnexpectedReply` and :class:`~.errors.ConnectionClosed`. MotoROS replies
        (MOTO_MOTION_REPLY) are returned as they are: their outcome is in the body's ``result``.
        """
        if msg.comm_type != CommType.SERVICE_REQUEST:
            raise LocalProtocolError(f"request() sends SERVICE_REQUESTs, not comm_type {msg.comm_type}")
        if self.state is ConnectionState.CLOSED:
            raise ConnectionClosed(f"{self.name}: connection closed")
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Message] = loop.create_future()
        entry = _Pending(msg.msg_type, future)
        self._pending.append(entry)
        # A timer on the future itself, not wait_for(): no extra task per request on the hot path.
        timer = loop.call_later(timeout, _expire, future) if timeout is not None else None
        try:
            await self.send(msg)
            reply = await future
        except asyncio.CancelledError:
            entry.future = None  # keep the place in the FIFO: a late reply must not go to the next request
            if future.cancelled() and getattr(future, "expired", False):
                raise RequestTimeout(f"{self.name}: no reply to {msg.name} within {timeout} s") from None
            raise
        except BaseException:
            entry.future = None
            raise
        finally:
            if timer is not None:
                timer.cancel()
        if reply.reply_code == ReplyCode.SUCCESS:
            return reply
        if reply.reply_code == ReplyCode.FAILURE:
            raise RequestFailed(f"{self.name}: {msg.name} request answered FAILURE", reply)
        raise UnexpectedReply(f"{self.name}: reply to {msg.name} has reply_code {reply.reply_code}", reply)

    @property
    def pending_requests(self) -> int:
        return sum(1 for p in self._pending if p.future is not None)


class _MalformedFrame(Message):
    """Internal: hands a MalformedMessage to a server's handler in arrival order."""

    __slots__ = ("error",)
    error: MalformedMessage

    def __init__(self, error: MalformedMessage) -> None:
        object.__setattr__(self, "comm_type", error.comm_type)
        object.__setattr__(self, "reply_code", 0)
        object.__setattr__(self, "error", error)

    @property
    def msg_type(self) -> int:
        return self.error.msg_type or 0


def _expire(future: asyncio.Future[Message]) -> None:
    """The request timer fired: mark the future, so request() can tell a timeout from a cancel."""
    if not future.done():
        future.expired = True  # type: ignore[attr-defined]
        future.cancel()


def _type_name(msg_type: int) -> str:
    try:
        return MsgType(msg_type).name
    except ValueError:
        return f"type {msg_type}"


def _hang_up(reason: BaseException) -> bool:
    """The peer went away (normal life of a connection, not a warning)."""
    return isinstance(reason, BrokenPipeError | ConnectionResetError)


def malformed_error(msg: Message) -> MalformedMessage | None:
    """The decoding error carried by a message handed to a server handler, if any."""
    return msg.error if isinstance(msg, _MalformedFrame) else None
