"""One simple_message connection over any byte stream: send, receive, request/reply, topics.

The asyncio layer over the sans-I/O :class:`~..link.Link`, which owns the protocol's rules (frames,
byte order, which reply answers which request, requests given up on). A :class:`Connection`
moves bytes and time. It is the asyncio :class:`~asyncio.Protocol` of its transport (TCP, serial,
pty, memory pair): what arrives is fed to the link in the transport's own callback and the
events are acted on there, with no task and no stream buffer in between; a reply computed at once
goes out in the same loop iteration as the request that asked for it.

* A reply that answers a request completes its caller's future; a reply that cannot answer it
  (another type, reply_code INVALID, a malformed body) fails it with
  :class:`~..errors.UnexpectedReply`. Which replies may answer which requests is the peer's
  dialect (``answers``; :mod:`..dialects`).
* Anything else goes to the connection's message handler (servers; a body that does not decode
  arrives as the :class:`~..errors.MalformedMessage` itself) and to every subscription.

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
:class:`~..errors.ConnectionClosed`. Nothing is ever re-sent by this layer.

A :class:`Tap` (``tap=``; e.g. :class:`~..capture.CaptureWriter`) sees the connection open,
every chunk of bytes as it is handed to the transport or received from it (before it is acted on:
a request comes before the reply it causes), and the end. Unset, it costs one ``is not None`` per
write and read; a tap that raises is logged once and dropped for that connection.

:class:`Connection` is the asyncio side of the connection, what its users call, and its life (start,
close). It hands the rest to one part per idea, each in its own module: :mod:`.inbound` (what
arrives, acted on), :mod:`.outbound` (what is sent, bounded), :mod:`.requests` (the requests that
wait for replies), :mod:`.subscriptions` (where received messages go) and :mod:`.taps`.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Sequence
from typing import cast

from ..constants import ReplyCode
from ..dialects import any_dialect_answers
from ..errors import ConnectionClosed, MalformedMessage, RequestFailed, RequestTimeout, UnexpectedReply
from ..fixed_reads import FixedReads
from ..framing import DEFAULT_MAX_LENGTH
from ..link import Link, ReplyRule
from ..lograte import LogBudget
from ..messages import Message
from ..transport import StreamPair, set_nodelay, take_over, unread_by_peers
from ..wire import DEFAULT_FORMAT, WireFormat
from .inbound import Inbound, hung_up
from .outbound import Outbound
from .requests import Requests, expire
from .subscriptions import Subscribers, Subscription
from .taps import Tap, TapLink, TapPoint, TapTee, socket_addresses

__all__ = ["Connection", "ConnectionState", "Subscription", "MessageHandler", "Tap", "TapLink", "TapTee"]

log = logging.getLogger(__name__)
#: every frame as hex at DEBUG (sent ones are logged by :mod:`.outbound`)
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


class Connection(asyncio.Protocol):
    """A simple_message link over one transport (TCP socket, serial port, pty, memory pair).

    ``streams``: the stream pair of an opened link (:mod:`..transport`; the connection takes its
    transport over, with whatever was already read), or an asyncio transport (a server's accepted
    socket), whose protocol the connection becomes at once (so asyncio's ``connection_made`` is
    never called). ``autodetect`` detects the byte order from the peer's first frame (servers);
    until then, and for everything sent, ``wire`` applies. ``answers``: which replies may answer
    which requests (the peer's dialect, :meth:`..dialects.Dialect.answers`; default: what any
    dialect may send). ``frame_timeout``: a peer that begins a frame and sends nothing more for that
    long (s) is closed with :class:`~..errors.IncompleteFrame` (servers; ``None``: wait for ever).
    Call :meth:`start` (or use ``async with``) to begin acting on what arrives; what arrives before
    is kept.
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
        self.drain_timeout = drain_timeout
        self.max_write_buffer = max_write_buffer
        #: close the connection when a frame was begun and nothing more came for this long (s)
        self.frame_timeout = frame_timeout
        #: ``time.monotonic()`` of the last bytes received (or of the connection)
        self.last_input = time.monotonic()
        self.on_message = on_message
        self._subscribers = Subscribers(subscriptions)
        #: Shared with a reconnecting client, so subscriptions outlive one connection.
        self.subscriptions: list[Subscription] = self._subscribers.subscriptions
        self._requests = Requests(self.link)
        self._closed = asyncio.Event()
        self.state = ConnectionState.CONNECTED
        #: Why the connection ended (``None`` for a clean close or EOF).
        self.close_reason: BaseException | None = None
        #: If set, called when reading ends (EOF or a frame error) instead of closing at once, so a
        #: server can still answer the requests it already read; it must close the connection.
        self.on_read_end: Callable[[BaseException | None], None] | None = None
        #: The message handler on whose behalf the link's standing replies (:attr:`~..link.Link.standing`)
        #: are sent, or ``None``: set by its owner while the handler would answer those requests at
        #: once with those replies (nothing of the connection's waits to be answered before them);
        #: they are sent only while it is :attr:`on_message` (see :meth:`data_received`).
        self.standing_for: MessageHandler | None = None
        #: the link's standing replies (the same dict), looked up here before anything else
        self._standing = self.link.standing
        self._started = False
        self._transport_lost = asyncio.Event()
        #: the stream pair given, kept only because a StreamWriter closes its transport when collected
        self._streams: StreamPair | None = None
        early, end = b"", None
        if isinstance(streams, tuple):
            self._streams = streams
            transport, early, end, gone = take_over(streams, self)
            if gone:
                self._transport_lost.set()
        else:
            transport = streams
            transport.set_protocol(self)
        #: the transport this connection is the protocol of
        self.transport = cast(asyncio.Transport, transport)
        set_nodelay(transport)
        self.name = name or str(transport.get_extra_info("peername") or "link")
        #: the log lines this peer may cause (:mod:`..lograte`)
        self.log_budget = LogBudget(self.name)
        #: what the tap is told about this connection
        self.tap_link = TapLink(self.name, *socket_addresses(transport), accepted=accepted)
        self._tap = TapPoint(self.tap_link)
        self._outbound = Outbound(self._tap)
        self._inbound = Inbound(
            self._requests, self._subscribers, self._tap, autodetect=autodetect, early=early, end=end
        )
        if tap is not None:
            self._tap.open(tap)

    @property
    def wire(self) -> WireFormat:
        """The wire format spoken: as given, or as detected from the peer's first frame."""
        return self.link.wire

    @wire.setter
    def wire(self, wire: WireFormat) -> None:
        self.link.wire = wire

    @property
    def tap(self) -> Tap | None:
        """Sees the traffic (:class:`Tap`): given to the constructor; ``None`` once it failed, and
        once the connection is closed."""
        return self._tap.tap

    # -- lifecycle -----------------------------------------------------------------------------

    def start(self) -> Connection:
        """Begin acting on what arrives (including what arrived before)."""
        if self._started:
            return self
        self._started = True
        log.info("%s: connected (%s)", self.name, self.wire)
        if frames_log.isEnabledFor(logging.DEBUG):
            self.link.on_frame = lambda frame: frames_log.debug("%s <- %s", self.name, frame.hex())
        self._inbound.start(self)
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
        task = self._inbound.resume_task
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
        self.log_budget.flush()
        if reason is None or hung_up(reason):
            # the peer hung up (cleanly or not): normal life of a connection, not a warning
            log.info("%s: disconnected%s", self.name, f" ({reason})" if reason else "")
            self._outbound.end(self, graceful=True)  # queued goes out before the close
            self.transport.close()
        else:
            log.warning("%s: disconnected: %s", self.name, reason)
            # Drop what is buffered: a stalled peer would otherwise hold the close for ever.
            self._outbound.end(self, graceful=False)
            self.transport.abort()
        self._tap.close(self._inbound.input_over)
        error = ConnectionClosed(f"{self.name}: connection closed" + (f" ({reason})" if reason else ""))
        self.link.close()
        self._requests.fail_all(error)
        self._outbound.wake(error)
        self._subscribers.close()
        self._inbound.stop()
        self._closed.set()

    # -- the transport's callbacks (asyncio.Protocol) ---------------------------------------------

    def data_received(self, data: bytes) -> None:
        armed = self.standing_for
        if (
            armed is not None
            and armed is self.on_message
            and type(data) is bytes
            and data in self._standing
            and self._answer_standing(data)
        ):
            return
        self._inbound.data_received(self, data)

    def _answer_standing(self, data: bytes) -> bool:
        """Answer ``data``, one of the link's standing requests, with its standing reply, when it is
        what the general path would do with it: the connection reading and nothing waiting (no
        handler awaited, no input ended), no tap, no subscriber, no frame log, nothing queued to
        send and none of the transport's write buffer in use, and the link taking it as the one
        message received (:meth:`~..link.Link.take_standing`). Then what the general path does
        besides decoding it and calling the handler happens: the frame is counted, the peer's input
        noted, the reply written (a peer found too far behind is closed), the incomplete-frame clock
        stopped. Returns whether it did (else nothing was done)."""
        inbound = self._inbound
        subscribers = self._subscribers
        transport = self.transport
        if (
            inbound.early is not None
            or inbound.done
            or inbound.blocked
            or self.state is ConnectionState.CLOSED
            or self._tap.tap is not None
            or subscribers.subscriptions
            or subscribers.inbox is not None
            or self.write_split is not None
            or self._outbound.queued
            or transport.is_closing()
            or transport.get_write_buffer_size()
            or frames_log.isEnabledFor(_DEBUG)
        ):
            return False
        reply = self.link.take_standing(data)
        if reply is None:
            return False
        transport.write(reply)
        if self.frame_timeout is not None:
            self.last_input = time.monotonic()  # (after the reply: nothing reads it in between)
        # written with the buffer empty, the buffer holds at most the reply now
        if len(reply) > self.max_write_buffer and transport.get_write_buffer_size() > self.max_write_buffer:
            self.abort(ConnectionClosed(f"peer fell {transport.get_write_buffer_size()} bytes behind"))
        if inbound.partial_timer is not None and self.frame_timeout is not None:
            inbound.watch_partial(self)  # nothing is held: the clock stops
        return True

    def eof_received(self) -> bool:
        self._inbound.input_ended(self, None)
        return True  # keep the transport open: what was read is still answered

    def connection_lost(self, exc: Exception | None) -> None:
        self._transport_lost.set()
        inbound = self._inbound
        inbound.transport_lost(self, exc)
        if self.state is not ConnectionState.CLOSED and inbound.done and self.on_read_end is None:
            self._shutdown(exc)
        self._outbound.wake(ConnectionClosed(f"{self.name}: connection lost"))

    def pause_writing(self) -> None:
        self._outbound.paused = True

    def resume_writing(self) -> None:
        self._outbound.paused = False
        self._outbound.wake(None)

    # -- receiving -------------------------------------------------------------------------------

    def subscribe(self, maxsize: int = 256, msg_types: Iterable[int] | None = None) -> Subscription:
        """A new bounded subscription to received topics (``msg_types``: only these types)."""
        return self._subscribers.add(maxsize, msg_types)

    def unsubscribe(self, sub: Subscription) -> None:
        self._subscribers.remove(sub)

    def __aiter__(self) -> AsyncIterator[Message]:
        """Every message that is not a reply, received from the first call on, through one
        bounded inbox of 1024 (oldest dropped first, like any :class:`Subscription`)."""
        return self._subscribers.open_inbox(self.closed)

    # -- sending ---------------------------------------------------------------------------------

    def queue_frame(self, frame: bytes) -> bool:
        """Queue a frame in this connection's :attr:`wire` format, to be written with the others
        queued, in one write, by :meth:`flush` (which the queuer calls, e.g. a server's broadcast at
        the end of the loop iteration); anything sent meanwhile goes out after them. Returns whether
        the frame was queued (not on a closed connection)."""
        return self._outbound.queue(self, frame)

    def flush(self) -> bool:
        """Write what :meth:`queue_frame` queued; a peer with more than ``max_write_buffer`` bytes
        unread is closed then. Returns whether the connection is still open."""
        return self._outbound.flush(self)

    def write_buffer_size(self) -> int:
        """Bytes queued in the transport, not yet taken by the peer (or the kernel)."""
        return self.transport.get_write_buffer_size()

    @property
    def is_socket(self) -> bool:
        """The link is a network socket (not a serial port or a pipe)."""
        return self.transport.get_extra_info("socket") is not None

    def unread_bytes(self) -> int:
        """Bytes sent that the peer has not taken yet: our buffer plus, where the OS says, what its
        sockets hold for the peer (:func:`..transport.unread_by_peers`)."""
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
        self._outbound.write_frame(self, self.link.send(msg))
        if self.transport.get_write_buffer_size() > self.max_write_buffer:
            await self._outbound.drained(self)

    def send_nowait(self, msg: Message) -> bool:
        """Send without waiting (topic broadcast). A peer with more than ``max_write_buffer`` bytes
        unread is closed. Returns whether the message was queued."""
        if self.state is ConnectionState.CLOSED:
            return False
        return self._outbound.send_nowait(self, self.link.send(msg))

    def send_frame_nowait(self, frame: bytes) -> bool:
        """:meth:`send_nowait` of a frame already encoded in this connection's :attr:`wire` format
        (a broadcast encodes each message once per wire format, not once per peer)."""
        return self._outbound.send_nowait(self, frame)

    async def request(self, msg: Message, timeout: float | None = 5.0) -> Message:
        """Send a SERVICE_REQUEST and return its SUCCESS reply.

        Raises :class:`~..errors.RequestFailed` on FAILURE, :class:`~..errors.RequestTimeout`,
        :class:`~..errors.UnexpectedReply`, :class:`~..errors.ConnectionClosed`, and
        :class:`~..errors.LocalProtocolError` for a message that is not a request. MotoROS replies
        (MOTO_MOTION_REPLY) are returned as they are: their outcome is in the body's ``result``.
        """
        if self.state is ConnectionState.CLOSED or self.link.ended:
            raise ConnectionClosed(f"{self.name}: connection closed")
        loop = asyncio.get_running_loop()
        requests = self._requests
        request, frame = self.link.send_request(msg)
        future = requests.expect(request)
        # A timer on the future itself, not wait_for(): no extra task per request on the hot path.
        timer = loop.call_later(timeout, expire, future) if timeout is not None else None
        try:
            self._outbound.write_frame(self, frame)
            if self.transport.get_write_buffer_size() > self.max_write_buffer:
                await self._outbound.drained(self)
            reply = await future
        except asyncio.CancelledError:
            requests.give_up(request)
            if future.cancelled() and getattr(future, "expired", False):
                raise RequestTimeout(f"{self.name}: no reply to {msg.name} within {timeout} s") from None
            raise
        except BaseException:
            requests.give_up(request)
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

    @property
    def pending_requests(self) -> int:
        return self.link.pending_requests


_SUCCESS = int(ReplyCode.SUCCESS)
_DEBUG = logging.DEBUG
_FAILURE = int(ReplyCode.FAILURE)
