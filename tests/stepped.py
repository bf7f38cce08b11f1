"""The emulator on a clock the test advances (:class:`robot_server.control.SteppedClock`).

Controller time moves only in :func:`step`: between steps the robot stands still wherever it is,
so what a test sees at a controller time (a reply, a STATUS, a position) does not depend on how
fast or loaded the machine is. State topics still go out on the wall clock (they publish the
frozen state). Every advance is bounded in wall time: a control loop that died fails the test,
it never hangs it.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from typing import Any

from robot_server.control import SteppedClock
from robot_server.emulator import Emulator, EmulatorConfig

#: wall-clock bound of one step (the loop answers within milliseconds)
STEP_TIMEOUT = 10.0
#: one interpolation period of the default configuration (s of controller time)
TICK = 0.004


async def step(clock: SteppedClock, seconds: float) -> None:
    """Advance the controller by ``seconds``, bounded."""
    async with asyncio.timeout(STEP_TIMEOUT):
        await clock.advance(seconds)


async def advance_until(
    clock: SteppedClock, predicate: Callable[[], bool], *, limit: float = 20.0, dt: float = TICK, what: str = "it"
) -> None:
    """Advance in steps of ``dt`` until ``predicate()`` holds; fails after ``limit`` s of controller time."""
    end = clock.now() + limit
    while not predicate():
        assert clock.now() < end, f"{what} did not happen within {limit} s of controller time"
        await step(clock, dt)


async def settle(emu: Emulator, clock: SteppedClock, limit: float = 20.0) -> None:
    """Advance until the robot has settled (at most ``limit`` s of controller time)."""
    await advance_until(clock, lambda: not emu.cell.in_motion, limit=limit, what="the robot settling")


async def poll(predicate: Callable[[], bool], timeout: float = 10.0) -> None:
    """Wait for something outside the controller's time (a serial port opening) by checking
    ``predicate`` every 10 ms, at most ``timeout`` s."""
    async with asyncio.timeout(timeout):
        while not predicate():  # noqa: ASYNC110 - nothing to wait on: a bounded poll
            await asyncio.sleep(0.01)


@contextlib.asynccontextmanager
async def stepped_emulator(
    *, record: float | None = None, **options: Any
) -> AsyncIterator[tuple[Emulator, SteppedClock]]:
    """An emulator on free loopback ports whose controller time moves only when the test advances
    it; with ``record``, recording ``record`` s of every tick from the first one
    (``emu.control.recorder``). On the way out the robot is brought to rest first (``close`` would
    otherwise wait, on the wall clock, for a deceleration nobody advances)."""
    options.setdefault("motion_port", 0)
    options.setdefault("state_port", 0)
    if options.get("profile") == "motoros":
        options.setdefault("io_port", 0)
    clock = SteppedClock()
    emu = Emulator(EmulatorConfig(**options), clock=clock)
    await emu.start()
    try:
        if record is not None:
            emu.record(record)
        await step(clock, 0.0)  # the loop has run its first period and waits
        yield emu, clock
        await settle(emu, clock)
    finally:
        await emu.close(settle_timeout=1.0)  # after a failure: no more than a second of wall time
