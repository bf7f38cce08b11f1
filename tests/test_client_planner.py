"""The planner: joint moves, Cartesian lines on one IK branch, time parameterization within limits."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import numpy as np
import pytest

from client.demo import distance_to_path
from client.planner import (
    Planner,
    PlanningError,
    pose,
    quaternion_to_rotation,
    rotation_to_quaternion,
    slerp,
)
from robot_server.kinematics import closed_form, fk, fk_batch
from robot_server.loader import load_model

MODEL = load_model("jibot_zxs")
Q0 = np.array([0.0, 0.3, -0.2, 0.0, 0.9, 0.0])


def rectangle(width: float = 0.16, height: float = 0.10) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Start configuration, the four corner poses (back to the first), and the corners' positions."""
    t = fk(MODEL, Q0)
    c, r = t[:3, 3], t[:3, :3]
    offsets = [(-height / 2, -width / 2, 0), (height / 2, -width / 2, 0), (height / 2, width / 2, 0)]
    offsets += [(-height / 2, width / 2, 0), (-height / 2, -width / 2, 0)]
    corners = np.array([c + np.array(o) for o in offsets])
    ik = closed_form(MODEL)
    assert ik is not None
    solution = ik.solve(pose(corners[0], r), Q0)
    assert solution is not None
    return np.array(solution.q), [pose(p, r) for p in corners[1:]], corners


def branch_slots(q: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Which of the closed-form solver's 8 branch slots each configuration is (its own numbering)."""
    ik = closed_form(MODEL)
    assert ik is not None
    solutions, valid, _ = ik.solve_batch(poses, q)
    wrapped = (solutions - q[:, None, :] + np.pi) % (2 * np.pi) - np.pi
    distance = np.where(valid, np.max(np.abs(wrapped), axis=2), np.inf)
    assert np.all(np.min(distance, axis=1) < 1e-6)
    return np.argmin(distance, axis=1)


def test_rectangle_waypoints_on_the_ideal_path_and_one_branch() -> None:
    start, poses, corners = rectangle()
    motion = Planner(MODEL, max_speed=0.08, max_acceleration=0.5).linear_moves(start, poses)
    sparse = motion.sparse()
    flange = fk_batch(MODEL, sparse.positions)
    deviation = distance_to_path(flange[:, :3, 3], corners)
    assert deviation.max() < 1e-4  # 0.1 mm
    # the waypoints include every corner, reached exactly
    for corner in corners:
        assert np.min(np.linalg.norm(flange[:, :3, 3] - corner, axis=1)) < 1e-6
    # the orientation is the corners' throughout
    assert np.allclose(flange[:, :3, :3], poses[0][:3, :3], atol=1e-6)
    # one IK branch from start to end, along the dense path too
    dense = motion.dense(0.01)
    assert len(set(branch_slots(dense.positions, fk_batch(MODEL, dense.positions)).tolist())) == 1
    assert len(set(branch_slots(sparse.positions, flange).tolist())) == 1
    # sparse: about one waypoint per 20 mm of the 520 mm perimeter, at rest at the ends
    assert 26 <= len(sparse) <= 32
    assert sparse.velocities is not None
    assert np.allclose(sparse.velocities[[0, -1]], 0.0, atol=1e-9)


def test_time_parameterization_within_the_limits() -> None:
    start, poses, _corners = rectangle()
    planner = Planner(MODEL, velocity_scale=0.5, acceleration_scale=0.5, max_speed=0.2, max_acceleration=2.0)
    motion = planner.linear_moves(start, poses)
    t = np.linspace(0.0, motion.duration, 4001)
    q, v, a = motion.sample(t)
    assert np.all(np.abs(v) <= 0.5 * MODEL.max_velocity * (1 + 1e-6))
    assert np.all(np.abs(a) <= 0.5 * MODEL.max_acceleration * (1 + 1e-6))
    # the flange never exceeds the Cartesian speed (finite differences of the dense path)
    p = fk_batch(MODEL, q)[:, :3, 3]
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)
    assert speed.max() <= 0.2 * 1.01
    # dense samples are consistent with the sampled velocities (a real time parameterization)
    dense = motion.dense(0.002)
    assert dense.velocities is not None
    numeric = np.gradient(dense.positions, dense.times, axis=0)
    assert np.max(np.abs(numeric[1:-1] - dense.velocities[1:-1])) < 0.01
    assert dense.times[-1] == pytest.approx(motion.duration)
    assert np.allclose(dense.positions[-1], motion.end)


def test_joint_move_is_a_straight_line_at_rest_at_both_ends() -> None:
    planner = Planner(MODEL, velocity_scale=0.3, acceleration_scale=0.3, jerk_scale=0.3)
    goal = Q0 + np.array([0.5, -0.2, 0.3, 0.1, -0.4, 1.0])
    motion = planner.joint_move(Q0, goal)
    sparse = motion.sparse()
    assert np.allclose(sparse.positions[0], Q0) and np.allclose(sparse.positions[-1], goal)
    assert len(sparse) == 6  # 1.0 rad in steps of at most 0.2 rad
    direction = (goal - Q0) / np.linalg.norm(goal - Q0)
    rel = sparse.positions - Q0
    assert np.allclose(rel - np.outer(rel @ direction, direction), 0.0, atol=1e-12)
    t = np.linspace(0.0, motion.duration, 2001)
    _, v, a = motion.sample(t)
    assert np.all(np.abs(v) <= 0.3 * MODEL.max_velocity * (1 + 1e-9))
    assert np.all(np.abs(a) <= 0.3 * MODEL.max_acceleration * (1 + 1e-9))
    # jerk-limited: the acceleration changes no faster than the scaled jerk limit
    jerk = np.diff(a, axis=0) / np.diff(t)[:, None]
    assert np.all(np.abs(jerk) <= 0.3 * MODEL.max_jerk * (1 + 1e-6))
    # the fastest joint (the 1.0 rad one) reaches its scaled speed limit: time-optimal, not timid
    assert np.max(np.abs(v[:, 5])) == pytest.approx(0.3 * MODEL.max_velocity[5], rel=1e-3)


def test_motions_concatenate() -> None:
    start, poses, _ = rectangle()
    planner = Planner(MODEL)
    approach = planner.joint_move(Q0, start)
    lines = planner.linear_moves(start, poses[:1])
    both = planner.then(approach, lines)
    assert both.duration == pytest.approx(approach.duration + lines.duration)
    sparse = both.sparse()
    assert np.all(np.diff(sparse.times) > 0)
    assert len(sparse) == len(approach.sparse()) + len(lines.sparse()) - 1
    with pytest.raises(PlanningError, match="starts"):
        planner.then(lines, approach)


def test_refuses_a_line_through_the_wrist_singularity() -> None:
    # q5 = 0 aligns axes 4 and 6: a line whose orientation passes it cannot keep a branch
    q = np.array([0.0, 0.3, -0.2, 0.3, 0.4, 0.0])
    t1 = fk(MODEL, np.array([0.0, 0.3, -0.2, 0.3, -0.4, 0.0]))
    with pytest.raises(PlanningError, match=r"(singularity|jump).*: (try|a straight line cannot)"):
        Planner(MODEL).linear_moves(q, [t1])
    # the same line away from the singularity is fine
    t2 = fk(MODEL, np.array([0.0, 0.3, -0.2, 0.3, 0.8, 0.0]))
    assert Planner(MODEL).linear_moves(q, [t2]).duration > 0


def test_refuses_unreachable_and_bad_input() -> None:
    planner = Planner(MODEL)
    far = pose([2.0, 0.0, 0.0], fk(MODEL, Q0)[:3, :3])
    with pytest.raises(PlanningError, match="out of reach"):
        planner.linear_moves(Q0, [far])
    with pytest.raises(PlanningError, match="6 finite values"):
        planner.joint_move(Q0[:5], Q0)
    with pytest.raises(PlanningError, match="outside the joint limits"):
        planner.joint_move(Q0, Q0 + np.array([0, 0, 0, 0, 0, 10.0]))
    with pytest.raises(PlanningError, match="4x4"):
        planner.linear_moves(Q0, [np.eye(3)])
    with pytest.raises(PlanningError, match="velocity_scale"):
        Planner(MODEL, velocity_scale=1.5)
    urdf = load_model("kuka_kr6_r900_sixx")
    if closed_form(urdf) is None:  # pragma: no cover - depends on the model's geometry
        with pytest.raises(PlanningError, match="closed-form"):
            Planner(urdf).linear_moves(np.zeros(6), [np.eye(4)])


def test_a_zero_length_move_adds_no_point() -> None:
    planner = Planner(MODEL)
    motion = planner.joint_move(Q0, Q0)
    assert motion.duration == 0.0
    assert len(motion.sparse()) == 1


def test_quaternions_round_trip_and_slerp() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        r = quaternion_to_rotation(q)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.allclose(rotation_to_quaternion(r), q, atol=1e-9)
    a = rotation_to_quaternion(np.eye(3))
    b = rotation_to_quaternion(quaternion_to_rotation([np.cos(0.5), 0, 0, np.sin(0.5)]))
    half = quaternion_to_rotation(slerp(a, b, 0.5))
    assert np.allclose(half, quaternion_to_rotation([np.cos(0.25), 0, 0, np.sin(0.25)]), atol=1e-12)


def test_rest_to_rest_retiming_keeps_every_segment_within_the_limits() -> None:
    start, poses, _ = rectangle()
    planner = Planner(MODEL, velocity_scale=0.3, acceleration_scale=0.3, max_speed=0.25, max_acceleration=2.0)
    motion = planner.linear_moves(start, poses)
    plain, retimed = motion.sparse(), motion.sparse(rest_to_rest=True)
    assert np.array_equal(plain.positions, retimed.positions)
    assert retimed.velocities is None and retimed.accelerations is None
    d = np.abs(np.diff(retimed.positions, axis=0))
    t = np.diff(retimed.times)[:, None]
    # a rest-to-rest cubic (peak 1.5 D/T, 6 D/T^2) and quintic (1.875 D/T, 5.77 D/T^2) both fit
    assert np.all(1.875 * d / t <= 0.3 * MODEL.max_velocity * (1 + 1e-9))
    assert np.all(6.0 * d / t**2 <= 0.3 * MODEL.max_acceleration * (1 + 1e-9))
    # fast enough for the continuous profile, too fast for stopping at every point: retimed longer
    assert np.all(np.diff(retimed.times) >= np.diff(plain.times) - 1e-12)
    assert retimed.duration > plain.duration


#: the packages whose ``__all__`` is the server side's public API for the client
PUBLIC_PACKAGES = ("robot_server", "robot_server.control", "robot_server.kinematics", "simple_message")
SERVER_SIDE = ("robot_server", "simple_message")


@pytest.mark.parametrize("module", ["planner", "trajectory"])
def test_the_client_uses_public_names_only(module: str) -> None:
    """The planner and the trajectories import from the server side and the protocol only names
    those packages export (``__all__``), never a module inside them."""
    source = Path(__file__).resolve().parent.parent / "client" / f"{module}.py"
    for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names if alias.name.split(".")[0] in SERVER_SIDE]
            assert all(name in PUBLIC_PACKAGES for name in names), f"line {node.lineno}: import {names}"
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module is not None:
            if node.module.split(".")[0] not in SERVER_SIDE:
                continue
            assert node.module in PUBLIC_PACKAGES, f"line {node.lineno}: from {node.module} (not a public package)"
            exported = importlib.import_module(node.module).__all__
            for alias in node.names:
                assert alias.name in exported, f"line {node.lineno}: {alias.name} is not in {node.module}.__all__"
