"""The controller layer: trajectory semantics, queue, stop, servo drives, alarms, clocks, recorder."""

from __future__ import annotations

import asyncio
import dataclasses
import io
import math

import numpy as np
import pytest

from robot_server.control import (
    FOLLOWING_ERROR_ALARM,
    Controller,
    ControllerConfig,
    ControlLoop,
    Point,
    PointRejected,
    Policy,
    RealTimeClock,
    Reason,
    Recorder,
    SimulatedClock,
    Tick,
    point_from_message,
    run_simulated,
)
from robot_server.loader import load_model
from robot_server.model import ModelError, MotorParameters
from simple_message.constants import ValidFields
from simple_message.messages import JointTrajPt, JointTrajPtFull

MODEL = load_model("jibot_zxs")
N = MODEL.dof
VMAX, AMAX, JMAX = MODEL.max_velocity, MODEL.max_acceleration, MODEL.max_jerk


def controller(policy: Policy = Policy.QUINTIC, **options: object) -> Controller:
    return Controller(MODEL, ControllerConfig(policy=policy, **options))  # type: ignore[arg-type]


def pt(seq: int, positions: object, ratio: float = 1.0, duration: float = 0.0) -> Point:
    return Point(seq, np.array(positions, dtype=float), velocity_ratio=ratio, duration=duration)


def full(seq: int, time: float, p: object, v: object = None, a: object = None) -> Point:
    arr = [None if x is None else np.array(x, dtype=float) for x in (p, v, a)]
    return Point(seq, arr[0], arr[1], arr[2], time=time)


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
    ctl = controller(Policy.QUINTIC)
    ctl.submit(pt(0, np.zeros(N)))
    ctl.submit(pt(1, np.full(N, 0.5), duration=2.0))
    assert ctl._queue[-1].duration == 2.0
    ctl.submit(pt(2, np.zeros(N), ratio=0.5))
    # quintic peak speed is 1.875 D / T: at half of pi rad/s, T = 1.875 * 0.5 / (0.5 * pi)
    expected = max(1.875 * 0.5 / (0.5 * math.pi), math.sqrt(10 / math.sqrt(3) * 0.5 / AMAX[0]))
    assert math.isclose(ctl._queue[-1].duration, expected)
    assert ctl.queue_fill == 2
    for policy, factor in ((Policy.LINEAR, 1.0), (Policy.CUBIC, 1.5)):
        c = controller(policy)
        c.submit(pt(0, np.zeros(N)))
        c.submit(pt(1, [1.0, 0, 0, 0, 0, 0], ratio=1.0))
        accel = 0.0 if policy is Policy.LINEAR else math.sqrt(6.0 / AMAX[0])
        assert math.isclose(c._queue[-1].duration, max(factor / math.pi, accel))


def test_every_policy_reaches_every_point_within_the_limits() -> None:
    targets = [np.zeros(N), np.full(N, 0.8), np.array([-0.5, 0.3, 1.0, -1.0, 0.7, 2.0]), np.zeros(N)]
    for policy in Policy:
        ctl = controller(policy)
        for i, target in enumerate(targets):
            ctl.submit(pt(i, target, ratio=0.8))
        rec = run(ctl, 8.0)
        assert not ctl.in_motion and ctl.queue_fill == 0 and not ctl.in_error
        assert np.allclose(ctl.command.command_position, targets[-1], atol=1e-12)
        assert np.allclose(ctl.command.actual_position, targets[-1], atol=1e-3)
        vel = np.abs(rec.get("command_velocity"))
        assert np.all(vel <= VMAX * 0.8 * (1 + 1e-9))
        if policy is not Policy.LINEAR:
            assert np.all(np.abs(rec.get("command_acceleration")) <= AMAX * (1 + 1e-9))


def test_full_points_choose_the_segment_by_their_fields() -> None:
    ctl = controller(Policy.LINEAR)  # the policy does not apply to JOINT_TRAJ_PT_FULL
    z = np.zeros(N)
    ctl.submit(full(0, 0.0, z, z, z))
    ctl.submit(full(1, 1.0, np.full(N, 0.2), np.full(N, 0.3), np.full(N, 0.1)))
    ctl.submit(full(2, 2.0, np.full(N, 0.5), np.full(N, 0.2)))
    ctl.submit(full(3, 3.0, np.full(N, 0.6)))
    ctl.submit(full(4, 4.0, np.full(N, 0.6), z, z))
    assert [s.kind for s in ctl._queue] == ["quintic", "cubic", "linear", "linear"]
    assert [s.duration for s in ctl._queue] == [1.0, 1.0, 1.0, 1.0]
    # the quintic and the cubic pass through the given velocities
    quintic_end = ctl._queue[0].end()
    assert np.allclose(quintic_end.velocity, 0.3) and np.allclose(quintic_end.acceleration, 0.1)
    assert np.allclose(ctl._queue[1].end().velocity, 0.2)


def test_full_points_need_time_and_positions_and_increasing_times() -> None:
    ctl = controller()
    z = np.zeros(N)
    no_time = JointTrajPtFull(sequence=0, valid_fields=ValidFields.POSITION)
    with pytest.raises(PointRejected) as err:
        ctl.submit(point_from_message(no_time, N))
    assert err.value.reason is Reason.MISSING_FIELDS
    with pytest.raises(PointRejected) as err:
        ctl.submit(full(0, 0.0, None, z))
    assert err.value.reason is Reason.MISSING_FIELDS
    ctl.submit(full(0, 0.0, z))
    ctl.submit(full(1, 1.0, np.full(N, 0.1)))
    with pytest.raises(PointRejected) as err:
        ctl.submit(full(2, 1.0, np.full(N, 0.2)))
    assert err.value.reason is Reason.TIMING
    assert ctl.queue_fill == 1


def test_point_from_message() -> None:
    msg = JointTrajPt(sequence=3, joint_data=[0.1] * N + [0.0] * 4, velocity=0.5, duration=0.2)
    point = point_from_message(msg, N)
    assert point.sequence == 3 and np.allclose(point.positions, 0.1)
    assert point.velocity_ratio == pytest.approx(0.5) and point.duration == pytest.approx(0.2)
    valid = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
    msg_full = JointTrajPtFull(sequence=1, valid_fields=valid, time=1.5, positions=[0.2] * 10, velocities=[0.0] * 10)
    with pytest.raises(PointRejected) as err:  # values in slots 7..10 for a 6-joint robot
        point_from_message(msg_full, N)
    assert err.value.reason is Reason.JOINT_COUNT and "10 joints" in str(err.value)
    msg_full = dataclasses.replace(msg_full, positions=[0.2] * N + [0.0] * 4)
    point = point_from_message(msg_full, N)
    assert point.time == 1.5 and point.accelerations is None and point.velocities is not None
    stop = point_from_message(JointTrajPt(sequence=-4, joint_data=[math.nan] * 10), N)
    assert stop.sequence == -4 and stop.positions is None


@pytest.mark.parametrize(
    ("point", "reason"),
    [
        (pt(1, [4.0, 0, 0, 0, 0, 0]), Reason.POSITION_LIMIT),
        (pt(1, [math.nan, 0, 0, 0, 0, 0]), Reason.NOT_FINITE),
        (pt(1, [2.5, 0, 0, 0, 0, math.inf]), Reason.NOT_FINITE),
        (pt(1, [2.5] + [0.0] * (N - 2)), Reason.JOINT_COUNT),
        (pt(1, [1.5, 0, 0, 0, 0, 0], duration=0.2), Reason.VELOCITY_LIMIT),  # quintic peak 9.4 rad/s
        (pt(1, [2.7, 0, 0, 0, 0, 0], duration=0.2), Reason.ACCELERATION_LIMIT),  # 28.9 rad/s^2
        (pt(1, [2.6, 0, 0, 0, 0, 0], ratio=0.0), Reason.TIMING),
        (pt(1, [2.6, 0, 0, 0, 0, 0], ratio=1.5), Reason.VELOCITY_LIMIT),
        (full(1, 1.0, [2.5, 0, 0, 0, 0, 0], [9.0] * N), Reason.VELOCITY_LIMIT),
        (full(1, 1.0, [2.5, 0, 0, 0, 0, 0], [0.0] * N, [90.0] * N), Reason.ACCELERATION_LIMIT),
        # a cubic Hermite that overshoots the position limit between two points inside it
        (full(1, 1.0, [2.9, 0, 0, 0, 0, 0], [-3.0, 0, 0, 0, 0, 0]), Reason.POSITION_LIMIT),
        (pt(-7, [0.1] * N), Reason.SEQUENCE),
        (pt(-3, [0.1] * N), Reason.SEQUENCE),
    ],
)
def test_bad_points_are_rejected_before_anything_moves(point: Point, reason: Reason) -> None:
    start = (2.5, 0.0, 0.0, 0.0, 0.0, 0.0)
    ctl = controller(initial_position=start)
    ctl.submit(full(0, 0.0, start, np.zeros(N), np.zeros(N)) if point.time is not None else pt(0, start))
    before = ctl.queue_fill
    with pytest.raises(PointRejected) as err:
        ctl.submit(point)
    assert err.value.reason is reason
    assert ctl.queue_fill == before
    run(ctl, 0.2)
    assert not ctl.in_motion
    assert np.allclose(ctl.command.actual_position, ctl.command.command_position, atol=1e-12)


def test_first_point_must_match_the_current_position() -> None:
    ctl = controller(initial_position=(0.5, 0, 0, 0, 0, 0))
    with pytest.raises(PointRejected) as err:
        ctl.submit(pt(0, np.zeros(N)))
    assert err.value.reason is Reason.START_MISMATCH and err.value.joint == 0
    ctl.submit(pt(0, [0.505, 0, 0, 0, 0, 0]))  # within the default 0.01 rad
    ctl.submit(pt(1, [0.6, 0, 0, 0, 0, 0], ratio=1.0))
    # with the check off, a first point with a duration is a segment from where the robot is
    loose = controller(start_tolerance=None)
    loose.submit(pt(0, [0.3] * N, duration=1.0))
    assert loose.queue_fill == 1
    run(loose, 1.5)
    assert np.allclose(loose.command.command_position, 0.3, atol=1e-12)


def test_streaming_queue_is_bounded_and_reports_its_fill() -> None:
    ctl = controller(queue_capacity=4)
    ctl.submit(pt(0, np.zeros(N)))
    for i in range(1, 5):
        ctl.submit(pt(i, np.full(N, 0.1 * i), duration=0.5))
    assert ctl.queue_fill == 4 == ctl.queue_capacity
    with pytest.raises(PointRejected) as err:
        ctl.submit(pt(5, np.full(N, 0.5), duration=0.5))
    assert err.value.reason is Reason.QUEUE_FULL
    run(ctl, 0.6)
    assert ctl.queue_fill == 3
    ctl.submit(pt(5, np.full(N, 0.5), duration=0.5))  # room again: the same point is accepted
    run(ctl, 2.5)
    assert ctl.queue_fill == 0 and np.allclose(ctl.command.command_position, 0.5, atol=1e-12)


def test_streaming_while_moving_appends_without_a_pause() -> None:
    ctl = controller(Policy.LINEAR)
    ctl.submit(pt(0, np.zeros(N)))
    ctl.submit(pt(1, np.full(N, 0.5), duration=1.0))
    run(ctl, 0.5)
    ctl.submit(pt(2, np.full(N, 1.0), duration=1.0))
    rec = run(ctl, 1.0)
    # constant 0.5 rad/s through the join at t = 1.0 s: no stop between streamed points
    assert np.allclose(interpolation_samples(ctl, rec, "command_velocity"), 0.5, atol=1e-9)


def test_download_runs_only_after_the_end_marker() -> None:
    ctl = controller()
    ctl.submit(pt(-1, np.zeros(N)))
    ctl.submit(pt(1, np.full(N, 0.3), duration=0.5))
    ctl.submit(pt(2, np.full(N, 0.6), duration=0.5))
    assert ctl.downloading and ctl.queue_fill == 0
    run(ctl, 0.3)
    assert np.allclose(ctl.command.command_position, 0.0) and not ctl.in_motion
    ctl.submit(pt(-3, np.full(N, 0.2), duration=0.5))
    assert not ctl.downloading and ctl.queue_fill == 3 and ctl.in_motion
    run(ctl, 2.0)
    assert np.allclose(ctl.command.command_position, 0.2, atol=1e-12)
    small = controller(download_capacity=2)
    small.submit(pt(-1, np.zeros(N)))
    small.submit(pt(1, np.full(N, 0.1), duration=0.5))
    small.submit(pt(2, np.full(N, 0.2), duration=0.5))
    with pytest.raises(PointRejected) as err:
        small.submit(pt(-3, np.full(N, 0.3), duration=0.5))
    assert err.value.reason is Reason.QUEUE_FULL


# -- stop --------------------------------------------------------------------------------------


def full_speed_controller() -> Controller:
    ctl = controller(Policy.RUCKIG, initial_position=(-2.0,) * N)
    ctl.submit(pt(0, ctl.command.command_position))
    ctl.submit(pt(1, np.full(N, 2.0), ratio=1.0))
    run(ctl, 0.6)  # ruckig reaches pi rad/s after ~0.33 s
    assert np.allclose(ctl.command.command_velocity, VMAX)
    return ctl


def test_stop_from_full_speed_in_every_joint() -> None:
    ctl = full_speed_controller()
    predicted = ctl.stop()
    assert predicted > 0.3 and ctl.queue_fill == 1  # only the deceleration remains
    before = ctl.command.command_position
    rec = run(ctl, predicted + 0.1)
    vel = interpolation_samples(ctl, rec, "command_velocity")
    acc = interpolation_samples(ctl, rec, "command_acceleration")
    times = interpolation_samples(ctl, rec, "command_position")  # positions at the same instants
    assert np.all(np.abs(vel) <= VMAX * (1 + 1e-9)) and np.all(np.abs(acc) <= AMAX * (1 + 1e-9))
    jerk = np.diff(acc, axis=0) / ctl.config.interpolation_period
    assert np.all(np.abs(jerk) <= JMAX * (1 + 1e-6))
    assert np.all(np.abs(np.diff(times, axis=0)) <= VMAX * ctl.config.interpolation_period * (1 + 1e-9))
    # at rest within the predicted time (to the next interpolation instant), then the queue is empty
    sub = round(ctl.config.interpolation_period / ctl.config.servo_period)
    t = rec.time()[sub - 1 :: sub]
    moving = np.any(np.abs(vel) > 1e-9, axis=1)
    last_moving = t[np.flatnonzero(moving)[-1]] - t[0] if moving.any() else 0.0
    assert last_moving <= predicted + ctl.config.interpolation_period
    assert ctl.queue_fill == 0
    # decelerating, not jumping: it went on in the direction of travel
    assert np.all(np.array(ctl.command.command_position) > np.array(before))
    run(ctl, 0.3)
    assert not ctl.in_motion


def test_stop_while_idle_and_the_next_trajectory() -> None:
    ctl = controller()
    assert ctl.stop() == 0.0
    ctl.submit(Point(-4, None))  # STOP as a point
    ctl.submit(pt(0, np.zeros(N)))
    ctl.submit(pt(1, np.full(N, 0.4), ratio=1.0))
    run(ctl, 0.2)
    ctl.submit(Point(-4, None))
    run(ctl, 1.0)
    stopped_at = ctl.command.command_position
    assert 0.0 < stopped_at[0] < 0.4 and ctl.queue_fill == 0
    with pytest.raises(PointRejected) as err:  # a new trajectory starts where the robot stopped
        ctl.submit(pt(0, np.zeros(N)))
    assert err.value.reason is Reason.START_MISMATCH
    ctl.submit(pt(0, stopped_at))
    ctl.submit(pt(1, np.zeros(N), ratio=1.0))
    run(ctl, 2.0)
    assert np.allclose(ctl.command.command_position, 0.0, atol=1e-12)


def test_a_queue_running_dry_in_motion_decelerates() -> None:
    ctl = controller()
    z = np.zeros(N)
    ctl.submit(full(0, 0.0, z, z, z))
    ctl.submit(full(1, 1.0, np.full(N, 0.5), np.full(N, 1.0), z))  # ends moving at 1 rad/s
    rec = run(ctl, 2.0)
    assert not ctl.moving
    acc = interpolation_samples(ctl, rec, "command_acceleration")
    assert np.all(np.abs(acc) <= AMAX * (1 + 1e-9))
    assert np.all(np.array(ctl.command.command_position) > 0.5)  # past the point, at rest


# -- servo drives and alarms -------------------------------------------------------------------


def test_drives_follow_a_quintic_move_within_the_following_error() -> None:
    ctl = controller()
    ctl.submit(pt(0, np.zeros(N)))
    ctl.submit(pt(1, [2.0, 1.5, 2.0, 2.5, 1.5, 3.0], ratio=1.0))
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
    ctl = Controller(model)
    ctl.submit(pt(0, np.zeros(N)))
    ctl.submit(pt(1, np.full(N, 1.5), ratio=1.0))
    run(ctl, 2.0)
    assert ctl.in_error and FOLLOWING_ERROR_ALARM < ctl.error_code <= FOLLOWING_ERROR_ALARM + N
    assert ctl.queue_fill == 0 and "following error" in ctl.error_message
    with pytest.raises(PointRejected) as err:
        ctl.submit(pt(0, ctl.command.actual_position))
    assert err.value.reason is Reason.NOT_READY
    run(ctl, 1.0)
    assert not ctl.in_motion  # held where it stopped
    ctl.reset()
    ctl.submit(pt(0, ctl.command.command_position))


def test_motor_parameters_from_the_model_file(tmp_path: object) -> None:
    assert MODEL.motor(5).gear_ratio == 50 and MODEL.motor(0).load_inertia == 0.4
    assert load_model("puma560").motor(0) == MotorParameters()
    path = tmp_path / "bad.toml"  # type: ignore[operator]
    text = (MODEL_FILE := load_text("jibot_zxs.toml")).replace("gear_ratio             = [100,", "gear_ratio = [-1,")
    path.write_text(text)
    with pytest.raises(ModelError, match=r"\[motors\] joint 1: motor parameter gear_ratio"):
        load_model(path)
    path.write_text(MODEL_FILE.replace("[motors]", "[motors]\nbrake_torque = [1, 1, 1, 1, 1, 1]"))
    with pytest.raises(ModelError, match=r"unknown field.*brake_torque"):
        load_model(path)


def load_text(name: str) -> str:
    from importlib import resources

    return (resources.files("robot_server") / "models" / name).read_text()


# -- clocks, determinism, recorder --------------------------------------------------------------


def scripted_run() -> Recorder:
    async def main() -> Recorder:
        ctl = controller(Policy.RUCKIG)
        rec = Recorder(N, capacity=5000)
        loop = ControlLoop(ctl, SimulatedClock(), rec)
        ctl.submit(pt(0, np.zeros(N)))
        ctl.submit(pt(1, [0.5, -0.3, 0.8, 1.0, -0.6, 2.0], ratio=0.7))
        await loop.run(0.5)
        ctl.submit(pt(2, np.zeros(N), ratio=1.0))
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


async def test_simulated_clock_runs_faster_than_real_time() -> None:
    ctl = controller()
    stats = await run_simulated(ctl, 2.0)
    assert stats.ticks == 2000 and stats.simulated == pytest.approx(2.0) and stats.overruns == 0
    assert ctl.time == pytest.approx(2.0)
    assert stats.realtime_factor > 1.0


@pytest.mark.slow
async def test_real_time_loop_has_no_drift() -> None:
    """10 s of a 1 ms servo loop: every tick ran, and the last wake-up was less than one period late."""
    ctl = controller()
    clock = RealTimeClock()
    stats = await ControlLoop(ctl, clock).run(10.0)
    period = ctl.config.interpolation_period
    assert stats.ticks == 10_000 and ctl.time == pytest.approx(10.0)
    assert 0.0 <= stats.final_lateness < period
    assert abs(clock.now() - 10.0) < period + ctl.config.servo_period
    print(f"overruns {stats.overruns}, max lateness {stats.max_lateness * 1e3:.2f} ms")


async def test_speedup_clock_and_loop_stop() -> None:
    ctl = controller()
    stats = await asyncio.wait_for(ControlLoop(ctl, RealTimeClock(speedup=50.0)).run(0.5), 5)
    assert stats.ticks == 500 and ctl.time == pytest.approx(0.5)

    class StopAfter(Recorder):
        def add(self, tick: Tick) -> None:
            super().add(tick)
            if len(self) == 40:
                endless.stop()

    endless = ControlLoop(ctl, RealTimeClock(speedup=10.0), StopAfter(N))
    stats = await asyncio.wait_for(endless.run(), 5)
    assert stats.ticks == 40 and stats.wakes == 10 and stats.simulated == pytest.approx(0.04)


def test_recorder_is_bounded_and_exports_csv() -> None:
    ctl = controller()
    rec = Recorder(N, capacity=100)
    ctl.submit(pt(0, np.zeros(N)))
    ctl.submit(pt(1, np.full(N, 0.1), ratio=1.0))
    ctl.run_for(0.25, rec)
    assert len(rec) == 100 and rec.dropped == 150
    assert rec.time()[0] == pytest.approx(0.151) and rec.time()[-1] == pytest.approx(0.25)
    out = io.StringIO()
    rec.to_csv(out, MODEL.joint_names)
    lines = out.getvalue().splitlines()
    assert len(lines) == 101
    assert lines[0].startswith("time,command_position_joint_1,") and lines[0].endswith(",points")
    assert len(lines[1].split(",")) == 1 + 7 * N + 1
    assert lines[1].endswith(",2") and list(rec.points()) == [2] * 100  # both points arrived before
    every_tenth = Recorder(N, capacity=100, decimation=10)
    ctl.run_for(0.1, every_tenth)
    assert len(every_tenth) == 10


def test_config_is_validated() -> None:
    with pytest.raises(ValueError, match="whole multiple"):
        ControllerConfig(interpolation_period=0.0045)
    with pytest.raises(ValueError, match="initial position"):
        controller(initial_position=(9.0, 0, 0, 0, 0, 0))
