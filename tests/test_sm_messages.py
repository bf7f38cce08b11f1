"""The message API: construction, padding, typed errors, vendor reply shapes, both real sizes."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from simple_message import (
    BE32,
    BE64,
    LE32,
    LE64,
    CommType,
    DhLink,
    DummyReply,
    ExGroup,
    FrameDecoder,
    GetDhParameters,
    GetDhParametersReply,
    GetVersion,
    GetVersionReply,
    HeaderOnly,
    JointFeedback,
    JointFeedbackEx,
    JointTraj,
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    LocalProtocolError,
    MalformedMessage,
    Message,
    MotoCommand,
    MotoMotionCtrl,
    MotoMotionReply,
    MsgType,
    Ping,
    RawMessage,
    ReadMRegister,
    ReadMRegisterReply,
    ReadSingleIo,
    ReplyCode,
    SelectTool,
    Status,
    TrajPoint,
    TriState,
    ValidFields,
    WireFormat,
    WriteMRegister,
    WriteMRegisterReply,
    decode,
    encode,
    message_from_json,
    message_to_json,
)
from simple_message.messages import register, scoped_registry, unregister


def test_joint_arrays_are_padded_and_normalised() -> None:
    msg = JointTrajPt(0, np.array([0.1, 0.2, 0.3]), 0.5, 1.0)
    assert msg.joint_data == (0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert all(type(v) is float for v in msg.joint_data)
    assert JointTrajPt(0, [1, 2]).joint_data[:2] == (1.0, 2.0)


def test_more_than_ten_joints_is_a_local_error() -> None:
    with pytest.raises(LocalProtocolError, match="at most 10"):
        JointTrajPt(0, list(range(11)))
    with pytest.raises(ValueError):  # LocalProtocolError is also a ValueError
        JointFeedback(positions=[0.0] * 12)


def test_out_of_range_ints_are_local_errors_at_encode() -> None:
    with pytest.raises(LocalProtocolError, match="JointTrajPt"):
        encode(JointTrajPt(2**31), LE32)
    with pytest.raises(LocalProtocolError):
        encode(ReadSingleIo(-1), LE32)  # uint32 address
    with pytest.raises(LocalProtocolError):
        encode(HeaderOnly(2**40), LE32)


def test_messages_are_immutable_and_hashable() -> None:
    msg = Status(1, 0, 0, 0, 0, 2, 1)
    with pytest.raises(AttributeError):
        msg.in_motion = 1  # type: ignore[misc]
    assert hash(msg) == hash(Status(1, 0, 0, 0, 0, 2, 1))
    assert msg.msg_type == MsgType.STATUS and msg.name == "STATUS"


def test_decoded_constants_come_back_as_enums() -> None:
    status = decode(Status(1, 0, 1234, 1, 0, 2, -1).encode(), LE32)
    assert status.drives_powered is TriState.TRUE  # type: ignore[attr-defined]
    assert status.comm_type is CommType.TOPIC
    full = decode(JointTrajPtFull(valid_fields=0x0F).encode(), LE32)
    assert (
        full.valid_fields == ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY | ValidFields.ACCELERATION
    )  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("msg", "length32", "length64"),
    [
        (Ping(), 12, 12),
        (JointTrajPt(), 64, 112),
        (Status(), 40, 40),
        (JointTrajPtFull(), 148, 272),
        (JointFeedback(), 144, 268),
        (MotoMotionCtrl(), 64, 104),
        (JointTrajPtFullEx(groups=[ExGroup()]), 152, 276),
        (JointTrajPtFullEx(groups=[ExGroup()] * 2), 284, 532),
        (JointTrajPtFullEx(groups=[ExGroup()] * 4), 548, 1044),
        (JointFeedbackEx(groups=[ExGroup()]), 544, 1040),
    ],
)
def test_frame_sizes(msg: object, length32: int, length64: int) -> None:
    """docs/reference/protocol.md §12 frame size table; FLOAT64 doubles every real."""
    assert len(encode(msg, LE32)) - 4 == length32  # type: ignore[arg-type]
    assert len(encode(msg, LE64)) - 4 == length64  # type: ignore[arg-type]


def test_to_reply_echoes_the_body_like_the_cpp_library() -> None:
    req = JointTrajPt(3, [0.5], 0.5, 1.25)
    rep = req.to_reply(ReplyCode.SUCCESS)
    assert (rep.comm_type, rep.reply_code) == (3, 1)
    assert encode(rep, LE32)[16:] == encode(req, LE32)[16:]
    assert HeaderOnly.reply_to(req, ReplyCode.FAILURE).encode(BE32).hex() == "0000000c0000000b0000000300000002"


def test_ping_with_the_rep_body_of_ten_ints() -> None:
    frame = Ping(data=[0] * 10).encode(LE32)
    assert len(frame) == 56
    assert decode(frame, LE32) == Ping(data=[0] * 10)
    assert decode(Ping().encode(LE32), LE32) == Ping()


def test_get_version_request_and_reply() -> None:
    assert decode(GetVersion().encode(), LE32) == GetVersion()
    rep = GetVersionReply(1, 2, 3)
    assert decode(rep.encode(), LE32) == rep
    assert isinstance(decode(HeaderOnly(2, reply_code=2).encode(), LE32), HeaderOnly)


def test_joint_traj_cpp_layout_puts_the_count_last() -> None:
    traj = JointTraj([TrajPoint(0, [0.5], 0.5, 1.0), TrajPoint(1, [0.25], 0.5, 1.0)])
    frame = traj.encode(LE32)
    assert len(frame) == 16 + 2 * 52 + 4
    assert frame[-4:] == (2).to_bytes(4, "little")
    assert decode(frame, LE32) == traj
    with pytest.raises(LocalProtocolError, match="200"):
        JointTraj([TrajPoint()] * 201)


def test_joint_traj_points_from_json_objects() -> None:
    """JointTraj builds its points from dicts, so the JSON form needs no per-class code."""
    traj = JointTraj([TrajPoint(0, [0.5], 0.5, 1.0), TrajPoint(1, [0.25], 0.5, 1.0)])
    assert (
        JointTraj([{"sequence": 0, "joint_data": [0.5], "velocity": 0.5, "duration": 1.0}]).points[0] == traj.points[0]
    )
    assert message_from_json(message_to_json(traj)) == traj


def test_empty_json_body_is_header_only_except_for_ping() -> None:
    """``{}`` is PING's own body (its default message is header-sized); any other type's ``{}`` is a
    header-only message, and a type without fields is itself."""
    assert message_from_json({"name": "PING", "body": {}}) == Ping()
    assert type(message_from_json({"name": "PING", "body": {}})) is Ping
    ack = message_from_json({"name": "JOINT_TRAJ_PT", "comm_type": 3, "reply_code": 1, "body": {}})
    assert ack == HeaderOnly(MsgType.JOINT_TRAJ_PT, comm_type=3, reply_code=1)
    assert type(message_from_json({"name": "GET_VERSION"})) is GetVersion
    assert message_from_json({"name": "robot_status", "body": {"mode": 2}}) == Status(mode=2)  # MsgType alias


def test_full_ex_short_and_full_forms_both_reencode() -> None:
    short = JointTrajPtFullEx(sequence=7, groups=[ExGroup(0, 7, 1.0, [0.5]), ExGroup(1, 7, 1.0, [0.25])])
    assert short.number_of_valid_groups == 2
    assert decode(short.encode(), LE32) == short
    full = JointTrajPtFullEx(2, 7, [ExGroup(0), ExGroup(1), ExGroup(), ExGroup()])
    assert len(full.encode()) == 4 + 12 + 536
    back = decode(full.encode(), LE32)
    assert back == full and len(back.valid_groups) == 2  # type: ignore[attr-defined]
    three_of_two = JointTrajPtFullEx(2, 7, [ExGroup()] * 3).encode()
    with pytest.raises(MalformedMessage):
        decode(three_of_two, LE32)


def test_feedback_ex_always_carries_four_groups() -> None:
    fb = JointFeedbackEx(groups=[ExGroup(0, 6, 0.0, [0.5]), ExGroup(1, 6)])
    assert fb.number_of_valid_groups == 2 and len(fb.groups) == 4
    assert len(fb.encode()) == 548
    assert decode(fb.encode(), LE32) == fb


def test_motoros_mregister_request_and_reply_share_a_type() -> None:
    assert decode(ReadMRegister(123).encode(), LE32) == ReadMRegister(123)
    rep = ReadMRegisterReply(42, 0)
    assert rep.msg_type == MsgType.READ_MREGISTER
    assert decode(rep.encode(), LE32) == rep
    assert decode(WriteMRegister(5, 9).encode(), LE32) == WriteMRegister(5, 9)
    assert decode(WriteMRegisterReply(1003).encode(), LE32) == WriteMRegisterReply(1003)


def test_select_tool_and_dh_parameters() -> None:
    assert decode(SelectTool(0, 3, 9).encode(), LE32) == SelectTool(0, 3, 9)
    assert decode(GetDhParameters().encode(), LE32) == GetDhParameters()
    # MotoROS always sends 4 groups x 8 axes (512 bytes with float32): fewer are padded with zeros
    dh = GetDhParametersReply([[DhLink(0.0, 0.375, 0.0, 0.0), DhLink(1.0, 0.0, 0.25, 1.5)]])
    assert len(dh.groups) == 4 and all(len(g) == 8 for g in dh.groups)
    assert dh.groups[0][1] == DhLink(1.0, 0.0, 0.25, 1.5) and dh.groups[0][2] == DhLink() == dh.groups[3][7]
    assert len(dh.encode(LE32)) == 16 + 512
    assert len(dh.encode(LE64)) == 16 + 1024
    assert decode(dh.encode(LE32), LE32) == dh
    # a shorter body from another peer decodes with its axes per group, and re-encodes exactly;
    # more than 8 axes is refused both ways
    body = b"".join(LE32.struct("rrrr").pack(1.0, 2.0, 3.0, 4.0) for _ in range(4 * 6))
    frame = LE32.struct("iiii").pack(12 + len(body), 2020, 3, 1) + body
    back = decode(frame, LE32)
    assert isinstance(back, GetDhParametersReply) and back.groups[3][5] == DhLink(1.0, 2.0, 3.0, 4.0)
    assert back.axes == 6 and len(back.groups[3]) == 6 and back.encode(LE32) == frame
    assert GetDhParametersReply([[DhLink()]], axes=6).encode(LE32) == LE32.struct("iiii").pack(396, 2020, 3, 1) + bytes(
        384
    )
    with pytest.raises(LocalProtocolError):
        GetDhParametersReply([[DhLink()] * 7], axes=6)
    with pytest.raises(LocalProtocolError):
        GetDhParametersReply([[DhLink()] * 9])


def test_dummy_data_reply_of_rep_i0006() -> None:
    frame = DummyReply(11, [1.0] * 10).encode(LE32)
    assert len(frame) == 16 + 40
    back = decode(frame, LE32)
    assert isinstance(back, DummyReply) and back.msg_type == 11 and back.data == (1.0,) * 10


def test_unknown_type_is_raw_and_byte_exact() -> None:
    frame = RawMessage(65500, b"\x01\x02\x03", comm_type=1).encode(BE32)  # 65001/65002 are the extensions
    back = decode(frame, BE32)
    assert isinstance(back, RawMessage) and back.body == b"\x01\x02\x03" and back.name == "UNKNOWN"
    assert back.encode(BE32) == frame


def test_moto_motion_ctrl_command() -> None:
    msg = MotoMotionCtrl(command=MotoCommand.STOP_MOTION)
    assert decode(msg.encode(), LE32).command == 200111  # type: ignore[attr-defined]


# -- how decoding builds messages (messages._Codec, messages._builder) --------------------------


@pytest.mark.parametrize("wire", [LE32, BE32, LE64, BE64], ids=str)
def test_decoded_messages_are_exactly_their_class_frozen_and_equal(wire: WireFormat) -> None:
    """Decoding sets the fields without the constructor: what comes out is a plain instance of the
    class, immutable, and equal (hash, repr) to the message made by the constructor."""
    plain = [
        JointTrajPt(3, [0.5, -0.25], 0.5, 1.0),
        ReadSingleIo(2**32 - 1),
        SelectTool(0, 3, 9, comm_type=CommType.TOPIC),
    ]
    converted = [Status(1, 0, 7, 0, 1, 2, 1), JointFeedback(1, 0x0E, 1.5, [0.5]), MotoMotionReply(1, 2, 3, 4, 5)]
    for msg in plain + converted:
        frame = msg.encode(wire)
        for back in (decode(frame, wire), *FrameDecoder(wire.byte_order).feed_messages(frame * 2, wire)):
            assert type(back) is type(msg)
            assert back == msg and hash(back) == hash(msg)
            if msg in plain:
                assert repr(back) == repr(msg)
            with pytest.raises(AttributeError):
                back.comm_type = 1  # type: ignore[misc]
            with pytest.raises(AttributeError):
                del back.reply_code  # type: ignore[misc]
            assert dataclasses.replace(back) == msg and back.encode(wire) == frame


@dataclass(frozen=True, slots=True)
class GaugeBase(Message):
    """A vendor base class with ``__init_subclass__``: decoding must not subclass its classes."""

    subclasses: ClassVar[list[type]] = []

    def __init_subclass__(cls) -> None:
        GaugeBase.subclasses.append(cls)


@dataclass(frozen=True, slots=True)
class AcmeGauge(GaugeBase):
    width: float = 0.0
    state: int = 0
    MSG_TYPE: ClassVar[int] = 1777
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("width", "r"), ("state", "i"))


def test_a_class_without_a_builder_decodes_alike() -> None:
    with scoped_registry():
        register(AcmeGauge, converters={"state": TriState})
        before = list(GaugeBase.subclasses)
        msg = AcmeGauge(0.5, 1, comm_type=CommType.TOPIC)
        frame = msg.encode(LE32)
        for back in (decode(frame, LE32), *FrameDecoder().feed_messages(frame * 3, LE32)):
            assert isinstance(back, AcmeGauge) and type(back) is AcmeGauge
            assert back == msg and back.state is TriState.TRUE
        assert GaugeBase.subclasses == before  # no builder subclass was made


def test_registering_other_converters_changes_what_feed_messages_decodes() -> None:
    """feed_messages's tables (and its decoded header-only frames) follow the registry."""
    frame = AcmeGauge(0.5, 1).encode(LE32)
    ack = HeaderOnly(AcmeGauge.MSG_TYPE, reply_code=ReplyCode.SUCCESS).encode(LE32)
    dec = FrameDecoder()
    assert dec.feed_messages(ack, LE32) == [RawMessage(AcmeGauge.MSG_TYPE, comm_type=3, reply_code=1)]
    with scoped_registry():
        register(AcmeGauge, converters={"state": TriState})
        assert dec.feed_messages(ack * 2, LE32) == [decode(ack, LE32)] * 2
        assert type(decode(ack, LE32)) is HeaderOnly
        (back,) = dec.feed_messages(frame, LE32)
        assert isinstance(back, AcmeGauge) and back.state is TriState.TRUE
        register(AcmeGauge, replace=True)
        (back,) = dec.feed_messages(frame, LE32)
        assert isinstance(back, AcmeGauge) and back.state == 1 and type(back.state) is int
        unregister(AcmeGauge.MSG_TYPE)
        assert isinstance(dec.feed_messages(frame, LE32)[0], RawMessage)
    assert isinstance(dec.feed_messages(frame, LE32)[0], RawMessage)
    assert type(dec.feed_messages(ack, LE32)[0]) is RawMessage


def test_json_names_the_numbers_the_protocol_names() -> None:
    from simple_message.constants import MotoCommand, MotoResult
    from simple_message.jsonio import message_from_json, message_to_json
    from simple_message.messages import JointTrajPtFull, MotoMotionReply, Status

    status = message_to_json(Status(1, 0, 0, 0, 1, 2, 1))
    assert status["body"]["drives_powered"] == 1  # the numbers stay, and decide
    assert status["names"] == {
        "comm_type": "TOPIC",
        "reply_code": "INVALID",
        "drives_powered": "TRUE",
        "e_stopped": "FALSE",
        "in_error": "FALSE",
        "in_motion": "TRUE",
        "mode": "AUTO",
        "motion_possible": "TRUE",
    }
    reply = message_to_json(MotoMotionReply(0, 3, MotoCommand.START_TRAJ_MODE, MotoResult.NOT_READY, 5003))
    assert reply["names"]["command"] == "START_TRAJ_MODE" and reply["names"]["subcode"] == "ESTOP"
    invalid = message_to_json(MotoMotionReply(0, 3, 0, MotoResult.INVALID, 3011))
    assert invalid["names"]["result"] == "INVALID" and invalid["names"]["subcode"] == "DATA_START_POS"
    point = message_to_json(JointTrajPtFull(0, -1, 0x07, 0.0, [0.0] * 6))
    assert point["names"]["sequence"] == "START_TRAJECTORY_DOWNLOAD"
    assert point["names"]["valid_fields"] == "TIME|POSITION|VELOCITY"
    assert message_from_json({**status, "names": {"mode": "MANUAL"}}) == Status(1, 0, 0, 0, 1, 2, 1)  # ignored
