"""SharedLoop.catch_up: the control periods due run before a request is handled, not behind a
burst of them (robot_server.control.loop; the hook is simple_message's Server.before_handler).

The clock here is moved by the test but says it is a real-time one, as the fleet's is: that is
what makes periods "due" between two wake-ups."""

from __future__ import annotations

import asyncio
import logging
import sys

import pytest

from robot_server.control import ControlLoop, LoopStats, SharedLoop, SteppedClock
from robot_server.control.controller import Controller
from robot_server.fleet import Fleet, parse_fleet
from robot_server.loader import load_model
from simple_message import Ping
from simple_message.endpoints import Client, Server
from tests.handclock import HandClock
from tests.rawpeer import RawPeer, joint_traj_pt, vectors

PERIOD = 0.004
JTP = vectors("<")["JOINT_TRAJ_PT_REQUEST_SEQ3"]


async def _started(shared: SharedLoop, loops: list[ControlLoop], woke: asyncio.Event) -> asyncio.Task[object]:
    for loop in loops:
        shared.add(loop)
    task = asyncio.get_running_loop().create_task(shared.run())
    async with asyncio.timeout(5.0):
        await woke.wait()  # the first period (deadline 0) runs at once
    return task


async def _stopped(shared: SharedLoop, task: asyncio.Task[object], clock: HandClock) -> None:
    shared.stop()
    clock.set(clock.now() + PERIOD)  # wake it to see the stop
    async with asyncio.timeout(5.0):
        await task


def _controllers(count: int) -> list[Controller]:
    model = load_model("jibot_zxs")
    return [Controller(model) for _ in range(count)]


async def test_catch_up_runs_the_periods_due_and_the_wake_up_then_runs_none_twice() -> None:
    clock = HandClock()
    controllers = _controllers(2)
    woke = asyncio.Event()
    loops = [ControlLoop(c, clock, on_wake=woke.set) for c in controllers]
    shared = SharedLoop(clock, PERIOD, controllers[0].servo_ticks_per_interpolation)
    task = await _started(shared, loops, woke)
    assert [c.time for c in controllers] == [pytest.approx(PERIOD)] * 2

    clock.move_quietly(3.5 * PERIOD)  # deadlines 1, 2 and 3 have passed; the loop has not woken
    shared.catch_up()  # one period per call: requests are not held back by a loop far behind
    assert shared.stats.wakes == 2
    shared.catch_up()
    shared.catch_up()
    assert shared.stats.wakes == 4
    assert [c.time for c in controllers] == [pytest.approx(4 * PERIOD)] * 2
    assert shared.stats.max_lateness == pytest.approx(2.5 * PERIOD), "period 1 ran 2.5 periods late"
    assert shared.stats.overruns == 2, "periods 1 and 2 were more than a period late, period 3 not"
    assert [late for _, late in shared.stats.late_wakes] == pytest.approx([2.5 * PERIOD, 1.5 * PERIOD])

    shared.catch_up()  # nothing more is due
    assert shared.stats.wakes == 4

    woke.clear()
    clock.set(4.0 * PERIOD)  # the loop wakes for period 4, the one due now, and runs it once
    async with asyncio.timeout(5.0):
        await woke.wait()
    for _ in range(3):
        await asyncio.sleep(0)
    assert shared.stats.wakes == 5
    assert [c.time for c in controllers] == [pytest.approx(5 * PERIOD)] * 2
    await _stopped(shared, task, clock)


async def test_catch_up_does_nothing_inside_a_period_nor_before_the_loop_runs() -> None:
    clock = HandClock()
    (controller,) = _controllers(1)
    shared = SharedLoop(clock, PERIOD, controller.servo_ticks_per_interpolation)
    shared.catch_up()  # not running yet
    assert shared.stats.wakes == 0
    calls: list[int] = []
    woke = asyncio.Event()

    def on_wake() -> None:  # a member's callback that would call back into the loop
        calls.append(shared.stats.wakes)
        shared.catch_up()
        woke.set()

    task = await _started(shared, [ControlLoop(controller, clock, on_wake=on_wake)], woke)
    clock.move_quietly(2.0 * PERIOD)
    shared.catch_up()
    shared.catch_up()
    assert calls == [0, 1, 2], "one call per period, none nested"
    assert controller.time == pytest.approx(3 * PERIOD)
    await _stopped(shared, task, clock)


async def test_catch_up_leaves_a_stepped_clock_to_its_steps() -> None:
    clock = SteppedClock()
    (controller,) = _controllers(1)
    shared = SharedLoop(clock, PERIOD, controller.servo_ticks_per_interpolation)
    shared.add(ControlLoop(controller, clock))
    task = asyncio.get_running_loop().create_task(shared.run())
    async with asyncio.timeout(5.0):
        await clock.advance(PERIOD)
    before = controller.time
    shared.catch_up()
    assert controller.time == before
    shared.stop()
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_the_server_calls_before_handler_before_each_request_and_drops_a_failing_one(
    caplog: pytest.LogCaptureFixture,
) -> None:
    server = Server()
    seen: list[str] = []

    def on_ping(msg: object, session: object) -> None:
        seen.append("handler")

    server.handle(Ping.MSG_TYPE, on_ping)
    server.before_handler = lambda: seen.append("before")
    port = await server.serve_tcp()
    try:
        async with Client.tcp("127.0.0.1", port) as client:
            await client.request(Ping(), 5.0)
            assert seen == ["before", "handler"]

            def broken() -> None:
                raise RuntimeError("defect")

            server.before_handler = broken
            with caplog.at_level(logging.ERROR, logger="simple_message"):
                await client.request(Ping(), 5.0)
                await client.request(Ping(), 5.0)
            failures = [r for r in caplog.records if "before_handler hook failed" in r.getMessage()]
            assert len(failures) == 1, "logged once, then no longer called"
            assert server.before_handler is None
            assert seen == ["before", "handler", "handler", "handler"], "the requests were still handled"
    finally:
        await server.close()


async def _request_while_a_period_is_due(clock: HandClock, port: int) -> None:
    """A JOINT_TRAJ_PT handled at a moment when a control period is due and the loop has not woken
    (the event loop was busy); it is accepted."""
    clock.move_quietly(clock.now() + 1.5 * PERIOD)
    motion = await RawPeer.connect(port)
    try:
        reply = await motion.request(joint_traj_pt(JTP, 0, [0.0] * 6))
    finally:
        await motion.close()
    assert reply.reply_code == 1


async def test_in_a_fleet_a_request_runs_every_controllers_period_due_before_it_is_handled() -> None:
    """A burst of requests (many clients' points) is handled one after another on the event loop;
    the fleet's control period due meanwhile runs before each one, for every controller."""
    clock = HandClock()
    data = {"controller": [{"name": n, "motion_port": 0, "state_port": 0} for n in ("r1", "r2")]}
    fleet = Fleet(parse_fleet(data), clock=clock)
    await fleet.start()
    try:
        r1, r2 = fleet["r1"], fleet["r2"]
        start = r2.cell.time
        await _request_while_a_period_is_due(clock, r1.ports["motion"])
        assert r2.cell.time >= start + PERIOD - 1e-9, "r2's period due ran before r1's request"
    finally:
        clock.set(clock.now() + PERIOD)
        await fleet.close(settle_timeout=1.0)


class HandTicker:
    """The state rounds' ticker on a time the test sets."""

    def __init__(self) -> None:
        self.t = 0.0
        self._moved = asyncio.Event()

    def now(self) -> float:
        return self.t

    def set(self, t: float) -> None:
        self.t = t
        self._moved.set()

    async def sleep_until(self, deadline: float) -> None:
        while self.t < deadline - 1e-12:
            self._moved.clear()
            await self._moved.wait()


async def test_state_rounds_run_every_slot_due_at_a_late_wake_up_and_each_round_once_after_a_stall() -> None:
    from robot_server.emulator.shared import StateRounds

    ticker = HandTicker()
    rounds = StateRounds(0.006, ticker, now=ticker.now)  # type: ignore[arg-type]
    assert rounds.slots == 3
    published: list[tuple[str, float]] = []
    skipped: dict[str, int] = {}
    arrived = asyncio.Event()

    def member(name: str) -> None:
        def publish(deadline: float) -> None:
            published.append((name, round(deadline, 6)))
            arrived.set()

        def skip(count: int) -> None:
            skipped[name] = skipped.get(name, 0) + count

        rounds.add(publish, skip)

    for name in ("a", "b", "c"):  # slots 0, 1, 2
        member(name)
    task = asyncio.get_running_loop().create_task(rounds.run())
    await asyncio.sleep(0)  # its first step: origin 0, asleep until the first slot

    async def at(t: float, count: int) -> None:
        arrived.clear()
        ticker.set(t)
        async with asyncio.timeout(5.0):
            while len(published) < count:
                arrived.clear()
                await arrived.wait()

    try:
        await at(0.002, 1)  # on time: slot 1's round
        assert published == [("b", 0.002)]
        await at(0.0065, 3)  # late by a slot: slots 2 and 0 (3) run at this one wake-up
        assert published[1:] == [("c", 0.004), ("a", 0.006)]
        await at(0.0261, 6)  # stalled: rounds 4..10 skipped, then 11, 12, 13 once each
        assert published[3:] == [("c", 0.022), ("a", 0.024), ("b", 0.026)]
        assert skipped == {"a": 2, "b": 3, "c": 2}
        await at(0.0281, 7)  # on schedule again
        assert published[6:] == [("c", 0.028)]
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task


# -- a controller with its loop to itself (a lone robot-server): ControlLoop.catch_up ----------------


async def _lone(loop: ControlLoop, woke: asyncio.Event, duration: float | None = None) -> asyncio.Task[LoopStats]:
    task = asyncio.get_running_loop().create_task(loop.run(duration))
    async with asyncio.timeout(5.0):
        await woke.wait()  # the first period (deadline 0) runs at once
    return task


async def test_a_lone_loop_catches_up_one_period_per_call_and_its_wake_up_runs_none_twice() -> None:
    clock = HandClock()
    (controller,) = _controllers(1)
    woke = asyncio.Event()
    loop = ControlLoop(controller, clock, on_wake=woke.set)
    loop.catch_up()  # not running yet
    assert loop.stats.wakes == 0
    task = await _lone(loop, woke)
    assert controller.time == pytest.approx(PERIOD)

    clock.move_quietly(3.5 * PERIOD)  # deadlines 1, 2 and 3 have passed; the loop has not woken
    loop.catch_up()
    assert loop.stats.wakes == 2
    loop.catch_up()
    loop.catch_up()
    loop.catch_up()  # nothing more is due
    assert loop.stats.wakes == 4
    assert controller.time == pytest.approx(4 * PERIOD)
    assert loop.stats.max_lateness == pytest.approx(2.5 * PERIOD), "period 1 ran 2.5 periods late"
    assert loop.stats.overruns == 2, "periods 1 and 2 were more than a period late, period 3 not"

    clock.set(3.6 * PERIOD)  # the sleeping loop wakes (its deadline, period 1's, has passed): nothing is due
    for _ in range(5):
        await asyncio.sleep(0)
    assert loop.stats.wakes == 4, "the wake-up found the periods run and ran none early"

    woke.clear()
    clock.set(4.0 * PERIOD)  # the loop wakes for period 4, the one due now, and runs it once
    async with asyncio.timeout(5.0):
        await woke.wait()
    for _ in range(3):
        await asyncio.sleep(0)
    assert loop.stats.wakes == 5 and controller.time == pytest.approx(5 * PERIOD)
    loop.stop()
    clock.set(clock.now() + PERIOD)
    async with asyncio.timeout(5.0):
        stats = await task
    assert stats.simulated == pytest.approx(stats.wakes * PERIOD), "the periods run are the time simulated"


async def test_a_lone_loop_catches_up_neither_inside_a_period_nor_past_its_duration() -> None:
    clock = HandClock()
    (controller,) = _controllers(1)
    calls: list[int] = []
    woke = asyncio.Event()
    loop = ControlLoop(controller, clock)

    def on_wake() -> None:  # a callback that would call back into the loop
        calls.append(loop.stats.wakes)
        loop.catch_up()
        woke.set()

    loop.on_wake = on_wake
    task = await _lone(loop, woke, duration=3 * PERIOD)
    clock.move_quietly(10.0 * PERIOD)
    for _ in range(5):
        loop.catch_up()
    assert calls == [0, 1, 2], "one call per period, none nested, none beyond the 3 periods asked"
    assert controller.time == pytest.approx(3 * PERIOD)
    clock.set(clock.now())  # the sleeping loop wakes, finds its periods run and ends
    async with asyncio.timeout(5.0):
        stats = await task
    assert stats.wakes == 3 and stats.simulated == pytest.approx(3 * PERIOD)


async def test_a_lone_loop_leaves_a_stepped_clock_to_its_steps() -> None:
    clock = SteppedClock()
    (controller,) = _controllers(1)
    loop = ControlLoop(controller, clock)
    task = asyncio.get_running_loop().create_task(loop.run())
    caught: list[float] = []

    def in_the_middle() -> bool:  # checked before each period of the advance: the next one is due now
        if len(caught) < 3:
            before = controller.time
            loop.catch_up()
            caught.append(controller.time - before)
        return False

    async with asyncio.timeout(5.0):
        await clock.advance(3 * PERIOD, until=in_the_middle)
    assert caught == [0.0, 0.0, 0.0], "the stepped clock's periods are its advances', never a request's"
    assert controller.time == pytest.approx(4 * PERIOD)
    loop.stop()
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_a_lone_emulator_runs_the_period_due_before_a_request_is_handled() -> None:
    from robot_server.emulator import Emulator, EmulatorConfig

    clock = HandClock()
    emu = Emulator(EmulatorConfig(motion_port=0, state_port=0), clock=clock)
    await emu.start()
    try:
        await emu.wait_until(lambda: emu.control.stats.wakes == 1, 5.0)  # the first period (deadline 0)
        start = emu.cell.time
        await _request_while_a_period_is_due(clock, emu.ports["motion"])
        assert emu.cell.time >= start + PERIOD - 1e-9, "the period due ran before the request"
    finally:
        clock.set(clock.now() + PERIOD)
        await emu.close(settle_timeout=1.0)


async def test_a_lone_period_failing_in_catch_up_ends_the_loop_and_is_told_once() -> None:
    clock = HandClock()
    (controller,) = _controllers(1)
    woke = asyncio.Event()
    told: list[str] = []

    def on_wake() -> None:
        woke.set()
        if loop.stats.wakes == 1:  # the second period (counted once its on_wake returns)
            raise RuntimeError("a defect in the period")

    def on_failure() -> None:  # in the except block, as the emulator's e-stop logs the traceback
        told.append(repr(sys.exc_info()[1]))

    loop = ControlLoop(controller, clock, on_wake=on_wake, on_failure=on_failure)
    task = await _lone(loop, woke)
    clock.move_quietly(1.5 * PERIOD)
    loop.catch_up()
    assert told == ["RuntimeError('a defect in the period')"]
    failed_at = controller.time
    clock.set(5.0 * PERIOD)  # the sleeping loop wakes: it has ended, no period runs again
    async with asyncio.timeout(5.0):
        await task
    loop.catch_up()
    assert controller.time == failed_at and told == ["RuntimeError('a defect in the period')"]


async def test_before_handler_runs_once_for_a_request_with_an_arrival_hook() -> None:
    server = Server()
    seen: list[str] = []
    server.handle(
        Ping.MSG_TYPE, lambda msg, session: seen.append("handler"), on_arrival=lambda msg, s: seen.append("arrival")
    )
    server.before_handler = lambda: seen.append("before")
    port = await server.serve_tcp()
    try:
        async with Client.tcp("127.0.0.1", port) as client:
            await client.request(Ping(), 5.0)
            assert seen == ["before", "arrival", "handler"]
    finally:
        await server.close()
