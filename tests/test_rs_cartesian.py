"""The controller runs the kinematics: the tool pose every interpolation period, Cartesian
supervision (TCP speed, zones) and straight lines executed by the controller.

Everything here runs on the controller alone (simulated time, no sockets): the emulator's message
handling is tested in test_rs_lines_emulator.py.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from robot_server.control import Controller, ControllerConfig, Point, PointRejected, Reason, Recorder
from robot_server.control.cartesian import LineTarget
from robot_server.kinematics import closed_form, fk, quaternion_angle, rotation_to_quaternion, slerp
from robot_server.loader import load_model
from robot_server.workspace import FLOOR_ALARM, FORBIDDEN_ZONE_ALARM, TCP_SPEED_ALARM, Box, Supervision

MODEL = load_model("jibot_zxs")
#: a configuration away from singularities: the tool points forward and down
START = (0.0, 0.3, -0.6, 0.0, 0.8, 0.0)
DOWN = rotation_to_quaternion(np.diag([1.0, -1.0, -1.0]))  # the tool's z axis pointing down


def controller(start: tuple[float, ...] = START, supervision: Supervision | None = None) -> Controller:
    return Controller(MODEL, ControllerConfig(initial_position=start, supervision=supervision))


def pose_of(q: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    t = fk(MODEL, q)
    return t[:3, 3], rotation_to_quaternion(t)


def target(position: object, orientation: object, speed: float = 0.25, blend: float = 0.0, seq: int = 0) -> LineTarget:
    p = tuple(float(x) for x in np.asarray(position).reshape(3))
    r = tuple(float(x) for x in np.asarray(orientation).reshape(4))
    return LineTarget(p, r, speed, blend, seq)  # type: ignore[arg-type]


def joint_move(offset: list[float], ratio: float) -> tuple[Controller, tuple[float, ...]]:
    """A controller at START with a streamed joint move by ``offset`` at ``ratio`` of the top speed."""
    goal = tuple(np.array(START) + np.array(offset))
    ctl = controller()
    ctl.start(Point(np.array(START), velocity_ratio=ratio, duration=0.0))
    ctl.add(Point(np.array(goal), velocity_ratio=ratio, duration=0.0))
    return ctl, goal


def run_until_rest(ctl: Controller, recorder: Recorder | None = None, limit: float = 30.0) -> None:
    steps = 0
    while ctl.in_motion:
        tick = ctl.step()
        if recorder is not None:
            recorder.add(tick)
        steps += 1
        assert steps * ctl.config.servo_period < limit, "the motion did not end"


def interpolation_ticks(recorder: Recorder) -> np.ndarray:
    """The recorded rows at interpolation instants (where the tool pose was computed)."""
    tool = recorder.tool()
    return np.flatnonzero(np.isclose(tool[:, -1], recorder.time()))


def line_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    return np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)


# -- the tool every interpolation period ---------------------------------------------------------------


def test_the_tool_pose_and_speed_are_computed_every_interpolation_period() -> None:
    ctl = controller()
    recorder = Recorder(MODEL.dof)
    ctl.start(Point(np.array(START), velocity_ratio=0.5, duration=0.0))
    ctl.add(Point(np.array(START) + 0.2, velocity_ratio=0.5, duration=0.0))
    run_until_rest(ctl, recorder)
    tool = recorder.tool()
    rows = interpolation_ticks(recorder)
    assert np.allclose(np.diff(recorder.time()[rows]), ctl.config.interpolation_period)
    command = recorder.get("command_position")
    actual = recorder.get("actual_position")
    velocity = recorder.get("command_velocity")
    for row in rows[:: max(1, rows.size // 25)]:
        t = fk(MODEL, command[row])
        assert np.allclose(tool[row, 0:3], t[:3, 3], atol=1e-12)
        assert quaternion_angle(tool[row, 3:7], rotation_to_quaternion(t)) < 1e-9
        assert np.allclose(tool[row, 8:11], fk(MODEL, actual[row])[:3, 3], atol=1e-12)
        # the speed is |J_v q'|: compare with a difference of positions
        h = 1e-6
        ahead = fk(MODEL, command[row] + h * velocity[row])[:3, 3]
        assert tool[row, 7] == pytest.approx(np.linalg.norm(ahead - t[:3, 3]) / h, rel=1e-4, abs=1e-6)
    # between interpolation instants the record holds the last one
    assert np.all(tool[:, -1] <= recorder.time() + 1e-12)


# -- straight lines ------------------------------------------------------------------------------------


def test_a_controller_line_is_straight_and_its_orientation_follows_the_slerp() -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    p1 = p0 + np.array([0.12, 0.08, -0.05])
    turn = rotation_to_quaternion(fk(MODEL, (0.0, 0.3, -0.6, 0.3, 0.6, 0.4)))  # another orientation
    r1 = turn if np.dot(turn, r0) >= 0 else -turn
    recorder = Recorder(MODEL.dof)
    ctl.add_line(target(p1, r1, speed=0.2))
    run_until_rest(ctl, recorder)
    assert not ctl.in_error
    rows = interpolation_ticks(recorder)
    tool = recorder.tool()[rows]
    cmd = tool[:, 0:3]
    # the commanded TCP at every interpolation instant: on the line within 0.01 mm
    assert float(line_distance(cmd, p0, p1).max()) < 1e-5
    # ... and its orientation is the slerp at the same fraction of the way, within 1e-6 rad
    u = np.clip((cmd - p0) @ (p1 - p0) / float(np.dot(p1 - p0, p1 - p0)), 0.0, 1.0)
    ideal = slerp(r0, r1, u)
    assert max(quaternion_angle(a, b) for a, b in zip(tool[:, 3:7], ideal, strict=True)) < 1e-6
    # it ends exactly at the target
    assert np.allclose(cmd[-1], p1, atol=1e-9) and quaternion_angle(tool[-1, 3:7], r1) < 1e-9
    # the TCP never goes faster than asked
    assert float(tool[:, 7].max()) <= 0.2 * (1 + 1e-6)
    # the actual TCP follows within what the joints' following error allows: every joint error
    # moves the TCP at most by (its lever, < 1 m) x (the error)
    error = np.abs(recorder.get("following_error")[rows]).sum(axis=1)
    assert np.all(line_distance(tool[:, 8:11], p0, p1) <= 1.0 * error + 1e-9)
    assert float(error.max()) < 0.05


@pytest.mark.parametrize(
    ("length", "turn"),
    [(0.08, 30.0), (0.08, 60.0), (0.1, 90.0), (0.12, 90.0), (0.13, 90.0), (0.1, 135.0), (0.1, 150.0)],
)
def test_lines_stop_exactly_at_a_corner_unless_blended(length: float, turn: float) -> None:
    """(A corner whose blend would ask more of the joints than they can give is not blended: the
    cases here are ones it can be.)"""
    p0, r0 = pose_of(START)
    corner = p0 + np.array([length, 0.0, 0.0])
    end = corner + 0.08 * np.array([math.cos(math.radians(turn)), math.sin(math.radians(turn)), 0.0])
    period = ControllerConfig().interpolation_period
    for blend in (0.0, 0.02):
        ctl = controller()
        recorder = Recorder(MODEL.dof)
        ctl.add_line(target(corner, r0, 0.2, blend, seq=0))
        ctl.add_line(target(end, r0, 0.2, 0.0, seq=1))
        run_until_rest(ctl, recorder)
        rows = interpolation_ticks(recorder)
        tool = recorder.tool()[rows]
        nearest = int(np.argmin(np.linalg.norm(tool[:, 0:3] - corner, axis=1)))
        gap = float(np.linalg.norm(tool[nearest, 0:3] - corner))
        if blend == 0.0:  # it stops at the corner, between two interpolation instants (jerk-limited:
            # within j t^3 / 6 of it 2 ms away; the speed: a central difference over +-4 ms)
            assert gap < 1e-6 and tool[nearest, 7] < 1e-4
        else:  # it rounds the corner within the radius, moving
            assert 1e-4 < gap < blend and tool[nearest, 7] > 0.02
        assert np.allclose(tool[-1, 0:3], end, atol=1e-9)
        assert float(tool[:, 7].max()) <= 0.2 * 1.001
        # the TCP within its acceleration at any corner: the two lines share it
        tcp_acceleration = np.linalg.norm(np.diff(tool[:, 0:3], 2, axis=0), axis=1) / period**2
        assert float(tcp_acceleration.max()) <= ctl.config.line.acceleration * 1.01
        # the joints' commanded motion stays within their limits, blended or not: the drives'
        # view, differences of the setpoints at the interpolation instants
        command = recorder.get("command_position")[rows]
        velocity = np.diff(command, axis=0) / period
        acceleration = np.diff(command, 2, axis=0) / period**2
        assert np.all(np.abs(velocity) <= MODEL.max_velocity * 1.001)
        assert np.all(np.abs(acceleration) <= MODEL.max_acceleration * 1.01)


@pytest.mark.parametrize(
    ("case", "reason", "words"),
    [
        ("unreachable", Reason.UNREACHABLE, "leaves the reachable space"),
        ("singular", Reason.SINGULAR, "passes a singularity"),
        ("joint limit", Reason.POSITION_LIMIT, "beyond its limits"),
        ("zone", Reason.WORKSPACE, "forbidden zone"),
        ("floor", Reason.WORKSPACE, "below the floor"),
    ],
)
def test_a_line_that_cannot_run_is_refused_and_nothing_moves(case: str, reason: Reason, words: str) -> None:
    solver = closed_form(MODEL)
    assert solver is not None
    start = START
    supervision = None
    if case == "joint limit":  # the tool pointing down, in front of the robot
        pose = np.eye(4)
        pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
        pose[:3, 3] = (0.3, 0.05, 0.25)
        solution = solver.solve(pose, START)
        assert solution is not None
        start = solution.q
    elif case == "singular":  # the wrist bent one way, to the pose with it bent the other way
        start = (0.0, 0.3, -0.6, 0.0, 0.3, 0.0)
    p0, r0 = pose_of(start)
    if case == "unreachable":
        goal = p0 + np.array([1.5, 0.0, 0.0])
    elif case == "singular":  # joint 5 would pass 0: axes 4 and 6 aligned on the way
        goal, r0 = pose_of((0.0, 0.3, -0.6, 0.0, -0.3, 0.0))
    elif case == "joint limit":  # round the back of the robot: joint 1 beyond 170 degrees
        goal = p0 + np.array([-0.65, 0.0, 0.0])
    elif case == "zone":
        box = Box((p0[0] + 0.04, p0[1] - 0.01, p0[2] - 0.01), (p0[0] + 0.05, p0[1] + 0.01, p0[2] + 0.01), "fixture")
        supervision = Supervision(forbidden=(box,))
        goal = p0 + np.array([0.1, 0.0, 0.0])
    else:
        supervision = Supervision(floor=p0[2] - 0.03)
        goal = p0 + np.array([0.0, 0.0, -0.05])
    ctl = controller(start, supervision)
    with pytest.raises(PointRejected) as info:
        ctl.add_line(target(goal, r0, 0.2))
    assert info.value.reason is reason, info.value
    assert words in str(info.value)
    ctl.run_for(0.1)
    assert not ctl.moving and not ctl.in_error
    assert np.allclose(ctl.command.command_position, start, atol=1e-12)


def test_malformed_lines_are_refused() -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    for bad, reason in [
        (target(p0, r0 * 2.0), Reason.INVALID),
        (target(p0, r0, speed=0.0), Reason.INVALID),
        (target(p0, r0, blend=-1.0), Reason.INVALID),
        (target(p0 + np.array([math.nan, 0, 0]), r0), Reason.NOT_FINITE),
    ]:
        with pytest.raises(PointRejected) as info:
            ctl.add_line(bad)
        assert info.value.reason is reason


def test_lines_and_joint_points_do_not_mix() -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    ctl.add_line(target(p0 + np.array([0.05, 0, 0]), r0))
    with pytest.raises(PointRejected) as info:
        ctl.start(Point(np.array(START), velocity_ratio=0.5, duration=0.0))
    assert info.value.reason is Reason.BUSY
    run_until_rest(ctl)
    # then joint motion starts from where the line ended
    here = tuple(ctl.command.command_position)
    ctl.start(Point(np.array(here), velocity_ratio=0.5, duration=0.0))
    ctl.add(Point(np.array(START), velocity_ratio=0.5, duration=0.0))
    with pytest.raises(PointRejected) as info:
        ctl.add_line(target(p0, r0))
    assert info.value.reason is Reason.BUSY
    run_until_rest(ctl)
    assert np.allclose(ctl.command.command_position, START, atol=1e-9)


def test_a_stopped_line_brakes_on_the_line() -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    p1 = p0 + np.array([0.12, 0.1, 0.05])
    recorder = Recorder(MODEL.dof)
    ctl.add_line(target(p1, r0, 0.25))
    ctl.run_for(0.4, recorder)
    assert ctl.stop() > 0.0
    run_until_rest(ctl, recorder)
    tool = recorder.tool()[interpolation_ticks(recorder)]
    assert float(line_distance(tool[:, 0:3], p0, p1).max()) < 1e-5
    assert float(np.linalg.norm(tool[-1, 0:3] - p1)) > 1e-3  # it stopped short of the end
    assert not ctl.in_error


# -- supervision ----------------------------------------------------------------------------------------


def fixture_across(start: tuple[float, ...], goal: tuple[float, ...]) -> Box:
    """A thin box across the TCP path of the joint move ``start -> goal``, half way."""
    middle = fk(MODEL, (np.array(start) + np.array(goal)) / 2.0)[:3, 3]
    return Box(tuple(middle - 0.02), tuple(middle + 0.02), "fixture")  # type: ignore[arg-type]


def test_a_joint_trajectory_that_cuts_a_forbidden_box_is_refused() -> None:
    goal = tuple(np.array(START) + np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.0]))
    supervision = Supervision(forbidden=(fixture_across(START, goal),))
    for download in (False, True):
        ctl = controller(supervision=supervision)
        first = Point(np.array(START), velocity_ratio=0.5, duration=0.0)
        last = Point(np.array(goal), velocity_ratio=0.5, duration=0.0)
        if download:
            ctl.start_download(first)
            with pytest.raises(PointRejected) as info:
                ctl.finish_download(last)
        else:
            ctl.start(first)
            with pytest.raises(PointRejected) as info:
                ctl.add(last)
        assert info.value.reason is Reason.WORKSPACE and "forbidden zone 1 'fixture'" in str(info.value)
        ctl.run_for(0.5)
        assert np.allclose(ctl.command.actual_position, START, atol=1e-9) and not ctl.in_error
    # the same trajectory without the box runs
    ctl = controller()
    ctl.start(Point(np.array(START), velocity_ratio=0.5, duration=0.0))
    ctl.add(Point(np.array(goal), velocity_ratio=0.5, duration=0.0))
    run_until_rest(ctl)
    assert np.allclose(ctl.command.command_position, goal, atol=1e-9)


@pytest.mark.parametrize("where", [0.5, 0.75, 0.95])
@pytest.mark.parametrize("download", [False, True])
def test_a_thin_plate_anywhere_on_the_way_is_found(where: float, download: bool) -> None:
    """A 0.8 mm plate across the TCP's way, at full speed (the TCP moves several mm per 4 ms
    interpolation period): the path is checked in 1 mm steps to the end of its last segment."""
    goal = np.array(START) + np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.0])
    middle = np.array(START) + where * (goal - np.array(START))
    at = fk(MODEL, middle)[:3, 3]
    travel = fk(MODEL, middle + np.array([1e-4, 0, 0, 0, 0, 0]))[:3, 3] - at
    axis = int(np.argmax(np.abs(travel)))
    lower, upper = at - 0.05, at + 0.05
    lower[axis], upper[axis] = at[axis] - 0.0004, at[axis] + 0.0004
    ctl = controller(supervision=Supervision(forbidden=(Box(tuple(lower), tuple(upper), "plate"),)))  # type: ignore[arg-type]
    first = Point(np.array(START), velocity_ratio=1.0, duration=0.0)
    last = Point(goal, velocity_ratio=1.0, duration=0.0)
    with pytest.raises(PointRejected) as info:
        if download:
            ctl.start_download(first)
            ctl.finish_download(last)
        else:
            ctl.start(first)
            ctl.add(last)
    assert info.value.reason is Reason.WORKSPACE and "'plate'" in str(info.value)


@pytest.mark.parametrize(
    "goal",
    [
        (0.8, -0.3, 0.4, 0.5, 0.0, 0.5),
        (0.29, 0.24, -0.17, 0.63, 0.6, -0.77),
        (0.283, -0.281, 0.036, -0.366, 0.607, -0.697),
        (0.217, -0.079, 0.191, -0.49, -0.175, 0.477),
    ],
)
def test_manual_mode_slows_any_joint_move_down_to_the_reduced_speed(goal: tuple[float, ...]) -> None:
    for download in (False, True):
        ctl = controller()
        ctl.manual = True
        recorder = Recorder(MODEL.dof)
        target = np.array(START) + np.array(goal)
        first = Point(np.array(START), velocity_ratio=1.0, duration=0.0)
        last = Point(target, velocity_ratio=1.0, duration=0.0)
        if download:
            ctl.start_download(first)
            ctl.finish_download(last)
        else:
            ctl.start(first)
            ctl.add(last)
        run_until_rest(ctl, recorder)
        assert not ctl.in_error, ctl.error_message
        tool = recorder.tool()[interpolation_ticks(recorder)]
        assert float(tool[:, 7].max()) <= 0.25 and float(tool[:, 15].max()) <= 0.25
        assert float(tool[:, 7].max()) > 0.1  # slowed down to the limit, not to a crawl
        assert np.allclose(ctl.command.command_position, target, atol=1e-9)


def test_a_stop_whose_braking_path_enters_a_zone_raises_the_alarm_and_cuts_the_drives() -> None:
    ctl, goal = joint_move([0.8, 0.0, 0.0, 0.0, 0.0, 0.0], 1.0)
    ctl.run_for(0.25)
    assert ctl.moving
    # a zone just ahead of the TCP, which the braking path reaches (a fixture put down mid-move)
    here = np.array(ctl.command.command_position)
    ahead = here + 0.08 * np.sign(np.array(goal) - here) * (np.array(goal) != here)
    where = fk(MODEL, ahead)[:3, 3]
    ctl.supervision = Supervision(forbidden=(Box(tuple(where - 0.03), tuple(where + 0.03), "cart"),))  # type: ignore[arg-type]
    ctl.stop()
    assert ctl.in_error and ctl.error_code == FORBIDDEN_ZONE_ALARM + 1
    assert "braking path" in ctl.error_message and "e-stop" in ctl.error_message
    assert not ctl.drives_powered
    held = list(ctl.command.actual_position)
    ctl.run_for(0.1)
    assert ctl.command.actual_position == held  # the brakes hold every joint


def test_an_actual_zone_excursion_raises_the_alarm_with_the_e_stop_reaction() -> None:
    ctl, goal = joint_move([0.5, 0.0, 0.0, 0.0, 0.0, 0.0], 0.5)
    ctl.run_for(0.2)
    z = ctl.tool.actual_position[2]
    ctl.supervision = Supervision(floor=z + 0.5)  # the floor rises above the tool (a wrong cell file)
    ctl.run_for(0.004)
    assert ctl.error_code == FLOOR_ALARM and not ctl.drives_powered
    assert "below the floor" in ctl.error_message
    # reset: it may be moved out (the violation is not raised again while it stays there) ...
    ctl.reset()
    ctl.power_on()
    ctl.run_for(0.1)
    assert not ctl.in_error
    # ... but a path that stays in the violation the whole way is not checked against it: it leads
    # nowhere worse. A path from a clear start into a violation is refused.
    ctl.supervision = Supervision(floor=-10.0, forbidden=(fixture_across(START, goal),))
    here = tuple(ctl.command.command_position)
    assert np.linalg.norm(np.array(here) - START) < np.linalg.norm(np.array(goal) - START) / 2
    ctl.start(Point(np.array(here), velocity_ratio=0.5, duration=0.0))
    with pytest.raises(PointRejected) as info:
        ctl.add(Point(np.array(goal), velocity_ratio=0.5, duration=0.0))
    assert info.value.reason is Reason.WORKSPACE


def test_manual_mode_holds_the_reduced_tcp_speed_for_lines() -> None:
    """(Joint moves: test_manual_mode_slows_any_joint_move_down_to_the_reduced_speed.)"""
    # a line asking for more is slowed down to the limit too
    ctl = controller()
    ctl.manual = True
    p0, r0 = pose_of(START)
    recorder = Recorder(MODEL.dof)
    ctl.add_line(target(p0 + np.array([0.12, 0.1, 0.05]), r0, speed=1.0))
    run_until_rest(ctl, recorder)
    tool = recorder.tool()[interpolation_ticks(recorder)]
    assert 0.2 < float(tool[:, 7].max()) <= 0.25 and float(tool[:, 15].max()) <= 0.25


def test_switching_to_manual_while_moving_fast_stops_without_a_speed_alarm() -> None:
    ctl, _ = joint_move([0.8, 0.0, 0.0, 0.0, 0.0, 0.0], 1.0)
    ctl.run_for(0.3)
    assert ctl.tool.actual_speed > 0.3
    ctl.stop()  # what the cell does on "mode manual"
    ctl.manual = True
    run_until_rest(ctl)
    assert not ctl.in_error
    # the next motion is supervised again
    ctl.supervision = Supervision(manual_speed=0.01)
    here = tuple(ctl.command.command_position)
    ctl.start(Point(np.array(here), velocity_ratio=1.0, duration=0.0))
    ctl.add(Point(np.array(START), velocity_ratio=1.0, duration=0.0))
    ctl.run_for(0.2)
    assert ctl.tool.actual_speed <= 0.01 and not ctl.in_error


def test_auto_mode_refuses_a_trajectory_over_its_maximum_and_alarms_on_an_actual_excursion() -> None:
    goal = tuple(np.array(START) + np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.0]))
    ctl = controller(supervision=Supervision(auto_speed=0.3))
    ctl.start(Point(np.array(START), velocity_ratio=1.0, duration=0.0))
    with pytest.raises(PointRejected) as info:
        ctl.add(Point(np.array(goal), velocity_ratio=1.0, duration=0.0))
    assert info.value.reason is Reason.TCP_SPEED and "over the AUTO limit" in str(info.value)
    p0, r0 = pose_of(START)
    with pytest.raises(PointRejected) as info:
        ctl.add_line(target(p0 + np.array([0.1, 0, 0]), r0, speed=0.5))
    assert info.value.reason is Reason.TCP_SPEED
    # planned without the limit, it trips the supervision once the limit comes into force
    ctl = controller()
    ctl.start(Point(np.array(START), velocity_ratio=1.0, duration=0.0))
    ctl.add(Point(np.array(goal), velocity_ratio=1.0, duration=0.0))
    ctl.run_for(0.2)
    ctl.supervision = replace(ctl.supervision, auto_speed=0.1)
    ctl.run_for(0.01)
    assert ctl.error_code == TCP_SPEED_ALARM and "over the AUTO limit" in ctl.error_message
    assert ctl.drives_powered  # the alarm reaction: the drives brake the robot under their loops
    run_until_rest(ctl)


@pytest.mark.parametrize("after", [0.0, 0.002, 0.02])
def test_a_stop_right_after_a_line_is_accepted_holds_the_robot_where_it_is(after: float) -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    recorder = Recorder(MODEL.dof)
    ctl.add_line(target(p0 + np.array([0.05, 0.0, 0.0]), r0, 0.2))
    ctl.run_for(after, recorder)
    ctl.stop()
    run_until_rest(ctl, recorder)
    ctl.run_for(0.05, recorder)
    assert not ctl.in_error, ctl.error_message
    command = recorder.get("command_position")
    assert float(np.abs(np.diff(command, axis=0)).max()) < 1e-3  # no jump of the command
    tool = recorder.tool()[interpolation_ticks(recorder)]
    assert float(line_distance(tool[:, 0:3], p0, p0 + np.array([0.05, 0.0, 0.0])).max()) < 1e-5
    assert float(np.linalg.norm(tool[-1, 0:3] - p0)) < 0.01


def test_a_line_sent_while_a_stop_brakes_starts_where_the_braking_ends() -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    ctl.add_line(target(p0 + np.array([0.15, 0.0, 0.0]), r0, 0.25, seq=0))
    ctl.run_for(0.3)
    assert ctl.stop() > 0.0
    ctl.run_for(0.02)  # still braking
    assert ctl.moving
    goal = p0 + np.array([0.05, 0.05, 0.0])
    recorder = Recorder(MODEL.dof)
    ctl.add_line(target(goal, r0, 0.25, seq=0))
    run_until_rest(ctl, recorder)
    assert not ctl.in_error, ctl.error_message
    assert np.allclose(ctl.tool.command_position, goal, atol=1e-9)
    command = recorder.get("command_position")
    assert float(np.abs(np.diff(command, axis=0)).max()) < 2e-3  # no jump on the way


def test_a_very_slow_line_is_checked_on_a_bounded_number_of_samples() -> None:
    ctl = controller()
    p0, r0 = pose_of(START)
    ctl.add_line(target(p0 + np.array([0.1, 0.0, 0.0]), r0, speed=1e-4, seq=0))  # 1000 s
    [line] = ctl.lines._lines
    assert line.duration > 999.0
    assert line.checked is not None and line.checked[0].size <= 5_001
    positions = np.array([fk(MODEL, q)[:3, 3] for q in line.checked[1][::50]])
    assert float(np.linalg.norm(np.diff(positions, axis=0), axis=1).max()) <= 50 * 0.001  # 1 mm apart at most
