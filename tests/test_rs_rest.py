"""A controller at rest replays its last period (robot_server.control.rest): exactly what stepping gives.

Two controllers run the same script of verbs side by side, tick by tick: one as shipped, one whose
watch never replays. Every tick (command, actual, errors, points, the tool with its time) must be
the same, bit for bit, through rests long enough to replay, and verbs called at rest between two
interpolation instants and at them: points, moves, stops, alarms, resets, drives off and on, the
mode, a supervision swapped.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from robot_server.control import Controller, ControllerConfig, Point, Recorder, Tick
from robot_server.control.recorder import QUANTITIES
from robot_server.control.rest import RestWatch
from robot_server.loader import load_model
from robot_server.workspace import Supervision


class _NeverReplays(RestWatch):
    def replay(self, *args: object, **kwargs: object) -> None:  # type: ignore[override]
        return None


def _pair(model: str = "jibot_zxs") -> tuple[Controller, Controller]:
    robot = load_model(model)
    fast, slow = Controller(robot, ControllerConfig()), Controller(robot, ControllerConfig())
    slow._rest = _NeverReplays()
    return fast, slow


def _same(a: Tick, b: Tick) -> bool:
    return a == b  # lists, floats, the tool (a NamedTuple): exact equality


Verb = Callable[[Controller], object]


def _run(fast: Controller, slow: Controller, ticks: int) -> None:
    for k in range(ticks):
        a, b = fast.step(), slow.step()
        assert _same(a, b), f"tick {k} at t={b.time}: {a} != {b}"


def _both(fast: Controller, slow: Controller, verb: Verb) -> None:
    results = []
    for ctl in (fast, slow):
        try:
            results.append(verb(ctl))
        except Exception as exc:  # the same refusal on both
            results.append(type(exc))
    assert results[0] == results[1]


SCRIPT: list[tuple[int, Verb]] = [
    (3000, lambda c: c.add_move(np.full(6, 0.3), speed=0.5)),
    (4002, lambda c: c.add_move(np.full(6, -0.2), speed=0.3)),  # between two interpolation instants
    (5001, lambda c: c.raise_alarm(4999, "a test alarm at rest")),
    (3003, lambda c: c.reset()),
    (2500, lambda c: c.power_off()),
    (1500, lambda c: c.power_on()),
    (3000, lambda c: c.stop()),  # a stop at rest stops nothing
    (3000, lambda c: setattr(c, "manual", True)),
    (3000, lambda c: setattr(c, "manual", False)),
    (2000, lambda c: setattr(c, "supervision", Supervision())),
    (2000, lambda c: c.start(Point(np.array(c.command.command_position), duration=0.0, velocity_ratio=0.5))),
    (2, lambda c: c.add(Point(np.full(6, 0.1), duration=2.0))),
    (6000, lambda c: None),
]


def test_a_resting_controller_replays_exactly_what_stepping_gives() -> None:
    fast, slow = _pair()
    for ticks, verb in SCRIPT:
        _run(fast, slow, ticks)
        _both(fast, slow, verb)
    _run(fast, slow, 3000)
    assert fast.points_accepted == 4, "two moves and a trajectory of two points ran"
    assert fast.trajectories == 1
    assert fast._rest.periods > 3000, "the rests were long enough to replay"
    assert slow._rest.periods == 0


@pytest.mark.parametrize("model", ["puma560", "ur5", "kuka_kr6_r900_sixx"])
def test_every_shipped_model_comes_to_an_exact_rest_after_a_move(model: str) -> None:
    fast, slow = _pair(model)
    n = fast.dof
    _both(fast, slow, lambda c: c.add_move(np.linspace(-0.3, 0.4, n), speed=0.6))
    _run(fast, slow, 8000)
    assert not fast.in_motion
    assert fast._rest.periods > 0


def test_a_period_stepped_at_once_ends_as_its_ticks_one_by_one() -> None:
    """Controller.step_period (what a control loop without a recorder runs: at rest a replay, moving
    the drives alone until the period's last tick) against step() four times, through motion, a
    following-error alarm in the middle of a period, a stop, and rests."""
    robot = load_model("jibot_zxs")
    whole, ticks = Controller(robot, ControllerConfig()), Controller(robot, ControllerConfig())
    sub = whole.servo_ticks_per_interpolation

    def periods(count: int) -> None:
        for _ in range(count):
            last = whole.step_period()
            for _ in range(sub):
                tick = ticks.step()
            # the period's last tick leaves the TCP to Controller.tool (computed when read): the same
            assert last._replace(tool=None) == tick._replace(tool=None), f"at t={tick.time}"
            assert whole.tool == ticks.tool == tick.tool, f"at t={tick.time}"
            assert whole.servo.position == ticks.servo.position and whole.servo.integral == ticks.servo.integral

    script: list[tuple[int, Verb]] = [
        (500, lambda c: c.add_move(np.full(6, 0.4), speed=0.8)),
        (100, lambda c: c.stop()),
        (800, lambda c: c.add_move(np.full(6, -0.3), speed=0.5)),
        (40, lambda c: setattr(c.servo, "following_error_limit", [1e-6] * 6)),  # moving: trips at once
        (300, lambda c: alarms.append(c.error_code)),
        (0, lambda c: setattr(c.servo, "following_error_limit", [1.0] * 6)),
        (10, lambda c: c.reset()),
        (10, lambda c: c.add_move(np.full(6, 0.1), speed=0.5)),
        (1500, lambda c: None),
    ]
    alarms: list[int] = []
    for count, verb in script:
        periods(count)
        _both(whole, ticks, verb)
    assert alarms == [4101, 4101], "the following-error alarm tripped in both"
    assert whole.error_code == 0 and ticks.error_code == 0
    assert whole.points_accepted == 3 and whole._rest.periods > 0


@pytest.mark.parametrize(
    ("decimation", "computed_when_read"), [(1, True), (1, False), (3, False)], ids=["tcp-when-read", "tcp", "decimated"]
)
def test_a_recorded_period_is_its_ticks_one_by_one(decimation: int, computed_when_read: bool) -> None:
    """Controller.step_period(recorder) (what a control loop with a recorder runs: a rest replayed
    tick by tick, a moving tick's numbers handed over with its two setpoints, the command computed
    by the recorder a block at a time, the TCP of an instant computed by the recorder when read if
    it takes it) records exactly the ticks step() gives, the TCP of each included, through motion,
    a verb between two instants, a following-error alarm in mid-period, a stop, drives off and on,
    and rests; decimated too (the TCP then computed by the controller)."""
    robot = load_model("jibot_zxs")
    whole, ticks = Controller(robot, ControllerConfig()), Controller(robot, ControllerConfig())
    sub = whole.servo_ticks_per_interpolation
    meter = whole.tool_meter if computed_when_read else None
    # the ring wraps; the instants' ring as short as the emulator makes it (one instant per period)
    by_period = Recorder(6, capacity=5000, decimation=decimation, tool_meter=meter, instants=5000 // sub + 2)
    one_by_one = Recorder(6, capacity=5000, decimation=decimation)
    assert by_period.takes_instants(whole.tool_meter) == computed_when_read

    def one_tick(c: Controller) -> None:  # one tick into a period: the next step_period ends it
        c.step()

    def periods(count: int) -> None:
        for _ in range(count):
            before = whole.time
            last = whole.step_period(by_period)
            while ticks.time < whole.time - 1e-9:
                tick = ticks.step()
                one_by_one.add(tick)
            assert last.time == tick.time > before and round(last.time / whole.config.servo_period) % sub == 0
            assert last._replace(tool=None) == tick._replace(tool=None)
            assert whole.servo.position == ticks.servo.position and whole.servo.integral == ticks.servo.integral

    script: list[tuple[int, Verb]] = [
        (50, lambda c: c.add_move(np.full(6, 0.4), speed=0.8)),
        (100, lambda c: c.stop()),
        (300, lambda c: c.add_move(np.full(6, -0.3), speed=0.5)),
        (40, lambda c: setattr(c.servo, "following_error_limit", [1e-6] * 6)),  # moving: trips at once
        (300, lambda c: alarms.append(c.error_code)),
        (0, lambda c: setattr(c.servo, "following_error_limit", [1.0] * 6)),
        (10, lambda c: c.reset()),
        (10, lambda c: c.add_move(np.full(6, 0.1), speed=0.5)),
        (30, one_tick),
        (1, lambda c: c.power_off()),
        (20, lambda c: c.power_on()),
        (10, lambda c: c.add_move(np.full(6, 0.2), speed=0.5)),
        (200, lambda c: c.tool),  # the controller's TCP read in mid-move: the recorder's the same
        (600, lambda c: c.add_move(np.full(6, -0.5), speed=0.01)),  # slow: still moving at the end
        (1300, lambda c: None),
    ]
    alarms: list[int] = []
    reads = 0
    for count, verb in script:
        periods(count)
        _both(whole, ticks, verb)
        if verb is one_tick:
            one_by_one.add(ticks.command)  # the tick the verb made, in both records
            by_period.add(whole.command)
        if count == 300 and reads < 2:  # read in the middle: the TCPs computed so far, the rest later
            reads += 1
            assert np.array_equal(by_period.tool(), one_by_one.tool(), equal_nan=True)
    assert alarms == [4101, 4101], "the following-error alarm tripped in both"
    assert whole.points_accepted == 5 and whole._rest.periods > 0 and whole.moving, "the ring's last periods moving"
    assert len(by_period) == len(one_by_one) > 3000 and by_period.dropped == one_by_one.dropped
    assert (by_period.dropped > 0) == (decimation == 1), "undecimated, the ring wrapped"
    copy = by_period.copy()  # taken before the TCPs are computed: they are computed when the copy's are read
    assert np.array_equal(copy.tool_time(), one_by_one.tool()[:, -1], equal_nan=True)
    assert np.array_equal(by_period.tool_time(), one_by_one.tool()[:, -1], equal_nan=True)
    for a, b in ((by_period, one_by_one), (copy, one_by_one)):
        assert np.array_equal(a.time(), b.time())
        for quantity in QUANTITIES:
            assert np.array_equal(a.get(quantity), b.get(quantity)), quantity
        assert np.array_equal(a.points(), b.points())
        assert np.array_equal(a.tool(), b.tool(), equal_nan=True)
    assert not np.isnan(by_period.tool()).any(), "every tick had a TCP"


def test_a_recorder_swapped_or_cleared_in_mid_move_has_every_tick_s_tcp() -> None:
    """The TCP an instant's recorder was left is computed by the controller for another recorder
    (a second Emulator.record while moving) or for the same one cleared since: no tick without it."""
    robot = load_model("jibot_zxs")
    whole, ticks = Controller(robot, ControllerConfig()), Controller(robot, ControllerConfig())
    for c in (whole, ticks):
        c.add_move(np.full(6, 0.4), speed=0.05)
    sub = whole.servo_ticks_per_interpolation

    def taking() -> Recorder:
        return Recorder(6, 4000, tool_meter=whole.tool_meter, instants=4000 // sub + 2)

    def run(recorder: Recorder, reference: Recorder, periods: int) -> None:
        for _ in range(periods):
            whole.step_period(recorder)
            for _ in range(sub):
                reference.add(ticks.step())

    first, first_reference = taking(), Recorder(6, 4000)
    run(first, first_reference, 50)
    second, second_reference = taking(), Recorder(6, 4000)
    run(second, second_reference, 50)  # swapped in mid-move: its first ticks hold the instant first was left
    first.clear()
    first_reference.clear()
    run(first, first_reference, 50)  # cleared in mid-move, then recording on
    whole.run_for(0.1, second)  # and ticks by step() after a period left to another recorder
    ticks.run_for(0.1, second_reference)
    assert whole.moving
    for recorder, reference in ((first, first_reference), (second, second_reference)):
        assert np.array_equal(recorder.tool(), reference.tool(), equal_nan=True)
        assert not np.isnan(recorder.tool()).any()
