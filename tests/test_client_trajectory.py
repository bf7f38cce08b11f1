"""Trajectory files: CSV and JSON round trips, and clear errors for bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from client.trajectory import Trajectory, TrajectoryError


def sample(velocities: bool = True, accelerations: bool = True) -> Trajectory:
    t = np.array([0.0, 0.5, 1.25])
    q = np.array([[0.0, 0.1, 0.2], [0.3, 0.4, 0.5], [0.6, -0.7, 0.8]])
    return Trajectory(
        t, q, q * 2 if velocities else None, q * 3 if accelerations else None, joint_names=("s", "l", "u")
    )


@pytest.mark.parametrize("suffix", [".csv", ".json"])
@pytest.mark.parametrize("fields", [(True, True), (True, False), (False, False)])
def test_round_trip(tmp_path: Path, suffix: str, fields: tuple[bool, bool]) -> None:
    original = sample(*fields)
    path = tmp_path / f"t{suffix}"
    original.save(path)
    back = Trajectory.load(path)
    assert back.joint_names == ("s", "l", "u")
    np.testing.assert_array_equal(back.times, original.times)
    np.testing.assert_array_equal(back.positions, original.positions)
    for name in ("velocities", "accelerations"):
        a, b = getattr(back, name), getattr(original, name)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)


def test_extra_columns_named_with_a_dot_are_ignored_on_reading(tmp_path: Path) -> None:
    path = tmp_path / "extra.csv"
    path.write_text("time,q1,q2,q1.velocity,q2.velocity,q1.effort,note.source\n0,0,0,0,0,5,1\n1,0.5,0.25,0,0,6,1\n")
    t = Trajectory.load(path)
    assert t.joint_names == ("q1", "q2") and t.velocities is not None and t.accelerations is None
    assert t.positions.tolist() == [[0.0, 0.0], [0.5, 0.25]]


def test_csv_format_is_documented_columns(tmp_path: Path) -> None:
    text = sample(True, False).to_csv()
    assert text.splitlines()[0] == "time,s,l,u,s.velocity,l.velocity,u.velocity"
    path = tmp_path / "plain.csv"
    path.write_text("# a comment\ntime,q1,q2\n0,0,0\n1.5,0.25,-0.5\n")
    t = Trajectory.load(path)
    assert t.dof == 2 and t.duration == 1.5 and t.velocities is None


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        ("a.csv", "", "empty"),
        ("b.csv", "t,q1\n0,0\n", "'time'"),
        ("c.csv", "time,q1\n0,0\n1,x\n", "line 3"),
        ("d.csv", "time,q1\n0,0\n1\n", "line 3"),
        ("e.csv", "time,q1\n0,0\n0,1\n", "increase"),
        ("f.csv", "time,q1\n0.5,0\n1,1\n", "must be 0"),
        ("g.csv", "time,q1\n0,nan\n", "NaN"),
        ("h.json", "{", "JSON"),
        ("i.json", '{"points": []}', "at least one"),
        ("j.json", '{"points": [{"time": 0}]}', "point 0"),
        (
            "k.json",
            '{"points": [{"time": 0, "positions": [0], "velocities": [0]}, {"time": 1, "positions": [1]}]}',
            "some points",
        ),
        ("l.json", '{"points": [{"time": 0, "positions": [0, 1]}, {"time": 1, "positions": [1]}]}', "as many joints"),
        ("m.csv", "time,q1,q2.velocity\n0,0,0\n", "name no joint column"),
        ("n.csv", "time,q1,q2,q1.velocity\n0,0,0,0\n", "some joints only"),
        ("o.csv", "time,q1,q1.velocity,q2\n0,0,0,0\n", "columns must be"),
    ],
)
def test_bad_files_name_the_file_and_the_place(tmp_path: Path, name: str, content: str, words: str) -> None:
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(TrajectoryError, match=words) as info:
        Trajectory.load(path)
    assert name in str(info.value)


def test_missing_file() -> None:
    with pytest.raises(TrajectoryError, match="nosuchfile"):
        Trajectory.load("/nonexistent/nosuchfile.csv")


def test_a_recording_puts_states_read_late_back_in_their_period() -> None:
    from client.trajectory import recording

    # a 100 Hz publisher; the third state was read late, with the fourth
    stamps = [100.0, 100.01, 100.0299, 100.03, 100.04]
    t = recording(stamps, [[0.0], [0.1], [0.2], [0.3], [0.4]])
    assert t.times.tolist() == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])
    assert t.positions[:, 0].tolist() == [0.0, 0.1, 0.2, 0.3, 0.4]
    single = recording([5.0, 5.0], [[0.1], [0.2]])  # two states at one instant: the later one
    assert single.times.tolist() == [0.0] and single.positions[:, 0].tolist() == [0.2]


def test_a_recording_takes_the_controllers_sample_times_where_it_sends_them() -> None:
    from client.trajectory import recording

    # a 25 ms state period on 4 ms servo ticks: samples 24 or 28 ms apart, received on a grid
    true = np.cumsum([0.0, 0.024, 0.028, 0.024, 0.024, 0.028])
    q = [[0.5 * 3.0 * x * x] for x in true]
    received = [10.0 + 0.025 * k for k in range(6)]
    t = recording(received, q, None, ("j",), [7.0 + x for x in true])
    assert t.times.tolist() == pytest.approx(true.tolist(), abs=1e-9)
    again = recording([*received, 10.2], [*q, q[-1]], None, ("j",), [7.0 + x for x in true] + [7.0 + true[-1]])
    assert len(again) == 6  # the same sample sent twice is one state
    # the controller's clock went back (it restarted): the states until it passes the last one kept are left out
    restarted = [7.0 + x for x in true[:3]] + [0.5, 0.6, 7.0 + true[5]]
    assert recording(received, q, None, ("j",), restarted).times.tolist() == pytest.approx([0.0, *true[1:3], true[5]])
    # the first state before the controller took the request for stamps: the recording starts after it
    late = recording(received, q, None, ("j",), [None, *[7.0 + x for x in true[1:]]])
    assert late.times.tolist() == pytest.approx((true[1:] - true[1]).tolist(), abs=1e-9)
    # a state without a stamp in the middle: the receipt times (the slots), not a mix of two clocks
    mixed = recording(received, q, None, ("j",), [7.0, None, *[7.0 + x for x in true[2:]]])
    assert mixed.times.tolist() == pytest.approx([0.025 * k for k in range(6)])


def test_a_recording_without_sample_times_is_timed_by_the_velocities_sent_with_it() -> None:
    from client.trajectory import recording

    # MotoROS sends positions and velocities, no time: a constant acceleration of 3 rad/s^2 sampled
    # 24 or 28 ms apart, received on an even 25 ms grid (and one state read late, with the next)
    true = np.cumsum([0.0, 0.024, 0.028, 0.024, 0.024, 0.028, 0.024, 0.028])
    start = 0.5
    q = [[start + 0.5 * (3.0 * x) * x + 0.4 * x] for x in true]
    v = [[3.0 * x + 0.4] for x in true]
    received = [10.0 + 0.025 * k for k in range(8)]
    received[4] += 0.02
    t = recording(received, q, v, ("j",))
    # every moving segment timed by its distance over its mean speed: exact at a constant acceleration
    assert t.times.tolist() == pytest.approx(true.tolist(), abs=1e-9)
    assert t.velocities is not None
    # standing still, the velocities say nothing: the slots stay
    still = recording(received, [[0.0]] * 8, [[0.0]] * 8, ("j",))
    assert still.times.tolist() == pytest.approx([0.025 * k for k in range(8)])


def test_a_recording_is_timed_by_the_joint_whose_measured_speed_changes_least() -> None:
    """A drive's measured speed is a difference over its last servo period, half a period late: a
    joint braking hard gives a time off by that lag, a cruising one the exact time. The segment is
    timed by the cruising joint, and a state 12 ms after the one before (a round that came late,
    then one on time) keeps that time instead of the slot's."""
    from client.trajectory import recording

    true = np.cumsum([0.0, 0.024, 0.028, 0.012, 0.036, 0.024])
    lag = 0.0005
    # joint 1 brakes at 10 rad/s^2 from 2 rad/s (measured half a millisecond late), joint 2 cruises at 0.7
    q = [[2.0 * x - 5.0 * x * x, 0.7 * x] for x in true]
    v = [[2.0 - 10.0 * (x - lag), 0.7] for x in true]
    received = [3.0 + 0.025 * k for k in range(6)]
    t = recording(received, q, v, ("a", "b"))
    assert t.times.tolist() == pytest.approx(true.tolist(), abs=1e-9)
