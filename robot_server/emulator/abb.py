"""The ABB profile: an IRC5 running abb_driver's RAPID servers, as they behave.

Read from ros-industrial/abb_driver ``rapid/`` (melodic-devel f3068b9; the kinetic branches have the
same files); docs/vendors.md has every rule with its file:line, and what the emulator does.

**Motion port** (11000, one client: ``ROS_motionServer.mod:42-49``; a second waits unserved in the
listen backlog, and is reset when the first goes: the server closes its listening socket then,
``:59-61``, and opens a new one, ``:41-43``, so only a connect made after that is served). RAPID
reads the length prefix, then that many bytes (``ROS_socket.sys:67-71``), and takes only
JOINT_TRAJ_PT: another type, a body under 52 bytes, or a length RAPID cannot read (0, or over its
1024-byte rawbytes) raises an error no handler catches (``ROS_messages.sys:111-124``,
``ROS_motionServer.mod:51``): the motion server task stops, unanswered, reading nothing more, until
the operator restarts it (here: the ``reset`` fault command), which closes every connection of the
port. That is reproduced and logged once; ``--lenient`` drops such a message with a warning instead.

* A SERVICE_REQUEST gets a header-only SUCCESS (length 12) once the point is handled, a TOPIC
  nothing; FAILURE never (``ROS_motionServer.mod:91-94``).
* Sequence -1 empties the buffer and adds its point; -3 adds its point and hands the buffer to the
  motion task; -4 empties the buffer (its own point is not added) and hands over nothing, which
  stops the robot (StopMove, ClearPath, StartMove: the stop does not latch); any other value adds a
  point, in any order (``ROS_motionServer.mod:72-88``). Nothing but -3 starts a motion, and -3 does
  not empty the buffer: points sent after it without a -1 are added to the old ones.
* The buffer holds 100 points (``MAX_TRAJ_LENGTH``, ``ROS_common.sys:37``). A point beyond it,
  END's own included, is dropped (RAPID writes one event-log warning per point) and still answered
  SUCCESS; -3 hands over the first 100, which run, and the robot stops short of the goal. The
  emulator says so in one WARNING line at -3 naming the buffer and how many points were dropped.
* A hand-over pre-empts what runs: the robot decelerates (StopMove, ClearPath) and the new points
  run from where it stopped (``ROS_motion.mod:107-124``).

**Execution** (``ROS_motion.mod``): each point is ``MoveAbsJ target, v10, \\T:=duration, z10, tool0``,
the last with ``fine`` (``:59-66``): the point's duration times its segment, its velocity is never
used, the robot passes the points (z10) and stops at the last one. The first point is skipped when
every axis is within 0.1 degree of where the robot is (``is_near``, ``:59,92-104``); otherwise the
robot moves there in that point's duration (industrial_robot_client gives a first point 10 s).
The emulator runs the points as a download under the ``blend`` policy: through the points on time,
slowed where a segment is beyond the joints (RAPID's \\T cannot make the robot faster than its
limits either), to rest at the last. A duration of 0 is a move as fast as the joints allow
(what RAPID does with ``\\T:=0`` is not in the sources). A point beyond the joint limits: MoveAbsJ
fails there and the motion task aborts the trajectory (``:74-76``): the points before it run.

**Connections**: a lost motion client does not stop the motion (the motion task runs on its own,
``ROS_motionServer.mod:51-61``), and the buffer is kept for the next client.

**State port** (11002, one client, never read): JOINT_POSITION (sequence 0, the robot's joints,
unused slots 0) then STATUS, each with its own send, every 0.1 s (``ROS_stateServer.mod:43-47``).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Awaitable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from simple_message.constants import CommType, MsgType, SpecialSeq
from simple_message.dialects import ABB
from simple_message.endpoints import NO_REPLY, HandlerResult, Server, Session
from simple_message.errors import MalformedMessage
from simple_message.fixed_reads import FRAME_HEAD, FixedReads
from simple_message.messages import JointPosition, Message, RawMessage, Status
from simple_message.wire import WireFormat

from ..control import Point, PointRejected, check_point
from .cell import RobotCell
from .owner import OnDisconnect
from .profiles import EmulatorProfile, PortRules, ProfileContext, never_read, register_profile
from .quirks import Quirks

__all__ = [
    "ABB_BUFFER",
    "ABB_PROFILE",
    "ABB_SKIP_TOLERANCE",
    "AbbBehaviour",
    "AbbMotion",
    "AbbReads",
    "AbbState",
]

log = logging.getLogger(__name__)

#: ``MAX_TRAJ_LENGTH``: the points the RAPID server buffers (ROS_common.sys:37)
ABB_BUFFER = 100
#: ``is_near(target, 0.1, 0.1)``: a first point closer than 0.1 degree on every axis is skipped
ABB_SKIP_TOLERANCE = math.radians(0.1)
#: the largest message RAPID can read: a rawbytes holds 1024 bytes
ABB_MAX_LENGTH = 1024
#: JOINT_TRAJ_PT's body as RAPID decodes it: sequence, 10 joints, velocity, duration
_POINT_BODY = 52


class AbbReads(FixedReads):
    """RAPID's reads: the length prefix, then that many bytes. A length it cannot read (below the
    12-byte header or over 1024) is a read of the prefix alone, which the motion server dies on.
    ``lenient``: the same, but such a length ends the connection as a frame error."""

    def __init__(self, wire: WireFormat, *, lenient: bool = False) -> None:
        super().__init__(wire)
        self.lenient = lenient
        self._prefix = wire.struct("i")

    def cut(self, buf: bytes, start: int) -> int | None:
        if len(buf) - start < 4:
            return None
        (length,) = self._prefix.unpack_from(buf, start)
        if not 12 <= length <= ABB_MAX_LENGTH:
            return start + 4
        end = start + 4 + length
        return end if end <= len(buf) else None

    def message(self, frame: bytes, wire: WireFormat) -> Message | MalformedMessage:
        if len(frame) < FRAME_HEAD:
            (length,) = self._prefix.unpack_from(frame, 0)
            return MalformedMessage(
                f"length prefix {length}: RAPID reads 12 to {ABB_MAX_LENGTH} bytes (a rawbytes holds 1024)",
                msg_type=0,
                comm_type=0,
                frame=frame,
            )
        return super().message(frame, wire)


@dataclass(frozen=True)
class _Stored:
    """A point as the RAPID server stores it: joints (rad here) and duration; no velocity."""

    positions: np.ndarray
    duration: float


class AbbMotion:
    """The RAPID motion server and motion task (see the module doc)."""

    def __init__(self, cell: RobotCell, *, lenient: bool = False) -> None:
        if len(cell.groups) != 1:
            raise ValueError("the abb profile plays one robot: give one model")
        self.cell = cell
        self.lenient = lenient
        self.controller = cell.groups[0]
        #: the server's own buffer (``trajectory``), kept across clients and after -3
        self.buffer: list[_Stored] = []
        #: points dropped since the buffer was last emptied (beyond its 100)
        self.dropped = 0
        #: the motion server task stopped on an error (until the operator's reset)
        self.dead: str | None = None
        #: the motion port's server (:meth:`install`)
        self.server: Server | None = None
        self._quirks = Quirks(log)

    def install(self, server: Server) -> None:
        self.server = server
        server.unknown_request = self.on_read  # every read: the server registers no type of its own
        server.malformed_request = self.on_bad_length
        self.cell.reset_listeners.append(self.restart)

    def client_gone(self, session: Session) -> None:
        """The client left: ``main``'s handler ends the cycle and the UNDO closes the listening
        socket too (``ROS_motionServer.mod:51-61``); the new cycle opens a new one. A client that
        waited in the old backlog is reset. (A stopped task runs no handler: see :meth:`restart`.)"""
        if self.dead is None and self.server is not None:
            self.server.reset_backlog(
                "the RAPID motion server closes its listening socket when its client goes and opens "
                "a new one (ROS_motionServer.mod:41-43,59-61): connect again"
            )

    # -- the server task ---------------------------------------------------------------------------

    def on_read(self, msg: Message, session: Session) -> HandlerResult | Awaitable[HandlerResult]:
        if self.dead is not None:
            return self._while_dead(session)
        assert isinstance(msg, RawMessage)
        if msg.msg_type != MsgType.JOINT_TRAJ_PT:
            return self._die(
                session,
                f"unexpected message type {msg.msg_type}: RAPID raises ERR_ARGVALERR (ROS_messages.sys:111-116)",
            )
        if len(msg.body) < _POINT_BODY:
            return self._die(
                session,
                f"JOINT_TRAJ_PT body of {len(msg.body)} bytes: RAPID needs 52 and raises ERR_OUTOFBND "
                "(ROS_messages.sys:119-124)",
            )
        values = session.wire.struct("i10rrr").unpack_from(msg.body, 0)
        sequence, joints, duration = int(values[0]), values[1:11], float(values[12])
        self._handle(sequence, np.array(joints[: self.controller.dof], dtype=float), duration, session)
        return None if msg.comm_type == CommType.SERVICE_REQUEST else NO_REPLY

    def on_bad_length(self, error: MalformedMessage, session: Session) -> Message | None:
        if self.lenient:
            self._quirks.say(session, "bad length", f"{error}: the connection is closed (--lenient)")
            session.connection.abort()
        elif self.dead is None:
            self._stop_task(session, str(error))
        return None

    def _die(self, session: Session, why: str) -> HandlerResult | Awaitable[HandlerResult]:
        if self.lenient:
            self._quirks.say(session, "dropped", f"{why}; the message is dropped (--lenient)")
            return NO_REPLY
        self._stop_task(session, why)
        return self._while_dead(session)

    def _stop_task(self, session: Session, why: str) -> None:
        self.dead = why
        session.log(
            log,
            logging.ERROR,
            "%s: no handler catches it (ROS_motionServer.mod:51), so the RAPID motion server stops: no "
            "reply, nothing more read on the motion port until the operator restarts it (the reset fault "
            "command); the motion task runs on (--lenient drops such messages instead)",
            why,
        )

    async def _while_dead(self, session: Session) -> HandlerResult:
        """A read while the server task is stopped: never answered (the connection is closed at
        the restart, or by its peer, first)."""
        await asyncio.Event().wait()
        return NO_REPLY  # never reached

    def restart(self) -> None:
        """The operator restarts the RAPID program (the reset fault command): the UNDO closes the
        client socket and the listening one (``ROS_motionServer.mod:59-61``), and ``main`` opens a
        new one. Every connection of the motion port is closed, those still waiting included; the
        next connect is served."""
        if self.dead is None:
            return
        log.info("the RAPID motion server is restarted: it listens for a client again, connect anew")
        self.dead = None
        assert self.server is not None
        self.server.reset_backlog("the restarted RAPID motion server opens a new listening socket: connect again")
        for session in list(self.server.sessions):
            session.connection.abort()

    # -- trajectory_pt_callback ----------------------------------------------------------------------

    def _handle(self, sequence: int, positions: np.ndarray, duration: float, session: Session) -> None:
        point = _Stored(positions, duration)
        if sequence == SpecialSeq.START_TRAJECTORY_DOWNLOAD:
            self.buffer, self.dropped = [], 0
            self._add(point)
        elif sequence == SpecialSeq.END_TRAJECTORY:
            self._add(point)
            self._activate(session)
        elif sequence == SpecialSeq.STOP_TRAJECTORY:
            self.buffer, self.dropped = [], 0
            duration = self.cell.stop()
            session.log(log, logging.INFO, "Traj STOP received: decelerating for %.3f s, the buffer emptied", duration)
        else:
            self._add(point)

    def _add(self, point: _Stored) -> None:
        if len(self.buffer) >= ABB_BUFFER:
            self.dropped += 1  # RAPID: ErrWrite "Too Many Trajectory Points", once per point
            return
        self.buffer.append(point)

    def _activate(self, session: Session) -> None:
        """Hand the buffer to the motion task: what runs is stopped, the points run from there."""
        points = list(self.buffer)
        if self.dropped:
            session.log(
                log,
                logging.WARNING,
                "the RAPID server's buffer holds %d points (MAX_TRAJ_LENGTH): %d points of this trajectory were "
                "dropped (the END point included) and the robot runs the first %d, stopping short of the goal",
                ABB_BUFFER,
                self.dropped,
                len(points),
            )
        self.cell.stop()  # StopMove; ClearPath; StartMove: a new trajectory pre-empts the running one
        controller = self.controller
        here = controller.queue.planned_end().position
        first = points[0].positions
        moves = points
        if np.all(np.abs(first - here) < ABB_SKIP_TOLERANCE):
            start = Point(first.copy(), duration=0.0)  # skipped: the robot is there
            moves = points[1:]
        else:
            start = Point(here.copy(), duration=0.0)  # MoveAbsJ to the first point in its duration
        run = []
        for k, stored in enumerate(moves):
            point = _point(stored)
            try:
                check_point(point, controller.limits, controller.config.max_segment_time)
            except PointRejected as exc:
                index = k + (len(points) - len(moves)) + 1
                session.log(
                    log,
                    logging.WARNING,
                    "point %d of %d: %s: MoveAbsJ fails there and the motion task aborts the trajectory "
                    "(ROS_motion.mod:74-76); the %d points before it run",
                    index,
                    len(points),
                    exc,
                    index - 1,
                )
                break
            run.append(point)
        if not run:
            return
        try:
            self.cell.submit_download(0, [start, *run])
        except PointRejected as exc:
            session.log(log, logging.WARNING, "the trajectory of %d points does not run: %s", len(points), exc)
            return
        session.log(log, logging.INFO, "Sending %d points to MOTION task", len(points))


def _point(stored: _Stored) -> Point:
    """MoveAbsJ with \\T:=duration: the duration times the segment; 0 is as fast as the joints allow.
    A negative or NaN duration is kept, so the check refuses it (MoveAbsJ fails there)."""
    if stored.duration == 0.0:
        return Point(stored.positions.copy(), duration=0.0, velocity_ratio=1.0)
    return Point(stored.positions.copy(), duration=stored.duration)


class AbbState:
    """The RAPID state server: JOINT_POSITION then STATUS (see the module doc)."""

    def __init__(self, cell: RobotCell) -> None:
        self.cell = cell

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        recipients = list(sessions)
        tick = self.cell.groups[0].command
        server.broadcast(JointPosition(0, tuple(tick.actual_position)), recipients)
        server.broadcast(self.cell.status(), recipients)


class AbbBehaviour:
    """The ABB profile's :class:`~.profiles.Behaviour`."""

    def __init__(self, context: ProfileContext) -> None:
        self.cell = context.cell
        self.motion = AbbMotion(context.cell, lenient=context.lenient)
        self.state = AbbState(context.cell)
        if context.owner is not None:
            context.owner.when_gone(self.motion.client_gone)

    def install(self, servers: Mapping[str, Server]) -> None:
        self.motion.install(servers["motion"])

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        self.state.publish(server, sessions)

    def status(self) -> Status:
        return self.cell.status()


ABB_PROFILE = register_profile(
    EmulatorProfile(
        ABB,
        AbbBehaviour,
        ports={
            "motion": PortRules(max_connections=1, excess="wait", answer_topics=True, reader=AbbReads),
            "state": PortRules(max_connections=1, excess="wait", listen_only=True, reader=never_read),
        },
        start_tolerance=ABB_SKIP_TOLERANCE,
        description="ABB IRC5, abb_driver's RAPID: JOINT_TRAJ_PT downloads of at most 100 points (-1 ... -3), "
        "MoveAbsJ timed by duration, header-only replies",
        state_rate=10.0,
        on_disconnect=OnDisconnect.CONTINUE,
        fixed_wire=True,
    )
)
