"""What the emulators of one process share: the controllers' clock, their servo wake-ups, the state topics' ticker.

A fleet (:mod:`robot_server.fleet`) runs many controllers in one process and one event loop. Each
as its own process would wake its control loop every interpolation period and keep a thread for
its state topics' deadlines; together they would wake the process hundreds of times per period.
:class:`Shared` gives them one :class:`~..control.SharedLoop` per interpolation period (one wake-up
runs every controller's period), one :class:`~.ticker.Ticker` thread for every state topic, and
spreads the state topics' deadlines over their period (:meth:`Shared.state_phase`), so that the
controllers' rounds do not all fall due at the same instant and wait for one another.
"""

from __future__ import annotations

import asyncio
import contextlib

from ..control import Clock, ControlLoop, SharedLoop
from .ticker import Ticker

__all__ = ["Shared"]

#: the golden ratio's fractional part: successive multiples spread evenly over [0, 1) for any count
_SPREAD = 0.6180339887498949


class Shared:
    """The clock, wake-ups and ticker of a process's emulators (see the module doc). Make it and
    :meth:`start` it in the running loop, before the emulators start; :meth:`close` it after they
    have closed."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        #: one shared control loop per (interpolation period, servo ticks in it)
        self.loops: dict[tuple[float, int], SharedLoop] = {}
        self._tasks: list[asyncio.Task[object]] = []
        self.ticker: Ticker | None = None
        self._phases = 0

    def start(self) -> None:
        if self.clock.realtime and self.ticker is None:
            self.ticker = Ticker()

    def join(self, loop: ControlLoop) -> None:
        """Run ``loop``'s periods at the shared wake-ups of its interpolation period from the next one on."""
        ctl = loop.controller
        key = (ctl.config.interpolation_period, ctl.servo_ticks_per_interpolation)
        shared = self.loops.get(key)
        if shared is None:
            shared = self.loops[key] = SharedLoop(self.clock, *key)
            self._tasks.append(asyncio.get_running_loop().create_task(shared.run(), name=f"shared control loop {key}"))
        shared.add(loop)

    def leave(self, loop: ControlLoop) -> None:
        for shared in self.loops.values():
            shared.remove(loop)

    def state_phase(self) -> float:
        """Where in its period the next emulator's state rounds fall due: a share of the period,
        0..1, spread evenly however many emulators ask."""
        phase = (self._phases * _SPREAD) % 1.0
        self._phases += 1
        return phase

    async def close(self) -> None:
        for shared in self.loops.values():
            shared.stop()
        for task in self._tasks:
            task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        if self.ticker is not None:
            self.ticker.close()
            self.ticker = None
