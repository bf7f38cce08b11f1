"""One clock abstraction for the control loop: real time (optionally sped up) or simulated.

The loop asks a clock for ``now()`` and waits with ``sleep_until(deadline)``; deadlines are
absolute (``start + k x period`` with an integer k), so waiting late once never shifts the ticks
after it: there is no drift, however long the run.

* :class:`RealTimeClock`: controller time follows the monotonic wall clock, ``speedup`` times as
  fast (``speedup=1``: real time).
* :class:`SimulatedClock`: time jumps to each deadline at once, so the loop runs as fast as the
  computer can; it still yields to the event loop at every wait, so servers keep working. Its
  runs are deterministic: the same inputs at the same controller times give the same results.
* :class:`SteppedClock`: time moves only when the program (a test) calls :meth:`SteppedClock.advance`;
  the loop then runs up to the new time and ``advance`` returns. Between advances the controller
  waits, so points sent meanwhile, over TCP or otherwise, arrive at a known controller time: a
  streaming test gives the same trace, bit for bit, every time, with no wall-clock tolerance.
"""

from __future__ import annotations

import asyncio
import time
from abc import ABC, abstractmethod
from collections.abc import Callable

__all__ = ["Clock", "RealTimeClock", "SimulatedClock", "SteppedClock"]


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


class SteppedClock(Clock):
    realtime = False

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)
        self._limit = float(start)
        self._wake = asyncio.Event()
        self._idle = asyncio.Event()
        #: while an :meth:`advance` with ``until`` runs: the condition, and what it raised
        self._until: Callable[[], bool] | None = None
        self._raised: BaseException | None = None

    def now(self) -> float:
        return self._now

    async def sleep_until(self, deadline: float) -> None:
        while True:
            if self._until is not None:
                await asyncio.sleep(0)  # servers and clients run between two periods, as between two advances
            until = self._until
            if deadline <= self._limit + 1e-9 and (until is None or not self._holds(until)):
                break
            self._wake.clear()
            self._idle.set()
            await self._wake.wait()
        self._now = max(self._now, deadline)

    def _holds(self, until: Callable[[], bool]) -> bool:
        """``until()``; what it raises (a test's ``pytest.fail`` too) ends the advance and is
        raised there, not in the loop. Where it ends, the clock stays: no period after it runs."""
        try:
            held = bool(until())
        except BaseException as exc:  # (handed to the advance, which raises it)
            self._raised = exc
            held = True
        if held:
            self._limit = self._now
        return held

    async def advance(self, seconds: float, until: Callable[[], bool] | None = None) -> None:
        """Let the loop run ``seconds`` further; returns once it waits for a later deadline. Bound
        it with a timeout: it waits for as long as no loop runs on this clock.

        With ``until``, the advance ends early, at the first deadline the loop waits for where
        ``until()`` holds (checked before every period, on the loop's task; what it raises is
        raised here), and the loop yields to the event loop before every period, so I/O goes on
        between them as between two advances: a wait for a condition in one call instead of a
        call per period. Ended early or cancelled, the clock stays where the loop stands."""
        if not seconds >= 0.0:
            raise ValueError(f"time only moves forward, not by {seconds}")
        self._limit += seconds
        self._until = until
        self._raised = None
        self._idle.clear()
        self._wake.set()
        try:
            await self._idle.wait()
        except asyncio.CancelledError:
            if until is not None:  # cut short: the clock stays where the loop stands
                self._limit = min(self._limit, self._now)
            raise
        finally:
            if until is not None:
                self._until = None
        raised, self._raised = self._raised, None
        if raised is not None:
            raise raised

    async def advance_to(self, time: float) -> None:
        """:meth:`advance` up to controller time ``time``."""
        await self.advance(max(0.0, time - self._limit))
