"""Recording our own traffic as pcapng (:mod:`simple_message.capture.writer`, issue 20).

The files are read back with dpkt (``dpkt.pcapng.Reader``, and block by block for the nanosecond
timestamps a float cannot hold), each packet checked: Ethernet/IPv4/TCP, valid checksums, each
direction's sequence numbers advancing by its payload, every ACK the other side's next sequence
number. Then the writer alone, its size bound (rotation; a cap with ``files=1``), a full disk, the
connection layer's tap, an emulator with ``capture``, and ``robot-client --capture``. With tshark
installed, it must open the files and find nothing to complain about.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import logging
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path

import dpkt
import dpkt.pcapng
import pytest

from client import cli as client_cli
from robot_server import cli as server_cli
from robot_server.emulator import Emulator, EmulatorConfig
from simple_message import LE32, FrameDecoder, MsgType, Ping, decode
from simple_message.capture import MAX_SEGMENT, CapturedMessage, CaptureWriter, captured_messages, rotated_name
from simple_message.capture import read_capture as read_capture_segments
from simple_message.connection import Connection, TapLink
from simple_message.endpoints import Client, Server
from simple_message.transport import open_serial, open_tcp
from tests.rawpeer import RawPeer
from tests.stepped import poll, stepped_emulator

T = 10.0  # every wait here is bounded by this many seconds
#: a timestamp whose nanoseconds a float of seconds would lose
T0 = 1_700_000_000_123_456_789

SYN, FIN, ACK, PSH = dpkt.tcp.TH_SYN, dpkt.tcp.TH_FIN, dpkt.tcp.TH_ACK, dpkt.tcp.TH_PUSH


# -- reading a capture back ------------------------------------------------------------------------


@dataclass
class Packet:
    time_ns: int
    raw: bytes
    comment: str | None

    @property
    def ip(self) -> dpkt.ip.IP:
        return dpkt.ethernet.Ethernet(self.raw).data

    @property
    def tcp(self) -> dpkt.tcp.TCP:
        return self.ip.data

    @property
    def key(self) -> tuple[str, int, str, int]:
        ip = self.ip
        return (socket.inet_ntoa(ip.src), ip.data.sport, socket.inet_ntoa(ip.dst), ip.data.dport)


@dataclass
class Capture:
    linktype: int
    tsresol: bytes | None
    packets: list[Packet]
    #: each direction's payload, by (src, sport, dst, dport), in order
    streams: dict[tuple[str, int, str, int], bytes] = field(default_factory=dict)

    def flags(self) -> list[tuple[tuple[str, int, str, int], int, int]]:
        return [(p.key, p.tcp.flags, len(p.tcp.data)) for p in self.packets]


def read_capture(path: Path, *, handshakes: bool = True) -> Capture:
    """The file's interface and packets, every packet checked (module doc); ``handshakes``: every
    connection must begin with its SYN (not so in a file begun by a rotation)."""
    data = path.read_bytes()
    (magic,) = struct.unpack_from("<I", data, 8)
    little = magic == 0x1A2B3C4D
    order = "<" if little else ">"
    idb_class = dpkt.pcapng.InterfaceDescriptionBlockLE if little else dpkt.pcapng.InterfaceDescriptionBlock
    epb_class = dpkt.pcapng.EnhancedPacketBlockLE if little else dpkt.pcapng.EnhancedPacketBlock
    idbs, packets = [], []
    pos = 0
    while pos < len(data):
        block_type, length = struct.unpack_from(order + "II", data, pos)
        block = data[pos : pos + length]
        if block_type == dpkt.pcapng.PCAPNG_BT_IDB:
            idbs.append(idb_class(block))
        elif block_type == dpkt.pcapng.PCAPNG_BT_EPB:
            epb = epb_class(block)
            comments = [o.text for o in epb.opts if o.code == dpkt.pcapng.PCAPNG_OPT_COMMENT]
            packets.append(
                Packet((epb.ts_high << 32) | epb.ts_low, bytes(epb.pkt_data), comments[0] if comments else None)
            )
        pos += length
    assert pos == len(data), "a truncated block"
    assert len(idbs) == 1, "one interface"
    tsresol = [o.data for o in idbs[0].opts if o.code == dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL]
    with path.open("rb") as file:  # the stock reader agrees
        reader = dpkt.pcapng.Reader(file)
        assert reader.datalink() == dpkt.pcapng.DLT_EN10MB
        stock = list(reader)
    assert [bytes(buf) for _, buf in stock] == [p.raw for p in packets]
    for (seconds, _), p in zip(stock, packets, strict=True):
        assert abs(seconds - p.time_ns / 1e9) < 1e-6
    capture = Capture(idbs[0].linktype, tsresol[0] if tsresol else None, packets)
    capture.streams = check_tcp(packets, handshakes=handshakes)
    return capture


def check_packet(p: Packet) -> None:
    """Ethernet, IPv4 and TCP as Wireshark expects them, checksums included."""
    eth = dpkt.ethernet.Ethernet(p.raw)
    assert eth.type == dpkt.ethernet.ETH_TYPE_IP
    assert eth.src[0] & 0x02 and not eth.src[0] & 0x01  # locally administered, unicast
    raw_ip = p.raw[14:]
    ip = eth.data
    assert ip.v == 4 and ip.hl == 5 and ip.p == dpkt.ip.IP_PROTO_TCP and ip.len == len(raw_ip) <= 65535
    assert dpkt.in_cksum(raw_ip[:20]) == 0, "bad IPv4 header checksum"
    pseudo = ip.src + ip.dst + struct.pack(">xBH", dpkt.ip.IP_PROTO_TCP, ip.len - 20)
    assert dpkt.in_cksum(pseudo + raw_ip[20:]) == 0, "bad TCP checksum"
    # and as dpkt computes them
    again = dpkt.ip.IP(raw_ip)
    sums = again.sum, again.data.sum
    again.sum = again.data.sum = 0
    bytes(again)
    assert (again.sum, again.data.sum) == sums
    assert len(ip.data.data) <= MAX_SEGMENT


def check_tcp(packets: list[Packet], *, handshakes: bool) -> dict[tuple[str, int, str, int], bytes]:
    """Sequence and acknowledgement numbers consistent in every direction; each direction's payload."""
    following: dict[tuple[str, int, str, int], int] = {}  # direction -> next sequence number
    streams: dict[tuple[str, int, str, int], bytearray] = defaultdict(bytearray)
    finished: set[tuple[str, int, str, int]] = set()
    last = 0
    for p in packets:
        check_packet(p)
        assert p.time_ns >= last, "timestamps go forward"
        last = p.time_ns
        key, tcp = p.key, p.tcp
        back = (key[2], key[3], key[0], key[1])
        if tcp.flags & SYN:
            assert key not in following, "one SYN per direction"
            assert len(tcp.data) == 0
            following[key] = (tcp.seq + 1) & 0xFFFFFFFF
            if tcp.flags & ACK:
                assert tcp.ack == following[back]
            else:
                assert back not in following, "the SYN comes first"
            continue
        if key not in following:
            assert not handshakes, f"{key} sends before its handshake"
            following[key] = tcp.seq
        assert key not in finished or (tcp.flags == ACK and not tcp.data), "nothing but an ACK after a FIN"
        assert tcp.seq == following[key], "each segment follows the last"
        assert tcp.flags & ACK
        if back in following:
            assert tcp.ack == following[back], "every segment acknowledges all the other side sent"
        if tcp.data:
            assert tcp.flags & PSH
            streams[key] += tcp.data
        following[key] = (following[key] + len(tcp.data) + (1 if tcp.flags & FIN else 0)) & 0xFFFFFFFF
        if tcp.flags & FIN:
            finished.add(key)
    return {key: bytes(data) for key, data in streams.items()}


def frames(stream: bytes) -> list[bytes]:
    """The whole frames a direction's stream is made of (nothing left over)."""
    decoder = FrameDecoder()
    decoder.feed(stream)
    cut = list(decoder)
    assert decoder.buffered == 0 and not decoder.failed, "the stream is whole frames"
    return cut


# -- the writer alone ------------------------------------------------------------------------------

SERVER_LINK = TapLink("motion ('127.0.0.1', 40522)", ("127.0.0.1", 11000), ("127.0.0.1", 40522), accepted=True)
CLIENT_LINK = TapLink("motion 127.0.0.1:11000", ("127.0.0.1", 40522), ("127.0.0.1", 11000), accepted=False)
PING_REQUEST = Ping().encode(LE32)
PING_REPLY = Ping(comm_type=3, reply_code=1).encode(LE32)


def test_a_connection_is_a_handshake_data_both_ways_and_a_fin_exchange(tmp_path: Path) -> None:
    path = tmp_path / "one.pcapng"
    with CaptureWriter(path) as writer:
        writer.opened(SERVER_LINK, T0)
        writer.data(SERVER_LINK, False, PING_REQUEST, T0 + 1)
        writer.data(SERVER_LINK, True, PING_REPLY, T0 + 2)
        writer.data(SERVER_LINK, False, PING_REQUEST[:5], T0 + 3)  # chunks as they come
        writer.data(SERVER_LINK, False, PING_REQUEST[5:], T0 + 4)
        writer.closed(SERVER_LINK, True, T0 + 5)
    assert writer.stopped and writer.packets == 3 + 4 + 3
    capture = read_capture(path)
    assert capture.linktype == dpkt.pcapng.DLT_EN10MB
    assert capture.tsresol == bytes([9])  # nanoseconds
    client, server = ("127.0.0.1", 40522, "127.0.0.1", 11000), ("127.0.0.1", 11000, "127.0.0.1", 40522)
    assert capture.flags() == [
        (client, SYN, 0),  # the peer opened it: a server's connection
        (server, SYN | ACK, 0),
        (client, ACK, 0),
        (client, PSH | ACK, len(PING_REQUEST)),
        (server, PSH | ACK, len(PING_REPLY)),
        (client, PSH | ACK, 5),
        (client, PSH | ACK, len(PING_REQUEST) - 5),
        (client, FIN | ACK, 0),  # the peer ended first
        (server, FIN | ACK, 0),
        (client, ACK, 0),
    ]
    assert [p.time_ns for p in capture.packets] == [T0] * 3 + [T0 + 1, T0 + 2, T0 + 3, T0 + 4] + [T0 + 5] * 3
    assert capture.packets[0].comment == SERVER_LINK.name
    assert capture.streams == {client: PING_REQUEST * 2, server: PING_REPLY}
    assert decode(frames(capture.streams[server])[0], LE32) == Ping(comm_type=3, reply_code=1)


def test_a_client_connection_opens_and_closes_from_this_end(tmp_path: Path) -> None:
    path = tmp_path / "client.pcapng"
    with CaptureWriter(path) as writer:
        writer.opened(CLIENT_LINK, T0)
        writer.data(CLIENT_LINK, True, PING_REQUEST, T0 + 10)
        writer.data(CLIENT_LINK, False, PING_REPLY, T0 + 20)
        writer.closed(CLIENT_LINK, False, T0 + 30)
    capture = read_capture(path)
    ours, theirs = ("127.0.0.1", 40522, "127.0.0.1", 11000), ("127.0.0.1", 11000, "127.0.0.1", 40522)
    assert [(key, flags) for key, flags, _ in capture.flags()] == [
        (ours, SYN),
        (theirs, SYN | ACK),
        (ours, ACK),
        (ours, PSH | ACK),
        (theirs, PSH | ACK),
        (ours, FIN | ACK),
        (theirs, FIN | ACK),
        (ours, ACK),
    ]


def test_a_connection_met_first_with_data_gets_its_handshake_and_close_ends_the_open_ones(tmp_path: Path) -> None:
    path = tmp_path / "late.pcapng"
    with CaptureWriter(path) as writer:
        writer.data(CLIENT_LINK, True, PING_REQUEST, T0)
    capture = read_capture(path)
    assert [flags for _, flags, _ in capture.flags()] == [SYN, SYN | ACK, ACK, PSH | ACK, FIN | ACK, FIN | ACK, ACK]


def test_a_big_chunk_is_cut_into_segments_and_acknowledged(tmp_path: Path) -> None:
    path = tmp_path / "big.pcapng"
    payload = bytes(range(256)) * 600  # 153,600 bytes
    with CaptureWriter(path) as writer:
        writer.opened(SERVER_LINK, T0)
        writer.data(SERVER_LINK, True, payload, T0 + 1)
        writer.closed(SERVER_LINK, False, T0 + 2)
    capture = read_capture(path)
    server = ("127.0.0.1", 11000, "127.0.0.1", 40522)
    sizes = [size for key, _, size in capture.flags() if key == server and size]
    assert sizes == [MAX_SEGMENT, MAX_SEGMENT, len(payload) - 2 * MAX_SEGMENT]
    assert capture.streams[server] == payload
    # the receiver acknowledges what it got (Wireshark sees no window over-run)
    client = ("127.0.0.1", 40522, "127.0.0.1", 11000)
    assert sum(1 for key, flags, _ in capture.flags() if key == client and flags == ACK) >= 3


def test_ipv6_and_links_without_addresses_get_synthetic_ipv4_addresses(tmp_path: Path) -> None:
    path = tmp_path / "synthetic.pcapng"
    v6 = TapLink("v6", ("::1", 11000), ("::1", 50000), accepted=True)
    mapped = TapLink("mapped", ("::ffff:10.1.2.3", 11002), ("::ffff:10.1.2.4", 50001), accepted=True)
    serial = TapLink("serial", None, None, accepted=True)
    serial_client = TapLink("serial client", None, None, accepted=False)
    with CaptureWriter(path) as writer:
        for link in (v6, mapped, serial, serial_client):
            writer.data(link, True, PING_REPLY, T0)
    capture = read_capture(path)
    assert set(capture.streams) == {
        ("198.18.0.1", 11000, "198.18.0.1", 50000),
        ("10.1.2.3", 11002, "10.1.2.4", 50001),
        ("198.19.0.1", 11000, "198.19.0.2", 49152),  # the server's end on the motion port
        ("198.19.0.2", 49153, "198.19.0.1", 11000),
    }
    assert {p.comment for p in capture.packets if p.tcp.flags == SYN} == {"v6", "mapped", "serial", "serial client"}


@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark is not installed")
def test_tshark_reads_it_without_a_complaint(tmp_path: Path) -> None:
    path = tmp_path / "tshark.pcapng"
    with CaptureWriter(path) as writer:
        writer.opened(SERVER_LINK, T0)
        for k in range(20):
            writer.data(SERVER_LINK, k % 2 == 1, PING_REQUEST if k % 2 == 0 else PING_REPLY, T0 + k)
        writer.data(SERVER_LINK, True, bytes(150_000), T0 + 50)
        writer.closed(SERVER_LINK, True, T0 + 100)
    base = ["tshark", "-n", "-r", str(path), "-o", "tcp.check_checksum:TRUE", "-o", "ip.check_checksum:TRUE"]
    problems = "tcp.analysis.flags || tcp.checksum.status == 2 || ip.checksum.status == 2 || _ws.malformed"
    run = subprocess.run([*base, "-Y", problems], capture_output=True, text=True, timeout=60, check=True)
    assert run.stdout == ""
    fields = ["-T", "fields", "-e", "frame.time_epoch", "-e", "tcp.len"]
    run = subprocess.run([*base, *fields], capture_output=True, text=True, timeout=60, check=True)
    rows = [line.split("\t") for line in run.stdout.splitlines()]
    assert len(rows) == writer.packets
    assert rows[0][0] == "1700000000.123456789"  # nanoseconds


# -- the size bound ----------------------------------------------------------------------------------


def test_a_full_file_is_rotated_and_the_disk_holds_at_most_the_bound(tmp_path: Path) -> None:
    path = tmp_path / "traffic.pcapng"
    (tmp_path / "traffic.2.pcapng").write_bytes(b"an earlier capture's")  # not part of this one
    max_bytes, files = 6000, 3
    with CaptureWriter(path, max_bytes=max_bytes, files=files) as writer:
        assert not (tmp_path / "traffic.2.pcapng").exists()
        writer.opened(SERVER_LINK, T0)
        for k in range(200):
            writer.data(SERVER_LINK, k % 2 == 1, PING_REPLY if k % 2 else PING_REQUEST, T0 + k)
        writer.data(SERVER_LINK, True, b"the last chunk!!", T0 + 1000)
    assert writer.rotations > files
    names = [rotated_name(path, k) for k in range(files)]
    assert sorted(tmp_path.iterdir()) == sorted(names)
    sizes = [name.stat().st_size for name in names]
    assert all(size <= max_bytes // files for size in sizes), sizes
    assert sum(sizes) <= max_bytes
    # oldest first, each a pcapng of its own; together one consistent stream, ending with the latest
    packets = [p for name in reversed(names) for p in read_capture(name, handshakes=False).packets]
    streams = check_tcp(packets, handshakes=False)
    server = ("127.0.0.1", 11000, "127.0.0.1", 40522)
    assert streams[server].endswith(PING_REPLY * 3 + b"the last chunk!!")
    assert packets[-1].tcp.flags == ACK  # the FIN exchange closes the last file


def test_one_file_stops_at_the_bound_with_one_warning(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "capped.pcapng"
    with (
        caplog.at_level(logging.INFO, "simple_message.capture_writer"),
        CaptureWriter(path, max_bytes=3000, files=1) as writer,
    ):
        writer.opened(SERVER_LINK, T0)
        for k in range(100):
            writer.data(SERVER_LINK, False, PING_REQUEST, T0 + k)
        assert writer.full and writer.stopped
        writer.data(SERVER_LINK, False, PING_REQUEST, T0 + 200)  # ignored
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "limit" in warnings[0].getMessage()
    assert path.stat().st_size <= 3000
    assert sorted(tmp_path.iterdir()) == [path]
    capture = read_capture(path)
    assert frames(capture.streams[("127.0.0.1", 40522, "127.0.0.1", 11000)])  # what it holds is whole


def test_a_tiny_bound_still_takes_one_packet_per_file(tmp_path: Path) -> None:
    path = tmp_path / "tiny.pcapng"
    with CaptureWriter(path, max_bytes=10, files=2) as writer:
        writer.data(CLIENT_LINK, True, PING_REQUEST, T0)
    assert len(read_capture(path, handshakes=False).packets) == 1
    assert writer.packets == 7


def test_bad_bounds_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="max_bytes"):
        CaptureWriter(tmp_path / "x.pcapng", max_bytes=0)
    with pytest.raises(ValueError, match="files"):
        CaptureWriter(tmp_path / "x.pcapng", files=0)
    with pytest.raises(OSError):
        CaptureWriter(tmp_path / "no such directory" / "x.pcapng")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_a_full_disk_stops_the_capture_with_one_error_line(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, "simple_message.capture_writer"):
        writer = CaptureWriter("/dev/full", files=1)  # the headers wait in the buffer
        writer.opened(SERVER_LINK, T0)
        for k in range(5):
            writer.data(SERVER_LINK, True, bytes(100_000), T0 + k)  # more than the buffer holds
        writer.flush()
        writer.close()
    assert writer.stopped and writer.error is not None and writer.error.errno == 28  # ENOSPC
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "stopped" in errors[0].getMessage()


# -- the tap in the connection layer ------------------------------------------------------------------


class Recorder:
    """A tap that keeps what it is told."""

    def __init__(self) -> None:
        self.events: list[tuple[str, TapLink, object]] = []

    def opened(self, link: TapLink, time_ns: int) -> None:
        self.events.append(("opened", link, time_ns))

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        self.events.append(("out" if outgoing else "in", link, data))

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        self.events.append(("closed", link, by_peer))


async def test_the_tap_sees_each_end_open_send_receive_in_order_and_close() -> None:
    server_tap, client_tap = Recorder(), Recorder()
    server = Server(LE32, name="test", tap=server_tap)
    port = await server.serve_tcp("127.0.0.1", 0)
    try:
        client = Client.tcp("127.0.0.1", port, LE32, tap=client_tap, reconnect=None)
        async with asyncio.timeout(T):
            await client.start()
            await client.request(Ping())
            await client.request(Ping())
            local = client.connection.transport.get_extra_info("sockname") if client.connection else None
            await client.close()
            await poll(lambda: len(server_tap.events) == 6, T)
    finally:
        await server.close()
    assert [(kind, value) for kind, _, value in client_tap.events[1:]] == [
        ("out", PING_REQUEST),
        ("in", PING_REPLY),
        ("out", PING_REQUEST),
        ("in", PING_REPLY),
        ("closed", False),  # this end closed
    ]
    assert [(kind, value) for kind, _, value in server_tap.events[1:]] == [
        ("in", PING_REQUEST),  # the request comes before the reply it causes
        ("out", PING_REPLY),
        ("in", PING_REQUEST),
        ("out", PING_REPLY),
        ("closed", True),  # the peer closed first
    ]
    client_link, server_link = client_tap.events[0][1], server_tap.events[0][1]
    assert client_tap.events[0][0] == server_tap.events[0][0] == "opened"
    assert isinstance(client_tap.events[0][2], int)
    assert (client_link.accepted, server_link.accepted) == (False, True)
    assert local is not None and client_link.local == server_link.peer == ("127.0.0.1", local[1])
    assert client_link.peer == server_link.local == ("127.0.0.1", port)
    assert {link for _, link, _ in server_tap.events} == {server_link}


class Failing(Recorder):
    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        raise RuntimeError("a broken tap")


async def test_a_failing_tap_is_logged_once_dropped_and_the_connection_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    tap = Failing()
    server = Server(LE32, name="test", tap=tap)
    port = await server.serve_tcp("127.0.0.1", 0)
    try:
        async with asyncio.timeout(T):
            connection = Connection(await open_tcp("127.0.0.1", port), LE32).start()
            for _ in range(3):
                reply = await connection.request(Ping())
                assert reply.reply_code == 1
            await connection.close()
    finally:
        await server.close()
    failures = [r for r in caplog.records if "tap failed" in r.getMessage()]
    assert len(failures) == 1
    assert [kind for kind, _, _ in tap.events] == ["opened"]  # dropped: not even told of the close


async def test_a_serial_link_is_captured_with_synthetic_addresses(tmp_path: Path) -> None:
    path = tmp_path / "pty.pcapng"
    master, slave = os.openpty()
    with CaptureWriter(path) as writer:
        server = Server(LE32, name="serial", tap=writer)
        try:
            server.start_serving(server.serve_fd(master, name="pty-master"))
            async with asyncio.timeout(T):
                streams = await open_serial(os.ttyname(slave), baudrate=115200)
                os.close(slave)
                connection = Connection(streams, LE32).start()
                await connection.request(Ping())
                await connection.close()
                await poll(lambda: not server.sessions, T)
        finally:
            await server.close()
    capture = read_capture(path)
    client, server_end = ("198.19.0.2", 49152, "198.19.0.1", 11000), ("198.19.0.1", 11000, "198.19.0.2", 49152)
    assert capture.streams == {client: PING_REQUEST, server_end: PING_REPLY}
    assert capture.packets[0].key == client and capture.packets[0].tcp.flags == SYN


# -- the emulator and the commands --------------------------------------------------------------------


async def test_an_emulator_records_every_frame_that_went_over_the_wire(tmp_path: Path) -> None:
    path = tmp_path / "emulator.pcapng"
    before = time.time_ns()
    async with stepped_emulator(capture=path) as (emu, _clock):
        assert emu.capture is not None and not emu.capture.stopped
        motion = await RawPeer.connect(emu.ports["motion"])
        state = await RawPeer.connect(emu.ports["state"])
        try:
            reply = await motion.request(PING_REQUEST, T)
            topics = [await state.frame(T) for _ in range(4)]
            motion_port = motion.writer.get_extra_info("sockname")[1]
            state_port = state.writer.get_extra_info("sockname")[1]
        finally:
            await motion.close()
            await state.close()
        await poll(lambda: not emu.motion_server.sessions and not emu.state_server.sessions, T)
    after = time.time_ns()
    assert emu.capture.stopped  # closed with the emulator
    capture = read_capture(path)
    assert before <= capture.packets[0].time_ns and capture.packets[-1].time_ns <= after
    m, s = emu.ports["motion"], emu.ports["state"]
    to_motion, from_motion = ("127.0.0.1", motion_port, "127.0.0.1", m), ("127.0.0.1", m, "127.0.0.1", motion_port)
    to_state, from_state = ("127.0.0.1", state_port, "127.0.0.1", s), ("127.0.0.1", s, "127.0.0.1", state_port)
    assert capture.streams[to_motion] == PING_REQUEST
    assert capture.streams[from_motion] == reply.raw
    assert to_state not in capture.streams  # a state client only listens
    sent = capture.streams[from_state]
    assert sent.startswith(b"".join(t.raw for t in topics))  # and perhaps more, in flight when it left
    kinds = [decode(frame, LE32).msg_type for frame in frames(sent)]
    assert kinds[:4] == [MsgType.JOINT_POSITION, MsgType.STATUS] * 2
    # the clients opened their connections, and ended them first
    syns = [p.key for p in capture.packets if p.tcp.flags == SYN]
    fins = [p.key for p in capture.packets if p.tcp.flags & FIN]
    assert sorted(syns) == sorted([to_motion, to_state])
    assert fins[0::2] in ([to_motion, to_state], [to_state, to_motion])


async def test_an_emulator_refuses_to_start_when_the_capture_cannot_be_written(tmp_path: Path) -> None:
    emu = Emulator(EmulatorConfig(motion_port=0, state_port=0, capture=tmp_path / "nowhere" / "x.pcapng"))
    with pytest.raises(OSError):
        await emu.start()
    assert not emu.ports
    await emu.close()


@contextlib.asynccontextmanager
async def controller() -> AsyncIterator[tuple[Emulator, list[str]]]:
    config = EmulatorConfig(motion_port=0, state_port=0, speedup=8.0, state_rate=100.0)
    async with Emulator(config) as emu:
        yield emu, ["--motion-port", str(emu.ports["motion"]), "--state-port", str(emu.ports["state"])]


async def robot_client(*argv: str) -> tuple[int, str]:
    out = io.StringIO()
    async with asyncio.timeout(60.0):
        code = await asyncio.to_thread(client_cli.main, list(argv), out)
    return code, out.getvalue()


async def test_robot_client_ping_and_status_capture_their_traffic(tmp_path: Path) -> None:
    async with controller() as (emu, ports):
        code, out = await robot_client("ping", "--count", "2", *ports, "--capture", str(tmp_path / "ping.pcapng"))
        assert code == 0, out
        code, out = await robot_client("status", *ports, "--capture", str(tmp_path / "status.pcapng"))
        assert code == 0, out
    m, s = emu.ports["motion"], emu.ports["state"]
    ping = read_capture(tmp_path / "ping.pcapng")
    requests = {key: data for key, data in ping.streams.items() if key[3] == m}
    replies = {key: data for key, data in ping.streams.items() if key[1] == m}
    assert list(requests.values()) == [PING_REQUEST * 2]
    assert list(replies.values()) == [PING_REPLY * 2]
    status = read_capture(tmp_path / "status.pcapng")
    assert {key[3] for key, flags, _ in status.flags() if flags == SYN} == {s}  # status watches: state port alone
    from_state = next(data for key, data in status.streams.items() if key[1] == s)
    kinds = {decode(frame, LE32).msg_type for frame in frames(from_state)}
    assert {MsgType.JOINT_POSITION, MsgType.STATUS} <= kinds
    to_state = next(data for key, data in status.streams.items() if key[3] == s)
    assert [decode(frame, LE32).msg_type for frame in frames(to_state)] == [MsgType.TOOL_POSE]  # it asked
    assert status.packets[-1].tcp.flags == ACK  # the connection's end is in the file


async def test_robot_server_closes_its_capture_cleanly_on_sigterm(tmp_path: Path) -> None:
    path = tmp_path / "server.pcapng"
    log = tmp_path / "robot-server.log"
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "robot_server",
            *("--motion-port", "0", "--state-port", "0", "--no-stdin", "--capture", str(path)),
            stdout=asyncio.subprocess.PIPE,
            stderr=err,
        )
    try:
        assert proc.stdout is not None
        line = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).decode()
        assert line.startswith("robot-server ready"), line + log.read_text()
        motion_port = int(re.findall(r"motion [\d.]+:(\d+)", line)[0])
        peer = await RawPeer.connect(motion_port)
        try:
            reply = await peer.request(PING_REQUEST, T)
            proc.send_signal(signal.SIGTERM)  # with the client still connected
            assert await asyncio.wait_for(proc.wait(), 20.0) == 0, log.read_text()
        finally:
            await peer.close()
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    capture = read_capture(path)
    to_server = next(key for key in capture.streams if key[3] == motion_port)
    from_server = (to_server[2], to_server[3], to_server[0], to_server[1])
    assert capture.streams == {to_server: PING_REQUEST, from_server: reply.raw}
    # the server closed the connection at exit: its FIN first, and the file holds the whole exchange
    assert capture.flags()[-3:] == [(from_server, FIN | ACK, 0), (to_server, FIN | ACK, 0), (from_server, ACK, 0)]


def test_the_commands_refuse_a_capture_they_cannot_write(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = str(tmp_path / "nowhere" / "x.pcapng")
    assert client_cli.main(["status", "--capture", missing], io.StringIO()) == 2
    assert "cannot write it" in capsys.readouterr().err
    assert client_cli.main(["demo", "--capture", missing], io.StringIO()) == 2
    assert "cannot write it" in capsys.readouterr().err
    assert server_cli.main(["--capture", missing, "--no-stdin"]) == 2
    assert "--capture" in capsys.readouterr().err
    assert server_cli.main(["--capture", str(tmp_path), "--no-stdin"]) == 2
    assert "is a directory" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_the_demo_records_every_run_of_its_own(tmp_path: Path) -> None:
    """robot-client demo --capture: the runs on its embedded emulators, in one file."""
    path = tmp_path / "demo.pcapng"
    argv = ["demo", "--simulated", "--embedded", "--short", "--policies", "quintic", "--no-plot"]
    argv += ["--output", str(tmp_path / "out"), "--capture", str(path)]
    assert client_cli.main(argv, io.StringIO()) == 0
    names = [
        item.message.name
        for item in captured_messages(str(path), LE32, True)
        if isinstance(item, CapturedMessage) and item.message is not None
    ]
    # the quintic row downloads its waypoints; the MOVL row sends CARTESIAN_LINE; both read the state
    assert "JOINT_TRAJ_PT" in names and "CARTESIAN_LINE" in names and "JOINT_POSITION" in names


def test_a_pcap_and_a_pcapng_written_by_the_project_read_back_identically(tmp_path: Path) -> None:
    """The same traffic through a writer to FILE.pcap (classic pcap, ns timestamps) and to
    FILE.pcapng: the reader gives the same packets, times and payloads from both."""
    server = TapLink("motion", ("127.0.0.1", 11000), ("127.0.0.1", 40001), accepted=True)
    client = TapLink("state", ("10.0.0.2", 40002), ("10.0.0.1", 11002), accepted=False)
    ping = PING_REQUEST
    segments = {}
    for name in ("traffic.pcap", "traffic.pcapng"):
        with CaptureWriter(tmp_path / name) as writer:
            assert writer.format == name.rsplit(".", 1)[1]
            writer.opened(server, T0)
            writer.opened(client, T0 + 1)
            for k in range(5):
                writer.data(server, False, ping, T0 + 10 * k + 2)
                writer.data(server, True, ping, T0 + 10 * k + 3)
                writer.data(client, False, bytes(range(40)) * (k + 1), T0 + 10 * k + 4)
            writer.closed(server, True, T0 + 100)
            writer.closed(client, False, T0 + 101)
        segments[name] = [
            (s.time_ns, s.src, s.dst, s.flags, s.seq, s.payload) for s in read_capture_segments(str(tmp_path / name))
        ]
    assert segments["traffic.pcap"] == segments["traffic.pcapng"]
    assert len(segments["traffic.pcap"]) > 15 and segments["traffic.pcap"][0][0] == T0  # nanoseconds kept
