"""The standard ROS-Industrial messages (docs/reference/protocol.md §2.2): PING to JOINT_FEEDBACK.

PING, GET_VERSION, JOINT_POSITION, JOINT_TRAJ_PT, JOINT_TRAJ (and its :class:`TrajPoint`), STATUS,
JOINT_TRAJ_PT_FULL and JOINT_FEEDBACK, in the layouts of the C++ library, which every peer follows.
The classes only; :mod:`simple_message.messages` registers them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from ..constants import MAX_JOINTS, CommType, MsgType, ReplyCode, RobotMode, TriState, ValidFields
from ..errors import LocalProtocolError
from ..wire import WireFormat
from .base import ZEROS, Floats, Message, _normalise_arrays
from .codec import _body_format

__all__ = [
    "Ping",
    "GetVersion",
    "GetVersionReply",
    "JointPosition",
    "JointTrajPt",
    "TrajPoint",
    "JointTraj",
    "Status",
    "JointTrajPtFull",
    "JointFeedback",
    "JOINT_TRAJ_MAX_POINTS",
]


@dataclass(frozen=True, slots=True)
class Ping(Message):
    """PING (1). The C++ library and MotoROS send an empty body (§0 item 2); REP-I0006 documents
    ``data: shared_int[10]``, which is accepted and kept (``data`` is then a 10-tuple of ints)."""

    data: tuple[int, ...] | None = None
    MSG_TYPE: ClassVar[int] = MsgType.PING

    def __post_init__(self) -> None:
        if self.data is not None:
            items = tuple(int(v) for v in self.data)
            if len(items) > MAX_JOINTS:
                raise LocalProtocolError(f"PING data has {len(items)} ints; at most {MAX_JOINTS}")
            object.__setattr__(self, "data", items + (0,) * (MAX_JOINTS - len(items)))

    def body_dict(self) -> dict[str, Any]:
        return {} if self.data is None else {"data": list(self.data)}

    def _encode_body(self, wire: WireFormat) -> bytes:
        if self.data is None:
            return b""
        return wire.struct(f"{MAX_JOINTS}i").pack(*self.data)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        if not body:
            return cls(comm_type=comm_type, reply_code=reply_code)
        s = wire.struct(f"{MAX_JOINTS}i")
        if len(body) != s.size:
            return None
        return cls(s.unpack(body), comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class GetVersion(Message):
    """GET_VERSION (2) request: empty body (REP-I0006; no known peer implements it, §2.1)."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_VERSION


@dataclass(frozen=True, slots=True)
class GetVersionReply(Message):
    """GET_VERSION (2) reply: ``major, minor, patch``."""

    major: int = 0
    minor: int = 0
    patch: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.GET_VERSION
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("major", "i"), ("minor", "i"), ("patch", "i"))


@dataclass(frozen=True, slots=True)
class JointPosition(Message):
    """JOINT_POSITION (10): the state message of the generic nodes, ABB and Fanuc; also Fanuc's
    ack of a JOINT_TRAJ_PT (a SERVICE_REPLY echoing the sequence, §3)."""

    sequence: int = 0
    joint_data: Floats = ZEROS
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_POSITION
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("sequence", "i"), ("joint_data", "r10"))
    ARRAYS: ClassVar[tuple[str, ...]] = ("joint_data",)


@dataclass(frozen=True, slots=True)
class JointTrajPt(Message):
    """JOINT_TRAJ_PT (11): one point, a velocity ratio in (0, 1] and a segment duration (§4.3)."""

    sequence: int = 0
    joint_data: Floats = ZEROS
    velocity: float = 0.0
    duration: float = 0.0
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ_PT
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("sequence", "i"),
        ("joint_data", "r10"),
        ("velocity", "r"),
        ("duration", "r"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("joint_data",)


@dataclass(frozen=True, slots=True)
class TrajPoint:
    """One point inside a JOINT_TRAJ (12) message: the JOINT_TRAJ_PT body without a header."""

    sequence: int = 0
    joint_data: Floats = ZEROS
    velocity: float = 0.0
    duration: float = 0.0

    def __post_init__(self) -> None:
        _normalise_arrays(self, ("joint_data",))


#: A JOINT_TRAJ point is laid out as a JOINT_TRAJ_PT body.
_TRAJ_POINT = _body_format(JointTrajPt.LAYOUT)
#: JOINT_TRAJ holds at most this many points (``JointTraj::MAX_NUM_POINTS``).
JOINT_TRAJ_MAX_POINTS = 200


@dataclass(frozen=True, slots=True)
class JointTraj(Message):
    """JOINT_TRAJ (12), deprecated and unused by any peer, in the C++ library's layout: the points
    (52 bytes each in float32), then the point count as the *last* int32 (§2.2). At most 200."""

    points: tuple[TrajPoint, ...] = ()
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ

    def __post_init__(self) -> None:
        points = tuple(
            p if isinstance(p, TrajPoint) else TrajPoint(**p) if isinstance(p, Mapping) else TrajPoint(*p)
            for p in self.points
        )
        if len(points) > JOINT_TRAJ_MAX_POINTS:
            raise LocalProtocolError(f"JOINT_TRAJ holds at most {JOINT_TRAJ_MAX_POINTS} points, not {len(points)}")
        object.__setattr__(self, "points", points)

    def _encode_body(self, wire: WireFormat) -> bytes:
        s = wire.struct(_TRAJ_POINT)
        parts = [s.pack(p.sequence, *p.joint_data, p.velocity, p.duration) for p in self.points]
        parts.append(wire.struct("i").pack(len(self.points)))
        return b"".join(parts)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        s = wire.struct(_TRAJ_POINT)
        if len(body) < 4 or (len(body) - 4) % s.size:
            return None
        (count,) = wire.struct("i").unpack_from(body, len(body) - 4)
        if count != (len(body) - 4) // s.size or count > JOINT_TRAJ_MAX_POINTS:
            return None
        points = []
        for k in range(count):
            v = s.unpack_from(body, k * s.size)
            points.append(TrajPoint(v[0], v[1:11], v[11], v[12]))
        return cls(tuple(points), comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class Status(Message):
    """STATUS (13): the controller's tristates, alarm code and mode (§5)."""

    drives_powered: int = TriState.UNKNOWN
    e_stopped: int = TriState.UNKNOWN
    error_code: int = 0
    in_error: int = TriState.UNKNOWN
    in_motion: int = TriState.UNKNOWN
    mode: int = RobotMode.UNKNOWN
    motion_possible: int = TriState.UNKNOWN
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.STATUS
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("drives_powered", "i"),
        ("e_stopped", "i"),
        ("error_code", "i"),
        ("in_error", "i"),
        ("in_motion", "i"),
        ("mode", "i"),
        ("motion_possible", "i"),
    )


@dataclass(frozen=True, slots=True)
class JointTrajPtFull(Message):
    """JOINT_TRAJ_PT_FULL (14): time from start plus positions, velocities and accelerations, of
    which ``valid_fields`` says which are meaningful (§2.2)."""

    robot_id: int = 0
    sequence: int = 0
    valid_fields: int = ValidFields.NONE
    time: float = 0.0
    positions: Floats = ZEROS
    velocities: Floats = ZEROS
    accelerations: Floats = ZEROS
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ_PT_FULL
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("sequence", "i"),
        ("valid_fields", "i"),
        ("time", "r"),
        ("positions", "r10"),
        ("velocities", "r10"),
        ("accelerations", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("positions", "velocities", "accelerations")


@dataclass(frozen=True, slots=True)
class JointFeedback(Message):
    """JOINT_FEEDBACK (15): like JOINT_TRAJ_PT_FULL without a sequence (§2.2)."""

    robot_id: int = 0
    valid_fields: int = ValidFields.NONE
    time: float = 0.0
    positions: Floats = ZEROS
    velocities: Floats = ZEROS
    accelerations: Floats = ZEROS
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_FEEDBACK
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("valid_fields", "i"),
        ("time", "r"),
        ("positions", "r10"),
        ("velocities", "r10"),
        ("accelerations", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("positions", "velocities", "accelerations")
