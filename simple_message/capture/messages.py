"""A capture's simple_message traffic decoded: each direction's reassembled bytes cut into frames
and decoded, with events for what could not be.

:func:`captured_messages` reads the file (:mod:`.formats`), reassembles each direction of each
connection (:mod:`.reassembly`) and decodes its byte stream with the project's
:class:`~simple_message.framing.FrameDecoder`, giving :class:`CapturedMessage` items and
:class:`~.reassembly.CaptureEvent` items for what could not be decoded. :class:`CaptureReader` and
:func:`read_capture` are the file reader as the package gives it: raising :class:`CaptureError`, a
``SimpleMessageError``.

**Errors.** A file that is not a capture, is truncated or is malformed raises
:class:`CaptureError`, naming the file, what is wrong and at which byte (see :mod:`.formats`).
Everything :func:`captured_messages` yielded before stays valid.

**What ``simple-message decode CAPTURE`` prints.** One JSON object per message on stdout, as for hex
input (``msg_type``, ``name``, ``comm_type``, ``reply_code``, ``body``, ``names`` when a field has
a symbolic name), plus ``"time"`` (seconds since the epoch as the capture gives them, a float),
``"src"`` and ``"dst"`` (``"address:port"``, an IPv6 address in brackets). On stderr, one JSON
object per problem: ``{"error": TEXT, "type": KIND, ...}``, KIND an
:class:`~.reassembly.EventKind` value or ``MalformedMessage`` (a frame whose body fits no layout,
with its ``"hex"``), with the same ``time``, ``src`` and ``dst`` where they apply and ``start`` and
``end`` (stream offsets) for a ``Gap`` or a ``TruncatedFrame``. ``--port`` keeps the connections
with that port at either end, ``--type`` the messages of these types; the wire options are the
command's (``--byte-order auto`` detects each direction's order; the default is little-endian, as
for hex input). A file that begins like a capture but cannot be read as one is a single
``CaptureError`` line; the command exits 1 when anything was reported.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass

from ..errors import FrameError, MalformedMessage, SimpleMessageError
from ..framing import DEFAULT_MAX_LENGTH, FrameDecoder, decode_or_error
from ..messages import Message, decode
from ..wire import DEFAULT_FORMAT, ByteOrder, WireFormat
from .formats import LINK_TYPES, Address, FormatError, SegmentReader, Source, TcpSegment, to_seconds
from .reassembly import DEFAULT_REORDER_LIMIT, CaptureEvent, Connection, Direction, EventKind, Reassembler

__all__ = [
    "CaptureError",
    "CaptureReader",
    "CapturedMessage",
    "captured_messages",
    "read_capture",
]

_LE_INT = struct.Struct("<i").unpack_from
_BE_INT = struct.Struct(">i").unpack_from


class CaptureError(FormatError, SimpleMessageError):
    """A file that is not a pcap/pcapng capture, or is truncated or malformed.

    The message names the file and what is wrong; :attr:`offset` is the byte where, when known.
    """


class CaptureReader(SegmentReader):
    """The TCP segments of a pcap or pcapng capture, in capture order (see
    :class:`~.formats.SegmentReader`), raising :class:`CaptureError`."""

    error = CaptureError


def read_capture(source: Source) -> Iterator[TcpSegment]:
    """Every TCP segment of a pcap or pcapng capture, in capture order (see :mod:`.formats`).

    Raises :class:`CaptureError` if the file is not a capture (at the first item), or when a
    truncated or malformed part is reached.
    """
    with CaptureReader(source) as reader:
        yield from reader


@dataclass(slots=True)
class CapturedMessage:
    """One simple_message frame of a capture; read-only by convention.

    ``message`` is the decoded message, or ``None`` when the frame's body does not fit its type,
    then ``error`` says why (the frame was delimited: the stream goes on).
    """

    #: capture time of the segment that completed the frame, nanoseconds since the epoch
    time_ns: int
    src: Address
    dst: Address
    message: Message | None
    error: MalformedMessage | None
    #: the whole frame, length prefix included, as on the wire
    frame: bytes
    #: the side that opened the connection, when the capture shows its SYN (or SYN-ACK)
    client: Address | None = None

    @property
    def time(self) -> float:
        """Capture time in seconds since the epoch."""
        return to_seconds(self.time_ns)


class _Stream(Direction):
    """A direction and the frame decoder of its bytes."""

    __slots__ = ("decoder", "type_of", "wire")

    def __init__(self, key: bytes, src: Address, dst: Address, conn: Connection, decoder: FrameDecoder) -> None:
        super().__init__(key, src, dst, conn)
        self.decoder = decoder
        self.wire: WireFormat | None = None
        self.type_of: Callable[[bytes, int], tuple[int, ...]] = _LE_INT  # the msg_type of a frame


class _Decoding(Reassembler[_Stream]):
    """Reassembles the connections of one capture and decodes their frames into :attr:`out`."""

    def __init__(
        self,
        *,
        wire: WireFormat,
        auto: bool,
        ports: Collection[int] | None,
        types: Collection[int] | None,
        reorder_limit: int,
        max_length: int,
    ) -> None:
        super().__init__(ports=ports, reorder_limit=reorder_limit)
        self.wire = wire
        self.auto = auto
        self.types = frozenset(types) if types is not None else None
        self.max_length = max_length
        self.out: list[CapturedMessage | CaptureEvent] = []
        self._spent = FrameDecoder(None)  # the decoder of every ended stream: never fed

    def _decoder(self, previous: FrameDecoder | None) -> FrameDecoder:
        if previous is not None and previous.byte_order is not None:
            order: ByteOrder | None = previous.byte_order  # a restart keeps the detected order
        else:
            order = None if self.auto else self.wire.byte_order
        return FrameDecoder(order, max_length=self.max_length)

    # -- the reassembly's hooks

    def direction(self, key: bytes, src: Address, dst: Address, conn: Connection) -> _Stream:
        return _Stream(key, src, dst, conn, self._decoder(None))

    def deliver(self, s: _Stream, data: bytes, ts: int) -> None:
        """Decode the frames that ``data``, the stream's next bytes, completes."""
        decoder = s.decoder
        if decoder.failed:
            return  # until a gap restarts it
        decoder.feed(data)
        wire = s.wire
        if wire is None:
            order = decoder.byte_order
            if order is None:  # fewer than 4 bytes yet, or no plausible length prefix
                if decoder.error is not None:
                    self.frame_error(s, decoder, ts)
                return
            s.wire = wire = self.wire.with_byte_order(order) if self.auto else self.wire
            s.type_of = _LE_INT if order is ByteOrder.LITTLE else _BE_INT
        types = self.types
        type_of = s.type_of
        append = self.out.append
        src, dst, client = s.src, s.dst, s.conn.client
        try:
            for frame in decoder:
                if types is not None and type_of(frame, 4)[0] not in types:
                    continue
                item = decode_or_error(frame, wire)
                if isinstance(item, MalformedMessage):
                    append(CapturedMessage(ts, src, dst, None, item, frame, client))
                else:
                    append(CapturedMessage(ts, src, dst, item, None, frame, client))
        except FrameError:
            self.frame_error(s, decoder, ts)

    def buffered(self, s: _Stream) -> int:
        return s.decoder.buffered if not s.decoder.failed else 0

    def restart(self, s: _Stream) -> None:
        s.decoder = self._decoder(s.decoder)

    def closed(self, s: _Stream, ts: int) -> None:
        """Report an incomplete frame at the end of the direction."""
        decoder = s.decoder
        if decoder.buffered and not decoder.failed:
            self.out.append(
                CaptureEvent(
                    EventKind.TRUNCATED_FRAME,
                    f"{decoder.buffered} bytes at the end of {s} do not make a whole frame",
                    ts,
                    s.src,
                    s.dst,
                    s.offset - decoder.buffered,
                    s.offset,
                )
            )
        s.decoder = self._spent  # the incomplete frame is not kept

    def report(self, event: CaptureEvent) -> None:
        self.out.append(event)

    def frame_error(self, s: _Stream, decoder: FrameDecoder, ts: int) -> None:
        self.out.append(
            CaptureEvent(
                EventKind.FRAME_ERROR,
                f"{decoder.error}: {s} cannot be realigned, nothing more of it is decoded "
                "(up to a gap in the capture, where decoding restarts)",
                ts,
                s.src,
                s.dst,
            )
        )


def captured_messages(
    source: Source,
    wire: WireFormat = DEFAULT_FORMAT,
    auto: bool = True,
    *,
    ports: Collection[int] | None = None,
    types: Collection[int] | None = None,
    reorder_limit: int = DEFAULT_REORDER_LIMIT,
    max_length: int = DEFAULT_MAX_LENGTH,
) -> Iterator[CapturedMessage | CaptureEvent]:
    """The simple_message frames of every TCP connection of a capture, decoded, and the events of
    what could not be (gaps, truncated frames, framing errors): see :mod:`.reassembly` for how the
    connections are put together.

    ``wire`` is the wire format; with ``auto`` (the default) each direction's byte order is
    detected from its first length prefix (``wire`` then gives the real size). ``ports`` keeps the
    connections with one of these ports at either end; ``types`` the messages of these msg_types
    (events are not filtered). ``reorder_limit`` bounds the out-of-order bytes held per direction,
    ``max_length`` is the frame decoder's largest accepted length prefix.

    Items come in capture order, a message at the segment that completed its frame (a message
    after a gap: when the gap is given up on). Raises :class:`CaptureError` if the file is not a
    capture (at the first item), or when a truncated or malformed part is reached.
    """
    if reorder_limit < 0:
        raise ValueError(f"reorder_limit must be >= 0, not {reorder_limit}")
    with CaptureReader(source) as reader:
        tracker = _Decoding(
            wire=wire, auto=auto, ports=ports, types=types, reorder_limit=reorder_limit, max_length=max_length
        )
        out = tracker.out
        streams = tracker.streams
        new_stream = tracker.stream
        segment = tracker.segment
        deliver = tracker.deliver
        frame_error = tracker.frame_error
        wanted = tracker.types
        ts = 0
        for ts, key, seq, ack, flags, payload in reader.segment_tuples():
            s = streams.get(key)
            if s is None:
                s = new_stream(key)
                if s is None:
                    continue
            # The fast path: the next bytes of a started stream, nothing to sort out (Direction.take),
            # a decoder that knows its byte order: its frames are decoded and given here, at once.
            if not s.take(seq, flags, len(payload)):
                segment(s, ts, seq, ack, flags, payload)
            elif payload:
                decoder = s.decoder
                found = s.wire
                if found is None or decoder.failed:
                    deliver(s, payload, ts)
                else:
                    decoder.feed(payload)
                    src, dst, client = s.src, s.dst, s.conn.client
                    type_of = s.type_of
                    try:
                        while (frame := decoder.next_frame()) is not None:
                            if wanted is not None and type_of(frame, 4)[0] not in wanted:
                                continue
                            try:
                                message = decode(frame, found)
                            except MalformedMessage as exc:
                                yield CapturedMessage(ts, src, dst, None, exc.with_traceback(None), frame, client)
                                continue
                            yield CapturedMessage(ts, src, dst, message, None, frame, client)
                    except FrameError:
                        frame_error(s, decoder, ts)
            else:
                continue  # an ACK in order
            if out:
                yield from out
                out.clear()
        tracker.finish(ts)
        yield from out
        out.clear()
        for link, count in sorted(reader.unsupported.items()):
            yield CaptureEvent(
                EventKind.UNSUPPORTED_LINK_TYPE,
                f"{count} packets of link type {link} were skipped (read are: "
                + ", ".join(f"{number} {name}" for number, name in sorted(LINK_TYPES.items()))
                + ")",
            )
