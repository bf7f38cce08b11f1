"""Frame decoder: fragmentation, coalescing, bad lengths and byte-order detection (docs/reference/protocol.md §12)."""

from __future__ import annotations

import struct

import pytest

from simple_message import (
    BE32,
    BE64,
    DEFAULT_MAX_LENGTH,
    LE32,
    LE64,
    CommType,
    FrameDecoder,
    FrameError,
    HeaderOnly,
    JointFeedback,
    JointTraj,
    JointTrajPt,
    JointTrajPtFull,
    MalformedMessage,
    Message,
    MsgType,
    Ping,
    RawMessage,
    ReplyCode,
    Status,
    TrajPoint,
    TriState,
    WireFormat,
    decode,
    detect_byte_order,
    encode,
)
from simple_message.wire import ByteOrder

from .test_sm_conformance import V4, words

V8 = words("0000000C 0000000B 00000003 00000001")
V11 = words("0000000C 0000270F 00000003 00000002")
V12 = words("00000028 0000000D 00000001 00000000 00000001 FFFFFFFF 00000000 00000000 00000000 00000002 00000001")
V13 = words("00000038 0000000A 00000001 00000000 00000000") + bytes(40)


@pytest.mark.parametrize("chunk", [1, 3, 10, 54])
def test_split_frame_gives_exactly_one_message(chunk: int) -> None:
    dec = FrameDecoder(ByteOrder.BIG)
    frames = []
    for i in range(0, len(V4), chunk):
        dec.feed(V4[i : i + chunk])
        frames.extend(dec)
    assert frames == [V4]
    assert dec.buffered == 0


def test_coalesced_frames() -> None:
    dec = FrameDecoder(ByteOrder.BIG)
    dec.feed(V8 + V11)
    assert list(dec) == [V8, V11]


def test_three_and_a_half_frames_then_the_rest() -> None:
    dec = FrameDecoder(ByteOrder.BIG)
    dec.feed(V12 * 3 + V13[:30])
    assert list(dec) == [V12] * 3
    assert dec.buffered == 30
    dec.feed(V13[30:])
    assert list(dec) == [V13]
    assert next(type(decode(f, BE32)) for f in (V12, V13)) is Status


@pytest.mark.parametrize("length", [0, 1, 11, -1, -(2**31), DEFAULT_MAX_LENGTH + 1, 2**31 - 1])
def test_bad_length_prefix_is_a_fatal_frame_error(length: int) -> None:
    dec = FrameDecoder(ByteOrder.LITTLE)
    good = Status().encode(LE32)
    dec.feed(good + struct.pack("<i", length) + bytes(64))
    assert dec.next_frame() == good  # frames before the error are still delivered
    with pytest.raises(FrameError) as info:
        dec.next_frame()
    assert info.value.fatal and info.value.length == length
    assert dec.failed and dec.buffered == 0
    dec.feed(bytes(1000))  # ignored once failed: nothing is buffered
    assert dec.buffered == 0
    with pytest.raises(FrameError):
        dec.next_frame()


def test_configurable_maximum_for_cpp_peers() -> None:
    dec = FrameDecoder(ByteOrder.LITTLE, max_length=1019)
    dec.feed(struct.pack("<i", 1020))
    with pytest.raises(FrameError, match="exceeds the maximum of 1019"):
        dec.next_frame()


def test_huge_announced_length_is_rejected_before_buffering() -> None:
    dec = FrameDecoder(ByteOrder.BIG)
    dec.feed(words("7FFFFFFF"))
    with pytest.raises(FrameError):
        dec.next_frame()
    assert dec.buffered == 0


def test_incomplete_frame_never_exceeds_one_maximum_frame() -> None:
    dec = FrameDecoder(ByteOrder.LITTLE, max_length=1000)
    dec.feed(struct.pack("<iiii", 1000, 9999, 1, 0))
    for _ in range(246):
        dec.feed(bytes(4))
        assert dec.buffered <= 1004
        assert dec.next_frame() is None
    dec.feed(bytes(4))  # 16 + 247 * 4 = 4 + 1000 bytes complete the frame
    assert dec.buffered == 0
    assert dec.next_frame() is not None


@pytest.mark.parametrize("cut", range(1, 68))
def test_truncated_frames_wait_for_more_data(cut: int) -> None:
    dec = FrameDecoder(ByteOrder.BIG)
    dec.feed(V4[:cut])
    assert dec.next_frame() is None
    assert dec.buffered == cut


def test_decode_rejects_a_frame_whose_prefix_disagrees_with_its_size() -> None:
    with pytest.raises(MalformedMessage):
        decode(V4[:-4], BE32)
    with pytest.raises(MalformedMessage):
        decode(V4[:10], BE32)


def test_known_type_with_a_body_that_fits_no_layout_is_malformed_not_fatal() -> None:
    frame = struct.pack(">iiii", 12 + 7, 11, 2, 0) + bytes(7)
    dec = FrameDecoder(ByteOrder.BIG)
    dec.feed(frame + V8)
    bad = dec.next_frame()
    assert bad == frame
    with pytest.raises(MalformedMessage) as info:
        decode(bad, BE32)
    assert info.value.msg_type == 11 and info.value.comm_type == 2 and not info.value.fatal
    assert info.value.reply_code == 2  # FAILURE
    assert dec.next_frame() == V8  # the stream stays aligned


def test_byte_order_autodetection() -> None:
    le = V4[:0] + Status().encode(LE32)
    assert detect_byte_order(le) is ByteOrder.LITTLE
    assert detect_byte_order(V4) is ByteOrder.BIG
    # §12 test 11: V5 read as big-endian gives a length of 0x40000000, a mismatch to flag.
    assert struct.unpack(">i", words("40000000"))[0] > 0xFFFF
    with pytest.raises(FrameError, match="cannot detect"):
        detect_byte_order(words("00000000"))
    dec = FrameDecoder(None)
    assert dec.byte_order is None
    dec.feed(le[:2])
    assert dec.byte_order is None
    dec.feed(le[2:] + le)
    assert dec.byte_order is ByteOrder.LITTLE and dec.detected
    assert list(dec) == [le, le]


def test_autodetection_failure_is_fatal() -> None:
    dec = FrameDecoder(None)
    dec.feed(words("FFFFFFFF 00000001"))
    with pytest.raises(FrameError):
        dec.next_frame()


# -- feed_messages: feed + decode in one pass ---------------------------------------------------


def _plain(dec: FrameDecoder, data: bytes, wire: WireFormat) -> list[Message | MalformedMessage]:
    """What feed_messages stands for: feed, then decode every frame (errors returned)."""
    dec.feed(data)
    out: list[Message | MalformedMessage] = []
    for frame in dec:
        try:
            out.append(decode(frame, wire))
        except MalformedMessage as exc:
            out.append(exc)
    return out


def keyed(items: list[Message | MalformedMessage]) -> list[object]:
    """Comparable: a MalformedMessage as its type, text and fields (exceptions compare by identity)."""
    return [
        (MalformedMessage, str(m), m.msg_type, m.comm_type, m.reply_code, m.frame)
        if isinstance(m, MalformedMessage)
        else (type(m), m)
        for m in items
    ]


def test_feed_messages_decodes_runs_and_their_ends() -> None:
    """Runs of one header (decoded in one loop) end at another body, comm_type, reply_code or
    length, and at a frame that is not complete yet."""
    msgs: list[Message] = [JointTrajPt(k, [k / 8], 0.5, 0.25) for k in range(5)]
    msgs += [JointTrajPt(5, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS), JointTrajPt(6)]
    msgs += [JointTrajPt(7, reply_code=ReplyCode.FAILURE), JointTrajPt(8, reply_code=ReplyCode.FAILURE)]
    msgs += [HeaderOnly(MsgType.JOINT_TRAJ_PT), JointTrajPt(9), Status(1, 0, 0, 0, 1, 2, 1), Status(), JointTrajPt(10)]
    stream = b"".join(m.encode(LE32) for m in msgs)
    for cut in (len(stream), 3, 68 * 2 + 5, 68 * 4 + 16, 68 * 4 + 17):
        dec = FrameDecoder()
        got = dec.feed_messages(stream[:cut], LE32)
        assert dec.buffered == cut - sum(len(m.encode(LE32)) for m in got if isinstance(m, Message))
        got += dec.feed_messages(stream[cut:], LE32)
        assert got == msgs and dec.buffered == 0 and dec.frames_decoded == len(msgs)
    decoded = FrameDecoder().feed_messages(stream, LE32)
    assert [type(m) for m in decoded] == [type(m) for m in msgs]
    assert decoded[5].comm_type is CommType.SERVICE_REPLY and decoded[7].reply_code is ReplyCode.FAILURE
    status = decoded[11]
    assert isinstance(status, Status) and status.drives_powered is TriState.TRUE


@pytest.mark.parametrize("wire", [LE32, BE32, LE64, BE64], ids=str)
def test_feed_messages_is_feed_and_decode_in_every_wire_format(wire: WireFormat) -> None:
    q = [0.1, -0.2, 0.3]
    msgs = [
        JointTrajPt(1, q, 0.5, 0.1),
        JointTrajPt(1, q, 0.5, 0.1),
        JointTrajPtFull(0, 7, 0x0F, 1.5, q, q, q),
        JointFeedback(0, 0x0E, 1.5, q, q, q),
        JointFeedback(0, 0x0E, 1.5, q, q, q),
        Ping(),
        RawMessage(65500, b"\x01\x02\x03", comm_type=1),  # an unknown type (65001/65002 are the extensions)
        JointTraj([TrajPoint(0, q, 0.5, 1.0)]),
    ]
    stream = b"".join(encode(m, wire) for m in msgs) * 3
    for size in (1, 7, 64, len(stream)):
        fast, plain = FrameDecoder(wire.byte_order), FrameDecoder(wire.byte_order)
        got, want = [], []
        for i in range(0, len(stream), size):
            got += fast.feed_messages(stream[i : i + size], wire)
            want += _plain(plain, stream[i : i + size], wire)
        assert keyed(got) == keyed(want) and len(got) == 3 * len(msgs)
        assert fast.frames_decoded == plain.frames_decoded and fast.buffered == 0


def test_feed_messages_header_only_frames() -> None:
    """Header-only frames (PING, acks) are decoded once per distinct frame and then reused: the
    same immutable message as decode gives."""
    frames = [Ping().encode(BE32), V8, V11, HeaderOnly(11, reply_code=2).encode(BE32), V8, Ping().encode(BE32)]
    dec = FrameDecoder(ByteOrder.BIG)
    for _ in range(2):
        got = dec.feed_messages(b"".join(frames), BE32)
        assert keyed(got) == keyed([decode(f, BE32) for f in frames])
    assert got[1] is got[4] and type(got[0]) is Ping and type(got[2]) is RawMessage


def test_feed_messages_returns_a_malformed_body_and_stays_aligned() -> None:
    frame = struct.pack(">iiii", 12 + 7, 11, 2, 0) + bytes(7)
    dec = FrameDecoder(ByteOrder.BIG)
    bad, ack = dec.feed_messages(frame + V8, BE32)
    assert isinstance(bad, MalformedMessage) and not bad.fatal
    assert (bad.msg_type, bad.comm_type, bad.reply_code, bad.frame) == (11, 2, 2, frame)
    assert ack == HeaderOnly(11, comm_type=3, reply_code=1)


@pytest.mark.parametrize("length", [0, 11, -1, DEFAULT_MAX_LENGTH + 1])
def test_feed_messages_after_a_bad_length_prefix(length: int) -> None:
    good = JointTrajPt(3).encode(LE32)
    dec = FrameDecoder(ByteOrder.LITTLE)
    got = dec.feed_messages(good * 2 + struct.pack("<i", length) + bytes(64), LE32)
    assert got == [JointTrajPt(3)] * 2 and dec.frames_decoded == 2
    assert dec.failed and isinstance(dec.error, FrameError) and dec.error.length == length
    assert dec.buffered == 0
    assert dec.feed_messages(good, LE32) == [] and dec.buffered == 0
    with pytest.raises(FrameError):
        dec.next_frame()


def test_feed_messages_checks_a_lone_length_prefix_and_the_maximum() -> None:
    dec = FrameDecoder(ByteOrder.LITTLE)
    assert dec.feed_messages(struct.pack("<i", 5), LE32) == [] and dec.failed  # 4 bytes are enough
    dec = FrameDecoder(ByteOrder.LITTLE, max_length=63)  # a JOINT_TRAJ_PT is 64
    assert dec.feed_messages(Status().encode(LE32) + JointTrajPt().encode(LE32), LE32) == [Status()]
    assert dec.error is not None and "exceeds the maximum of 63" in str(dec.error)


def test_feed_messages_detects_the_byte_order() -> None:
    stream = V12 + JointTrajPt(4).encode(BE32) * 2 + V13
    dec = FrameDecoder(None)
    got: list[Message | MalformedMessage] = []
    for i in range(len(stream)):  # byte by byte: detection waits for 4 bytes
        got += dec.feed_messages(stream[i : i + 1], LE32)
    assert dec.byte_order is ByteOrder.BIG and dec.detected
    assert got == [decode(V12, BE32), JointTrajPt(4), JointTrajPt(4), decode(V13, BE32)]
    dec = FrameDecoder(None)
    assert dec.feed_messages(words("FFFFFFFF 00000001"), LE32) == [] and dec.failed


def test_feed_messages_takes_frames_queued_by_feed_first() -> None:
    dec = FrameDecoder(ByteOrder.BIG)
    dec.feed(V8 + V11 + V12[:10])
    got = dec.feed_messages(V12[10:], BE32)
    assert got == [decode(V8, BE32), decode(V11, BE32), decode(V12, BE32)]
    assert dec.frames_decoded == 3 and dec.next_frame() is None


def test_feed_messages_decodes_in_the_wire_given_when_frames_are_cut_in_another_order() -> None:
    """A decoder that does not detect cuts in its own order; decoding follows the wire it is given
    (as feed + decode does, e.g. a Link whose wire was reassigned)."""
    stream = JointTrajPt(2).encode(LE32) + Status().encode(LE32)
    got = FrameDecoder(ByteOrder.LITTLE).feed_messages(stream, BE32)
    assert len(got) == 2 and keyed(got) == keyed(_plain(FrameDecoder(ByteOrder.LITTLE), stream, BE32))
