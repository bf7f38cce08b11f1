"""The motion assertions (robot_server.testing.assertions): they pass on good motion and fail on bad
with a message that says where, when and by how much; records made by a real controller stepped in
process (as bench/motion_identity.py steps one) and synthetic ones whose violations are known."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from robot_server.control.controller import Controller, ControllerConfig, Tick
from robot_server.control.points import Limits, Point
from robot_server.control.recorder import Recorder
from robot_server.kinematics import fk
from robot_server.loader import load_model
from robot_server.model import RobotModel, rot_z
from robot_server.testing.assertions import (
    LimitReport,
    MotionAssertionError,
    Recorded,
    assert_reached,
    assert_stopped_within,
    assert_within_box,
    assert_within_joints,
    assert_within_limits,
)

MODEL = load_model("jibot_zxs")
Q0 = np.clip(np.zeros(MODEL.dof), MODEL.lower, MODEL.upper)
TARGET = Q0 + np.array([1.0, -0.5, 0.4, 0.8, 0.6, -1.0])
#: the controller's clock is stepped: ticks every millisecond, exactly
TICK = 0.001


def run(policy: str = "ruckig", seconds: float = 2.5, stop_at: float | None = None) -> tuple[Recorded, float]:
    """A controller moving from rest at Q0 to TARGET at half speed, recorded tick by tick; with
    ``stop_at``, a STOP at that controller time. Returns the record and the stop's braking time."""
    controller = Controller(MODEL, ControllerConfig(policy=policy))
    record = Recorder(MODEL.dof, capacity=10_000)
    controller.start(Point(Q0, duration=0.0, velocity_ratio=0.5))
    controller.add(Point(TARGET, duration=0.0, velocity_ratio=0.5))
    braking = 0.0
    if stop_at is not None:
        controller.run_for(stop_at, record)
        braking = controller.stop()
        seconds -= stop_at
    controller.run_for(seconds, record)
    return Recorded(record, MODEL), braking


@pytest.fixture(scope="module")
def moved() -> Recorded:
    return run()[0]


def synthetic(
    times: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray | None = None,
    model: RobotModel = MODEL,
) -> Recorded:
    """A record of given positions (and velocities; by default their differences), command and
    actual alike, without a TCP."""
    if velocities is None:
        velocities = np.gradient(positions, times, axis=0)
    record = Recorder(model.dof, capacity=max(1, times.size))
    zeros = [0.0] * model.dof
    for t, q, v in zip(times.tolist(), positions.tolist(), velocities.tolist(), strict=True):
        record.add(Tick(t, q, v, zeros, q, v, zeros, zeros))
    return Recorded(record, model)


def fails(check: object, *args: object, **kwargs: object) -> MotionAssertionError:
    assert callable(check)
    with pytest.raises(MotionAssertionError) as caught:
        check(*args, **kwargs)
    return caught.value


# -- good motion passes ------------------------------------------------------------------------


def test_a_controllers_motion_passes_every_assertion(moved: Recorded) -> None:
    assert_reached(moved, TARGET)
    assert_reached(moved, TARGET, side="both", settled=True)
    assert_reached(moved, {"joint_3": TARGET[2]})
    assert_reached(moved, pose=fk(MODEL, TARGET))  # position and orientation, as a 4x4 transform
    assert_reached(moved, TARGET, pose=fk(MODEL, TARGET)[:3, 3])
    assert_within_joints(moved, MODEL.lower, MODEL.upper, side="both")
    assert_within_joints(moved, np.minimum(Q0, TARGET) - 0.01, np.maximum(Q0, TARGET) + 0.01)
    start, end = fk(MODEL, Q0)[:3, 3], fk(MODEL, TARGET)[:3, 3]
    assert_within_box(moved, np.minimum(start, end) - 0.05, np.maximum(start, end) + 0.05, side="both")
    report = assert_within_limits(moved)
    assert isinstance(report, LimitReport)
    limits = Limits.from_model(MODEL)
    assert np.all(report.velocity <= limits.max_velocity) and np.all(report.velocity > 0)
    assert np.all(report.acceleration <= limits.max_acceleration * (1 + 1e-9))
    assert report.jerk_exceeded == ()  # ruckig keeps the jerk limit
    assert "joint_6" in str(report) and "rad/s³" in str(report)


def test_the_source_is_anything_with_a_record_and_a_model(moved: Recorded) -> None:
    @dataclass
    class Handle:  # as the plugin's controller handle offers them
        record: Recorder
        model: RobotModel

    assert_reached(Handle(moved.record, moved.model), TARGET)


# -- assert_reached --------------------------------------------------------------------------------


def test_reached_fails_naming_the_joint_the_time_and_the_excess(moved: Recorded) -> None:
    wrong = TARGET.copy()
    wrong[2] += 0.01
    error = fails(assert_reached, moved, wrong)
    assert isinstance(error, AssertionError)
    assert error.where == "joint_3" and error.unit == "rad"
    assert error.time == pytest.approx(2.5)
    assert error.excess == pytest.approx(0.009, abs=1e-6)
    text = str(error)
    assert text.startswith("assert_reached: joint_3 actual position ended 0.01 rad from its target at t = 2.5000 s")
    assert "by 0.009 rad beyond it" in text
    assert "it never came within tolerance of the target" in text
    assert "how it ended:" in text
    # one joint of a mapping, and a tolerance wide enough
    assert fails(assert_reached, moved, {"joint_3": wrong[2]}).where == "joint_3"
    assert_reached(moved, wrong, tol=0.011)


def test_reached_at_a_time_says_when_it_was_there(moved: Recorded) -> None:
    # at 0.1 s the robot has barely left Q0: it had been within tolerance of it, then left
    error = fails(assert_reached, moved, Q0, at=0.3)
    assert error.time == pytest.approx(0.3)
    assert "it was within tolerance of the target from t = 0.0010 s to t = " in str(error)
    assert "then left it at t = " in str(error)
    still = fails(assert_reached, moved, TARGET, at=0.5, tol=10.0, settled=True)
    assert "still moving at t = 0.5000 s" in str(still) and still.unit == "rad/s"


def test_reached_checks_the_tcp_position_and_orientation(moved: Recorded) -> None:
    pose = fk(MODEL, TARGET)
    off = fails(assert_reached, moved, pose=pose[:3, 3] + [0.0, 0.0, 0.005])
    assert off.where == "TCP z" and off.unit == "m"
    assert off.excess == pytest.approx(0.004, abs=1e-6)
    assert "the actual TCP ended 0.005 m from the target position at t = 2.5000 s" in str(off)
    assert_reached(moved, pose=pose[:3, 3] + [0.0, 0.0, 0.005], pose_tol=0.006)
    turned = pose @ rot_z(0.01)
    error = fails(assert_reached, moved, pose=turned)
    assert error.where == "TCP orientation"
    assert error.value == pytest.approx(0.01, rel=1e-3)
    assert "ended turned 0.01 rad from the target orientation" in str(error)
    assert_reached(moved, pose=turned, angle_tol=0.011)


def test_reached_refuses_what_it_cannot_check(moved: Recorded) -> None:
    with pytest.raises(TypeError):
        assert_reached(moved)
    with pytest.raises(ValueError, match="no joint 'elbow'"):
        assert_reached(moved, {"elbow": 0.0})
    with pytest.raises(ValueError, match="joints: 3 values"):
        assert_reached(moved, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="pose"):
        assert_reached(moved, pose=[0.0, 0.0])
    with pytest.raises(ValueError, match="side"):
        assert_reached(moved, TARGET, side="planned")  # type: ignore[arg-type]
    with pytest.raises(MotionAssertionError, match="no tick at or before t = -1"):
        assert_reached(moved, TARGET, at=-1.0)


# -- envelopes -------------------------------------------------------------------------------------


def test_within_joints_fails_at_the_first_tick_out_and_says_for_how_long(moved: Recorded) -> None:
    upper = MODEL.upper.copy()
    upper[0] = 0.5
    error = fails(assert_within_joints, moved, MODEL.lower, upper)
    actual = moved.record.get("actual_position")[:, 0]
    times = moved.record.time()
    first = int(np.argmax(actual > 0.5))
    assert error.where == "joint_1"
    assert error.time == times[first]
    assert error.value == actual[first] and error.bound == 0.5
    assert error.excess == pytest.approx(actual[first] - 0.5)
    assert error.duration is None  # it stays beyond the bound to the end
    text = str(error)
    assert f"joint_1 actual position went above the envelope's upper bound at t = {times[first]:.4f} s" in text
    assert "still beyond it at the end of the record" in text
    assert f"by {actual[first] - 0.5:.4g} rad" in text
    assert "*" in text and "excess (rad)" in text  # the table around it
    # a window before the crossing passes
    assert_within_joints(moved, MODEL.lower, upper, end=times[first - 1])


def test_within_joints_excursion_timing_on_a_synthetic_record() -> None:
    times = np.arange(2001) * TICK
    positions = np.zeros((times.size, MODEL.dof))
    positions[(times >= 1.0 - 1e-9) & (times < 1.2 - 1e-9), 4] = -0.3  # joint_5 below -0.2 for 200 ms
    positions[(times >= 1.5 - 1e-9) & (times < 1.6 - 1e-9), 1] = 0.5  # joint_2 above later
    record = synthetic(times, positions)
    error = fails(assert_within_joints, record, -0.2, 0.2)
    assert error.where == "joint_5"
    assert error.time == pytest.approx(1.0)
    assert error.duration == pytest.approx(0.2)
    assert error.excess == pytest.approx(0.1)
    text = str(error)
    assert "joint_5 actual position went below the envelope's lower bound at t = 1.0000 s for 200 ms" in text
    assert "2 excursion(s)" in text and "the largest: joint_2, by 0.3 rad at t = 1.5000 s" in text
    with pytest.raises(ValueError, match="lower is above upper"):
        assert_within_joints(record, 0.2, -0.2)


def test_within_box_names_the_axis(moved: Recorded) -> None:
    tool = moved.record.tool()
    y = tool[:, 9]  # tool.actual_y
    error = fails(assert_within_box, moved, [-1.0, -1.0, -1.0], [1.0, float(np.nanmax(y)) - 0.01, 1.0])
    assert error.where == "TCP y" and error.unit == "m"
    instants = np.isfinite(tool[:, 16])
    crossing = np.flatnonzero(instants & (y > np.nanmax(y) - 0.01))[0]
    assert error.time == pytest.approx(tool[crossing, 16])
    assert "TCP y actual position went above the box's upper side" in str(error)
    commanded = fails(assert_within_box, moved, [-1.0, -1.0, -1.0], [1.0, 1.0, -0.05], side="command")
    assert commanded.where == "TCP z" and "command position" in str(commanded)


def test_within_box_needs_a_tcp() -> None:
    times = np.arange(10) * TICK
    record = synthetic(times, np.zeros((10, MODEL.dof)))
    with pytest.raises(MotionAssertionError, match="no TCP"):
        assert_within_box(record, [-1, -1, -1], [1, 1, 1])


# -- limits ----------------------------------------------------------------------------------------


def test_within_limits_fails_on_the_linear_policys_velocity_steps() -> None:
    """Not interpolated, the velocity steps at every point: the drives are asked for an
    acceleration far beyond the limit (what the paper's Fig. 6 shows)."""
    record, _ = run("linear", seconds=1.5)
    error = fails(assert_within_limits, record)
    assert error.unit == "rad/s²" and error.where in MODEL.joint_names
    assert error.excess is not None and error.excess > 10.0
    text = str(error)
    assert f"{error.where} command acceleration went " in text
    assert "differences of the commanded positions at the interpolation instants" in text
    assert "jerk (reported, not enforced): above the limit" in text


def test_within_limits_position_and_velocity_on_synthetic_records() -> None:
    times = np.arange(1000) * TICK
    positions = np.zeros((times.size, MODEL.dof))
    positions[500:, 1] = MODEL.upper[1] + 0.01  # joint_2 beyond its upper limit from 0.5 s (a jump too)
    error = fails(assert_within_limits, synthetic(times, positions))
    assert error.where == "joint_2" and error.time == pytest.approx(0.5)
    assert "joint_2 command position went above the upper limit at t = 0.5000 s" in str(error)
    assert error.excess == pytest.approx(0.01, rel=1e-3)
    # a joint at 1.5 x its speed limit, from rest by a ramp within the acceleration limit
    speed = 1.5 * MODEL.max_velocity[3]
    velocity = np.minimum(times * MODEL.max_acceleration[3] * 0.9, speed)
    positions = np.zeros((times.size, MODEL.dof))
    positions[:, 3] = np.cumsum(velocity) * TICK
    error = fails(assert_within_limits, synthetic(times, positions))
    assert error.where == "joint_4" and error.unit == "rad/s"
    assert "velocity" in str(error) and "minus the limit" not in str(error)


def test_jerk_is_reported_not_enforced() -> None:
    times = np.arange(1000) * TICK
    acceleration = np.where((times >= 0.2) & (times < 0.5), 5.0, 0.0)  # steps of half the limit: jerk impulses
    positions = np.zeros((times.size, MODEL.dof))
    positions[:, 0] = np.cumsum(np.cumsum(acceleration) * TICK) * TICK
    report = assert_within_limits(synthetic(times, positions))
    assert report.jerk_exceeded == ("joint_1",)
    assert report.jerk[0] > MODEL.max_jerk[0]
    assert report.acceleration[0] == pytest.approx(5.0)


def test_the_actual_side_sees_the_drives_overshoot(moved: Recorded) -> None:
    # the drive's loop catching up at the start of a fast move exceeds the planned acceleration
    error = fails(assert_within_limits, moved, side="actual")
    assert error.unit == "rad/s²" and "actual acceleration went above the limit" in str(error)


# -- stopping --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stopped() -> tuple[Recorded, float, float]:
    record, braking = run(seconds=1.6, stop_at=0.6)
    return record, 0.6, braking


def test_stopped_within_passes_and_says_how_long_it_took(stopped: tuple[Recorded, float, float]) -> None:
    record, since, braking = stopped
    took = assert_stopped_within(record, since, 500)
    assert braking < took < 0.5  # the drives settle after the command has stopped
    assert assert_stopped_within(record, since, braking * 1000 + 1, side="command") <= braking + 0.005


def test_stopped_within_fails_naming_the_joint_and_how_late(stopped: tuple[Recorded, float, float]) -> None:
    record, since, braking = stopped
    ms = braking * 1000 / 2
    error = fails(assert_stopped_within, record, since, ms)
    assert error.where in MODEL.joint_names and error.unit == "rad/s"
    assert error.time is not None and since + ms / 1000 <= error.time < since + ms / 1000 + 2 * TICK
    assert error.excess is not None and error.excess > 0.01
    text = str(error)
    assert f"{error.where} actual speed was still above the tolerance at t = {error.time:.4f} s" in text
    assert f"the stop at t = 0.6000 s allowed {ms:g} ms" in text
    assert "it came to rest for good at t = " in text


def test_stopped_within_fails_when_the_robot_moves_again() -> None:
    times = np.arange(1000) * TICK
    velocity = np.zeros((times.size, MODEL.dof))
    velocity[:100, 2] = 1.0  # moving at the stop (t = 0), at rest from 0.1 s ...
    velocity[700:720, 2] = 0.2  # ... and moving again at 0.7 s for 20 ms
    record = synthetic(times, np.cumsum(velocity, axis=0) * TICK, velocity)
    error = fails(assert_stopped_within, record, 0.0, 200)
    assert error.where == "joint_3" and error.time == pytest.approx(0.7)
    assert error.duration == pytest.approx(0.02)
    assert "it came to rest for good at t = 0.7200 s" in str(error)
    # a record that ends before the time allowed: at rest by then, it passes ...
    assert assert_stopped_within(record, 0.5, 600) == pytest.approx(0.22)
    # ... still moving, it cannot tell
    velocity[900:, 0] = 0.5
    moving = synthetic(times, np.cumsum(velocity, axis=0) * TICK, velocity)
    short = str(fails(assert_stopped_within, moving, 0.85, 500))
    assert (
        "the record ends at t = 0.9990 s, 149 ms after the stop at t = 0.8500 s, with the robot still moving" in short
    )
    with pytest.raises(MotionAssertionError, match=r"before the stop at t = 2\.0000 s"):
        assert_stopped_within(record, 2.0, 100)


# -- plots -----------------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def fonts(tmp_path_factory: pytest.TempPathFactory) -> None:
    """matplotlib installed, and its fonts opened once: its font cache keeps them open for the life
    of the process, and a session fixture is set up before the leak guard looks at a test's
    descriptors (as tests/test_client_cli_inprocess.py's ``plotting``)."""
    pytest.importorskip("matplotlib")
    folder = tmp_path_factory.mktemp("fonts")
    times = np.arange(100) * TICK
    record = synthetic(times, np.full((100, MODEL.dof), 10.0))  # beyond every limit
    for check, args in ((assert_within_limits, ()), (assert_reached, (np.zeros(MODEL.dof),))):
        with pytest.raises(MotionAssertionError):
            check(record, *args, plot_dir=folder)


def test_a_failure_draws_the_offending_quantity_when_asked(
    moved: Recorded, stopped: tuple[Recorded, float, float], tmp_path: Path, fonts: None
) -> None:
    error = fails(assert_within_joints, moved, -0.5, 0.5, plot_dir=tmp_path / "plots")
    assert error.plot is not None and error.plot.exists() and error.plot.parent == tmp_path / "plots"
    assert error.plot.read_bytes().startswith(b"\x89PNG")
    assert f"plot: {error.plot}" in str(error)
    again = fails(assert_within_joints, moved, -0.5, 0.5, plot_dir=tmp_path / "plots")
    assert again.plot is not None and again.plot != error.plot and again.plot.exists()  # never overwritten
    pose = fk(MODEL, TARGET)
    drawn = [
        fails(assert_reached, moved, TARGET + 0.01, plot_dir=tmp_path),
        fails(assert_reached, moved, pose=pose[:3, 3] + 0.01, plot_dir=tmp_path),
        fails(assert_reached, moved, pose=pose @ rot_z(0.1), plot_dir=tmp_path),
        fails(assert_within_box, moved, [-1, -1, -1], [1, 1, -0.05], plot_dir=tmp_path),
        fails(assert_within_limits, moved, side="actual", plot_dir=tmp_path),
        fails(assert_stopped_within, stopped[0], stopped[1], 10, plot_dir=tmp_path),
    ]
    for error in drawn:
        assert error.plot is not None and error.plot.exists() and f"plot: {error.plot}" in str(error)
    assert len({error.plot for error in drawn}) == len(drawn)


def test_no_plot_unless_asked_nor_without_matplotlib(
    moved: Recorded, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    error = fails(assert_within_joints, moved, -0.5, 0.5)
    assert error.plot is None and "plot:" not in str(error)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    error = fails(assert_within_joints, moved, -0.5, 0.5, plot_dir=tmp_path)
    assert error.plot is None and "plot: not drawn (matplotlib is not installed" in str(error)
    assert not any(tmp_path.iterdir())


def test_a_record_that_dropped_ticks_warns(moved: Recorded) -> None:
    small = Recorder(MODEL.dof, capacity=100)
    for _ in range(150):
        small.add(Tick(0.0, list(Q0), [0.0] * 6, [0.0] * 6, list(Q0), [0.0] * 6, [0.0] * 6, [0.0] * 6))
    with pytest.warns(RuntimeWarning, match="dropped its 50 oldest ticks"):
        assert_within_joints(Recorded(small, MODEL), MODEL.lower, MODEL.upper)


def test_a_nan_target_bound_or_time_is_refused_not_passed(moved: Recorded) -> None:
    nan = float("nan")
    with pytest.raises(ValueError, match="the target must be finite"):
        assert_reached(moved, [nan] * MODEL.dof)
    with pytest.raises(ValueError, match="the target must be finite"):
        assert_reached(moved, {MODEL.joint_names[0]: nan})
    with pytest.raises(ValueError, match="has a NaN"):
        assert_within_joints(moved, nan, nan)
    for kwargs in ({"since": 0.0, "ms": nan}, {"since": nan, "ms": 100.0}, {"since": 0.0, "ms": 100.0, "tol": nan}):
        with pytest.raises(ValueError, match="must be finite"):
            assert_stopped_within(moved, **kwargs)
