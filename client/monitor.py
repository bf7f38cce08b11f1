"""The robot's state as the driver knows it: what the state connection last said, and the wait for more.

:class:`StateMonitor` reads the state connection of a :class:`~.driver.RobotDriver`: one
:class:`JointState` per state round (from JOINT_FEEDBACK once the controller sends it, else from
JOINT_POSITION), the latest STATUS and each motion group's latest TOOL_POSE. It waits for the next
sample (never without a timeout), asks again for TOOL_POSE and JOINT_FEEDBACK on each new state
connection, and says in words why no state came or why the robot may not move (the latest STATUS).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from robot_server import Array
from simple_message.connection import Connection, ConnectionState, Subscription
from simple_message.constants import ValidFields
from simple_message.messages import JointFeedback, JointPosition, Status, ToolPose

from .errors import DriverError
from .reasons import status_faults, status_why

if TYPE_CHECKING:
    from .driver import RobotDriver

__all__ = ["JointState", "StateMonitor"]

log = logging.getLogger("client.driver")


@dataclass(frozen=True)
class JointState:
    """The robot's latest state: positions (and velocities if the controller sends them) of
    motion group 0, the latest STATUS, and when it arrived (``time.monotonic()``)."""

    positions: Array
    velocities: Array | None
    status: Status | None
    received: float
    #: the controller's time of the sample (s), where it says it (JOINT_FEEDBACK with a valid time)
    stamp: float | None = None


class StateMonitor:
    """The state connection of ``driver`` read into its latest joint state, STATUS and TOOL_POSEs
    (see the module doc)."""

    def __init__(self, driver: RobotDriver) -> None:
        self.driver = driver
        #: the latest joint-state sample (with the latest STATUS) and the latest STATUS
        self.latest: JointState | None = None
        self.status: Status | None = None
        self._changed = asyncio.Event()
        self._reader: asyncio.Task[None] | None = None
        #: every joint-state sample and TOOL_POSE sets it (waits for "this, or so many rounds")
        self._activity = asyncio.Event()
        self.samples = 0
        self.tool_poses: dict[int, ToolPose] = {}
        self._tool_wanted = False
        self._tool_asked_on: Connection | None = None
        self._feedback_wanted = False
        self._feedback_asked_on: Connection | None = None

    def start(self, subscription: Subscription) -> None:
        """Read ``subscription`` (the state connection's topics) from now on."""
        self._reader = asyncio.get_running_loop().create_task(self._read(subscription), name="driver state")

    async def stop(self) -> None:
        """Stop reading (if reading)."""
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reader

    async def _read(self, subscription: Subscription) -> None:
        """One joint-state sample per state round: from JOINT_FEEDBACK once the controller has sent
        one (it carries velocities too), else from JOINT_POSITION; the other joint topic of the
        same round is ignored. A STATUS updates the latest sample's status, and wakes waiters only
        when it changed (:meth:`states` yields each sample once: recordings used to hold copies
        0.2 ms apart, and rates read high)."""
        client = self.driver.state
        feedback = False
        async for msg in subscription:
            if self._tool_wanted and client.connection is not self._tool_asked_on:
                self._ask_tool_pose()  # a new state connection: the controller forgot who asked
            if self._feedback_wanted and client.connection is not self._feedback_asked_on:
                self.ask_feedback()
            if isinstance(msg, ToolPose):
                self.tool_poses[msg.robot_id] = msg
                self._wake_activity()
                continue
            if isinstance(msg, Status):
                changed = msg != self.status
                self.status = msg
                if self.latest is not None:
                    latest = self.latest
                    self.latest = dataclasses.replace(latest, status=msg)
                if not changed:
                    continue  # the same STATUS again: nothing new to wake anyone for
            if isinstance(msg, JointPosition):
                if feedback:
                    continue
                self.latest = JointState(self._positions(msg.joint_data), None, self.status, time.monotonic())
            elif isinstance(msg, JointFeedback) and msg.robot_id == 0:
                feedback = True
                velocities = self._positions(msg.velocities) if ValidFields.VELOCITY & msg.valid_fields else None
                stamp = float(msg.time) if ValidFields.TIME & msg.valid_fields else None
                self.latest = JointState(
                    self._positions(msg.positions), velocities, self.status, time.monotonic(), stamp
                )
            else:
                continue
            self._changed.set()
            self._changed = asyncio.Event()
            self.samples += 1
            self._wake_activity()

    def _wake_activity(self) -> None:
        self._activity.set()
        self._activity = asyncio.Event()

    def _positions(self, values: tuple[float, ...]) -> Array:
        model = self.driver.model
        dof = model.dof if model is not None else len(values)
        return self.driver.from_controller(np.array(values[:dof], dtype=float))

    async def subscribe_tool_pose(self, *, wait: bool = True, rounds: int | None = 3) -> ToolPose | None:
        """:meth:`.driver.RobotDriver.subscribe_tool_pose` (see there)."""
        self._tool_wanted = True
        if self.driver.state.connection is not self._tool_asked_on:
            self._ask_tool_pose()
        pose = self.tool_poses.get(0)
        if not wait or pose is not None:
            return pose
        start = self.samples
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(self.driver.watchdog):
                while self.tool_poses.get(0) is None and (rounds is None or self.samples - start < rounds):
                    await self._activity.wait()
        return self.tool_poses.get(0)

    def ask_feedback(self) -> None:
        """:meth:`.driver.RobotDriver.ask_feedback` (see there)."""
        self._feedback_wanted = True
        client = self.driver.state
        connection = client.connection
        if connection is None or connection.closed or client.state is not ConnectionState.CONNECTED:
            return
        if connection.send_nowait(JointFeedback()):
            self._feedback_asked_on = connection

    def _ask_tool_pose(self) -> None:
        """Send the TOOL_POSE request on the state connection as it is now (if it is up)."""
        client = self.driver.state
        connection = client.connection
        if connection is None or connection.closed or client.state is not ConnectionState.CONNECTED:
            return  # asked again once a state message arrives on the next connection
        if connection.send_nowait(ToolPose()):
            self._tool_asked_on = connection
            log.debug("TOOL_POSE requested on %s", client.name)

    async def wait_state(self, timeout: float | None = None) -> JointState:
        """The next joint state (within ``timeout``, default the watchdog period)."""
        waited = timeout if timeout is not None else self.driver.watchdog
        try:
            async with asyncio.timeout(waited):
                while True:
                    await self._changed.wait()
                    if self.latest is not None and self.status is not None:
                        return self.latest
        except TimeoutError:
            client = self.driver.state
            if client.state is not ConnectionState.CONNECTED:
                raise DriverError(self.no_state(waited)) from None
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

    def no_state(self, waited: float | None = None) -> str:
        """Why no joint state came within ``waited`` s (default: the watchdog period): the
        connection's end if it ended, else the wait."""
        client = self.driver.state
        seconds = self.driver.watchdog if waited is None else waited
        if client.state is not ConnectionState.CONNECTED:
            cause = client.last_error
            full = (
                ": a controller closes a state client it has no room for (MotoROS serves 4): close another client of "
                "its state port"
                if not cause and self.samples == 0
                else ""
            )
            return (
                f"the controller closed the state connection ({client.name}"
                f"{f': {cause}' if cause else ''}); no joint state for {seconds:g} s{full}"
            )
        return f"no joint state for {seconds:g} s" + (" (watchdog)" if waited is None else "")

    async def why_now(self) -> str:
        """:meth:`why` from a STATUS that came after the refusal (the controller may have replied
        before publishing the change that made it refuse, e.g. an e-stop), waiting at most a
        watchdog period for it."""
        with contextlib.suppress(DriverError, TimeoutError):
            seen = self.latest.received if self.latest is not None else None
            async with asyncio.timeout(self.driver.watchdog):
                while self.latest is None or self.latest.received == seen:
                    await self.wait_state()
        return self.why()

    def faulted(self) -> bool:
        """The latest STATUS shows a reason the robot cannot move (see :meth:`why`)."""
        return bool(status_faults(self.status))

    def why(self) -> str:
        """Why the controller may refuse motion, as its latest STATUS says (:func:`.reasons.status_why`)."""
        return status_why(self.status)
