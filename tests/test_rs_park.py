"""A controller at rest is left out of its fleet's shared control loop until something needs it
(ControlLoop.park, robot_server.control.loop), and comes back exactly where running every period
would have brought it.

The shared loops here run on a clock the test sets but that says it is a real-time one (as a
fleet's is): the periods due are run one at a time by ``catch_up`` (what a request does), so the
test knows which periods ran."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

import numpy as np
import pytest

from robot_server.control import Controller, ControllerConfig, ControlLoop, Recorder, SharedLoop, SteppedClock
from robot_server.control.points import Point
from robot_server.fleet import Fleet, parse_fleet
from robot_server.loader import load_model
from simple_message import Ping
from tests.handclock import HandClock
from tests.rawpeer import RawPeer, joint_traj_pt, vectors
from tests.stepped import poll

PERIOD = 0.004
JTP = vectors("<")["JOINT_TRAJ_PT_REQUEST_SEQ3"]

Verb = Callable[[Controller], object]


class Pair:
    """Two identical controllers in one shared loop: ``parked`` may be parked, ``every`` never is
    (no idle check) and runs every period."""

    def __init__(self, model: str = "jibot_zxs") -> None:
        robot = load_model(model)
        self.clock = HandClock()
        self.parked = ControlLoop(Controller(robot, ControllerConfig()), self.clock, idle=lambda: True)
        self._woke = asyncio.Event()
        self.every = ControlLoop(Controller(robot, ControllerConfig()), self.clock, on_wake=self._woke.set)
        sub = self.parked.controller.servo_ticks_per_interpolation
        self.shared = SharedLoop(self.clock, PERIOD, sub)
        self.shared.add(self.parked)
        self.shared.add(self.every)
        self.task: asyncio.Task[object] | None = None
        self.k = 0

    async def start(self) -> None:
        self.task = asyncio.get_running_loop().create_task(self.shared.run())
        async with asyncio.timeout(5.0):
            await self._woke.wait()  # the first period (deadline 0) runs at once
        self.every.on_wake = None
        self.k = 1

    def periods(self, count: int) -> None:
        """``count`` more periods, each run by a catch_up the moment it is due."""
        for _ in range(count):
            self.clock.move_quietly(self.k * PERIOD)
            self.shared.catch_up()
            self.k += 1
        assert self.shared.next_period == self.k

    def same(self) -> None:
        """Both controllers stand at the same place, bit for bit (the parked one brought up first)."""
        self.parked.unpark()
        a, b = self.parked.controller, self.every.controller
        assert a.time == b.time
        assert a.command == b.command, f"at t={b.time}"
        assert a.tool == b.tool
        assert a.servo.position == b.servo.position and a.servo.integral == b.servo.integral
        assert a._rest.periods == b._rest.periods
        assert (self.parked.stats.ticks, self.parked.stats.wakes) == (self.every.stats.ticks, self.every.stats.wakes)

    def both(self, verb: Verb) -> None:
        self.parked.unpark()  # what the emulator's cell.sync does before a verb
        results = []
        for ctl in (self.parked.controller, self.every.controller):
            try:
                results.append(verb(ctl))
            except Exception as exc:  # the same refusal on both
                results.append(type(exc))
        assert results[0] == results[1]

    async def stop(self) -> None:
        self.shared.stop()
        self.clock.set(self.clock.now() + PERIOD)
        assert self.task is not None
        async with asyncio.timeout(5.0):
            await self.task


SCRIPT: list[tuple[int, Verb]] = [
    (300, lambda c: c.add_move(np.full(6, 0.3), speed=0.5)),
    (1000, lambda c: c.raise_alarm(4999, "a test alarm at rest")),
    (700, lambda c: c.reset()),
    (500, lambda c: c.power_off()),
    (300, lambda c: c.power_on()),
    (700, lambda c: c.stop()),  # a stop at rest stops nothing
    (700, lambda c: setattr(c, "manual", True)),
    (700, lambda c: setattr(c, "manual", False)),
    (600, lambda c: c.start(Point(np.array(c.command.command_position), duration=0.0, velocity_ratio=0.5))),
    (2, lambda c: c.add(Point(np.full(6, 0.1), duration=2.0))),
    (1500, lambda c: None),
]


async def test_a_parked_controller_comes_back_where_every_period_would_have_brought_it() -> None:
    pair = Pair()
    await pair.start()
    pair.periods(10)
    assert pair.parked.parked, "a new controller at rest is parked within a few periods"
    frozen = pair.parked.controller.time
    pair.periods(500)
    assert pair.parked.controller.time == frozen, "its periods were left out"
    assert pair.every.controller.time == pytest.approx(511 * PERIOD)
    pair.same()
    parked_periods = 0
    for count, verb in SCRIPT:
        for _ in range(count // 50):
            pair.periods(50)
            parked_periods += pair.parked.parked
            pair.same()
        pair.both(verb)
    assert pair.parked.controller.points_accepted == 3, "a move and a trajectory of two points ran"
    assert parked_periods > 40, "it was parked at every rest"
    assert pair.every.controller._rest.periods > 3000, "the rests were replayed"
    await pair.stop()


async def test_unpark_after_many_periods_is_one_period_of_work() -> None:
    pair = Pair()
    await pair.start()
    pair.periods(20)
    assert pair.parked.parked
    calls = 0
    wake = pair.parked.wake

    def counted() -> None:
        nonlocal calls
        calls += 1
        wake()

    pair.parked.wake = counted  # type: ignore[method-assign]
    pair.periods(10_000)  # 40 s
    assert calls == 0
    pair.same()
    assert calls == 1, "the periods left out are passed at once, the last one stepped"
    await pair.stop()


async def test_a_loop_is_not_parked_while_something_waits_records_or_has_another_group() -> None:
    idle = False
    pair = Pair()
    pair.parked.idle = lambda: idle
    await pair.start()
    pair.periods(20)
    assert not pair.parked.parked, "its owner says something waits for its wake-ups"
    idle = True
    pair.periods(2)
    assert pair.parked.parked
    pair.parked.unpark()
    pair.parked.recorder = Recorder(6, 1000)
    pair.periods(20)
    assert not pair.parked.parked, "a recorder sees every tick"
    assert len(pair.parked.recorder) == 20 * pair.parked.controller.servo_ticks_per_interpolation
    pair.parked.recorder = None
    pair.periods(2)
    assert pair.parked.parked
    pair.parked.unpark()
    pair.parked.others = [Controller(load_model("jibot_zxs"), ControllerConfig())]
    pair.periods(20)
    assert not pair.parked.parked, "several motion groups are never left out"
    await pair.stop()


async def test_a_loop_is_not_parked_on_a_stepped_clock() -> None:
    clock = SteppedClock()
    controller = Controller(load_model("jibot_zxs"), ControllerConfig())
    loop = ControlLoop(controller, clock, idle=lambda: True)
    shared = SharedLoop(clock, PERIOD, controller.servo_ticks_per_interpolation)
    shared.add(loop)
    task = asyncio.get_running_loop().create_task(shared.run())
    async with asyncio.timeout(5.0):
        await clock.advance(1.0)
    assert not loop.parked, "a test stepping the clock reads the controllers directly"
    assert controller.time == pytest.approx(1.0, abs=2 * PERIOD)
    shared.stop()
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_unpark_asked_inside_a_period_is_done_right_after_it() -> None:
    pair = Pair()
    await pair.start()
    pair.periods(20)
    assert pair.parked.parked
    asked: list[int] = []

    def on_wake() -> None:  # another member's task, run in the period, reads the parked controller
        if not asked:
            asked.append(pair.shared.next_period)
            pair.parked.unpark()
            assert pair.parked.parked, "not in the middle of the period"

    pair.every.on_wake = on_wake
    pair.periods(1)
    assert asked
    pair.every.on_wake = None
    assert not pair.parked.parked, "brought up right after that period"
    assert pair.parked.controller.time == pair.every.controller.time
    pair.same()
    pair.periods(30)
    pair.same()
    await pair.stop()


async def test_leaving_the_shared_loop_brings_a_parked_controller_up_to_its_last_period() -> None:
    pair = Pair()
    await pair.start()
    pair.periods(300)
    assert pair.parked.parked
    pair.shared.remove(pair.parked)
    assert not pair.parked.parked
    assert pair.parked.controller.time == pair.every.controller.time
    assert pair.parked.controller.command == pair.every.controller.command
    await pair.stop()


# -- in a fleet ----------------------------------------------------------------------------------


class Due:
    """What each controller's time is when it has run every shared period so far (the controllers
    joined the shared loop one after another as they started: each at a later period)."""

    def __init__(self, fleet: Fleet, shared: SharedLoop) -> None:
        self.shared = shared
        self.offset = {name: shared.next_period * PERIOD - fleet[name].cell.time for name in fleet}

    def __call__(self, name: str) -> float:
        return self.shared.next_period * PERIOD - self.offset[name]


async def _fleet_at_rest(names: dict[str, str]) -> tuple[Fleet, Due, Callable[[int], None]]:
    clock = HandClock()
    data = {
        "controller": [
            {"name": n, "profile": p, "motion_port": 0, "state_port": 0, **({"io_port": 0} if p == "motoros" else {})}
            for n, p in names.items()
        ]
    }
    fleet = Fleet(parse_fleet(data), clock=clock)
    await fleet.start()
    (shared,) = fleet.shared.loops.values()
    k = 1

    def periods(count: int) -> None:
        nonlocal k
        for _ in range(count):
            clock.move_quietly(k * PERIOD)
            shared.catch_up()
            k += 1

    periods(1)
    return fleet, Due(fleet, shared), periods


async def test_in_a_fleet_controllers_at_rest_are_parked_and_a_request_brings_back_that_one_only() -> None:
    fleet, due, periods = await _fleet_at_rest({"r1": "generic", "r2": "fanuc", "r3": "staubli", "r4": "motoros"})
    try:
        (shared,) = fleet.shared.loops.values()
        periods(50)
        assert shared.parked_members == 4, "every controller at rest, nothing waiting: all parked"
        loops = {name: fleet[name].control for name in fleet}
        assert all(loops[name].controller.time < due(name) - PERIOD for name in loops)
        motion = await RawPeer.connect(fleet["r1"].ports["motion"])
        try:
            await poll(lambda: fleet["r1"].owner.owner is not None)  # (its hook brought r1 up to now)
            periods(50)
            # (a PING is answered without reading the controller: it is left parked)
            assert (await motion.request(Ping().encode())).reply_code == 1
            assert loops["r1"].parked
            reply = await motion.request(joint_traj_pt(JTP, 0, [0.0] * 6))
        finally:
            await motion.close()
        assert reply.reply_code == 1, "the point, handled once r1 stands where its periods brought it"
        assert loops["r1"].controller.time == pytest.approx(due("r1"))
        assert not loops["r1"].parked
        assert loops["r2"].parked and loops["r3"].parked, "a request to r1 brings r1 up, not the others"
        # any read through the cell brings its controller up to now first
        assert fleet["r3"].cell.time == pytest.approx(due("r3"))
        assert not loops["r3"].parked
        periods(5)
        assert loops["r3"].parked, "parked again after a period: still at rest"
    finally:
        await fleet.close()


async def test_in_a_fleet_a_fault_or_a_wait_on_a_parked_controller_happens_at_its_period() -> None:
    fleet, due, periods = await _fleet_at_rest({"r1": "generic", "r2": "generic"})
    try:
        periods(50)
        r1, r2 = fleet["r1"], fleet["r2"]
        assert r1.control.parked and r2.control.parked
        r1.cell.estop()  # the Python API, as the fleet's docs show it: r1 first comes up to now
        assert r1.cell.groups[0].time == pytest.approx(due("r1"))
        assert not r1.cell.drives_powered and r1.cell.e_stopped
        periods(20)
        assert not r1.control.parked, "drives off: stepped every period"
        assert r2.control.parked, "the other one rests on"
        target = r2.cell.time + 10 * PERIOD
        waiting = asyncio.get_running_loop().create_task(r2.wait_until(lambda: r2.cell.time >= target - 1e-9, 5.0))
        for _ in range(3):
            await asyncio.sleep(0)
        assert not waiting.done()
        assert not r2.control.parked, "a task waits for its wake-ups"
        for _ in range(10):
            periods(1)
            for _ in range(3):  # the waiting task sees the wake-up
                await asyncio.sleep(0)
        async with asyncio.timeout(5.0):
            await waiting
        assert r2.cell.time == pytest.approx(target)
    finally:
        await fleet.close()


async def test_in_a_fleet_a_controller_with_work_around_it_is_not_parked() -> None:
    fleet, _, periods = await _fleet_at_rest({"f": "fanuc", "s": "staubli"})
    try:
        periods(50)
        f, s = fleet["f"], fleet["s"]
        assert f.control.parked and s.control.parked
        relay = await RawPeer.connect(f.ports["motion"])  # a relay connection: its stall watch runs
        try:
            await poll(lambda: bool(f.motion_server.sessions))  # (its owner's hook brought it up)
            periods(20)
            assert not f.control.parked
        finally:
            await relay.close()
        await poll(lambda: not f.motion_server.sessions)
        periods(3)
        assert f.control.parked, "the relay gone: nothing to watch"
        motion_task = s.behaviour.motion  # type: ignore[attr-defined]
        assert motion_task.idle()
        motion_task.queue.append(object())  # a command queued for the VAL3 motion task
        assert not motion_task.idle() and not s.cell.idle()
        motion_task.queue.clear()
        motion_task.stop_now = True
        assert not motion_task.idle()
        motion_task.stop_now = False
    finally:
        await fleet.close()


async def test_a_state_round_with_a_client_brings_its_controller_up_to_now() -> None:
    fleet, due, periods = await _fleet_at_rest({"r1": "motoros", "r2": "motoros"})
    try:
        periods(50)
        r1, r2 = fleet["r1"], fleet["r2"]
        assert r1.control.parked and r2.control.parked
        state = await RawPeer.connect(r1.ports["state"])
        try:
            await poll(lambda: bool(r1.state_server.sessions))
            fleet.run_as("r1", lambda: r1._state_round(time.monotonic()))
            fleet.run_as("r2", lambda: r2._state_round(time.monotonic()))
        finally:
            await state.close()
        assert r1.cell.groups[0].time == pytest.approx(due("r1")), "r1's client reads it"
        assert r1.control.parked, "read, not changed: left out again at once"
        r1.cell.estop()  # a change after the round: made on a controller running again
        periods(3)
        assert not r1.control.parked and not r1.cell.groups[0].drives_powered
        assert r1.cell.groups[0].time == pytest.approx(due("r1"))
        assert r2.control.parked, "r2 has no state client: nothing to bring up"
    finally:
        await fleet.close()


async def test_a_cell_is_not_idle_while_a_task_waits_for_its_wake_ups() -> None:
    fleet, _, periods = await _fleet_at_rest({"r1": "generic"})
    try:
        cell = fleet["r1"].cell
        assert cell.idle()
        waiting = asyncio.get_running_loop().create_task(cell.changed())
        await asyncio.sleep(0)
        assert not cell.idle(), "a task waits in changed()"
        periods(1)
        async with asyncio.timeout(5.0):
            await waiting
        assert cell.idle()
    finally:
        await fleet.close()


def _settle_after_move(pair: Pair) -> None:
    pair.periods(10)
    pair.both(lambda c: c.add_move(np.full(6, 0.3), speed=0.5))
    pair.periods(1500)
    assert pair.parked.parked


@pytest.mark.parametrize(
    "verb",
    [
        lambda c: c.raise_alarm(4999, "a test alarm at rest"),
        lambda c: c.power_off(),
        lambda c: c.stop(),
        lambda c: setattr(c, "manual", True),
    ],
    ids=["alarm", "drives off", "stop", "manual"],
)
async def test_a_controller_just_changed_is_not_parked_before_its_next_period(verb: Verb) -> None:
    """A state round (rest_again) between a change and the next period: the change is stepped
    first, by the next period, as running every period does (a review found it parked at once)."""
    pair = Pair()
    await pair.start()
    _settle_after_move(pair)
    pair.both(verb)
    pair.parked.rest_again()  # a state round with a client before the next shared period
    assert not pair.parked.parked
    pair.periods(200)
    pair.same()
    assert pair.parked.controller.in_motion == pair.every.controller.in_motion
    await pair.stop()


async def test_a_change_made_in_the_loops_own_period_is_stepped_before_it_is_parked() -> None:
    """A controller's own periodic task (a tick listener: Staubli's motion task raising an alarm for
    a movej it cannot run) changes it in its period: not parked in that same period."""
    pair = Pair()
    await pair.start()
    _settle_after_move(pair)
    fired: list[int] = []

    def alarm_once() -> None:
        if not fired:
            fired.append(1)
            pair.parked.controller.raise_alarm(9001, "movej with acceleration 0")

    pair.parked.unpark()  # (a controller running again: its task has work)
    pair.parked.on_wake = alarm_once
    pair.periods(1)
    pair.every.controller.raise_alarm(9001, "movej with acceleration 0")
    pair.parked.on_wake = None
    assert not pair.parked.parked, "changed in its own period"
    pair.periods(10)
    pair.same()
    assert not pair.parked.controller.in_motion and not pair.every.controller.in_motion
    await pair.stop()


async def test_in_a_fleet_an_alarm_then_a_state_round_leaves_the_robot_settled_and_free() -> None:
    """A fault command at rest, then a state round with a client before the next period: the
    controller settles (in_motion FALSE) and a new motion client is not refused as busy."""
    fleet, _, periods = await _fleet_at_rest({"r1": "generic", "r2": "generic"})
    try:
        periods(50)
        r1, r2 = fleet["r1"], fleet["r2"]
        assert r1.control.parked
        state = await RawPeer.connect(r1.ports["state"])
        try:
            await poll(lambda: bool(r1.state_sessions()))
            for name in ("r1", "r2"):
                fleet.command(f"{name} alarm 42")
            fleet.run_as("r1", lambda: r1._state_round(time.monotonic()))
            periods(20)
            assert not r2.cell.in_motion
            assert not r1.cell.in_motion and not r1.owner.busy
        finally:
            await state.close()
    finally:
        await fleet.close()


async def test_a_request_brings_its_controller_up_before_any_handler_reads_it() -> None:
    """The servers' before_handler (not only the cell's own reads): a handler reading the
    controller directly sees it where its periods brought it."""
    fleet, due, periods = await _fleet_at_rest({"r1": "generic"})
    try:
        periods(50)
        r1 = fleet["r1"]
        assert r1.control.parked
        seen: list[float] = []

        def on_ping(msg: object, session: object) -> None:
            seen.append(r1.cell.groups[0].time)  # the controller itself, not through the cell

        r1.motion_server.handle(Ping.MSG_TYPE, on_ping)
        motion = await RawPeer.connect(r1.ports["motion"])
        try:
            await poll(lambda: r1.owner.owner is not None)
            periods(50)
            assert r1.control.parked
            await motion.request(Ping().encode())
        finally:
            await motion.close()
        assert seen == [pytest.approx(due("r1"))]
    finally:
        await fleet.close()


async def test_a_motion_client_leaving_brings_its_controller_up_first() -> None:
    fleet, due, periods = await _fleet_at_rest({"r1": "generic"})
    try:
        periods(50)
        r1 = fleet["r1"]
        motion = await RawPeer.connect(r1.ports["motion"])
        await poll(lambda: r1.owner.owner is not None)
        periods(50)
        assert r1.control.parked
        await motion.close()
        await poll(lambda: r1.owner.owner is None)
        assert r1.cell.groups[0].time == pytest.approx(due("r1")), "the owner's hook read it up to date"
    finally:
        await fleet.close()


async def test_a_record_or_the_web_view_brings_a_parked_controller_up_first() -> None:
    from robot_server.web.feed import status_of

    fleet, due, periods = await _fleet_at_rest({"r1": "generic", "r2": "generic"})
    try:
        periods(50)
        r1, r2 = fleet["r1"], fleet["r2"]
        assert r1.control.parked and r2.control.parked
        r1.record(1.0)
        assert r1.cell.groups[0].time == pytest.approx(due("r1")), "the record starts now"
        periods(5)
        assert not r1.control.parked, "recorded: every tick is stepped"
        status_of(r2)  # what the web view's lights read
        assert r2.cell.groups[0].time == pytest.approx(due("r2"))
    finally:
        await fleet.close()


async def test_a_controller_changed_behind_its_cells_back_is_told_once(caplog: pytest.LogCaptureFixture) -> None:
    """A change that did not bring the parked controller up first (a defect of the caller): the
    periods left out still pass, and the log says so once, not at every unpark."""
    pair = Pair()
    await pair.start()
    pair.periods(20)
    assert pair.parked.parked
    with caplog.at_level(logging.WARNING, logger="robot_server.control.loop"):
        for _ in range(3):
            pair.parked.controller.raise_alarm(4999, "behind the cell's back")  # no unpark first
            pair.periods(10)
            pair.parked.unpark()
            pair.parked.controller.reset()
            pair.periods(300)
    told = [r for r in caplog.records if "without being brought up to now" in r.getMessage()]
    assert len(told) == 1
    pair.parked.unpark()
    assert pair.parked.controller.time == pair.every.controller.time
    await pair.stop()
