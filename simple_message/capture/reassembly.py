"""TCP reassembly of a capture's connections: each direction's bytes in order, what the capture lost
reported, never guessed.

:class:`Reassembler` takes the segments of :meth:`.formats.SegmentReader.segment_tuples` and keeps
one :class:`Direction` per direction of each connection. It knows TCP only: what the bytes are is
the business of a subclass (the frame decoding of :mod:`.messages`), which makes the directions
(:meth:`Reassembler.direction`), takes each direction's next bytes (:meth:`Reassembler.deliver`),
says how many bytes of an incomplete frame it holds (:meth:`Reassembler.buffered`), starts again
after a gap (:meth:`Reassembler.restart`), hears that a direction ended
(:meth:`Reassembler.closed`) and collects the events (:meth:`Reassembler.report`). A caller on the
hot path takes a segment that is simply a direction's next bytes itself (:meth:`Direction.take`)
and gives every other one to :meth:`Reassembler.segment`.

**TCP reassembly** is per direction of each connection (the 4-tuple), on sequence numbers alone:

* A SYN gives the initial sequence number; a stream captured mid-connection (no SYN, e.g. the
  second file of a rotated capture) starts at the first segment seen. A SYN with another initial
  sequence number on the same 4-tuple starts a new connection (the old one is ended first).
* Segments in order are handed to the frame decoder as they are (their payload is the only copy
  made of a packet; held segments are kept as they came). Retransmitted and duplicated bytes are
  dropped; of a segment that overlaps what was already taken, only the new bytes are used (the
  first copy of a byte wins). A segment beyond the next expected byte is held until the bytes
  before it arrive.
* **A gap** (bytes the capture does not hold) is given up on, never guessed, when it cannot fill
  any more: when the receiver acknowledges bytes beyond it (the sender will not send them again:
  the capture dropped them), at a RST, at the end of the capture, when the same 4-tuple starts a
  new connection, or when the held segments outgrow ``reorder_limit``. It is reported as a ``Gap``
  event with the byte range (offsets in the direction's stream, and the sequence numbers in the
  message). Frame alignment is lost there, so the direction's frame decoder is restarted at the
  next segment after the gap (keeping the byte order it detected): if that segment does not begin
  a frame, the misframe shows as a ``FrameError`` event, never as made-up messages. The bytes of
  an incomplete frame before the gap are dropped (the ``Gap`` event says how many). Bytes missing
  at the end of a direction are reported too when a later segment of it (a FIN, a pure ACK's
  sequence number) shows they were sent; bytes lost with nothing of their direction captured
  after them cannot be told from bytes never sent.
* A FIN ends its direction once every byte before it arrived; a RST ends both directions.
* After a ``FrameError`` (an impossible length prefix: the stream cannot be realigned) nothing
  more of that direction is decoded until a gap restarts its decoder.
* An incomplete frame at the end of a direction (FIN, RST, end of capture) is a
  ``TruncatedFrame`` event.
* Items come in capture order; a message comes at (and has the time of) the segment that carried
  the last byte of its frame; messages held behind a gap come when it is filled or given up on
  (at the latest at the end of the capture).

**Memory** is bounded: each direction holds at most one incomplete frame (the frame decoder's
bound, ``4 + max_length``) and at most ``reorder_limit`` bytes (default 4 MiB) of out-of-order
segments: one more segment reports a ``ReorderOverflow`` event and gives up on the gap before the
held segments. Per connection, a small fixed state is kept until the end (ended connections
included, so that late retransmissions are recognised).
"""

from __future__ import annotations

import heapq
import itertools
from abc import ABC, abstractmethod
from collections.abc import Collection
from dataclasses import dataclass
from enum import StrEnum
from typing import Generic, Self, TypeVar

import dpkt  # type: ignore[import-untyped, unused-ignore]

from .formats import Address, addresses, format_address, to_seconds

__all__ = [
    "DEFAULT_REORDER_LIMIT",
    "CaptureEvent",
    "Connection",
    "Direction",
    "EventKind",
    "Reassembler",
]

#: Default bound of the out-of-order segments held per direction (bytes).
DEFAULT_REORDER_LIMIT = 4 * 1024 * 1024

_SEQ = 0xFFFFFFFF
_HALF = 1 << 31

_FIN, _SYN, _RST, _ACK = dpkt.tcp.TH_FIN, dpkt.tcp.TH_SYN, dpkt.tcp.TH_RST, dpkt.tcp.TH_ACK
_SYN_RST_FIN = _SYN | _RST | _FIN


class EventKind(StrEnum):
    """What a :class:`CaptureEvent` reports (the value is the ``"type"`` the command prints)."""

    #: bytes of a direction the capture does not hold; decoding restarts after them
    GAP = "Gap"
    #: more than ``reorder_limit`` bytes waited for a missing segment; the gap is given up on
    REORDER_OVERFLOW = "ReorderOverflow"
    #: an incomplete frame at the end of a direction
    TRUNCATED_FRAME = "TruncatedFrame"
    #: an impossible length prefix: the direction cannot be realigned (until a gap)
    FRAME_ERROR = "FrameError"
    #: packets of a link type the capture package does not read were skipped
    UNSUPPORTED_LINK_TYPE = "UnsupportedLinkType"


@dataclass(frozen=True, slots=True)
class CaptureEvent:
    """Something in a capture that is not a message: a gap, a truncated frame, a framing error."""

    kind: EventKind
    #: what happened, in words (the command's ``"error"``)
    message: str
    #: capture time it was found at (ns since the epoch), ``None`` for the capture as a whole
    time_ns: int | None = None
    src: Address | None = None
    dst: Address | None = None
    #: the byte range concerned, as offsets in the direction's stream (0: its first byte)
    start: int | None = None
    end: int | None = None

    @property
    def time(self) -> float | None:
        """Capture time in seconds since the epoch, or ``None``."""
        return None if self.time_ns is None else to_seconds(self.time_ns)


class Connection:
    """What the two directions of one connection share."""

    __slots__ = ("client",)

    def __init__(self) -> None:
        #: the side that opened the connection, once a SYN (or SYN-ACK) shows it
        self.client: Address | None = None


class Direction:
    """One direction of one connection: its sequence state and held segments (read-only outside
    this module but for :meth:`take`; a subclass adds what its bytes are decoded with)."""

    __slots__ = (
        "conn",
        "done",
        "dst",
        "fin_at",
        "heap",
        "held",
        "high",
        "isn",
        "key",
        "late_start",
        "next_seq",
        "offset",
        "reverse",
        "src",
    )

    #: the other direction of the connection (set by the :class:`Reassembler` that makes the two)
    reverse: Self

    def __init__(self, key: bytes, src: Address, dst: Address, conn: Connection) -> None:
        self.key = key
        self.src = src
        self.dst = dst
        self.conn = conn
        self.isn: int | None = None
        self.next_seq: int | None = None  # the sequence number of the next byte expected
        self.offset = 0  # its offset in the stream
        self.heap: list[tuple[int, int, int, bytes]] = []  # (offset, order, time_ns, payload)
        self.held = 0
        self.high = 0  # the end of the furthest bytes the capture shows were sent (a stream offset)
        self.fin_at: int | None = None
        self.done = False
        #: captured without its SYN, it began with a segment that earlier bytes came after (reported once)
        self.late_start = False

    def take(self, seq: int, flags: int, n: int) -> bool:
        """Whether a segment of ``n`` bytes at ``seq`` is simply this direction's next bytes: the
        direction started, not ended, no SYN, RST or FIN, nothing held either way (so its ACK has
        no gap to close). Then its bytes are counted as taken and the caller hands them on itself
        (:meth:`Reassembler.deliver` does it the slow way); else the caller gives the segment to
        :meth:`Reassembler.segment`."""
        if seq != self.next_seq or flags & _SYN_RST_FIN or self.heap or self.reverse.heap or self.done:
            return False
        if n:
            self.next_seq = (seq + n) & _SEQ
            self.offset += n
        return True

    def __str__(self) -> str:
        return f"{format_address(self.src)} -> {format_address(self.dst)}"


D = TypeVar("D", bound=Direction)


class Reassembler(ABC, Generic[D]):
    """Reassembles the connections of one capture; a subclass says what their bytes are (see the
    module doc). ``ports`` keeps the connections with one of these ports at either end."""

    def __init__(self, *, ports: Collection[int] | None, reorder_limit: int) -> None:
        self.ports = frozenset(ports) if ports is not None else None
        self.reorder_limit = reorder_limit
        #: the directions by :meth:`~.formats.SegmentReader.segment_tuples` key
        self.streams: dict[bytes, D] = {}
        self.ignored: set[bytes] = set()  # the connections the ports filter drops, both directions
        self._order = itertools.count()

    # -- what a subclass does with the bytes

    @abstractmethod
    def direction(self, key: bytes, src: Address, dst: Address, conn: Connection) -> D:
        """A new direction of a connection (a :class:`Direction` with the subclass's state)."""

    @abstractmethod
    def deliver(self, s: D, data: bytes, ts: int) -> None:
        """``data`` are the direction's next bytes, the last of them captured at ``ts``."""

    @abstractmethod
    def buffered(self, s: D) -> int:
        """How many bytes of an incomplete frame the direction holds (dropped at a gap)."""

    @abstractmethod
    def restart(self, s: D) -> None:
        """Bytes are missing before the next ones: alignment is lost there."""

    @abstractmethod
    def closed(self, s: D, ts: int) -> None:
        """The direction is over (:attr:`Direction.done`): nothing more is delivered."""

    @abstractmethod
    def report(self, event: CaptureEvent) -> None:
        """Something the reassembly found (a gap, a reorder overflow), in capture order."""

    # -- streams

    def stream(self, key: bytes) -> D | None:
        """The stream of ``key``, made (with its reverse) on first sight; ``None`` if filtered out."""
        stream = self.streams.get(key)
        if stream is not None or key in self.ignored:
            return stream
        src, dst = addresses(key)
        if self.ports is not None and src[1] not in self.ports and dst[1] not in self.ports:
            self.ignored.update((key, _reverse(key)))
            return None
        return self._connect(key, src, dst)

    def _connect(self, key: bytes, src: Address, dst: Address) -> D:
        conn = Connection()
        there = self.direction(key, src, dst, conn)
        back = self.direction(_reverse(key), dst, src, conn)
        there.reverse, back.reverse = back, there
        self.streams[key] = there
        self.streams[back.key] = back
        return there

    # -- segments

    def segment(  # noqa: PLR0917 - the fields of one segment, on the hot path
        self, s: D, ts: int, seq: int, ack: int, flags: int, payload: bytes
    ) -> None:
        """Take one segment of stream ``s``."""
        if flags & _ACK and s.reverse.heap:
            self._acked(s.reverse, ack, ts)
        if flags & _SYN and not flags & _RST:
            syn = self._syn(s, ts, seq, flags)
            if syn is None:
                return
            s = syn
            seq = (seq + 1) & _SEQ
        if s.done:
            return
        expected = s.next_seq
        if expected is None:  # captured mid-connection: the stream starts here
            s.next_seq = expected = seq
        n = len(payload)
        delta = (seq - expected) & _SEQ
        at = s.offset + delta if delta < _HALF else s.offset + delta - (1 << 32)  # seq's stream offset
        if flags & _RST:  # (its sequence number is not taken as a sign of bytes sent: RSTs answer anything)
            self._end_connection(s, ts)
            return
        s.high = max(s.high, at + n)  # the sender has sent up to here (a later segment or FIN tells)
        if n:
            if delta == 0:  # in order: the fast path
                s.next_seq = (expected + n) & _SEQ
                s.offset += n
                self.deliver(s, payload, ts)
                if s.heap:
                    self._drain(s)
            elif delta >= _HALF:  # begins before the next byte: a retransmission, maybe with new bytes
                old = (1 << 32) - delta
                if at < 0 and s.isn is None and not s.late_start:  # before the capture's first byte of it
                    s.late_start = True
                    self.report(
                        CaptureEvent(
                            EventKind.GAP,
                            f"{-at} bytes of {s} came after later ones at the capture's start (no SYN: "
                            "the stream was taken to begin with the first segment seen); they are not decoded",
                            ts,
                            s.src,
                            s.dst,
                            at,
                            0,
                        )
                    )
                if n > old:
                    s.next_seq = (expected + n - old) & _SEQ
                    s.offset += n - old
                    self.deliver(s, payload[old:], ts)
                    if s.heap:
                        self._drain(s)
            else:
                self._hold(s, at, payload, ts)
        if flags & _FIN and not s.done:
            s.fin_at = at + n
            if s.offset >= s.fin_at:
                self._close(s, ts)

    def _syn(self, s: D, ts: int, seq: int, flags: int) -> D | None:
        """A SYN: the stream's initial sequence number, or a new connection on the same 4-tuple;
        ``None`` for a retransmitted SYN."""
        if s.isn is not None and s.isn == seq:
            return None
        if s.isn is not None or s.next_seq is not None:  # the 4-tuple is used again: a new connection
            self._end_connection(s, ts)
            s = self._connect(s.key, s.src, s.dst)
        s.isn = seq
        conn = s.conn
        if conn.client is None:
            conn.client = s.dst if flags & _ACK else s.src
        return s

    def _hold(self, s: D, at: int, payload: bytes, ts: int) -> None:
        """Keep a segment that came before the bytes ahead of it; give up on the gap past the limit."""
        heapq.heappush(s.heap, (at, next(self._order), ts, payload))
        s.held += len(payload)
        if s.held > self.reorder_limit:
            self.report(
                CaptureEvent(
                    EventKind.REORDER_OVERFLOW,
                    f"more than {self.reorder_limit} bytes of {s} waited for a missing segment "
                    f"({s.held} held): the gap before them is given up on",
                    ts,
                    s.src,
                    s.dst,
                )
            )
            while s.held > self.reorder_limit and s.heap and not s.done:
                self._gap(s, ts)

    def _acked(self, s: D, ack: int, ts: int) -> None:
        """The receiver of ``s`` acknowledged up to ``ack``: a gap it covers will never be filled."""
        assert s.next_seq is not None  # segments are held only once the stream has started
        ahead = (ack - s.next_seq) & _SEQ
        if ahead == 0 or ahead >= _HALF:
            return
        acked = s.offset + ahead
        while s.heap and not s.done and acked > s.heap[0][0]:
            self._gap(s, ts)

    def _gap(self, s: D, ts: int) -> None:
        """Give up on the bytes missing before the first held segment; restart the decoder there."""
        self._missing(s, ts, s.heap[0][0], "decoding resumes after them")
        self.restart(s)
        self._drain(s)

    def _missing(self, s: D, ts: int, end: int, then: str) -> None:
        """Report the bytes from the stream's next one up to ``end`` as missing, and skip them."""
        assert s.next_seq is not None
        start = s.offset
        dropped = self.buffered(s)
        first = s.next_seq
        last = (first + end - start) & _SEQ
        note = f"; the {dropped} bytes of an incomplete frame before them are dropped" if dropped else ""
        self.report(
            CaptureEvent(
                EventKind.GAP,
                f"{end - start} bytes of {s} are missing from the capture (stream bytes {start}..{end}, "
                f"seq {first}..{last}); {then}{note}",
                ts,
                s.src,
                s.dst,
                start,
                end,
            )
        )
        s.next_seq = last
        s.offset = end

    def _drain(self, s: D) -> None:
        """Hand on the held segments that are now in order."""
        heap = s.heap
        while heap and heap[0][0] <= s.offset and not s.done:
            at, _, ts, payload = heapq.heappop(heap)
            s.held -= len(payload)
            skip = s.offset - at
            if skip >= len(payload):
                continue  # nothing new
            if skip:
                payload = payload[skip:]
            assert s.next_seq is not None
            s.next_seq = (s.next_seq + len(payload)) & _SEQ
            s.offset += len(payload)
            self.deliver(s, payload, ts)
            if s.fin_at is not None and s.offset >= s.fin_at:
                self._close(s, ts)

    def _end(self, s: D, ts: int) -> None:
        """The direction ends without its FIN reached (RST, end of capture, a new connection on its
        4-tuple): give up on its gaps, then close it."""
        while s.heap and not s.done:
            self._gap(s, ts)
        if s.done:
            return
        if s.high > s.offset:  # later segments (a FIN, an ACK's sequence number) show bytes never captured
            self._missing(s, ts, s.high, "nothing of this direction after them was captured")
            self.restart(s)  # the incomplete frame is dropped (the Gap says so)
        self._close(s, ts)

    def _close(self, s: D, ts: int) -> None:
        """The direction is over: what is held beyond it is dropped."""
        s.done = True
        s.heap.clear()
        s.held = 0
        self.closed(s, ts)

    def _end_connection(self, s: D, ts: int) -> None:
        self._end(s, ts)
        self._end(s.reverse, ts)

    def finish(self, ts: int) -> None:
        """The end of the capture: every direction ends."""
        for stream in self.streams.values():
            if not stream.done:
                self._end(stream, ts)


def _reverse(key: bytes) -> bytes:
    """The key of the other direction of the same connection."""
    size = 4 if len(key) == 12 else 16
    return key[size : 2 * size] + key[:size] + key[2 * size + 2 :] + key[2 * size : 2 * size + 2]
