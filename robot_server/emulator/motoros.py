"""The MotoROS profile: a Yaskawa controller running MotoROS 1.9 (docs/reference/protocol.md §8.1).

**Motion port** (50240). Every message that is not a SERVICE_REPLY is answered with
MOTO_MOTION_REPLY (2002), header SUCCESS, the outcome in ``result``/``subcode`` (0 = success):

* MOTO_MOTION_CTRL: CHECK_MOTION_READY (TRUE, or FALSE with the NOT_READY subcode), CHECK_QUEUE_CNT
  (subcode = interpolation increments still queued for the group), STOP_MOTION (controlled stop),
  START/STOP_SERVOS, RESET_ALARM, START_TRAJ_MODE (refused NOT_READY while e-stopped or in teach
  mode; otherwise it clears alarms, powers the servos and enables trajectory points, as MotoROS
  does), STOP_TRAJ_MODE, DISCONNECT (stops, then closes without a reply). Unknown: INVALID/3006.
* JOINT_TRAJ_PT_FULL, checked in MotoROS's order: motion ready (NOT_READY + subcode), group
  (3004), TIME, POSITION and VELOCITY all valid (3015), time < 14400 s (3016), sequence >= 0
  (3005). Sequence 0 starts a trajectory at the current command position (within 30 pulses, else
  3011); later points are BUSY while the group's buffer is full, as MotoROS's single staging slot
  in front of its 200-increment queue is: here, while at least 200 interpolation periods of motion
  are queued (0.8 s at the default 4 ms; the real FS100 capture's BUSY pattern matches 200 x 2 ms,
  so run with ``--interpolation-period 0.002`` to imitate an FS100). Speeds above the joint limit
  give 3013, other refusals their data subcode (position 3012, time 3016, anything else 3010);
  MotoROS never refuses a point for its acceleration (3014 is defined and never sent), and neither
  does the emulator. MotoROS checks the points' speeds only (MotionServer.c:1313, motoman_driver
  1.9.12) and runs the cubic between two points as it is, whatever it asks of the joints'
  acceleration (MotionServer.c:1414-1468 samples it, 1487-1505 queues the increments, and
  mpExRcsIncrementMove sends them at 2004, unchecked); so does the emulator
  (``ControllerConfig.follow_given_acceleration``: a WARNING says where the first such segment is and
  by how much, INFO a later one 10 % worse; a segment from rest after the queue ran dry is no state
  MotoROS would be in and is met locally), and its drives take their velocity from the increments
  as MotoROS's do (``increment_feedforward``). A segment whose cubic passes a joint's speed limit
  between its points is slowed down (``control.scaling``); MotoROS would run it too.
  The time becomes whole milliseconds as MotoROS truncates it, except that a time within float32
  precision of a whole millisecond is that millisecond (:func:`motoros_milliseconds`: a client's
  grid time is never a millisecond short, where MotoROS loses one on some), segments are
  cubic in position and velocity (accelerations are not used), and values in the slots beyond the
  group's axes are ignored. CHECK_QUEUE_CNT never reports more than the 200 increments MotoROS's
  queue holds. Unlike MotoROS, every point is checked completely before it is acknowledged, so a
  point that would later be skipped is refused instead.
* JOINT_TRAJ_PT_FULL_EX (2016): one point per group, all accepted or none; BUSY if any group is.
* SELECT_TOOL (tool 0-63, else 3017), GET_DH_PARAMETERS (the model's D-H table, always 4 groups
  of 8 axes as MotoROS sends it; FAILURE for a model without one or with more than 8 joints),
  PING (header-only SUCCESS), the IO bits and groups (as on the IO port; the M registers only there,
  as in MotoROS, whose motion port does not know their types: INVALID/3003).
* Unknown types: INVALID/3003 with group and sequence -1. A message of a known type whose size is
  not its type's (a header-only JOINT_TRAJ_PT_FULL, a short MOTO_MOTION_CTRL): INVALID/3001
  (:func:`malformed_motion_reply`); on the IO port, the IO error reply with 3001. STATUS,
  JOINT_FEEDBACK, MOTO_MOTION_REPLY and JOINT_FEEDBACK_EX close the connection without a reply, as
  in MotoROS.
* One motion client at a time: a new connection replaces the old one unless the robot is busy,
  in which case the new one is closed (:mod:`.owner`, MotoROS's rule, on every profile). When the
  motion client leaves, the robot stops (``--on-disconnect``) and trajectory mode ends.

**State port** (50241): every state period (25 ms at the default 40 Hz) JOINT_FEEDBACK per group
(valid_fields POSITION | VELOCITY; time 0 with the TIME bit clear, as MotoROS), JOINT_FEEDBACK_EX
when there are two groups or more, and STATUS (motion_possible also needs trajectory mode).

**IO port** (50242): READ/WRITE_SINGLE_IO, READ/WRITE_GROUP_IO, READ/WRITE_MREGISTER on an
:class:`~.io_table.IoTable`, replies with the IO result codes and header FAILURE on error; an
unknown type gets MotoROS's odd error reply (type 2002 carrying result and subcode at the start of
a 60-byte body).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping

import numpy as np

from simple_message.constants import (
    CommType,
    InvalidSubcode,
    IoResult,
    MotoCommand,
    MotoResult,
    MsgType,
    NotReadySubcode,
    ReplyCode,
    RobotMode,
    ValidFields,
)
from simple_message.dialects import MOTOROS
from simple_message.endpoints import CloseConnection, Server, Session
from simple_message.errors import MalformedMessage
from simple_message.messages import (
    DH_AXES,
    DhLink,
    ExGroup,
    GetDhParametersReply,
    JointFeedback,
    JointFeedbackEx,
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
    WriteGroupIo,
    WriteGroupIoReply,
    WriteMRegister,
    WriteMRegisterReply,
    WriteSingleIo,
    WriteSingleIoReply,
)

from ..control import Point, PointRejected, Reason
from .cell import FaultError, RobotCell
from .io_table import IoTable
from .points import point_from_message
from .profiles import EmulatorProfile, PortRules, ProfileContext, register_profile

__all__ = [
    "MotorosMotion",
    "MotorosState",
    "MotorosIo",
    "MotorosBehaviour",
    "MOTOROS_PROFILE",
    "MOTOROS_START_TOLERANCE",
    "MOTOROS_QUEUE_INCREMENTS",
    "MOTOROS_MAX_TIME",
    "motoros_milliseconds",
]

log = logging.getLogger(__name__)

#: ``Q_SIZE``: interpolation increments MotoROS buffers per group (CtrlGroup.h)
MOTOROS_QUEUE_INCREMENTS = 200
#: ``MAX_TRAJECTORY_TIME_LENGTH`` (s)
MOTOROS_MAX_TIME = 14400.0
#: ``START_MAX_PULSE_DEVIATION`` is 30 pulses; a typical Yaskawa axis resolves about 1000 pulses
#: per degree, so 30 pulses is about 5.2e-4 rad (the exact figure depends on the axis).
MOTOROS_START_TOLERANCE = math.radians(30 / 1000)

_REQUIRED = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
_SUBCODES = {
    Reason.START_MISMATCH: InvalidSubcode.DATA_START_POS,
    Reason.POSITION_LIMIT: InvalidSubcode.DATA_POSITION,
    Reason.VELOCITY_LIMIT: InvalidSubcode.DATA_SPEED,
    Reason.TIMING: InvalidSubcode.DATA_TIME,
    Reason.MISSING_FIELDS: InvalidSubcode.DATA_INSUFFICIENT,
    Reason.SEQUENCE: InvalidSubcode.SEQUENCE,
    Reason.JOINT_COUNT: InvalidSubcode.DATA,
    Reason.NOT_FINITE: InvalidSubcode.DATA,
}
#: types MotoROS knows but refuses on its motion port: the connection is closed (§8.1)
_CLOSING_TYPES = (MsgType.STATUS, MsgType.JOINT_FEEDBACK, MsgType.MOTO_MOTION_REPLY, MsgType.JOINT_FEEDBACK_EX)


def motoros_milliseconds(time: float) -> int:
    """A JOINT_TRAJ_PT_FULL time in whole milliseconds, as MotoROS computes it and a millisecond
    better where MotoROS loses one to float32.

    MotoROS computes ``(int)(jointTrajData->time * 1000)`` (``Ros_MotionServer_ConvertToJointMotionData``)
    with a float ``time``: the product is rounded to float32 and truncated toward zero. The float32
    nearest 0.02 is 0.0199999995..., whose float32 product with 1000 is exactly 20.0, so clean client
    times mostly stay whole (truncating the double product would give 19 ms). But not always: the
    float32 nearest 16.06 times 1000 is 16059.999..., and MotoROS runs that point a millisecond
    early. Here a time whose product lies within float32's precision (2^-23 relative) of a whole
    millisecond, above or below, is that millisecond, so a time a client computes on a clean grid
    is never a millisecond short nor long, up to MotoROS's 14400 s; any other time is truncated as
    MotoROS does (0.0199 s is 19 ms)."""
    product = float(np.float32(time)) * 1000.0  # exact float32 time, product in double
    nearest = round(product)
    if abs(product - nearest) <= abs(product) * 2.0**-23:
        return int(nearest)  # float32's rounding of a whole millisecond, either way
    return math.floor(product)


class _Refused(Exception):
    def __init__(self, result: MotoResult, subcode: int = 0) -> None:
        self.result = result
        self.subcode = subcode


class MotorosMotion:
    """Motion-port handlers of the MotoROS profile (see the module doc)."""

    def __init__(self, cell: RobotCell, io: IoTable | None = None) -> None:
        self.cell = cell
        self.io = MotorosIo(io if io is not None else IoTable())
        self.traj_mode = False
        period = cell.config.interpolation_period
        #: a group is BUSY while this much motion (s) is queued
        self.buffer_time = MOTOROS_QUEUE_INCREMENTS * period

    def install(self, server: Server) -> None:
        server.handle(MsgType.MOTO_MOTION_CTRL, self.on_ctrl)
        server.handle(MsgType.JOINT_TRAJ_PT_FULL, self.on_point)
        server.handle(MsgType.JOINT_TRAJ_PT_FULL_EX, self.on_point_ex)
        server.handle(MsgType.SELECT_TOOL, self.on_select_tool)
        server.handle(MsgType.GET_DH_PARAMETERS, self.on_get_dh)
        server.handle(MsgType.PING, _ping)
        for msg_type in _CLOSING_TYPES:
            server.handle(msg_type, _close)
        self.io.install(server)
        server.unknown_request = self.on_unknown
        server.malformed_request = self.on_malformed

    # -- connections -------------------------------------------------------------------------------

    def owner_gone(self, session: Session) -> None:
        """The motion client went away (:class:`~.owner.MotionOwner` stopped the robot): MotoROS
        ends trajectory mode with the connection."""
        if self.traj_mode:
            session.log(log, logging.INFO, "the motion client left: trajectory mode off")
        self.traj_mode = False

    # -- readiness ---------------------------------------------------------------------------------

    def not_ready(self) -> NotReadySubcode | None:
        """Why trajectory points cannot run now (MotoROS's NOT_READY subcode), or None."""
        cell = self.cell
        if cell.in_error:
            return NotReadySubcode.ALARM
        if cell.e_stopped:
            return NotReadySubcode.ESTOP
        if cell.mode != RobotMode.AUTO:
            return NotReadySubcode.NOT_PLAY
        if not cell.drives_powered:
            return NotReadySubcode.SERVO_OFF
        if not self.traj_mode:
            return NotReadySubcode.NOT_STARTED
        return None

    @property
    def motion_ready(self) -> bool:
        return self.not_ready() is None

    # -- MOTO_MOTION_CTRL --------------------------------------------------------------------------

    def on_ctrl(self, msg: Message, session: Session) -> Message:
        assert isinstance(msg, MotoMotionCtrl)
        try:
            result, subcode = self._ctrl(msg, session)
        except _Refused as refused:
            result, subcode = refused.result, refused.subcode
        return MotoMotionReply(msg.group_no, msg.sequence, msg.command, result, subcode)

    def _ctrl(self, msg: MotoMotionCtrl, session: Session) -> tuple[MotoResult, int]:
        cell = self.cell
        command = msg.command
        if command == MotoCommand.CHECK_MOTION_READY:
            reason = self.not_ready()
            return (MotoResult.TRUE, 0) if reason is None else (MotoResult.FALSE, reason)
        if command == MotoCommand.CHECK_QUEUE_CNT:
            group = self._group(msg.group_no)
            period = cell.config.interpolation_period
            queued = math.ceil(cell.groups[group].remaining / period - 1e-9)
            return MotoResult.SUCCESS, min(queued, MOTOROS_QUEUE_INCREMENTS)  # the queue holds 200 at most
        if command == MotoCommand.STOP_MOTION:
            cell.stop()
            return MotoResult.SUCCESS, 0
        if command == MotoCommand.START_SERVOS:
            try:
                cell.drives_on()
            except FaultError:
                raise _Refused(MotoResult.NOT_READY, NotReadySubcode.ESTOP) from None
            return MotoResult.SUCCESS, 0
        if command == MotoCommand.STOP_SERVOS:
            cell.drives_off()
            return MotoResult.SUCCESS, 0
        if command == MotoCommand.RESET_ALARM:
            cell.reset_alarm()
            return MotoResult.SUCCESS, 0
        if command == MotoCommand.START_TRAJ_MODE:
            if cell.e_stopped:
                raise _Refused(MotoResult.NOT_READY, NotReadySubcode.ESTOP)
            if cell.mode != RobotMode.AUTO:
                raise _Refused(MotoResult.NOT_READY, NotReadySubcode.NOT_PLAY)
            if cell.in_error:
                cell.reset_alarm()
            if not cell.drives_powered:
                cell.drives_on()
            if not self.traj_mode:
                session.log(log, logging.INFO, "trajectory mode on")
            self.traj_mode = True
            return MotoResult.SUCCESS, 0
        if command == MotoCommand.STOP_TRAJ_MODE:
            cell.stop()
            if self.traj_mode:
                session.log(log, logging.INFO, "trajectory mode off")
            self.traj_mode = False
            return MotoResult.SUCCESS, 0
        if command == MotoCommand.DISCONNECT:
            cell.stop()
            self.traj_mode = False
            raise CloseConnection
        raise _Refused(MotoResult.INVALID, InvalidSubcode.COMMAND)

    def _group(self, group: int) -> int:
        if not 0 <= group < len(self.cell.groups):
            raise _Refused(MotoResult.INVALID, InvalidSubcode.GROUPNO)
        return group

    # -- trajectory points -------------------------------------------------------------------------

    def on_point(self, msg: Message, session: Session) -> Message:
        assert isinstance(msg, JointTrajPtFull)
        group = msg.robot_id
        try:
            point = self._check(
                group, msg.sequence, msg.valid_fields, msg.time, positions=msg.positions, velocities=msg.velocities
            )
            if msg.sequence > 0 and self._busy(group):
                raise _Refused(MotoResult.BUSY)
            self._submit(msg.sequence, [(group, point)], session)
            result, subcode = MotoResult.SUCCESS, 0
        except _Refused as refused:
            result, subcode = refused.result, refused.subcode
        return MotoMotionReply(group, msg.sequence, MsgType.JOINT_TRAJ_PT_FULL, result, subcode)

    def on_point_ex(self, msg: Message, session: Session) -> Message:
        assert isinstance(msg, JointTrajPtFullEx)
        group = 0
        try:
            groups = msg.valid_groups
            if (
                not 1 <= msg.number_of_valid_groups <= len(self.cell.groups)
                or len(groups) != msg.number_of_valid_groups
            ):
                raise _Refused(MotoResult.INVALID, InvalidSubcode.DATA)
            points = []
            for g in groups:
                group = g.group_no
                points.append(
                    (
                        group,
                        self._check(
                            group, msg.sequence, g.valid_fields, g.time, positions=g.positions, velocities=g.velocities
                        ),
                    )
                )
            if len({g for g, _ in points}) != len(points):
                raise _Refused(MotoResult.INVALID, InvalidSubcode.GROUPNO)
            if msg.sequence > 0 and any(self._busy(g) for g, _ in points):
                raise _Refused(MotoResult.BUSY)
            self._submit(msg.sequence, points, session)
            result, subcode = MotoResult.SUCCESS, 0
        except _Refused as refused:
            result, subcode = refused.result, refused.subcode
        return MotoMotionReply(group, msg.sequence, MsgType.JOINT_TRAJ_PT_FULL_EX, result, subcode)

    def _check(
        self,
        group: int,
        sequence: int,
        valid_fields: int,
        time: float,
        *,
        positions: Iterable[float],
        velocities: Iterable[float],
    ) -> Point:
        """MotoROS's checks, in its order, up to the point itself."""
        reason = self.not_ready()
        if reason is not None:
            raise _Refused(MotoResult.NOT_READY, reason)
        self._group(group)
        if valid_fields & _REQUIRED != _REQUIRED:
            raise _Refused(MotoResult.INVALID, InvalidSubcode.DATA_INSUFFICIENT)
        if not (math.isfinite(time) and 0.0 <= time < MOTOROS_MAX_TIME):
            # MotoROS refuses a time from 14400 s; a negative or non-finite one it would turn into
            # a meaningless millisecond count (and skip the segment): refused here too
            raise _Refused(MotoResult.INVALID, InvalidSubcode.DATA_TIME)
        if sequence < 0:
            raise _Refused(MotoResult.INVALID, InvalidSubcode.SEQUENCE)
        if sequence == 0 and self.cell.groups[group].moving:
            raise _Refused(MotoResult.BUSY)  # a new trajectory waits until the last one has run
        controller = self.cell.groups[group]
        # MotoROS uses time, positions and velocities (accelerations never), and only its axes' slots
        message = JointTrajPtFull(
            group,
            sequence,
            ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY,
            motoros_milliseconds(time) / 1000.0,
            tuple(positions),
            tuple(velocities),
        )
        try:
            return point_from_message(message, controller.dof, extra_slots="ignore")[1]
        except PointRejected as exc:
            raise _refusal(exc) from None

    def _busy(self, group: int) -> bool:
        controller = self.cell.groups[group]
        return controller.remaining >= self.buffer_time or controller.queue_fill >= controller.queue_capacity

    def _submit(self, sequence: int, points: list[tuple[int, Point]], session: Session) -> None:
        try:
            if len(points) == 1:
                self.cell.submit(points[0][0], sequence, points[0][1])
            else:
                self.cell.submit_together(sequence, points)
        except PointRejected as exc:
            session.log(log, logging.WARNING, "point %d refused: %s", sequence, exc)
            raise _refusal(exc) from None

    # -- other motion-port messages ----------------------------------------------------------------

    def on_select_tool(self, msg: Message, session: Session) -> Message:
        assert isinstance(msg, SelectTool)
        result, subcode = MotoResult.SUCCESS, 0
        if not 0 <= msg.group_no < len(self.cell.groups):
            result, subcode = MotoResult.INVALID, InvalidSubcode.GROUPNO
        elif not 0 <= msg.tool <= 63:
            result, subcode = MotoResult.INVALID, InvalidSubcode.DATA_TOOLNO
        return MotoMotionReply(msg.group_no, msg.sequence, MsgType.SELECT_TOOL, result, subcode)

    def on_get_dh(self, msg: Message, session: Session) -> Message:
        groups = []
        for model in self.cell.models:
            rows = [joint.dh for joint in model.joints]
            if any(row is None for row in rows) or len(rows) > DH_AXES:
                session.log(log, logging.INFO, "GET_DH_PARAMETERS: model %s has no D-H table", model.name)
                return GetDhParametersReply(reply_code=ReplyCode.FAILURE)
            groups.append(tuple(DhLink(*row) for row in rows if row is not None))
        return GetDhParametersReply(tuple(groups))

    def on_unknown(self, msg: Message, session: Session) -> Message:
        session.log(log, logging.INFO, "unknown message type %d: INVALID/3003", msg.msg_type)
        return MotoMotionReply(-1, -1, msg.msg_type, MotoResult.INVALID, InvalidSubcode.MSGTYPE)

    def on_malformed(self, error: MalformedMessage, session: Session) -> Message:
        """A message shorter (or longer) than its type: INVALID/3001, filled as
        ``Ros_SimpleMsg_MotionReply`` fills it (module doc)."""
        return malformed_motion_reply(error, session)


#: where ``Ros_SimpleMsg_MotionReply`` reads the sequence (and the command) of the message it
#: answers: (sequence offset, command offset or None for the type itself), by type
_ECHOED = {
    MsgType.MOTO_MOTION_CTRL: (4, 8),
    MsgType.JOINT_TRAJ_PT_FULL: (4, None),
    MsgType.JOINT_TRAJ_PT_FULL_EX: (4, None),
    MsgType.SELECT_TOOL: (8, None),
}
#: the types whose size MotoROS's motion port knows (``Ros_MotionServer_GetExpectedByteSizeForMessageType``);
#: any other type is unknown there (INVALID/3003), whatever its size
_SIZED = frozenset(
    {
        MsgType.PING,
        MsgType.STATUS,
        MsgType.JOINT_TRAJ_PT_FULL,
        MsgType.JOINT_FEEDBACK,
        MsgType.MOTO_MOTION_CTRL,
        MsgType.MOTO_MOTION_REPLY,
        MsgType.JOINT_TRAJ_PT_FULL_EX,
        MsgType.JOINT_FEEDBACK_EX,
        MsgType.READ_SINGLE_IO,
        MsgType.WRITE_SINGLE_IO,
        MsgType.READ_GROUP_IO,
        MsgType.WRITE_GROUP_IO,
        MsgType.GET_DH_PARAMETERS,
        MsgType.SELECT_TOOL,
    }
)


def malformed_motion_reply(error: MalformedMessage, session: Session) -> MotoMotionReply:
    """MOTO_MOTION_REPLY INVALID/3001 to a message whose size is not its type's. MotoROS reads a
    message by the size of its type, not by the prefix, and answers a short one at once, with
    the sequence (and command) from where they would be in the body: the bytes that came, zeros
    beyond them (its buffer is cleared before each read), group 0; any other type gets group and
    sequence -1. A type MotoROS's motion port does not know is INVALID/3003 whatever its size. A
    frame longer than its type is answered 3001 here too, where MotoROS would read the surplus as
    the start of the next message: this emulator frames by the prefix."""
    msg_type = error.msg_type or 0
    if msg_type not in _SIZED:
        session.log(log, logging.INFO, "unknown message type %d: INVALID/3003", msg_type)
        return MotoMotionReply(-1, -1, msg_type, MotoResult.INVALID, InvalidSubcode.MSGTYPE)
    session.log(log, logging.INFO, "%s: INVALID/3001", error)
    echoed = _ECHOED.get(msg_type)  # type: ignore[call-overload]
    if echoed is None:
        return MotoMotionReply(-1, -1, msg_type, MotoResult.INVALID, InvalidSubcode.MSGSIZE)
    body = error.frame[16:].ljust(12, b"\0")
    ints = session.wire.struct("iii").unpack_from(body, 0)
    sequence_at, command_at = echoed
    sequence = ints[sequence_at // 4]
    command = msg_type if command_at is None else ints[command_at // 4]
    return MotoMotionReply(0, sequence, command, MotoResult.INVALID, InvalidSubcode.MSGSIZE)


def _refusal(exc: PointRejected) -> _Refused:
    if exc.reason is Reason.QUEUE_FULL:
        return _Refused(MotoResult.BUSY)
    if exc.reason is Reason.NOT_READY:
        return _Refused(MotoResult.NOT_READY, NotReadySubcode.UNSPECIFIED)
    return _Refused(MotoResult.INVALID, _SUBCODES.get(exc.reason, InvalidSubcode.DATA))


def _ping(msg: Message, session: Session) -> Message:
    return Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)


def _close(msg: Message, session: Session) -> None:
    session.log(log, logging.WARNING, "%s is not accepted on the motion port: closing, as MotoROS does", msg.name)
    raise CloseConnection


class MotorosIo:
    """IO handlers (IO port, and the motion port too), on an :class:`IoTable`."""

    def __init__(self, table: IoTable) -> None:
        self.table = table

    def install(self, server: Server, *, registers: bool = False) -> None:
        """The IO bits and groups (MotoROS's motion port serves those too); ``registers``: the M
        registers as well (the IO port only)."""
        server.handle(MsgType.READ_SINGLE_IO, self.on_io)
        server.handle(MsgType.WRITE_SINGLE_IO, self.on_io)
        server.handle(MsgType.READ_GROUP_IO, self.on_io)
        server.handle(MsgType.WRITE_GROUP_IO, self.on_io)
        if registers:
            server.handle(MsgType.READ_MREGISTER, self.on_io)
            server.handle(MsgType.WRITE_MREGISTER, self.on_io)

    def install_port(self, server: Server) -> None:
        """The IO port itself: these handlers plus MotoROS's error reply for anything else."""
        self.install(server, registers=True)
        server.unknown_request = self.on_unknown
        server.malformed_request = self.on_malformed

    def on_io(self, msg: Message, session: Session) -> Message:
        table = self.table
        reply: Message
        if isinstance(msg, ReadSingleIo):
            value, code = table.read_bit(msg.address)
            reply = ReadSingleIoReply(value, code, reply_code=_code(code))
        elif isinstance(msg, WriteSingleIo):
            code = table.write_bit(msg.address, msg.value)
            reply = WriteSingleIoReply(code, reply_code=_code(code))
        elif isinstance(msg, ReadGroupIo):
            value, code = table.read_group(msg.address)
            reply = ReadGroupIoReply(value, code, reply_code=_code(code))
        elif isinstance(msg, WriteGroupIo):
            code = table.write_group(msg.address, msg.value)
            reply = WriteGroupIoReply(code, reply_code=_code(code))
        elif isinstance(msg, ReadMRegister):
            value, code = table.read_register(msg.register_number)
            reply = ReadMRegisterReply(value, code, reply_code=_code(code))
        elif isinstance(msg, WriteMRegister):
            code = table.write_register(msg.register_number, msg.value)
            reply = WriteMRegisterReply(code, reply_code=_code(code))
        else:  # pragma: no cover - only registered for the types above
            raise TypeError(msg.name)
        if code != IoResult.OK:
            session.log(log, logging.INFO, "%s: %s", msg.name, code.name)
        return reply

    def on_unknown(self, msg: Message, session: Session) -> Message:
        """``Ros_SimpleMsg_IoReply``: type 2002, but result and subcode at the start of the body."""
        session.log(log, logging.INFO, "unknown message type %d on the IO port: INVALID/3003", msg.msg_type)
        return _io_error(session, InvalidSubcode.MSGTYPE)

    def on_malformed(self, error: MalformedMessage, session: Session) -> Message:
        """A message whose size is not its type's: the same error reply, INVALID/3001."""
        session.log(log, logging.INFO, "%s on the IO port: INVALID/3001", error)
        return _io_error(session, InvalidSubcode.MSGSIZE)


def _io_error(session: Session, subcode: InvalidSubcode) -> Message:
    body = session.wire.struct("ii").pack(MotoResult.INVALID, subcode) + bytes(52)
    return RawMessage(MsgType.MOTO_MOTION_REPLY, body, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)


def _code(result: IoResult) -> ReplyCode:
    return ReplyCode.SUCCESS if result == IoResult.OK else ReplyCode.FAILURE


class MotorosState:
    """State-port messages of the MotoROS profile (see the module doc)."""

    def __init__(self, cell: RobotCell, motion: MotorosMotion) -> None:
        self.cell = cell
        self.motion = motion

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        cell = self.cell
        recipients = list(sessions)
        fields = ValidFields.POSITION | ValidFields.VELOCITY
        groups = []
        for index, controller in enumerate(cell.groups):
            tick = controller.command
            position, velocity = tuple(tick.actual_position), tuple(tick.actual_velocity)
            groups.append(ExGroup(index, fields, 0.0, position, velocity))
            server.broadcast(JointFeedback(index, fields, 0.0, position, velocity), recipients)
        if len(groups) >= 2:
            server.broadcast(JointFeedbackEx(len(groups), tuple(groups)), recipients)
        server.broadcast(self.status(), recipients)

    def status(self) -> Status:
        """STATUS as MotoROS reports it: motion possible only in trajectory mode."""
        return self.cell.status(motion_possible=self.cell.motion_possible and self.motion.traj_mode)


class MotorosBehaviour:
    """The MotoROS profile's :class:`~.profiles.Behaviour`: its motion, state and IO ports."""

    def __init__(self, context: ProfileContext) -> None:
        self.motion = MotorosMotion(context.cell, context.io_table)
        self.state = MotorosState(context.cell, self.motion)
        self.io = self.motion.io
        if context.owner is not None:
            context.owner.when_gone(self.motion.owner_gone)

    def install(self, servers: Mapping[str, Server]) -> None:
        self.motion.install(servers["motion"])
        if "io" in servers:
            self.io.install_port(servers["io"])

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        self.state.publish(server, sessions)

    def status(self) -> Status:
        return self.state.status()


MOTOROS_PROFILE = register_profile(
    EmulatorProfile(
        MOTOROS,
        MotorosBehaviour,
        ports={
            # one motion client, plus the newcomer that replaces it
            "motion": PortRules(max_connections=2, answer_topics=True),
            "state": PortRules(max_connections=4, listen_only=True),
            "io": PortRules(max_connections=1, answer_topics=True),
        },
        start_tolerance=MOTOROS_START_TOLERANCE,
        follow_given_acceleration=True,
        increment_feedforward=True,
        description="Yaskawa MotoROS: trajectory mode, JOINT_TRAJ_PT_FULL(_EX), MOTO_MOTION_REPLY, IO port",
    )
)
