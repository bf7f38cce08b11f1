"""Record a program's own simple_message traffic as a pcapng file that Wireshark opens as it is.

A :class:`CaptureWriter` is a :class:`~simple_message.connection.Tap`: given to a server (``Server(tap=...)``,
``robot-server --capture``) or a client (``Client(tap=...)``, ``robot-client --capture``), it
writes every chunk of bytes the program sends or receives, as the connection layer hands it to the
transport or gets it from it, as one TCP segment (or several, see below) of a synthesised
Ethernet/IPv4/TCP packet. Reading the file back with dpkt, tshark or ``simple-message decode``
gives each direction's byte stream exactly.

**The file.** A path ending in ``.pcap`` gets a classic pcap file (nanosecond timestamps, magic
``a1b23c4d``, link type Ethernet; no packet comments), any other a pcapng one. pcapng (little- or
big-endian as the machine, written with ``dpkt.pcapng``): one
Section Header Block (``shb_userappl``: the program), one Interface Description Block (link type
Ethernet, ``DLT_EN10MB``; snap length 262144; ``if_name`` ``simple_message``; ``if_tsresol`` 9:
timestamps in nanoseconds, from ``time.time_ns()`` when the tap was called), then one Enhanced
Packet Block per packet. The SYN of each connection carries a packet comment: the connection's name
(``motion ('127.0.0.1', 40522)``).

**The packets.** Per connection (local address:port, peer address:port):

* when it opens, a three-way handshake: SYN (MSS 65495 option), SYN-ACK, ACK, from the side that
  opened it (a server's connections: the peer; a client's: this end) — written when the connection
  layer saw it, so the three packets share one timestamp;
* each chunk of bytes: PSH|ACK segments from the side that sent it. Each direction's sequence
  number starts at a fixed initial sequence number (a CRC-32 of the addresses and ports) and
  advances by the payload length (and 1 for SYN and FIN); every segment acknowledges everything the
  other side has sent. A receiver that has not sent anything for 32 KiB gets a pure ACK (so
  Wireshark's TCP analysis sees no window over-run). A chunk over 65,000 bytes is cut into several
  segments (an IPv4 packet holds at most 65,535 bytes), all with the chunk's timestamp;
* when it closes, FIN|ACK from the side that ended first (the peer when its EOF or reset came
  first, else this end), FIN|ACK from the other, and the last ACK. A connection still open when
  the writer closes is closed that way by this end.

IPv4 header: 20 bytes, DF set, TTL 64, an identification counting per direction; TCP header: 20
bytes (24 for the SYNs), window 65535 (no scaling). The IPv4 and TCP checksums are computed (with
dpkt's Internet checksum), so Wireshark's checksum validation, when on, passes. MAC addresses are
synthetic and locally administered: ``02:00`` followed by the four bytes of the IPv4 address.

**Addresses.** An IPv4 connection keeps its real addresses and ports. An IPv6 connection keeps its
ports; each IPv6 address gets a synthetic IPv4 address from 198.18.0.0/16 (RFC 2544's benchmarking
range: never a real host), in the order the writer first meets them (an IPv4-mapped IPv6 address
``::ffff:a.b.c.d`` is a.b.c.d). A link without addresses (a serial port, a pty, a memory pair) is
shown as TCP between 198.19.0.1 port 11000 (the server's end: the simple_message motion port, where
a dissector looks by default) and 198.19.0.2 port 49152 + n (the client's end; n counts such
links from 0), so a dissector decodes it like a socket.

**The size bound: rotation.** ``max_bytes`` (default 100 MB) bounds all the capture's files
together, ``files`` (default 2) of them: the current one, ``FILE``, grows up to
``max_bytes // files`` bytes; the packet that would take it over that limit goes to a new ``FILE``
instead, after the full one is renamed ``FILE`` -> stem.1.suffix (``traffic.pcapng`` ->
``traffic.1.pcapng``: the suffix stays last so that tools that go by it still know the format),
``.1`` -> ``.2`` and so on, the oldest beyond ``files - 1`` deleted. So the disk holds at most
``max_bytes`` (plus one packet) and the latest traffic is always kept. Every file is a complete
pcapng of its own (its own headers); the connections that span a rotation continue in the new file
without a handshake (Wireshark follows such streams; ``mergecap`` joins the files). With
``files=1`` there is no rotation: the capture stops at ``max_bytes`` with one WARNING line. A file
always takes at least one packet, so a tiny limit still records something. Starting a capture
replaces ``FILE`` and deletes the rotated files an earlier capture to the same name left.

**Failures.** Opening the file raises :class:`OSError` (say so before serving). Any later error
writing (a full disk) is logged once, as an ERROR, and the capture stops there; the program goes
on. The file is flushed by the first packet a second or more after the last flush, and by
:meth:`CaptureWriter.close` (a program killed with SIGKILL loses at most the last 64 KiB).

**Cost.** Nothing when no tap is set (one ``is not None`` per write and read in the connection
layer). With one, each chunk costs packing, checksumming and writing one packet: about 11
microseconds (headers packed with ``struct``; building them as dpkt objects took three times as
long). Pipelined PINGs through a server whose every connection is captured ran 20-30 % slower.

**Threads.** Every method takes a lock, so the writer may be shared by connections of one event
loop (the usual case: one server's taps all run on its loop) and be closed from another thread.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import os
import struct
import sys
import threading
import time
import zlib
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any

import dpkt  # type: ignore[import-untyped, unused-ignore]
import dpkt.pcap  # type: ignore[import-untyped, unused-ignore]
import dpkt.pcapng  # type: ignore[import-untyped, unused-ignore]

if TYPE_CHECKING:
    from ..connection import TapLink

__all__ = [
    "CaptureWriter",
    "DEFAULT_MAX_BYTES",
    "DEFAULT_FILES",
    "MAX_SEGMENT",
    "rotated_name",
]

#: the logger keeps the name of the module the writer was before the capture package (logging
#: configurations name it)
log = logging.getLogger("simple_message.capture_writer")

#: the bound of all the capture's files together (bytes)
DEFAULT_MAX_BYTES = 100_000_000
#: how many files the bound is shared by (the current one and the rotated ones)
DEFAULT_FILES = 2
#: the longest TCP payload of one packet (an IPv4 packet is at most 65,535 bytes with its headers)
MAX_SEGMENT = 65_000
#: the snap length the Interface Description Block declares (libpcap's largest)
SNAPLEN = 262_144
#: the window every segment advertises (no window scaling)
WINDOW = 65_535
#: a receiver that has sent nothing acknowledges the data once this much is unacknowledged
ACK_EVERY = 32_768
#: the MSS option of the SYNs (loopback's: 65,535 - 40)
MSS = 65_495
#: links without addresses (serial ports, ptys): the server's end, the client's end and ports
SERIAL_SERVER = ("198.19.0.1", 11000)
SERIAL_CLIENT_IP = "198.19.0.2"
SERIAL_CLIENT_PORT = 49152
#: IPv6 addresses are shown as addresses of this IPv4 network, in the order they are met
IPV6_STAND_IN = ipaddress.IPv4Network("198.18.0.0/16")
#: flush the file at least this often while packets come (ns)
FLUSH_EVERY_NS = 1_000_000_000

_LITTLE = sys.byteorder == "little"
_SHB = dpkt.pcapng.SectionHeaderBlockLE if _LITTLE else dpkt.pcapng.SectionHeaderBlock
_IDB = dpkt.pcapng.InterfaceDescriptionBlockLE if _LITTLE else dpkt.pcapng.InterfaceDescriptionBlock
_OPTION = dpkt.pcapng.PcapngOptionLE if _LITTLE else dpkt.pcapng.PcapngOption

_FIN, _SYN, _PSH, _ACK = dpkt.tcp.TH_FIN, dpkt.tcp.TH_SYN, dpkt.tcp.TH_PUSH, dpkt.tcp.TH_ACK
_MSS_OPTION = struct.pack(">BBH", dpkt.tcp.TCP_OPT_MSS, 4, MSS)
_IPPROTO_TCP = dpkt.ip.IP_PROTO_TCP
_DF = dpkt.ip.IP_DF
_ETHERTYPE_IPV4 = struct.pack(">H", dpkt.ethernet.ETH_TYPE_IP)
#: TCP header without its checksum and urgent pointer (sport, dport, seq, ack, offset+flags, window)
_TCP = struct.Struct(">HHIIHH4x")
#: IPv4 header (version+IHL, TOS, length, id, flags+offset, TTL, protocol, checksum 0, src, dst)
_IP = struct.Struct(">BBHHHBB2x4s4s")
_PSEUDO = struct.Struct(">xBH")
_SUM = struct.Struct(">H")
_EPB_HEADER = struct.Struct("=7I")
_OPTION_HEADER = struct.Struct("=HH")
_TOTAL = struct.Struct("=I")
in_cksum, in_cksum_add, in_cksum_done = dpkt.in_cksum, dpkt.in_cksum_add, dpkt.in_cksum_done


def rotated_name(path: str | os.PathLike[str], k: int) -> Path:
    """The name of the ``k``-th rotated file of a capture to ``path`` (0: ``path`` itself):
    ``traffic.pcapng`` -> ``traffic.1.pcapng``, ``traffic`` -> ``traffic.1``."""
    path = Path(path)
    if k == 0:
        return path
    return path.with_name(f"{path.stem}.{k}{path.suffix}") if path.suffix else path.with_name(f"{path.name}.{k}")


class _End:
    """One side of a connection as the packets show it."""

    __slots__ = ("ip", "mac", "port")

    def __init__(self, ip: bytes, port: int) -> None:
        self.ip = ip
        self.port = port
        self.mac = b"\x02\x00" + ip


class _Flow:
    """One connection's TCP state: index 0 is this end, 1 the peer."""

    __slots__ = ("ends", "ip_id", "name", "seq", "unacked")

    def __init__(self, name: str, local: _End, peer: _End, serial: int) -> None:
        self.name = name
        self.ends = (local, peer)
        self.seq = [_isn(local, peer, serial), _isn(peer, local, serial)]
        self.unacked = [0, 0]
        self.ip_id = [0, 0]


def _isn(src: _End, dst: _End, serial: int) -> int:
    """A direction's initial sequence number: from its addresses, ports and the connection's serial
    number in this capture (a port pair used again gets other numbers, as a real stack's would)."""
    return zlib.crc32(src.ip + dst.ip + struct.pack(">HHI", src.port, dst.port, serial))


class CaptureWriter:
    """Writes what a :class:`~simple_message.connection.Tap` sees as pcapng (see the module doc).

    ``path``: the file (replaced); ``max_bytes``: the bound of all its files together; ``files``:
    how many files share it (rotation; 1: stop at the bound); ``application``: the Section Header
    Block's ``shb_userappl``. Opening the file may raise :class:`OSError`. A context manager;
    :meth:`close` ends the connections still open and closes the file.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        max_bytes: int = DEFAULT_MAX_BYTES,
        files: int = DEFAULT_FILES,
        application: str = "simple_message",
    ) -> None:
        if max_bytes < 1:
            raise ValueError(f"max_bytes must be at least 1, not {max_bytes}")
        if files < 1:
            raise ValueError(f"files must be at least 1, not {files}")
        self.path = Path(path)
        self.max_bytes = max_bytes
        self.files = files
        #: the bound of one file (bytes)
        self.file_limit = max(1, max_bytes // files)
        self.application = application
        #: ``pcap`` for a path ending in ``.pcap``, else ``pcapng``
        self.format = "pcap" if self.path.suffix.lower() == ".pcap" else "pcapng"
        #: packets written (all files)
        self.packets = 0
        #: how many times the file was full and a new one begun
        self.rotations = 0
        #: the error that stopped the capture (None: none)
        self.error: OSError | None = None
        #: the bound was reached with ``files=1``: nothing more is recorded
        self.full = False
        self._lock = threading.Lock()
        self._flows: dict[TapLink, _Flow] = {}
        self._stand_ins: dict[str, bytes] = {}
        self._serial_links = 0
        self._file: IO[bytes] | None = None
        self._size = 0
        self._in_file = 0
        self._flushed = time.time_ns()  # the taps' clock
        self._connections = 0
        for k in range(1, files):  # an earlier capture's rotated files: not part of this one
            with contextlib.suppress(FileNotFoundError):
                os.remove(rotated_name(self.path, k))
        self._open()

    # -- the tap (connection.Tap) ------------------------------------------------------------------

    def opened(self, link: TapLink, time_ns: int) -> None:
        with self._lock:
            if self._file is not None:
                self._flow(link, time_ns)

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        with self._lock:
            if self._file is None or not data:
                return
            flow = self._flow(link, time_ns)
            sender = 0 if outgoing else 1
            for start in range(0, len(data), MAX_SEGMENT):
                segment = data if len(data) <= MAX_SEGMENT else data[start : start + MAX_SEGMENT]
                self._segment(flow, sender, _PSH | _ACK, segment, time_ns)
                if flow.unacked[sender] >= ACK_EVERY:
                    self._segment(flow, 1 - sender, _ACK, b"", time_ns)

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        with self._lock:
            flow = self._flows.pop(link, None)
            if flow is not None and self._file is not None:
                self._close_flow(flow, 1 if by_peer else 0, time_ns)
                self._flush()  # a connection's end is on disk, even if nothing follows for long

    # -- the file ------------------------------------------------------------------------------------

    @property
    def stopped(self) -> bool:
        """Nothing more is recorded (closed, full with ``files=1``, or an error)."""
        return self._file is None

    def flush(self) -> None:
        with self._lock:
            self._flush()

    def _flush(self) -> None:
        if self._file is not None:
            try:
                self._file.flush()
            except OSError as exc:
                self._fail(exc)

    def close(self) -> None:
        """Close the connections still open (this end first), flush and close the file."""
        with self._lock:
            now = time.time_ns()
            flows, self._flows = self._flows, {}
            for flow in flows.values():
                if self._file is None:
                    break
                self._close_flow(flow, 0, now)
            file, self._file = self._file, None
            if file is not None:
                try:
                    file.close()
                except OSError as exc:
                    self._fail(exc)

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "stopped" if self.stopped else f"{self._size} bytes"
        return f"<CaptureWriter {self.path} {self.packets} packets, {state}>"

    # -- internals (under the lock) -----------------------------------------------------------------

    def _open(self) -> None:
        """Begin a new file with its headers (raises OSError)."""
        file = open(self.path, "wb", buffering=1 << 16)  # noqa: SIM115 - kept open, closed by close()
        if self.format == "pcap":
            try:
                dpkt.pcap.Writer(file, snaplen=SNAPLEN, linktype=dpkt.pcap.DLT_EN10MB, nano=True)  # the header
            except BaseException:
                file.close()
                raise
            self._file, self._size, self._in_file = file, _PCAP_HEADER_SIZE, 0
            self._flush()  # a file that tools can open from the start
            return
        try:
            shb = _SHB(opts=[_option(dpkt.pcapng.PCAPNG_OPT_SHB_USERAPPL, self.application.encode()), _option(0)])
            idb = _IDB(
                linktype=dpkt.pcapng.DLT_EN10MB,
                snaplen=SNAPLEN,
                opts=[
                    _option(dpkt.pcapng.PCAPNG_OPT_IF_NAME, b"simple_message"),
                    _option(dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL, bytes([9])),
                    _option(0),
                ],
            )
            dpkt.pcapng.Writer(file, shb=shb, idb=idb)  # writes the two header blocks
            self._size = len(bytes(shb)) + len(bytes(idb))
        except BaseException:
            file.close()
            raise
        self._file = file
        self._in_file = 0
        self._flush()  # a file that tools can open from the start

    def _fail(self, exc: OSError) -> None:
        """Writing failed: say so once and record nothing more (the program goes on)."""
        log.error("capture %s stopped: cannot write it: %s", self.path, exc)
        self.error = exc
        file, self._file = self._file, None
        if file is not None:
            with contextlib.suppress(OSError, ValueError):
                file.close()

    def _write(self, packet: bytes, time_ns: int, comment: str | None = None) -> None:
        if self.format == "pcap":
            seconds, nanoseconds = divmod(time_ns, 1_000_000_000)
            block = _PCAP_RECORD.pack(seconds, nanoseconds, len(packet), len(packet)) + packet
        else:
            block = _packet_block(packet, time_ns, comment)
        if self._size + len(block) > self.file_limit and self._in_file > 0 and not self._next_file():
            return
        file = self._file
        if file is None:
            return
        try:
            file.write(block)
            if time_ns - self._flushed >= FLUSH_EVERY_NS:
                self._flushed = time_ns
                file.flush()
        except OSError as exc:
            self._fail(exc)
            return
        self._size += len(block)
        self._in_file += 1
        self.packets += 1

    def _next_file(self) -> bool:
        """The file is full: rotate (``files`` > 1) or stop. Returns whether there is a file."""
        file, self._file = self._file, None
        assert file is not None
        try:
            file.close()
            if self.files == 1:
                self.full = True
                log.warning(
                    "capture %s reached its limit of %d bytes: nothing more is recorded", self.path, self.max_bytes
                )
                return False
            for k in range(self.files - 1, 0, -1):
                with contextlib.suppress(FileNotFoundError):
                    os.replace(rotated_name(self.path, k - 1), rotated_name(self.path, k))
            self._open()
        except OSError as exc:
            self._fail(exc)
            return False
        self.rotations += 1
        log.info("capture %s: %d bytes, rotated (%d files kept)", self.path, self.file_limit, self.files)
        return True

    def _flow(self, link: TapLink, time_ns: int) -> _Flow:
        """The connection's flow; a connection met for the first time gets its handshake."""
        flow = self._flows.get(link)
        if flow is not None:
            return flow
        self._connections += 1
        flow = self._flows[link] = _Flow(link.name, *self._ends(link), self._connections)
        client = 1 if link.accepted else 0
        server = 1 - client
        self._segment(flow, client, _SYN, b"", time_ns, options=_MSS_OPTION, comment=link.name)
        self._segment(flow, server, _SYN | _ACK, b"", time_ns, options=_MSS_OPTION)
        self._segment(flow, client, _ACK, b"", time_ns)
        return flow

    def _close_flow(self, flow: _Flow, closer: int, time_ns: int) -> None:
        self._segment(flow, closer, _FIN | _ACK, b"", time_ns)
        self._segment(flow, 1 - closer, _FIN | _ACK, b"", time_ns)
        self._segment(flow, closer, _ACK, b"", time_ns)

    def _ends(self, link: TapLink) -> tuple[_End, _End]:
        """The addresses the packets show for the connection's two ends (see the module doc)."""
        if link.local is not None and link.peer is not None:
            return (
                _End(self._ipv4(link.local[0]), link.local[1]),
                _End(self._ipv4(link.peer[0]), link.peer[1]),
            )
        n = self._serial_links
        self._serial_links += 1
        server = _End(ipaddress.IPv4Address(SERIAL_SERVER[0]).packed, SERIAL_SERVER[1])
        client = _End(ipaddress.IPv4Address(SERIAL_CLIENT_IP).packed, SERIAL_CLIENT_PORT + n % 16384)
        return (server, client) if link.accepted else (client, server)

    def _ipv4(self, host: str) -> bytes:
        """The four bytes shown for ``host``: its own for IPv4, a stand-in for IPv6."""
        try:
            address = ipaddress.ip_address(host.partition("%")[0])  # without an IPv6 scope
        except ValueError:
            address = None
        if isinstance(address, ipaddress.IPv4Address):
            return address.packed
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            return address.ipv4_mapped.packed
        stand_in = self._stand_ins.get(host)
        if stand_in is None:
            index = len(self._stand_ins) + 1
            stand_in = self._stand_ins[host] = IPV6_STAND_IN[index % (IPV6_STAND_IN.num_addresses - 1) or 1].packed
        return stand_in

    def _segment(
        self,
        flow: _Flow,
        sender: int,
        flags: int,
        payload: bytes,
        time_ns: int,
        *,
        options: bytes = b"",
        comment: str | None = None,
    ) -> None:
        """Write one TCP segment from ``sender`` (0: this end, 1: the peer) and advance its flow."""
        src, dst = flow.ends[sender], flow.ends[1 - sender]
        receiver = 1 - sender
        seq = flow.seq[sender]
        ack = flow.seq[receiver] if flags & _ACK else 0
        tcp_length = 20 + len(options) + len(payload)
        tcp = _TCP.pack(src.port, dst.port, seq, ack, ((5 + len(options) // 4) << 12) | flags, WINDOW) + options
        pseudo = src.ip + dst.ip + _PSEUDO.pack(_IPPROTO_TCP, tcp_length)
        checksum = in_cksum_done(in_cksum_add(in_cksum_add(0, pseudo + tcp), payload))
        tcp = tcp[:16] + _SUM.pack(checksum) + tcp[18:]
        ip = _IP.pack(0x45, 0, 20 + tcp_length, flow.ip_id[sender], _DF, 64, _IPPROTO_TCP, src.ip, dst.ip)
        ip = ip[:10] + _SUM.pack(in_cksum(ip)) + ip[12:]
        self._write(dst.mac + src.mac + _ETHERTYPE_IPV4 + ip + tcp + payload, time_ns, comment)
        flow.ip_id[sender] = (flow.ip_id[sender] + 1) & 0xFFFF
        flow.seq[sender] = (seq + len(payload) + (1 if flags & (_SYN | _FIN) else 0)) & 0xFFFFFFFF
        flow.unacked[sender] += len(payload)
        if flags & _ACK:
            flow.unacked[receiver] = 0


#: a classic pcap file's header, and a record's header in the machine's byte order (dpkt's Writer)
_PCAP_HEADER_SIZE = 24
_PCAP_RECORD = struct.Struct("<IIII" if _LITTLE else ">IIII")


def _packet_block(packet: bytes, time_ns: int, comment: str | None) -> bytes:
    """An Enhanced Packet Block (interface 0) in the machine's byte order, as dpkt's Writer writes."""
    options = b""
    if comment:
        text = comment.encode()
        options = _OPTION_HEADER.pack(dpkt.pcapng.PCAPNG_OPT_COMMENT, len(text)) + _pad(text) + bytes(4)
    length = len(packet)
    total = 32 + (length + 3) // 4 * 4 + len(options)
    return b"".join(
        (
            _EPB_HEADER.pack(dpkt.pcapng.PCAPNG_BT_EPB, total, 0, time_ns >> 32, time_ns & 0xFFFFFFFF, length, length),
            _pad(packet),
            options,
            _TOTAL.pack(total),
        )
    )


def _pad(data: bytes) -> bytes:
    return data + bytes(-len(data) % 4)


def _option(code: int, data: bytes = b"") -> Any:
    return _OPTION(code=code, data=data)
