"""The controller layer: trajectory semantics, queue, stop, servo drives, alarms, clocks, recorder.

The ``blend`` policy's own behaviour (passing through points, slowing down, look-ahead) is tested
in test_rs_blend.py; here the paper's rest-to-rest policies and what every policy shares.
"""

from __future__ import annotations

import asyncio
import dataclasses
import io
import math
import time
from types import SimpleNamespace

import numpy as np
import pytest

from robot_server.control import (
    CUBIC_PEAK_ACCELERATION,
    CUBIC_PEAK_VELOCITY,
    FOLLOWING_ERROR_ALARM,
    POLICIES,
    QUINTIC_PEAK_ACCELERATION,
    QUINTIC_PEAK_VELOCITY,
    Controller,
    ControllerConfig,
    ControlLoop,
    Point,
    PointRejected,
    RealTimeClock,
    Reason,
    Recorder,
    SimulatedClock,
    Tick,
    cubic,
    quintic,
    run_simulated,
    submit_together,
)
from robot_server.control import clock as clock_module
from robot_server.control import loop as loop_module
from robot_server.control.loop import OVERRUNS_KEPT, LoopStats, overrun_times
from robot_server.loader import load_model
from robot_server.model import ModelError, MotorParameters

MODEL = load_model("jibot_zxs")
N = MODEL.dof
VMAX, AMAX, JMAX = MODEL.max_velocity, MODEL.max_acceleration, MODEL.max_jerk


def controller(policy: str = "quintic", **options: object) -> Controller:
    return Controller(MODEL, ControllerConfig(policy=policy, **options))  # type: ignore[arg-type]


def pt(positions: object, ratio: float = 1.0, duration: float = 0.0) -> Point:
    return Point(np.array(positions, dtype=float), velocity_ratio=ratio, duration=duration)


def full(time: float, p: object, v: object = None, a: object = None) -> Point:
    arr = [None if x is None else np.array(x, dtype=float) for x in (p, v, a)]
    return Point(arr[0], arr[1], arr[2], time=time)


def run(ctl: Controller, seconds: float) -> Recorder:
    recorder = Recorder(N, capacity=round(seconds / ctl.config.servo_period) + 1)
    ctl.run_for(seconds, recorder)
    return recorder


def interpolation_samples(ctl: Controller, recorder: Recorder, quantity: str) -> np.ndarray:
    """The recorded command at the interpolation instants (every 4th servo tick)."""
    sub = round(ctl.config.interpolation_period / ctl.config.servo_period)
    return recorder.get(quantity)[sub - 1 :: sub]


# -- trajectory semantics ---------------------------------------------------------------------


def test_duration_is_the_segment_time_and_the_ratio_sets_it_otherwise() -> None:
    ctl = controller("quintic")
    ctl.start(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.5), duration=2.0))
    assert ctl.queue.segments()[-1].duration == 2.0
    ctl.add(pt(np.zeros(N), ratio=0.5))
    # quintic peak speed is 1.875 D / T: at half of pi rad/s, T = 1.875 * 0.5 / (0.5 * pi)
    expected = max(1.875 * 0.5 / (0.5 * math.pi), math.sqrt(10 / math.sqrt(3) * 0.5 / AMAX[0]))
    assert math.isclose(ctl.queue.segments()[-1].duration, expected)
    assert ctl.queue_fill == 2
    for policy, factor in (("linear", 1.0), ("cubic", 1.5)):
        c = controller(policy)
        c.start(pt(np.zeros(N)))
        c.add(pt([1.0, 0, 0, 0, 0, 0], ratio=1.0))
        accel = 0.0 if policy == "linear" else math.sqrt(6.0 / AMAX[0])
        assert math.isclose(c.queue.segments()[-1].duration, max(factor / math.pi, accel))


def test_the_peak_ratios_are_those_of_the_shapes_and_of_the_policies() -> None:
    """The shared constants (what planners time points with) are the segments' own peaks, and
    what the rest-to-rest policies time points with."""
    delta, tf = np.array([0.7, -1.3]), 0.9
    for shape, speed, accel in (
        (cubic, CUBIC_PEAK_VELOCITY, CUBIC_PEAK_ACCELERATION),
        (quintic, QUINTIC_PEAK_VELOCITY, QUINTIC_PEAK_ACCELERATION),
    ):
        segment = shape(np.zeros(2), delta, tf)
        assert np.allclose(segment.peak(1), speed * np.abs(delta) / tf, rtol=1e-12)
        assert np.allclose(segment.peak(2), accel * np.abs(delta) / tf**2, rtol=1e-12)
    assert (QUINTIC_PEAK_VELOCITY, CUBIC_PEAK_ACCELERATION) == (1.875, 6.0)
    for name, speed, accel in (
        ("cubic", CUBIC_PEAK_VELOCITY, CUBIC_PEAK_ACCELERATION),
        ("quintic", QUINTIC_PEAK_VELOCITY, QUINTIC_PEAK_ACCELERATION),
    ):
        shape_policy = POLICIES[name]
        assert (shape_policy.speed_factor, shape_policy.accel_factor) == (speed, accel)


def test_submit_together_is_all_or_nothing() -> None:
    """Motion groups accept points together or not at all (their shared time scale, read from
    each plan with :meth:`Controller.plan_scale`, is test_rs_blend.py's)."""
    a, b = controller("blend"), controller("blend")
    z = np.zeros(N)
    submit_together([(a, full(0.0, z)), (b, full(0.0, z))], first=True)
    for i in range(1, 21):  # group a: 10 rad/s^2 over the limit
        t = 0.02 * i
        submit_together([(a, full(t, z + 0.8 * (t / 0.4) ** 2)), (b, full(t, z + 0.05 * t / 0.4))])
    before = [(c.queue_fill, c.queue.scale, c.points_accepted) for c in (a, b)]
    with pytest.raises(PointRejected) as err:
        submit_together([(a, full(0.42, z + 0.84)), (b, full(0.42, np.full(N, 9.0)))])
    assert err.value.reason is Reason.POSITION_LIMIT
    assert [(c.queue_fill, c.queue.scale, c.points_accepted) for c in (a, b)] == before
    plan = a.prepare(full(0.42, z + 0.84), first=False)
    a.commit(plan)
    assert a.queue.scale == Controller.plan_scale(plan) > 1.0


def test_the_first_point_is_the_start_itself_whatever_its_duration() -> None:
    """industrial_robot_client gives every trajectory's first point a 10 s duration: no policy
    waits 10 s for it (ABB's server skips a first point at the current position too)."""
    for policy in POLICIES:
        ctl = controller(policy)
        ctl.start(pt(np.zeros(N), ratio=0.0, duration=10.0))
        assert ctl.queue_fill == 0 and not ctl.moving
        ctl.add(pt(np.full(N, 0.2), duration=0.5))
        run(ctl, 0.02)
        assert np.all(np.array(ctl.command.command_position) > 0.0), policy  # moving at once


def test_every_policy_reaches_every_point_within_the_limits() -> None:
    targets = [np.zeros(N), np.full(N, 0.8), np.array([-0.5, 0.3, 1.0, -1.0, 0.7, 2.0]), np.zeros(N)]
    for name, policy in POLICIES.items():
        ctl = controller(name)
        ctl.start(pt(targets[0]))
        for target in targets[1:]:
            ctl.add(pt(target, ratio=0.8))
        rec = run(ctl, 8.0)
        assert not ctl.in_motion and ctl.queue_fill == 0 and not ctl.in_error
        assert np.allclose(ctl.command.command_position, targets[-1], atol=1e-12)
        assert np.allclose(ctl.command.actual_position, targets[-1], atol=1e-3)
        vel = np.abs(rec.get("command_velocity"))
        # the ratio caps the rest-to-rest policies' peak speed; for blend it is the mean speed
        assert np.all(vel <= VMAX * (1.0 if policy.passes_through else 0.8) * (1 + 1e-9))
        if name != "linear":
            assert np.all(np.abs(rec.get("command_acceleration")) <= AMAX * (1 + 1e-9))


def test_full_points_choose_the_segment_by_their_fields() -> None:
    ctl = controller("linear")  # the policy does not apply to points with velocities
    z = np.zeros(N)
    ctl.start(full(0.0, z, z, z))
    ctl.add(full(1.0, np.full(N, 0.2), np.full(N, 0.3), np.full(N, 0.1)))
    ctl.add(full(2.0, np.full(N, 0.5), np.full(N, 0.2)))
    ctl.add(full(3.0, np.full(N, 0.6)))
    ctl.add(full(4.0, np.full(N, 0.6), z, z))
    segments = ctl.queue.segments()
    assert [s.kind for s in segments] == ["quintic", "cubic", "linear", "linear"]
    assert [s.duration for s in segments] == [1.0, 1.0, 1.0, 1.0]
    # the quintic and the cubic pass through the given velocities
    quintic_end = segments[0].end()
    assert np.allclose(quintic_end.velocity, 0.3) and np.allclose(quintic_end.acceleration, 0.1)
    assert np.allclose(segments[1].end().velocity, 0.2)


def test_full_points_need_time_and_positions_and_increasing_times() -> None:
    ctl = controller()
    z = np.zeros(N)
    with pytest.raises(PointRejected) as err:
        ctl.start(full(0.0, None, z))
    assert err.value.reason is Reason.MISSING_FIELDS
    ctl.start(full(0.0, z))
    ctl.add(full(1.0, np.full(N, 0.1)))
    with pytest.raises(PointRejected) as err:
        ctl.add(full(1.0, np.full(N, 0.2)))
    assert err.value.reason is Reason.TIMING
    assert ctl.queue_fill == 1


@pytest.mark.parametrize(
    ("policy", "point", "reason"),
    [
        ("quintic", pt([4.0, 0, 0, 0, 0, 0]), Reason.POSITION_LIMIT),
        ("blend", pt([4.0, 0, 0, 0, 0, 0]), Reason.POSITION_LIMIT),
        ("blend", pt([math.nan, 0, 0, 0, 0, 0]), Reason.NOT_FINITE),
        ("blend", pt([2.5, 0, 0, 0, 0, math.inf]), Reason.NOT_FINITE),
        ("blend", pt([2.5] + [0.0] * (N - 2)), Reason.JOINT_COUNT),
        ("quintic", pt([1.5, 0, 0, 0, 0, 0], duration=0.2), Reason.VELOCITY_LIMIT),  # quintic peak 9.4 rad/s
        ("quintic", pt([2.7, 0, 0, 0, 0, 0], duration=0.2), Reason.ACCELERATION_LIMIT),  # 28.9 rad/s^2
        ("quintic", pt([2.6, 0, 0, 0, 0, 0], ratio=0.0), Reason.TIMING),
        ("blend", pt([2.6, 0, 0, 0, 0, 0], ratio=0.0), Reason.TIMING),  # no duration, no speed
        ("blend", pt([2.6, 0, 0, 0, 0, 0], ratio=1.5), Reason.VELOCITY_LIMIT),
        ("blend", pt([2.6, 0, 0, 0, 0, 0], ratio=-0.5), Reason.TIMING),
        ("blend", pt([2.6, 0, 0, 0, 0, 0], duration=-1.0), Reason.TIMING),
        ("blend", pt([2.6, 0, 0, 0, 0, 0], duration=1e9), Reason.TIMING),  # beyond max_segment_time
        ("blend", pt([2.6, 0, 0, 0, 0, 0], duration=1e-9), Reason.TIMING),  # below MIN_DURATION
        ("blend", pt([2.6, 0, 0, 0, 0, 0], ratio=1e-6), Reason.TIMING),  # a computed time beyond the maximum
        ("quintic", pt([2.6, 0, 0, 0, 0, 0], ratio=1e-6), Reason.TIMING),
        ("blend", full(1.0, [2.5, 0, 0, 0, 0, 0], [9.0] * N), Reason.VELOCITY_LIMIT),
        ("blend", full(-1.0, [2.5, 0, 0, 0, 0, 0]), Reason.TIMING),
        ("blend", full(5000.0, [2.5, 0, 0, 0, 0, 0]), Reason.TIMING),  # 5000 s after the last point
        # a cubic Hermite that overshoots the position limit between two points inside it
        ("blend", full(1.0, [2.9, 0, 0, 0, 0, 0], [-3.0, 0, 0, 0, 0, 0]), Reason.POSITION_LIMIT),
    ],
)
def test_bad_points_are_rejected_before_anything_moves(policy: str, point: Point, reason: Reason) -> None:
    start = (2.5, 0.0, 0.0, 0.0, 0.0, 0.0)
    ctl = controller(policy, initial_position=start)
    ctl.start(full(0.0, start, np.zeros(N), np.zeros(N)) if point.time is not None else pt(start))
    before = ctl.queue_fill
    with pytest.raises(PointRejected) as err:
        ctl.add(point)
    assert err.value.reason is reason
    assert ctl.queue_fill == before
    run(ctl, 0.2)
    assert not ctl.in_motion
    assert np.allclose(ctl.command.actual_position, ctl.command.command_position, atol=1e-12)


def test_first_point_must_match_the_current_position() -> None:
    ctl = controller(initial_position=(0.5, 0, 0, 0, 0, 0))
    with pytest.raises(PointRejected) as err:
        ctl.start(pt(np.zeros(N)))
    assert err.value.reason is Reason.START_MISMATCH and err.value.joint == 0
    ctl.start(pt([0.505, 0, 0, 0, 0, 0]))  # within the default 0.01 rad
    ctl.add(pt([0.6, 0, 0, 0, 0, 0], ratio=1.0))
    # with the check off, a first point away from the robot is a segment from where it is
    loose = controller(start_tolerance=None)
    loose.start(pt([0.3] * N, duration=1.0))
    assert loose.queue_fill == 1
    run(loose, 1.5)
    assert np.allclose(loose.command.command_position, 0.3, atol=1e-12)


def test_streaming_queue_is_bounded_and_reports_its_fill() -> None:
    ctl = controller(queue_capacity=4)
    ctl.start(pt(np.zeros(N)))
    for i in range(1, 5):
        ctl.add(pt(np.full(N, 0.1 * i), duration=0.5))
    assert ctl.queue_fill == 4 == ctl.queue_capacity
    with pytest.raises(PointRejected) as err:
        ctl.add(pt(np.full(N, 0.5), duration=0.5))
    assert err.value.reason is Reason.QUEUE_FULL
    run(ctl, 0.6)
    assert ctl.queue_fill == 3
    ctl.add(pt(np.full(N, 0.5), duration=0.5))  # room again: the same point is accepted
    run(ctl, 2.5)
    assert ctl.queue_fill == 0 and np.allclose(ctl.command.command_position, 0.5, atol=1e-12)


def test_streaming_while_moving_appends_without_a_pause() -> None:
    ctl = controller("linear")
    ctl.start(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.5), duration=1.0))
    run(ctl, 0.5)
    ctl.add(pt(np.full(N, 1.0), duration=1.0))
    rec = run(ctl, 1.0)
    # constant 0.5 rad/s through the join at t = 1.0 s: no stop between streamed points
    assert np.allclose(interpolation_samples(ctl, rec, "command_velocity"), 0.5, atol=1e-9)


@pytest.mark.parametrize("policy", ["quintic", "blend"])
def test_download_runs_only_after_the_end_marker(policy: str) -> None:
    ctl = controller(policy)
    ctl.start_download(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.3), duration=0.5))
    ctl.add(pt(np.full(N, 0.6), duration=0.5))
    assert ctl.downloading and ctl.queue_fill == 0
    run(ctl, 0.3)
    assert np.allclose(ctl.command.command_position, 0.0) and not ctl.in_motion
    ctl.finish_download(pt(np.full(N, 0.2), duration=0.5))
    assert not ctl.downloading and ctl.queue_fill == 3 and ctl.in_motion
    run(ctl, 2.0)
    assert np.allclose(ctl.command.command_position, 0.2, atol=1e-12)
    small = controller(policy, download_capacity=3)  # the buffer holds the first point and two more
    small.start_download(pt(np.zeros(N)))
    small.add(pt(np.full(N, 0.1), duration=0.5))
    small.add(pt(np.full(N, 0.2), duration=0.5))
    with pytest.raises(PointRejected) as err:
        small.finish_download(pt(np.full(N, 0.3), duration=0.5))
    assert err.value.reason is Reason.QUEUE_FULL and not small.downloading


def test_a_refused_download_point_drops_the_whole_download() -> None:
    ctl = controller()
    ctl.start_download(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.3), duration=0.5))
    with pytest.raises(PointRejected):
        ctl.add(pt(np.full(N, 9.0), duration=0.5))  # beyond the position limits
    assert not ctl.downloading
    # a point refused only when the download is planned (too fast for the quintic) drops it too
    ctl.start_download(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.3), duration=0.5))
    with pytest.raises(PointRejected) as err:
        ctl.finish_download(pt(np.full(N, 2.0), duration=0.1))
    assert err.value.reason is Reason.VELOCITY_LIMIT and not ctl.downloading and ctl.queue_fill == 0
    run(ctl, 0.5)
    assert not ctl.in_motion


# -- stop --------------------------------------------------------------------------------------


def full_speed_controller() -> Controller:
    ctl = controller("ruckig", initial_position=(-2.0,) * N)
    ctl.start(pt(ctl.command.command_position))
    ctl.add(pt(np.full(N, 2.0), ratio=1.0))
    run(ctl, 0.6)  # ruckig reaches pi rad/s after ~0.33 s
    assert np.allclose(ctl.command.command_velocity, VMAX)
    return ctl


def test_stop_from_full_speed_in_every_joint() -> None:
    ctl = full_speed_controller()
    predicted = ctl.stop()
    assert predicted > 0.3 and ctl.queue_fill == 0 and ctl.moving  # only the deceleration remains
    before = ctl.command.command_position
    rec = run(ctl, predicted + 0.1)
    vel = interpolation_samples(ctl, rec, "command_velocity")
    acc = interpolation_samples(ctl, rec, "command_acceleration")
    times = interpolation_samples(ctl, rec, "command_position")  # positions at the same instants
    assert np.all(np.abs(vel) <= VMAX * (1 + 1e-9)) and np.all(np.abs(acc) <= AMAX * (1 + 1e-9))
    jerk = np.diff(acc, axis=0) / ctl.config.interpolation_period
    assert np.all(np.abs(jerk) <= JMAX * (1 + 1e-6))
    assert np.all(np.abs(np.diff(times, axis=0)) <= VMAX * ctl.config.interpolation_period * (1 + 1e-9))
    # at rest within the predicted time (to the next interpolation instant), then nothing is queued
    sub = round(ctl.config.interpolation_period / ctl.config.servo_period)
    t = rec.time()[sub - 1 :: sub]
    moving = np.any(np.abs(vel) > 1e-9, axis=1)
    last_moving = t[np.flatnonzero(moving)[-1]] - t[0] if moving.any() else 0.0
    assert last_moving <= predicted + ctl.config.interpolation_period
    assert ctl.queue_fill == 0 and not ctl.moving
    # decelerating, not jumping: it went on in the direction of travel
    assert np.all(np.array(ctl.command.command_position) > np.array(before))
    run(ctl, 0.3)
    assert not ctl.in_motion


def test_stop_while_idle_and_the_next_trajectory() -> None:
    ctl = controller()
    assert ctl.stop() == 0.0
    ctl.start(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.4), ratio=1.0))
    run(ctl, 0.2)
    ctl.stop()
    run(ctl, 1.0)
    stopped_at = ctl.command.command_position
    assert 0.0 < stopped_at[0] < 0.4 and ctl.queue_fill == 0
    with pytest.raises(PointRejected) as err:  # a new trajectory starts where the robot stopped
        ctl.start(pt(np.zeros(N)))
    assert err.value.reason is Reason.START_MISMATCH
    with pytest.raises(PointRejected) as err:  # so does the next point after a stop, whatever it says
        ctl.add(pt(np.zeros(N)))
    assert err.value.reason is Reason.START_MISMATCH
    ctl.start(pt(stopped_at))
    ctl.add(pt(np.zeros(N), ratio=1.0))
    run(ctl, 2.0)
    assert np.allclose(ctl.command.command_position, 0.0, atol=1e-12)


def test_a_queue_running_dry_in_motion_decelerates() -> None:
    ctl = controller()
    z = np.zeros(N)
    ctl.start(full(0.0, z, z, z))
    ctl.add(full(1.0, np.full(N, 0.5), np.full(N, 1.0), z))  # ends moving at 1 rad/s
    rec = run(ctl, 2.0)
    assert not ctl.moving
    acc = interpolation_samples(ctl, rec, "command_acceleration")
    assert np.all(np.abs(acc) <= AMAX * (1 + 1e-9))
    assert np.all(np.array(ctl.command.command_position) > 0.5)  # past the point, at rest


# -- servo drives and alarms -------------------------------------------------------------------


def test_drives_follow_a_quintic_move_within_the_following_error() -> None:
    ctl = controller()
    ctl.start(pt(np.zeros(N)))
    ctl.add(pt([2.0, 1.5, 2.0, 2.5, 1.5, 3.0], ratio=1.0))
    rec = run(ctl, 3.0)
    error = np.abs(rec.get("following_error")).max(axis=0)
    limits = np.array([MODEL.motor(i).following_error_limit for i in range(N)])
    assert np.all(error < limits)
    assert np.all(error > 1e-4)  # a real drive lags: the model is not a copy of the command
    # at full speed the error is about (1 - k_ff) v / Kp, a few mrad: a few mm at the flange
    assert 0.002 < error.max() < 0.02
    assert not ctl.in_error and not ctl.in_motion


def test_a_move_faster_than_the_motors_raises_the_following_error_alarm() -> None:
    weak = [dataclasses.replace(MODEL.motor(i), max_current=0.2) for i in range(N)]
    model = dataclasses.replace(MODEL, motors=tuple(weak))
    ctl = Controller(model, ControllerConfig(policy="quintic"))
    ctl.start(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 1.5), ratio=1.0))
    run(ctl, 2.0)
    assert ctl.in_error and FOLLOWING_ERROR_ALARM < ctl.error_code <= FOLLOWING_ERROR_ALARM + N
    assert ctl.queue_fill == 0 and "following error" in ctl.error_message
    with pytest.raises(PointRejected) as err:
        ctl.start(pt(ctl.command.actual_position))
    assert err.value.reason is Reason.NOT_READY
    run(ctl, 1.0)
    assert not ctl.in_motion  # held where it stopped
    ctl.reset()
    ctl.start(pt(ctl.command.command_position))


def test_motor_parameters_from_the_model_file(tmp_path: object) -> None:
    assert MODEL.motor(5).gear_ratio == 50 and MODEL.motor(0).load_inertia == 0.4
    assert load_model("puma560").motor(0) == MotorParameters()
    path = tmp_path / "bad.toml"  # type: ignore[operator]
    text = (MODEL_FILE := load_text("jibot_zxs.toml")).replace("gear_ratio             = [100,", "gear_ratio = [-1,")
    path.write_text(text)
    with pytest.raises(ModelError, match=r"\[motors\] joint 1: motor parameter gear_ratio"):
        load_model(path)
    path.write_text(MODEL_FILE.replace("[motors]", "[motors]\nbrake_torque = [1, 1, 1, 1, 1, 1]"))
    with pytest.raises(ModelError, match=r"\[motors\] brake_torque: unknown key"):
        load_model(path)


def load_text(name: str) -> str:
    from importlib import resources

    return (resources.files("robot_server") / "models" / name).read_text()


# -- clocks, determinism, recorder --------------------------------------------------------------


def scripted_run() -> Recorder:
    async def main() -> Recorder:
        ctl = controller("ruckig")
        rec = Recorder(N, capacity=5000)
        loop = ControlLoop(ctl, SimulatedClock(), rec)
        ctl.start(pt(np.zeros(N)))
        ctl.add(pt([0.5, -0.3, 0.8, 1.0, -0.6, 2.0], ratio=0.7))
        await loop.run(0.5)
        ctl.add(pt(np.zeros(N), ratio=1.0))
        await loop.run(0.5)
        ctl.stop()
        await loop.run(1.0)
        return rec

    return asyncio.run(main())


def test_simulated_runs_are_deterministic() -> None:
    a, b = scripted_run(), scripted_run()
    assert len(a) == 2000
    assert np.array_equal(a.time(), b.time())
    for quantity in ("command_position", "actual_position", "actual_velocity", "following_error"):
        assert np.array_equal(a.get(quantity), b.get(quantity))


class FakeTime:
    """The monotonic clock and the sleep of :mod:`robot_server.control.clock`, moved by the test:
    a sleep of ``d`` seconds moves the time ``d`` plus the next scripted lateness on, at once (it
    still yields to the event loop). No wall-clock time is measured or waited for."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, lateness: tuple[float, ...] = ()) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []
        self.lateness = list(lateness)
        monkeypatch.setattr(clock_module, "time", SimpleNamespace(monotonic=lambda: self.now))
        monkeypatch.setattr(clock_module, "asyncio", SimpleNamespace(sleep=self.sleep))

    async def sleep(self, delay: float) -> None:
        self.sleeps.append(delay)
        self.now += delay + (self.lateness.pop(0) if self.lateness else 0.0)
        await asyncio.sleep(0)


async def test_simulated_clock_never_waits(monkeypatch: pytest.MonkeyPatch) -> None:
    """The simulated clock jumps to each deadline: the loop only yields to the event loop, so it
    runs as fast as the computer can (how fast is bench/controller.py's figure, not a test's)."""
    fake = FakeTime(monkeypatch)
    ctl = controller()
    stats = await run_simulated(ctl, 2.0)
    assert stats.ticks == 2000 and stats.wakes == 500 and stats.simulated == pytest.approx(2.0)
    assert stats.overruns == 0 and stats.max_lateness == 0.0  # lateness means nothing off the wall clock
    assert ctl.time == pytest.approx(2.0)
    assert fake.sleeps == [0] * 500 and fake.now == 100.0


async def test_real_time_clock_follows_the_monotonic_clock_sped_up(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = FakeTime(monkeypatch)
    clock = RealTimeClock(speedup=50.0)
    assert clock.realtime and clock.now() == 0.0
    fake.now += 0.01
    assert clock.now() == pytest.approx(0.5)
    await clock.sleep_until(1.5)  # 1 s of controller time ahead: 20 ms of monotonic time
    assert fake.sleeps == [pytest.approx(0.02)] and clock.now() == pytest.approx(1.5)
    await clock.sleep_until(1.0)  # passed: no wait, but other tasks still run
    assert fake.sleeps[-1] == 0.0 and clock.now() == pytest.approx(1.5)
    with pytest.raises(ValueError, match="speed-up"):
        RealTimeClock(speedup=0.0)


async def test_real_time_loop_keeps_absolute_deadlines(monkeypatch: pytest.MonkeyPatch) -> None:
    """Wake-ups late by scripted amounts (one of 2.5 periods): every servo tick still runs, a late
    wake-up catches the missed ticks up, the next deadlines do not move (no drift), and the
    lateness and overruns are counted. (The lateness a real machine gives is bench/controller.py's
    figure.)"""
    period = 0.004
    fake = FakeTime(monkeypatch, lateness=(0.0, 0.001, 0.0, 0.0102, 0.0, 0.0, 0.0, 0.0005, 0.0, 0.0))
    monkeypatch.setattr(
        loop_module, "time", SimpleNamespace(monotonic=lambda: fake.now, perf_counter=time.perf_counter)
    )
    ctl = controller()
    clock = RealTimeClock()
    wakes: list[tuple[float, float]] = []
    loop = ControlLoop(ctl, clock, on_wake=lambda: wakes.append((clock.now(), ctl.time)))
    stats = await loop.run(10 * period)
    assert stats.ticks == 40 and stats.wakes == 10 and ctl.time == pytest.approx(10 * period)
    # wake-up k happens at its deadline k x period plus its own lateness only, and has run the
    # ticks up to the next deadline, however late the wake-ups before it were
    lateness = [0.0, 0.001, 0.0, 0.0102, 0.0062, 0.0022, 0.0, 0.0005, 0.0, 0.0]
    assert [w for w, _ in wakes] == pytest.approx([k * period + late for k, late in enumerate(lateness)], abs=1e-12)
    assert [t for _, t in wakes] == pytest.approx([(k + 1) * period for k in range(10)], abs=1e-12)
    assert fake.sleeps == pytest.approx([0.0, 0.004, 0.003, 0.004, 0.0, 0.0, 0.0018, 0.004, 0.0035, 0.004], abs=1e-12)
    assert stats.overruns == 2  # 10.2 and 6.2 ms late: more than one period
    assert stats.max_lateness == pytest.approx(0.0102) and stats.final_lateness == pytest.approx(0.0, abs=1e-12)
    # each overrun kept with the monotonic time it came (the fake's: origin 100 s) and its lateness
    assert [value for pair in stats.late_wakes for value in pair] == pytest.approx(
        [100.0 + 3 * period + 0.0102, 0.0102, 100.0 + 4 * period + 0.0062, 0.0062]
    )
    assert overrun_times(stats) == "100.022200 +10.200 ms, 100.022200 +6.200 ms"


async def test_loop_stop() -> None:
    ctl = controller()

    class StopAfter(Recorder):
        def add(self, tick: Tick) -> None:
            super().add(tick)
            if len(self) == 40:
                endless.stop()

    endless = ControlLoop(ctl, SimulatedClock(), StopAfter(N))
    stats = await endless.run(1.0)  # stopped long before 1 s
    assert stats.ticks == 40 and stats.wakes == 10 and stats.simulated == pytest.approx(0.04)
    assert ctl.time == pytest.approx(0.04)


def test_recorder_is_bounded_and_exports_csv() -> None:
    ctl = controller()
    rec = Recorder(N, capacity=100)
    ctl.start(pt(np.zeros(N)))
    ctl.add(pt(np.full(N, 0.1), ratio=1.0))
    ctl.run_for(0.25, rec)
    assert len(rec) == 100 and rec.dropped == 150
    assert rec.time()[0] == pytest.approx(0.151) and rec.time()[-1] == pytest.approx(0.25)
    out = io.StringIO()
    rec.to_csv(out, MODEL.joint_names)
    lines = out.getvalue().splitlines()
    assert len(lines) == 101
    assert lines[0].startswith("time,joint_1,") and f",joint_{N}.velocity," in lines[0]
    assert ",record.controller_time,record.points,tool.command_x," in lines[0]
    assert lines[0].endswith(",tool.actual_speed,tool.time")
    header = lines[0].split(",")
    assert len(lines[1].split(",")) == len(header) == 1 + 7 * N + 2 + 17
    row = lines[1].split(",")
    assert lines[1].startswith("0.0,") and row[header.index("record.controller_time")] == repr(float(rec.time()[0]))
    assert row[header.index("record.points")] == "2" and list(rec.points()) == [2] * 100  # both arrived before
    # the tool as of the last interpolation instant (every 4 ms): the TCP of the commanded joints
    tool_time = float(row[header.index("tool.time")])
    assert rec.time()[0] - 0.004 < tool_time <= rec.time()[0]
    tcp = [float(row[header.index(f"tool.command_{a}")]) for a in "xyz"]
    assert all(np.isfinite(tcp))
    every_tenth = Recorder(N, capacity=100, decimation=10)
    ctl.run_for(0.1, every_tenth)
    assert len(every_tenth) == 10


def test_config_is_validated() -> None:
    with pytest.raises(ValueError, match="whole multiple"):
        ControllerConfig(interpolation_period=0.0045)
    with pytest.raises(ValueError, match="initial position"):
        controller(initial_position=(9.0, 0, 0, 0, 0, 0))


def test_loop_stats_keep_the_latest_overruns_only() -> None:
    """A long run's overruns do not grow the stats: the last OVERRUNS_KEPT are kept, oldest first."""
    stats = LoopStats()
    for k in range(OVERRUNS_KEPT + 10):
        loop_module._late(stats, 0.005 + k * 1e-6, 0.004)
    loop_module._late(stats, 0.003, 0.004)  # late, but within a period: not an overrun
    assert stats.overruns == OVERRUNS_KEPT + 10 and len(stats.late_wakes) == OVERRUNS_KEPT
    assert [late for _, late in stats.late_wakes] == pytest.approx(
        [0.005 + k * 1e-6 for k in range(10, OVERRUNS_KEPT + 10)]
    )
    assert overrun_times(LoopStats()) == ""
