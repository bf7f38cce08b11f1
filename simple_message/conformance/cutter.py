"""The tolerant frame cutter: how both conformance suites cut a peer's bytes into frames.

The project's own framing (:class:`~simple_message.framing.FrameDecoder`) is made to *speak* the
protocol: a bad length prefix ends the stream with an error. A conformance suite must instead
*describe* what a peer sent. So a frame whose length prefix is a plausible length only in the other
byte order is cut in that order and handed on as such (docs/reference/protocol.md §10 pitfall 1, the
dissector's heuristic): every length a frame can have (12..0xFFFF) reads as at least 0x10000 the
other way round, so the byte order of a plausible prefix is never in doubt. A prefix plausible in
neither order ends the cutting: the rest of the stream is handed on as it is, uncut.

The server suite's links (:mod:`.links`) read the server's frames with :class:`FrameCutter`; the
client suite's proxy (:mod:`.client_proxy`) the client's and the controller's, and the client suite
(:mod:`.client`) the controller's state port.
"""

from __future__ import annotations

import struct

from ..constants import HEADER_SIZE, LENGTH_SIZE
from ..wire import ByteOrder

__all__ = ["MAX_FRAME", "FrameCutter", "other_order", "prefix_order"]

#: the largest length prefix taken as a frame (the largest standard message is about 1 KiB). Every
#: length from 12 to 0xFFFF reads as at least 0x10000 the other way round, so the byte order of a
#: plausible prefix is never in doubt (§10 pitfall 1)
MAX_FRAME = 0xFFFF

_ORDER = {ByteOrder.LITTLE: struct.Struct("<i"), ByteOrder.BIG: struct.Struct(">i")}


def other_order(order: ByteOrder) -> ByteOrder:
    return ByteOrder.BIG if order is ByteOrder.LITTLE else ByteOrder.LITTLE


def prefix_order(prefix: bytes | bytearray, expected: ByteOrder) -> tuple[ByteOrder, int] | None:
    """The byte order a length prefix is a plausible length in, ``expected`` first, and that
    length; ``None`` when it is one in neither (the stream cannot be cut further)."""
    for order in (expected, other_order(expected)):
        (length,) = _ORDER[order].unpack_from(prefix, 0)
        if HEADER_SIZE <= length <= MAX_FRAME:
            return order, length
    return None


def read_length(prefix: bytes | bytearray, order: ByteOrder) -> int:
    """A length prefix as read in ``order``, plausible or not."""
    (length,) = _ORDER[order].unpack_from(prefix, 0)
    return int(length)


class FrameCutter:
    """Cuts a byte stream into frames, each in the byte order its length prefix is plausible in
    (``order``, the one expected, first).

    :meth:`feed` gives each whole frame with its byte order. A prefix plausible in neither order
    ends the cutting: what is left of the stream comes back with the order ``None``, and so does
    everything fed after it (:attr:`lost`). At most one frame (4 + 0xFFFF bytes) is held; ``order``
    may be changed between feeds (once the peer's byte order is decided).
    """

    def __init__(self, order: ByteOrder) -> None:
        self.order = order
        self._buf = bytearray()
        #: the stream could not be cut any further
        self.lost = False

    @property
    def held(self) -> int:
        """Bytes of a frame begun and not yet whole."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[tuple[bytes, ByteOrder | None]]:
        if self.lost:
            return [(data, None)] if data else []
        self._buf += data
        out: list[tuple[bytes, ByteOrder | None]] = []
        buf = self._buf
        while len(buf) >= LENGTH_SIZE:
            found = prefix_order(buf, self.order)
            if found is None:
                out.append((bytes(buf), None))
                buf.clear()
                self.lost = True
                break
            order, length = found
            end = LENGTH_SIZE + length
            if len(buf) < end:
                break
            out.append((bytes(buf[:end]), order))
            del buf[:end]
        return out
