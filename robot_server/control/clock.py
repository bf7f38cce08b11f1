"""One clock abstraction for the control loop: real time (optionally sped up) or simulated.

The loop asks a clock for ``now()`` and waits with ``sleep_until(deadline)``; deadlines are
absolute (``start + k x period`` with an integer k), so waiting late once never shifts the ticks
after it: there is no drift, however long the run.

* :class:`RealTimeClock`: controller time follows the monotonic wall clock, ``speedup`` times as
  fast (``speedup=1``: real time).
* :class:`SimulatedClock`: time jumps to each deadline at once, so the loop runs as fast as the
  computer can; it still yields to the event loop at every wait, so servers keep working. Its
  runs are deterministic: the same inputs at the same controller times give the same results.
"""

from __future__ import annotations

import asyncio
import time
from abc import ABC, abstractmethod

__all__ = ["Clock", "RealTimeClock", "SimulatedClock"]


class Clock(ABC):
    #: whether the clock follows the wall clock (lateness and overruns mean something)
    realtime: bool

    @abstractmethod
    def now(self) -> float:
        """Controller time, seconds."""

    @abstractmethod
    async def sleep_until(self, deadline: float) -> None:
        """Wait until controller time ``deadline`` (at once if it has passed)."""


class RealTimeClock(Clock):
    realtime = True

    def __init__(self, speedup: float = 1.0) -> None:
        if not speedup > 0.0:
            raise ValueError(f"the speed-up factor must be > 0, not {speedup}")
        self.speedup = float(speedup)
        self._origin = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._origin) * self.speedup

    async def sleep_until(self, deadline: float) -> None:
        delay = (deadline - self.now()) / self.speedup
        await asyncio.sleep(delay if delay > 0.0 else 0.0)  # late: still let other tasks run


class SimulatedClock(Clock):
    realtime = False

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        return self._now

    async def sleep_until(self, deadline: float) -> None:
        self._now = max(self._now, deadline)
        await asyncio.sleep(0)  # let servers and clients run between ticks
