"""The control loop: asyncio drives sans-I/O controllers (:mod:`.controller`) on a :mod:`.clock`.

A :class:`ControlLoop` wakes once per interpolation period at absolute deadlines
(``origin + k x period``, k an integer) and runs that period's servo ticks; a late wake-up runs
them at once and the next deadline is unchanged, so lateness never accumulates (no drift), however
long the run. On a real-time clock every wake-up's lateness is measured (:class:`LoopStats`).
This module is where the controllers meet the event loop and time; they know neither.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from .clock import Clock, SimulatedClock
from .controller import Controller
from .recorder import Recorder

__all__ = ["ControlLoop", "LoopStats", "run_simulated"]


@dataclass
class LoopStats:
    """What a :class:`ControlLoop` run did. Lateness is how long after its deadline a wake-up
    happened (controller time); an overrun is a wake-up later than one interpolation period."""

    ticks: int = 0
    wakes: int = 0
    overruns: int = 0
    max_lateness: float = 0.0
    final_lateness: float = 0.0
    simulated: float = 0.0
    wall: float = 0.0

    @property
    def realtime_factor(self) -> float:
        return self.simulated / self.wall if self.wall > 0 else float("inf")


@dataclass
class ControlLoop:
    """Runs a controller on a clock: one wake-up per interpolation period at absolute deadlines,
    each running that period's servo ticks (and any missed ones, so a late wake-up catches up)."""

    controller: Controller
    clock: Clock
    #: records controller ticks while set (it may be set and cleared while the loop runs)
    recorder: Recorder | None = None
    stats: LoopStats = field(default_factory=LoopStats)
    #: further controllers stepped in lockstep (other motion groups; same periods)
    others: Sequence[Controller] = ()
    #: records the ticks of ``others`` (by position; None or missing: not recorded)
    other_recorders: list[Recorder | None] = field(default_factory=list)
    #: called after every wake-up's ticks (e.g. to hand points over or to wake waiting replies)
    on_wake: Callable[[], None] | None = None
    _running: bool = field(default=False, init=False)

    def stop(self) -> None:
        self._running = False

    async def run(self, duration: float | None = None) -> LoopStats:
        """Run for ``duration`` seconds of controller time (None: until :meth:`stop`)."""
        ctl, clock = self.controller, self.clock
        period = ctl.config.interpolation_period
        sub = ctl.servo_ticks_per_interpolation
        origin = clock.now()
        periods = None if duration is None else round(duration / period)
        stats = self.stats
        controllers = [ctl, *self.others]
        for other in self.others:
            if other.config.interpolation_period != period or other.servo_ticks_per_interpolation != sub:
                raise ValueError("every controller of one loop must have the same interpolation and servo periods")
        on_wake = self.on_wake
        self._running = True
        wall0 = time.perf_counter()
        k = 0
        try:
            while self._running and (periods is None or k < periods):
                deadline = origin + k * period
                await clock.sleep_until(deadline)  # returns at once when late: the loop catches up
                if clock.realtime:
                    lateness = clock.now() - deadline
                    stats.final_lateness = lateness
                    stats.max_lateness = max(stats.max_lateness, lateness)
                    if lateness > period:
                        stats.overruns += 1
                recorder = self.recorder  # may be attached or detached between wake-ups
                others = [
                    (c, self.other_recorders[i] if i < len(self.other_recorders) else None)
                    for i, c in enumerate(controllers[1:])
                ]
                for _ in range(sub):
                    tick = ctl.step()
                    if recorder is not None:
                        recorder.add(tick)
                    for other, other_recorder in others:
                        other_tick = other.step()
                        if other_recorder is not None:
                            other_recorder.add(other_tick)
                if on_wake is not None:
                    on_wake()
                stats.ticks += sub
                stats.wakes += 1
                k += 1
        finally:
            self._running = False
            stats.simulated += k * period
            stats.wall += time.perf_counter() - wall0
        return stats


async def run_simulated(controller: Controller, seconds: float, recorder: Recorder | None = None) -> LoopStats:
    """Convenience: run ``controller`` for ``seconds`` on a :class:`.SimulatedClock`."""
    return await ControlLoop(controller, SimulatedClock(controller.time), recorder).run(seconds)
