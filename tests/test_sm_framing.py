"""Frame decoder: fragmentation, coalescing, bad lengths and byte-order detection (simple-message.md §12)."""

from __future__ import annotations

import struct

import pytest

from simple_message import (
    BE32,
    DEFAULT_MAX_LENGTH,
    LE32,
    FrameDecoder,
    FrameError,
    MalformedMessage,
    Status,
    decode,
    detect_byte_order,
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
