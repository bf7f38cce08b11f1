"""The robot driver: the PC side of a simple_message controller, done right.

The reference client's defects (simple-message.md §4, §7, §10) are what this driver must not do:
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
  as a share of its limit (when the model is known; see :meth:`RobotDriver._ratio`);
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
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from robot_server import RobotModel
from robot_server.control import QUINTIC_PEAK_VELOCITY
from simple_message.connection import ConnectionState, Subscription
from simple_message.constants import (
    CommType,
    MotoCommand,
    MotoResult,
    MsgType,
    RobotMode,
    SpecialSeq,
    TriState,
    ValidFields,
    moto_subcode_name,
)
from simple_message.dialects import GENERIC, Dialect, dialect
from simple_message.endpoints import Client, ReconnectPolicy
from simple_message.errors import (
    ConnectionClosed,
    NotConnected,
    RequestFailed,
    RequestTimeout,
    SimpleMessageError,
)
from simple_message.messages import (
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Ping,
    Status,
)
from simple_message.wire import WireFormat

from .trajectory import Trajectory

__all__ = ["RobotDriver", "DriverError", "ExecutionAborted", "JointState", "Mode"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]


class Mode(StrEnum):
    STREAM = "stream"
    DOWNLOAD = "download"


class DriverError(Exception):
    """The driver cannot do what was asked (not connected, bad trajectory, robot not ready...)."""


class ExecutionAborted(DriverError):
    """A trajectory execution stopped before the goal; ``confirmed`` is the index of the last point
    the controller acknowledged (-1: none)."""

    def __init__(self, message: str, confirmed: int) -> None:
        super().__init__(f"{message} (last point confirmed by the controller: {confirmed})")
        self.confirmed = confirmed


class _NotSent(DriverError):
    """The motion connection was down before the request was written: the controller never saw it."""


class _InFlight(DriverError):
    """The motion connection dropped while a request awaited its reply: the controller may have it."""


@dataclass(frozen=True)
class JointState:
    """The robot's latest state: positions (and velocities if the controller sends them) of
    motion group 0, the latest STATUS, and when it arrived (``time.monotonic()``)."""

    positions: Array
    velocities: Array | None
    status: Status | None
    received: float


class RobotDriver:
    """One controller's motion and state connections (see the module doc)."""

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
    ) -> None:
        #: the controller family (its ports, byte order, reply rule, how motion is commanded)
        self.dialect = dialect(profile) if isinstance(profile, str) else profile
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
        policy = ReconnectPolicy(initial_delay=0.1, max_delay=2.0)
        self.serial = serial
        if serial is not None:  # one link carries motion and state (robot-server --serial)
            self.motion = Client.serial(serial, wire, reconnect=policy, name=f"link {serial}", dialect=self.dialect)
            self.state = self.motion
        else:
            self.motion = Client.tcp(
                host,
                self.motion_port,
                wire,
                reconnect=policy,
                name=f"motion {host}:{self.motion_port}",
                dialect=self.dialect,
            )
            self.state = Client.tcp(
                host, self.state_port, wire, reconnect=policy, name=f"state {host}:{self.state_port}"
            )
        self._latest: JointState | None = None
        self._status: Status | None = None
        self._changed = asyncio.Event()
        self._reader: asyncio.Task[None] | None = None

    # -- lifecycle ---------------------------------------------------------------------------------

    async def connect(self, timeout: float = 10.0, *, motion: bool = True) -> RobotDriver:
        """Connect both ports and wait for the first joint state. ``motion=False`` connects the
        state port only: to watch the robot without being a motion client, which a controller
        serves one at a time (MotoROS, and the emulator, close an idle one for a newcomer)."""
        try:
            # whatever joint-state topic the peer sends (its dialect's state_topics, or another: a
            # generic peer may send JOINT_FEEDBACK, a MotoROS look-alike JOINT_POSITION)
            topics = {*self.dialect.state_topics, MsgType.JOINT_POSITION, MsgType.JOINT_FEEDBACK, MsgType.STATUS}
            subscription = self.state.subscribe(64, topics)
            clients = [self.motion] if motion or self.state is self.motion else []
            if self.state is not self.motion:
                clients.append(self.state)
            for client in clients:
                await client.start(timeout, refused_ends=True)
        except (TimeoutError, ConnectionClosed, OSError) as exc:
            await self.close()
            raise DriverError(self._cannot_connect(exc)) from None
        self._reader = asyncio.get_running_loop().create_task(self._read_state(subscription), name="driver state")
        await self.wait_state(timeout)
        return self

    def _no_state(self) -> str:
        """Why no joint state came: the connection's end if it ended, else the watchdog."""
        client = self.state
        if client.state is not ConnectionState.CONNECTED:
            cause = client.last_error
            return (
                f"the controller closed the state connection ({client.name}"
                f"{f': {cause}' if cause else ''}); no joint state for {self.watchdog} s"
            )
        return f"no joint state for {self.watchdog} s (watchdog)"

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
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reader
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

    # -- state -------------------------------------------------------------------------------------

    async def _read_state(self, subscription: Subscription) -> None:
        """One joint-state sample per state round: from JOINT_FEEDBACK once the controller has sent
        one (it carries velocities too), else from JOINT_POSITION; the other joint topic of the
        same round is ignored. A STATUS updates the latest sample's status, and wakes waiters only
        when it changed (:meth:`states` yields each sample once: recordings used to hold copies
        0.2 ms apart, and rates read high)."""
        feedback = False
        async for msg in subscription:
            if isinstance(msg, Status):
                changed = msg != self._status
                self._status = msg
                if self._latest is not None:
                    latest = self._latest
                    self._latest = JointState(latest.positions, latest.velocities, msg, latest.received)
                if not changed:
                    continue  # the same STATUS again: nothing new to wake anyone for
            if isinstance(msg, JointPosition):
                if feedback:
                    continue
                self._latest = JointState(self._positions(msg.joint_data), None, self._status, time.monotonic())
            elif isinstance(msg, JointFeedback) and msg.robot_id == 0:
                feedback = True
                velocities = self._positions(msg.velocities) if ValidFields.VELOCITY & msg.valid_fields else None
                self._latest = JointState(self._positions(msg.positions), velocities, self._status, time.monotonic())
            else:
                continue
            self._changed.set()
            self._changed = asyncio.Event()

    def _positions(self, values: tuple[float, ...]) -> Array:
        dof = self.model.dof if self.model is not None else len(values)
        return np.array(values[:dof], dtype=float)

    @property
    def joint_state(self) -> JointState | None:
        return self._latest

    @property
    def status(self) -> Status | None:
        return self._status

    async def wait_state(self, timeout: float | None = None) -> JointState:
        """The next joint state (within ``timeout``, default the watchdog period)."""
        try:
            async with asyncio.timeout(timeout if timeout is not None else self.watchdog):
                while True:
                    await self._changed.wait()
                    if self._latest is not None and self._status is not None:
                        return self._latest
        except TimeoutError:
            client = self.state
            if client.state is not ConnectionState.CONNECTED:
                raise DriverError(self._no_state()) from None
            raise DriverError(f"no joint state and STATUS from {client.name}") from None

    async def states(self) -> AsyncIterator[JointState]:
        """Every joint-state sample once, as it arrives (raises DriverError when none comes for the
        watchdog period); a changed STATUS alone is not a new sample."""
        last: float | None = None
        while True:
            state = await self.wait_state()
            if state.received != last:
                last = state.received
                yield state

    # -- requests ----------------------------------------------------------------------------------

    async def ping(self) -> float:
        """Round-trip time of a PING (s)."""
        start = time.perf_counter()
        await self._request(Ping())
        return time.perf_counter() - start

    async def _request(self, msg: Message) -> Message:
        try:
            return await self.motion.request(msg, self.reply_timeout)
        except RequestTimeout:
            # simple_message replies carry no request id: a reply arriving later could be taken
            # for the next request's, so the link is reset (it reconnects by itself)
            connection = self.motion.connection
            if connection is not None:
                log.warning("no reply to %s within %s s: resetting the motion link", msg.name, self.reply_timeout)
                await connection.close()
            raise DriverError(f"no reply to {msg.name} within {self.reply_timeout} s") from None
        except NotConnected as exc:
            raise _NotSent(
                f"motion connection down: {exc} (if the controller is up, another client may be moving the robot: "
                "a controller takes one motion client at a time)"
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

    # -- execution ---------------------------------------------------------------------------------

    async def execute(self, trajectory: Trajectory, mode: Mode | str = Mode.STREAM) -> JointState:
        """Run ``trajectory`` and wait for the goal (see the module doc). Returns the final state."""
        mode = Mode(mode)
        state = await self.wait_state()
        if self.motion.state is not ConnectionState.CONNECTED:  # e.g. being reset after a lost reply
            try:
                await self.motion.wait_for(ConnectionState.CONNECTED, self.reply_timeout)
            except (TimeoutError, ConnectionClosed):
                raise DriverError(f"the motion link to {self.address} is down") from None
        if self.model is not None and trajectory.dof != self.model.dof:
            raise DriverError(f"the trajectory has {trajectory.dof} joints, the robot {self.model.dof}")
        if trajectory.dof != state.positions.size and self.model is None:
            raise DriverError(
                f"the trajectory has {trajectory.dof} joints, the controller reports {state.positions.size}"
            )
        if self.model is not None and self.check_limits:
            check_limits(trajectory, self.model)
        gap = float(np.max(np.abs(trajectory.positions[0] - state.positions[: trajectory.dof])))
        if gap > self.goal_tolerance:
            raise DriverError(
                f"the trajectory starts {gap:.4g} away from the robot's position (tolerance {self.goal_tolerance})"
            )
        confirmed = -1
        try:
            if self.dialect.motion_control:
                confirmed = await self._send_motoros(trajectory)
            elif mode is Mode.DOWNLOAD:
                confirmed = await self._send_download(trajectory)
            else:
                confirmed = await self._send_stream(trajectory)
            return await self._wait_goal(trajectory, confirmed)
        except asyncio.CancelledError:
            await self._stop_quietly()
            raise
        except ExecutionAborted:
            await self._stop_quietly()
            raise
        except DriverError as exc:
            await self._stop_quietly()
            raise ExecutionAborted(str(exc), confirmed) from None

    async def _why_now(self) -> str:
        """:meth:`_why` from a STATUS that came after the refusal (the controller may have replied
        before publishing the change that made it refuse, e.g. an e-stop), waiting at most a
        watchdog period for it."""
        with contextlib.suppress(DriverError, TimeoutError):
            seen = self._latest.received if self._latest is not None else None
            async with asyncio.timeout(self.watchdog):
                while self._latest is None or self._latest.received == seen:
                    await self.wait_state()
        return self._why()

    def _faults(self) -> list[str]:
        """The reasons the latest STATUS gives for the robot not to move (none: nothing wrong)."""
        status = self._status
        if status is None:
            return []
        reasons = []
        if status.e_stopped == TriState.TRUE:
            reasons.append("the controller is e-stopped")
        if status.drives_powered == TriState.FALSE:
            reasons.append("the drives are off")
        if status.in_error == TriState.TRUE:
            reasons.append(f"it is in error (code {status.error_code})")
        if status.mode == RobotMode.MANUAL:
            reasons.append("it is in MANUAL mode (motion from a PC needs AUTO)")
        if not reasons and status.motion_possible == TriState.FALSE:
            reasons.append("STATUS says motion is not possible")
        return reasons

    def _faulted(self) -> bool:
        """The latest STATUS shows a reason the robot cannot move (see :meth:`_why`)."""
        return bool(self._faults())

    def _why(self) -> str:
        """Why the controller may refuse motion, as its latest STATUS says (it gives no reason with a
        FAILURE): e-stop, drives, an alarm, the mode; or that STATUS shows nothing wrong."""
        if self._status is None:
            return "no STATUS received to say why"
        reasons = self._faults()
        if reasons:
            return "; ".join(reasons)
        return "STATUS shows nothing wrong, so the point itself was refused (beyond a limit, or not where the robot is)"

    async def _stop_quietly(self) -> None:
        """Stop after an abort; if the motion link is down, wait (bounded) for it to come back."""

        async def stop() -> None:
            if self.motion.state is not ConnectionState.CONNECTED:
                await self.motion.wait_for(ConnectionState.CONNECTED, self.reply_timeout)
            await self.stop()

        with contextlib.suppress(DriverError, SimpleMessageError, TimeoutError):
            await asyncio.shield(stop())

    def _ratio(self, trajectory: Trajectory, k: int) -> float:
        """The velocity ratio of segment ``k``: the critical joint's peak speed as a share of its
        limit, the peak taken as a rest-to-rest quintic's (1.875 x the segment's mean speed; a
        controller joins JOINT_TRAJ_PT points at rest). 0 without a model, for the first point
        and for a pause."""
        if self.model is None or k == 0:
            return 0.0
        dt = trajectory.times[k] - trajectory.times[k - 1]
        mean = np.abs(trajectory.positions[k] - trajectory.positions[k - 1]) / dt
        return float(np.clip(np.max(QUINTIC_PEAK_VELOCITY * mean / self.model.max_velocity), 0.0, 1.0))

    def _point(self, trajectory: Trajectory, k: int, sequence: int, comm_type: int) -> JointTrajPt:
        duration = 0.0 if k == 0 else float(trajectory.times[k] - trajectory.times[k - 1])
        return JointTrajPt(
            sequence,
            tuple(trajectory.positions[k]),
            self._ratio(trajectory, k),
            duration,
            comm_type=comm_type,
        )

    async def _send_stream(self, trajectory: Trajectory) -> int:
        confirmed = -1
        k = 0
        while k < len(trajectory):
            try:
                await self._request(self._point(trajectory, k, k, CommType.SERVICE_REQUEST))
            except RequestFailed:
                raise ExecutionAborted(
                    f"the controller refused point {k}: {await self._why_now()}", confirmed
                ) from None
            except _NotSent as exc:
                await self._reconnected(k, confirmed, exc)
                continue  # point k was never written: send it on the new connection
            except _InFlight as exc:
                raise ExecutionAborted(_in_flight(k, exc), confirmed) from None
            except DriverError as exc:
                raise ExecutionAborted(f"point {k}: {exc}", confirmed) from None
            confirmed = k
            k += 1
        return confirmed

    async def _reconnected(self, k: int, confirmed: int, cause: DriverError) -> None:
        """Point ``k`` was not sent because the motion link is down: with ``resume``, wait for
        the reconnection and carry on from ``k`` (saying so); otherwise abort."""
        if not self.resume:
            raise ExecutionAborted(f"{cause} before point {k} was sent; not resuming (resume=False)", confirmed)
        try:
            await self.motion.wait_for(ConnectionState.CONNECTED, self.reply_timeout)
        except (TimeoutError, ConnectionClosed):
            raise ExecutionAborted(
                f"{cause}; no reconnection within {self.reply_timeout} s, point {k} was never sent", confirmed
            ) from None
        log.warning("motion connection re-established: resuming at point %d (points 0..%d confirmed)", k, confirmed)

    async def _send_download(self, trajectory: Trajectory) -> int:
        n = len(trajectory)
        indices = list(range(n)) if n > 1 else [0, 0]
        for i, k in enumerate(indices):
            sequence = (
                SpecialSeq.START_TRAJECTORY_DOWNLOAD
                if i == 0
                else SpecialSeq.END_TRAJECTORY
                if i == len(indices) - 1
                else k
            )
            try:
                await self.motion.send(self._point(trajectory, k if i else 0, sequence, CommType.TOPIC))
            except ConnectionClosed as exc:
                raise ExecutionAborted(f"motion connection lost during the download: {exc}", -1) from None
        # a download has no acknowledgements; a PING after it proves the controller read it all
        await self._request(Ping())
        return n - 1

    async def _motion_ready(self) -> None:
        ready = await self._moto(MotoCommand.CHECK_MOTION_READY)
        if ready.result != MotoResult.TRUE:
            enable = await self._moto(MotoCommand.START_TRAJ_MODE)
            if enable.result != MotoResult.SUCCESS:
                raise ExecutionAborted(
                    f"START_TRAJ_MODE refused: {moto_reason(enable.result, enable.subcode)}; {await self._why_now()}",
                    -1,
                )
            ready = await self._moto(MotoCommand.CHECK_MOTION_READY)
            if ready.result != MotoResult.TRUE:
                raise ExecutionAborted(
                    f"the controller is not ready for motion: {moto_reason(ready.result, ready.subcode)}", -1
                )

    async def _send_motoros(self, trajectory: Trajectory) -> int:
        await self._motion_ready()
        velocities = trajectory.velocities if trajectory.velocities is not None else _differences(trajectory)
        fields = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
        confirmed = -1
        for k in range(len(trajectory)):
            point = JointTrajPtFull(
                0, k, fields, float(trajectory.times[k]), tuple(trajectory.positions[k]), tuple(velocities[k])
            )
            delay, waited = 0.005, 0.0
            while True:
                try:
                    reply = await self._request(point)
                except _NotSent as exc:
                    await self._reconnected(k, confirmed, exc)
                    await self._ready_after_reconnect(k, confirmed)
                    continue
                except _InFlight as exc:
                    raise ExecutionAborted(_in_flight(k, exc), confirmed) from None
                if not isinstance(reply, MotoMotionReply):
                    raise ExecutionAborted(f"point {k} answered with {reply.name}", confirmed)
                if reply.result == MotoResult.SUCCESS:
                    break
                if reply.result != MotoResult.BUSY:
                    why = await self._why_now() if reply.result == MotoResult.NOT_READY else ""
                    raise ExecutionAborted(
                        f"the controller refused point {k}: {moto_reason(reply.result, reply.subcode)}"
                        f"{f'; {why}' if why else ''}",
                        confirmed,
                    )
                if waited > self.goal_timeout:
                    raise ExecutionAborted(f"point {k} still BUSY after {waited:.1f} s", confirmed)
                await asyncio.sleep(delay)  # back-off before resending: the controller said BUSY
                waited += delay
                delay = min(delay * 1.5, 0.05)
            confirmed = k
        return confirmed

    async def _ready_after_reconnect(self, k: int, confirmed: int) -> None:
        """MotoROS after a reconnection: carry on only if trajectory mode survived (it still says
        ready); a controller that dropped the trajectory would need a new one from where it stopped."""
        ready = await self._moto(MotoCommand.CHECK_MOTION_READY)
        if ready.result != MotoResult.TRUE:
            raise ExecutionAborted(
                f"after the reconnection the controller is not ready (subcode {ready.subcode}): it dropped the "
                f"trajectory, so point {k} is not sent",
                confirmed,
            )

    async def _wait_goal(self, trajectory: Trajectory, confirmed: int) -> JointState:
        goal = trajectory.positions[-1]
        sent = time.monotonic()
        deadline = sent + trajectory.duration + self.goal_timeout
        stalled_since: float | None = None
        # "at the goal and not moving" means done only once the robot has run the trajectory: a path
        # that ends where it starts is "at the goal" before it begins, and the STATUS that comes with
        # a joint state may be older than the last point. So the robot must have been seen moving
        # (in_motion TRUE, or away from the start), unless the trajectory does not move it, or the
        # planned duration (and stall_timeout) has passed since everything was sent.
        start = trajectory.positions[0]
        moves = bool(np.max(np.abs(trajectory.positions - start)) > self.goal_tolerance)
        seen_moving = False
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise ExecutionAborted("the robot did not reach the goal in time", confirmed)
            try:
                state = await self.wait_state(min(self.watchdog, remaining))
            except DriverError:
                if remaining < self.watchdog:
                    raise ExecutionAborted("the robot did not reach the goal in time", confirmed) from None
                raise ExecutionAborted(self._no_state(), confirmed) from None
            error = float(np.max(np.abs(state.positions[: goal.size] - goal)))
            if self.path_tolerance is not None:
                deviation = _path_deviation(trajectory, state.positions[: goal.size])
                if deviation > self.path_tolerance:
                    raise ExecutionAborted(
                        f"the robot is {deviation:.4g} from the path (tolerance {self.path_tolerance})", confirmed
                    )
            status = state.status
            if status is not None and status.in_error == TriState.TRUE:
                raise ExecutionAborted(f"the controller is in error (code {status.error_code})", confirmed)
            at_goal = error <= self.goal_tolerance
            here = state.positions[: goal.size]
            if (status is not None and status.in_motion == TriState.TRUE) or bool(
                np.max(np.abs(here - start)) > self.goal_tolerance
            ):
                seen_moving = True
            waited = time.monotonic() - sent
            if moves and not seen_moving and waited > self.stall_timeout and self._faulted():
                # a trajectory the controller dropped before it began (a download has no replies)
                raise ExecutionAborted(f"the robot did not move: {self._why()}", confirmed)
            ran = seen_moving or not moves or waited > trajectory.duration + self.stall_timeout
            if at_goal and ran and status is not None and status.in_motion != TriState.TRUE:
                if status.in_motion == TriState.UNKNOWN:
                    log.warning("goal reached, but the controller reports in_motion UNKNOWN")
                return state
            # standing still short of the goal: the controller dropped the trajectory (a refused
            # download point has no reply to say so) or someone stopped the robot
            if not at_goal and status is not None and status.in_motion == TriState.FALSE:
                now = time.monotonic()
                if stalled_since is None:
                    stalled_since = now
                elif now - stalled_since > self.stall_timeout:
                    raise ExecutionAborted(
                        f"the robot stands still {error:.4g} from the goal (in_motion FALSE for "
                        f"{self.stall_timeout} s): the controller dropped or stopped the trajectory"
                        f"{f': {self._why()}' if self._faulted() else ''}",
                        confirmed,
                    )
            else:
                stalled_since = None


def _in_flight(k: int, exc: DriverError) -> str:
    return (
        f"{exc} with point {k} awaiting its reply: the controller may or may not have it, so it is not "
        "resent (that could repeat it)"
    )


def _differences(trajectory: Trajectory) -> Array:
    """Waypoint velocities by central differences, zero at both ends."""
    q, t = trajectory.positions, trajectory.times
    v = np.zeros_like(q)
    if len(trajectory) > 2:
        v[1:-1] = (q[2:] - q[:-2]) / (t[2:] - t[:-2])[:, None]
    return v


def _path_deviation(trajectory: Trajectory, position: Array) -> float:
    """Distance (max over joints) from ``position`` to the piecewise-linear joint path."""
    q = trajectory.positions
    if len(trajectory) == 1:
        return float(np.max(np.abs(position - q[0])))
    a, b = q[:-1], q[1:]
    d = b - a
    length = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", position - a, d) / np.where(length > 0, length, 1.0), 0.0, 1.0)
    nearest = a + s[:, None] * d
    return float(np.min(np.max(np.abs(nearest - position), axis=1)))


def moto_reason(result: int, subcode: int) -> str:
    """A MOTO_MOTION_REPLY's result and subcode, named."""
    try:
        name = MotoResult(result).name
    except ValueError:
        name = f"result {result}"
    sub = moto_subcode_name(result, subcode)
    if sub is not None:
        return f"{name} ({sub}, subcode {subcode})"
    return f"{name} (subcode {subcode})" if subcode else name


def check_limits(trajectory: Trajectory, model: RobotModel) -> None:
    """Refuse, before anything is sent, a trajectory the robot cannot follow: a position beyond a
    joint's limits, or a segment whose mean speed is beyond a joint's maximum speed (no controller
    can run it in its time). The message names the point, the joint, the value and the limit."""
    names = model.joint_names
    units = ["m" if joint.type.value == "prismatic" else "rad" for joint in model.joints]
    lower, upper, vmax = model.lower, model.upper, model.max_velocity
    q = trajectory.positions
    for bound, beyond, side in ((lower, q < lower - 1e-9, "lower"), (upper, q > upper + 1e-9, "upper")):
        if beyond.any():
            k, j = (int(i) for i in np.argwhere(beyond)[0])
            raise DriverError(
                f"point {k}: joint {j + 1} ({names[j]}) at {q[k, j]:.4g} is beyond its {side} limit "
                f"{bound[j]:.4g} {units[j]}"
            )
    dt = np.diff(trajectory.times)
    if dt.size:
        speed = np.abs(np.diff(q, axis=0)) / np.maximum(dt, 1e-12)[:, None]
        over = speed > vmax * (1 + 1e-6)
        if over.any():
            k, j = (int(i) for i in np.argwhere(over)[0])
            raise DriverError(
                f"segment {k}->{k + 1}: joint {j + 1} ({names[j]}) would move at {speed[k, j]:.4g} {units[j]}/s on "
                f"average, beyond its maximum {vmax[j]:.4g} {units[j]}/s (give the segment at least "
                f"{abs(q[k + 1, j] - q[k, j]) / vmax[j]:.3g} s)"
            )
