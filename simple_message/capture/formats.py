"""pcap and pcapng files read into TCP segments: the capture package's bottom layer, which knows
nothing of simple_message (it imports dpkt and the standard library only).

:class:`SegmentReader` gives a capture's TCP segments in capture order, as :class:`TcpSegment`
objects or, on the fast path the reassembly takes, as plain tuples
(:meth:`SegmentReader.segment_tuples`). What the segments carry is the business of the layers above
(:mod:`.reassembly`, :mod:`.messages`).

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
of any other link type are skipped and counted (:attr:`SegmentReader.unsupported`; the decoding
reports them as one ``UnsupportedLinkType`` event at the end). IPv4 and IPv6 (hop-by-hop, routing,
destination options and AH extension headers are skipped), TCP only; IP fragments are not
reassembled (what they carry then shows as a gap). Ethernet padding and trailers are cut off by
the IP length.

**Memory.** The file is read in 1 MiB chunks (a packet record may be at most 16 MiB).

**Errors.** A file that is not a capture, is truncated (a header, record or block cut short) or is
malformed (an impossible length, a packet on an interface no block describes, a bad header block)
raises :attr:`SegmentReader.error` (:class:`FormatError` here; the package's
:class:`~.messages.CaptureReader` raises its :class:`~.messages.CaptureError`, a
``SimpleMessageError``), naming the file, what is wrong and at which byte. The segments given
before stay valid.
"""

from __future__ import annotations

import os
import socket
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import IO, ClassVar, Final, Literal, Self

import dpkt  # type: ignore[import-untyped, unused-ignore]
import dpkt.pcap  # type: ignore[import-untyped, unused-ignore]
import dpkt.pcapng  # type: ignore[import-untyped, unused-ignore]

__all__ = [
    "LINK_TYPES",
    "Address",
    "FormatError",
    "SegmentReader",
    "Source",
    "TcpSegment",
    "addresses",
    "capture_format",
    "format_address",
    "to_seconds",
]

#: (IP address as text, port)
Address = tuple[str, int]
#: A capture file: a path, or a binary file object open for reading.
Source = str | os.PathLike[str] | IO[bytes]

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


def to_seconds(time_ns: int) -> float:
    """Nanoseconds as float seconds, the nearest float to the decimal value (``1431715297.100403``,
    where ``time_ns / 1e9`` rounds twice and gives ``1431715297.1004028``)."""
    seconds, fraction = divmod(time_ns, 1_000_000_000)
    return seconds + fraction / 1e9


def format_address(address: Address) -> str:
    """``"address:port"``, an IPv6 address in brackets (``"[::1]:11000"``)."""
    host, port = address
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class FormatError(Exception):
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
class TcpSegment:
    """One TCP segment of a capture (:class:`SegmentReader`); read-only by convention."""

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
        return to_seconds(self.time_ns)


class SegmentReader:
    """The TCP segments of a pcap or pcapng capture, in capture order.

    ``source`` is a path (opened here, closed by :meth:`close` or at the end of the ``with``) or a
    binary file object (left open). The format is detected at once: :attr:`error` if the file does
    not begin like a capture. Iterating gives :class:`TcpSegment` objects (once); a truncated or
    malformed file raises :attr:`error` when the bad part is reached.
    """

    #: what a file that is no capture, or a truncated or malformed one, raises (a subclass may name
    #: a subclass of :class:`FormatError`: the package's ``CaptureReader`` raises ``CaptureError``)
    error: ClassVar[type[FormatError]] = FormatError

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
                raise self.error(self.name, f"not a pcap or pcapng capture (it begins with {shown})")
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

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __iter__(self) -> Iterator[TcpSegment]:
        known: dict[bytes, tuple[Address, Address]] = {}
        for ts, key, seq, ack, flags, payload in self.segment_tuples():
            pair = known.get(key)
            if pair is None:
                pair = known[key] = addresses(key)
            yield TcpSegment(ts, pair[0], pair[1], flags, seq, ack, payload)

    # The two generators below are the hot path: a packet costs a few struct unpacks and slices.

    def segment_tuples(self) -> Iterator[tuple[int, bytes, int, int, int, bytes]]:
        """The TCP segments as tuples ``(time_ns, key, seq, ack, flags, payload)``, where ``key``
        is the source and destination addresses then ports as on the wire (12 bytes for IPv4, 36
        for IPv6; :func:`addresses` makes them readable). The fast path of :meth:`__iter__`, and
        what the reassembly reads."""
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

    def _error(self, problem: str, offset: int | None = None) -> FormatError:
        return self.error(self.name, problem, offset)

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


def addresses(key: bytes) -> tuple[Address, Address]:
    """(source, destination) of a :meth:`SegmentReader.segment_tuples` key."""
    family, size = (socket.AF_INET, 4) if len(key) == 12 else (socket.AF_INET6, 16)
    sport, dport = _PORTS.unpack_from(key, 2 * size)
    return (
        (socket.inet_ntop(family, key[:size]), sport),
        (socket.inet_ntop(family, key[size : 2 * size]), dport),
    )
