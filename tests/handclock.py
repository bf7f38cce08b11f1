"""A clock the test sets that a control loop takes for a real-time one (a fleet's): periods become
"due" between two wake-ups, as on the wall clock, but only when the test says so."""

from __future__ import annotations

import asyncio

from robot_server.control import Clock

__all__ = ["HandClock"]


class HandClock(Clock):
    """A real-time clock as far as the loop can tell, whose time the test sets."""

    realtime = True

    def __init__(self) -> None:
        self._now = 0.0
        self._moved = asyncio.Event()

    def now(self) -> float:
        return self._now

    def set(self, now: float) -> None:
        self._now = now
        self._moved.set()

    def move_quietly(self, now: float) -> None:
        """Time passes while the event loop is busy: the sleeping loop is not woken."""
        self._now = now

    async def sleep_until(self, deadline: float) -> None:
        while self._now < deadline:
            self._moved.clear()
            await self._moved.wait()
