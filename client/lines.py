"""Straight lines run by the controller, from the PC side (CARTESIAN_LINE and TOOL_POSE, this
project's extension, docs/protocol.md).

:class:`CartesianLines` does for :class:`~.driver.RobotDriver` what its ``supports_lines`` and
``move_lines`` say: it asks the controller once per connection whether it runs lines (a
CARTESIAN_LINE STOP: only its own reply type means yes), sends :class:`LineGoal` targets as lines
0, 1, ... and waits, as ``execute`` does, until the robot has run them and the actual TCP is at the
last one. A refused line raises :class:`LineRefused`, which names the controller's
:class:`~simple_message.constants.LineResult` (:func:`line_reason`).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from robot_server import Array
from robot_server.kinematics import fk, quaternion_angle, rotation_to_quaternion
from simple_message.connection import Connection, ConnectionState
from simple_message.constants import CommType, LineResult, SpecialSeq
from simple_message.errors import (
    ConnectionClosed,
    NotConnected,
    RequestFailed,
    RequestTimeout,
    UnexpectedReply,
)
from simple_message.messages import CartesianLine, CartesianLineReply, Message, ToolPose

from .errors import DriverError, ExecutionAborted, _InFlight, _NotSent
from .stopping import stop_after_abort
from .waiting import Look, Wait

if TYPE_CHECKING:
    from .driver import RobotDriver
    from .monitor import JointState

__all__ = ["LINE_REFUSALS", "CartesianLines", "LineGoal", "LineRefused", "line_reason"]

log = logging.getLogger("client.driver")


#: what each refusal of a straight line means (docs/protocol.md, CARTESIAN_LINE's reply)
LINE_REFUSALS = {
    LineResult.NOT_READY: "the robot cannot move",
    LineResult.BUSY: "a joint trajectory is under way",
    LineResult.INVALID: "a field is out of bounds",
    LineResult.SEQUENCE: "a sequence number the controller does not accept",
    LineResult.UNREACHABLE: "the target, or a point of the line, is out of reach",
    LineResult.SINGULAR: "it passes a singularity",
    LineResult.JOINT_LIMIT: "it would take a joint past its limits, or the joints cannot follow it",
    LineResult.WORKSPACE: "it leaves the allowed workspace",
    LineResult.TCP_SPEED: "the speed is more than the controller allows",
}


def line_reason(result: int) -> str:
    """A CARTESIAN_LINE reply's result, named and explained: ``SINGULAR (it passes a singularity)``."""
    try:
        name = LineResult(result)
    except ValueError:
        return f"result {result} (not a known LineResult)"
    meaning = LINE_REFUSALS.get(name)
    return f"{name.name} ({meaning})" if meaning else name.name


class LineRefused(ExecutionAborted):
    """The controller refused straight line ``line`` with ``result`` (a :class:`LineResult`):
    nothing of it ran, nothing after it was sent, and the lines before it were stopped."""

    def __init__(self, line: int, result: int, confirmed: int, why: str = "") -> None:
        super().__init__(
            f"the controller refused line {line}: {line_reason(result)}{f'; {why}' if why else ''}",
            confirmed,
            what="line",
        )
        self.line = line
        self.result = result


class LineGoal(NamedTuple):
    """Where a straight line ends: the TCP position (m, in the controller's cell frame) and
    orientation, a unit quaternion ``(w, x, y, z)`` (w first, as ``robot_server.kinematics``; the
    wire's CARTESIAN_LINE has x y z w)."""

    position: ArrayLike
    orientation: ArrayLike

    @classmethod
    def from_pose(cls, pose: ArrayLike) -> LineGoal:
        """The goal of a 4x4 homogeneous pose (a planner's, :func:`robot_server.kinematics.fk`'s)."""
        t = np.asarray(pose, dtype=float)
        return cls(t[:3, 3].copy(), rotation_to_quaternion(t))


class _LineInFlight(ExecutionAborted):
    """A line got no reply (lost connection, timeout): the controller may have it, so stop."""


class CartesianLines:
    """Straight lines for ``driver`` (see the module doc), and whether its controller runs them."""

    def __init__(self, driver: RobotDriver) -> None:
        self.driver = driver
        #: :meth:`supports`' answer and the motion connection it holds for (None: for the driver's life)
        self._found: tuple[Connection | None, bool] | None = None

    async def supports(self) -> bool:
        """:meth:`.driver.RobotDriver.supports_lines` (see there)."""
        d = self.driver
        cached = self._found
        if cached is not None and (cached[0] is None or cached[0] is d.motion.connection):
            return cached[1]
        if not d.dialect.unknown_types:  # a probe would stop ABB's server, misframe Fanuc's, hang on Staubli's
            self._found = (None, False)
            return False
        await d._motion_up()
        connection = d.motion.connection
        timeout = min(d.reply_timeout, 1.0)
        reply: object
        try:
            reply = await d.motion.request(CartesianLine(0, SpecialSeq.STOP_TRAJECTORY), timeout)
        except RequestFailed as exc:
            reply = exc.reply  # a refused STOP is still a CARTESIAN_LINE reply; a header-only one is not
        except UnexpectedReply as exc:
            reply = exc.reply  # another type, or a body no layout fits: the link stays aligned
        except RequestTimeout:
            if connection is not None:
                log.warning("no reply to the CARTESIAN_LINE probe within %s s: resetting the motion link", timeout)
                await connection.close()
            log.info("%s: no reply to CARTESIAN_LINE: no straight-line motion", d.motion.name)
            self._found = (None, False)
            return False
        except NotConnected as exc:
            raise DriverError(f"motion connection down: {exc}") from None
        except ConnectionClosed as exc:
            raise DriverError(f"motion connection lost while asking for straight lines: {exc}") from None
        supported = isinstance(reply, CartesianLineReply) and reply.comm_type == CommType.SERVICE_REPLY
        log.info(
            "%s: %s",
            d.motion.name,
            "runs CARTESIAN_LINE"
            if supported
            else f"no CARTESIAN_LINE (answered {getattr(reply, 'name', None) or type(reply).__name__})",
        )
        self._found = (connection, supported)
        return supported

    async def move(
        self, targets: Sequence[LineGoal], *, speed: float, blend_radius: float = 0.0, group: int = 0
    ) -> ToolPose:
        """:meth:`.driver.RobotDriver.move_lines` (see there)."""
        d = self.driver
        goals = _line_goals(targets)
        if not (math.isfinite(speed) and speed > 0.0):
            raise DriverError(f"the TCP speed must be a number > 0, not {speed}")
        if not (math.isfinite(blend_radius) and blend_radius >= 0.0):
            raise DriverError(f"the blend radius must be a number >= 0, not {blend_radius}")
        if group < 0:
            raise DriverError(f"no motion group {group}")
        await d.wait_state()
        await d._motion_up()
        if not await self.supports():
            raise DriverError(
                f"the controller at {d.address} has no straight-line motion (it does not answer CARTESIAN_LINE)"
            )
        await d.subscribe_tool_pose()
        start = self.tcp(group, d.joint_state)
        if start is None:
            raise DriverError(
                "cannot tell where the TCP is: the controller sends no TOOL_POSE and the driver has no robot model"
            )
        confirmed, pending = -1, False
        try:
            for k, (position, orientation) in enumerate(goals):
                (px, py, pz), (w, x, y, z) = position.tolist(), orientation.tolist()
                line = CartesianLine(group, k, px, py, pz, x, y, z, w, speed, blend_radius)
                pending = True
                try:
                    reply = await self._send(k, line, confirmed)
                except ExecutionAborted as exc:
                    pending = isinstance(exc, _LineInFlight)  # else answered (refused) or never sent
                    raise
                pending = False
                if not isinstance(reply, CartesianLineReply) or reply.result != LineResult.ACCEPTED:
                    raise ExecutionAborted(f"line {k} answered with {reply.name}", confirmed, what="line")
                confirmed = k
            return await self._wait(group, start, goals, speed, confirmed)
        except (asyncio.CancelledError, ExecutionAborted):
            if confirmed >= 0 or pending:
                await self._stop_quietly(group)
            raise

    async def _send(self, k: int, line: CartesianLine, confirmed: int) -> Message:
        """Send line ``k`` and return its reply; a refusal or a failure to send raises."""
        d = self.driver
        try:
            return await d._request(line)
        except RequestFailed as exc:
            reply = exc.reply
            if isinstance(reply, CartesianLineReply):
                why = await d._monitor.why_now() if reply.result == LineResult.NOT_READY else ""
                raise LineRefused(k, reply.result, confirmed, why) from None
            name = getattr(reply, "name", type(reply).__name__)
            raise ExecutionAborted(f"line {k} answered FAILURE ({name})", confirmed, what="line") from None
        except UnexpectedReply as exc:
            raise ExecutionAborted(f"line {k}: {exc}", confirmed, what="line") from None
        except _NotSent as exc:
            raise ExecutionAborted(f"{exc}; line {k} was never sent", confirmed, what="line") from None
        except _InFlight as exc:
            raise _LineInFlight(
                f"{exc} with line {k} awaiting its reply: the controller may or may not have it", confirmed, what="line"
            ) from None
        except DriverError as exc:  # no reply in time (the link is reset): the controller may have it
            raise _LineInFlight(f"line {k}: {exc}", confirmed, what="line") from None

    async def _stop_quietly(self, group: int) -> None:
        """A CARTESIAN_LINE STOP after an abort (the plain STOP if that fails); bounded; one not sent is
        a warning, not raised (:func:`.stopping.stop_after_abort`)."""
        d = self.driver

        async def stop() -> None:
            if d.motion.state is not ConnectionState.CONNECTED:
                await d.motion.wait_for(ConnectionState.CONNECTED, d.reply_timeout)
            try:
                reply = await d._request(CartesianLine(group, SpecialSeq.STOP_TRAJECTORY))
            except (RequestFailed, UnexpectedReply):
                reply = None
            if not isinstance(reply, CartesianLineReply):
                await d.stop()
            else:
                log.info("line stop sent")

        await stop_after_abort(stop(), "line STOP")

    def tcp(self, group: int, state: JointState | None) -> tuple[Array, Array] | None:
        """The actual TCP position and orientation ``(w, x, y, z)``: the latest TOOL_POSE, else
        the forward kinematics of ``state`` (group 0 with a model), else None."""
        d = self.driver
        pose = d.tool_pose_of(group)
        if pose is not None:
            return np.array([pose.x, pose.y, pose.z]), np.array([pose.qw, pose.qx, pose.qy, pose.qz])
        if d.model is None or group != 0 or state is None:
            return None
        t = fk(d.model, state.positions[: d.model.dof])
        return t[:3, 3].copy(), rotation_to_quaternion(t)

    async def _wait(
        self, group: int, start: tuple[Array, Array], goals: list[tuple[Array, Array]], speed: float, confirmed: int
    ) -> ToolPose:
        """Wait until the robot has run the lines (see :meth:`move`), as
        :meth:`.waiting.GoalSupervisor.goal` does for a trajectory; the TCP is compared with the last target."""
        d = self.driver
        goal_position, goal_orientation = goals[-1]

        def off(pose: tuple[Array, Array], position: Array, orientation: Array) -> tuple[float, float]:
            return float(np.linalg.norm(pose[0] - position)), quaternion_angle(pose[1], orientation)

        def look(state: JointState) -> Look | None:
            tcp = self.tcp(group, state)
            if tcp is None:  # TOOL_POSE came and went? (a group without it): nothing to compare yet
                return None
            distance, angle = off(tcp, goal_position, goal_orientation)
            away, turned = off(tcp, *start)
            return Look(
                distance <= d.tcp_tolerance and angle <= d.orientation_tolerance,
                away > d.tcp_tolerance or turned > d.orientation_tolerance,
                f"{distance * 1000:.3g} mm and {angle:.3g} rad from the last line's end",
            )

        # a rough duration: the lengths at the TCP speed (the turns, accelerations and any slowing
        # down are the controller's; goal_timeout covers them)
        corners = np.array([start[0], *(p for p, _ in goals)])
        length = float(np.sum(np.linalg.norm(np.diff(corners, axis=0), axis=1)))
        offsets = [off(start, p, q) for p, q in goals]
        moves = any(far > d.tcp_tolerance or turn > d.orientation_tolerance for far, turn in offsets)
        wait = Wait("line", "the last line's end", "the lines", length / speed, moves, stops=True)
        state = await d._supervisor.done(wait, look, confirmed)
        tcp = self.tcp(group, state)
        assert tcp is not None  # done means it was compared
        return self._final_pose(group, tcp, state)

    def _final_pose(self, group: int, tcp: tuple[Array, Array], state: JointState) -> ToolPose:
        d = self.driver
        pose = d.tool_pose_of(group)
        if pose is not None:
            return pose
        (x, y, z), (qw, qx, qy, qz) = tcp[0].tolist(), tcp[1].tolist()
        return ToolPose(group, 0, state.received, x, y, z, qx, qy, qz, qw, 0.0)


def _line_goals(targets: Sequence[LineGoal]) -> list[tuple[Array, Array]]:
    """The targets as (position, unit quaternion w x y z) arrays; a quaternion within 1e-3 of
    unit length is normalised, anything else refused (DriverError) before anything is sent."""
    goals = []
    for k, target in enumerate(targets):
        try:
            position, orientation = target
            p = np.asarray(position, dtype=float).reshape(3)
            q = np.asarray(orientation, dtype=float).reshape(4)
        except (TypeError, ValueError):
            raise DriverError(
                f"line {k}: a target is a position (x, y, z) and a quaternion (w, x, y, z), not {target!r}"
            ) from None
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
            raise DriverError(f"line {k}: the target is not finite")
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-3:
            raise DriverError(f"line {k}: the orientation is not a unit quaternion (norm {norm:.6g})")
        goals.append((p, q / norm))
    if not goals:
        raise DriverError("no line to move along (give at least one target)")
    return goals
