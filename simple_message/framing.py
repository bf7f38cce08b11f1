"""The frame decoder: bytes in any chunking, complete frames out.

simple_message frames by byte count only: a 4-byte length prefix that counts the header and body
but not itself, no magic bytes and no checksum (simple-message.md §1.1). So a frame decoder can
realign after a bad *body* but never after a bad *length*: a prefix below 12, negative or above the
configured maximum raises :class:`~.errors.FrameError`, after which the connection must be closed
(§12 test 4). The default maximum, 64 KiB, is far above any standard message (the largest,
GET_DH_PARAMETERS in float64, is 1036 bytes); a C++-compatible peer cannot take more than 1019.

The decoder is sans-I/O (like h11): :meth:`FrameDecoder.feed` takes whatever bytes arrived,
:meth:`FrameDecoder.next_frame` hands out complete frames (``None`` means "need more data"). Frames
are cut as soon as they are complete, so the decoder never holds more than one incomplete frame,
which is at most ``4 + max_length`` bytes: a peer cannot make it allocate more by announcing a
huge length, because the length is checked before any of the body is kept.

Byte-order autodetection (§10 pitfall 1, the Wireshark dissector's rule): the first length prefix is
read both ways; the order in which it is a plausible length wins. Once decided it holds for the rest
of the stream and is available as :attr:`FrameDecoder.byte_order`.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Iterator

from .constants import HEADER_SIZE, LENGTH_SIZE
from .errors import FrameError
from .wire import ByteOrder

__all__ = ["FrameDecoder", "DEFAULT_MAX_LENGTH", "detect_byte_order"]

#: Default largest accepted length prefix (header + body), in bytes.
DEFAULT_MAX_LENGTH = 64 * 1024

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
    ``bytes`` including its length prefix, ready for :func:`~.messages.decode`.
    """

    __slots__ = ("_buf", "_error", "_frames", "_order", "_prefix", "detected", "frames_decoded", "max_length")

    def __init__(
        self, byte_order: ByteOrder | None = ByteOrder.LITTLE, *, max_length: int = DEFAULT_MAX_LENGTH
    ) -> None:
        if max_length < HEADER_SIZE:
            raise ValueError(f"max_length must be at least {HEADER_SIZE}")
        self.max_length = max_length
        self._buf = bytearray()
        self._frames: deque[bytes] = deque()
        self._error: FrameError | None = None
        self._order: ByteOrder | None = ByteOrder(byte_order) if byte_order is not None else None
        self._prefix = (_LE if self._order is ByteOrder.LITTLE else _BE) if self._order else None
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

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Take the next chunk of the stream. Frames it completes are queued for :meth:`next_frame`."""
        if self._error is not None or not data:
            return
        # Work on one immutable bytes object, so each frame costs one slice (one copy); only the
        # incomplete tail, at most one frame, is kept between calls.
        buf = bytes(self._buf) + bytes(data) if self._buf else bytes(data)
        pos = 0
        end = len(buf)
        prefix = self._prefix
        max_length = self.max_length
        append = self._frames.append
        try:
            while end - pos >= LENGTH_SIZE:
                if prefix is None:
                    self._order = detect_byte_order(buf[pos : pos + LENGTH_SIZE], max_length)
                    prefix = self._prefix = _LE if self._order is ByteOrder.LITTLE else _BE
                    self.detected = True
                (length,) = prefix.unpack_from(buf, pos)
                if length < HEADER_SIZE or length > max_length:
                    raise FrameError(_length_problem(length, max_length), length=length)
                stop = pos + LENGTH_SIZE + length
                if stop > end:
                    break
                append(buf[pos:stop])
                pos = stop
        except FrameError as exc:
            self._error = exc
            self._buf = bytearray()
            return
        self._buf = bytearray(buf[pos:]) if pos < end else bytearray()

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


def _length_problem(length: int, max_length: int) -> str:
    if length < 0:
        return f"negative length prefix {length}: the stream is corrupt or the byte order is wrong"
    if length < HEADER_SIZE:
        return f"length prefix {length} is below the {HEADER_SIZE}-byte header"
    return f"length prefix {length} exceeds the maximum of {max_length} bytes (wrong byte order?)"
