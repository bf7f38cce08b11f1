"""JointMoves, sans-I/O: moves planned, blended, stopped and sampled on a clock the test advances."""

from __future__ import annotations

import numpy as np
import pytest

from robot_server.control.moves import JointMoves
from robot_server.control.points import Limits, PointRejected

DT = 0.004
LIMITS = Limits(
    lower=np.full(2, -3.0),
    upper=np.full(2, 3.0),
    max_velocity=np.full(2, 2.0),
    max_acceleration=np.full(2, 8.0),
    max_jerk=np.full(2, 200.0),
)


def run(moves: JointMoves, start: float, until: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample every DT from ``start`` to ``until``: positions, velocities, accelerations."""
    rows = [moves.sample(t) for t in np.arange(start, until + DT / 2, DT)]
    return (
        np.array([r.position for r in rows]),
        np.array([r.velocity for r in rows]),
        np.array([r.acceleration for r in rows]),
    )


def test_a_move_runs_rest_to_rest_within_the_limits_and_ends_exactly_on_its_target() -> None:
    moves = JointMoves(LIMITS, np.zeros(2))
    move = moves.plan(np.array([1.0, 0.5]), speed=0.5)
    moves.commit(move)
    p, v, a = run(moves, 0.0, move.end + 0.1)
    assert np.max(np.abs(v[:, 0])) == pytest.approx(1.0, rel=1e-3)  # half of 2 rad/s on the longest way
    assert np.allclose(v[:, 1], v[:, 0] / 2)  # synchronised: joint 1 proportionally slower
    assert np.max(np.abs(a)) <= 8.0 + 1e-6
    assert np.array_equal(p[-1], [1.0, 0.5])
    assert not moves.active


def test_moves_in_one_direction_overlap_by_the_blend_and_never_stop_between() -> None:
    moves = JointMoves(LIMITS, np.zeros(2))
    first = moves.plan(np.array([1.0, 0.0]), speed=1.0)
    moves.commit(first)
    second = moves.plan(np.array([2.0, 1.0]), speed=1.0, blend=1.0)
    moves.commit(second)
    assert second.begin == pytest.approx(first.end - min(first.decelerating, second.accelerating))
    p, v, _ = run(moves, 0.0, second.end + 0.05)
    moving = np.flatnonzero(np.abs(v[:, 0]) > 1e-3)
    assert np.all(np.abs(v[moving[0] : moving[-1], 0]) > 1e-3)  # joint 0 never stops at the corner
    assert np.array_equal(p[-1], [2.0, 1.0])


def test_where_a_joint_turns_back_only_the_jerk_ramps_overlap_so_its_acceleration_stays_within_the_limit() -> None:
    moves = JointMoves(LIMITS, np.zeros(2))
    first = moves.plan(np.array([1.0, 1.0]), speed=1.0)
    moves.commit(first)
    back = moves.plan(np.array([0.0, 2.0]), speed=1.0, blend=1.0)  # joint 0 reverses, joint 1 goes on
    moves.commit(back)
    ramps = min(first.ramp_out, back.ramp_in)
    assert 0.0 < ramps < min(first.decelerating, back.accelerating)
    assert back.begin == pytest.approx(first.end - ramps)
    _, v, a = run(moves, 0.0, back.end + 0.05)
    assert np.max(np.abs(a)) <= 8.0 + 1e-6  # fully superposed, joint 0 would reach 16 rad/s²
    moving = np.flatnonzero(np.abs(v[:, 1]) > 1e-3)
    assert np.all(np.abs(v[moving[0] : moving[-1], 1]) > 1e-3)  # joint 1 never stops at the corner


def test_a_move_during_a_stop_waits_for_its_end_and_the_setpoint_stays_continuous() -> None:
    moves = JointMoves(LIMITS, np.zeros(2))
    moves.commit(moves.plan(np.array([2.0, 0.0]), speed=1.0))
    run(moves, 0.0, 0.5)  # cruising by now
    duration = moves.stop()
    assert duration > 0.1
    stop_end = 0.5 + duration
    assert moves.end_position[0] > moves.sample(0.5).position[0]  # the stop runs on
    stopped_at = moves.end_position.copy()
    after = moves.plan(np.array([0.0, 0.0]), speed=1.0, rest=np.array([9.0, 9.0]))  # rest ignored meanwhile
    moves.commit(after)
    assert moves.stopping  # still braking: the controller keeps its stop's supervision until the end
    assert np.array_equal(after.start, stopped_at)
    assert after.begin == pytest.approx(stop_end)
    assert moves.remaining() == pytest.approx(after.end - 0.5)
    p, v, a = run(moves, 0.5 + DT, after.end + 0.05)
    assert not moves.stopping
    assert np.max(np.abs(np.diff(v[:, 0]))) <= 8.0 * DT + 1e-6  # no jump in velocity
    assert np.max(np.abs(a)) <= 8.0 + 1e-6
    assert np.array_equal(p[-1], [0.0, 0.0])


def test_a_target_out_of_the_limits_or_a_bad_share_is_refused_and_nothing_is_queued() -> None:
    moves = JointMoves(LIMITS, np.zeros(2))
    with pytest.raises(PointRejected, match="position"):
        moves.plan(np.array([4.0, 0.0]), speed=0.5)
    with pytest.raises(PointRejected, match="speed share"):
        moves.plan(np.array([1.0, 0.0]), speed=0.0)
    assert not moves.active
