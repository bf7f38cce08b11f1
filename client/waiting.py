"""What the driver waits for once everything is sent: the robot at its goal, at rest.

:meth:`~.driver.RobotDriver._wait_done` watches the joint states until the controller has done what
was sent (a trajectory, straight lines): each state is looked at (:class:`Look`: at the goal, moved
from the start, how far off), against what the wait is for (:class:`Wait`), and a robot standing
still short of its goal for too long (:class:`Stall`) ends the wait. After a STOP,
:meth:`~.driver.RobotDriver.settle_after_stop` waits for a state whose joints are all slower than
:data:`REST_VELOCITY` (:func:`joints_still`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = ["Look", "REST_VELOCITY", "Stall", "Wait", "joints_still"]

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
    """What :meth:`~.driver.RobotDriver._wait_done` waits for: ``what`` the items confirmed (``point``,
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
