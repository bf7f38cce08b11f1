"""How a trajectory goes to a controller: the driver's senders, one per way a controller family
takes points (:func:`sender_for` chooses by the dialect and the :class:`Mode` asked for).

* ``stream`` (:class:`StreamSender`): JOINT_TRAJ_PT SERVICE_REQUESTs, sequence 0..n-1, one in
  flight; each reply must be SUCCESS. Durations are the waypoint time differences (0 for the first
  point, which is where the robot is); the velocity ratio is the critical joint's peak speed as a
  share of its limit when the model is known (:meth:`TrajectorySender.ratio`).
* ``download`` (:class:`DownloadSender`): TOPICs with sequence -1, 1..n-2, -3 (a single point is
  sent twice, as the reference downloader does), then a PING that proves the controller read them all.
* MotoROS's (:class:`MotorosSender`, a dialect with ``motion_control``): CHECK_MOTION_READY (and
  START_TRAJ_MODE if needed), then JOINT_TRAJ_PT_FULL with time, positions and velocities (central
  differences when the trajectory has none), on MotoROS's millisecond grid (:func:`_on_milliseconds`);
  BUSY is retried with a growing back-off; anything else aborts.

Each one's :meth:`~TrajectorySender.send` returns the index of the last point the controller
confirmed, or raises :class:`~.driver.ExecutionAborted` (with that index).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from abc import ABC, abstractmethod
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np

from robot_server import Array
from robot_server.control import QUINTIC_PEAK_VELOCITY
from robot_server.control.segments import cubic_hermite
from simple_message.connection import ConnectionState
from simple_message.constants import CommType, MotoCommand, MotoResult, SpecialSeq, TriState, ValidFields
from simple_message.errors import ConnectionClosed, RequestFailed
from simple_message.messages import JointTrajPt, JointTrajPtFull, MotoMotionReply, Ping

from .errors import DriverError, ExecutionAborted, _InFlight, _NotSent, moto_reason
from .limits import central_velocities, cubic_accelerations
from .trajectory import Trajectory

if TYPE_CHECKING:
    from .driver import RobotDriver

__all__ = ["DownloadSender", "Mode", "MotorosSender", "StreamSender", "TrajectorySender", "sender_for"]

log = logging.getLogger("client.driver")


class Mode(StrEnum):
    """How a controller that takes JOINT_TRAJ_PT gets a trajectory: point by point, or downloaded."""

    STREAM = "stream"
    DOWNLOAD = "download"


def sender_for(driver: RobotDriver, mode: Mode | str | None) -> TrajectorySender:
    """The sender for ``driver``'s controller family and ``mode`` (see :func:`_mode`)."""
    chosen = _mode(driver, mode)
    if driver.dialect.motion_control:
        return MotorosSender(driver)
    if chosen is Mode.DOWNLOAD:
        return DownloadSender(driver)
    return StreamSender(driver)


def _mode(driver: RobotDriver, mode: Mode | str | None) -> Mode:
    """The way to send a trajectory: ``mode``, if the controller family takes it, else its usual one."""
    modes = driver.dialect.modes
    if mode is None:
        return Mode(modes[0])
    chosen = Mode(mode)
    if driver.dialect.motion_control:  # one way only, whatever is asked (as before the vendor modes)
        if chosen.value not in modes:
            log.warning(
                "%s: the %s controller runs a trajectory one way, its trajectory mode: %s is not a choice there",
                driver.address,
                driver.dialect.name,
                chosen.value,
            )
        return Mode(modes[0])
    if chosen.value not in modes:
        raise DriverError(
            f"the {driver.dialect.name} controller takes trajectories {' or '.join(f'{m}ed' for m in modes)}, "
            f"not {chosen.value}ed"
        )
    return chosen


class TrajectorySender(ABC):
    """Sends one trajectory to ``driver``'s controller, one way (see the module doc): what the
    ways share."""

    def __init__(self, driver: RobotDriver) -> None:
        self.driver = driver

    @abstractmethod
    async def send(self, trajectory: Trajectory) -> int:
        """Send ``trajectory``; the index of the last point the controller confirmed."""

    def ratio(self, trajectory: Trajectory, k: int) -> float:
        """The velocity ratio of segment ``k``: the critical joint's peak speed as a share of its
        limit, the peak taken as a rest-to-rest quintic's (1.875 x the segment's mean speed; a
        controller joins JOINT_TRAJ_PT points at rest). 0 without a model, for the first point
        and for a pause."""
        if self.driver.model is None or k == 0:
            # a controller that moves at the velocity given (Staubli: VAL3 refuses 0) gets the
            # stock client's default share, 0.1 (joint_trajectory_interface.h)
            return 0.0 if self.driver.dialect.timed else 0.1
        dt = trajectory.times[k] - trajectory.times[k - 1]
        mean = np.abs(trajectory.positions[k] - trajectory.positions[k - 1]) / dt
        ratio = float(np.clip(np.max(QUINTIC_PEAK_VELOCITY * mean / self.driver.model.max_velocity), 0.0, 1.0))
        return ratio if ratio > 0.0 or self.driver.dialect.timed else 0.1

    def _point(self, trajectory: Trajectory, k: int, sequence: int, comm_type: int) -> JointTrajPt:
        duration = 0.0 if k == 0 else float(trajectory.times[k] - trajectory.times[k - 1])
        positions = trajectory.positions[k]
        skip = self.driver.dialect.skips_first_within
        state = self.driver.joint_state
        if k == 0 and skip is not None and state is not None:
            # ABB skips a first point within 0.1 degree of the robot and moves to any other in its
            # duration (0 here): the first point sent is where the robot is (the start gap, within
            # the goal tolerance, is made up by the next segment)
            here = state.positions[: positions.size]
            if np.max(np.abs(here - positions)) >= skip:
                positions = here
        return JointTrajPt(
            sequence,
            tuple(self.driver.to_controller(np.asarray(positions, dtype=float)).tolist()),
            self.ratio(trajectory, k),
            duration,
            comm_type=comm_type,
        )

    async def _reconnected(self, k: int, confirmed: int, cause: DriverError) -> None:
        """Point ``k`` was not sent because the motion link is down: with ``resume``, wait for
        the reconnection and carry on from ``k`` (saying so); otherwise abort."""
        if not self.driver.resume:
            raise ExecutionAborted(f"{cause} before point {k} was sent; not resuming (resume=False)", confirmed)
        try:
            await self.driver.motion.wait_for(ConnectionState.CONNECTED, self.driver.reply_timeout)
        except (TimeoutError, ConnectionClosed):
            raise ExecutionAborted(
                f"{cause}; no reconnection within {self.driver.reply_timeout} s, point {k} was never sent", confirmed
            ) from None
        log.warning("motion connection re-established: resuming at point %d (points 0..%d confirmed)", k, confirmed)


class StreamSender(TrajectorySender):
    """``stream``: one JOINT_TRAJ_PT request at a time, each reply SUCCESS (see the module doc)."""

    async def send(self, trajectory: Trajectory) -> int:
        confirmed = -1
        k = 0
        while k < len(trajectory):
            try:
                await self.driver._request(self._point(trajectory, k, k, CommType.SERVICE_REQUEST))
            except RequestFailed:
                if self.driver.dialect.fails_when_full and await self._room_made(k):
                    continue  # a full queue: the same point again, now that the robot has taken one
                raise ExecutionAborted(
                    f"the controller refused point {k}: {await self.driver._monitor.why_now()}", confirmed
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

    async def _room_made(self, k: int) -> bool:
        """A controller that answers FAILURE when its queue is full (Stäubli): True once the
        robot has moved on (STATUS in_motion TRUE on a fresh joint state) and the point may be sent
        again; False if it stands still for ``stall_timeout`` s (a refusal, not a full queue)."""
        driver = self.driver
        deadline = time.monotonic() + driver.stall_timeout
        while time.monotonic() < deadline:
            try:
                state = await driver.wait_state(min(driver.watchdog, max(deadline - time.monotonic(), 0.001)))
            except DriverError:
                return False
            if state.status is not None and state.status.in_motion == TriState.TRUE:
                log.debug("point %d: FAILURE while the robot moves (a full queue): sent again", k)
                return True
        return False


class DownloadSender(TrajectorySender):
    """``download``: the points as TOPICs, then a PING (see the module doc)."""

    async def send(self, trajectory: Trajectory) -> int:
        n = len(trajectory)
        indices = list(range(n)) if n > 1 else [0, 0]
        confirmed = -1
        for i, k in enumerate(indices):
            sequence = (
                SpecialSeq.START_TRAJECTORY_DOWNLOAD
                if i == 0
                else SpecialSeq.END_TRAJECTORY
                if i == len(indices) - 1
                else k
            )
            if not self.driver.dialect.ping:
                # a controller that answers no PING (ABB) answers each point of a download sent as
                # a request: one in flight, each confirmed
                point = self._point(trajectory, k if i else 0, sequence, CommType.SERVICE_REQUEST)
                try:
                    await self.driver._request(point)
                except RequestFailed:
                    raise ExecutionAborted(f"the controller refused point {k}", confirmed) from None
                except (_NotSent, _InFlight) as exc:
                    raise ExecutionAborted(
                        f"motion connection lost during the download (nothing runs before its last point): {exc}",
                        confirmed,
                    ) from None
                confirmed = k
                continue
            try:
                await self.driver.motion.send(self._point(trajectory, k if i else 0, sequence, CommType.TOPIC))
            except ConnectionClosed as exc:
                raise ExecutionAborted(f"motion connection lost during the download: {exc}", -1) from None
        if self.driver.dialect.ping:
            # a download has no acknowledgements; a PING after it proves the controller read it all
            await self.driver._request(Ping())
        return n - 1


class MotorosSender(TrajectorySender):
    """MotoROS's way: trajectory mode, then JOINT_TRAJ_PT_FULL on the millisecond grid (see the
    module doc)."""

    async def send(self, trajectory: Trajectory) -> int:
        await self._motion_ready()
        velocities = trajectory.velocities if trajectory.velocities is not None else central_velocities(trajectory)
        times, positions, velocities = _on_milliseconds(trajectory.times, trajectory.positions, velocities)
        if np.any(velocities[-1] != 0.0):
            # the goal is where the robot stops: a last point still moving (a recording cut off mid-motion)
            # would leave the controller without a next point to go on to, braking past it
            log.info("the last point's velocities are sent as 0: the robot comes to rest at the goal")
            velocities = velocities.copy()
            velocities[-1] = 0.0
        if self.driver.model is not None:
            _warn_cubics(times, positions, velocities, self.driver.model.max_acceleration)
        fields = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
        confirmed = -1
        for k in range(len(trajectory)):
            point = JointTrajPtFull(0, k, fields, float(times[k]), tuple(positions[k]), tuple(velocities[k]))
            delay, waited = 0.005, 0.0
            while True:
                try:
                    reply = await self.driver._request(point)
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
                    why = await self.driver._monitor.why_now() if reply.result == MotoResult.NOT_READY else ""
                    raise ExecutionAborted(
                        f"the controller refused point {k}: {moto_reason(reply.result, reply.subcode)}"
                        f"{f'; {why}' if why else ''}",
                        confirmed,
                    )
                if waited > self.driver.goal_timeout:
                    raise ExecutionAborted(f"point {k} still BUSY after {waited:.1f} s", confirmed)
                await asyncio.sleep(delay)  # back-off before resending: the controller said BUSY
                waited += delay
                delay = min(delay * 1.5, 0.05)
            confirmed = k
        return confirmed

    async def _motion_ready(self) -> None:
        ready = await self.driver._moto(MotoCommand.CHECK_MOTION_READY)
        if ready.result != MotoResult.TRUE:
            enable = await self.driver._moto(MotoCommand.START_TRAJ_MODE)
            if enable.result != MotoResult.SUCCESS:
                why = await self.driver._monitor.why_now()
                raise ExecutionAborted(
                    f"START_TRAJ_MODE refused: {moto_reason(enable.result, enable.subcode)}; {why}", -1
                )
            ready = await self.driver._moto(MotoCommand.CHECK_MOTION_READY)
            if ready.result != MotoResult.TRUE:
                raise ExecutionAborted(
                    f"the controller is not ready for motion: {moto_reason(ready.result, ready.subcode)}", -1
                )
            await self._alarm_cleared()

    async def _alarm_cleared(self, rounds: int = 3) -> None:
        """After START_TRAJ_MODE, which resets an alarm: wait (a few state rounds, at most the
        watchdog period) for a STATUS without the alarm, so that one published before the reset, and
        read after the reply on the other connection, is not taken for an alarm during the motion.
        An alarm still there after that is the motion's to report."""
        driver = self.driver
        with contextlib.suppress(DriverError, TimeoutError):
            async with asyncio.timeout(driver.watchdog):
                for _ in range(rounds):
                    state = await driver.wait_state()
                    if state.status is None or state.status.in_error != TriState.TRUE:
                        return

    async def _ready_after_reconnect(self, k: int, confirmed: int) -> None:
        """MotoROS after a reconnection: carry on only if trajectory mode survived (it still says
        ready); a controller that dropped the trajectory would need a new one from where it stopped."""
        ready = await self.driver._moto(MotoCommand.CHECK_MOTION_READY)
        if ready.result != MotoResult.TRUE:
            raise ExecutionAborted(
                f"after the reconnection the controller is not ready (subcode {ready.subcode}): it dropped the "
                f"trajectory, so point {k} is not sent",
                confirmed,
            )


def _in_flight(k: int, exc: DriverError) -> str:
    return (
        f"{exc} with point {k} awaiting its reply: the controller may or may not have it, so it is not "
        "resent (that could repeat it)"
    )


def _on_milliseconds(times: Array, positions: Array, velocities: Array) -> tuple[Array, Array, Array]:
    """The waypoints moved onto whole milliseconds, where they are not already: MotoROS keeps a
    point's time as whole milliseconds, truncated (``(int)(time * 1000)``, motoman_driver
    MotoPlus/MotionServer.c:2094), and joins the points by cubics through their positions and
    velocities. A point 0.4 ms off the grid (a recording's times are the controller's sample
    instants, to the microsecond) would then be reached 0.4 ms early with the position and velocity
    of its own time: at 2 rad/s over a 24 ms segment the cubic's acceleration is off by some
    10 rad/s^2, which MotoROS runs as given (beyond the limit, where the trajectory was at it). So each point is
    moved to its nearest millisecond (after the one before it), with the position and velocity the
    trajectory's own cubics give there (the velocity kept between those of the two points around it);
    the first keeps its state, and the last, reached at rest or not, keeps its state at the
    millisecond after its time."""
    ms = times * 1000.0
    grid = np.round(ms)
    if np.all(np.abs(ms - grid) <= 1e-6 * np.maximum(1.0, np.abs(ms))):
        return grid / 1000.0, positions, velocities
    n = times.size
    new = grid / 1000.0
    new[0] = times[0]
    new[-1] = math.ceil(ms[-1] - 1e-6) / 1000.0
    for k in range(1, n):
        new[k] = max(new[k], new[k - 1] + 1e-3)
    q, v = positions.copy(), velocities.copy()
    for k in range(1, n - 1):
        t = min(new[k], times[-1])
        i = min(int(np.searchsorted(times, t, side="right")) - 1, n - 2)
        v0, v1 = velocities[i], velocities[i + 1]
        at = cubic_hermite(positions[i], v0, positions[i + 1], v1, float(times[i + 1] - times[i])).sample(t - times[i])
        q[k] = at.position
        # within its neighbours' velocities: the cubic may bulge past them, and past a speed limit
        # that they are at (MotoROS refuses a velocity beyond it)
        v[k] = np.clip(at.velocity, np.minimum(v0, v1), np.maximum(v0, v1))
    return new, q, v


def _warn_cubics(times: Array, positions: Array, velocities: Array, limit: Array) -> None:
    """Say so, once, before sending, when the cubics MotoROS runs through the points' positions and
    velocities accelerate a joint beyond its limit: MotoROS runs them as they are (it checks the
    points' speeds only), so the drives are asked for more than the joint's acceleration limit and
    lag (or a real controller alarms). The client's own plans are kept within
    (:func:`.limits.within_cubics`); a recording is not retimed (its time is what a replay keeps):
    where the robot moved at its acceleration limit, the times estimated from the velocities of a
    controller that publishes no sample time (MotoROS) do not match them closely enough."""
    if times.size < 2:
        return
    ratio = cubic_accelerations(times, positions, velocities) / limit
    if not np.any(ratio > 1.0 + 1e-6):
        return
    k, j = (int(i) for i in np.unravel_index(int(np.argmax(ratio)), ratio.shape))
    log.warning(
        "the cubics through the points' positions and velocities accelerate joint %d up to %.3g x its limit "
        "(segment %d->%d): MotoROS runs them as given, beyond the limit (velocities that do not match the "
        "times: a recording of a controller that publishes no sample time has estimated times)",
        j + 1,
        float(ratio[k, j]),
        k,
        k + 1,
    )
