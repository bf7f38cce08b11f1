"""The project's extension messages CARTESIAN_LINE (65001) and TOOL_POSE (65002).

Expected frames are written with :mod:`struct` here, independently of the codec; then every generic
path is checked with them: decode and encode in the four wire formats, the reply class chosen by
comm_type, the fast stream decoder, the JSON form, the ``simple-message`` command and the registry.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import simple_message
from simple_message import (
    BE32,
    BE64,
    LE32,
    LE64,
    CartesianLine,
    CartesianLineReply,
    CommType,
    FrameDecoder,
    HeaderOnly,
    LineResult,
    LocalProtocolError,
    MalformedMessage,
    Message,
    MotoResult,
    MsgType,
    ReplyCode,
    SpecialSeq,
    ToolPose,
    VendorRange,
    WireFormat,
    constants,
    decode,
    encode,
    message_class,
    message_from_json,
    message_to_json,
)
from simple_message.cli import main
from simple_message.jsonio import symbolic_names
from simple_message.messages import MESSAGE_CLASSES, lookup, type_for_name, type_name

WIRES = {"le32": LE32, "be32": BE32, "le64": LE64, "be64": BE64}
FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# -- reference frames, packed by hand ---------------------------------------------------------

#: Values every real of which is exact in float32, so the same message decodes from every format.
LINE = CartesianLine(1, 3, 0.5, -0.25, 0.75, 0.0, 0.0, 0.70703125, 0.70703125, 0.125, 0.015625)
LINE_VALUES = (1, 3, 0.5, -0.25, 0.75, 0.0, 0.0, 0.70703125, 0.70703125, 0.125, 0.015625)
REPLY = CartesianLineReply(1, 3, LineResult.SINGULAR, reply_code=ReplyCode.FAILURE)
POSE = ToolPose(0, 2, 12.5, 0.5, -0.25, 0.75, 0.0, 0.0, 0.0, 1.0, 0.0625)
POSE_VALUES = (0, 2, 12.5, 0.5, -0.25, 0.75, 0.0, 0.0, 0.0, 1.0, 0.0625)


def packed(order: str, real: str, head: tuple[int, int, int], ints: int, values: tuple[Any, ...]) -> bytes:
    """A whole frame: the length prefix, the header ``head`` and a body of ``ints`` int32 followed
    by reals (``real`` is "f" or "d"), in byte order ``order`` ("<" or ">")."""
    body = struct.pack(f"{order}{ints}i{len(values) - ints}{real}", *values)
    return struct.pack(f"{order}4i", 12 + len(body), *head) + body


def line_frame(order: str, real: str) -> bytes:
    return packed(order, real, (65001, 2, 0), 2, LINE_VALUES)


def reply_frame(order: str) -> bytes:
    return packed(order, "f", (65001, 3, 2), 3, (1, 3, 11))


def pose_frame(order: str, real: str) -> bytes:
    return packed(order, real, (65002, 1, 0), 2, POSE_VALUES)


# -- numbers and names --------------------------------------------------------------------------


def test_the_numbers_are_in_the_freely_assignable_range() -> None:
    for member in (MsgType.CARTESIAN_LINE, MsgType.TOOL_POSE):
        assert 65001 <= member <= 65535
        assert member > max(VendorRange) + 99  # beyond every vendor block
    assert (int(MsgType.CARTESIAN_LINE), int(MsgType.TOOL_POSE)) == (65001, 65002)
    assert MsgType(65001).name == "CARTESIAN_LINE" and MsgType(65002).name == "TOOL_POSE"
    assert (CartesianLine.MSG_TYPE, CartesianLineReply.MSG_TYPE, ToolPose.MSG_TYPE) == (65001, 65001, 65002)


def test_line_result_codes() -> None:
    assert {m.name: int(m) for m in LineResult} == {
        "ACCEPTED": 0,
        "NOT_READY": 1,
        "BUSY": 2,
        "INVALID": 3,
        "SEQUENCE": 4,
        "UNREACHABLE": 10,
        "SINGULAR": 11,
        "JOINT_LIMIT": 12,
        "WORKSPACE": 13,
        "TCP_SPEED": 14,
    }
    assert "LineResult" in constants.__all__ and simple_message.LineResult is LineResult


def test_the_classes_are_exported() -> None:
    for name in ("CartesianLine", "CartesianLineReply", "ToolPose", "LineResult"):
        assert name in simple_message.__all__
    for name in ("CartesianLine", "CartesianLineReply", "ToolPose"):
        assert name in simple_message.messages.__all__


def test_registry_names_and_classes() -> None:
    assert type_name(65001) == "CARTESIAN_LINE" and type_name(65002) == "TOOL_POSE"
    assert type_for_name("cartesian_line") == 65001 and type_for_name("Tool_Pose") == 65002
    line = lookup(65001)
    assert line is not None and (line.name, line.request, line.reply) == (
        "CARTESIAN_LINE",
        CartesianLine,
        CartesianLineReply,
    )
    assert line.converters["result"][11] is LineResult.SINGULAR
    pose = lookup(65002)
    assert pose is not None and (pose.name, pose.request, pose.reply) == ("TOOL_POSE", ToolPose, ToolPose)
    assert MESSAGE_CLASSES[65001] == (CartesianLine, CartesianLineReply)
    assert LINE.name == REPLY.name == "CARTESIAN_LINE" and POSE.name == "TOOL_POSE"


def test_defaults() -> None:
    assert CartesianLine().comm_type is CommType.SERVICE_REQUEST and CartesianLine().reply_code is ReplyCode.INVALID
    assert CartesianLine().qw == 1.0 and ToolPose().qw == 1.0  # the identity orientation
    reply = CartesianLineReply()
    assert reply.comm_type is CommType.SERVICE_REPLY and reply.reply_code is ReplyCode.SUCCESS
    assert reply.result is LineResult.ACCEPTED
    assert ToolPose().comm_type is CommType.TOPIC and ToolPose().reply_code is ReplyCode.INVALID


# -- exact bytes --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("wire", "order", "real"),
    [(LE32, "<", "f"), (BE32, ">", "f"), (LE64, "<", "d"), (BE64, ">", "d")],
    ids=["le32", "be32", "le64", "be64"],
)
def test_byte_exact_in_every_format(wire: WireFormat, order: str, real: str) -> None:
    cases: list[tuple[Message, bytes]] = [
        (LINE, line_frame(order, real)),
        (REPLY, reply_frame(order)),  # no reals: the same in both real sizes
        (POSE, pose_frame(order, real)),
    ]
    for msg, frame in cases:
        assert encode(msg, wire) == frame, type(msg).__name__
        back = decode(frame, wire)
        assert type(back) is type(msg) and back == msg
        assert encode(back, wire) == frame


def test_the_two_formats_the_brief_pins_down() -> None:
    """Little-endian float32 and big-endian float64 spelled out, field by field."""
    le32 = struct.pack("<iiii", 56, 65001, 2, 0) + struct.pack("<ii", 1, 3)
    le32 += struct.pack("<fffffffff", 0.5, -0.25, 0.75, 0.0, 0.0, 0.70703125, 0.70703125, 0.125, 0.015625)
    assert LINE.encode(LE32) == le32 and len(le32) - 16 == 44
    be64 = struct.pack(">iiii", 92, 65001, 2, 0) + struct.pack(">ii", 1, 3)
    be64 += struct.pack(">ddddddddd", 0.5, -0.25, 0.75, 0.0, 0.0, 0.70703125, 0.70703125, 0.125, 0.015625)
    assert LINE.encode(BE64) == be64 and len(be64) - 16 == 80
    reply = struct.pack("<iiii", 24, 65001, 3, 2) + struct.pack("<iii", 1, 3, 11)
    assert REPLY.encode(LE32) == reply and REPLY.encode(LE64) == reply and len(reply) - 16 == 12
    assert REPLY.encode(BE64) == struct.pack(">iiii", 24, 65001, 3, 2) + struct.pack(">iii", 1, 3, 11)
    pose = struct.pack("<iiii", 56, 65002, 1, 0) + struct.pack("<ii", 0, 2)
    pose += struct.pack("<fffffffff", 12.5, 0.5, -0.25, 0.75, 0.0, 0.0, 0.0, 1.0, 0.0625)
    assert POSE.encode(LE32) == pose and len(pose) - 16 == 44  # 2 int32 + 9 float32
    pose64 = struct.pack(">iiii", 92, 65002, 1, 0) + struct.pack(">ii", 0, 2)
    pose64 += struct.pack(">ddddddddd", 12.5, 0.5, -0.25, 0.75, 0.0, 0.0, 0.0, 1.0, 0.0625)
    assert POSE.encode(BE64) == pose64 and len(pose64) - 16 == 80


def test_field_order_on_the_wire() -> None:
    """Each field lands at its own offset (distinct values, read back with struct)."""
    line = CartesianLine(7, -4, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0)
    assert struct.unpack("<ii9f", line.encode(LE32)[16:]) == (7, -4, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0)
    pose = ToolPose(7, 5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0)
    assert struct.unpack(">ii9d", pose.encode(BE64)[16:]) == (7, 5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0)
    reply = CartesianLineReply(7, -4, LineResult.TCP_SPEED)
    assert struct.unpack("<iii", reply.encode(LE32)[16:]) == (7, -4, 14)


def test_ints_must_fit_int32_and_reals_may_be_anything() -> None:
    for msg in (
        CartesianLine(2**31),
        CartesianLine(sequence=-(2**31) - 1),
        CartesianLineReply(result=2**31),
        ToolPose(tool=2**32),
    ):
        with pytest.raises(LocalProtocolError):
            msg.encode(LE32)
    odd = CartesianLine(0, 0, math.nan, math.inf, -math.inf, 0.0, 0.0, 0.0, 2.0, -1.0, -0.5)  # the controller refuses
    frame = odd.encode(LE64)
    back = decode(frame, LE64)
    assert isinstance(back, CartesianLine) and math.isnan(back.x) and back.y == math.inf and back.speed == -1.0
    assert encode(back, LE64) == frame


# -- round trips --------------------------------------------------------------------------------

INT32 = st.integers(-(2**31), 2**31 - 1)


def reals(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[float]:
    return st.floats(width=32 if wire.real_size == 4 else 64, allow_nan=allow_nan)


def lines(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[CartesianLine]:
    r = reals(wire, allow_nan)
    return st.builds(
        CartesianLine,
        INT32,
        INT32 | st.sampled_from([0, int(SpecialSeq.STOP_TRAJECTORY)]),
        r,
        r,
        r,
        r,
        r,
        r,
        r,
        r,
        r,
        comm_type=INT32.filter(lambda c: c != CommType.SERVICE_REPLY),
        reply_code=INT32,
    )


def replies() -> st.SearchStrategy[CartesianLineReply]:
    results = st.sampled_from(list(LineResult)) | INT32
    return st.builds(
        CartesianLineReply, INT32, INT32, results, comm_type=st.just(CommType.SERVICE_REPLY), reply_code=INT32
    )


def poses(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[ToolPose]:
    r = reals(wire, allow_nan)
    return st.builds(ToolPose, INT32, INT32, r, r, r, r, r, r, r, r, r, comm_type=INT32, reply_code=INT32)


def extension_messages(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[Message]:
    return st.one_of(lines(wire, allow_nan), replies(), poses(wire, allow_nan))


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_decode_of_encode_is_the_message(wire: WireFormat) -> None:
    @FAST
    @given(extension_messages(wire))
    def check(msg: Message) -> None:
        frame = encode(msg, wire)
        back = decode(frame, wire)
        assert type(back) is type(msg) and back == msg
        assert encode(back, wire) == frame

    check()


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_nan_reencodes_byte_exact(wire: WireFormat) -> None:
    @FAST
    @given(extension_messages(wire, allow_nan=True))
    def check(msg: Message) -> None:
        frame = encode(msg, wire)
        assert encode(decode(frame, wire), wire) == frame

    check()


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_the_fast_stream_decoder_agrees_with_decode(wire: WireFormat) -> None:
    @FAST
    @given(st.lists(extension_messages(wire), min_size=1, max_size=8), st.integers(1, 64))
    def check(msgs: list[Message], size: int) -> None:
        stream = b"".join(encode(m, wire) for m in msgs) * 2
        dec = FrameDecoder(wire.byte_order)
        got: list[Message | MalformedMessage] = []
        for i in range(0, len(stream), size):
            got += dec.feed_messages(stream[i : i + size], wire)
        assert [(type(m), m) for m in got] == [(type(m), m) for m in msgs * 2]
        assert dec.buffered == 0

    check()


# -- which class decodes what ---------------------------------------------------------------------


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_the_reply_class_is_chosen_by_comm_type(wire: WireFormat) -> None:
    order = wire.byte_order.struct_char
    frame = struct.pack(f"{order}4i3i", 24, 65001, 3, 1, 4, 9, 2)
    reply = decode(frame, wire)
    assert type(reply) is CartesianLineReply and (reply.robot_id, reply.sequence) == (4, 9)
    assert reply.result is LineResult.BUSY  # the registered converter
    assert reply.comm_type is CommType.SERVICE_REPLY and reply.reply_code is ReplyCode.SUCCESS
    unmapped = decode(struct.pack(f"{order}4i3i", 24, 65001, 3, 2, 4, 9, 99), wire)
    assert unmapped.result == 99 and type(unmapped.result) is int  # type: ignore[attr-defined]
    topic = decode(encode(CartesianLine(2, 1, comm_type=CommType.TOPIC), wire), wire)
    assert type(topic) is CartesianLine and topic.comm_type is CommType.TOPIC
    assert message_class(65001) is CartesianLine
    assert message_class(65001, CommType.TOPIC) is CartesianLine
    assert message_class(65001, CommType.SERVICE_REPLY) is CartesianLineReply
    for comm in (CommType.TOPIC, CommType.SERVICE_REQUEST, CommType.SERVICE_REPLY):
        assert message_class(65002, comm) is ToolPose
        request = decode(encode(ToolPose(1, comm_type=comm), wire), wire)
        assert type(request) is ToolPose and request.comm_type is comm


def test_bodies_of_the_other_shape_are_malformed() -> None:
    request_sized = CartesianLine(1, 2).encode(LE32)
    as_reply = request_sized[:8] + struct.pack("<i", 3) + request_sized[12:]
    with pytest.raises(MalformedMessage, match="CARTESIAN_LINE SERVICE_REPLY body of 44 bytes"):
        decode(as_reply, LE32)
    reply_sized = CartesianLineReply(1, 2).encode(LE32)
    as_request = reply_sized[:8] + struct.pack("<ii", 2, 0) + reply_sized[16:]
    with pytest.raises(MalformedMessage, match="CARTESIAN_LINE SERVICE_REQUEST body of 12 bytes"):
        decode(as_request, LE32)
    with pytest.raises(MalformedMessage, match="TOOL_POSE TOPIC body of 48 bytes"):
        decode(struct.pack("<4i", 60, 65002, 1, 0) + bytes(48), LE32)  # its body is 44 bytes


def test_what_a_controller_without_the_extension_answers() -> None:
    """The C++ library answers an unknown request with a header-only FAILURE: it decodes as such,
    not as a CartesianLineReply, which is how a client tells support from its absence."""
    refusal = decode(struct.pack("<4i", 12, 65001, 3, 2), LE32)
    assert isinstance(refusal, HeaderOnly) and refusal.msg_type == 65001 and refusal.reply_code is ReplyCode.FAILURE
    assert refusal.name == "CARTESIAN_LINE"
    opt_in = decode(HeaderOnly(65002, comm_type=CommType.SERVICE_REQUEST, reply_code=0).encode(BE32), BE32)
    assert isinstance(opt_in, HeaderOnly) and opt_in.msg_type == MsgType.TOOL_POSE  # an empty-body opt-in


# -- JSON -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("wire", [LE32, BE64], ids=str)
def test_json_round_trip(wire: WireFormat) -> None:
    for msg in (LINE, REPLY, POSE, CartesianLineReply(0, 0, 99), HeaderOnly(65001, reply_code=ReplyCode.FAILURE)):
        obj = json.loads(json.dumps(message_to_json(msg, wire.real_size)))
        assert obj["msg_type"] == msg.msg_type and obj["name"] == msg.name
        back = message_from_json(obj)
        assert type(back) is type(msg) and back == msg
        assert encode(back, wire) == encode(msg, wire)


def test_json_form_and_names() -> None:
    obj = message_to_json(REPLY)
    assert obj == {
        "msg_type": 65001,
        "name": "CARTESIAN_LINE",
        "comm_type": 3,
        "reply_code": 2,
        "body": {"robot_id": 1, "sequence": 3, "result": 11},
        "names": {"comm_type": "SERVICE_REPLY", "reply_code": "FAILURE", "result": "SINGULAR"},
    }
    # named by LineResult, never by MotoResult (the other messages' "result")
    assert symbolic_names(CartesianLineReply(result=LineResult.ACCEPTED))["result"] == "ACCEPTED"
    assert symbolic_names(CartesianLineReply(result=4))["result"] == "SEQUENCE"
    assert MotoResult(5).name == "NOT_READY" and "result" not in symbolic_names(CartesianLineReply(result=5))
    assert "result" not in symbolic_names(CartesianLineReply(result=99))
    stop = message_to_json(CartesianLine(0, SpecialSeq.STOP_TRAJECTORY))
    assert stop["names"]["sequence"] == "STOP_TRAJECTORY"
    assert list(stop["body"]) == [
        "robot_id",
        "sequence",
        "x",
        "y",
        "z",
        "qx",
        "qy",
        "qz",
        "qw",
        "speed",
        "blend_radius",
    ]
    pose = message_to_json(POSE)
    assert list(pose["body"]) == ["robot_id", "tool", "time", "x", "y", "z", "qx", "qy", "qz", "qw", "speed"]
    assert pose["names"] == {"comm_type": "TOPIC", "reply_code": "INVALID"}
    assert message_to_json(CartesianLine(x=0.1))["body"]["x"] == 0.1  # shortest float32 decimal


def test_json_by_name_and_non_finite_reals() -> None:
    built = message_from_json({"name": "cartesian_line", "body": {"robot_id": 1, "x": 0.5, "speed": 0.25}})
    assert built == CartesianLine(1, x=0.5, speed=0.25)
    reply = message_from_json({"name": "CARTESIAN_LINE", "comm_type": 3, "body": {"result": 13}})
    assert type(reply) is CartesianLineReply and reply.result == LineResult.WORKSPACE
    odd = CartesianLine(x=math.nan, y=math.inf, z=-math.inf)
    obj = json.loads(json.dumps(message_to_json(odd)))
    assert (obj["body"]["x"], obj["body"]["y"], obj["body"]["z"]) == ("NaN", "Infinity", "-Infinity")
    assert encode(message_from_json(obj)) == encode(odd)
    with pytest.raises(LocalProtocolError, match="no field"):
        message_from_json({"name": "TOOL_POSE", "body": {"result": 0}})


# -- the simple-message command -------------------------------------------------------------------


def test_cli_decodes_them_by_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = tmp_path / "ext.txt"
    text = [f"LINE {line_frame('<', 'f').hex()}", "# a comment", f"REPLY {reply_frame('<').hex()}"]
    frames.write_text("\n".join([*text, f"POSE {pose_frame('<', 'f').hex()}", ""]))
    assert main(["decode", str(frames)]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    line, reply, pose = (json.loads(text) for text in out.splitlines())
    assert line == {
        "msg_type": 65001,
        "name": "CARTESIAN_LINE",
        "comm_type": 2,
        "reply_code": 0,
        "body": {
            "robot_id": 1,
            "sequence": 3,
            "x": 0.5,
            "y": -0.25,
            "z": 0.75,
            "qx": 0.0,
            "qy": 0.0,
            "qz": 0.70703125,
            "qw": 0.70703125,
            "speed": 0.125,
            "blend_radius": 0.015625,
        },
        "names": {"comm_type": "SERVICE_REQUEST", "reply_code": "INVALID"},
        "line": 1,
        "label": "LINE",
    }
    assert reply["name"] == "CARTESIAN_LINE" and reply["body"] == {"robot_id": 1, "sequence": 3, "result": 11}
    assert reply["names"]["result"] == "SINGULAR" and reply["label"] == "REPLY"
    assert pose["name"] == "TOOL_POSE" and pose["msg_type"] == 65002 and pose["body"]["time"] == 12.5


@pytest.mark.parametrize(("order", "real"), [("big", "d"), ("little", "d"), ("big", "f")])
def test_cli_decodes_a_raw_stream_in_other_formats(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], order: str, real: str
) -> None:
    char = "<" if order == "little" else ">"
    stream = tmp_path / "ext.bin"
    stream.write_bytes(line_frame(char, real) + reply_frame(char) + pose_frame(char, real))
    argv = ["decode", "--raw", "--byte-order", order, *(["--float64"] if real == "d" else []), str(stream)]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert err == ""
    objs = [json.loads(text) for text in out.splitlines()]
    assert [o["name"] for o in objs] == ["CARTESIAN_LINE", "CARTESIAN_LINE", "TOOL_POSE"]
    assert [message_from_json(o) for o in objs] == [LINE, REPLY, POSE]


def test_cli_encode_then_decode(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lines = tmp_path / "ext.jsonl"
    lines.write_text("\n".join(json.dumps(message_to_json(m, 8)) for m in (LINE, REPLY, POSE)) + "\n")
    assert main(["encode", "--byte-order", "big", "--float64", str(lines)]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert out.split() == [line_frame(">", "d").hex(), reply_frame(">").hex(), pose_frame(">", "d").hex()]
    hexes = tmp_path / "ext.txt"
    hexes.write_text(out)
    assert main(["decode", "--byte-order", "auto", "--float64", str(hexes)]) == 0
    decoded = [json.loads(text) for text in capsys.readouterr().out.splitlines()]
    assert [d["name"] for d in decoded] == ["CARTESIAN_LINE", "CARTESIAN_LINE", "TOOL_POSE"]
    assert decoded[1]["names"]["result"] == "SINGULAR"
