"""The Fanuc profile: a controller running fanuc_driver's KAREL relay and TP program, as they behave.

Read from ros-industrial/fanuc ``fanuc_driver/karel/`` and ``tpe/`` (melodic-devel 8fee5e3; the
indigo and kinetic branches have the same files); docs/vendors.md has every rule with its file:line,
and what the emulator does.

**Motion port** (11000, big-endian, one client; a second waits in the listen backlog). The relay
(``ros_relay.kl``) reads nothing until 56 bytes are waiting, then reads 60: the length prefix, the
header, a sequence and 10 joints, and 8 more (velocity, duration) when the header says
JOINT_TRAJ_PT with a length of 64 or more (``libind_pkt.kl:218-258,310-314``), whatever the type
otherwise: any such read is a trajectory point. So a message shorter than 56 bytes alone (a PING)
is never read and never answered, and one of another size misframes the stream from there on. Both
are reproduced and logged once; ``--lenient`` frames by the length prefix and drops what is not a
JOINT_TRAJ_PT with a warning instead (still unanswered, as the relay answers no such message). When
nothing is waiting the relay sleeps 24 ms between looks (``ros_relay.kl:354-358``).

* A point with sequence >= 0 is acknowledged at once, before anything else is checked, whatever its
  comm type: a JOINT_POSITION (10), SERVICE_REPLY, SUCCESS, the sequence echoed, 10 zero joints
  (``ros_relay.kl:328-336``). Then it is checked against the joint limits (``J_IN_RANGE``): out of
  range, a FAILURE reply of the same shape follows and the relay closes the connection
  (``:339-349``, a status check that always disconnects), and the point is not run.
* Sequences -1, -2, -3 and below -4 get no reply (``:294-306,321-323``). -4 is answered SUCCESS,
  but its ``CANCEL`` stops nothing: the motion belongs to the TP program (``:309-318``,
  ros-industrial/fanuc#93). Reproduced (the points taken run to their end, one line says so);
  with ``--lenient`` the robot stops.
* The relay hands one point at a time to the TP program ``ros_movesm`` (flags F[1]/F[2], PR[1]) and
  reads nothing more until the TP has taken it (``ros_relay.kl:496-513``): the next reply waits.

**Execution** (``ros_movesm.ls:30-46``): each point is ``J PR[2] R[1]% CNT R[2]``, a joint move at
R[1] = 20 % of the joints' speed with CNT R[2] = 50; its duration and velocity are never used. The
TP program takes the next point when the move's CNT window begins, so the moves blend when the
points come in time (:mod:`..control.moves`, blend CNT/100). ``--profile-option speed=N`` and
``cnt=N`` set R[1] and R[2].

**The J2/J3 coupling**: the controller's J3 is the ROS J3 minus ``J23_factor`` times J2, which
fanuc_driver converts both ways (``fanuc_joint_streamer_node.cpp:70-76``,
``fanuc_robot_state_node.cpp:73-77``); the model is in ROS's joints. The profile converts likewise
(``--profile-option j23_factor=1``, the default; 0, -1), so the emulated arm's pose, tool pose and
limits are what fanuc_driver publishes with that factor.

**Connections**: a lost motion client does not stop the motion (the TP program runs on), and a
point the relay was handing over is still handed over (``ros_relay.kl:278-284,365-366``); the next
client's points are read only after that.

**E-stop, alarms, reset**: the e-stop (or an alarm, or the drives off) abandons the move under way
and the moves the TP program had taken; a point the relay is handing over waits, as the relay
waits for F[1], and is handed over after ``reset``, so the robot moves on to it: the TP program's
interrupted moves are not resumed (the ROS driver sees the robot short of its goal).

**State port** (11002, one client, never read): every 24 ms a JOINT_POSITION (sequence 0, the
controller's joints), and a STATUS after every 11th, the count kept across clients
(``ros_state.kl:242-297``); each message in its own write.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Awaitable, Iterable, Mapping

import numpy as np

from simple_message.constants import CommType, MsgType, ReplyCode, SpecialSeq
from simple_message.dialects import FANUC
from simple_message.endpoints import NO_REPLY, CloseConnection, HandlerResult, Server, Session
from simple_message.fixed_reads import FRAME_HEAD, FixedReads, prefix_cut
from simple_message.framing import DEFAULT_MAX_LENGTH
from simple_message.messages import JointPosition, Message, RawMessage, Status
from simple_message.wire import WireFormat

from ..control import Point, PointRejected, Reason
from ..control.points import within
from .cell import RobotCell
from .owner import OnDisconnect
from .profiles import EmulatorProfile, PortRules, ProfileContext, int_option, never_read, register_profile
from .quirks import Quirks

__all__ = [
    "FANUC_PROFILE",
    "FanucBehaviour",
    "FanucReads",
    "FanucRelay",
    "FanucState",
    "KAREL_GATE",
    "KAREL_PERIOD",
]

log = logging.getLogger(__name__)

#: the relay reads once this many bytes are waiting (RI_SZ_HDR + RI_SZB_JPOS, libind_pkt.kl:310-314)
KAREL_GATE = 56
#: what it then reads: prefix, header, sequence, 10 joints; and velocity and duration for a point
KAREL_READ = 60
KAREL_POINT_READ = 68
#: the relay's and the state server's sleep: ROUND(1000 / 42) ms (ros_relay.kl:206, ros_state.kl:180)
KAREL_PERIOD = 0.024
#: a STATUS after every 11th JOINT_POSITION (sloop_div 10, ros_state.kl:269-291)
KAREL_STATUS_AFTER = 10
#: R[1] and R[2]: the move's speed (% of the joints' maximum) and CNT (ros_relay.kl:399-403)
DEFAULT_SPEED = 20
DEFAULT_CNT = 50


class FanucReads(FixedReads):
    """The relay's reads (see the module doc). ``lenient``: by the length prefix."""

    def __init__(self, wire: WireFormat, *, lenient: bool = False) -> None:
        super().__init__(wire)
        self.lenient = lenient

    def cut(self, buf: bytes, start: int) -> int | None:
        if self.lenient:
            return prefix_cut(buf, start, self.wire, DEFAULT_MAX_LENGTH)
        waiting = len(buf) - start
        if waiting < KAREL_GATE:
            return None
        length, msg_type, _, _ = self.wire.header.unpack_from(buf, start)
        size = KAREL_POINT_READ if msg_type == MsgType.JOINT_TRAJ_PT and length >= 64 else KAREL_READ
        return start + size if waiting >= size else None  # READ blocks until the rest has come


class FanucRelay:
    """``ros_relay`` and ``ros_movesm``: points read, acknowledged and handed to the TP program."""

    def __init__(
        self,
        cell: RobotCell,
        *,
        lenient: bool = False,
        speed: int = DEFAULT_SPEED,
        cnt: int = DEFAULT_CNT,
        j23_factor: int = 1,
    ) -> None:
        if len(cell.groups) != 1:
            raise ValueError("the fanuc profile plays one robot: give one model")
        if cell.groups[0].dof > 9:
            raise ValueError("the fanuc profile plays a robot of at most 9 axes (a KAREL JOINTPOS)")
        self.cell = cell
        self.controller = cell.groups[0]
        self.lenient = lenient
        self.speed = speed / 100.0
        self.blend = cnt / 100.0
        self.j23_factor = j23_factor if self.controller.dof >= 3 else 0
        #: controller time when the relay last found nothing to read (it looks again every 24 ms)
        self._idle_since = 0.0
        self._handover: asyncio.Task[None] | None = None
        #: the motion port's server (:meth:`install`)
        self.server: Server | None = None
        self._quirks = Quirks(log)
        self._short_seen: dict[Session, float] = {}

    def install(self, server: Server) -> None:
        self.server = server
        server.unknown_request = self.on_read
        self.cell.listen(self.tick, self.idle)

    def idle(self) -> bool:
        """:meth:`tick` has nothing to watch: no relay connection (or lenient), none noted."""
        return self.server is None or self.lenient or (not self.server.sessions and not self._short_seen)

    def close(self) -> None:
        """The controller is switched off: a hand-over still waiting for the TP program ends."""
        if self._handover is not None and not self._handover.done():
            self._handover.cancel()
        self._handover = None

    # -- the coupling ----------------------------------------------------------------------------

    def to_model(self, joints: np.ndarray) -> np.ndarray:
        """The controller's joints to the model's (ROS's): J3 + J23_factor * J2."""
        q = joints.copy()
        if self.j23_factor:
            q[2] = joints[2] + self.j23_factor * joints[1]
        return q

    def to_controller(self, q: np.ndarray) -> np.ndarray:
        """The model's joints to the controller's: J3 - J23_factor * J2."""
        joints = np.array(q, dtype=float)
        if self.j23_factor:
            joints[2] = q[2] - self.j23_factor * q[1]
        return joints

    # -- ros_relay -------------------------------------------------------------------------------

    def on_read(self, msg: Message, session: Session) -> Awaitable[HandlerResult]:
        return self._relay(msg, session)

    async def _relay(self, msg: Message, session: Session) -> HandlerResult:
        assert isinstance(msg, RawMessage)
        read_at = self._read_at()
        await self.cell.until(lambda: self.cell.time >= read_at - 1e-9)
        try:
            return await self._point(msg, session)
        finally:
            self._idle_since = self.cell.time

    def _read_at(self) -> float:
        """When the relay reads what came: at once if it was busy, else at its next 24 ms look."""
        now, idle = self.cell.time, self._idle_since
        if now <= idle + 1e-9:
            return now
        return idle + math.ceil((now - idle) / KAREL_PERIOD - 1e-9) * KAREL_PERIOD

    async def _point(self, msg: RawMessage, session: Session) -> HandlerResult:
        wire = session.wire
        is_point = msg.msg_type == MsgType.JOINT_TRAJ_PT
        if self.lenient and not is_point:
            self._quirks.say(
                session,
                "not a point",
                f"message type {msg.msg_type} dropped: the relay takes only trajectory points (--lenient)",
            )
            return NO_REPLY
        if not is_point:
            self._quirks.say(
                session,
                "misframed",
                f"a read of {len(msg.body) + FRAME_HEAD} bytes whose header says type {msg.msg_type} is taken for a "
                "trajectory point, as the relay takes any read (libind_pkt.kl:218-258); a message of another size "
                "than a point misframes the stream from there on",
            )
        fields = wire.struct("i10r").unpack_from(msg.body.ljust(44, b"\0"), 0)
        sequence = int(fields[0])
        joints = np.array(fields[1:11], dtype=float)
        if sequence == SpecialSeq.STOP_TRAJECTORY:
            if self.lenient:
                duration = self.cell.stop()
                session.log(log, logging.INFO, "STOP: decelerating for %.3f s (--lenient)", duration)
            else:
                self._quirks.say(
                    session,
                    "stop",
                    "STOP (-4) answered SUCCESS, but the relay's CANCEL stops nothing: the TP program runs the "
                    "points it has taken to their end (ros_relay.kl:309-318, ros-industrial/fanuc#93; --lenient "
                    "stops the robot)",
                )
            return _ack(sequence, ReplyCode.SUCCESS)
        if sequence < 0:
            session.log(log, logging.INFO, "sequence %d: not answered (the relay ignores it)", sequence)
            return NO_REPLY
        session.send_nowait(_ack(sequence, ReplyCode.SUCCESS))  # before anything is checked
        dof = self.controller.dof
        q = self.to_model(joints[:dof])
        lim = self.controller.limits
        try:
            if not np.all(np.isfinite(q)):
                raise PointRejected(Reason.NOT_FINITE, "the point contains NaN or infinity")
            within(q, lim.lower, lim.upper, Reason.POSITION_LIMIT, "position")
        except PointRejected as exc:
            session.log(
                log,
                logging.WARNING,
                "point %d is out of range (%s): FAILURE, and the relay closes the connection (ros_relay.kl:339-349)",
                sequence,
                exc,
            )
            session.send_nowait(_ack(sequence, ReplyCode.FAILURE))
            raise CloseConnection from None
        # exec_move_: hand the point to the TP program; finished even if the client goes meanwhile
        handover = asyncio.ensure_future(self._hand_over(sequence, q))
        self._handover = handover
        await asyncio.shield(handover)
        return NO_REPLY

    async def _hand_over(self, sequence: int, q: np.ndarray) -> None:
        """WAIT F[1] (the TP program is ready for a point), then PR[1], F[2]; the TP takes it."""
        moves = self.controller.moves
        while True:
            ready = self.cell.motion_possible and self.cell.time >= moves.ready_at(self.blend) - 1e-9
            if ready:
                try:
                    self.cell.submit_move(0, Point(q), speed=self.speed, blend=self.blend)
                    return
                except PointRejected as exc:
                    if exc.reason is not Reason.NOT_READY and exc.reason is not Reason.BUSY:
                        log.warning("point %d: the TP program's move fails: %s", sequence, exc)
                        return
            await self.cell.changed()

    def tick(self) -> None:
        """A message shorter than 56 bytes waiting on its own is never read: say so once."""
        server = self.server
        if server is None or self.lenient:
            return
        now = self.cell.time
        for session in list(server.sessions):
            waiting = session.connection.link.buffered
            if 0 < waiting < KAREL_GATE:
                seen = self._short_seen.setdefault(session, now)
                if now - seen >= 2 * KAREL_PERIOD:
                    self._quirks.say(
                        session,
                        "stalled",
                        f"{waiting} bytes wait unread: the relay reads only once {KAREL_GATE} are waiting "
                        "(libind_pkt.kl:310-314), so a message shorter than that stalls it (a PING is never answered)",
                    )
            else:
                self._short_seen.pop(session, None)
        for session in [s for s in self._short_seen if s not in server.sessions]:
            del self._short_seen[session]


def _ack(sequence: int, code: ReplyCode) -> JointPosition:
    """The relay's reply: a JOINT_POSITION carrying the sequence, its joints zero."""
    return JointPosition(sequence, comm_type=CommType.SERVICE_REPLY, reply_code=code)


class FanucState:
    """``ros_state``: JOINT_POSITION, and STATUS after every 11th (see the module doc)."""

    def __init__(self, cell: RobotCell, relay: FanucRelay) -> None:
        self.cell = cell
        self.relay = relay
        self._count = 0

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        recipients = list(sessions)
        tick = self.cell.groups[0].command
        joints = self.relay.to_controller(np.array(tick.actual_position))
        server.broadcast(JointPosition(0, tuple(joints.tolist())), recipients)
        if self._count >= KAREL_STATUS_AFTER:
            server.broadcast(self.cell.status(), recipients)
            self._count = 0
        else:
            self._count += 1


class FanucBehaviour:
    """The Fanuc profile's :class:`~.profiles.Behaviour`."""

    def __init__(self, context: ProfileContext) -> None:
        options = context.options
        self.cell = context.cell
        self.relay = FanucRelay(
            context.cell,
            lenient=context.lenient,
            speed=int_option("fanuc", options, "speed", DEFAULT_SPEED, allowed=range(1, 101), what="in 1..100"),
            cnt=int_option("fanuc", options, "cnt", DEFAULT_CNT, allowed=range(101), what="in 0..100"),
            j23_factor=int_option("fanuc", options, "j23_factor", 1, allowed=(-1, 0, 1), what="in -1, 0, 1"),
        )
        self.state = FanucState(context.cell, self.relay)

    def install(self, servers: Mapping[str, Server]) -> None:
        self.relay.install(servers["motion"])

    def close(self) -> None:
        self.relay.close()

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        self.state.publish(server, sessions)

    def status(self) -> Status:
        return self.cell.status()


FANUC_PROFILE = register_profile(
    EmulatorProfile(
        FANUC,
        FanucBehaviour,
        ports={
            "motion": PortRules(max_connections=1, excess="wait", answer_topics=True, reader=FanucReads),
            "state": PortRules(max_connections=1, excess="wait", listen_only=True, reader=never_read),
        },
        description="Fanuc, fanuc_driver's KAREL relay and TP program: each point a J move at 20 % CNT50 (time "
        "ignored), JOINT_POSITION acks, big-endian",
        state_rate=1000.0 / 24.0,
        on_disconnect=OnDisconnect.CONTINUE,
        fixed_wire=True,
        motion="J moves at the R[1] % speed, CNT R[2] (the TP program's)",
        options={
            "speed": f"R[1], the moves' speed in % of the joints' maximum, default {DEFAULT_SPEED}",
            "cnt": f"R[2], the moves' CNT 0..100, default {DEFAULT_CNT}",
            "j23_factor": "fanuc_driver's J23_factor (controller J3 = ROS J3 - factor x J2): 1 (default), 0, -1",
        },
    )
)
