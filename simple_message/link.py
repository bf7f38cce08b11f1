"""One simple_message link without I/O: framing, byte order and the request/reply rules.

The asyncio :class:`~.connection.Connection` (and anything else: a test, a capture reader, a
serial loop) moves bytes and time; a :class:`Link` decides what they mean, after h11. Feed it
what arrived with :meth:`Link.receive_data` (``b""`` at the end of the stream) and take
:meth:`Link.next_event` until it says :data:`NEED_DATA`; turn messages into bytes with
:meth:`Link.send` and, for a SERVICE_REQUEST whose reply you want, :meth:`Link.send_request`.

The rules of replies. simple_message has no correlation id, so replies are matched to requests in
order (FIFO). A request whose caller gave up (:meth:`Link.abandon`: a timeout, a cancellation)
keeps its place, so that its late reply, if it comes, is consumed (:class:`LateReply`) instead of
being taken as the answer to the next request; if another reply comes first, the abandoned
request's reply is taken to be lost and the reply goes to the next request. Which reply may
answer which request is the peer's dialect (:mod:`.dialects`): the ``answers`` rule given to the
link. A reply that cannot answer the oldest live request (another type, or a body that does not
decode) ends that request with :class:`Unanswerable`: the reference client takes whatever
arrives next as "the reply"; we check. A reply with nothing pending is a :class:`StrayReply`.

A request or topic whose body does not decode is :class:`Malformed`, and so is one of a known type
that comes without the body its type has: a header-only frame is the shape of a reply (ABB's
acknowledgement), never of a JOINT_TRAJ_PT request.
"""

from __future__ import annotations

import contextlib
import enum
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from .constants import CommType
from .dialects import any_dialect_answers
from .errors import FrameError, LocalProtocolError, MalformedMessage
from .fixed_reads import FixedReads
from .framing import DEFAULT_MAX_LENGTH, FrameDecoder, decode_or_error
from .messages import MESSAGE_CLASSES, HeaderOnly, Message, encode, type_name
from .wire import DEFAULT_FORMAT, WireFormat

__all__ = [
    "NEED_DATA",
    "Answered",
    "Ended",
    "Event",
    "LateReply",
    "Link",
    "Malformed",
    "NeedData",
    "Received",
    "ReplyRule",
    "Request",
    "StrayReply",
    "Unanswerable",
]

#: Whether a reply (a decoded SERVICE_REPLY) can be the answer to a request of a message type.
ReplyRule = Callable[[int, Message], bool]

#: bytes decoded at a time (at most 1,024 messages: a link never holds more decoded at once)
DECODE_SLICE = 16 * 1024

_SERVICE_REPLY = int(CommType.SERVICE_REPLY)
_COMM_TYPES = frozenset(int(c) for c in CommType)


class NeedData(enum.Enum):
    """The sentinel type of :data:`NEED_DATA`."""

    NEED_DATA = "need data"


#: :meth:`Link.next_event` has nothing more until more bytes (or the end) are fed.
NEED_DATA = NeedData.NEED_DATA


class Request:
    """A SERVICE_REQUEST sent with :meth:`Link.send_request`, waiting for its reply. The I/O
    layer keeps whatever it needs (a future) keyed by it."""

    __slots__ = ("abandoned", "msg_type")

    def __init__(self, msg_type: int) -> None:
        self.msg_type = msg_type
        #: its caller gave up (:meth:`Link.abandon`); it keeps its place for a late reply
        self.abandoned = False

    def __repr__(self) -> str:
        return f"Request(msg_type={self.msg_type}{', abandoned' if self.abandoned else ''})"


@dataclass(frozen=True, slots=True)
class Received:
    """A message that is not a reply: a request (servers) or a topic."""

    message: Message


@dataclass(frozen=True, slots=True)
class Malformed:
    """A frame that is not a reply and whose body does not decode (its header did). A server
    answers a malformed request (FAILURE, or its dialect's reply)."""

    error: MalformedMessage


@dataclass(frozen=True, slots=True)
class Answered:
    """``reply`` answers ``request``."""

    request: Request
    reply: Message


@dataclass(frozen=True, slots=True)
class Unanswerable:
    """What arrived as the reply to ``request`` cannot answer it: ``reply`` of another type, or
    (``reply`` None) a reply whose body does not decode, ``error``. The request is over."""

    request: Request
    reply: Message | None
    error: MalformedMessage | None

    def describe(self) -> str:
        if self.error is not None:
            return str(self.error)
        assert self.reply is not None
        return f"{self.reply.name} reply"


@dataclass(frozen=True, slots=True)
class LateReply:
    """The late reply of an abandoned request, consumed."""

    request: Request
    reply: Message


@dataclass(frozen=True, slots=True)
class StrayReply:
    """A reply with no request pending (``reply`` None: its body did not decode, ``error``)."""

    reply: Message | None
    error: MalformedMessage | None


@dataclass(frozen=True, slots=True)
class Ended:
    """No more input: the peer closed the stream (``error`` None) or sent bytes that cannot be
    framed (``error``; the link cannot find the next frame). Requests still pending will never
    be answered: :meth:`Link.close` hands them back."""

    error: FrameError | None


Event = Received | Malformed | Answered | Unanswerable | LateReply | StrayReply | Ended


class Link:
    """The protocol state of one link. ``autodetect`` takes the byte order from the peer's first
    frame (servers; until then, and for what is sent, ``wire`` applies); ``answers`` is the
    peer's reply rule (:meth:`.dialects.Dialect.answers`; default: what any dialect may send).
    ``reader``: cut the input as a controller that reads fixed byte counts does
    (:class:`~.fixed_reads.FixedReads`: every read is received as it is, none is a reply) instead
    of by the length prefix."""

    def __init__(
        self,
        wire: WireFormat = DEFAULT_FORMAT,
        *,
        autodetect: bool = False,
        max_length: int = DEFAULT_MAX_LENGTH,
        answers: ReplyRule = any_dialect_answers,
        reader: FixedReads | None = None,
    ) -> None:
        #: the wire format spoken (assignable: a server may guess what a peer that has not spoken yet
        #: understands; the peer's first frame still decides, if the link autodetects)
        self.wire = wire
        self.answers = answers
        self._decoder: FrameDecoder | FixedReads = (
            FrameDecoder(None if autodetect else wire.byte_order, max_length=max_length) if reader is None else reader
        )
        self._raw = reader is not None
        #: the decoder when it cuts by the length prefix (receive_one's shortcut), else None
        self._cutter = self._decoder if isinstance(self._decoder, FrameDecoder) else None
        self._pending: deque[Request] = deque()
        self._events: deque[Event] = deque()
        self._ended = False
        #: bytes received and not decoded yet (decoded a slice at a time, as events are taken)
        self._backlog = b""
        self._backlog_pos = 0
        #: the input ended behind the backlog
        self._end_after = False
        #: Called with each complete frame received, before it is decoded (frame logs, captures).
        self.on_frame: Callable[[bytes], None] | None = None
        self._standing: dict[bytes, tuple[bytes, type[Message]]] = {}

    # -- state -----------------------------------------------------------------------------------

    @property
    def standing(self) -> dict[bytes, tuple[bytes, type[Message]]]:
        """Standing replies: whole request frames that the link's user answers with a fixed reply
        frame without having them decoded (:meth:`take_standing`): request frame -> (reply frame, the
        class of the message the request must decode to for that reply). One dict for the link's
        life: change its items."""
        return self._standing

    @property
    def detected(self) -> bool:
        """The byte order was detected from the peer's first frame (a link that autodetects)."""
        return self._decoder.detected

    @property
    def ended(self) -> bool:
        """The input ended (:class:`Ended` was produced)."""
        return self._ended

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete frame received so far (0 between frames, and while received bytes
        wait to be decoded: the peer is then ahead of us, not behind)."""
        return 0 if self._backlog else self._decoder.buffered

    @property
    def pending_requests(self) -> int:
        """Requests waiting for a reply, abandoned ones not counted."""
        return sum(1 for r in self._pending if not r.abandoned)

    # -- sending ---------------------------------------------------------------------------------

    def send(self, msg: Message) -> bytes:
        """The frame of ``msg`` in this link's wire format (nothing is expected back)."""
        return encode(msg, self.wire)

    def send_request(self, msg: Message) -> tuple[Request, bytes]:
        """A SERVICE_REQUEST whose reply is expected, and its frame."""
        if msg.comm_type != CommType.SERVICE_REQUEST:
            raise LocalProtocolError(f"a request is a SERVICE_REQUEST, not comm_type {msg.comm_type}")
        if self._ended:
            raise LocalProtocolError("the link has ended")
        frame = encode(msg, self.wire)
        request = Request(msg.msg_type)
        self._pending.append(request)
        return request, frame

    def abandon(self, request: Request) -> None:
        """Its caller gave up on ``request``: it keeps its place, and its late reply is consumed."""
        request.abandoned = True

    def close(self) -> list[Request]:
        """End the link: the requests that were still waiting (not abandoned), oldest first."""
        self._ended = True
        self._backlog, self._backlog_pos = b"", 0
        waiting = [r for r in self._pending if not r.abandoned]
        self._pending.clear()
        return waiting

    # -- receiving -------------------------------------------------------------------------------

    def receive_data(self, data: bytes) -> None:
        """Bytes as they arrived, in any chunking; ``b""``: the stream ended."""
        if self._ended:
            if data:
                raise LocalProtocolError("data received after the link ended")
            return
        if self._end_after:
            if data:
                raise LocalProtocolError("data received after the end of the stream")
            return
        if not data:
            if self._backlog:
                self._end_after = True  # once the backlog is decoded
            else:
                self._end(None)
            return
        # Kept as bytes and decoded a slice at a time as the events are taken (next_event): what a
        # link holds decoded is bounded by one slice, however much arrived at once.
        if self._backlog:
            self._backlog = self._backlog[self._backlog_pos :] + data
        else:
            self._backlog = bytes(data)
        self._backlog_pos = 0
        if not self._events:
            self._decode_slice()

    def take_standing(self, data: bytes) -> bytes | None:
        """Take ``data``, one of the :attr:`standing` request frames, as received and answered, when
        the general path would make of it exactly one :class:`Received` event of a message of the
        standing class, and nothing else: nothing waits (no event, no bytes), ``data`` is that one
        whole frame in the stream's byte order, and it decodes (in the registry as it is now) to an
        instance of that class, a request or a topic. Its message, kept from when that frame was first
        decoded, is not decoded again and no event is queued; the decoder counts the frame, and the
        reply frame is returned for the caller to send. ``None`` otherwise, with nothing done."""
        entry = self._standing.get(data)
        cutter = self._cutter
        if (
            entry is None
            or cutter is None
            or self._events
            or self._backlog
            or self._ended
            or self._end_after
            or self.on_frame is not None
        ):
            return None
        msg = cutter.cached(data, self.wire)
        if (
            msg is None
            or msg.__class__ is not entry[1]
            or msg.__class__ is HeaderOnly
            or msg.comm_type == _SERVICE_REPLY
        ):
            return None
        cutter.frames_decoded += 1
        return entry[0]

    def receive_one(self, data: bytes) -> Message | None:
        """:meth:`receive_data` with a shortcut for the commonest read: when ``data`` is exactly one
        whole frame, nothing waits before it (no event, no bytes) and it is a message received (a
        request or a topic that decodes: what :meth:`next_event` would give as :class:`Received`),
        that message is returned instead, as if its :class:`Received` had been queued and taken.
        Otherwise ``None`` is returned and the events are queued as :meth:`receive_data` queues them.
        The events that follow are the same either way: with nothing before and nothing after it,
        the frame's :class:`Received` would have been the only one."""
        cutter = self._cutter
        if (
            cutter is None
            or self._events
            or self._backlog
            or self._ended
            or self._end_after
            or self.on_frame is not None
            or not data
        ):
            self.receive_data(data)
            return None
        msg = cutter.one_message(data, self.wire)
        if msg is None:
            self.receive_data(data)
            return None
        if msg.__class__ is HeaderOnly or msg.comm_type == _SERVICE_REPLY or isinstance(msg, MalformedMessage):
            self._message(msg)  # not a plain Received (a reply, a malformed body...): its event, as ever
            return None
        return msg

    def next_event(self) -> Event | NeedData:
        """The next thing that happened, or :data:`NEED_DATA`."""
        events = self._events
        while not events:
            if not self._decode_slice():
                return NEED_DATA
        return events.popleft()

    def _decode_slice(self) -> bool:
        """Cut and decode the next slice of the backlog (frames of a fixed layout straight from the
        bytes, in the order detected from the peer's first frame if this link detects); returns
        whether there was one."""
        backlog, pos = self._backlog, self._backlog_pos
        if not backlog:
            return False
        stop = pos + DECODE_SLICE
        chunk = backlog if pos == 0 and stop >= len(backlog) else backlog[pos:stop]
        if stop >= len(backlog):
            self._backlog, self._backlog_pos = b"", 0
        else:
            self._backlog_pos = stop
        decoder = self._decoder
        on_frame = self.on_frame
        if on_frame is None:
            for msg in decoder.feed_messages(chunk, self.wire):
                self._message(msg)
            self._detected_order()
        else:  # each frame is wanted as bytes too (logs, captures)
            decoder.feed(chunk)
            self._detected_order()
            with contextlib.suppress(FrameError):  # decoder.failed says so, below
                for frame in decoder:
                    on_frame(frame)
                    if isinstance(decoder, FixedReads):
                        self._message(decoder.message(frame, self.wire))
                    else:
                        self._message(decode_or_error(frame, self.wire))
        if decoder.failed:
            self._backlog, self._backlog_pos = b"", 0
            self._end(decoder.error)
        elif self._end_after and not self._backlog:
            self._end(None)
        return True

    def _detected_order(self) -> None:
        """Speak the byte order detected from the peer's first frame (a link that detects)."""
        decoder = self._decoder
        if decoder.detected:
            order = decoder.byte_order
            if order is not None and order is not self.wire.byte_order:
                self.wire = self.wire.with_byte_order(order)

    def _end(self, error: FrameError | None) -> None:
        self._ended = True
        self._events.append(Ended(error))

    def _message(self, msg: Message | MalformedMessage) -> None:
        """A frame, decoded (or its body that does not decode): a reply, or something received."""
        if self._raw:  # a read of a fixed-size reader: the server's handlers make of it what they will
            self._events.append(Malformed(msg) if isinstance(msg, MalformedMessage) else Received(msg))
            return
        if isinstance(msg, MalformedMessage):
            if msg.comm_type == _SERVICE_REPLY:
                self._reply(None, msg)
            else:
                self._events.append(Malformed(msg))
        elif msg.comm_type == _SERVICE_REPLY:
            self._reply(msg, None)
        elif msg.__class__ is HeaderOnly and msg.msg_type in MESSAGE_CLASSES:
            self._events.append(Malformed(_bodiless(msg, self.wire)))
        else:
            self._events.append(Received(msg))

    def _reply(self, reply: Message | None, error: MalformedMessage | None) -> None:
        pending = self._pending
        while pending:
            head = pending.popleft()
            if reply is not None and self.answers(head.msg_type, reply):
                self._events.append(LateReply(head, reply) if head.abandoned else Answered(head, reply))
                return
            if head.abandoned:
                continue  # its reply never came; this one is for a later request
            self._events.append(Unanswerable(head, reply, error))
            return
        self._events.append(StrayReply(reply, error))


def _bodiless(msg: Message, wire: WireFormat) -> MalformedMessage:
    """A request or topic of a known type without the body its type has (a header-only frame is
    a reply's shape, §3: ABB's acknowledgement; the types whose requests are empty, such as PING,
    decode as themselves and never come here)."""
    comm = CommType(msg.comm_type).name if msg.comm_type in _COMM_TYPES else str(msg.comm_type)
    return MalformedMessage(
        f"{type_name(msg.msg_type)} {comm} without a body (its type has one)",
        msg_type=msg.msg_type,
        comm_type=msg.comm_type,
        frame=encode(msg, wire),
    )
