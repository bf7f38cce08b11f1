"""A fleet: many emulated controllers in one process and one event loop.

:class:`Fleet` makes one :class:`~..emulator.Emulator` per controller of a :class:`~.config.FleetSpec`,
all sharing the process's clock, control wake-ups and state ticker (:class:`~..emulator.shared.Shared`),
each on its own ports and with its own profile, models and settings, as if it were its own
``robot-server``. Each controller's code runs with its name in :data:`~.logs.CONTROLLER`, so that its
log lines name it::

    spec = load_fleet("cell.toml")
    async with Fleet(spec) as fleet:
        fleet["r2"].cell.estop()        # one controller; the others go on
        fleet.command("r1 alarm 42")    # as typed on stdin

:meth:`Fleet.close` brings every robot to rest (all together, each as its own close does), closes
every connection and the shared pieces.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import functools
import logging
from collections import Counter
from collections.abc import Callable, Iterator
from typing import TypeVar

from ..control import Clock, RealTimeClock, Recorder
from ..control.loop import overrun_times
from ..emulator import Emulator, FaultError
from ..emulator.server import lateness_quantile
from ..emulator.shared import Shared
from ..loader import load_model
from ..model import ModelError, RobotModel
from .config import ALL, FleetError, FleetSpec
from .logs import CONTROLLER, FleetCeiling

__all__ = ["Fleet", "FleetCommandError"]

log = logging.getLogger(__name__)
T = TypeVar("T")


class FleetCommandError(FaultError):
    """A fault command line that names no controller of the fleet (or no command)."""


class Fleet:
    """The controllers of a fleet file in one process (see the module doc)."""

    def __init__(self, spec: FleetSpec, *, clock: Clock | None = None) -> None:
        self.spec = spec
        speedups = {c.config.speedup for c in spec.controllers}
        if len(speedups) > 1:
            raise FleetError(f"{spec.path}: the controllers of one fleet share one clock: one speed-up, not {speedups}")
        #: each controller's log budget under the fleet's, while the fleet runs (:mod:`.logs`)
        self.ceiling = FleetCeiling([c.name for c in spec.controllers])
        self.shared = Shared(clock if clock is not None else RealTimeClock(speedups.pop() if speedups else 1.0))
        self.emulators: dict[str, Emulator] = {}
        #: each controller's context: its name for the log (:data:`.logs.CONTROLLER`)
        self._contexts: dict[str, contextvars.Context] = {}
        #: the record of each controller that keeps one (``record`` in the file)
        self.recorders: dict[str, list[Recorder]] = {}
        models: dict[str, RobotModel] = {}  # a model file read once, however many controllers use it
        for controller in spec.controllers:
            try:
                group_models = []
                for name in controller.config.models:
                    key = str(name)
                    if key not in models:
                        models[key] = load_model(name)
                    group_models.append(models[key])
                emulator = Emulator(controller.config, group_models, shared=self.shared)
            except (ValueError, ModelError, OSError) as exc:
                raise FleetError(f"{spec.path}: controller {controller.name}: {exc}") from None
            self.emulators[controller.name] = emulator
            context = contextvars.copy_context()
            context.run(CONTROLLER.set, controller.name)
            self._contexts[controller.name] = context
            if controller.record is not None:
                self.recorders[controller.name] = emulator.record(controller.record_seconds)
        self._tasks: list[asyncio.Task[None]] = []
        self._started = False
        self._closed = False

    def __getitem__(self, name: str) -> Emulator:
        return self.emulators[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.emulators)

    def __len__(self) -> int:
        return len(self.emulators)

    def run_as(self, name: str, function: Callable[[], T]) -> T:
        """Call ``function`` as controller ``name``'s code (its log lines name it)."""
        return self._contexts[name].run(function)

    async def start(self) -> Fleet:
        """Bind every controller's ports and start them, in the file's order. If one cannot start
        (a port taken meanwhile), the ones started are closed and :class:`FleetError` names it."""
        if self._started:
            return self
        self._started = True
        self.ceiling.install(*{type(e.behaviour).__module__ for e in self.emulators.values()})
        self.shared.start()
        loop = asyncio.get_running_loop()
        for controller in self.spec.controllers:
            name = controller.name
            emulator = self.emulators[name]
            try:
                await loop.create_task(emulator.start(), name=f"start {name}", context=self._contexts[name].copy())
            except OSError as exc:
                await self.close()
                raise FleetError(f"{self.spec.path}: controller {name}: cannot start: {exc}") from None
            for at, command in controller.faults:
                self._tasks.append(
                    loop.create_task(self._scheduled(name, at, command), context=self._contexts[name].copy())
                )
        return self

    async def _scheduled(self, name: str, at: float, command: str) -> None:
        cell = self.emulators[name].cell  # at that controller's time, which began when it started
        await cell.until(lambda: cell.time >= at - 1e-9)
        with contextlib.suppress(FaultError):  # logged as that controller's
            self._apply(name, command)

    def _apply(self, name: str, command: str) -> str:
        try:
            applied = self.emulators[name].command(command)
        except FaultError as exc:
            log.warning("%s", exc)
            raise
        log.info("applied: %s", applied)
        return applied

    def command(self, line: str) -> list[str]:
        """A fault command for one controller, ``NAME COMMAND`` (``r2 estop``), or for every one,
        ``all COMMAND``; returns what was done. Raises :class:`~..emulator.FaultError` for an
        unknown controller or command (the controllers it was applied to keep it)."""
        name, _, command = line.strip().partition(" ")
        if not command.strip():
            raise FleetCommandError(f"expected NAME COMMAND (e.g. {next(iter(self.emulators))} estop) or {ALL} COMMAND")
        if name == ALL:
            return [f"{n}: " + self.run_as(n, functools.partial(self._apply, n, command)) for n in self.emulators]
        if name not in self.emulators:
            names = list(self.emulators)
            shown = ", ".join(names[:10]) + (f" ... ({len(names)})" if len(names) > 10 else "")
            raise FleetCommandError(f"no controller {name!r} in the fleet (controllers: {shown}; {ALL}: every one)")
        return [f"{name}: " + self.run_as(name, functools.partial(self._apply, name, command))]

    async def close(self, settle_timeout: float = 10.0) -> None:
        """Bring every robot to rest (together), close every connection, then the shared pieces."""
        if self._closed:
            return
        self._closed = True
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        loop = asyncio.get_running_loop()
        closing = [
            loop.create_task(emulator.close(settle_timeout), context=self._contexts[name].copy())
            for name, emulator in self.emulators.items()
        ]
        results = await asyncio.gather(*closing, return_exceptions=True)
        for name, result in zip(self.emulators, results, strict=True):
            if isinstance(result, BaseException):
                log.error("controller %s did not close cleanly: %s", name, result)
        if self._started:
            self._report()
            self.ceiling.remove()
        await self.shared.close()

    def _report(self) -> None:
        for (period, _), shared in self.shared.loops.items():
            loop = shared.stats
            if self.shared.clock.realtime and loop.wakes:
                log.info(
                    "control loop (%g ms, %d controllers): %d wake-ups, %d overruns (a wake-up more than one "
                    "interpolation period late), latest %.3f ms",
                    period * 1e3,
                    shared.joined,
                    loop.wakes,
                    loop.overruns,
                    loop.max_lateness * 1e3,
                )
                if loop.late_wakes:
                    log.info(
                        "control loop (%g ms) overruns, the last %d (time.monotonic() of the late wake-up, "
                        "lateness): %s",
                        period * 1e3,
                        len(loop.late_wakes),
                        overrun_times(loop),
                    )
        stats = [e.state_stats for e in self.emulators.values()]
        together = [sum(column) for column in zip(*(s.histogram for s in stats), strict=True)]
        worst = max(stats, key=lambda s: s.quantile(0.99))
        log.info(
            "state topics: %d rounds, %d skipped, lateness p99 %.3f ms (the worst controller's p99 %.3f ms), "
            "latest %.3f ms",
            sum(s.sent for s in stats),
            sum(s.skipped for s in stats),
            lateness_quantile(together, 0.99) * 1e3,
            worst.quantile(0.99) * 1e3,
            max(s.max_lateness for s in stats) * 1e3,
        )

    async def __aenter__(self) -> Fleet:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def ready_lines(self) -> list[str]:
        """One line per controller (its ``robot-server`` ready line after its name), then the fleet's."""
        lines = [f"{name}: {emulator.describe()}" for name, emulator in self.emulators.items()]
        profiles = Counter(e.config.profile for e in self.emulators.values())
        counted = ", ".join(f"{profile} {count}" for profile, count in profiles.items())
        clock = self.shared.clock
        timing = "simulated time" if not clock.realtime else "real time"
        if isinstance(clock, RealTimeClock) and clock.speedup != 1.0:
            timing = f"{clock.speedup:g}x real time"
        noun = "controller" if len(self) == 1 else "controllers"
        lines.append(f"robot-server fleet ready: {len(self)} {noun} ({counted}), {timing}")
        return lines
