"""SteppedClock.advance(seconds, until): a wait for a condition in one call, period by period,
as the same wait made of one advance per interpolation period (robot_server.control.clock).

The control loop here is a ControlLoop of one controller; what the test compares is controller
time and the ticks, never the wall clock."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

import numpy as np
import pytest

from robot_server.control import ControlLoop, Recorder, SteppedClock
from robot_server.control.controller import Controller
from robot_server.loader import load_model

PERIOD = 0.004
TARGET = np.full(6, 0.3)
#: wall-clock bound of every wait here (the loop runs a few seconds of controller time in far less)
BOUND = 20.0


class Stepped:
    """A controller on a stepped clock, its loop on this event loop, every tick recorded."""

    def __init__(self) -> None:
        self.clock = SteppedClock()
        self.controller = Controller(load_model("jibot_zxs"))
        self.recorder = Recorder(6, capacity=100_000)
        self.loop = ControlLoop(self.controller, self.clock, self.recorder)
        self.task = asyncio.get_running_loop().create_task(self.loop.run())

    async def advance(self, seconds: float, until: object = None) -> None:
        async with asyncio.timeout(BOUND):
            await self.clock.advance(seconds, until)  # type: ignore[arg-type]

    async def close(self) -> None:
        self.loop.stop()
        self.task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await self.task


@pytest.fixture
async def pair() -> AsyncIterator[tuple[Stepped, Stepped]]:
    made = [Stepped(), Stepped()]
    for s in made:
        await s.advance(0.0)  # each loop waits for its first deadline
    yield made[0], made[1]
    for s in made:
        await s.close()


async def test_until_stops_where_one_advance_per_period_stops(pair: tuple[Stepped, Stepped]) -> None:
    at_once, by_period = pair
    for s in pair:
        s.controller.add_move(TARGET, speed=0.5)
    await at_once.advance(30.0, lambda: not at_once.controller.in_motion)
    steps = 0
    while by_period.controller.in_motion:
        await by_period.advance(PERIOD)
        steps += 1
    assert steps > 50, "the move took many periods"
    assert at_once.controller.time == by_period.controller.time
    assert at_once.clock.now() == pytest.approx(by_period.clock.now(), abs=1e-9)
    for quantity in ("command_position", "actual_position", "following_error"):
        assert np.array_equal(at_once.recorder.get(quantity), by_period.recorder.get(quantity))
    assert np.array_equal(at_once.recorder.tool(), by_period.recorder.tool(), equal_nan=True)
    # the clock stays where the condition held: a later advance runs from there
    before = at_once.controller.time
    await at_once.advance(2 * PERIOD)
    assert at_once.controller.time == pytest.approx(before + 2 * PERIOD)


async def test_until_that_holds_at_once_runs_no_period_and_one_that_never_holds_runs_the_whole_limit() -> None:
    s = Stepped()
    try:
        await s.advance(0.0)
        before = s.controller.time
        await s.advance(10.0, lambda: True)
        assert s.controller.time == before
        await s.advance(0.1, lambda: False)
        assert s.controller.time == pytest.approx(before + 0.1)
    finally:
        await s.close()


async def test_other_tasks_run_between_the_periods_of_one_advance() -> None:
    s = Stepped()
    seen: list[float] = []

    async def watch() -> None:
        while True:
            seen.append(s.controller.time)
            await asyncio.sleep(0)

    watcher = asyncio.get_running_loop().create_task(watch())
    try:
        await s.advance(0.0)
        seen.clear()
        await s.advance(0.2, lambda: False)
        assert len(set(seen)) >= 45, "a task saw most of the 50 periods go by, one by one"
    finally:
        watcher.cancel()
        with pytest.raises(asyncio.CancelledError):
            await watcher
        await s.close()


async def test_what_until_raises_is_raised_by_advance_and_the_loop_runs_on() -> None:
    s = Stepped()
    try:
        await s.advance(0.0)
        calls = 0

        def broken() -> bool:
            nonlocal calls
            calls += 1
            if calls == 3:
                raise RuntimeError("a predicate's own defect")
            return False

        with pytest.raises(RuntimeError, match="a predicate's own defect"):
            await s.advance(5.0, broken)
        stopped = s.controller.time
        assert stopped == pytest.approx(2 * PERIOD + 0.004), "two periods ran, the third was not"
        assert not s.task.done(), "the control loop did not end"
        await s.advance(PERIOD)
        assert s.controller.time == pytest.approx(stopped + PERIOD)
    finally:
        await s.close()


async def test_a_cancelled_advance_leaves_the_clock_where_the_loop_stands() -> None:
    s = Stepped()
    try:
        await s.advance(0.0)
        periods = 0
        twenty = asyncio.Event()

        def count() -> bool:
            nonlocal periods
            periods += 1
            if periods == 20:
                twenty.set()
            return False

        advancing = asyncio.get_running_loop().create_task(s.clock.advance(1000.0, count))
        async with asyncio.timeout(BOUND):
            await twenty.wait()
        advancing.cancel()
        with pytest.raises(asyncio.CancelledError):
            await advancing
        stood = s.controller.time
        for _ in range(10):
            await asyncio.sleep(0)  # the loop would go on here if the clock still let it
        assert s.controller.time == stood
        assert s.clock.now() <= stood + 1e-9
        await s.advance(PERIOD)
        assert s.controller.time == pytest.approx(stood + PERIOD)
    finally:
        await s.close()
