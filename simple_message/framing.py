"""The frame decoder: bytes in any chunking, complete frames out.

simple_message frames by byte count only: a 4-byte length prefix that counts the header and body
but not itself, no magic bytes and no checksum (docs/reference/protocol.md §1.1). So a frame decoder can
realign after a bad *body* but never after a bad *length*: a prefix below 12, negative or above the
configured maximum raises :class:`~.errors.FrameError`, after which the connection must be closed
(§12 test 4). The default maximum, 64 KiB, is far above any standard message (the largest,
GET_DH_PARAMETERS in float64, is 1036 bytes); a C++-compatible peer cannot take more than 1019.

The decoder is sans-I/O (like h11): :meth:`FrameDecoder.feed` takes whatever bytes arrived,
:meth:`FrameDecoder.next_frame` hands out complete frames (``None`` means "need more data"). Frames
are cut as soon as they are complete, so the decoder never holds more than one incomplete frame,
which is at most ``4 + max_length`` bytes: a peer cannot make it allocate more by announcing a
huge length, because the length is checked before any of the body is kept.

:meth:`FrameDecoder.feed_messages` is ``feed`` plus :func:`~.messages.decode` of each frame in one
pass, the path of a :class:`~.link.Link`: a frame of a fixed layout is decoded where it lies in the
received bytes, and a run of frames with the same header (a streamed trajectory, a feedback topic)
is decoded in one loop that compares each next header's bytes instead of reading them.

Byte-order autodetection (§10 pitfall 1, the Wireshark dissector's rule): the first length prefix is
read both ways; the order in which it is a plausible length wins. Once decided it holds for the rest
of the stream and is available as :attr:`FrameDecoder.byte_order`.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Iterator

from .constants import HEADER_SIZE, LENGTH_SIZE, CommType
from .errors import FrameError, MalformedMessage
from .messages import Message, decode, fast_decoders
from .wire import DEFAULT_FORMAT, ByteOrder, WireFormat

__all__ = ["FrameDecoder", "DEFAULT_MAX_LENGTH", "detect_byte_order", "decode_or_error"]

#: Default largest accepted length prefix (header + body), in bytes.
DEFAULT_MAX_LENGTH = 64 * 1024

#: The smallest frame: the length prefix and the header.
_FRAME_MIN = LENGTH_SIZE + HEADER_SIZE
_SERVICE_REPLY = int(CommType.SERVICE_REPLY)
#: At most this many distinct header-only frames are kept decoded (per wire format, for all decoders).
_SMALL_FRAMES = 256

_LE = struct.Struct("<i")
_BE = struct.Struct(">i")


def detect_byte_order(prefix: bytes | bytearray, max_length: int = DEFAULT_MAX_LENGTH) -> ByteOrder:
    """Decide the byte order from a frame's first four bytes.

    Raises :class:`~.errors.FrameError` if the prefix is a plausible length in neither order. If it
    is plausible in both (only possible for a ``max_length`` of 16 MiB or more), little-endian, the
    ROS default, wins.
    """
    (le,) = _LE.unpack_from(prefix, 0)
    (be,) = _BE.unpack_from(prefix, 0)
    le_ok = HEADER_SIZE <= le <= max_length
    be_ok = HEADER_SIZE <= be <= max_length
    if le_ok:
        return ByteOrder.LITTLE
    if be_ok:
        return ByteOrder.BIG
    raise FrameError(
        f"cannot detect the byte order: the first length prefix {bytes(prefix[:4]).hex()} reads as {le} "
        f"(little-endian) and {be} (big-endian), neither within {HEADER_SIZE}..{max_length}",
        length=le,
    )


class FrameDecoder:
    """Cuts a byte stream into simple_message frames.

    ``byte_order=None`` detects the order from the first frame. Each frame is returned whole, as
    ``bytes`` including its length prefix, ready for :func:`~.messages.decode`; or, with
    :meth:`feed_messages`, frames are cut and decoded in one pass.
    """

    __slots__ = (
        "_buf",
        "_error",
        "_frames",
        "_given",
        "_order",
        "_plain",
        "_prefix",
        "_tables",
        "_wire",
        "detected",
        "frames_decoded",
        "max_length",
    )

    def __init__(
        self, byte_order: ByteOrder | None = ByteOrder.LITTLE, *, max_length: int = DEFAULT_MAX_LENGTH
    ) -> None:
        if max_length < HEADER_SIZE:
            raise ValueError(f"max_length must be at least {HEADER_SIZE}")
        self.max_length = max_length
        self._buf = b""
        self._frames: deque[bytes] = deque()
        self._error: FrameError | None = None
        self._order: ByteOrder | None = ByteOrder(byte_order) if byte_order is not None else None
        self._prefix = (_LE if self._order is ByteOrder.LITTLE else _BE) if self._order else None
        # feed_messages: the wire it was last given, the one it decodes in, whether that is in
        # another byte order than frames are cut in (then the plain path), and its fast decoders.
        self._given: WireFormat | None = None
        self._wire = DEFAULT_FORMAT
        self._plain = False
        self._tables = fast_decoders(DEFAULT_FORMAT)
        #: True once the byte order was detected from the stream (autodetection only).
        self.detected = False
        #: Number of complete frames cut so far.
        self.frames_decoded = 0

    @property
    def byte_order(self) -> ByteOrder | None:
        """The stream's byte order: as configured, as detected, or ``None`` while still unknown."""
        return self._order

    @property
    def buffered(self) -> int:
        """Bytes held for an incomplete frame (at most ``4 + max_length``)."""
        return len(self._buf)

    @property
    def failed(self) -> bool:
        """True once a framing error was found; the stream cannot be realigned."""
        return self._error is not None

    @property
    def error(self) -> FrameError | None:
        """The framing error that ended the stream, or ``None``."""
        return self._error

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Take the next chunk of the stream. Frames it completes are queued for :meth:`next_frame`."""
        if self._error is not None or not data:
            return
        # Work on one immutable bytes object, so each frame costs one slice (one copy); only the
        # incomplete tail, at most one frame, is kept between calls.
        buf = self._buf + data if self._buf else bytes(data)
        pos = 0
        end = len(buf)
        max_length = self.max_length
        append = self._frames.append
        try:
            prefix = self._prefix or self._detect(buf, end)
            if prefix is None:
                self._buf = buf
                return
            while end - pos >= LENGTH_SIZE:
                (length,) = prefix.unpack_from(buf, pos)
                if length < HEADER_SIZE or length > max_length:
                    raise FrameError(_length_problem(length, max_length), length=length)
                stop = pos + LENGTH_SIZE + length
                if stop > end:
                    break
                append(buf[pos:stop])
                pos = stop
        except FrameError as exc:
            self._error = exc.with_traceback(None)  # kept: its frames would keep this decoder in a cycle
            self._buf = b""
            return
        self._buf = buf[pos:] if pos < end else b""

    def feed_messages(self, data: bytes | bytearray | memoryview, wire: WireFormat) -> list[Message | MalformedMessage]:
        """:meth:`feed` and :func:`~.messages.decode` in one pass: the messages of the frames that
        ``data`` completes, in stream order.

        The same as ``feed(data)`` followed by ``decode(frame, wire)`` of every frame it completes
        (frames queued by an earlier :meth:`feed` and not taken yet come first), but a frame of a
        fixed layout is decoded straight from the stream, never cut out, and a header-only frame
        (PING, an ack) seen before comes back as the same (immutable) message as then. A frame whose
        body does not decode comes back as its :class:`~.errors.MalformedMessage` (returned, not
        raised: the stream stays aligned). Frames are decoded in ``wire``, but in the stream's byte order once
        it was detected (with ``wire``'s real size): what a :class:`~.link.Link` does.

        A bad length prefix ends the stream as with :meth:`feed`: the messages of the frames before
        it are returned, :attr:`failed` becomes true, :attr:`error` holds the
        :class:`~.errors.FrameError`, and later calls return nothing.
        """
        if wire is not self._given:
            self._use(wire)
        out: list[Message | MalformedMessage] = []
        if self._frames:
            self._take_frames(out)
        if self._error is not None or not data:
            return out
        if self._plain:
            # Frames cut in one byte order and decoded in another (the wire a Link that does not
            # detect decodes with was changed): the plain path, which does just what was asked.
            self.feed(data)
            self._take_frames(out)
            return out
        buf = self._buf + data if self._buf else data if type(data) is bytes else bytes(data)
        pos = 0
        end = len(buf)
        max_length = self.max_length
        queued = len(out)
        try:
            prefix = self._prefix
            if prefix is None:
                prefix = self._detect(buf, end)
                if prefix is None:
                    self._buf = buf
                    return out
                self._use(wire)  # now in the detected byte order
            wire = self._wire
            tables = self._tables
            requests, replies, small = tables.requests, tables.replies, tables.small
            header = wire.header.unpack_from
            append = out.append
            service_reply = _SERVICE_REPLY
            # A complete frame is at least the length prefix and the header (16 bytes); with less
            # left, only the length prefix can be checked (below).
            while end - pos >= _FRAME_MIN:
                length, msg_type, comm, reply = header(buf, pos)
                if length < HEADER_SIZE or length > max_length:
                    raise FrameError(_length_problem(length, max_length), length=length)
                stop = pos + LENGTH_SIZE + length
                if stop > end:
                    break
                if length == HEADER_SIZE:  # header only: decoded once per distinct frame
                    frame = buf[pos:stop]
                    item: Message | MalformedMessage | None = small.get(frame)
                    if item is None:
                        item = decode_or_error(frame, wire)
                        if isinstance(item, Message) and len(small) < _SMALL_FRAMES:
                            small[frame] = item
                    append(item)
                    pos = stop
                    continue
                codec = (replies if comm == service_reply else requests)[msg_type]
                if codec is not None and length == codec.length:
                    # this frame and the ones after it with the same header, straight from buf
                    pos = codec.unpack_run(buf, pos, end, msg_type, comm, reply, out)
                else:  # any other shape of the type, an unknown type, a malformed body
                    append(decode_or_error(buf[pos:stop], wire))
                    pos = stop
            if end - pos >= LENGTH_SIZE:
                (length,) = prefix.unpack_from(buf, pos)
                if length < HEADER_SIZE or length > max_length:
                    raise FrameError(_length_problem(length, max_length), length=length)
        except FrameError as exc:
            self._error = exc.with_traceback(None)  # kept: its frames would keep this decoder in a cycle
            pos = end
        self._buf = buf[pos:] if pos < end else b""
        self.frames_decoded += len(out) - queued
        return out

    def one_message(self, data: bytes, wire: WireFormat) -> Message | MalformedMessage | None:
        """``feed_messages(data, wire)`` for the commonest read, one whole frame (a request, its reply,
        one topic): its message, or ``None`` with nothing done when ``data`` is anything else.

        The shortcut applies when nothing is held (no incomplete frame, no frame queued by
        :meth:`feed`, no error), the byte order is known, ``wire`` is the one the last
        :meth:`feed_messages` was given, and ``data`` (``bytes``) is exactly one frame whose length
        prefix is within the maximum. The message is then exactly what :meth:`feed_messages` returns
        as its only item, and :attr:`frames_decoded` counts it; otherwise call :meth:`feed_messages`.
        """
        if wire is not self._given or self._buf or self._frames or self._error is not None or self._plain:
            return None
        if self._prefix is None or type(data) is not bytes or len(data) < _FRAME_MIN:
            return None
        wire = self._wire
        length, msg_type, comm, _ = wire.header.unpack_from(data, 0)
        if length != len(data) - LENGTH_SIZE or length > self.max_length:
            return None  # a part of a frame, several, or a bad length: the general path
        self.frames_decoded += 1
        tables = self._tables
        if length == HEADER_SIZE:  # header only: decoded once per distinct frame, as feed_messages does
            small = tables.small
            item: Message | MalformedMessage | None = small.get(data)
            if item is None:
                item = decode_or_error(data, wire)
                if isinstance(item, Message) and len(small) < _SMALL_FRAMES:
                    small[data] = item
            return item
        codec = (tables.replies if comm == _SERVICE_REPLY else tables.requests)[msg_type]
        if codec is not None and length == codec.length:
            return codec.unpack(data)
        return decode_or_error(data, wire)

    def cached(self, data: bytes, wire: WireFormat) -> Message | None:
        """What :meth:`one_message` would return for ``data`` without decoding anything: the kept
        message of a header-only frame (PING, an ack) decoded before, when ``data`` is exactly that
        frame and the decoder is where :meth:`one_message` applies; else ``None``. Nothing is
        counted or changed (:meth:`.link.Link.take_standing` counts what it takes)."""
        if wire is not self._given or self._buf or self._frames or self._error is not None or self._plain:
            return None
        if self._prefix is None:
            return None
        return self._tables.small.get(data)

    def _detect(self, buf: bytes, end: int) -> struct.Struct | None:
        """Detect the byte order from the stream's first length prefix (``None``: not 4 bytes yet)."""
        if end < LENGTH_SIZE:
            return None
        self._order = detect_byte_order(buf[:LENGTH_SIZE], self.max_length)
        self._prefix = _LE if self._order is ByteOrder.LITTLE else _BE
        self.detected = True
        self._given = None  # feed_messages: decode in the detected order from now on
        return self._prefix

    def _use(self, wire: WireFormat) -> None:
        """Prepare :meth:`feed_messages` for ``wire``."""
        order = self._order
        if self.detected and order is not None and order is not wire.byte_order:
            self._wire = wire.with_byte_order(order)
        else:
            self._wire = wire
        self._plain = order is not None and order is not self._wire.byte_order
        self._tables = fast_decoders(self._wire)
        self._given = wire

    def _take_frames(self, out: list[Message | MalformedMessage]) -> None:
        """Decode the frames queued by :meth:`feed` into ``out`` (for :meth:`feed_messages`)."""
        wire = self._wire
        out.extend(decode_or_error(frame, wire) for frame in self._frames)
        self.frames_decoded += len(self._frames)
        self._frames.clear()

    def next_frame(self) -> bytes | None:
        """The next complete frame, or ``None`` if more data is needed.

        Raises :class:`~.errors.FrameError` (again on every call) once the frames before a bad
        length prefix have been handed out.
        """
        if self._frames:
            self.frames_decoded += 1
            return self._frames.popleft()
        if self._error is not None:
            raise self._error
        return None

    def __iter__(self) -> Iterator[bytes]:
        """Every complete frame queued so far; raises :class:`~.errors.FrameError` after them if
        the stream is broken."""
        frames = self._frames
        while frames:
            self.frames_decoded += 1
            yield frames.popleft()
        if self._error is not None:
            raise self._error


def decode_or_error(frame: bytes, wire: WireFormat) -> Message | MalformedMessage:
    """The message of one whole frame, or the :class:`~.errors.MalformedMessage` its body is
    (returned, without the traceback: a peer's garbage is data here, and an error that keeps its
    frames alive keeps a reference cycle alive until the garbage collector runs)."""
    try:
        return decode(frame, wire)
    except MalformedMessage as exc:
        return exc.with_traceback(None)


def _length_problem(length: int, max_length: int) -> str:
    if length < 0:
        return f"negative length prefix {length}: the stream is corrupt or the byte order is wrong"
    if length < HEADER_SIZE:
        return f"length prefix {length} is below the {HEADER_SIZE}-byte header"
    return f"length prefix {length} exceeds the maximum of {max_length} bytes (wrong byte order?)"
