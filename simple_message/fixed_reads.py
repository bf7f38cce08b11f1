"""Cutting a stream as a controller that reads fixed byte counts does.

The protocol frames by the length prefix (:class:`~.framing.FrameDecoder`), and so do the C++ library,
MotoROS and ABB's RAPID server. Some controller-side servers do not: Fanuc's KAREL relay waits until
56 bytes are buffered and then reads 60 (68 for a JOINT_TRAJ_PT), whatever the prefix says;
Stäubli's VAL3 server reads the prefix and the header, then a body whose size depends on the type
alone. Against such a server a message of another size is not "malformed": its bytes are read as
part of something else, and the stream is misframed from there on, silently. An emulator of those
controllers must cut the input the same way, or a client that works against it fails against the
robot.

:class:`FixedReads` is the frame cutter of a :class:`~.link.Link` for such a server. A subclass says
where each read ends (:meth:`FixedReads.cut`: the controller's read sizes, given the bytes waiting),
and every read becomes a :class:`~.messages.RawMessage` carrying the header as read and the bytes
read after it: what the controller understood is the server's handlers' business, not the codec's
(a Fanuc relay takes any read for a trajectory point). Like :class:`~.framing.FrameDecoder` it is
sans-I/O and holds at most one read's bytes; it never detects a byte order, and its link hands
every read to the server as received (``raw``): no read is a reply. A :meth:`~FixedReads.cut` that
raises :class:`~.errors.FrameError` ends the stream as a bad length prefix does (a lenient cutter
that frames by the prefix).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterator

from .constants import HEADER_SIZE, LENGTH_SIZE
from .errors import FrameError, MalformedMessage
from .messages import Message, RawMessage
from .wire import ByteOrder, WireFormat

__all__ = ["DiscardReads", "FixedReads", "FRAME_HEAD", "prefix_cut"]

#: the bytes of the length prefix and the header: what every read of these servers begins with
FRAME_HEAD = LENGTH_SIZE + HEADER_SIZE


class FixedReads(ABC):
    """A frame cutter that reads what a controller reads (see the module doc)."""

    #: the link hands every read to the server as received (no reply matching, no body check)
    raw = True
    #: never detected: a controller that reads fixed sizes speaks one byte order
    detected = False

    def __init__(self, wire: WireFormat) -> None:
        self.wire = wire
        self._buf = b""
        self._frames: deque[bytes] = deque()
        #: reads cut so far
        self.frames_decoded = 0
        #: what ended the stream (a cutter that frames by the length prefix), or None
        self.error: FrameError | None = None

    @property
    def failed(self) -> bool:
        return self.error is not None

    @abstractmethod
    def cut(self, buf: bytes, start: int) -> int | None:
        """Where the read that begins at ``buf[start]`` ends (an offset into ``buf``), or ``None``
        while the controller would not read yet (too few bytes waiting)."""

    def message(self, frame: bytes, wire: WireFormat) -> Message | MalformedMessage:
        """What one read is: its header's type, comm type and reply code as read, and the bytes
        read after the header as the body (a read shorter than a header is one all the same)."""
        head = frame[:FRAME_HEAD].ljust(FRAME_HEAD, b"\0")
        _, msg_type, comm, reply = wire.header.unpack_from(head, 0)
        return RawMessage(msg_type, bytes(frame[FRAME_HEAD:]), comm_type=comm, reply_code=reply)

    # -- what a Link asks of its cutter --------------------------------------------------------------

    @property
    def byte_order(self) -> ByteOrder:
        return self.wire.byte_order

    @property
    def buffered(self) -> int:
        """Bytes waiting that the controller has not read yet (at most one read)."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Take the next chunk of the stream; the reads it completes are queued."""
        if not data or self.error is not None:
            return
        buf = self._buf + bytes(data) if self._buf else bytes(data)
        pos = 0
        while pos < len(buf):
            try:
                end = self.cut(buf, pos)
            except FrameError as exc:
                self.error = exc.with_traceback(None)
                self._buf = b""
                return
            if end is None:
                break
            if end <= pos or end > len(buf):
                raise AssertionError(f"{type(self).__name__}.cut gave {end} for a read from {pos} of {len(buf)} bytes")
            self._frames.append(buf[pos:end])
            pos = end
        self._buf = buf[pos:]

    def feed_messages(self, data: bytes | bytearray | memoryview, wire: WireFormat) -> list[Message | MalformedMessage]:
        """:meth:`feed`, then :meth:`message` of every read completed."""
        self.feed(data)
        out = [self.message(frame, wire) for frame in self._frames]
        self.frames_decoded += len(out)
        self._frames.clear()
        return out

    def next_frame(self) -> bytes | None:
        """The next read's bytes, or ``None`` while none is complete (the stream's
        :class:`~.errors.FrameError` once it ended)."""
        if self._frames:
            self.frames_decoded += 1
            return self._frames.popleft()
        if self.error is not None:
            raise self.error
        return None

    def __iter__(self) -> Iterator[bytes]:
        while self._frames:
            self.frames_decoded += 1
            yield self._frames.popleft()
        if self.error is not None:
            raise self.error


class DiscardReads(FixedReads):
    """A server that never reads its input (a controller's state server sends and never reads):
    every byte is dropped as it comes, so no read is ever cut, nothing is answered and nothing is
    held. :attr:`discarded` counts the bytes."""

    def __init__(self, wire: WireFormat) -> None:
        super().__init__(wire)
        self.discarded = 0

    def cut(self, buf: bytes, start: int) -> int | None:
        return len(buf)  # never called: feed drops the bytes

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        self.discarded += len(data)


def prefix_cut(buf: bytes, start: int, wire: WireFormat, max_length: int) -> int | None:
    """Where the frame at ``buf[start]`` ends by its length prefix (``None``: not all here yet);
    :class:`~.errors.FrameError` for a length the protocol cannot have (a lenient cutter's rule)."""
    if len(buf) - start < LENGTH_SIZE:
        return None
    (length,) = wire.struct("i").unpack_from(buf, start)
    if not HEADER_SIZE <= length <= max_length:
        raise FrameError(f"length prefix {length} is not a frame of {HEADER_SIZE} to {max_length} bytes", length=length)
    end = start + LENGTH_SIZE + length
    return end if end <= len(buf) else None
