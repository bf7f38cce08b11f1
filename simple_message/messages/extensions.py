"""This project's own messages, in the range REP-I0004 leaves freely assignable (65001-65535).

CARTESIAN_LINE (65001: a straight line of the TCP, and its reply) and TOOL_POSE (65002: the TCP
pose topic), as ``docs/protocol.md`` ("Project extensions") specifies them. The classes only;
:mod:`simple_message.messages` registers them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from ..constants import CommType, LineResult, MsgType, ReplyCode
from .base import Message

__all__ = ["CartesianLine", "CartesianLineReply", "ToolPose"]


@dataclass(frozen=True, slots=True)
class CartesianLine(Message):
    """CARTESIAN_LINE (65001) request: move the TCP of ``robot_id`` in a straight line to a pose.

    The target is ``x, y, z`` (m, in the cell frame) and the orientation ``qx, qy, qz, qw`` (a unit
    quaternion, Hamilton convention, in the x y z w order of ROS ``geometry_msgs``), reached at the
    TCP linear speed ``speed`` (m/s). ``blend_radius`` (m) lets the TCP leave this line that close
    to its end for the next one; 0 stops exactly at the end. ``sequence`` 0 starts a new series of
    lines, 1, 2, ... continue it, -4 (``SpecialSeq.STOP_TRAJECTORY``) stops, as for JOINT_TRAJ_PT.
    44 bytes in float32, 80 in float64. A TOPIC decodes with this class too; the SERVICE_REPLY is a
    :class:`CartesianLineReply`. Nothing is checked here (NaN included); the controller checks.
    """

    robot_id: int = 0
    sequence: int = 0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    qx: float = 0.0
    qy: float = 0.0
    qz: float = 0.0
    qw: float = 1.0
    speed: float = 0.0
    blend_radius: float = 0.0
    MSG_TYPE: ClassVar[int] = MsgType.CARTESIAN_LINE
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("sequence", "i"),
        ("x", "r"),
        ("y", "r"),
        ("z", "r"),
        ("qx", "r"),
        ("qy", "r"),
        ("qz", "r"),
        ("qw", "r"),
        ("speed", "r"),
        ("blend_radius", "r"),
    )


@dataclass(frozen=True, slots=True)
class CartesianLineReply(Message):
    """CARTESIAN_LINE (65001) SERVICE_REPLY: the request's ``robot_id`` and ``sequence`` and the
    outcome ``result`` (:class:`~.constants.LineResult`, 0 = accepted); 12 bytes. The header
    reply_code is SUCCESS when the line was accepted, FAILURE otherwise."""

    robot_id: int = 0
    sequence: int = 0
    result: int = LineResult.ACCEPTED
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.CARTESIAN_LINE
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("robot_id", "i"), ("sequence", "i"), ("result", "i"))


@dataclass(frozen=True, slots=True)
class ToolPose(Message):
    """TOOL_POSE (65002) topic: the actual TCP pose of ``robot_id`` at controller time ``time`` (s).

    ``tool`` is the active tool number (0 = the model's own tool); ``x, y, z`` (m) and ``qx, qy,
    qz, qw`` (unit quaternion, as in :class:`CartesianLine`) are the TCP pose in the cell frame and
    ``speed`` the TCP's actual linear speed (m/s). 44 bytes in float32, 80 in float64. Sent on the
    state port only to clients that asked for it by sending a TOOL_POSE (docs/protocol.md).
    """

    robot_id: int = 0
    tool: int = 0
    time: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    qx: float = 0.0
    qy: float = 0.0
    qz: float = 0.0
    qw: float = 1.0
    speed: float = 0.0
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.TOOL_POSE
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("tool", "i"),
        ("time", "r"),
        ("x", "r"),
        ("y", "r"),
        ("z", "r"),
        ("qx", "r"),
        ("qy", "r"),
        ("qz", "r"),
        ("qw", "r"),
        ("speed", "r"),
    )
