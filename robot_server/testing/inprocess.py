"""An emulated controller in the test's own process: an :class:`~robot_server.emulator.Emulator`
made from the settings as ``robot-server`` makes it, on the event loop it is started on.

Its clock is real time (sped up by ``speedup``) or, with ``speedup="step"``, a
:class:`~robot_server.control.SteppedClock` that moves only when the test advances it: between
advances the robot stands where it is, so what a test sees at a controller time does not depend
on the machine. Every wait is bounded in wall time as well, so a control loop that died fails the
test instead of hanging it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from pathlib import Path

from simple_message.messages import Status

from ..cli import write_records
from ..control import Recorder, SteppedClock
from ..emulator import Emulator
from ..model import RobotModel
from .core import ControllerTimeout, describe_file, describe_joints, describe_status, loopback
from .records import snapshot
from .settings import Settings

__all__ = ["InProcess", "STEP_TIMEOUT"]

log = logging.getLogger(__name__)

#: wall-clock bound of one step of a stepped clock (the loop answers within milliseconds)
STEP_TIMEOUT = 10.0
#: wall time a real-time controller may fall behind its clock before a wait gives up (s)
GRACE = 10.0
#: controller time a stepped controller gets to come to rest when it is closed (s)
SETTLE_LIMIT = 30.0


def _never() -> bool:
    """The condition of a plain advance: it runs to its end, period by period."""
    return False


class InProcess:
    """One :class:`Emulator` on the current event loop (see the module doc)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        spec = settings.spec
        self.clock: SteppedClock | None = SteppedClock() if settings.stepped else None
        self.emulator = Emulator(spec.config, clock=self.clock)
        self.recorders: list[Recorder] = self.emulator.record(spec.record_seconds)
        self.host = loopback(spec.config.host)
        self.ports: dict[str, int] = {}
        self.models: list[RobotModel] = [g.model for g in self.emulator.cell.groups]
        capture = spec.config.capture
        self.capture_path: Path | None = None if capture is None else Path(capture)
        self.closed = False
        self._stepping = asyncio.Lock()
        self._faults: list[asyncio.Task[None]] = []
        self._period = self.emulator.cell.config.interpolation_period

    # -- lifecycle ---------------------------------------------------------------------------------

    async def start(self) -> None:
        await self.emulator.start()
        self.ports = dict(self.emulator.ports)
        if self.clock is not None:
            await self._step(0.0)  # the loop has run its first period and waits
        loop = asyncio.get_running_loop()
        for at, command in self.settings.spec.faults:
            self._faults.append(loop.create_task(self._scheduled(at, command), name=f"{self.settings.name} fault"))

    async def _scheduled(self, at: float, command: str) -> None:
        cell = self.emulator.cell
        await cell.until(lambda: cell.time >= at - 1e-9)
        try:
            log.info("%s: applied: %s", self.settings.name, self.emulator.command(command))
        except ValueError as exc:
            log.warning("%s: %s", self.settings.name, exc)

    async def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for task in self._faults:
            task.cancel()
        await asyncio.gather(*self._faults, return_exceptions=True)
        emulator = self.emulator
        try:
            if self.clock is not None and emulator.cell.in_motion:
                # nobody advances a stepped clock for close's deceleration: bring the robot to rest first
                emulator.cell.stop()
                with contextlib.suppress(TimeoutError, ControllerTimeout):
                    await self.advance_until(lambda: not emulator.cell.in_motion, SETTLE_LIMIT, None, "rest")
        finally:
            await emulator.close(settle_timeout=1.0 if self.clock is not None else GRACE)
            emulator.stop_recording()
        record = self.settings.spec.record
        if record is not None:
            write_records(str(record), self.recorders, emulator)

    # -- reading -----------------------------------------------------------------------------------

    def joints(self, group: int = 0) -> tuple[float, ...]:
        return tuple(self.emulator.cell.groups[group].command.actual_position)

    def status(self) -> Status:
        reported = getattr(self.emulator.behaviour, "status", None)  # the profile's, as its state port says
        status: Status = reported() if callable(reported) else self.emulator.cell.status()
        return status

    def time(self) -> float:
        return self.emulator.cell.time

    def in_motion(self) -> bool:
        return self.emulator.cell.in_motion

    def records(self) -> list[Recorder]:
        return [snapshot(r) for r in self.recorders]

    # -- acting ------------------------------------------------------------------------------------

    async def fault(self, command: str) -> str:
        applied = self.emulator.command(command)
        log.info("%s: applied: %s", self.settings.name, applied)
        return applied

    async def wait_idle(self, timeout: float) -> float:
        cell = self.emulator.cell
        return await self.advance_until(lambda: not cell.in_motion, timeout, None, "the robot at rest")

    async def _step(self, seconds: float, until: Callable[[], bool] | None = None) -> None:
        """Advance the stepped clock (until ``until`` holds, :meth:`SteppedClock.advance`); a
        control loop that stops moving controller time for :data:`STEP_TIMEOUT` s of wall time
        fails it (a long advance may take longer than that: it is progress that is bounded)."""
        clock = self.clock
        assert clock is not None
        async with self._stepping:  # one wait at a time moves the clock: two at once wait in turn
            await self._advance(clock, seconds, until)

    async def _advance(self, clock: SteppedClock, seconds: float, until: Callable[[], bool] | None) -> None:
        advancing = asyncio.ensure_future(clock.advance(seconds, until))
        try:
            while True:
                before = clock.now()
                done, _ = await asyncio.wait({advancing}, timeout=STEP_TIMEOUT)
                if done:
                    advancing.result()
                    return
                if clock.now() == before:
                    raise ControllerTimeout(
                        f"{self.settings.name}: the control loop ran no controller time in {STEP_TIMEOUT:g} s of wall "
                        f"time (it has stopped?); it stands at {before:.3f} s"
                    )
        finally:
            if not advancing.done():
                advancing.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await advancing
            elif not advancing.cancelled():
                advancing.exception()  # read (raised above, or lost to a cancellation in the same turn)

    async def advance(self, seconds: float) -> float:
        if not seconds >= 0.0:
            raise ValueError(f"time only moves forward, not by {seconds}")
        if self.clock is not None:
            await self._step(seconds, _never)  # period by period: the sockets served between periods
        else:
            cell = self.emulator.cell
            end = cell.time + seconds
            await self._within(seconds, cell.until(lambda: cell.time >= end - 1e-9), f"{seconds:g} s passing")
        return self.time()

    async def advance_until(self, predicate: Callable[[], bool], limit: float, dt: float | None, what: str) -> float:
        cell = self.emulator.cell
        end = cell.time + limit
        if self.clock is not None:
            if dt is None:  # period by period: the clock checks the predicate itself (one call, not one per period)
                if not predicate():
                    await self._step(max(0.0, end - cell.time), predicate)
                if not predicate():
                    raise self._timeout(what, limit)
                return cell.time
            if not dt > 0.0:
                raise ValueError(f"the step must be > 0 s, not {dt}")
            while not predicate():
                if cell.time >= end - 1e-9:
                    raise self._timeout(what, limit)
                await self._step(min(dt, end - cell.time))
            return cell.time
        await self._within(limit, cell.until(lambda: predicate() or cell.time >= end), what)
        if not predicate():
            raise self._timeout(what, limit)
        return cell.time

    async def _within(self, seconds: float, waiting: Awaitable[None], what: str) -> None:
        """Await ``waiting`` for at most ``seconds`` of a real-time clock, in wall time."""
        speedup = self.settings.speedup
        assert isinstance(speedup, float)
        bound = seconds / speedup + GRACE
        try:
            async with asyncio.timeout(bound):
                await waiting
        except TimeoutError:
            raise ControllerTimeout(
                f"{self.settings.name}: {what}: not within {bound:g} s of wall time (the controller has stopped?)"
            ) from None

    def _timeout(self, what: str, limit: float) -> ControllerTimeout:
        return ControllerTimeout(
            f"{self.settings.name}: {what}: not within {limit:g} s of controller time (now {self.time():.3f} s); "
            f"{describe_joints(self.joints())}; {describe_status(self.status())}"
        )

    # -- the report --------------------------------------------------------------------------------

    def describe(self) -> str:
        spec = self.settings.spec
        config = spec.config
        clock = "stepped clock" if self.clock is not None else f"{self.settings.speedup:g}x real time"
        ports = ", ".join(f"{role} {self.host}:{port}" for role, port in self.ports.items())
        models = " + ".join(m.name for m in self.models)
        record = self.recorders[0]
        lines = [
            f"{self.settings.name}: {config.profile} profile, {models}, in this process, {clock}; {ports}"
            + (" (closed)" if self.closed else ""),
            f"controller time: {self.time():.3f} s",
            describe_joints(self.joints()) + " (group 0, rad or m)",
            describe_status(self.status()),
            f"record: {len(record)} servo ticks" + (f", {record.dropped} older ones dropped" if record.dropped else ""),
        ]
        traffic = describe_file(self.capture_path, "traffic (pcapng; Wireshark, or: simple-message decode FILE)")
        if traffic is not None:
            lines.append(traffic)
        return "\n".join(lines)
