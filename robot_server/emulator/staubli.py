"""The Stäubli profile: a CS8/CS9 controller running staubli_val3_driver's VAL3 server, as it behaves.

Read from ros-industrial/staubli_val3_driver ``val3/ros_server/`` (master 6bff941); docs/vendors.md has
every rule with its file:line, and what the emulator does.

**Motion only while both sockets are connected** (``motionControl.pgx:31,68-79``): a 4 ms task moves
the robot only while the motion client is connected *and* the state client has been connected for
1 s (``recvHeartbeat.pgx:34-42``); otherwise, every tick, it stops the robot (``resetMotion``) and
empties both queues. Points that arrive meanwhile are still answered SUCCESS, then dropped.

**Motion port** (11000, one client; a second waits in the listen backlog): a 4 ms task reads at most
one message per tick (``dataReceiver.pgx:44-82``): the 16 bytes of prefix and header, then a body
whose size is its type's alone, 52 bytes for JOINT_TRAJ_PT (11) and 136 for JOINT_TRAJ_PT_FULL (14),
the length prefix unread (``recvMsgBody.pgx:29-46``). Any other type has no body read and no reply:
a PING is consumed (and its client waits for ever), and a message with a body loses the framing,
its body read as the next header. That is reproduced and logged once; ``--lenient`` frames by the
length prefix instead (the type is still not answered).

* Only a SERVICE_REQUEST is answered (``pushMotion.pgx:107-113``): a message of its type at its
  full length, SUCCESS or FAILURE, the sequence echoed, every other field zero (68 bytes for
  JOINT_TRAJ_PT), written as three sends: prefix, header, body (``sendRosMsg.pgx:28-30``). A TOPIC
  is handled the same way, unanswered. The reply means "queued", not "reached".
* FAILURE: a body that does not decode, joints outside the limits (``isInRange``), a velocity
  share not above 0 (above 1 is clamped to 100 %), a full queue (``pushMotion.pgx:83-104``); the
  stock streamer moves on past a FAILURE, so that point is lost.
* Sequence -4 stops at the next tick (``resetMotion``, both queues emptied) and is answered SUCCESS;
  every other sequence is a point (``pushMotion.pgx:68-70``).
* JOINT_TRAJ_PT_FULL is read with VAL3's decoding as it is: robot_id, sequence, valid_fields and
  time all from the body's first four bytes (``decTrajPtFull.pgx:34-55``), so the "sequence" is
  the robot_id (a -4 there stops, a -4 in the sequence field does not), the speed is joint 1's
  velocity read as a share, the acceleration joint 1's acceleration read as a percentage
  (``pushMotion.pgx:58-61``; one not above 0 would fail the motion task: an alarm here), and the
  reply carries robot_id 0 and the request's robot_id as its sequence.

**Queues and motion**: points wait in a 10-entry queue (``qTrajPtBuffer``); each 4 ms tick moves one
through a second 10-entry queue into ``movej`` (``motionControl.pgx:34-67``), which appends to the
VAL3 motion stack and waits while that is full. Each point is a ``movej`` at ``velocity x 100 %`` of
the joints' nominal speed and 100 % acceleration; its duration is ignored, the blend is left at
VAL3's default (off) with leave and reach 0, so the robot stops at every point
(:mod:`..control.moves`, blend 0). How many moves the VAL3 motion stack holds is not in the sources:
``--profile-option motion_stack=N`` (default 10).

**State port** (11002): every 20 ms a JOINT_POSITION (sequence 0, the commanded joints, ``herej``),
and a STATUS with every fifth, the count kept across clients (``dataStreamer.pgx:28-46``); nothing
until the state client has been connected for 1 s. Each message is written as three sends.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Awaitable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from simple_message.constants import HEADER_SIZE, LENGTH_SIZE, CommType, MsgType, ReplyCode, SpecialSeq
from simple_message.dialects import STAUBLI
from simple_message.endpoints import NO_REPLY, HandlerResult, Server, Session
from simple_message.fixed_reads import FRAME_HEAD, FixedReads, prefix_cut
from simple_message.framing import DEFAULT_MAX_LENGTH
from simple_message.messages import JointPosition, JointTrajPt, JointTrajPtFull, Message, RawMessage, Status
from simple_message.wire import WireFormat

from ..control import Point, PointRejected, Reason
from ..control.points import within
from .cell import RobotCell
from .profiles import EmulatorProfile, PortRules, ProfileContext, int_option, never_read, register_profile
from .quirks import Quirks

__all__ = [
    "STAUBLI_PROFILE",
    "StaubliBehaviour",
    "StaubliMotion",
    "StaubliReads",
    "StaubliState",
    "VAL3_QUEUE",
    "VAL3_TICK",
    "staubli_split",
]

log = logging.getLogger(__name__)

#: the period of the synchronous tasks that read messages and run the motion (start.pgx:66-71)
VAL3_TICK = 0.004
#: the entries of qTrajPtBuffer and qMoveBuffer (ros_server.dtx:278-283, 367-372)
VAL3_QUEUE = 10
#: the moves the VAL3 motion stack holds (not in the sources: --profile-option motion_stack)
VAL3_MOTION_STACK = 10
#: the state client counts as connected 1 s after it connects (recvHeartbeat.pgx:39)
VAL3_STATE_DELAY = 1.0
#: a STATUS goes with every fifth JOINT_POSITION (dataStreamer.pgx:36-44)
VAL3_STATUS_EVERY = 5
#: the body sizes VAL3 reads, by type (recvTrajPt.pgx:30, recvTrajPtFull.pgx:30)
VAL3_BODIES = {int(MsgType.JOINT_TRAJ_PT): 52, int(MsgType.JOINT_TRAJ_PT_FULL): 136}
_SINCE = "staubli_connected_at"


def staubli_split(frame: bytes) -> Sequence[bytes]:
    """A message as VAL3 writes it: prefix, header and body, one ``sioSet`` each."""
    head = LENGTH_SIZE + HEADER_SIZE
    return (
        (frame[:LENGTH_SIZE], frame[LENGTH_SIZE:head], frame[head:])
        if len(frame) > head
        else (
            frame[:LENGTH_SIZE],
            frame[LENGTH_SIZE:],
        )
    )


class StaubliReads(FixedReads):
    """VAL3's reads: prefix and header, then the type's body size (none for other types).
    ``lenient``: by the length prefix."""

    def __init__(self, wire: WireFormat, *, lenient: bool = False) -> None:
        super().__init__(wire)
        self.lenient = lenient

    def cut(self, buf: bytes, start: int) -> int | None:
        if self.lenient:
            return prefix_cut(buf, start, self.wire, DEFAULT_MAX_LENGTH)
        if len(buf) - start < FRAME_HEAD:
            return None
        _, msg_type, _, _ = self.wire.header.unpack_from(buf, start)
        end = start + FRAME_HEAD + VAL3_BODIES.get(msg_type, 0)
        return end if end <= len(buf) else None


@dataclass(frozen=True)
class _Command:
    """A queued ``MotionCmd``: where to, at which shares of the nominal speed and acceleration."""

    sequence: int
    positions: np.ndarray
    speed: float
    acceleration: float


class StaubliMotion:
    """The VAL3 server's dataReceiver and motionControl tasks (see the module doc)."""

    def __init__(self, cell: RobotCell, *, lenient: bool = False, motion_stack: int = VAL3_MOTION_STACK) -> None:
        if len(cell.groups) != 1:
            raise ValueError("the staubli profile plays one robot: give one model")
        if cell.groups[0].dof > 6:
            raise ValueError("the staubli profile plays a robot of at most 6 joints (VAL3 converts j1..j6)")
        self.cell = cell
        self.controller = cell.groups[0]
        self.lenient = lenient
        self.motion_stack = motion_stack
        #: qTrajPtBuffer and qMoveBuffer
        self.queue: deque[_Command] = deque()
        self.moves: deque[_Command] = deque()
        #: the point popped for a movej that waits for room in the motion stack
        self.waiting: _Command | None = None
        self.stop_now = False
        self.motion_server: Server | None = None
        self.state_server: Server | None = None
        self._tick = -1  # the last motionControl tick run
        self._read_tick = -1  # the tick of the last message read
        self._quirks = Quirks(log)

    def install(self, servers: Mapping[str, Server]) -> None:
        self.motion_server = servers["motion"]
        self.state_server = servers["state"]
        self.motion_server.unknown_request = self.on_read
        self.state_server.on_connect = self._state_connected
        self.cell.listen(self.tick, self.idle)

    def idle(self) -> bool:
        """The motion task has nothing to do at its ticks: no command queued, waiting or moving,
        no STOP to carry out (its queues are empty whether the connection is whole or not)."""
        return (
            not self.queue
            and not self.moves
            and self.waiting is None
            and not self.stop_now
            and not self.controller.moves.fill
        )

    def _state_connected(self, session: Session) -> None:
        session.data[_SINCE] = self.cell.time

    # -- the connection flags ---------------------------------------------------------------------

    def connected(self) -> bool:
        """nInConnFlag and nOutConnFlag both 1: a motion client, and a state client for 1 s."""
        now = self.cell.time
        motion = self.motion_server is not None and any(not s.connection.closed for s in self.motion_server.sessions)
        return motion and any(now >= since + VAL3_STATE_DELAY - 1e-9 for since in self._state_since())

    def _state_since(self) -> list[float]:
        """When each open state connection was first seen (controller time)."""
        if self.state_server is None:
            return []
        out = []
        for session in self.state_server.sessions:
            if session.connection.closed:
                continue
            out.append(session.data.setdefault(_SINCE, self.cell.time))
        return out

    # -- dataReceiver ------------------------------------------------------------------------------

    def on_read(self, msg: Message, session: Session) -> HandlerResult | Awaitable[HandlerResult]:
        return self._receive(msg, session)

    async def _receive(self, msg: Message, session: Session) -> HandlerResult:
        # one message per 4 ms tick: a second one waits for the next tick
        await self.cell.until(lambda: self._ticks(self.cell.time) > self._read_tick)
        self._read_tick = self._ticks(self.cell.time)
        assert isinstance(msg, RawMessage)
        body = msg.body
        if msg.msg_type not in VAL3_BODIES:
            self._quirks.say(
                session,
                "other type",
                f"message type {msg.msg_type}: VAL3 reads only JOINT_TRAJ_PT and JOINT_TRAJ_PT_FULL and answers "
                + "nothing "
                + (
                    "else (ignored, --lenient)"
                    if self.lenient
                    else "else; it reads no body for it, so any bytes after its header are read as the next "
                    "message (recvMsgBody.pgx:29-46): framing is lost"
                ),
            )
            return NO_REPLY
        request = msg.comm_type == CommType.SERVICE_REQUEST
        wire = session.wire
        if msg.msg_type == MsgType.JOINT_TRAJ_PT:
            fields = wire.struct("i10rrr").unpack_from(body.ljust(52, b"\0"), 0)
            sequence, joints, velocity = int(fields[0]), np.array(fields[1:11], dtype=float), float(fields[11])
            code = self._push(sequence, joints, velocity, 1.0, session)
            reply: Message = JointTrajPt(sequence, comm_type=CommType.SERVICE_REPLY, reply_code=code)
        else:
            (first,) = wire.struct("i").unpack_from(body, 0)  # robot_id, "sequence", valid_fields, time
            arrays = wire.struct("30r").unpack_from(body, 16)
            joints = np.array(arrays[0:10], dtype=float)
            speed, acceleration = float(arrays[10]), float(arrays[20]) / 100.0
            code = self._push(int(first), joints, speed, acceleration, session)
            reply = JointTrajPtFull(0, int(first), comm_type=CommType.SERVICE_REPLY, reply_code=code)
        return reply if request else NO_REPLY

    def _push(
        self, sequence: int, joints: np.ndarray, velocity: float, acceleration: float, session: Session
    ) -> ReplyCode:
        """pushMotion: a stop, or a point queued (SUCCESS) or refused (FAILURE)."""
        if sequence == SpecialSeq.STOP_TRAJECTORY:
            self.stop_now = True
            return ReplyCode.SUCCESS
        dof = self.controller.dof
        positions = joints[:dof]
        speed = min(max(velocity, 0.0), 1.0) if math.isfinite(velocity) else math.nan
        lim = self.controller.limits
        try:
            if not (np.all(np.isfinite(positions)) and math.isfinite(speed) and math.isfinite(acceleration)):
                raise PointRejected(Reason.NOT_FINITE, "the point does not decode (NaN or infinity)")
            within(positions, lim.lower, lim.upper, Reason.POSITION_LIMIT, "position")
            if not speed > 0.0:
                raise PointRejected(Reason.VELOCITY_LIMIT, f"the velocity {velocity:g} is not above 0")
            if len(self.queue) >= VAL3_QUEUE:
                raise PointRejected(Reason.QUEUE_FULL, f"the {VAL3_QUEUE}-entry queue is full")
        except PointRejected as exc:
            session.log(log, logging.WARNING, "point %d: FAILURE: %s", sequence, exc)
            return ReplyCode.FAILURE
        self.queue.append(_Command(sequence, positions.copy(), speed, acceleration))
        return ReplyCode.SUCCESS

    # -- motionControl -----------------------------------------------------------------------------

    def tick(self) -> None:
        """One 4 ms tick of the motion task (run on every control-loop wake-up, acting once per tick)."""
        tick = self._ticks(self.cell.time)
        if tick <= self._tick:
            return
        self._tick = tick
        if not self.connected() or self.stop_now:
            self._reset_motion()
            return
        if self.waiting is None:
            if self.queue:
                self.moves.append(self.queue.popleft())  # qMoveBuffer: a point lost were it full
            if not self.moves:
                return
            self.waiting = self.moves.popleft()
        if self.controller.moves.fill >= self.motion_stack:
            return  # movej waits for room in the motion stack
        command, self.waiting = self.waiting, None
        if command.acceleration <= 0.0:
            self.cell.alarm(
                9001, f"movej with acceleration {command.acceleration * 100:g} %: the VAL3 motion task stops"
            )
            return
        try:
            self.cell.submit_move(
                0,
                Point(command.positions),
                speed=command.speed,
                acceleration=min(command.acceleration, 1.0),
                blend=0.0,
            )
        except PointRejected as exc:
            log.warning("movej to point %d refused: %s", command.sequence, exc)

    def _reset_motion(self) -> None:
        """``resetMotion()`` and both queues emptied (every tick while the connection is not whole)."""
        if self.controller.moves.fill or self.queue or self.moves or self.waiting is not None:
            if self.controller.moves.fill:
                self.cell.stop()
            log.info(
                "%s: the robot stops and the queues are emptied (motionControl.pgx:68-79)",
                "STOP" if self.stop_now else "the motion and state clients are not both connected",
            )
        self.queue.clear()
        self.moves.clear()
        self.waiting = None
        self.stop_now = False

    def _ticks(self, time: float) -> int:
        return math.floor(time / VAL3_TICK + 1e-9)


class StaubliState:
    """The VAL3 dataStreamer (see the module doc)."""

    def __init__(self, cell: RobotCell, motion: StaubliMotion) -> None:
        self.cell = cell
        self.motion = motion
        self._count = 0

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        now = self.cell.time
        ready = [s for s in sessions if now >= s.data.setdefault(_SINCE, now) + VAL3_STATE_DELAY - 1e-9]
        if not ready:
            return
        tick = self.cell.groups[0].command
        server.broadcast(JointPosition(0, tuple(tick.command_position)), ready)
        if self._count == VAL3_STATUS_EVERY:
            server.broadcast(self.status(), ready)
            self._count = 0
        self._count += 1

    def status(self) -> Status:
        return self.cell.status()


class StaubliBehaviour:
    """The Stäubli profile's :class:`~.profiles.Behaviour`."""

    def __init__(self, context: ProfileContext) -> None:
        self.cell = context.cell
        depth = int_option(
            "staubli",
            context.options,
            "motion_stack",
            VAL3_MOTION_STACK,
            allowed=range(1, 2**31),
            what="of moves, >= 1",
        )
        self.motion = StaubliMotion(context.cell, lenient=context.lenient, motion_stack=depth)
        self.state = StaubliState(context.cell, self.motion)

    def install(self, servers: Mapping[str, Server]) -> None:
        self.motion.install(servers)

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        self.state.publish(server, sessions)

    def status(self) -> Status:
        return self.state.status()


STAUBLI_PROFILE = register_profile(
    EmulatorProfile(
        STAUBLI,
        StaubliBehaviour,
        ports={
            "motion": PortRules(
                max_connections=1, excess="wait", answer_topics=True, reader=StaubliReads, write_split=staubli_split
            ),
            "state": PortRules(
                max_connections=1, excess="wait", listen_only=True, reader=never_read, write_split=staubli_split
            ),
        },
        description="Staubli CS8/CS9, staubli_val3_driver's VAL3: movej at the velocity share, stopping at each "
        "point; 10-point queue, FAILURE when full; motion only while both sockets are connected",
        state_rate=50.0,
        fixed_wire=True,
        motion="movej at each point's velocity share, stopping at each",
        options={"motion_stack": f"moves the VAL3 motion stack holds, default {VAL3_MOTION_STACK}"},
    )
)
