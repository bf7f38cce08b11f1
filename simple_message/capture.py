"""Read simple_message traffic from pcap and pcapng captures: TCP reassembled, frames decoded.

:func:`read_capture` gives a capture's TCP segments; :func:`captured_messages` reassembles each
direction of each connection and decodes its byte stream with the project's
:class:`~.framing.FrameDecoder`, giving :class:`CapturedMessage` items and :class:`CaptureEvent`
items for what could not be decoded. ``simple-message decode CAPTURE`` prints them (see below).

**Formats.** The format is told by the file's first four bytes, not by its name: pcap
(``a1b2c3d4`` microseconds, ``a1b23c4d`` nanoseconds, either byte order; also the modified
``a1b2cd34`` format with its longer record headers) and pcapng (``0a0d0d0a``: any number of
sections, each in its own byte order, any number of interfaces, Enhanced, Simple and obsolete
Packet Blocks; other blocks are skipped). The file and section headers and the interface
descriptions are parsed with dpkt (``dpkt.pcap.FileHdr``, ``dpkt.pcapng.SectionHeaderBlock``,
``InterfaceDescriptionBlock``: the link type, ``if_tsresol``, ``if_tsoffset``); the packet records
themselves are cut with precompiled :mod:`struct` formats, as are the link, IP and TCP headers:
building dpkt objects for every packet costs several times as much (dpkt's pcapng reader and
Ethernet parser together read about 85,000 packets a second where this module reads and parses
about 700,000). Times are kept exact, in integer nanoseconds (``time_ns``; ``time`` is the same
as float seconds): a pcapng timestamp resolution finer than a nanosecond is rounded down to one.
A Simple Packet Block has no timestamp of its own and gets the previous packet's.

**Link types** (the LINKTYPE numbers files hold). Ethernet (1; 802.1Q/802.1ad VLAN tags are
skipped), Linux cooked capture SLL (113, ``tcpdump -i any``) and SLL2 (276), raw IP (101, 228
IPv4, 229 IPv6; also 12 and 14, the DLT_RAW values some writers put in files), BSD loopback/null
(0, 108: what ``tcpdump -i lo0`` gives on macOS and the BSDs; Linux's ``lo`` is Ethernet). Packets
of any other link type are skipped and counted (:attr:`CaptureReader.unsupported`; one
``UnsupportedLinkType`` event at the end). IPv4 and IPv6 (hop-by-hop, routing, destination options
and AH extension headers are skipped), TCP only; IP fragments are not reassembled (what they carry
then shows as a gap). Ethernet padding and trailers are cut off by the IP length.

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

**Memory** is bounded: the file is read in 1 MiB chunks (a packet record may be at most 16 MiB);
each direction holds at most one incomplete frame (the frame decoder's bound, ``4 + max_length``)
and at most ``reorder_limit`` bytes (default 4 MiB) of out-of-order segments: one more segment
reports a ``ReorderOverflow`` event and gives up on the gap before the held segments. Per
connection, a small fixed state is kept until the end (ended connections included, so that late
retransmissions are recognised).

**Errors.** A file that is not a capture, is truncated (a header, record or block cut short) or is
malformed (an impossible length, a packet on an interface no block describes, a bad header block)
raises :class:`CaptureError`, naming the file, what is wrong and at which byte. Everything
:func:`captured_messages` yielded before stays valid.

**What ``simple-message decode CAPTURE`` prints.** One JSON object per message on stdout, as for hex
input (``msg_type``, ``name``, ``comm_type``, ``reply_code``, ``body``, ``names`` when a field has
a symbolic name), plus ``"time"`` (seconds since the epoch as the capture gives them, a float),
``"src"`` and ``"dst"`` (``"address:port"``, an IPv6 address in brackets). On stderr, one JSON
object per problem: ``{"error": TEXT, "type": KIND, ...}``, KIND an :class:`EventKind` value or
``MalformedMessage`` (a frame whose body fits no layout, with its ``"hex"``), with the same
``time``, ``src`` and ``dst`` where they apply and ``start`` and ``end`` (stream offsets) for a
``Gap`` or a ``TruncatedFrame``. ``--port`` keeps the connections with that port at either end,
``--type`` the messages of these types; the wire options are the command's (``--byte-order auto``
detects each direction's order; the default is little-endian, as for hex input). A file that
begins like a capture but cannot be read as one is a single ``CaptureError`` line; the command
exits 1 when anything was reported.
"""

from __future__ import annotations

import heapq
import itertools
import os
import socket
import struct
from collections import Counter
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from enum import StrEnum
from types import TracebackType
from typing import IO, Final, Literal

import dpkt  # type: ignore[import-untyped, unused-ignore]
import dpkt.pcap  # type: ignore[import-untyped, unused-ignore]
import dpkt.pcapng  # type: ignore[import-untyped, unused-ignore]

from .errors import FrameError, MalformedMessage, SimpleMessageError
from .framing import DEFAULT_MAX_LENGTH, FrameDecoder, decode_or_error
from .messages import Message, decode
from .wire import DEFAULT_FORMAT, ByteOrder, WireFormat

__all__ = [
    "Address",
    "CaptureError",
    "CaptureEvent",
    "CaptureReader",
    "CapturedMessage",
    "DEFAULT_REORDER_LIMIT",
    "EventKind",
    "LINK_TYPES",
    "Segment",
    "capture_format",
    "captured_messages",
    "format_address",
    "read_capture",
]

#: (IP address as text, port)
Address = tuple[str, int]
#: A capture file: a path, or a binary file object open for reading.
Source = str | os.PathLike[str] | IO[bytes]

#: Default bound of the out-of-order segments held per direction (bytes).
DEFAULT_REORDER_LIMIT = 4 * 1024 * 1024

# Link types by their LINKTYPE_ numbers (tcpdump.org/linktypes.html), what files hold: not dpkt's
# DLT_RAW and DLT_LOOP, which are the platform's DLT_ values (12 and 108, or 14 and 12 on OpenBSD).
_LINK_NULL = 0
_LINK_ETHERNET = 1
_LINK_RAW = 101
_LINK_LOOP = 108
_LINK_SLL = 113
_LINK_IPV4 = 228
_LINK_IPV6 = 229
_LINK_SLL2 = 276

#: The link types read, by number: what they are.
LINK_TYPES: Final[dict[int, str]] = {
    _LINK_NULL: "BSD loopback (NULL)",
    _LINK_ETHERNET: "Ethernet",
    12: "raw IP (the DLT_RAW of most systems)",
    14: "raw IP (OpenBSD's DLT_RAW)",
    _LINK_RAW: "raw IP",
    _LINK_LOOP: "OpenBSD loopback (LOOP)",
    _LINK_SLL: "Linux cooked capture (SLL)",
    _LINK_IPV4: "raw IPv4",
    _LINK_IPV6: "raw IPv6",
    _LINK_SLL2: "Linux cooked capture v2 (SLL2)",
}

_CHUNK = 1 << 20  # the file is read this much at a time
_MAX_RECORD = 16 << 20  # a longer packet record or block is taken for corruption
_SEQ = 0xFFFFFFFF
_HALF = 1 << 31

_FIN, _SYN, _RST, _ACK = dpkt.tcp.TH_FIN, dpkt.tcp.TH_SYN, dpkt.tcp.TH_RST, dpkt.tcp.TH_ACK
_SYN_RST_FIN = _SYN | _RST | _FIN

_EN10MB = _LINK_ETHERNET
_SLL = _LINK_SLL
_SLL2 = _LINK_SLL2
_RAW = frozenset({12, 14, _LINK_RAW, _LINK_IPV4, _LINK_IPV6})
_NULL = frozenset({_LINK_NULL, _LINK_LOOP})
_ETH_IP = frozenset({dpkt.ethernet.ETH_TYPE_IP, dpkt.ethernet.ETH_TYPE_IP6})
_ETH_VLAN = frozenset({dpkt.ethernet.ETH_TYPE_8021Q, dpkt.ethernet.ETH_TYPE_8021AD, 0x9100})
_IP6_SKIP = frozenset({0, 43, 60})  # hop-by-hop, routing, destination options: (len + 1) * 8 bytes
_IP6_AH = 51  # authentication header: (len + 2) * 4 bytes
_TCP_PROTO = dpkt.ip.IP_PROTO_TCP

# IPv4: version+IHL, total length, flags+fragment offset, protocol
_IP4 = struct.Struct("!BxHxxHxB")
# TCP from its sequence number: seq, ack, data offset, flags
_TCP = struct.Struct("!IIBB")
# Ethernet and IPv4: EtherType, version+IHL, total length, flags+fragment offset, protocol, addresses
_ETH_IP4 = struct.Struct("!12xHBxHxxHxBxx8s")
# TCP: ports, seq, ack, data offset, flags
_TCP4 = struct.Struct("!4sIIBB")
_PORTS = struct.Struct("!HH")
_LE_INT = struct.Struct("<i").unpack_from
_BE_INT = struct.Struct(">i").unpack_from

_PCAP_MAGICS: Final[dict[bytes, tuple[bool, bool, bool]]] = {
    # first four bytes: (little-endian, nanoseconds, modified format with 24-byte records)
    b"\xa1\xb2\xc3\xd4": (False, False, False),
    b"\xd4\xc3\xb2\xa1": (True, False, False),
    b"\xa1\xb2\x3c\x4d": (False, True, False),
    b"\x4d\x3c\xb2\xa1": (True, True, False),
    b"\xa1\xb2\xcd\x34": (False, False, True),
    b"\x34\xcd\xb2\xa1": (True, False, True),
}
_PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"
_PCAPNG_BOM = {b"\x1a\x2b\x3c\x4d": False, b"\x4d\x3c\x2b\x1a": True}  # -> little-endian

_BT_SHB = dpkt.pcapng.PCAPNG_BT_SHB
_BT_IDB = dpkt.pcapng.PCAPNG_BT_IDB
_BT_EPB = dpkt.pcapng.PCAPNG_BT_EPB
_BT_SPB = dpkt.pcapng.PCAPNG_BT_SPB
_BT_PB = dpkt.pcapng.PCAPNG_BT_PB


def capture_format(head: bytes) -> Literal["pcap", "pcapng"] | None:
    """``"pcap"`` or ``"pcapng"`` if ``head`` (a file's first bytes, at least four) begins like
    one, else ``None``."""
    magic = bytes(head[:4])
    if magic in _PCAP_MAGICS:
        return "pcap"
    if magic == _PCAPNG_MAGIC:
        return "pcapng"
    return None


def _seconds(time_ns: int) -> float:
    """Nanoseconds as float seconds, the nearest float to the decimal value (``1431715297.100403``,
    where ``time_ns / 1e9`` rounds twice and gives ``1431715297.1004028``)."""
    seconds, fraction = divmod(time_ns, 1_000_000_000)
    return seconds + fraction / 1e9


def format_address(address: Address) -> str:
    """``"address:port"``, an IPv6 address in brackets (``"[::1]:11000"``)."""
    host, port = address
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class CaptureError(SimpleMessageError):
    """A file that is not a pcap/pcapng capture, or is truncated or malformed.

    The message names the file and what is wrong; :attr:`offset` is the byte where, when known.
    """

    def __init__(self, name: str, problem: str, offset: int | None = None) -> None:
        where = f" (at byte {offset})" if offset is not None else ""
        super().__init__(f"{name}: {problem}{where}")
        self.name = name
        self.problem = problem
        self.offset = offset


@dataclass(slots=True)
class Segment:
    """One TCP segment of a capture (:func:`read_capture`); read-only by convention."""

    #: capture time, nanoseconds since the epoch (as the capture gives it)
    time_ns: int
    src: Address
    dst: Address
    #: TCP flags (FIN 0x01, SYN 0x02, RST 0x04, PSH 0x08, ACK 0x10, URG 0x20, ...)
    flags: int
    seq: int
    ack: int
    #: the TCP payload as captured (shorter than sent if the capture's snap length cut it)
    payload: bytes

    @property
    def time(self) -> float:
        """Capture time in seconds since the epoch."""
        return _seconds(self.time_ns)


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
        return _seconds(self.time_ns)


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
    #: packets of a link type this module does not read were skipped
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
        return None if self.time_ns is None else _seconds(self.time_ns)


# -- reading the file ------------------------------------------------------------------------------


class CaptureReader:
    """The TCP segments of a pcap or pcapng capture, in capture order.

    ``source`` is a path (opened here, closed by :meth:`close` or at the end of the ``with``) or a
    binary file object (left open). The format is detected at once: :class:`CaptureError` if the
    file does not begin like a capture. Iterating gives :class:`Segment` objects (once); a
    truncated or malformed file raises :class:`CaptureError` when the bad part is reached.
    """

    def __init__(self, source: Source) -> None:
        if isinstance(source, str | os.PathLike):
            self.name = os.fspath(source)
            self._file: IO[bytes] = open(source, "rb")  # noqa: SIM115 - closed by close()
            self._owned = True
        else:
            self.name = str(getattr(source, "name", "<capture>"))
            self._file = source
            self._owned = False
        try:
            head = self._file.read(4)
            fmt = capture_format(head)
            if fmt is None:
                shown = head.hex() if head else "nothing"
                raise CaptureError(self.name, f"not a pcap or pcapng capture (it begins with {shown})")
        except BaseException:
            self.close()
            raise
        #: ``"pcap"`` or ``"pcapng"``
        self.format: Literal["pcap", "pcapng"] = fmt
        self._head = head
        #: packets skipped because of their link type, by link type
        self.unsupported: Counter[int] = Counter()
        #: packets read so far
        self.packets = 0

    def close(self) -> None:
        if self._owned:
            self._file.close()

    def __enter__(self) -> CaptureReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __iter__(self) -> Iterator[Segment]:
        addresses: dict[bytes, tuple[Address, Address]] = {}
        for ts, key, seq, ack, flags, payload in self._tcp():
            pair = addresses.get(key)
            if pair is None:
                pair = addresses[key] = _addresses(key)
            yield Segment(ts, pair[0], pair[1], flags, seq, ack, payload)

    # The two generators below are the hot path: a packet costs a few struct unpacks and slices.

    def _tcp(self) -> Iterator[tuple[int, bytes, int, int, int, bytes]]:
        """The TCP segments as tuples ``(time_ns, key, seq, ack, flags, payload)``, where ``key``
        is the source and destination addresses then ports as on the wire (12 bytes for IPv4, 36
        for IPv6; :func:`_addresses` makes them readable). The fast path of :meth:`__iter__`."""
        unsupported = self.unsupported
        ip4 = _IP4.unpack_from
        tcp = _TCP.unpack_from
        eth_ip = _ETH_IP
        vlan = _ETH_VLAN
        eth4 = _ETH_IP4.unpack_from
        tcp4 = _TCP4.unpack_from
        count = 0
        records = self._pcap_records() if self.format == "pcap" else self._pcapng_records()
        try:
            for ts, link, buf, start, stop in records:
                count += 1
                if link == _EN10MB and stop - start >= 54:
                    # Ethernet, IPv4 without options, TCP: the usual packet, in two unpacks
                    kind, vihl, total, frag, proto, addresses = eth4(buf, start)
                    if kind == 0x0800 and vihl == 0x45:
                        if proto != _TCP_PROTO or frag & 0x3FFF:
                            continue
                        end = start + 14 + total
                        if total == 0 or end > stop:
                            end = stop
                        ports, seq, ack, data_offset, flags = tcp4(buf, start + 34)
                        if data_offset < 0x50 or start + 54 > end:
                            continue
                        yield ts, addresses + ports, seq, ack, flags, buf[start + 34 + (data_offset >> 4) * 4 : end]
                        continue
                if link == _EN10MB:
                    off = start + 14
                    if off > stop:
                        continue
                    kind = (buf[off - 2] << 8) | buf[off - 1]
                    while kind in vlan and off + 4 <= stop:
                        kind = (buf[off + 2] << 8) | buf[off + 3]
                        off += 4
                    if kind not in eth_ip:
                        continue
                elif link == _SLL:
                    off = start + 16
                    if off > stop or ((buf[off - 2] << 8) | buf[off - 1]) not in eth_ip:
                        continue
                elif link == _SLL2:
                    off = start + 20
                    if off > stop or ((buf[start] << 8) | buf[start + 1]) not in eth_ip:
                        continue
                elif link in _RAW:
                    off = start
                elif link in _NULL:
                    off = start + 4  # the address family, in either byte order: the IP version tells
                else:
                    unsupported[link] += 1
                    continue
                if off >= stop:
                    continue
                version = buf[off] >> 4
                if version == 4:
                    if off + 20 > stop:
                        continue
                    vihl, total, frag, proto = ip4(buf, off)
                    if proto != _TCP_PROTO or frag & 0x3FFF or vihl & 15 < 5:
                        continue  # not TCP, or a fragment
                    t = off + (vihl & 15) * 4
                    end = off + total
                    if total == 0 or end > stop:  # 0: a TSO capture; beyond: cut by the snap length
                        end = stop
                    if t + 20 > end:
                        continue
                    key = buf[off + 12 : off + 20] + buf[t : t + 4]
                elif version == 6:
                    if off + 40 > stop:
                        continue
                    total = (buf[off + 4] << 8) | buf[off + 5]
                    nxt = buf[off + 6]
                    end = off + 40 + total
                    if total == 0 or end > stop:  # 0: a jumbogram; beyond: cut by the snap length
                        end = stop
                    t = off + 40
                    while t + 8 <= end:
                        if nxt in _IP6_SKIP:
                            nxt, t = buf[t], t + (buf[t + 1] + 1) * 8
                        elif nxt == _IP6_AH:
                            nxt, t = buf[t], t + (buf[t + 1] + 2) * 4
                        else:
                            break
                    if nxt != _TCP_PROTO or t + 20 > end:
                        continue  # not TCP (a fragment header included)
                    key = buf[off + 8 : off + 40] + buf[t : t + 4]
                else:
                    continue
                seq, ack, data_offset, flags = tcp(buf, t + 4)
                if data_offset < 0x50:
                    continue
                yield ts, key, seq, ack, flags, buf[t + (data_offset >> 4) * 4 : end]
        finally:
            self.packets += count

    def _error(self, problem: str, offset: int | None = None) -> CaptureError:
        return CaptureError(self.name, problem, offset)

    def _more(self, rest: bytes, need: int) -> bytes:
        """``rest`` and what follows it in the file, at least ``need`` bytes (fewer at its end)."""
        parts = [rest]
        have = len(rest)
        while have < need:
            data = self._file.read(max(_CHUNK, need - have))
            if not data:
                break
            parts.append(data)
            have += len(data)
        return b"".join(parts) if len(parts) > 1 else rest

    def _pcap_records(self) -> Iterator[tuple[int, int, bytes, int, int]]:
        """``(time_ns, link_type, buffer, start, stop)`` of each packet record of a pcap file."""
        buf = self._more(self._head, 24)
        if len(buf) < 24:
            raise self._error(f"truncated: the pcap file header is 24 bytes, the file has {len(buf)}")
        little, nano, modified = _PCAP_MAGICS[buf[:4]]
        try:
            header = (dpkt.pcap.LEFileHdr if little else dpkt.pcap.FileHdr)(buf[:24])
        except (dpkt.UnpackError, struct.error) as exc:  # pragma: no cover - 24 bytes always unpack
            raise self._error(f"malformed pcap file header: {exc}", 0) from None
        if header.v_major != dpkt.pcap.PCAP_VERSION_MAJOR:
            raise self._error(f"unsupported pcap version {header.v_major}.{header.v_minor}", 4)
        link = header.linktype & 0xFFFF  # the upper bits may say whether frames end with their FCS
        limit = min(max(header.snaplen, 262_144), _MAX_RECORD)
        size = 24 if modified else 16
        record = struct.Struct("<IIII" if little else ">IIII").unpack_from
        scale = 1 if nano else 1000
        base = 0  # file offset of buf[0]
        pos = 24
        end = len(buf)
        while True:
            if pos + size > end:
                base += pos
                buf = self._more(buf[pos:], size)
                pos = 0
                end = len(buf)
                if end == 0:
                    return
                if end < size:
                    raise self._error(f"truncated: the last packet record's header has {end} of its {size} bytes", base)
            sec, frac, caplen, _ = record(buf, pos)
            start = pos + size
            stop = start + caplen
            if stop > end:
                if caplen > limit:
                    raise self._error(
                        f"malformed: a packet record of {caplen} bytes, more than the snapshot length "
                        f"{header.snaplen} allows (not a pcap file, or a corrupt one)",
                        base + pos,
                    )
                base += pos
                buf = self._more(buf[pos:], size + caplen)
                pos = 0
                end = len(buf)
                start = size
                stop = start + caplen
                if stop > end:
                    raise self._error(f"truncated: the last packet record has {end - size} of its {caplen} bytes", base)
            yield sec * 1_000_000_000 + frac * scale, link, buf, start, stop
            pos = stop

    def _pcapng_records(self) -> Iterator[tuple[int, int, bytes, int, int]]:
        """``(time_ns, link_type, buffer, start, stop)`` of each packet block of a pcapng file."""
        buf = self._head
        base = pos = end = 0
        little = True
        block = epb = pb = spb = trailer = struct.Struct("<II").unpack_from  # set by the first SHB
        interfaces: list[tuple[int, int, int, int, int]] = []  # link, ns multiplier, divisor, offset, snaplen
        last_ts = 0
        while True:
            if pos + 12 > end:
                base += pos
                buf = self._more(buf[pos:], 12)
                pos = 0
                end = len(buf)
                if end == 0:
                    return
                if end < 12:
                    raise self._error(f"truncated: the last block's header has {end} of its 12 bytes", base)
            kind, length = block(buf, pos)
            if kind == _BT_SHB:  # the same bytes in either order: its byte-order magic tells
                bom = bytes(buf[pos + 8 : pos + 12])
                if bom not in _PCAPNG_BOM:
                    raise self._error(f"malformed: a section header with byte-order magic {bom.hex()}", base + pos)
                little = _PCAPNG_BOM[bom]
                order = "<" if little else ">"
                block = struct.Struct(order + "II").unpack_from
                epb = struct.Struct(order + "8xIIIII").unpack_from
                pb = struct.Struct(order + "8xHxxIIII").unpack_from
                spb = struct.Struct(order + "8xI").unpack_from
                trailer = struct.Struct(order + "I").unpack_from
                kind, length = block(buf, pos)
            if length < 12 or length % 4 or length > _MAX_RECORD:
                raise self._error(f"malformed: a block (type {kind:#x}) of impossible length {length}", base + pos)
            if pos + length > end:
                base += pos
                buf = self._more(buf[pos:], length)
                pos = 0
                end = len(buf)
                if length > end:
                    raise self._error(
                        f"truncated: the last block (type {kind:#x}) has {end} of its {length} bytes", base
                    )
            if trailer(buf, pos + length - 4)[0] != length:
                raise self._error(f"malformed: a block (type {kind:#x}) whose two length fields disagree", base + pos)
            if kind == _BT_EPB:
                if length < 32:
                    raise self._error(f"malformed: an enhanced packet block of {length} bytes", base + pos)
                iface, high, low, caplen, _ = epb(buf, pos)
                if caplen > length - 32:
                    raise self._error(f"malformed: a packet of {caplen} bytes in a block of {length}", base + pos)
                try:
                    link, scale, divisor, offset, _ = interfaces[iface]
                except IndexError:
                    raise self._error(
                        f"malformed: a packet on interface {iface}, which no interface block describes", base + pos
                    ) from None
                raw = (high << 32) | low
                last_ts = (raw * scale if divisor == 1 else raw * scale // divisor) + offset
                yield last_ts, link, buf, pos + 28, pos + 28 + caplen
            elif kind == _BT_SHB:
                interfaces = self._section(buf[pos : pos + length], little, base + pos)
            elif kind == _BT_IDB:
                interfaces.append(self._interface(buf[pos : pos + length], little, base + pos))
            elif kind == _BT_SPB:
                if not interfaces:
                    raise self._error("malformed: a simple packet block before any interface block", base + pos)
                (wire_length,) = spb(buf, pos)
                link, _, _, _, snaplen = interfaces[0]
                caplen = min(wire_length, snaplen or wire_length, length - 16)
                yield last_ts, link, buf, pos + 12, pos + 12 + caplen
            elif kind == _BT_PB:
                if length < 32:
                    raise self._error(f"malformed: a packet block of {length} bytes", base + pos)
                iface, high, low, caplen, _ = pb(buf, pos)
                if caplen > length - 32 or iface >= len(interfaces):
                    raise self._error("malformed: a packet block that does not fit, or names no interface", base + pos)
                link, scale, divisor, offset, _ = interfaces[iface]
                raw = (high << 32) | low
                last_ts = (raw * scale if divisor == 1 else raw * scale // divisor) + offset
                yield last_ts, link, buf, pos + 28, pos + 28 + caplen
            pos += length

    def _section(self, data: bytes, little: bool, offset: int) -> list[tuple[int, int, int, int, int]]:
        """Check a section header block (with dpkt); a new section has no interfaces yet."""
        try:
            shb = (dpkt.pcapng.SectionHeaderBlockLE if little else dpkt.pcapng.SectionHeaderBlock)(data)
        except (dpkt.UnpackError, ValueError, struct.error) as exc:
            raise self._error(f"malformed section header block: {exc or type(exc).__name__}", offset) from None
        if shb.v_major != dpkt.pcapng.PCAPNG_VERSION_MAJOR:
            raise self._error(f"unsupported pcapng version {shb.v_major}.{shb.v_minor}", offset)
        return []

    def _interface(self, data: bytes, little: bool, offset: int) -> tuple[int, int, int, int, int]:
        """An interface description block (read with dpkt): link type, how its timestamps become
        nanoseconds (multiplier, divisor, offset) and snap length."""
        try:
            idb = (dpkt.pcapng.InterfaceDescriptionBlockLE if little else dpkt.pcapng.InterfaceDescriptionBlock)(data)
        except (dpkt.UnpackError, ValueError, struct.error) as exc:
            raise self._error(f"malformed interface description block: {exc or type(exc).__name__}", offset) from None
        resolution = 6
        seconds = 0
        for option in idb.opts:
            if option.code == dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL and len(option.data) >= 1:
                resolution = option.data[0]
            elif option.code == dpkt.pcapng.PCAPNG_OPT_IF_TSOFFSET and len(option.data) >= 8:
                (seconds,) = struct.unpack("<q" if little else ">q", option.data[:8])
        if resolution & 0x80:  # a negative power of 2
            scale, divisor = 1_000_000_000, 1 << (resolution & 0x7F)
        elif resolution <= 9:  # a negative power of 10
            scale, divisor = 10 ** (9 - resolution), 1
        else:
            scale, divisor = 1, 10 ** (resolution - 9)
        return int(idb.linktype), scale, divisor, seconds * 1_000_000_000, int(idb.snaplen)


def _addresses(key: bytes) -> tuple[Address, Address]:
    """(source, destination) of a :meth:`CaptureReader._tcp` key."""
    family, size = (socket.AF_INET, 4) if len(key) == 12 else (socket.AF_INET6, 16)
    sport, dport = _PORTS.unpack_from(key, 2 * size)
    return (
        (socket.inet_ntop(family, key[:size]), sport),
        (socket.inet_ntop(family, key[size : 2 * size]), dport),
    )


def _reverse(key: bytes) -> bytes:
    """The key of the other direction of the same connection."""
    size = 4 if len(key) == 12 else 16
    return key[size : 2 * size] + key[:size] + key[2 * size + 2 :] + key[2 * size : 2 * size + 2]


def read_capture(source: Source) -> Iterator[Segment]:
    """Every TCP segment of a pcap or pcapng capture, in capture order (see the module doc).

    Raises :class:`CaptureError` if the file is not a capture (at the first item), or when a
    truncated or malformed part is reached.
    """
    with CaptureReader(source) as reader:
        yield from reader


# -- reassembly and decoding -------------------------------------------------------------------------


class _Connection:
    __slots__ = ("client",)

    def __init__(self) -> None:
        self.client: Address | None = None


class _Stream:
    """One direction of one connection: its sequence state, held segments and frame decoder."""

    __slots__ = (
        "conn",
        "decoder",
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
        "type_of",
        "wire",
    )

    def __init__(self, key: bytes, src: Address, dst: Address, conn: _Connection, decoder: FrameDecoder) -> None:
        self.key = key
        self.src = src
        self.dst = dst
        self.conn = conn
        self.decoder = decoder
        self.wire: WireFormat | None = None
        self.type_of: Callable[[bytes, int], tuple[int, ...]] = _LE_INT  # the msg_type of a frame
        self.isn: int | None = None
        self.next_seq: int | None = None  # the sequence number of the next byte expected
        self.offset = 0  # its offset in the stream
        self.heap: list[tuple[int, int, int, bytes]] = []  # (offset, order, time_ns, payload)
        self.held = 0
        self.high = 0  # the end of the furthest bytes the capture shows were sent (a stream offset)
        self.fin_at: int | None = None
        self.done = False
        self.reverse: _Stream = self  # the other direction, once made
        #: captured without its SYN, it began with a segment that earlier bytes came after (reported once)
        self.late_start = False


class _Tracker:
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
        self.wire = wire
        self.auto = auto
        self.ports = frozenset(ports) if ports is not None else None
        self.types = frozenset(types) if types is not None else None
        self.reorder_limit = reorder_limit
        self.max_length = max_length
        self.streams: dict[bytes, _Stream] = {}
        self.ignored: set[bytes] = set()  # the connections the ports filter drops, both directions
        self.out: list[CapturedMessage | CaptureEvent] = []
        self._order = itertools.count()
        self._spent = FrameDecoder(None)  # the decoder of every ended stream: never fed

    # -- streams

    def stream(self, key: bytes) -> _Stream | None:
        """The stream of ``key``, made (with its reverse) on first sight; ``None`` if filtered out."""
        stream = self.streams.get(key)
        if stream is not None or key in self.ignored:
            return stream
        src, dst = _addresses(key)
        if self.ports is not None and src[1] not in self.ports and dst[1] not in self.ports:
            self.ignored.update((key, _reverse(key)))
            return None
        return self._connect(key, src, dst)

    def _connect(self, key: bytes, src: Address, dst: Address) -> _Stream:
        conn = _Connection()
        there = _Stream(key, src, dst, conn, self._decoder(None))
        back = _Stream(_reverse(key), dst, src, conn, self._decoder(None))
        there.reverse, back.reverse = back, there
        self.streams[key] = there
        self.streams[back.key] = back
        return there

    def _decoder(self, previous: FrameDecoder | None) -> FrameDecoder:
        if previous is not None and previous.byte_order is not None:
            order: ByteOrder | None = previous.byte_order  # a restart keeps the detected order
        else:
            order = None if self.auto else self.wire.byte_order
        return FrameDecoder(order, max_length=self.max_length)

    # -- segments

    def segment(  # noqa: PLR0917 - the fields of one segment, on the hot path
        self, s: _Stream, ts: int, seq: int, ack: int, flags: int, payload: bytes
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
                self._deliver(s, payload, ts)
                if s.heap:
                    self._drain(s)
            elif delta >= _HALF:  # begins before the next byte: a retransmission, maybe with new bytes
                old = (1 << 32) - delta
                if at < 0 and s.isn is None and not s.late_start:  # before the capture's first byte of it
                    s.late_start = True
                    self.out.append(
                        CaptureEvent(
                            EventKind.GAP,
                            f"{-at} bytes of {_arrow(s)} came after later ones at the capture's start (no SYN: "
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
                    self._deliver(s, payload[old:], ts)
                    if s.heap:
                        self._drain(s)
            else:
                self._hold(s, at, payload, ts)
        if flags & _FIN and not s.done:
            s.fin_at = at + n
            if s.offset >= s.fin_at:
                self._close(s, ts)

    def _syn(self, s: _Stream, ts: int, seq: int, flags: int) -> _Stream | None:
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

    def _hold(self, s: _Stream, at: int, payload: bytes, ts: int) -> None:
        """Keep a segment that came before the bytes ahead of it; give up on the gap past the limit."""
        heapq.heappush(s.heap, (at, next(self._order), ts, payload))
        s.held += len(payload)
        if s.held > self.reorder_limit:
            self.out.append(
                CaptureEvent(
                    EventKind.REORDER_OVERFLOW,
                    f"more than {self.reorder_limit} bytes of {_arrow(s)} waited for a missing segment "
                    f"({s.held} held): the gap before them is given up on",
                    ts,
                    s.src,
                    s.dst,
                )
            )
            while s.held > self.reorder_limit and s.heap and not s.done:
                self._gap(s, ts)

    def _acked(self, s: _Stream, ack: int, ts: int) -> None:
        """The receiver of ``s`` acknowledged up to ``ack``: a gap it covers will never be filled."""
        assert s.next_seq is not None  # segments are held only once the stream has started
        ahead = (ack - s.next_seq) & _SEQ
        if ahead == 0 or ahead >= _HALF:
            return
        acked = s.offset + ahead
        while s.heap and not s.done and acked > s.heap[0][0]:
            self._gap(s, ts)

    def _gap(self, s: _Stream, ts: int) -> None:
        """Give up on the bytes missing before the first held segment; restart the decoder there."""
        self._missing(s, ts, s.heap[0][0], "decoding resumes after them")
        s.decoder = self._decoder(s.decoder)
        self._drain(s)

    def _missing(self, s: _Stream, ts: int, end: int, then: str) -> None:
        """Report the bytes from the stream's next one up to ``end`` as missing, and skip them."""
        assert s.next_seq is not None
        start = s.offset
        dropped = s.decoder.buffered if not s.decoder.failed else 0
        first = s.next_seq
        last = (first + end - start) & _SEQ
        note = f"; the {dropped} bytes of an incomplete frame before them are dropped" if dropped else ""
        self.out.append(
            CaptureEvent(
                EventKind.GAP,
                f"{end - start} bytes of {_arrow(s)} are missing from the capture (stream bytes {start}..{end}, "
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

    def _drain(self, s: _Stream) -> None:
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
            self._deliver(s, payload, ts)
            if s.fin_at is not None and s.offset >= s.fin_at:
                self._close(s, ts)

    def _deliver(self, s: _Stream, data: bytes, ts: int) -> None:
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
                    self._frame_error(s, decoder, ts)
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
            self._frame_error(s, decoder, ts)

    def _frame_error(self, s: _Stream, decoder: FrameDecoder, ts: int) -> None:
        self.out.append(
            CaptureEvent(
                EventKind.FRAME_ERROR,
                f"{decoder.error}: {_arrow(s)} cannot be realigned, nothing more of it is decoded "
                "(up to a gap in the capture, where decoding restarts)",
                ts,
                s.src,
                s.dst,
            )
        )

    def _end(self, s: _Stream, ts: int) -> None:
        """The direction ends without its FIN reached (RST, end of capture, a new connection on its
        4-tuple): give up on its gaps, then close it."""
        while s.heap and not s.done:
            self._gap(s, ts)
        if s.done:
            return
        if s.high > s.offset:  # later segments (a FIN, an ACK's sequence number) show bytes never captured
            self._missing(s, ts, s.high, "nothing of this direction after them was captured")
            s.decoder = self._decoder(s.decoder)  # the incomplete frame is dropped (the Gap says so)
        self._close(s, ts)

    def _close(self, s: _Stream, ts: int) -> None:
        """The direction is over: report an incomplete frame; what is held beyond it is dropped."""
        s.done = True
        s.heap.clear()
        s.held = 0
        decoder = s.decoder
        if decoder.buffered and not decoder.failed:
            self.out.append(
                CaptureEvent(
                    EventKind.TRUNCATED_FRAME,
                    f"{decoder.buffered} bytes at the end of {_arrow(s)} do not make a whole frame",
                    ts,
                    s.src,
                    s.dst,
                    s.offset - decoder.buffered,
                    s.offset,
                )
            )
        s.decoder = self._spent  # the incomplete frame is not kept

    def _end_connection(self, s: _Stream, ts: int) -> None:
        self._end(s, ts)
        self._end(s.reverse, ts)

    def finish(self, ts: int) -> None:
        """The end of the capture: every direction ends."""
        for stream in self.streams.values():
            if not stream.done:
                self._end(stream, ts)


def _arrow(s: _Stream) -> str:
    return f"{format_address(s.src)} -> {format_address(s.dst)}"


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
    what could not be (gaps, truncated frames, framing errors): see the module doc.

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
        tracker = _Tracker(
            wire=wire, auto=auto, ports=ports, types=types, reorder_limit=reorder_limit, max_length=max_length
        )
        out = tracker.out
        streams = tracker.streams
        new_stream = tracker.stream
        segment = tracker.segment
        deliver = tracker._deliver
        frame_error = tracker._frame_error
        wanted = tracker.types
        ts = 0
        for ts, key, seq, ack, flags, payload in reader._tcp():
            s = streams.get(key)
            if s is None:
                s = new_stream(key)
                if s is None:
                    continue
            # The fast path: the next bytes of a started stream, nothing held either way (so an
            # ACK has no gap to close), no SYN/RST/FIN, a decoder that knows its byte order.
            if seq != s.next_seq or flags & _SYN_RST_FIN or s.heap or s.reverse.heap or s.done:
                segment(s, ts, seq, ack, flags, payload)
            elif payload:
                s.next_seq = (seq + len(payload)) & _SEQ
                s.offset += len(payload)
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
