"""Conformance with the reference C++ library's byte vectors and a real Yaskawa FS100 capture."""

from __future__ import annotations

import struct
from collections import Counter

import pytest

from simple_message import (
    BE32,
    LE32,
    CommType,
    FrameDecoder,
    HeaderOnly,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    MotoMotionReply,
    MsgType,
    RawMessage,
    ReplyCode,
    Status,
    decode,
    encode,
)
from simple_message.wire import ByteOrder, WireFormat

from .refdata import load_segments, load_vectors

F32 = struct.Struct("<f")


def f32(x: float) -> float:
    return float(F32.unpack(F32.pack(x))[0])


def expected(value: object) -> object:
    if isinstance(value, list):
        return [f32(v) for v in value]
    if isinstance(value, float):
        return f32(value)
    return value


FILES = [("vectors_le.txt", LE32), ("vectors_be.txt", BE32)]
CASES = [(fname, wire, v) for fname, wire in FILES for v in load_vectors(fname)]


def test_vector_files_are_complete() -> None:
    le = load_vectors("vectors_le.txt")
    be = load_vectors("vectors_be.txt")
    assert len(le) == len(be) == 26
    assert [v.name for v in le] == [v.name for v in be]


@pytest.mark.parametrize(("fname", "wire", "vector"), CASES, ids=[f"{c[0][8:10]}-{c[2].name}" for c in CASES])
def test_vector_decodes_to_the_library_values_and_reencodes(fname: str, wire: WireFormat, vector) -> None:  # type: ignore[no-untyped-def]
    msg = decode(vector.frame, wire)
    assert msg.msg_type == vector.msg_type
    assert msg.comm_type == vector.comm_type
    assert msg.reply_code == vector.reply_code
    assert len(vector.frame) - 16 == vector.body_size
    for key, value in vector.fields.items():
        got = getattr(msg, key)
        got = list(got) if isinstance(got, tuple) else got
        assert got == expected(value), key
    if vector.msg_type == MsgType.INVALID or vector.msg_type not in set(MsgType):
        assert isinstance(msg, RawMessage | HeaderOnly)
    assert encode(msg, wire) == vector.frame


def test_both_byte_orders_decode_to_the_same_messages() -> None:
    for le, be in zip(load_vectors("vectors_le.txt"), load_vectors("vectors_be.txt"), strict=True):
        assert decode(le.frame, LE32) == decode(be.frame, BE32), le.name


def test_unknown_type_failure_reply_is_header_only_raw() -> None:
    (vector,) = [v for v in load_vectors("vectors_le.txt") if v.name == "UNHANDLED_TYPE_9999_REPLY_FAILURE"]
    msg = decode(vector.frame, LE32)
    assert isinstance(msg, RawMessage)
    assert (msg.msg_type, msg.comm_type, msg.reply_code, msg.body) == (9999, 3, 2, b"")


# docs/reference/protocol.md §12: the hand-made vectors V1-V20 (hex in 4-byte words).
def words(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


V4 = words(
    "00000040 0000000B 00000002 00000000 00000001 3DCCCCCD 3E4CCCCD 3E99999A 3ECCCCCD 3F000000 3F19999A "
    "00000000 00000000 00000000 00000000 3F000000 40000000"
)
V14 = words(
    "00000040 0000000B 00000002 00000000 00000001 A7600000 3EA7CDE8 BF5D9E57 C0490FDB 3F34815F C0490FDB "
    "00000000 00000000 00000000 00000000 3DCCCCCD 40A00000"
)


def test_doc_vectors_v1_to_v20() -> None:
    be = WireFormat(ByteOrder.BIG)
    v1 = decode(words("0000000C 00000001 00000002 00000000"), be)
    assert v1.msg_type == MsgType.PING and v1.comm_type == CommType.SERVICE_REQUEST
    v4 = decode(V4, be)
    assert isinstance(v4, JointTrajPt)
    assert (v4.sequence, v4.velocity, v4.duration) == (1, 0.5, 2.0)
    assert v4.joint_data[:7] == tuple(f32(x) for x in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.0))
    assert encode(JointTrajPt(1, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 0.5, 2.0), be) == V4
    v5 = encode(v4, LE32)
    assert v5[:8] == words("40000000 0B000000")
    v6 = JointTrajPt(-4)
    assert encode(v6, be) == words("00000040 0000000B 00000002 00000000 FFFFFFFC") + bytes(48)
    v8 = decode(words("0000000C 0000000B 00000003 00000001"), be)
    assert v8 == HeaderOnly(11, reply_code=ReplyCode.SUCCESS)
    v9 = decode(V4[:8] + words("00000003 00000001") + V4[16:], be)
    assert isinstance(v9, JointTrajPt) and v9.comm_type == 3 and v9.reply_code == 1
    v10 = decode(words("00000038 0000000A 00000003 00000001 00000001") + bytes(40), be)
    assert v10 == JointPosition(1, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
    v11 = decode(words("0000000C 0000270F 00000003 00000002"), be)
    assert isinstance(v11, RawMessage) and v11.reply_code == ReplyCode.FAILURE
    v12 = decode(
        words("00000028 0000000D 00000001 00000000 00000001 FFFFFFFF 00000000 00000000 00000000 00000002 00000001"), be
    )
    assert v12 == Status(1, -1, 0, 0, 0, 2, 1)
    v14 = decode(V14, be)
    assert isinstance(v14, JointTrajPt)
    assert v14.sequence == 1 and v14.velocity == f32(0.1) and v14.duration == 5.0
    ref = [-3.1e-15, 0.32774, -0.86570, -3.14159, 0.70510, -3.14159, 0, 0, 0, 0]
    assert v14.joint_data == pytest.approx(ref, rel=1e-5, abs=1e-14)
    v15 = decode(
        words(
            "94000000 0E000000 02000000 00000000 00000000 00000000 07000000 00000000 "
            "CDCCCC3D CDCC4C3E 9A99993E CDCCCC3E 0000003F 9A99193F"
        )
        + bytes(96),
        LE32,
    )
    assert isinstance(v15, JointTrajPtFull) and v15.valid_fields == 7 and len(encode(v15, LE32)) == 152
    v17 = words("40000000 D1070000 02000000 00000000 00000000 00000000 A50D0300") + bytes(40)
    assert decode(v17, LE32).command == 200101  # type: ignore[attr-defined]
    v19 = decode(
        words("48000000 D2070000 03000000 01000000 00000000 05000000 0E000000 01000000 00000000") + bytes(40), LE32
    )
    assert v19 == MotoMotionReply(0, 5, 14, 1, 0)
    v20 = decode(
        words("48000000 D2070000 03000000 01000000 FFFFFFFF FFFFFFFF D2040000 03000000 BB0B0000") + bytes(40), LE32
    )
    assert v20 == MotoMotionReply(-1, -1, 1234, 3, 3003)


# docs/reference/protocol.md §9: the real FS100 capture, 164 messages.
def test_fs100_capture_counts_and_reencodes() -> None:
    decoders: dict[tuple[int, int], FrameDecoder] = {}
    counts: Counter[tuple[int, int, int | None]] = Counter()
    total = 0
    for _, src, dst, payload in load_segments():
        dec = decoders.setdefault((src, dst), FrameDecoder(ByteOrder.BIG))
        dec.feed(payload)
        for frame in dec:
            msg = decode(frame, BE32)
            assert encode(msg, BE32) == frame
            result = msg.result if isinstance(msg, MotoMotionReply) else None
            counts[(msg.msg_type, msg.comm_type, result)] += 1
            total += 1
    assert all(d.buffered == 0 for d in decoders.values())
    assert total == 164
    assert counts == {
        (13, 1, None): 22,
        (14, 2, None): 58,
        (15, 1, None): 22,
        (2001, 2, None): 2,
        (2002, 3, 0): 11,
        (2002, 3, 1): 48,
        (2002, 3, 2): 1,
    }


def test_fs100_capture_autodetects_big_endian() -> None:
    for _, _, _, payload in load_segments()[:5]:
        dec = FrameDecoder(None)
        dec.feed(payload)
        assert dec.next_frame() is not None
        assert dec.byte_order is ByteOrder.BIG and dec.detected
