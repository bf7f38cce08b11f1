"""pcap/pcapng captures: reading, TCP reassembly, decoding (simple_message.capture) and ``decode CAPTURE``."""

from __future__ import annotations

import io
import json
import socket
import struct
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

import dpkt
import dpkt.ip6
import dpkt.pcap
import dpkt.pcapng
import pytest

from simple_message import BE32, LE32, ByteOrder, FrameDecoder, JointTrajPt, MsgType, Ping, Status, decode
from simple_message.capture import (
    CapturedMessage,
    CaptureError,
    CaptureEvent,
    EventKind,
    TcpSegment,
    capture_format,
    captured_messages,
    format_address,
    read_capture,
)
from simple_message.cli import main

from .refdata import DATA, load_segments

FS100 = DATA / "motoman_fs100_simple_move.pcapng"
T0 = 1_700_000_000.0

Address = tuple[str, int]
CLIENT: Address = ("10.0.0.2", 40000)
SERVER: Address = ("10.0.0.1", 11000)
SYN, ACK, FIN, RST, PSH = dpkt.tcp.TH_SYN, dpkt.tcp.TH_ACK, dpkt.tcp.TH_FIN, dpkt.tcp.TH_RST, dpkt.tcp.TH_PUSH
#: LINKTYPE_RAW and LINKTYPE_LOOP as in files (dpkt's DLT_RAW and DLT_LOOP are the platform's DLT values)
RAW, LOOP = 101, 108


# -- building captures ------------------------------------------------------------------------------


def ip_packet(
    src: Address, dst: Address, seq: int, ack: int = 0, flags: int = PSH | ACK, payload: bytes = b""
) -> bytes:
    """An IPv4 or IPv6 packet carrying one TCP segment, built with dpkt."""
    seq, ack = seq & 0xFFFFFFFF, ack & 0xFFFFFFFF
    tcp = dpkt.tcp.TCP(sport=src[1], dport=dst[1], seq=seq, ack=ack, flags=flags, win=65535, data=payload)
    if ":" in src[0]:
        ip6 = dpkt.ip6.IP6(
            src=socket.inet_pton(socket.AF_INET6, src[0]),
            dst=socket.inet_pton(socket.AF_INET6, dst[0]),
            nxt=dpkt.ip.IP_PROTO_TCP,
            hlim=64,
            data=tcp,
        )
        ip6.plen = len(bytes(tcp))
        return bytes(ip6)
    ip = dpkt.ip.IP(src=socket.inet_aton(src[0]), dst=socket.inet_aton(dst[0]), p=dpkt.ip.IP_PROTO_TCP, data=tcp)
    ip.len = len(ip)
    return bytes(ip)


def link_frame(packet: bytes, link: int) -> bytes:
    """``packet`` (IPv4 or IPv6) under the link-layer header of ``link``."""
    v6 = packet[0] >> 4 == 6
    ethertype = dpkt.ethernet.ETH_TYPE_IP6 if v6 else dpkt.ethernet.ETH_TYPE_IP
    if link == dpkt.pcap.DLT_EN10MB:
        return bytes(dpkt.ethernet.Ethernet(src=b"\x02" * 6, dst=b"\x04" * 6, type=ethertype, data=packet))
    if link == dpkt.pcap.DLT_LINUX_SLL:  # packet type, ARPHRD, address length, address, protocol
        return struct.pack(">HHH8sH", 0, 1, 6, b"\x02" * 6, ethertype) + packet
    if link == dpkt.pcap.DLT_LINUX_SLL2:  # protocol, reserved, ifindex, ARPHRD, packet type, address length, address
        return struct.pack(">HHiHBB8s", ethertype, 0, 1, 1, 0, 6, b"\x02" * 6) + packet
    if link in (RAW, 12, dpkt.pcap.DLT_IPV4, dpkt.pcap.DLT_IPV6):
        return packet
    if link == dpkt.pcap.DLT_NULL:  # the address family in the capturing host's byte order
        return struct.pack("=I", 30 if v6 else 2) + packet
    if link == LOOP:
        return struct.pack(">I", 24 if v6 else 2) + packet
    raise AssertionError(link)


Packets = Sequence[bytes | tuple[float, bytes]]


def timed(packets: Packets) -> list[tuple[float, bytes]]:
    """Packets with their times: as given, or 1 ms apart from T0."""
    return [p if isinstance(p, tuple) else (T0 + k * 0.001, p) for k, p in enumerate(packets)]


def write_capture(
    path: Path, packets: Packets, *, fmt: str = "pcapng", link: int = dpkt.pcap.DLT_EN10MB, nano: bool = False
) -> Path:
    """IP packets as a pcap or pcapng file (dpkt's writers), under the link type's header."""
    with path.open("wb") as f:
        writer = (
            dpkt.pcapng.Writer(f, snaplen=262144, linktype=link)
            if fmt == "pcapng"
            else dpkt.pcap.Writer(f, snaplen=262144, linktype=link, nano=nano)
        )
        for t, packet in timed(packets):
            writer.writepkt(link_frame(packet, link), t)
    return path


class Conversation:
    """Both directions of one TCP connection, as IP packets (sequence numbers kept here)."""

    def __init__(
        self, client: Address = CLIENT, server: Address = SERVER, client_isn: int = 1000, server_isn: int = 700_000
    ) -> None:
        self.end = {True: client, False: server}  # by from_client
        self.seq = {True: client_isn, False: server_isn}

    def handshake(self) -> list[bytes]:
        c, s = self.seq[True], self.seq[False]
        packets = [
            ip_packet(self.end[True], self.end[False], c, 0, SYN),
            ip_packet(self.end[False], self.end[True], s, c + 1, SYN | ACK),
            ip_packet(self.end[True], self.end[False], c + 1, s + 1, ACK),
        ]
        self.seq[True] += 1
        self.seq[False] += 1
        return packets

    def send(self, from_client: bool, payload: bytes, *, seq: int | None = None, flags: int = PSH | ACK) -> bytes:
        """A segment with ``payload`` at the next sequence number (or at ``seq``, which then does not advance)."""
        at = self.seq[from_client] if seq is None else seq
        packet = ip_packet(
            self.end[from_client], self.end[not from_client], at, self.seq[not from_client], flags, payload
        )
        if seq is None:
            self.seq[from_client] += len(payload) + (1 if flags & FIN else 0)
        return packet

    def ack(self, from_client: bool, upto: int | None = None) -> bytes:
        """A pure ACK from one side, of everything the other sent (or up to ``upto``)."""
        acked = self.seq[not from_client] if upto is None else upto
        return ip_packet(self.end[from_client], self.end[not from_client], self.seq[from_client], acked, ACK)

    def fin(self, from_client: bool) -> bytes:
        return self.send(from_client, b"", flags=FIN | ACK)


def frames(n: int, start: int = 0) -> list[bytes]:
    """``n`` distinct little-endian frames: JOINT_TRAJ_PT requests, sequence start..start+n-1."""
    return [JointTrajPt(k, [0.1 * k] * 6, 0.5, 1.0).encode(LE32) for k in range(start, start + n)]


def messages(items: Iterable[CapturedMessage | CaptureEvent]) -> list[CapturedMessage]:
    return [i for i in items if isinstance(i, CapturedMessage)]


def events(items: Iterable[CapturedMessage | CaptureEvent]) -> list[CaptureEvent]:
    return [i for i in items if isinstance(i, CaptureEvent)]


def decoded(path: Path, **options: object) -> list[CapturedMessage | CaptureEvent]:
    return list(captured_messages(path, LE32, **options))  # type: ignore[arg-type]


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[dict], list[str]]:  # type: ignore[type-arg]
    """The command in process: exit status, stdout's JSON objects, stderr's lines."""
    code = main(argv)
    out, err = capsys.readouterr()
    return code, [json.loads(line) for line in out.splitlines()], err.splitlines()


# -- the FS100 capture: the same 164 messages as its segments file ----------------------------------------


def _expected_fs100() -> list[tuple[float, int, int, bytes]]:
    """(time, src_port, dst_port, frame) of the segments file, per direction through FrameDecoder."""
    decoders: dict[tuple[int, int], FrameDecoder] = {}
    out = []
    for t, src, dst, payload in load_segments():
        decoder = decoders.setdefault((src, dst), FrameDecoder(ByteOrder.BIG))
        decoder.feed(payload)
        out += [(t, src, dst, frame) for frame in decoder]
    return out


def test_fs100_capture_decodes_to_the_segment_files_messages() -> None:
    expected = _expected_fs100()
    assert len(expected) == 164
    items = list(captured_messages(FS100, BE32, auto=True))
    got = messages(items)
    assert events(items) == [] and len(got) == 164
    assert all(m.error is None for m in got)
    for direction in {(src, dst) for _, src, dst, _ in expected}:
        want = [(t, frame) for t, src, dst, frame in expected if (src, dst) == direction]
        have = [m for m in got if (m.src[1], m.dst[1]) == direction]
        assert [m.frame for m in have] == [frame for _, frame in want]
        assert [m.message for m in have] == [decode(frame, BE32) for _, frame in want]
        first = got[0].time_ns
        assert [(m.time_ns - first) / 1e9 for m in have] == pytest.approx([t for t, _ in want], abs=1e-6)
    # in capture order overall too, with the controller's addresses
    assert [(m.src[1], m.dst[1], m.frame) for m in got] == [(s, d, f) for _, s, d, f in expected]
    assert got[0].src == ("192.168.245.156", 50241) and got[0].time == 1431715297.100403


def test_fs100_capture_autodetects_big_endian_and_reads_its_segments() -> None:
    got = messages(captured_messages(FS100))  # default: little-endian float32, autodetected per direction
    assert len(got) == 164 and all(m.message is not None for m in got)
    segments = [s for s in read_capture(FS100) if s.payload]
    assert [(s.src[1], s.dst[1], s.payload) for s in segments] == [(src, dst, p) for _, src, dst, p in load_segments()]
    assert isinstance(segments[0], TcpSegment) and segments[0].flags & ACK and segments[0].time == 1431715297.100403


def test_fs100_capture_on_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(["decode", "--byte-order", "auto", str(FS100)], capsys)
    assert code == 0 and err == [] and len(out) == 164
    assert out[0]["name"] == "JOINT_FEEDBACK" and out[0]["time"] == 1431715297.100403
    assert out[0]["src"] == "192.168.245.156:50241" and out[0]["dst"] == "10.116.249.229:55753"
    assert out[0]["names"]["valid_fields"] == "POSITION"
    code, out, _ = run_cli(
        ["decode", "--byte-order", "big", "--port", "50240", "--type", "moto_motion_reply", str(FS100)], capsys
    )
    assert code == 0 and len(out) == 60 and {o["msg_type"] for o in out} == {MsgType.MOTO_MOTION_REPLY}
    code, out, _ = run_cli(["decode", "--byte-order", "big", "--type", "13", "--type", "STATUS", str(FS100)], capsys)
    assert code == 0 and len(out) == 22


# -- synthesised captures: formats and link types ------------------------------------------------------------


@pytest.mark.parametrize(
    ("fmt", "link"),
    [
        ("pcapng", dpkt.pcap.DLT_EN10MB),
        ("pcap", dpkt.pcap.DLT_EN10MB),
        ("pcap", dpkt.pcap.DLT_LINUX_SLL),
        ("pcapng", dpkt.pcap.DLT_LINUX_SLL2),
        ("pcap", RAW),
        ("pcap", 12),
        ("pcapng", dpkt.pcap.DLT_IPV4),
        ("pcap", dpkt.pcap.DLT_NULL),
        ("pcapng", LOOP),
    ],
)
def test_in_order_both_directions(tmp_path: Path, fmt: str, link: int) -> None:
    conv = Conversation()
    requests, replies = frames(3), [JointTrajPt(k, comm_type=3, reply_code=1).encode(LE32) for k in range(3)]
    packets = conv.handshake()
    for request, reply in zip(requests, replies, strict=True):
        packets += [conv.send(True, request), conv.send(False, reply)]
    packets += [conv.fin(True), conv.fin(False), conv.ack(True)]
    items = decoded(write_capture(tmp_path / f"c.{fmt}", packets, fmt=fmt, link=link))
    assert events(items) == []
    got = messages(items)
    assert [m.frame for m in got] == [f for pair in zip(requests, replies, strict=True) for f in pair]
    assert [(m.src, m.dst) for m in got[:2]] == [(CLIENT, SERVER), (SERVER, CLIENT)]
    assert all(m.client == CLIENT for m in got)
    assert got[0].message == JointTrajPt(0, [0.0] * 6, 0.5, 1.0)
    assert got[0].time == pytest.approx(T0 + 0.003, abs=1e-6)


def test_ipv6_and_vlan(tmp_path: Path) -> None:
    conv = Conversation(("fd00::2", 40000), ("fd00::1", 11000))
    packets = [*conv.handshake(), conv.send(True, frames(1)[0])]
    path = write_capture(tmp_path / "v6.pcapng", packets)
    (got,) = messages(decoded(path))
    assert got.src == ("fd00::2", 40000) and format_address(got.src) == "[fd00::2]:40000"
    # an 802.1Q tag between the Ethernet header and IPv4
    frame = link_frame(ip_packet(CLIENT, SERVER, 5, 0, PSH | ACK, frames(1)[0]), dpkt.pcap.DLT_EN10MB)
    tagged = frame[:12] + b"\x81\x00\x00\x07" + frame[12:]
    with (tmp_path / "vlan.pcap").open("wb") as f:
        dpkt.pcap.Writer(f).writepkt(tagged, T0)
    assert [m.frame for m in messages(decoded(tmp_path / "vlan.pcap"))] == frames(1)


def test_nanosecond_pcap_keeps_the_time_exact(tmp_path: Path) -> None:
    conv = Conversation()
    packet = link_frame(conv.send(True, frames(1)[0]), 1)
    for magic, order, record, extra in (
        (0xA1B23C4D, ">", ">IIII", b""),  # nanoseconds, big-endian
        (0xA1B23C4D, "<", "<IIII", b""),  # nanoseconds, little-endian
        (0xA1B2CD34, ">", ">IIII", bytes(8)),  # the modified format: microseconds, 24-byte records
    ):
        header = struct.pack(order + "IHHiIII", magic, 2, 4, 0, 0, 262144, 1)
        fraction = 123456789 if magic == 0xA1B23C4D else 123456
        path = tmp_path / "exact.pcap"
        path.write_bytes(
            header + struct.pack(record, 1_700_000_000, fraction, len(packet), len(packet)) + extra + packet
        )
        (got,) = messages(decoded(path))
        assert got.time_ns == (1_700_000_000_123_456_789 if magic == 0xA1B23C4D else 1_700_000_000_123_456_000)
        (segment,) = read_capture(path)
        assert segment.time_ns == got.time_ns and segment.seq == 1000 and segment.payload == frames(1)[0]
    assert got.time == 1_700_000_000.123456


def _block(order: str, kind: int, body: bytes) -> bytes:
    body += b"\0" * (-len(body) % 4)
    return struct.pack(order + "II", kind, 12 + len(body)) + body + struct.pack(order + "I", 12 + len(body))


def _option(order: str, code: int, value: bytes) -> bytes:
    return struct.pack(order + "HH", code, len(value)) + value + b"\0" * (-len(value) % 4)


def _section(order: str, interfaces: list[tuple[int, bytes]], packets: list[tuple[int, int, bytes]]) -> bytes:
    """A pcapng section by hand: interfaces (link type, options), packets (interface, raw timestamp, data)."""
    out = _block(order, 0x0A0D0D0A, struct.pack(order + "IHHq", 0x1A2B3C4D, 1, 0, -1))
    for link, options in interfaces:
        out += _block(order, 1, struct.pack(order + "HHI", link, 0, 0) + options)
    for iface, ts, data in packets:
        out += _block(
            order, 6, struct.pack(order + "IIIII", iface, ts >> 32, ts & 0xFFFFFFFF, len(data), len(data)) + data
        )
    return out


def test_pcapng_sections_byte_orders_interfaces_and_resolutions(tmp_path: Path) -> None:
    conv = Conversation()
    one, two, three = frames(3)
    ns = 1_700_000_000_123_456_789
    big = _section(
        ">",
        [(1, _option(">", 9, b"\x09") + _option(">", 0, b""))],  # Ethernet, nanoseconds
        [(0, ns, link_frame(conv.send(True, one), 1))],
    )
    little = _section(
        "<",
        [
            (1, b""),  # Ethernet, microseconds (the default)
            (101, _option("<", 9, b"\x83") + _option("<", 14, struct.pack("<q", 10)) + _option("<", 0, b"")),
        ],  # raw IP, 1/8 s, 10 s offset
        [
            (1, 8 * 1_700_000_000 + 3, conv.send(True, two[:30])),
            (0, 1_700_000_001_000_000, link_frame(conv.send(True, two[30:] + three), 1)),
        ],
    )
    path = tmp_path / "sections.pcapng"
    path.write_bytes(big + little)
    got = messages(decoded(path))
    assert [m.frame for m in got] == [one, two, three]
    assert got[0].time_ns == ns
    assert got[1].time_ns == 1_700_000_001_000_000_000
    assert [s.time_ns for s in read_capture(path)][1] == 1_700_000_010_375_000_000


# -- reassembly ----------------------------------------------------------------------------------------------


def test_out_of_order_segments_wait_for_the_gap_to_fill(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c = frames(3)
    split = b + c  # one frame across segments, delivered last-first
    packets = conv.handshake()
    pa = conv.send(True, a)
    pb1 = conv.send(True, split[:20])
    pb2 = conv.send(True, split[20:70])
    pb3 = conv.send(True, split[70:])
    items = decoded(write_capture(tmp_path / "ooo.pcapng", [*packets, pb3, pa, pb2, pb1, conv.fin(True)]))
    assert events(items) == []
    assert [m.frame for m in messages(items)] == [a, b, c]


def test_sequence_numbers_wrap(tmp_path: Path) -> None:
    conv = Conversation(client_isn=0xFFFFFFFF - 70)
    a, b, c = frames(3)
    packets = conv.handshake()
    first, second, third = conv.send(True, a), conv.send(True, b), conv.send(True, c)  # b crosses 2**32
    assert conv.seq[True] > 1 << 32
    items = decoded(write_capture(tmp_path / "wrap.pcapng", [*packets, first, third, second, second, conv.ack(False)]))
    assert events(items) == [] and [m.frame for m in messages(items)] == [a, b, c]


def test_duplicates_and_overlapping_retransmissions_are_dropped(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c = frames(3)
    packets = conv.handshake()
    start = conv.seq[True]
    packets += [conv.send(True, a), conv.send(True, a, seq=start)]  # a retransmission
    packets.append(conv.send(True, (a + b)[30:], seq=start + 30))  # overlaps a's end, carries b
    conv.seq[True] = start + len(a + b)
    packets += [conv.send(True, c), conv.send(True, c[:10], seq=start + len(a + b)), conv.ack(False)]
    items = decoded(write_capture(tmp_path / "dup.pcapng", packets))
    assert events(items) == [] and [m.frame for m in messages(items)] == [a, b, c]


def test_a_lost_segment_is_reported_and_the_rest_decodes(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c, d = frames(4)
    packets = [*conv.handshake(), conv.send(True, a)]
    start = conv.seq[True]
    conv.send(True, b)  # lost: never in the capture
    packets += [conv.send(True, c), conv.send(True, d)]
    items = decoded(write_capture(tmp_path / "lost.pcapng", packets))  # no ACK: given up at the end of the capture
    (gap,) = events(items)
    assert gap.kind is EventKind.GAP and gap.src == CLIENT and gap.dst == SERVER
    assert (gap.start, gap.end) == (len(a), len(a) + len(b))
    assert f"seq {start}..{start + len(b)}" in gap.message
    assert [m.frame for m in messages(items)] == [a, c, d]
    assert items.index(gap) == 1  # reported before what comes after it


def test_an_acknowledged_gap_is_given_up_at_once(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c, d = frames(4)
    packets = [*conv.handshake(), conv.send(True, a), conv.send(True, b[:40])]
    conv.send(True, b[40:])  # lost by the capture, received by the server
    packets += [conv.send(True, c), conv.ack(False), conv.send(True, d)]
    items = decoded(write_capture(tmp_path / "acked.pcapng", packets))
    kinds = [i.kind if isinstance(i, CaptureEvent) else i.message.sequence for i in items]  # type: ignore[union-attr]
    assert kinds == [0, EventKind.GAP, 2, 3]  # c decoded at the ACK, before d arrives
    gap = events(items)[0]
    assert "the 40 bytes of an incomplete frame before them are dropped" in gap.message


def test_a_gap_that_breaks_the_framing_is_a_frame_error_until_the_next_gap(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c, d = frames(4)
    packets = [*conv.handshake(), conv.send(True, a)]
    conv.send(True, b[:40])  # lost
    packets.append(conv.send(True, b"\xff\xff\xff\xff" + b[44:] + c))  # resumes mid-frame: garbage length
    conv.send(True, d[:10])  # lost
    packets += [conv.send(True, d[10:]), conv.send(True, frames(1, 7)[0])]
    items = decoded(write_capture(tmp_path / "misframe.pcapng", packets))
    assert [i.kind for i in events(items)] == [
        EventKind.GAP,
        EventKind.FRAME_ERROR,
        EventKind.GAP,
        EventKind.FRAME_ERROR,
    ]
    assert [m.frame for m in messages(items)] == [a]


def test_a_stream_without_syn_starts_at_its_first_segment(tmp_path: Path) -> None:
    conv = Conversation()
    a, b = frames(2)
    items = decoded(
        write_capture(tmp_path / "mid.pcap", [conv.ack(False), conv.send(True, a), conv.send(True, b)], fmt="pcap")
    )
    got = messages(items)
    assert events(items) == [] and [m.frame for m in got] == [a, b] and got[0].client is None


def test_a_stream_without_syn_whose_first_segments_came_swapped_says_so(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c = frames(3)
    first, second, third = conv.send(True, a), conv.send(True, b), conv.send(True, c)
    items = decoded(write_capture(tmp_path / "swapped.pcap", [second, first, third], fmt="pcap"))
    # the stream is taken to begin with b: a came late, reported (never silently lost), b and c decode
    assert [m.frame for m in messages(items)] == [b, c]
    [event] = events(items)
    assert event.kind is EventKind.GAP and "came after later ones" in event.message and event.start == -len(a)


def test_two_connections_interleaved(tmp_path: Path) -> None:
    one = Conversation()
    two = Conversation(("10.0.0.3", 40001), ("10.0.0.1", 11002), 50, 60)
    first, second = frames(2), [Status().encode(LE32), Status(1, 1, 0, 0, 1, 2, 1).encode(LE32)]
    packets = [*one.handshake(), *two.handshake()]
    for x, y in zip(first, second, strict=True):
        packets += [one.send(True, x[:25]), two.send(False, y[:7]), one.send(True, x[25:]), two.send(False, y[7:])]
    items = decoded(write_capture(tmp_path / "two.pcapng", packets))
    got = messages(items)
    assert events(items) == []
    assert [m.frame for m in got if m.dst == SERVER] == first
    assert [m.frame for m in got if m.src == ("10.0.0.1", 11002)] == second
    assert {m.client for m in got} == {CLIENT, ("10.0.0.3", 40001)}


def test_a_truncated_frame_at_fin_and_a_gap_at_rst(tmp_path: Path) -> None:
    conv = Conversation()
    a, b = frames(2)
    packets = [*conv.handshake(), conv.send(True, a + b[:10]), conv.fin(True)]
    other = Conversation(("10.0.0.9", 41000))
    packets += other.handshake()
    packets.append(other.send(False, a))
    other.send(False, b)  # lost
    packets += [other.send(False, Ping().encode(LE32)), other.send(True, b"", flags=RST | ACK)]
    packets.append(other.send(False, a))  # after the reset: ignored
    items = decoded(write_capture(tmp_path / "end.pcapng", packets))
    kinds = [(i.kind, i.src) if isinstance(i, CaptureEvent) else i.frame for i in items]
    assert kinds == [
        a,
        (EventKind.TRUNCATED_FRAME, CLIENT),
        a,
        (EventKind.GAP, SERVER),
        Ping().encode(LE32),
    ]
    assert (
        events(items)[0].message == "10 bytes at the end of 10.0.0.2:40000 -> 10.0.0.1:11000 do not make a whole frame"
    )


def test_bytes_lost_at_the_end_are_reported_when_a_later_segment_shows_them(tmp_path: Path) -> None:
    conv = Conversation()
    a, b = frames(2)
    packets = [*conv.handshake(), conv.send(True, a + b[:20])]
    conv.send(True, b[20:])  # lost, and nothing after it but the FIN
    packets.append(conv.fin(True))
    items = decoded(write_capture(tmp_path / "tail.pcapng", packets))
    assert [i.kind if isinstance(i, CaptureEvent) else i.frame for i in items] == [a, EventKind.GAP]
    gap = events(items)[0]
    assert (gap.start, gap.end) == (len(a) + 20, len(a) + len(b))
    assert "nothing of this direction after them was captured" in gap.message
    assert "the 20 bytes of an incomplete frame before them are dropped" in gap.message


def test_a_new_syn_on_the_same_ports_is_a_new_connection(tmp_path: Path) -> None:
    old, new = Conversation(), Conversation(client_isn=90_000, server_isn=3)
    a, b = frames(2)
    packets = [*old.handshake(), old.send(True, a[:9]), *new.handshake(), new.send(True, b)]
    items = decoded(write_capture(tmp_path / "reuse.pcapng", packets))
    assert [i.kind if isinstance(i, CaptureEvent) else i.frame for i in items] == [EventKind.TRUNCATED_FRAME, b]


def test_the_reorder_buffer_is_bounded(tmp_path: Path) -> None:
    conv = Conversation()
    a, b, c, d = frames(4)
    packets = [*conv.handshake(), conv.send(True, a)]
    conv.send(True, b)  # lost
    packets += [conv.send(True, c), conv.send(True, d)]
    items = decoded(write_capture(tmp_path / "bounded.pcapng", packets), reorder_limit=len(c))
    assert [i.kind if isinstance(i, CaptureEvent) else i.frame for i in items] == [
        a,
        EventKind.REORDER_OVERFLOW,
        EventKind.GAP,
        c,
        d,
    ]


def test_filters_and_unsupported_link_types(tmp_path: Path) -> None:
    one = Conversation()
    two = Conversation(("10.0.0.3", 40001), ("10.0.0.1", 11002))
    status = Status().encode(LE32)
    packets = [one.send(True, frames(1)[0] + status), two.send(False, status + frames(1, 5)[0])]
    path = write_capture(tmp_path / "f.pcapng", packets)
    assert [m.src for m in messages(decoded(path, ports=[11002]))] == [("10.0.0.1", 11002)] * 2
    assert [m.frame for m in messages(decoded(path, types={MsgType.STATUS}))] == [status, status]
    assert messages(decoded(path, ports=[1], types=[13])) == []
    with (tmp_path / "wifi.pcap").open("wb") as f:
        dpkt.pcap.Writer(f, linktype=dpkt.pcap.DLT_IEEE802_11).writepkt(b"\0" * 40, T0)
    (event,) = decoded(tmp_path / "wifi.pcap")
    assert isinstance(event, CaptureEvent) and event.kind is EventKind.UNSUPPORTED_LINK_TYPE
    assert event.message.startswith("1 packets of link type 105 were skipped")


def test_a_malformed_body_is_a_message_with_its_error(tmp_path: Path) -> None:
    bad = bytes.fromhex("130000000b0000000200000000000000") + bytes(7)  # JOINT_TRAJ_PT with a 7-byte body
    conv = Conversation()
    (got,) = decoded(write_capture(tmp_path / "bad.pcapng", [conv.send(True, bad)]))
    assert isinstance(got, CapturedMessage) and got.message is None and got.error is not None and got.frame == bad


# -- broken files -------------------------------------------------------------------------------------------


def _good_pcap(tmp_path: Path) -> bytes:
    return write_capture(tmp_path / "good.pcap", [Conversation().send(True, frames(1)[0])], fmt="pcap").read_bytes()


def _good_pcapng(tmp_path: Path) -> bytes:
    return write_capture(tmp_path / "good.pcapng", [Conversation().send(True, frames(1)[0])]).read_bytes()


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (lambda g, n: b"\xd4\xc3\xb2\xa1", "truncated: the pcap file header"),
        (lambda g, n: g[:24] + b"\xff" * 40, "malformed: a packet record of"),
        (lambda g, n: g[:-5], "truncated: the last packet record has"),
        (lambda g, n: g[:30], "truncated: the last packet record's header"),
        (lambda g, n: n[:10], "truncated: the last block's header"),
        (lambda g, n: n[:20], "truncated: the last block (type 0xa0d0d0a) has 20 of its 28 bytes"),
        (lambda g, n: n[:28] + b"\xff" * 64, "impossible length"),
        (lambda g, n: n[:-3], "truncated: the last block (type 0x6)"),
        (lambda g, n: n.replace(b"\x4d\x3c\x2b\x1a", b"\0\0\0\0", 1), "byte-order magic"),
    ],
)
def test_a_broken_capture_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make: object, problem: str
) -> None:
    path = tmp_path / "broken.cap"
    path.write_bytes(make(_good_pcap(tmp_path), _good_pcapng(tmp_path)))  # type: ignore[operator]
    with pytest.raises(CaptureError, match=problem.replace("(", r"\(").replace(")", r"\)")) as info:
        list(captured_messages(path))
    assert str(path) in str(info.value)
    code, _, err = run_cli(["decode", str(path)], capsys)
    assert code == 1 and len(err) == 1, err
    error = json.loads(err[0])
    assert error["type"] == "CaptureError" and problem in error["error"] and str(path) in error["error"]


def test_other_malformed_pcapng_blocks(tmp_path: Path) -> None:
    conv = Conversation()
    packet = link_frame(conv.send(True, frames(1)[0]), 1)
    no_interface = _section("<", [], [(0, 1, packet)])
    path = tmp_path / "noif.pcapng"
    path.write_bytes(no_interface)
    with pytest.raises(CaptureError, match="interface 0, which no interface block describes"):
        list(captured_messages(path))
    mismatched = bytearray(_section("<", [(1, b"")], [(0, 1, packet)]))
    mismatched[-1] ^= 0x01  # the trailing copy of the last block's length
    path.write_bytes(bytes(mismatched))
    with pytest.raises(CaptureError, match="length fields disagree"):
        list(captured_messages(path))


def test_not_a_capture() -> None:
    assert capture_format(b"\x0a\x0d\x0d\x0a") == "pcapng" and capture_format(b"\xa1\xb2\x3c\x4d") == "pcap"
    assert capture_format(b"0c00") is None
    with pytest.raises(CaptureError, match="not a pcap or pcapng capture"):
        list(captured_messages(io.BytesIO(b"hello")))
    with pytest.raises(CaptureError, match="begins with nothing"):
        list(read_capture(io.BytesIO(b"")))


# -- the command ---------------------------------------------------------------------------------------------


def test_decode_capture_reports_gaps_and_goes_on(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conv = Conversation(("fd00::2", 40000), ("fd00::1", 11000))
    a, b, c = frames(3)
    packets = [*conv.handshake(), conv.send(True, a)]
    conv.send(True, b)  # lost
    packets.append(conv.send(True, c))
    path = write_capture(tmp_path / "gap.pcap", packets, fmt="pcap")
    code, out, err = run_cli(["decode", str(path)], capsys)
    assert code == 1
    assert [o["body"]["sequence"] for o in out] == [0, 2]
    assert out[0]["src"] == "[fd00::2]:40000" and out[0]["dst"] == "[fd00::1]:11000"
    assert out[0]["time"] == pytest.approx(T0 + 0.003, abs=1e-6)
    (gap,) = [json.loads(line) for line in err]
    assert gap["type"] == "Gap" and (gap["start"], gap["end"]) == (len(a), len(a) + len(b))
    assert gap["src"] == "[fd00::2]:40000" and "missing from the capture" in gap["error"]


def test_decode_capture_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    path = write_capture(tmp_path / "c.pcapng", [Conversation().send(True, frames(1)[0] + Status().encode(LE32))])
    code, out, _ = run_cli(["decode", "--type", "joint_traj_pt", str(path)], capsys)
    assert code == 0 and [o["name"] for o in out] == ["JOINT_TRAJ_PT"]
    code, out, _ = run_cli(["decode", "--port", "11000", "--type", "0x0d", str(path)], capsys)
    assert code == 0 and [o["name"] for o in out] == ["STATUS"]
    code, out, err = run_cli(["decode", "--type", "NO_SUCH_TYPE", str(path)], capsys)
    assert code == 2 and out == [] and json.loads(err[0])["type"] == "UsageError"
    hexfile = tmp_path / "frames.txt"
    hexfile.write_text(frames(1)[0].hex())
    code, out, err = run_cli(["decode", "--port", "11000", str(hexfile)], capsys)
    assert code == 2 and "captures only" in json.loads(err[0])["error"]
    # --raw and stdin never look for a capture
    code, out, err = run_cli(["decode", "--raw", str(path)], capsys)
    assert code == 1 and out == [] and json.loads(err[0])["type"] == "FrameError"
    monkeypatch.setattr(sys, "stdin", io.StringIO(frames(1)[0].hex()))
    code, out, err = run_cli(["decode"], capsys)
    assert code == 0 and len(out) == 1
    with pytest.raises(SystemExit):
        main(["decode", "--port", "0", str(path)])
    assert "a port is 1..65535" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        ("x.pcapng.gz", b"\x1f\x8b\x08\x00" + bytes(40), "gzip-compressed"),
        ("empty.pcapng", b"", "an empty file"),
        ("short.pcapng", b"\x0a\x0d\x0d", "not a pcap or pcapng capture"),
        ("x.bin", bytes(range(256)) * 4, "a binary file"),
    ],
)
def test_a_file_that_is_no_capture_and_no_text_is_one_line_of_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, content: bytes, words: str
) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    assert main(["decode", str(path)]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1 and words in captured.err
