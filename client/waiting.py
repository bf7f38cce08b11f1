"""What the driver waits for once everything is sent: the robot at its goal, at rest.

:meth:`~.driver.RobotDriver._wait_done` watches the joint states until the controller has done what
was sent (a trajectory, straight lines): each state is looked at (:class:`Look`: at the goal, moved
from the start, how far off), against what the wait is for (:class:`Wait`), and a robot standing
still short of its goal for too long (:class:`Stall`) ends the wait.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

__all__ = ["Look", "Stall", "Wait"]


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
