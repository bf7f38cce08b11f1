"""ROS-Industrial simple_message: the protocol, complete and exact.

The core is sans-I/O (after h11): :mod:`.messages` turns messages into bytes and back,
:mod:`.framing` cuts any chunking of a byte stream into frames, :mod:`.header` applies the C++
library's header rules. Nothing in it opens a socket, so every rule is tested synchronously and the
same code serves TCP, serial links and tests. Protocol references ("§4.2") point into
``docs/simple-message.md`` of the project's shared documentation.

Quick use::

    from simple_message import JointTrajPt, decode, LE32
    frame = JointTrajPt(0, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], velocity=0.5, duration=1.0).encode(LE32)
    assert decode(frame, LE32).sequence == 0
"""

from __future__ import annotations

from .constants import (
    HEADER_SIZE,
    LENGTH_SIZE,
    MAX_JOINTS,
    MOTO_MAX_GROUPS,
    CommType,
    InvalidSubcode,
    IoResult,
    MotoCommand,
    MotoResult,
    MsgType,
    NotReadySubcode,
    Port,
    ReplyCode,
    RobotMode,
    SpecialSeq,
    TriState,
    ValidFields,
    VendorRange,
)
from .errors import (
    FrameError,
    HeaderError,
    LocalProtocolError,
    MalformedMessage,
    RemoteProtocolError,
    SimpleMessageError,
)
from .framing import DEFAULT_MAX_LENGTH, FrameDecoder, detect_byte_order
from .header import header_error, validate_header
from .jsonio import message_from_json, message_to_json
from .messages import (
    ZEROS,
    DhLink,
    DummyReply,
    ExGroup,
    GetDhParameters,
    GetDhParametersReply,
    GetVersion,
    GetVersionReply,
    Header,
    HeaderOnly,
    IoCtrlReply,
    JointFeedback,
    JointFeedbackEx,
    JointPosition,
    JointTraj,
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Ping,
    RawMessage,
    ReadGroupIo,
    ReadGroupIoReply,
    ReadMRegister,
    ReadMRegisterReply,
    ReadSingleIo,
    ReadSingleIoReply,
    SelectTool,
    Status,
    TrajPoint,
    WriteGroupIo,
    WriteGroupIoReply,
    WriteMRegister,
    WriteMRegisterReply,
    WriteSingleIo,
    WriteSingleIoReply,
    decode,
    encode,
    message_class,
    read_header,
)
from .wire import BE32, BE64, DEFAULT_FORMAT, LE32, LE64, ByteOrder, WireFormat

__all__ = [
    "BE32", "BE64", "DEFAULT_FORMAT", "DEFAULT_MAX_LENGTH", "HEADER_SIZE", "LE32", "LE64", "LENGTH_SIZE",
    "MAX_JOINTS", "MOTO_MAX_GROUPS", "ZEROS", "ByteOrder", "CommType", "DhLink", "DummyReply", "ExGroup",
    "FrameDecoder", "FrameError", "GetDhParameters", "GetDhParametersReply", "GetVersion", "GetVersionReply",
    "Header", "HeaderError", "HeaderOnly", "InvalidSubcode", "IoCtrlReply", "IoResult", "JointFeedback",
    "JointFeedbackEx", "JointPosition", "JointTraj", "JointTrajPt", "JointTrajPtFull", "JointTrajPtFullEx",
    "LocalProtocolError", "MalformedMessage", "Message", "MotoCommand", "MotoMotionCtrl", "MotoMotionReply",
    "MotoResult", "MsgType", "NotReadySubcode", "Ping", "Port", "RawMessage", "ReadGroupIo", "ReadGroupIoReply",
    "ReadMRegister", "ReadMRegisterReply", "ReadSingleIo", "ReadSingleIoReply", "RemoteProtocolError",
    "ReplyCode", "RobotMode", "SelectTool", "SimpleMessageError", "SpecialSeq", "Status", "TrajPoint",
    "TriState", "ValidFields", "VendorRange", "WireFormat", "WriteGroupIo", "WriteGroupIoReply",
    "WriteMRegister", "WriteMRegisterReply", "WriteSingleIo", "WriteSingleIoReply", "decode",
    "detect_byte_order", "encode", "header_error", "message_class", "message_from_json", "message_to_json",
    "read_header", "validate_header",
]
