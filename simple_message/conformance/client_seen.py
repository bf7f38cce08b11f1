"""What the client suite's rules see: the client's points and STOPs, and its connections.

The proxy (:mod:`.client`) hands the observer (:mod:`.client_rules`) every frame the client sends;
those of the motion port that are a trajectory point or a STOP become a :class:`Point` (:func:`point_of`),
which the rules annotate as they judge it (its trajectory, whether it starts one or is sent again,
the reply's outcome once it reached the client, where the robot was). A :class:`LinkState` is what
the rules know about one of the client's connections: the requests awaiting their reply, the
trajectory under way, the points acknowledged. The small functions the rules compare points with
(the same positions, a reply's outcome) and show them by (a frame as evidence, capped) are here too.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

from ..constants import CommType, MotoCommand, MotoResult, MsgType, ReplyCode, SpecialSeq
from ..errors import MalformedMessage
from ..messages import (
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
)
from ..wire import WireFormat
from .report import Evidence

__all__ = ["SAME", "Group", "LinkState", "Point", "Positions", "Prev", "frame_evidence", "point_of"]

#: points waiting for the next joint state, and point requests remembered in flight per connection
MAX_WAITING = 64
#: the longest frame shown whole in the evidence (bytes)
MAX_SHOWN = 1024
#: values the same within this are the same point (float32 on the wire is far coarser)
SAME = 1e-6

STOP_SEQ = int(SpecialSeq.STOP_TRAJECTORY)
#: the sequences a trajectory starts with: 0 streamed, -1 a download, -2 MotoROS-style streaming
START_SEQS = (0, int(SpecialSeq.START_TRAJECTORY_DOWNLOAD), int(SpecialSeq.START_TRAJECTORY_STREAMING))
_POINT_TYPES = frozenset({MsgType.JOINT_TRAJ_PT, MsgType.JOINT_TRAJ_PT_FULL, MsgType.JOINT_TRAJ_PT_FULL_EX})

Positions = tuple[float, ...]


@dataclass(frozen=True)
class Group:
    """One motion group of a JOINT_TRAJ_PT_FULL(_EX): what the field and speed checks need."""

    group: int
    valid_fields: int
    time: float
    positions: Positions
    velocities: Positions


@dataclass(eq=False)
class Point:
    """A trajectory point or a STOP the client sent on the motion port."""

    link: LinkState
    frame: bytes
    msg: Message | MalformedMessage
    #: "point", "stop" or "malformed" (a point type whose body fits no layout)
    kind: str
    seq: int | None
    #: a SERVICE_REQUEST (awaits a reply)
    request: bool
    #: group 0's positions (None: the point carries none for group 0)
    positions: Positions | None
    groups: tuple[Group, ...]
    trajectory: int = 0
    #: the first point of a trajectory (sequence 0, -1 or -2)
    start: bool = False
    #: the previous point sent again after BUSY or FAILURE (not a repeat, nor a new trajectory)
    retry: bool = False
    #: the robot's position when it arrived, and at the next joint state after
    here: Positions | None = None
    after: Positions | None = None
    #: the reply's outcome once it reached the client: "success", "busy", "failure"
    outcome: str | None = None
    #: the injection that answered it, if any
    injected: str | None = None
    #: the first point-ish message of a motion connection after another one (the reconnect rule)
    reconnect: bool = False
    resolved: bool = False

    @property
    def what(self) -> str:
        if self.kind == "stop":
            return "STOP"
        if self.seq is None:
            return "a malformed point"
        return f"point {self.seq}"


@dataclass(eq=False)
class Prev:
    """The last point of a group in the current trajectory, for the time and speed checks."""

    seq: int
    time: float
    positions: Positions
    velocities: Positions
    point: Point
    #: the implied speed (per joint) of the segment that ends at it, if any
    before: Positions | None = None


@dataclass(eq=False)
class LinkState:
    """What the rules know about one of the client's connections."""

    id: int
    role: str
    peer: str
    #: 1 for the first motion connection of the run, 2 for the next...
    motion_index: int = 0
    #: point requests whose reply has not reached the client (the latest few: enough to show one)
    in_flight: deque[Point] = field(default_factory=lambda: deque(maxlen=MAX_WAITING))
    #: None (no trajectory under way), "stream" or "download"
    mode: str | None = None
    last: Point | None = None
    trajectory: int = 0
    acked: dict[int, Positions] = field(default_factory=dict)
    pending_stop: Point | None = None
    after_stop: Point | None = None
    seen_point: bool = False
    prev: dict[int, Prev] = field(default_factory=dict)
    #: the cutter gave up on this connection's bytes (warned once)
    uncut: bool = False
    #: the last JOINT_TRAJ_PT's positions (a segment's timing is judged against them)
    jtp_positions: Positions | None = None

    @property
    def name(self) -> str:
        return f"{self.role} connection {self.id} ({self.peer})"


def max_gap(a: Positions, b: Positions) -> float:
    return max((abs(x - y) for x, y in zip(a, b, strict=False)), default=0.0)


def same(a: Positions | None, b: Positions | None) -> bool:
    return a is not None and b is not None and max_gap(a, b) <= SAME


def same_positions(a: Point, b: Point) -> bool:
    """The same positions in every group (a point sent again)."""
    if a.groups or b.groups:
        key_a = sorted((g.group, g.positions) for g in a.groups)
        key_b = sorted((g.group, g.positions) for g in b.groups)
        return len(key_a) == len(key_b) and all(
            ga == gb and same(pa, pb) for (ga, pa), (gb, pb) in zip(key_a, key_b, strict=True)
        )
    return same(a.positions, b.positions)


def finite(values: Iterable[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def outcome(reply: Message | MalformedMessage) -> str:
    """A reply's meaning for the client: MotoROS's result (0 success, 1 BUSY), else the reply_code."""
    if isinstance(reply, MotoMotionReply):
        if reply.result == MotoResult.SUCCESS:
            return "success"
        return "busy" if reply.result == MotoResult.BUSY else "failure"
    if isinstance(reply, MalformedMessage):
        return "failure"
    return "success" if reply.reply_code == ReplyCode.SUCCESS else "failure"


def groups_of(msg: Message) -> tuple[Group, ...]:
    if isinstance(msg, JointTrajPtFull):
        return (Group(msg.robot_id, int(msg.valid_fields), msg.time, msg.positions, msg.velocities),)
    if isinstance(msg, JointTrajPtFullEx):
        return tuple(
            Group(g.group_no, int(g.valid_fields), g.time, g.positions, g.velocities) for g in msg.valid_groups
        )
    return ()


def group0(msg: Message, groups: tuple[Group, ...]) -> Positions | None:
    if isinstance(msg, JointTrajPt):
        return msg.joint_data
    for group in groups:
        if group.group == 0:
            return group.positions
    return None


def point_of(link: LinkState, frame: bytes, msg: Message | MalformedMessage) -> Point | None:
    """The point or STOP in a frame the client sent on the motion port (None: it is neither)."""
    request = msg.comm_type == CommType.SERVICE_REQUEST
    if isinstance(msg, MalformedMessage):
        if msg.msg_type not in _POINT_TYPES:
            return None
        return Point(link, frame, msg, "malformed", None, request, None, ())
    if isinstance(msg, MotoMotionCtrl):
        if msg.command != MotoCommand.STOP_MOTION:
            return None
        return Point(link, frame, msg, "stop", msg.sequence, request, None, ())
    if not isinstance(msg, JointTrajPt | JointTrajPtFull | JointTrajPtFullEx):
        return None
    groups = groups_of(msg)
    kind = "stop" if msg.sequence == STOP_SEQ else "point"
    return Point(link, frame, msg, kind, msg.sequence, request, group0(msg, groups), groups)


def frame_evidence(direction: str, frame: bytes, msg: Message | MalformedMessage | None, wire: WireFormat) -> Evidence:
    """A frame as evidence (decoded when it decodes), cut at :data:`MAX_SHOWN` bytes."""
    decoded = msg if isinstance(msg, Message) else None
    if len(frame) <= MAX_SHOWN:
        return Evidence.frame(direction, frame, decoded, wire.real_size)
    shown = Evidence.frame(direction, frame[:MAX_SHOWN], None, wire.real_size)
    return Evidence(shown.kind, f"{shown.text}... ({len(frame)} bytes)")


def type_name(point: Point) -> str:
    msg_type = point.msg.msg_type or 0
    try:
        return MsgType(msg_type).name
    except ValueError:
        return str(msg_type)


def fmt(positions: Positions | None) -> str:
    if positions is None:
        return "(unknown)"
    return "[" + ", ".join(f"{v:.4g}" for v in positions) + "]"
