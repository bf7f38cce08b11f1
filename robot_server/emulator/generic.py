"""The generic profile: what the ROS-Industrial generic nodes, ABB and the reference library speak.

**Motion port** (docs/reference/protocol.md §3, §4):

* JOINT_TRAJ_PT and JOINT_TRAJ_PT_FULL (``robot_id`` picks the motion group) as SERVICE_REQUEST:
  streaming, stop-and-wait. Each point is answered once, in order, SUCCESS when it was queued and
  FAILURE when the controller refused it (limits, NaN, joint count, start mismatch, alarm...), in
  which case nothing moved. When the queue is full the reply is *delayed* until there is room: the
  generic client cannot handle FAILURE (§10 pitfall 6), and waiting is the flow control it does
  understand. A point that waits across a STOP or a fault is not run and gets FAILURE.
* The same points as TOPIC: a download, -1 first and -3 last (§4.4); it runs at -3, and a refused
  point drops the whole download. A TOPIC point outside a download is ignored with a warning (no
  flow control is possible without replies).
* STOP (sequence -4): obeyed the moment it is read, ahead of anything queued, also while an
  earlier point waits for room; then acknowledged in order (§10 pitfall 5).
* CARTESIAN_LINE (65001, this project's extension, docs/protocol.md) as SERVICE_REQUEST: a
  straight line of the tool run by the controller (``robot_server.control.cartesian``), streamed
  like JOINT_TRAJ_PT: sequence 0 starts a series, each next line is the last + 1, -4 stops at once
  (braking along the line). Each is answered with a CARTESIAN_LINE reply whose ``result`` says why
  a refused line was refused (LineResult); SUCCESS/FAILURE in the header as for points. A full line
  queue delays the reply, as for points.
* PING: SUCCESS with an empty body. Other requests: FAILURE, header-only (the C++ library's reply).

Replies echo the request body (the C++ library's style, the ``generic`` dialect) or are header-only
(ABB's RAPID server, ``--reply-style header``), §3: the server's reply style, not the handlers'.

**State port**: JOINT_POSITION and STATUS at the state rate to every client. JOINT_FEEDBACK (time,
positions, velocities, accelerations of each group, all four valid bits set) goes to every client
with ``feedback=True``, and otherwise to the clients that ask for it by sending a JOINT_FEEDBACK
message (any body; as a SERVICE_REQUEST it is answered SUCCESS) on the state port. TOOL_POSE
(65002, this project's extension: the actual TCP pose and speed of each group, as of the last
interpolation instant) goes only to the clients that ask for it the same way, by sending a
TOOL_POSE: a client that never asks never receives a message it does not know.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Iterable, Mapping

from simple_message.constants import CommType, LineResult, MsgType, ReplyCode, SpecialSeq, ValidFields
from simple_message.dialects import GENERIC
from simple_message.endpoints import Server, Session
from simple_message.messages import (
    CartesianLine,
    CartesianLineReply,
    HeaderOnly,
    JointFeedback,
    JointPosition,
    JointTrajPtFull,
    Message,
    Status,
    ToolPose,
)

from ..control import LineTarget, Point, PointRejected, Reason
from .cell import RobotCell
from .points import point_from_message
from .profiles import STATE_LINK, EmulatorProfile, ProfileContext, register_profile

__all__ = ["GenericMotion", "GenericState", "GenericBehaviour", "GENERIC_PROFILE", "FEEDBACK_FIELDS"]

log = logging.getLogger(__name__)

FEEDBACK_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY | ValidFields.ACCELERATION
_WANTS_FEEDBACK = "joint_feedback"
_WANTS_TOOL = "tool_pose"

#: the reply's result for each reason the controller gives
_LINE_RESULTS = {
    Reason.NOT_READY: LineResult.NOT_READY,
    Reason.BUSY: LineResult.BUSY,
    Reason.SEQUENCE: LineResult.SEQUENCE,
    Reason.UNREACHABLE: LineResult.UNREACHABLE,
    Reason.SINGULAR: LineResult.SINGULAR,
    Reason.POSITION_LIMIT: LineResult.JOINT_LIMIT,
    Reason.VELOCITY_LIMIT: LineResult.JOINT_LIMIT,
    Reason.ACCELERATION_LIMIT: LineResult.JOINT_LIMIT,
    Reason.WORKSPACE: LineResult.WORKSPACE,
    Reason.TCP_SPEED: LineResult.TCP_SPEED,
}


class GenericMotion:
    """Motion-port handlers of the generic profile (see the module doc)."""

    def __init__(self, cell: RobotCell) -> None:
        self.cell = cell

    def install(self, server: Server) -> None:
        for msg_type in (MsgType.JOINT_TRAJ_PT, MsgType.JOINT_TRAJ_PT_FULL):
            server.handle(msg_type, self.on_point, on_arrival=self.on_arrival)
        server.handle(MsgType.CARTESIAN_LINE, self.on_line, on_arrival=self.on_arrival)

    def on_line(self, msg: Message, session: Session) -> Message | Awaitable[Message] | None:
        """A CARTESIAN_LINE: queued, refused with the reason, or (queue full) answered when there is room."""
        assert isinstance(msg, CartesianLine)
        if msg.comm_type != CommType.SERVICE_REQUEST:
            session.log(log, logging.WARNING, "CARTESIAN_LINE %d as a TOPIC ignored (lines are requests)", msg.sequence)
            return None
        if msg.sequence == SpecialSeq.STOP_TRAJECTORY:  # obeyed on arrival
            return _line_reply(msg, LineResult.ACCEPTED)
        target = LineTarget((msg.x, msg.y, msg.z), (msg.qw, msg.qx, msg.qy, msg.qz), msg.speed, msg.blend_radius)
        try:
            self.cell.submit_line(msg.robot_id, msg.sequence, target)
        except PointRejected as exc:
            if exc.reason is Reason.QUEUE_FULL:
                return self._line_when_room(msg, target, session)
            return self._line_refused(msg, session, exc)
        return _line_reply(msg, LineResult.ACCEPTED)

    @staticmethod
    def _line_refused(msg: CartesianLine, session: Session, exc: PointRejected) -> Message:
        session.log(log, logging.WARNING, "CARTESIAN_LINE %d refused: %s", msg.sequence, exc)
        return _line_reply(msg, _LINE_RESULTS.get(exc.reason, LineResult.INVALID))

    async def _line_when_room(self, msg: CartesianLine, target: LineTarget, session: Session) -> Message:
        cell = self.cell
        epoch = cell.interruptions
        while True:
            await cell.changed()
            if cell.interruptions != epoch:
                session.log(log, logging.WARNING, "line %d waited for room across a stop or fault", msg.sequence)
                return _line_reply(msg, LineResult.NOT_READY)
            try:
                cell.submit_line(msg.robot_id, msg.sequence, target)
            except PointRejected as exc:
                if exc.reason is Reason.QUEUE_FULL:
                    continue
                return self._line_refused(msg, session, exc)
            return _line_reply(msg, LineResult.ACCEPTED)

    def on_arrival(self, msg: Message, session: Session) -> None:
        """A STOP acts the moment it is read, before the requests queued ahead of it."""
        if getattr(msg, "sequence", None) == SpecialSeq.STOP_TRAJECTORY:
            stop = self.cell.stop()
            session.log(log, logging.INFO, "STOP: decelerating for %.3f s", stop)

    def on_point(self, msg: Message, session: Session) -> ReplyCode | Awaitable[ReplyCode] | None:
        is_request = msg.comm_type == CommType.SERVICE_REQUEST
        if getattr(msg, "sequence", None) == SpecialSeq.STOP_TRAJECTORY:
            if not is_request:  # a request was obeyed on arrival; a topic is obeyed now
                self.cell.stop()
            return ReplyCode.SUCCESS
        group = msg.robot_id if isinstance(msg, JointTrajPtFull) else 0
        try:
            controller = self.cell.group(group)
            sequence, point = point_from_message(msg, controller.dof)
            if not is_request and not controller.downloading and sequence != SpecialSeq.START_TRAJECTORY_DOWNLOAD:
                session.log(
                    log,
                    logging.WARNING,
                    "%s TOPIC with sequence %d outside a download (-1 ... -3) ignored",
                    msg.name,
                    sequence,
                )
                return None
        except PointRejected as exc:
            return self._refused(msg, session, exc)
        try:
            self.cell.submit(group, sequence, point)
        except PointRejected as exc:
            if exc.reason is Reason.QUEUE_FULL and is_request:
                return self._when_room(group, sequence, point, session)
            return self._refused(msg, session, exc)
        return ReplyCode.SUCCESS

    @staticmethod
    def _refused(msg: Message, session: Session, exc: PointRejected) -> ReplyCode | None:
        session.log(log, logging.WARNING, "%s %d refused: %s", msg.name, getattr(msg, "sequence", 0), exc)
        return ReplyCode.FAILURE if msg.comm_type == CommType.SERVICE_REQUEST else None

    async def _when_room(self, group: int, sequence: int, point: Point, session: Session) -> ReplyCode:
        """Hold the reply until the queue has room (the generic client's only flow control)."""
        cell = self.cell
        epoch = cell.interruptions
        while True:
            await cell.changed()
            if cell.interruptions != epoch:
                session.log(log, logging.WARNING, "point %d waited for room across a stop or fault: not run", sequence)
                return ReplyCode.FAILURE
            try:
                cell.submit(group, sequence, point)
            except PointRejected as exc:
                if exc.reason is Reason.QUEUE_FULL:
                    continue
                session.log(log, logging.WARNING, "point %d refused: %s", sequence, exc)
                return ReplyCode.FAILURE
            return ReplyCode.SUCCESS


class GenericState:
    """State-port messages of the generic profile (see the module doc)."""

    def __init__(self, cell: RobotCell, *, feedback: bool = False) -> None:
        self.cell = cell
        self.feedback = feedback

    def install(self, server: Server, motion: Server | None = None) -> None:
        """The subscriptions on the state port, and on the motion server for the links that carry
        the state topics too (a serial link); a TCP motion client gets FAILURE for them."""
        for msg_type in (MsgType.JOINT_FEEDBACK, MsgType.TOOL_POSE):
            server.handle(msg_type, self._subscribe)
            if motion is not None:
                motion.handle(msg_type, self._subscribe_on_link)

    def _subscribe_on_link(self, msg: Message, session: Session) -> Message | None:
        if not session.data.get(STATE_LINK):  # what an unknown request gets: a header-only FAILURE
            is_request = msg.comm_type == CommType.SERVICE_REQUEST
            return HeaderOnly(msg.msg_type, reply_code=ReplyCode.FAILURE) if is_request else None
        self._subscribe(msg, session)
        return None  # answered SUCCESS in the server's reply style

    def _subscribe(self, msg: Message, session: Session) -> None:
        key = _WANTS_TOOL if msg.msg_type == MsgType.TOOL_POSE else _WANTS_FEEDBACK
        if not session.data.get(key):
            session.log(log, logging.INFO, "%s requested", msg.name)
        session.data[key] = True

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        cell = self.cell
        recipients = list(sessions)
        first = cell.groups[0].command
        server.broadcast(JointPosition(0, tuple(first.actual_position)), recipients)
        server.broadcast(cell.status(), recipients)
        wanting = recipients if self.feedback else [s for s in recipients if s.data.get(_WANTS_FEEDBACK)]
        if wanting:
            for index, controller in enumerate(cell.groups):
                tick = controller.command
                server.broadcast(
                    JointFeedback(
                        index,
                        FEEDBACK_FIELDS,
                        tick.time,
                        tuple(tick.actual_position),
                        tuple(tick.actual_velocity),
                        tuple(tick.actual_acceleration),
                    ),
                    wanting,
                )
        wanting = [s for s in recipients if s.data.get(_WANTS_TOOL)]
        if wanting:
            for index, controller in enumerate(cell.groups):
                tool = controller.tool
                w, x, y, z = tool.actual_orientation
                pose = ToolPose(index, 0, tool.time, *tool.actual_position, x, y, z, w, tool.actual_speed)
                server.broadcast(pose, wanting)


def _line_reply(msg: CartesianLine, result: LineResult) -> CartesianLineReply:
    code = ReplyCode.SUCCESS if result is LineResult.ACCEPTED else ReplyCode.FAILURE
    return CartesianLineReply(
        msg.robot_id, msg.sequence, int(result), comm_type=CommType.SERVICE_REPLY, reply_code=code
    )


class GenericBehaviour:
    """The generic profile's :class:`~.profiles.Behaviour`: its motion and state ports."""

    def __init__(self, context: ProfileContext) -> None:
        self.cell = context.cell
        self.motion = GenericMotion(context.cell)
        self.state = GenericState(context.cell, feedback=context.feedback)

    def install(self, servers: Mapping[str, Server]) -> None:
        self.motion.install(servers["motion"])
        self.state.install(servers["state"], servers["motion"])

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        self.state.publish(server, sessions)

    def status(self) -> Status:
        return self.cell.status()


GENERIC_PROFILE = register_profile(
    EmulatorProfile(
        GENERIC,
        GenericBehaviour,
        description="the generic nodes' controller: JOINT_TRAJ_PT streamed or downloaded, JOINT_POSITION + STATUS",
    )
)
