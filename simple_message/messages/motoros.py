"""Yaskawa MotoROS's messages (docs/reference/protocol.md §8.1): 2001 to 2020.

Motion control and its reply (MOTO_MOTION_CTRL, MOTO_MOTION_REPLY), the IO and M-register reads and
writes, the multi-group points and feedback (JOINT_TRAJ_PT_FULL_EX, JOINT_FEEDBACK_EX, each group an
:class:`ExGroup`), SELECT_TOOL and GET_DH_PARAMETERS (each axis a :class:`DhLink`), in the layouts
MotoROS sends and accepts. The classes only; :mod:`simple_message.messages` registers them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar, cast

from ..constants import MOTO_MAX_GROUPS, CommType, MotoResult, MsgType, ReplyCode, ValidFields
from ..errors import LocalProtocolError
from ..wire import WireFormat
from .base import ZEROS, Floats, Message, _normalise_arrays
from .codec import _body_format
from .registry import _converter_table
from .standard import JointFeedback

__all__ = [
    "MotoMotionCtrl",
    "MotoMotionReply",
    "ReadSingleIo",
    "ReadSingleIoReply",
    "WriteSingleIo",
    "WriteSingleIoReply",
    "ReadGroupIo",
    "ReadGroupIoReply",
    "WriteGroupIo",
    "WriteGroupIoReply",
    "IoCtrlReply",
    "ReadMRegister",
    "ReadMRegisterReply",
    "WriteMRegister",
    "WriteMRegisterReply",
    "ExGroup",
    "JointTrajPtFullEx",
    "JointFeedbackEx",
    "SelectTool",
    "GetDhParameters",
    "GetDhParametersReply",
    "DhLink",
    "DH_AXES",
]

#: valid_fields of the EX groups (ExGroup is no message, so it converts this one field itself).
_VALID = _converter_table(ValidFields)


@dataclass(frozen=True, slots=True)
class MotoMotionCtrl(Message):
    """MOTO_MOTION_CTRL (2001): a motion command (:class:`~.constants.MotoCommand`)."""

    group_no: int = 0
    sequence: int = 0
    command: int = 0
    data: Floats = ZEROS
    MSG_TYPE: ClassVar[int] = MsgType.MOTO_MOTION_CTRL
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("group_no", "i"),
        ("sequence", "i"),
        ("command", "i"),
        ("data", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("data",)


@dataclass(frozen=True, slots=True)
class MotoMotionReply(Message):
    """MOTO_MOTION_REPLY (2002): MotoROS's answer to every motion-port message. The header
    reply_code is always SUCCESS; the outcome is ``result`` (0 = success) and ``subcode`` (§0 item
    3). The IO port's error reply uses this type with ``result``/``subcode`` at offsets 0 and 4 (the
    IoCtrlReply layout); it decodes here with those values in ``group_no`` and ``sequence``."""

    group_no: int = 0
    sequence: int = 0
    command: int = 0
    result: int = MotoResult.SUCCESS
    subcode: int = 0
    data: Floats = ZEROS
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.MOTO_MOTION_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("group_no", "i"),
        ("sequence", "i"),
        ("command", "i"),
        ("result", "i"),
        ("subcode", "i"),
        ("data", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("data",)


@dataclass(frozen=True, slots=True)
class ReadSingleIo(Message):
    """READ_SINGLE_IO (2003): read one IO bit at ``address`` (uint32)."""

    address: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.READ_SINGLE_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"),)


@dataclass(frozen=True, slots=True)
class ReadSingleIoReply(Message):
    """READ_SINGLE_IO_REPLY (2004): ``value`` (uint32) and ``result_code`` (:class:`~.constants.IoResult`)."""

    value: int = 0
    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.READ_SINGLE_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "I"), ("result_code", "i"))


@dataclass(frozen=True, slots=True)
class WriteSingleIo(Message):
    """WRITE_SINGLE_IO (2005): write ``value`` to the IO bit at ``address``."""

    address: int = 0
    value: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_SINGLE_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"), ("value", "I"))


@dataclass(frozen=True, slots=True)
class WriteSingleIoReply(Message):
    """WRITE_SINGLE_IO_REPLY (2006): ``result_code``."""

    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_SINGLE_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result_code", "i"),)


@dataclass(frozen=True, slots=True)
class ReadGroupIo(Message):
    """READ_GROUP_IO (2007): read an 8-bit IO group (e.g. address 1001 = OG#1)."""

    address: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.READ_GROUP_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"),)


@dataclass(frozen=True, slots=True)
class ReadGroupIoReply(Message):
    """READ_GROUP_IO_REPLY (2008): ``value`` and ``result_code``."""

    value: int = 0
    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.READ_GROUP_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "I"), ("result_code", "i"))


@dataclass(frozen=True, slots=True)
class WriteGroupIo(Message):
    """WRITE_GROUP_IO (2009): write ``value`` to the IO group at ``address``."""

    address: int = 0
    value: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_GROUP_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"), ("value", "I"))


@dataclass(frozen=True, slots=True)
class WriteGroupIoReply(Message):
    """WRITE_GROUP_IO_REPLY (2010): ``result_code``."""

    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_GROUP_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result_code", "i"),)


@dataclass(frozen=True, slots=True)
class IoCtrlReply(Message):
    """MOTO_IOCTRL_REPLY (2011): ``result`` and ``subcode``. Defined by MotoROS, which in fact sends
    its IO error replies as type 2002 (see :class:`MotoMotionReply`)."""

    result: int = 0
    subcode: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.MOTO_IOCTRL_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result", "i"), ("subcode", "i"))


@dataclass(frozen=True, slots=True)
class ReadMRegister(Message):
    """READ_MREGISTER (2012) request: ``register_number`` (M000-M999)."""

    register_number: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.READ_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("register_number", "I"),)


@dataclass(frozen=True, slots=True)
class ReadMRegisterReply(Message):
    """READ_MREGISTER (2012) SERVICE_REPLY: ``value`` and ``result_code``."""

    value: int = 0
    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.READ_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "I"), ("result_code", "i"))


@dataclass(frozen=True, slots=True)
class WriteMRegister(Message):
    """WRITE_MREGISTER (2013) request: ``register_number`` (M000-M559) and ``value``."""

    register_number: int = 0
    value: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("register_number", "I"), ("value", "I"))


@dataclass(frozen=True, slots=True)
class WriteMRegisterReply(Message):
    """WRITE_MREGISTER (2013) SERVICE_REPLY: ``result_code``."""

    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result_code", "i"),)


@dataclass(frozen=True, slots=True)
class ExGroup:
    """One motion group inside JOINT_TRAJ_PT_FULL_EX (2016) or JOINT_FEEDBACK_EX (2017): the
    JOINT_FEEDBACK body layout, 132 bytes in float32."""

    group_no: int = 0
    valid_fields: int = ValidFields.NONE
    time: float = 0.0
    positions: Floats = ZEROS
    velocities: Floats = ZEROS
    accelerations: Floats = ZEROS

    def __post_init__(self) -> None:
        _normalise_arrays(self, ("positions", "velocities", "accelerations"))

    def pack(self, wire: WireFormat) -> bytes:
        return wire.struct(_EX_GROUP).pack(
            self.group_no, self.valid_fields, self.time, *self.positions, *self.velocities, *self.accelerations
        )

    @classmethod
    def unpack_from(cls, body: bytes, offset: int, wire: WireFormat) -> ExGroup:
        v = wire.struct(_EX_GROUP).unpack_from(body, offset)
        return cls(v[0], _VALID.get(v[1], v[1]), v[2], v[3:13], v[13:23], v[23:33])


#: An EX group is laid out as a JOINT_FEEDBACK body (group_no in robot_id's place).
_EX_GROUP = _body_format(JointFeedback.LAYOUT)


def _ex_groups(groups: Iterable[ExGroup | dict[str, Any]]) -> tuple[ExGroup, ...]:
    return tuple(g if isinstance(g, ExGroup) else ExGroup(**g) for g in groups)


#: The default ``number_of_valid_groups`` of the EX messages: "not given", which the constructor
#: replaces with ``len(groups)``. It is ``None``, not an int, so that every int (-1 included) is a
#: count as given or decoded and re-encodes as itself; typed ``int`` because no instance keeps it.
_COUNT_OF_GROUPS = cast(int, None)


@dataclass(frozen=True, slots=True)
class JointTrajPtFullEx(Message):
    """JOINT_TRAJ_PT_FULL_EX (2016): one point for up to 4 motion groups, no per-group sequence.

    MotoROS accepts the short form (``8 + n x 132`` bytes, ``len(groups) == number_of_valid_groups``)
    and the full form (always 4 groups, 536 bytes). ``groups`` holds what is on the wire, so both
    forms re-encode exactly; ``number_of_valid_groups`` defaults to ``len(groups)`` when omitted, and
    any int given or decoded (-1 and other counts MotoROS refuses included) is kept as it is.
    """

    number_of_valid_groups: int = _COUNT_OF_GROUPS
    sequence: int = 0
    groups: tuple[ExGroup, ...] = ()
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ_PT_FULL_EX

    def __post_init__(self) -> None:
        groups = _ex_groups(self.groups)
        if len(groups) > MOTO_MAX_GROUPS:
            raise LocalProtocolError(f"at most {MOTO_MAX_GROUPS} groups, not {len(groups)}")
        object.__setattr__(self, "groups", groups)
        if self.number_of_valid_groups is _COUNT_OF_GROUPS:
            object.__setattr__(self, "number_of_valid_groups", len(groups))

    @property
    def valid_groups(self) -> tuple[ExGroup, ...]:
        return self.groups[: max(0, self.number_of_valid_groups)]

    def _encode_body(self, wire: WireFormat) -> bytes:
        head = wire.struct("ii").pack(self.number_of_valid_groups, self.sequence)
        return head + b"".join(g.pack(wire) for g in self.groups)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        size = wire.struct(_EX_GROUP).size
        if len(body) < 8 or (len(body) - 8) % size:
            return None
        count = (len(body) - 8) // size
        n, seq = wire.struct("ii").unpack_from(body, 0)
        if count > MOTO_MAX_GROUPS or count not in (n, MOTO_MAX_GROUPS):
            return None
        groups = tuple(ExGroup.unpack_from(body, 8 + k * size, wire) for k in range(count))
        return cls(n, seq, groups, comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class JointFeedbackEx(Message):
    """JOINT_FEEDBACK_EX (2017): ``number_of_valid_groups`` then always 4 JOINT_FEEDBACK bodies
    (532 bytes in float32). Fewer groups given to the constructor are padded with zero groups;
    ``number_of_valid_groups`` defaults to the number of groups given (before padding) when omitted,
    and any int given or decoded (-1 included) is kept as it is."""

    number_of_valid_groups: int = _COUNT_OF_GROUPS
    groups: tuple[ExGroup, ...] = ()
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_FEEDBACK_EX

    def __post_init__(self) -> None:
        groups = _ex_groups(self.groups)
        if len(groups) > MOTO_MAX_GROUPS:
            raise LocalProtocolError(f"at most {MOTO_MAX_GROUPS} groups, not {len(groups)}")
        if self.number_of_valid_groups is _COUNT_OF_GROUPS:
            object.__setattr__(self, "number_of_valid_groups", len(groups))
        object.__setattr__(self, "groups", groups + (ExGroup(),) * (MOTO_MAX_GROUPS - len(groups)))

    @property
    def valid_groups(self) -> tuple[ExGroup, ...]:
        return self.groups[: max(0, self.number_of_valid_groups)]

    def _encode_body(self, wire: WireFormat) -> bytes:
        return wire.struct("i").pack(self.number_of_valid_groups) + b"".join(g.pack(wire) for g in self.groups)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        size = wire.struct(_EX_GROUP).size
        if len(body) != 4 + MOTO_MAX_GROUPS * size:
            return None
        (n,) = wire.struct("i").unpack_from(body, 0)
        groups = tuple(ExGroup.unpack_from(body, 4 + k * size, wire) for k in range(MOTO_MAX_GROUPS))
        return cls(n, groups, comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class SelectTool(Message):
    """SELECT_TOOL (2018): ``group_no``, ``tool`` (0..63), ``sequence``."""

    group_no: int = 0
    tool: int = 0
    sequence: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.SELECT_TOOL
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("group_no", "i"), ("tool", "i"), ("sequence", "i"))


@dataclass(frozen=True, slots=True)
class GetDhParameters(Message):
    """GET_DH_PARAMETERS (2020) request: empty body."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_DH_PARAMETERS


@dataclass(frozen=True, slots=True)
class DhLink:
    """One axis of a GET_DH_PARAMETERS reply, in MotoPlus order."""

    theta: float = 0.0
    d: float = 0.0
    a: float = 0.0
    alpha: float = 0.0


#: Axes per group in MotoPlus's DH_PARAMETERS (``MAX_PULSE_AXES``). The SDK header is not public, but
#: MotoROS always sends 4 groups of 8 (a 512-byte body with float32) and MotoROS clients (the Python
#: ``moto`` package) parse exactly that, so a reply always carries 8 axes per group, unused ones 0.
#: Decoding still accepts fewer axes per group (derived from the body size) and pads them.
DH_AXES = 8


@dataclass(frozen=True, slots=True)
class GetDhParametersReply(Message):
    """GET_DH_PARAMETERS (2020) reply: 4 groups x 8 axes x (theta, d, a, alpha) reals (missing groups
    and axes are zero; a group of more than ``axes`` axes is an error). MotoROS sends 8 axes per
    group (``MAX_PULSE_AXES``, unverified); a reply with fewer per group decodes with ``axes`` set
    to their number, so it re-encodes to the same bytes."""

    groups: tuple[tuple[DhLink, ...], ...] = ()
    #: axes per group on the wire (1..8)
    axes: int = field(default=DH_AXES, kw_only=True)
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.GET_DH_PARAMETERS

    def __post_init__(self) -> None:
        groups = tuple(
            tuple(
                link if isinstance(link, DhLink) else DhLink(**link) if isinstance(link, dict) else DhLink(*link)
                for link in g
            )
            for g in self.groups
        )
        if len(groups) > MOTO_MAX_GROUPS:
            raise LocalProtocolError(f"at most {MOTO_MAX_GROUPS} groups, not {len(groups)}")
        axes = self.axes
        if not 1 <= axes <= DH_AXES:
            raise LocalProtocolError(f"a GET_DH_PARAMETERS reply has 1 to {DH_AXES} axes per group, not {axes}")
        if any(len(g) > axes for g in groups):
            raise LocalProtocolError(f"at most {axes} axes per group, not {max(len(g) for g in groups)}")
        padded = tuple(g + (DhLink(),) * (axes - len(g)) for g in groups)
        padded += ((DhLink(),) * axes,) * (MOTO_MAX_GROUPS - len(padded))
        object.__setattr__(self, "groups", padded)

    def _encode_body(self, wire: WireFormat) -> bytes:
        s = wire.struct("rrrr")
        return b"".join(s.pack(k.theta, k.d, k.a, k.alpha) for g in self.groups for k in g)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        s = wire.struct("rrrr")
        if not body or len(body) % (MOTO_MAX_GROUPS * s.size) or len(body) > MOTO_MAX_GROUPS * DH_AXES * s.size:
            return None
        axes = len(body) // (MOTO_MAX_GROUPS * s.size)
        groups = tuple(
            tuple(DhLink(*s.unpack_from(body, (g * axes + k) * s.size)) for k in range(axes))
            for g in range(MOTO_MAX_GROUPS)
        )
        return cls(groups, axes=axes, comm_type=comm_type, reply_code=reply_code)
