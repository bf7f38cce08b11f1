"""What the driver waits for once everything is sent: the robot at its goal, at rest.

:class:`GoalSupervisor` watches the joint states of a :class:`~.driver.RobotDriver` until the
controller has done what was sent (a trajectory, straight lines): each state is looked at
(:class:`Look`: at the goal, moved from the start, how far off), against what the wait is for
(:class:`Wait`); an alarm, a lost state connection, a robot standing still short of its goal for
too long (:class:`Stall`) or no goal in time ends the wait with
:class:`~.errors.ExecutionAborted`. After a STOP, :meth:`GoalSupervisor.settled` waits for a state
whose joints are all slower than :data:`REST_VELOCITY` (:func:`joints_still`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from simple_message.constants import TriState

from .errors import DriverError, ExecutionAborted
from .limits import path_deviation

if TYPE_CHECKING:
    from .driver import RobotDriver
    from .monitor import JointState
    from .trajectory import Trajectory

__all__ = ["GoalSupervisor", "Look", "REST_VELOCITY", "Stall", "Wait", "joints_still"]

log = logging.getLogger("client.driver")

#: a joint slower than this (rad/s or m/s) is at rest
REST_VELOCITY = 5e-3


def joints_still(velocities: NDArray[np.float64] | None, moved: NDArray[np.float64] | None, elapsed: float) -> bool:
    """Every joint slower than :data:`REST_VELOCITY`: by the ``velocities`` the controller sends, or
    (it sends none) by how far each ``moved`` since the sample ``elapsed`` s before (False without one)."""
    if velocities is not None:
        return float(np.max(np.abs(velocities))) < REST_VELOCITY
    if moved is None or elapsed <= 0.0:
        return False
    return float(np.max(np.abs(moved))) < REST_VELOCITY * elapsed


class Look(NamedTuple):
    """Where one joint state finds the robot: at the goal, moved from the start, and how far off (words)."""

    at_goal: bool
    moved: bool
    short: str


@dataclass(frozen=True)
class Wait:
    """What :meth:`GoalSupervisor.done` waits for: ``what`` the items confirmed (``point``,
    ``line``), ``goal`` and ``motion`` in words, the planned ``duration``, whether it ``moves`` the
    robot at all, and whether an e-stop or drives off ends it at once (``stops``; else a trajectory
    that never moved is given up on once the controller shows a fault)."""

    what: str
    goal: str
    motion: str
    duration: float
    moves: bool
    stops: bool


class Stall:
    """How long the robot has stood still short of its goal (STATUS in_motion FALSE)."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.since: float | None = None

    def standing(self, still: bool) -> bool:
        """Note one sample (``still``: standing short of the goal); True once that has lasted
        more than the limit."""
        if not still:
            self.since = None
            return False
        now = time.monotonic()
        if self.since is None:
            self.since = now
        return now - self.since > self.limit


class GoalSupervisor:
    """Watches the joint states of ``driver`` until what was sent is done, or, after a stop, until
    the robot is at rest (see the module doc)."""

    def __init__(self, driver: RobotDriver) -> None:
        self.driver = driver

    async def done(self, wait: Wait, look: Callable[[JointState], Look | None], confirmed: int) -> JointState:
        """Wait until the robot has done what was sent (``look`` says of each joint state where it
        is: at the goal, moved from the start): see :meth:`goal`. Returns the last state."""
        d = self.driver
        monitor = d._monitor
        what = wait.what
        sent = time.monotonic()
        deadline = sent + wait.duration + d.goal_timeout
        stall = Stall(d.stall_timeout)
        seen_moving = False
        late = f"the robot did not reach {wait.goal} in time"
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise ExecutionAborted(late, confirmed, what=what)
            try:
                state = await d.wait_state(min(d.watchdog, remaining))
            except DriverError:
                if remaining < d.watchdog:
                    raise ExecutionAborted(late, confirmed, what=what) from None
                raise ExecutionAborted(monitor.no_state(), confirmed, what=what) from None
            seen = look(state)
            status = state.status
            if status is not None and status.in_error == TriState.TRUE:
                raise ExecutionAborted(f"the controller is in error (code {status.error_code})", confirmed, what=what)
            if (
                wait.stops
                and status is not None
                and (status.e_stopped == TriState.TRUE or status.drives_powered == TriState.FALSE)
            ):
                raise ExecutionAborted(f"the robot stopped: {monitor.why()}", confirmed, what=what)
            if seen is None:
                continue
            if (status is not None and status.in_motion == TriState.TRUE) or seen.moved:
                seen_moving = True
            waited = time.monotonic() - sent
            if not wait.stops and wait.moves and not seen_moving and waited > d.stall_timeout and monitor.faulted():
                # a trajectory the controller dropped before it began (a download has no replies)
                raise ExecutionAborted(f"the robot did not move: {monitor.why()}", confirmed, what=what)
            ran = seen_moving or not wait.moves or waited > wait.duration + d.stall_timeout
            if seen.at_goal and ran and status is not None and status.in_motion != TriState.TRUE:
                if status.in_motion == TriState.UNKNOWN:
                    log.warning("%s reached, but the controller reports in_motion UNKNOWN", wait.goal)
                return state
            # standing still short of the goal: the controller dropped the motion (a refused
            # download point has no reply to say so) or someone stopped the robot
            if stall.standing(not seen.at_goal and status is not None and status.in_motion == TriState.FALSE):
                raise ExecutionAborted(
                    f"the robot stands still {seen.short} (in_motion FALSE for {d.stall_timeout} s): the "
                    f"controller dropped or stopped {wait.motion}{f': {monitor.why()}' if monitor.faulted() else ''}",
                    confirmed,
                    what=what,
                )

    async def goal(self, trajectory: Trajectory, confirmed: int) -> JointState:
        """Wait until the robot has run ``trajectory`` and is at rest within the driver's
        ``goal_tolerance`` of its last point (and within ``path_tolerance`` of its path all along)."""
        # "at the goal and not moving" means done only once the robot has run the trajectory: a path
        # that ends where it starts is "at the goal" before it begins, and the STATUS that comes with
        # a joint state may be older than the last point. So the robot must have been seen moving
        # (in_motion TRUE, or away from the start), unless the trajectory does not move it, or the
        # planned duration (and stall_timeout) has passed since everything was sent.
        d = self.driver
        goal = trajectory.positions[-1]
        start = trajectory.positions[0]
        moves = bool(np.max(np.abs(trajectory.positions - start)) > d.goal_tolerance)

        def look(state: JointState) -> Look:
            here = state.positions[: goal.size]
            if d.path_tolerance is not None:
                deviation = path_deviation(trajectory, here)
                if deviation > d.path_tolerance:
                    raise ExecutionAborted(
                        f"the robot is {deviation:.4g} from the path (tolerance {d.path_tolerance})", confirmed
                    )
            error = float(np.max(np.abs(here - goal)))
            moved = bool(np.max(np.abs(here - start)) > d.goal_tolerance)
            return Look(error <= d.goal_tolerance, moved, f"{error:.4g} from the goal")

        # a controller that moves at its own speed (Fanuc, Staubli) takes as long as it takes: no
        # deadline from the trajectory's times, the robot standing still short of the goal ends it
        duration = trajectory.duration if d.dialect.timed else math.inf
        wait = Wait("point", "the goal", "the trajectory", duration, moves, stops=False)
        return await self.done(wait, look, confirmed)

    async def settled(self, bound: float) -> JointState | None:
        """:meth:`.driver.RobotDriver.settle_after_stop` (see there): the state at rest, or None."""
        d = self.driver
        rest_after: float | None = None  # when the state current as STATUS said at rest arrived
        previous: JointState | None = None
        latest: JointState | None = None
        with contextlib.suppress(DriverError, TimeoutError):
            async with asyncio.timeout(bound):
                while True:
                    state = await d.wait_state()
                    status = d._monitor.status
                    if status is None or status.in_motion == TriState.TRUE:
                        rest_after, latest = None, None
                    elif rest_after is None:
                        rest_after = state.received
                    elif state.received > rest_after:
                        latest = state
                        if _still(state, previous):
                            break
                    if previous is None or state.received != previous.received:
                        previous = state
        return latest


def _still(state: JointState, previous: JointState | None) -> bool:
    """Every joint of ``state`` still (:func:`joints_still`), by its velocities or by the change
    since ``previous`` over the controller's sample times (else the receipt times)."""
    if state.velocities is not None or previous is None:
        return joints_still(state.velocities, None, 0.0)
    if state.stamp is not None and previous.stamp is not None and state.stamp > previous.stamp:
        elapsed = state.stamp - previous.stamp
    else:
        elapsed = state.received - previous.received
    return joints_still(None, state.positions - previous.positions, elapsed)
