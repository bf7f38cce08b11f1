"""The robot driver: the PC side of a simple_message controller, done right.

The reference client's defects (docs/reference/protocol.md §4, §7, §10) are what this driver must not do:
it checks every reply, never waits without a timeout, can stop at any moment (also with a point
pending, also when idle), computes a real duration for every JOINT_TRAJ_PT (no 10 s first segment),
and never skips or repeats a point silently.

:meth:`RobotDriver.execute` sends a :class:`~.trajectory.Trajectory` the way the controller family
expects and returns only when the robot is within ``goal_tolerance`` of the last point *and* STATUS
says in_motion FALSE (like ROS's FollowJointTrajectory action, §5):

The controller family is a :class:`~simple_message.dialects.Dialect` (``profile``: one, or its
name): its ports, byte order and reply rule, and whether motion takes MOTO_MOTION_CTRL commands.

* generic profile, ``mode="stream"``: JOINT_TRAJ_PT SERVICE_REQUESTs, sequence 0..n-1, one in
  flight; each reply must be SUCCESS; durations are the waypoint time differences (0 for the first
  point, which must be where the robot is) and the velocity ratio the critical joint's peak speed
  as a share of its limit (when the model is known; see :meth:`.sending.TrajectorySender.ratio`);
* generic profile, ``mode="download"``: TOPICs with sequence -1, 1..n-2, -3 (a single point is sent
  twice, as the reference downloader does);
* MotoROS profile (a dialect with ``motion_control``): CHECK_MOTION_READY (and START_TRAJ_MODE if
  needed), then JOINT_TRAJ_PT_FULL with time, positions and velocities (central differences when
  the trajectory has none); BUSY is retried with a growing back-off; anything else aborts.

**Reconnection.** The connections reconnect by themselves. If the motion link is down when a
point is about to be sent, the driver with ``resume=True`` waits for the reconnection and goes on
from that point (MotoROS: only if the controller still reports ready), logging a warning that says
where it resumed; with ``resume=False`` (the default) it aborts. If the link drops while a point
awaits its reply, the controller may or may not have that point, so the driver never resends it
(it could run twice): it aborts, says so, and stops the robot once the link is back.

It raises :class:`ExecutionAborted` (with :attr:`~ExecutionAborted.confirmed`, the last point the
controller acknowledged, so a caller can resume from there) on a refused point, a lost
connection, a state watchdog expiry (no joint state for ``watchdog`` s), a path deviation beyond
``path_tolerance``, a robot standing still short of the goal for ``stall_timeout`` s after every
point was sent (how a dropped download shows: TOPIC points have no reply), or no goal within
``goal_timeout`` s after the trajectory's end; before raising it tries to stop the robot.
Cancelling ``execute`` stops it too.

**Straight lines run by the controller** (CARTESIAN_LINE and TOOL_POSE, this project's extension,
docs/protocol.md). :meth:`RobotDriver.supports_lines` asks the controller once per connection
(a CARTESIAN_LINE STOP: only its own reply type means yes). :meth:`RobotDriver.move_lines` sends
:class:`LineGoal` targets as lines 0, 1, ... and waits, as ``execute`` does, until the robot has
run them and the actual TCP is at the last one; a refused line raises :class:`LineRefused`, which
names the controller's :class:`~simple_message.constants.LineResult`. :meth:`RobotDriver.subscribe_tool_pose`
asks for TOOL_POSE on the state connection; :attr:`RobotDriver.tool_pose` is the latest one.

:class:`RobotDriver` is the facade over the pieces that do this, one idea each: the state
connection read into the latest joint state and STATUS, and the wait for more (:mod:`.monitor`);
the trajectory's senders, one per way a controller family takes points (:mod:`.sending`); the
straight lines (:mod:`.lines`); the wait for the goal after either (:mod:`.waiting`). Itself it
keeps the connections and the requests on the motion connection.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import AsyncIterator, Sequence

import numpy as np

from robot_server import Array, RobotModel
from simple_message.connection import ConnectionState, Tap
from simple_message.constants import MotoCommand, MotoResult, MsgType, SpecialSeq
from simple_message.dialects import GENERIC, Dialect, dialect
from simple_message.endpoints import Client, ReconnectPolicy
from simple_message.errors import (
    ConnectionClosed,
    NotConnected,
    RequestFailed,
    RequestTimeout,
)
from simple_message.messages import (
    JointTrajPt,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Ping,
    Status,
    ToolPose,
)
from simple_message.wire import WireFormat

from .errors import DriverError, ExecutionAborted, _InFlight, _NotSent
from .limits import check_limits, within_speeds
from .lines import CartesianLines, LineGoal, LineRefused
from .monitor import JointState, StateMonitor
from .reasons import moving_elsewhere
from .sending import Mode, sender_for
from .stopping import stop_after_abort
from .trajectory import Trajectory
from .waiting import GoalSupervisor

__all__ = ["RobotDriver", "DriverError", "ExecutionAborted", "LineRefused", "LineGoal", "JointState", "Mode"]

log = logging.getLogger(__name__)


#: how long (s) a cancelled motion waits for the robot to come to rest before the client goes on
STOP_SETTLE = 10.0


class RobotDriver:
    """One controller's motion and state connections (see the module doc). ``tap`` sees both
    connections' traffic (:class:`~simple_message.connection.Tap`, e.g. a
    :class:`~simple_message.capture.CaptureWriter`: ``robot-client --capture``)."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        motion_port: int | None = None,
        state_port: int | None = None,
        *,
        profile: Dialect | str = GENERIC,
        wire: WireFormat | None = None,
        model: RobotModel | None = None,
        reply_timeout: float = 5.0,
        watchdog: float = 1.0,
        goal_tolerance: float = 0.01,
        path_tolerance: float | None = None,
        goal_timeout: float = 60.0,
        stall_timeout: float = 1.0,
        serial: str | None = None,
        resume: bool = False,
        check_limits: bool = True,
        tcp_tolerance: float = 0.001,
        orientation_tolerance: float = 0.01,
        tap: Tap | None = None,
        j23_factor: int | None = None,
    ) -> None:
        #: the controller family (its ports, byte order, reply rule, how motion is commanded)
        self.dialect = dialect(profile) if isinstance(profile, str) else profile
        if j23_factor is None:
            j23_factor = 1 if self.dialect.j23_coupled else 0
        if j23_factor not in (-1, 0, 1):
            raise ValueError(f"j23_factor is -1, 0 or 1 (fanuc_driver's J23_factor), not {j23_factor}")
        #: the controller's J3 is the model's J3 minus this times J2 (Fanuc's coupling, as fanuc_driver
        #: converts it): points are sent and joint states read in the model's joints
        self.j23_factor = j23_factor
        self.host = host
        self.motion_port = motion_port if motion_port is not None else self.dialect.motion_port
        self.state_port = state_port if state_port is not None else self.dialect.state_port
        self.wire = wire = wire if wire is not None else self.dialect.wire
        self.model = model
        self.reply_timeout = reply_timeout
        self.watchdog = watchdog
        self.goal_tolerance = goal_tolerance
        self.path_tolerance = path_tolerance
        self.goal_timeout = goal_timeout
        self.stall_timeout = stall_timeout
        self.resume = resume
        #: refuse a trajectory beyond the model's position or speed limits before sending it (off:
        #: to see what a controller does with points it must refuse, e.g. a conformance test)
        self.check_limits = check_limits
        #: :meth:`move_lines` is done when the actual TCP is this close to the last target (m, rad)
        self.tcp_tolerance = tcp_tolerance
        self.orientation_tolerance = orientation_tolerance
        policy = ReconnectPolicy(initial_delay=0.1, max_delay=2.0)
        self.serial = serial
        if serial is not None:  # one link carries motion and state (robot-server --serial)
            self.motion = Client.serial(
                serial, wire, reconnect=policy, name=f"link {serial}", dialect=self.dialect, tap=tap
            )
            self.state = self.motion
        else:
            self.motion = Client.tcp(
                host,
                self.motion_port,
                wire,
                reconnect=policy,
                name=f"motion {host}:{self.motion_port}",
                dialect=self.dialect,
                tap=tap,
            )
            self.state = Client.tcp(
                host, self.state_port, wire, reconnect=policy, name=f"state {host}:{self.state_port}", tap=tap
            )
        #: the state connection read into the latest joint state, STATUS and TOOL_POSEs
        self._monitor = StateMonitor(self)
        #: the wait for the goal of what was sent, and for rest after a stop
        self._supervisor = GoalSupervisor(self)
        #: straight lines run by the controller, and whether it runs them
        self._lines = CartesianLines(self)
        #: the motion connection (its count) the controller last answered on: one is made by connect()
        self._answered_on = 1
        #: where the robot came to rest after a cancelled motion (:meth:`settle_after_stop`)
        self.stopped_at: JointState | None = None

    # -- lifecycle ---------------------------------------------------------------------------------

    async def connect(self, timeout: float = 10.0, *, motion: bool = True) -> RobotDriver:
        """Connect both ports and wait for the first joint state. ``motion=False`` connects the
        state port only: to watch the robot without being a motion client, which a controller
        serves one at a time (MotoROS, and the emulator, close an idle one for a newcomer)."""
        try:
            # whatever joint-state topic the peer sends (its dialect's state_topics, or another: a
            # generic peer may send JOINT_FEEDBACK, a MotoROS look-alike JOINT_POSITION)
            topics = {
                *self.dialect.state_topics,
                MsgType.JOINT_POSITION,
                MsgType.JOINT_FEEDBACK,
                MsgType.STATUS,
                MsgType.TOOL_POSE,  # only if asked for (subscribe_tool_pose)
            }
            subscription = self.state.subscribe(64, topics)
            clients = [self.motion] if motion or self.state is self.motion else []
            if self.state is not self.motion:
                clients.append(self.state)
            for client in clients:
                await client.start(timeout, refused_ends=True)
        except (TimeoutError, ConnectionClosed, OSError) as exc:
            await self.close()
            raise DriverError(self._cannot_connect(exc)) from None
        self._monitor.start(subscription)
        try:
            await self.wait_state(timeout)
        except BaseException:  # no state came (or cancelled): nothing stays open behind the error
            await self.close()
            raise
        return self

    def _cannot_connect(self, exc: BaseException) -> str:
        """Why connecting failed, with the cause the connection attempts met."""
        for client in (self.motion, self.state):
            error = client.last_error
            if client.state is not ConnectionState.CONNECTED and error is not None:
                if isinstance(error, ConnectionRefusedError):
                    return (
                        f"cannot connect to {client.name}: connection refused (is the controller, e.g. robot-server, "
                        "running there? check --host and the ports)"
                    )
                return f"cannot connect to {client.name}: {error or type(error).__name__}"
        return f"cannot connect to {self.address}: {str(exc) or 'timed out'}"

    async def close(self) -> None:
        await self._monitor.stop()
        await self.motion.close()
        if self.state is not self.motion:
            await self.state.close()

    @property
    def address(self) -> str:
        if self.serial is not None:
            return self.serial
        return f"{self.host} ports {self.motion_port}/{self.state_port}"

    async def __aenter__(self) -> RobotDriver:
        return await self.connect()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # -- state (monitor.py) ------------------------------------------------------------------------

    def from_controller(self, joints: Array) -> Array:
        """The controller's joints as the model's (Fanuc's J3: + J23_factor x J2)."""
        if self.j23_factor and joints.shape[-1] >= 3:
            joints = joints.copy()
            joints[..., 2] += self.j23_factor * joints[..., 1]
        return joints

    def to_controller(self, joints: Array) -> Array:
        """The model's joints as the controller takes them (Fanuc's J3: - J23_factor x J2)."""
        if self.j23_factor and joints.shape[-1] >= 3:
            joints = np.array(joints, dtype=float)
            joints[..., 2] -= self.j23_factor * joints[..., 1]
        return joints

    @property
    def joint_state(self) -> JointState | None:
        return self._monitor.latest

    @property
    def status(self) -> Status | None:
        return self._monitor.status

    @property
    def tool_pose(self) -> ToolPose | None:
        """The latest TOOL_POSE of motion group 0 (None until one arrives: only after
        :meth:`subscribe_tool_pose`, and only from a controller that has the extension)."""
        return self._monitor.tool_poses.get(0)

    def tool_pose_of(self, group: int) -> ToolPose | None:
        """The latest TOOL_POSE of motion group ``group`` (None until one arrives)."""
        return self._monitor.tool_poses.get(group)

    async def subscribe_tool_pose(self, *, wait: bool = True, rounds: int | None = 3) -> ToolPose | None:
        """Ask the controller for TOOL_POSE (this project's extension, docs/protocol.md: the actual
        TCP pose and speed each state round) by sending one TOOL_POSE on the state connection,
        and again after each reconnection. A TOPIC: a controller that does not know it ignores it,
        and :attr:`tool_pose` stays None.

        With ``wait``, returns the first TOOL_POSE if it comes within ``rounds`` joint-state
        samples after asking (a controller that has the extension sends it with the next round)
        or the watchdog period, else None; without, returns at once what is known. ``rounds``
        None waits the watchdog period whatever arrives: samples read late come in a burst, which
        would count as rounds before the controller has seen the request."""
        return await self._monitor.subscribe_tool_pose(wait=wait, rounds=rounds)

    def ask_feedback(self) -> None:
        """Ask the controller for JOINT_FEEDBACK on the state connection (the emulator's generic
        profile sends it to a client that sent one, docs/protocol.md: positions, velocities and the
        controller's time of each sample, :attr:`JointState.stamp`). A TOPIC: a controller that
        does not know it ignores it. Asked again after a reconnection."""
        self._monitor.ask_feedback()

    async def wait_state(self, timeout: float | None = None) -> JointState:
        """The next joint state (within ``timeout``, default the watchdog period)."""
        return await self._monitor.wait_state(timeout)

    def states(self) -> AsyncIterator[JointState]:
        """Every joint-state sample once, as it arrives (raises DriverError when none comes for the
        watchdog period); a changed STATUS alone is not a new sample."""
        return self._monitor.states()

    # -- requests ----------------------------------------------------------------------------------

    async def ping(self) -> float:
        """Round-trip time of a PING (s). A controller whose motion port answers no PING (ABB's
        RAPID server stops on one; Fanuc's and Stäubli's never answer) is not sent one:
        :class:`DriverError`."""
        if not self.dialect.ping:
            raise DriverError(
                f"the {self.dialect.name} controller's motion port answers no PING (ABB's RAPID server would stop "
                "on one; Fanuc's and Staubli's leave it unanswered): not sent"
            )
        start = time.perf_counter()
        await self._request(Ping())
        return time.perf_counter() - start

    async def _request(self, msg: Message) -> Message:
        try:
            reply = await self.motion.request(msg, self.reply_timeout)
            self._answered_on = self.motion.connects
            return reply
        except RequestTimeout:
            # simple_message replies carry no request id: a reply arriving later could be taken
            # for the next request's, so the link is reset (it reconnects by itself)
            connection = self.motion.connection
            if connection is not None:
                log.warning("no reply to %s within %s s: resetting the motion link", msg.name, self.reply_timeout)
                await connection.close()
            raise DriverError(f"no reply to {msg.name} within {self.reply_timeout} s") from None
        except NotConnected as exc:
            busy = self.moving_elsewhere()
            raise _NotSent(
                f"motion connection down: {exc} ("
                + (
                    busy
                    if busy is not None
                    else "if the controller is up, another client may be moving the robot: a controller takes one "
                    "motion client at a time"
                )
                + ")"
            ) from None
        except ConnectionClosed as exc:
            raise _InFlight(f"motion connection lost: {exc}") from None

    async def _moto(self, command: MotoCommand) -> MotoMotionReply:
        reply = await self._request(MotoMotionCtrl(0, 0, command))
        if not isinstance(reply, MotoMotionReply):
            raise DriverError(f"{command.name} answered with {reply.name}")
        return reply

    async def stop(self) -> None:
        """Stop the robot now (also with a point pending, also when idle)."""
        if self.dialect.motion_control:
            reply = await self._moto(MotoCommand.STOP_MOTION)
            if reply.result != MotoResult.SUCCESS:
                raise DriverError(f"STOP_MOTION refused: result {reply.result}, subcode {reply.subcode}")
        else:
            try:
                await self._request(JointTrajPt(SpecialSeq.STOP_TRAJECTORY))
            except RequestFailed:
                raise DriverError("the controller answered FAILURE to STOP") from None
        log.info("stop sent")

    def moving_elsewhere(self) -> str | None:
        """Why a motion cannot start now because the robot is moving (the latest STATUS says in_motion
        TRUE): under another motion client when the controller closed this client's motion
        connection, else a motion still under way (:func:`.reasons.moving_elsewhere`). None when
        STATUS does not say the robot moves."""
        return moving_elsewhere(self._monitor.status, self._motion_closed())

    def _motion_closed(self) -> bool:
        """The controller has closed this client's motion connection since it last answered on it (it is
        down, or was re-established since)."""
        return self.serial is None and (
            self.motion.state is not ConnectionState.CONNECTED or self.motion.connects > self._answered_on
        )

    async def _motion_up(self) -> None:
        """Wait (bounded) for the motion link if it is being re-established, e.g. after a reset."""
        if self.motion.state is not ConnectionState.CONNECTED:
            try:
                await self.motion.wait_for(ConnectionState.CONNECTED, self.reply_timeout)
            except (TimeoutError, ConnectionClosed):
                raise DriverError(f"the motion link to {self.address} is down") from None

    # -- straight lines run by the controller (CARTESIAN_LINE, this project's extension; lines.py) --

    async def supports_lines(self) -> bool:
        """Whether the controller runs straight lines itself (CARTESIAN_LINE, docs/protocol.md).

        The probe is a CARTESIAN_LINE STOP (sequence -4): harmless for a robot at rest, but a stop
        all the same, so ask only as the motion client about to move. Only a CARTESIAN_LINE reply
        (type 65001, SERVICE_REPLY, its 12-byte body) means yes, whatever its result; anything
        else means no: the C++ library's header-only FAILURE, MotoROS's MOTO_MOTION_REPLY, a reply
        that does not decode, no reply within ``min(reply_timeout, 1)`` s (the link is then reset,
        as for any lost reply, and the answer kept for the driver's life). The answer is kept for
        the motion connection it was found on."""
        return await self._lines.supports()

    async def move_lines(
        self, targets: Sequence[LineGoal], *, speed: float, blend_radius: float = 0.0, group: int = 0
    ) -> ToolPose:
        """Move the TCP of motion group ``group`` along straight lines through ``targets``, each
        line run by the controller (CARTESIAN_LINE, sequence 0, 1, ...) at the TCP ``speed`` (m/s),
        rounding each corner within ``blend_radius`` (m; 0: exact stops), and wait until the
        robot has run them: STATUS in_motion FALSE after it moved, and the actual TCP within
        :attr:`tcp_tolerance` and :attr:`orientation_tolerance` of the last target. The actual
        TCP is the controller's TOOL_POSE (subscribed here), or, from a controller that does not
        send it, the forward kinematics of the joint state (group 0, with a model). Returns the
        final TOOL_POSE.

        Raises :class:`DriverError` for bad targets or a controller without the extension
        (:meth:`supports_lines`, nothing sent then), :class:`LineRefused` naming the
        :class:`LineResult` when the controller refuses a line (nothing after it is sent), and
        :class:`ExecutionAborted` as :meth:`execute` does (an alarm or e-stop, a lost connection,
        a robot standing still short of the goal, no goal in time). Once a line has been
        accepted, any failure (and a cancellation) sends a STOP before raising."""
        return await self._lines.move(targets, speed=speed, blend_radius=blend_radius, group=group)

    # -- execution ---------------------------------------------------------------------------------

    async def execute(self, trajectory: Trajectory, mode: Mode | str | None = None) -> JointState:
        """Run ``trajectory`` and wait for the goal (see the module doc). Returns the final state.
        ``mode``: stream or download (default: the controller family's usual way; a family that
        takes only one refuses the other)."""
        sender = sender_for(self, mode)
        limit = self.dialect.max_points
        if limit is not None and len(trajectory) > limit:
            raise DriverError(
                f"the {self.dialect.name} controller keeps {limit} points of a trajectory and drops the rest (the "
                f"robot would stop short of the goal); this one has {len(trajectory)}: resample it to at most "
                f"{limit} points"
            )
        state = await self.wait_state()
        await self._motion_up()  # e.g. being reset after a lost reply
        if self.model is not None and trajectory.dof != self.model.dof:
            raise DriverError(f"the trajectory has {trajectory.dof} joints, the robot {self.model.dof}")
        if trajectory.dof != state.positions.size and self.model is None:
            raise DriverError(
                f"the trajectory has {trajectory.dof} joints, the controller reports {state.positions.size}"
            )
        if self.model is not None and self.check_limits:
            if self.dialect.timed:  # the others move at their own speed, whatever the points' timing
                trajectory = within_speeds(trajectory, self.model, velocities=self.dialect.motion_control)
            check_limits(trajectory, self.model, speeds=self.dialect.timed)
        gap = float(np.max(np.abs(trajectory.positions[0] - state.positions[: trajectory.dof])))
        busy = self.moving_elsewhere()
        if busy is not None and (gap > self.goal_tolerance or self._motion_closed()):
            raise DriverError(busy)
        if gap > self.goal_tolerance:
            raise DriverError(
                f"the trajectory starts {gap:.4g} away from the robot's position (tolerance {self.goal_tolerance})"
            )
        confirmed = -1
        try:
            confirmed = await sender.send(trajectory)
            return await self._supervisor.goal(trajectory, confirmed)
        except asyncio.CancelledError:
            await self._stop_quietly()
            raise
        except ExecutionAborted:
            await self._stop_quietly()
            raise
        except DriverError as exc:
            await self._stop_quietly()
            raise ExecutionAborted(str(exc), confirmed) from None

    async def settle_after_stop(self, bound: float = STOP_SETTLE) -> JointState | None:
        """After a cancelled motion (its STOP sent and acknowledged): wait, at most ``bound`` s,
        for the robot to be at rest, so that a client that then leaves does not leave while the
        robot brakes (the controller would take that for a lost client; ``robot-client`` does this
        on Ctrl-C). At rest is the first joint state sampled after STATUS said in_motion not TRUE
        with every joint still (:func:`.waiting.joints_still`): a state that came before that STATUS
        may show the robot still braking. When ``bound`` passes with STATUS saying at rest but the
        joints never that slow, the latest state sampled after that STATUS; None when there was
        none. It is also :attr:`stopped_at`."""
        self.stopped_at = await self._supervisor.settled(bound)
        return self.stopped_at

    async def _stop_quietly(self) -> None:
        """Stop after an abort; if the motion link is down, wait (bounded) for it to come back."""

        async def stop() -> None:
            if self.motion.state is not ConnectionState.CONNECTED:
                await self.motion.wait_for(ConnectionState.CONNECTED, self.reply_timeout)
            await self.stop()

        await stop_after_abort(stop())
