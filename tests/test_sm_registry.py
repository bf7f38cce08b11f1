"""The message registry, with a worked example: a vendor message set added from outside the package.

The first part of this file is what a vendor module contains (CONTRIBUTING.md, "Adding a vendor
message set"): its message classes and one function that registers them. A real vendor module calls
``register`` at import time; here the ``acme`` fixture registers the set inside
:func:`~simple_message.messages.scoped_registry`, so every test starts from the built-in registry
and no other test module sees the vendor types. Nothing in ``simple_message`` knows about ACME:
decode, encode, the JSON form and the ``simple-message`` command all find the types in the registry.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import ClassVar

import pytest

from simple_message import (
    BE32,
    BE64,
    LE32,
    LE64,
    CommType,
    DummyReply,
    HeaderOnly,
    JointFeedback,
    MalformedMessage,
    Message,
    MsgType,
    RawMessage,
    ReplyCode,
    RobotMode,
    SimpleMessageError,
    Status,
    TriState,
    ValidFields,
    WireFormat,
    decode,
    encode,
    message_class,
    message_from_json,
    message_to_json,
)
from simple_message.cli import main
from simple_message.messages import (
    MESSAGE_CLASSES,
    MessageSpec,
    RegistrationError,
    lookup,
    message_types,
    register,
    scoped_registry,
    type_for_name,
    type_name,
    unregister,
)

# ---------------------------------------------------------------------------------------------
# The vendor module: a made-up gripper of "ACME", in the unallocated ID block 1700-1799
# ---------------------------------------------------------------------------------------------

ACME_GRIP = 1701
ACME_GRIPPER_STATUS = 1702


class GripState(IntEnum):
    """``state`` of the ACME messages."""

    UNKNOWN = -1
    OPEN = 0
    CLOSED = 1
    HOLDING = 2


@dataclass(frozen=True, slots=True)
class AcmeGrip(Message):
    """ACME_GRIP (1701) request: move gripper ``tool`` to ``width`` (m) with at most ``force`` (N)."""

    tool: int = 0
    width: float = 0.0
    force: float = 0.0
    MSG_TYPE: ClassVar[int] = ACME_GRIP
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("tool", "i"), ("width", "r"), ("force", "r"))


@dataclass(frozen=True, slots=True)
class AcmeGripReply(Message):
    """ACME_GRIP (1701) SERVICE_REPLY: the gripper's ``state`` after the move."""

    tool: int = 0
    state: int = GripState.UNKNOWN
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = ACME_GRIP
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("tool", "i"), ("state", "i"))


@dataclass(frozen=True, slots=True)
class AcmeGripperStatus(Message):
    """ACME_GRIPPER_STATUS (1702) topic: state, width (m) and force (N) of gripper ``tool``."""

    tool: int = 0
    state: int = GripState.UNKNOWN
    width: float = 0.0
    force: float = 0.0
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = ACME_GRIPPER_STATUS
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("tool", "i"),
        ("state", "i"),
        ("width", "r"),
        ("force", "r"),
    )


def register_acme() -> None:
    """What the vendor module runs at import time."""
    register(AcmeGrip, AcmeGripReply, converters={"state": GripState})
    register(AcmeGripperStatus, aliases=("ACME_STATUS",), converters={"state": GripState})


# ---------------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------------


@pytest.fixture
def acme() -> Iterator[None]:
    with scoped_registry():
        register_acme()
        yield


#: the standard and MotoROS types (25) and the project's extensions CARTESIAN_LINE and TOOL_POSE
BUILTIN_TYPES = 27

GRIP = AcmeGrip(2, 0.25, 40.0)
GRIP_FRAMES = {
    "LE32": "18000000a50600000200000000000000020000000000803e00002042",
    "BE32": "00000018000006a50000000200000000000000023e80000042200000",
    "LE64": "20000000a5060000020000000000000002000000000000000000d03f0000000000004440",
    "BE64": "00000020000006a50000000200000000000000023fd00000000000004044000000000000",
}
STATUS = AcmeGripperStatus(1, GripState.HOLDING, 0.5, -12.5)
STATUS_FRAMES = {
    "LE32": "1c000000a6060000010000000000000001000000020000000000003f000048c1",
    "BE32": "0000001c000006a6000000010000000000000001000000023f000000c1480000",
    "LE64": "24000000a606000001000000000000000100000002000000000000000000e03f00000000000029c0",
    "BE64": "00000024000006a6000000010000000000000001000000023fe0000000000000c029000000000000",
}
WIRES = {"LE32": LE32, "BE32": BE32, "LE64": LE64, "BE64": BE64}


@pytest.mark.parametrize("wire_name", list(WIRES))
def test_vendor_messages_encode_and_decode_byte_exact(acme: None, wire_name: str) -> None:
    wire = WIRES[wire_name]
    for msg, frames in ((GRIP, GRIP_FRAMES), (STATUS, STATUS_FRAMES)):
        frame = encode(msg, wire)
        assert frame.hex() == frames[wire_name]
        back = decode(frame, wire)
        assert type(back) is type(msg) and back == msg
        assert encode(back, wire) == frame
    reply = decode(encode(AcmeGripReply(2, GripState.CLOSED), wire), wire)
    assert type(reply) is AcmeGripReply and reply.reply_code is ReplyCode.SUCCESS


def test_request_and_reply_class_by_comm_type_and_converted_enums(acme: None) -> None:
    reply = decode(bytes.fromhex("14000000a506000003000000010000000200000001000000"), LE32)
    assert isinstance(reply, AcmeGripReply) and reply.tool == 2
    assert reply.state is GripState.CLOSED  # the registered converter
    status = decode(STATUS.encode(BE32), BE32)
    assert status.state is GripState.HOLDING  # type: ignore[attr-defined]
    assert status.comm_type is CommType.TOPIC
    odd = decode(AcmeGripperStatus(state=7).encode(), LE32)
    assert odd.state == 7 and type(odd.state) is int  # type: ignore[attr-defined]  # unmapped: plain int
    assert message_class(ACME_GRIP) is AcmeGrip
    assert message_class(ACME_GRIP, CommType.SERVICE_REPLY) is AcmeGripReply
    assert message_class(ACME_GRIPPER_STATUS, CommType.SERVICE_REPLY) is AcmeGripperStatus


def test_names_and_lookup(acme: None) -> None:
    assert GRIP.name == "ACME_GRIP" and STATUS.name == "ACME_GRIPPER_STATUS"
    assert type_name(ACME_GRIP) == "ACME_GRIP" and type_name(1799) is None
    assert type_for_name("acme_grip") == ACME_GRIP
    assert type_for_name("ACME_STATUS") == type_for_name("Acme_Gripper_Status") == ACME_GRIPPER_STATUS
    spec = lookup(ACME_GRIP)
    assert isinstance(spec, MessageSpec)
    assert (spec.msg_type, spec.name, spec.request, spec.reply) == (ACME_GRIP, "ACME_GRIP", AcmeGrip, AcmeGripReply)
    assert spec.classes == (AcmeGrip, AcmeGripReply)
    assert spec.converters["state"][2] is GripState.HOLDING
    types = [s.msg_type for s in message_types()]
    assert types == sorted(types) and {ACME_GRIP, ACME_GRIPPER_STATUS} <= set(types)
    assert len(message_types()) == BUILTIN_TYPES + 2
    assert MESSAGE_CLASSES[ACME_GRIP] == (AcmeGrip, AcmeGripReply)


def test_vendor_types_get_the_generic_reply_shapes_and_errors(acme: None) -> None:
    ack = decode(HeaderOnly(ACME_GRIP).encode(BE32), BE32)
    assert isinstance(ack, HeaderOnly) and ack.name == "ACME_GRIP"
    dummy = decode(DummyReply(ACME_GRIP, (1.0,)).encode(), LE32)
    assert isinstance(dummy, DummyReply) and dummy.name == "ACME_GRIP"
    bad = bytes.fromhex("14000000a6060000010000000000000001000000") + b"\0" * 4  # 8-byte body, needs 16
    with pytest.raises(MalformedMessage, match="ACME_GRIPPER_STATUS TOPIC body of 8 bytes") as info:
        decode(bad, LE32)
    assert info.value.msg_type == ACME_GRIPPER_STATUS


@pytest.mark.parametrize("real_size", [4, 8])
def test_json_round_trip(acme: None, real_size: int) -> None:
    wire = LE32 if real_size == 4 else LE64
    for msg in (GRIP, AcmeGripReply(2, GripState.OPEN), STATUS, HeaderOnly(ACME_GRIP)):
        obj = json.loads(json.dumps(message_to_json(msg, real_size)))
        assert obj["name"] == msg.name and obj["msg_type"] == msg.msg_type
        back = message_from_json(obj)
        assert type(back) is type(msg) and back == msg
        assert encode(back, wire) == encode(msg, wire)
    assert message_to_json(STATUS)["body"] == {"tool": 1, "state": 2, "width": 0.5, "force": -12.5}
    by_name = message_from_json({"name": "acme_status", "body": {"state": 1, "width": 0.1}})
    assert by_name == AcmeGripperStatus(state=1, width=0.1)
    reply = message_from_json({"name": "ACME_GRIP", "comm_type": 3, "body": {"state": 0}})
    assert type(reply) is AcmeGripReply and reply.state == GripState.OPEN


def test_cli_decodes_and_encodes_vendor_messages(
    acme: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = tmp_path / "acme.txt"
    frames.write_text(f"GRIP {GRIP_FRAMES['BE64']}\nSTATUS {STATUS_FRAMES['BE64']}\n")
    assert main(["decode", "--byte-order", "big", "--float64", str(frames)]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    grip, status = (json.loads(line) for line in out.splitlines())
    assert grip == {
        "msg_type": ACME_GRIP,
        "name": "ACME_GRIP",
        "comm_type": 2,
        "reply_code": 0,
        "body": {"tool": 2, "width": 0.25, "force": 40.0},
        "names": {"comm_type": "SERVICE_REQUEST", "reply_code": "INVALID"},
        "line": 1,
        "label": "GRIP",
    }
    assert status["name"] == "ACME_GRIPPER_STATUS" and status["body"]["state"] == GripState.HOLDING

    lines = tmp_path / "acme.jsonl"
    lines.write_text(
        json.dumps({"name": "ACME_GRIP", "body": {"tool": 2, "width": 0.25, "force": 40.0}})
        + "\n"
        + json.dumps({"name": "acme_status", "body": {"tool": 1, "state": 2, "width": 0.5, "force": -12.5}})
        + "\n"
    )
    assert main(["encode", str(lines)]) == 0
    out, err = capsys.readouterr()
    assert err == "" and out.split() == [GRIP_FRAMES["LE32"], STATUS_FRAMES["LE32"]]


def test_cli_import_option_loads_a_vendor_module(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--import MODULE`` is how a vendor set reaches the command from the shell."""
    (tmp_path / "acme_vendor_shim.py").write_text(
        f"from {__name__} import register_acme\n\nregister_acme()\n", encoding="utf-8"
    )
    (tmp_path / "acme_broken_shim.py").write_text("raise RuntimeError('boom')\n", encoding="utf-8")
    frames = tmp_path / "acme.txt"
    frames.write_text(STATUS_FRAMES["LE32"] + "\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        with scoped_registry():
            assert main(["decode", str(frames)]) == 0
            assert json.loads(capsys.readouterr().out)["name"] == "UNKNOWN"  # not registered yet
            assert main(["decode", "--import", "acme_vendor_shim", str(frames)]) == 0
            obj = json.loads(capsys.readouterr().out)
            assert obj["name"] == "ACME_GRIPPER_STATUS" and obj["body"]["width"] == 0.5
        assert lookup(ACME_GRIPPER_STATUS) is None
        assert main(["encode", "--import", "acme_broken_shim", str(frames)]) == 2
        _, err = capsys.readouterr()
        error = json.loads(err)
        assert error["type"] == "RuntimeError" and "acme_broken_shim" in error["error"]
    finally:
        sys.modules.pop("acme_vendor_shim", None)
        sys.modules.pop("acme_broken_shim", None)


def test_conflicting_registrations_are_refused(acme: None) -> None:
    @dataclass(frozen=True, slots=True)
    class OtherGrip(Message):
        MSG_TYPE: ClassVar[int] = ACME_GRIP

    @dataclass(frozen=True, slots=True)
    class Elsewhere(Message):
        MSG_TYPE: ClassVar[int] = 1703

    with pytest.raises(RegistrationError, match="msg_type 1701 is already registered as ACME_GRIP") as info:
        register(OtherGrip)
    assert isinstance(info.value, SimpleMessageError) and isinstance(info.value, ValueError)
    assert lookup(ACME_GRIP).request is AcmeGrip  # type: ignore[union-attr]  # nothing changed
    with pytest.raises(RegistrationError, match="already registered as STATUS"):
        register(Status, converters={"mode": RobotMode})  # differs from the built-in registration
    with pytest.raises(RegistrationError, match="'ACME_GRIP' is already msg_type 1701's"):
        register(Elsewhere, name="ACME_GRIP")
    with pytest.raises(RegistrationError, match="'ACME_STATUS' is already msg_type 1702's"):
        register(Elsewhere, aliases=("ACME_STATUS",))
    with pytest.raises(RegistrationError, match="'ROBOT_STATUS' is already msg_type 13's"):
        register(Elsewhere, name="ROBOT_STATUS")  # MsgType's names are taken too
    assert lookup(1703) is None and type_name(1703) is None
    # the same registration again is a no-op (a module imported twice)
    assert register(AcmeGrip, AcmeGripReply, converters={"state": GripState}) is lookup(ACME_GRIP)


def test_replace_recompiles_the_converters(acme: None) -> None:
    frame = STATUS.encode(LE64)
    assert decode(frame, LE64).state is GripState.HOLDING  # type: ignore[attr-defined]  # codec compiled
    register(AcmeGripperStatus, name="ACME_GS", replace=True)  # no converters now
    plain = decode(frame, LE64)
    assert plain.state == 2 and type(plain.state) is int  # type: ignore[attr-defined]
    assert plain.name == "ACME_GS" and type_for_name("ACME_STATUS") is None
    register(AcmeGripperStatus, converters={"state": GripState}, replace=True)
    assert decode(frame, LE64).state is GripState.HOLDING  # type: ignore[attr-defined]


def test_malformed_registrations_are_refused() -> None:
    @dataclass(frozen=True, slots=True)
    class NoType(Message):
        value: int = 0
        LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "i"),)

    @dataclass(frozen=True, slots=True)
    class Mismatch(Message):
        MSG_TYPE: ClassVar[int] = 1710

    class NotADataclass(Message):
        MSG_TYPE: ClassVar[int] = 1711

    cases: list[tuple[object, dict[str, object], str]] = [
        (NoType, {}, "nonzero int32"),
        (AcmeGrip, {"reply": Mismatch}, "Mismatch.MSG_TYPE is 1710"),
        (AcmeGrip, {"converters": {"nope": GripState}}, "no LAYOUT field of that name"),
        (AcmeGrip, {"converters": {"width": GripState}}, "not an int"),
        (AcmeGripReply, {"converters": {"state": str}}, "IntEnum or IntFlag"),
        (AcmeGripReply, {"converters": {"state": {"1": "x"}}}, "wire ints"),
        (AcmeGrip, {"name": "acme grip"}, "upper case"),
        (AcmeGrip, {"aliases": ("ACME_GRIP",)}, "repeat"),
        (HeaderOnly, {}, "shape of any type"),
        (int, {}, "subclass of Message"),
        (NotADataclass, {}, "dataclass"),
    ]
    with scoped_registry():
        for cls, kwargs, reason in cases:
            with pytest.raises(RegistrationError, match=reason):
                register(cls, **kwargs)  # type: ignore[arg-type]
            assert lookup(ACME_GRIP) is None and lookup(1710) is None and lookup(1711) is None


def test_unregister_and_scoped_registry(acme: None) -> None:
    with scoped_registry():
        assert unregister(ACME_GRIP).request is AcmeGrip
        back = decode(GRIP.encode(), LE32)
        assert isinstance(back, RawMessage) and back.name == "UNKNOWN"
        assert GRIP.name == "UNKNOWN" and type_for_name("ACME_GRIP") is None
        unregister(MsgType.STATUS)  # built-ins are registrations like any other
        raw = decode(Status(1, 0, 0, 0, 0, 2, 1).encode(), LE32)
        assert isinstance(raw, RawMessage) and raw.name == "STATUS"  # MsgType still names it
        with pytest.raises(RegistrationError, match="not registered"):
            unregister(MsgType.STATUS)
    assert decode(GRIP.encode(), LE32) == GRIP
    status = decode(Status(1, 0, 0, 0, 0, 2, 1).encode(), LE32)
    assert isinstance(status, Status) and status.mode is RobotMode.AUTO


def test_builtin_converters_are_registered_with_their_messages() -> None:
    status = lookup(MsgType.STATUS)
    assert status is not None and status.request is Status
    assert set(status.converters) == {
        "drives_powered",
        "e_stopped",
        "in_error",
        "in_motion",
        "mode",
        "motion_possible",
    }
    assert status.converters["drives_powered"][-1] is TriState.UNKNOWN
    feedback = lookup(MsgType.JOINT_FEEDBACK)
    assert feedback is not None and feedback.request is JointFeedback
    assert feedback.converters["valid_fields"] == {v: ValidFields(v) for v in range(16)}


def test_the_registry_outside_the_fixture_is_the_builtin_one() -> None:
    """The acme fixture's registrations never leak into other tests."""
    assert len(message_types()) == BUILTIN_TYPES and len(MESSAGE_CLASSES) == BUILTIN_TYPES
    assert lookup(ACME_GRIP) is None and type_name(ACME_GRIPPER_STATUS) is None
    assert all(lookup(t.msg_type) is t for t in message_types())
    assert {type_name(int(m)) for m in MsgType} >= {"PING", "READ_INPUT", "INVALID"}


@pytest.mark.parametrize("wire", [LE32, BE64], ids=str)
def test_float64_and_both_byte_orders_decode_to_the_same_vendor_message(acme: None, wire: WireFormat) -> None:
    assert decode(STATUS.encode(wire), wire) == STATUS
