"""The paper's experiment, short form on a simulated clock: its table must show what the paper says."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from client.demo import GLOSSARY, MOVL, DemoConfig, analyse, corner_error, format_table, run_demo
from client.trajectory import Trajectory
from robot_server.loader import load_model

pytestmark = pytest.mark.slow

MODEL = load_model("jibot_zxs")


async def test_short_demo_table(tmp_path: Path) -> None:
    lines: list[str] = []
    config = DemoConfig(width=0.06, height=0.04, simulated=True, host=None, output=tmp_path, plot=False)
    result = await run_demo(config, progress=lines.append)
    rows = {row.policy: row for row in result.rows}
    assert list(rows) == ["linear", "cubic", "quintic", "ruckig", MOVL]
    waypoints = len(result.waypoints)
    assert waypoints >= 9  # 200 mm of edges, a waypoint every 25 mm
    # the paper's point: without interpolation the acceleration jumps at (nearly) every waypoint ...
    assert rows["linear"].discontinuities >= waypoints - 4
    # ... the rest-to-rest cubic still jumps at the waypoints, the quintic never does
    assert rows["cubic"].discontinuities >= waypoints // 2
    assert rows["quintic"].discontinuities == 0
    # ruckig keeps the jerk limit; linear's velocity steps are huge accelerations
    assert rows["ruckig"].peak_jerk <= MODEL.max_jerk.max() * (1 + 1e-6)
    assert rows["ruckig"].discontinuities == 0
    assert rows["linear"].peak_acceleration > 3 * rows["quintic"].peak_acceleration
    # the controller's own straight lines, at the planned rows' nominal TCP speed, exact stops:
    # smooth (jerk-limited in the TCP), no discontinuities, and the same cycle time as the others
    assert rows[MOVL].discontinuities == 0 and rows[MOVL].peak_jerk <= MODEL.max_jerk.max()
    for row in result.rows:
        assert 0.0 < row.path_deviation < 2e-3  # within 2 mm of the rectangle
        assert 0.0 <= row.corner_error < 1e-3  # every row stops at the corners: within 1 mm of each
        assert row.following_error is not None and 0.0 < row.following_error < 0.05
        assert row.cycle_time == pytest.approx(result.waypoints.duration, abs=0.5)
    # the files: planned waypoints and one trace per row, with their headers
    names = {f.name for f in result.files}
    assert names == {
        "demo_waypoints.csv",
        "demo_linear.csv",
        "demo_cubic.csv",
        "demo_quintic.csv",
        "demo_ruckig.csv",
        "demo_movl.csv",
    }
    with (tmp_path / "demo_quintic.csv").open() as stream:
        header = next(csv.reader(stream))
    assert header[:2] == ["time", "joint_1"] and "joint_1.command_position" in header
    trace = Trajectory.load(tmp_path / "demo_quintic.csv")  # the one layout: a trace loads as a trajectory
    assert trace.velocities is not None and trace.accelerations is not None
    table = format_table(result.rows)
    header = table.splitlines()[0]
    assert header.startswith("policy") and "corner error (mm)" in header
    assert len(table.splitlines()) == 6 + 1 + len(GLOSSARY)
    assert any(line.startswith(f"{MOVL} ") for line in table.splitlines())
    # one definition of the acceleration: the table's peak is the trace's drive_acceleration column's
    for policy in ("linear", "quintic"):
        with (tmp_path / f"demo_{policy}.csv").open() as stream:
            reader = csv.DictReader(stream)
            columns = [f"{name}.drive_acceleration" for name in MODEL.joint_names]
            peak = max(abs(float(row[c])) for row in reader for c in columns if row[c])
        assert peak == pytest.approx(rows[policy].peak_acceleration, rel=1e-9), policy
    assert any("embedded emulator" in line for line in lines)
    assert any(line.startswith(f"{MOVL}: done in") for line in lines)


def test_analyse_counts_steps_and_impulses() -> None:
    """A synthetic record: one velocity step (an impulse of acceleration) is one discontinuity."""
    dt = 0.004
    t = np.arange(500) * dt
    v = np.where(t < 1.0, 0.1, 0.2)
    q = np.cumsum(v)[:, None] * dt * np.ones((1, 6))
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    row = analyse("synthetic", MODEL, corners, times=t, command=q, actual=q, following_error=None)
    assert row.discontinuities == 1
    assert row.peak_acceleration == pytest.approx(0.1 / dt, rel=1e-6)
    assert row.following_error is None


def test_corner_error_is_the_distance_from_each_corner_to_the_path() -> None:
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])  # closed
    # a path through the first two corners that cuts the third by 0.1 (its closest point: (0.9, 0.9))
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.8, 0.0], [0.8, 1.0, 0.0], [0.0, 0.0, 0.0]])
    assert corner_error(path, corners) == pytest.approx(np.hypot(0.1, 0.1))
    # between samples counts: the corner lies on a segment of the path
    assert corner_error(np.array([[-1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), corners[:2]) == 0.0
    assert corner_error(np.array([[0.0, 0.0, 0.5]]), corners[:1]) == pytest.approx(0.5)
