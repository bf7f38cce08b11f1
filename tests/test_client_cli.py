"""``robot-client`` as a user runs it: a real process against a real ``robot-server`` process."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from client.trajectory import Trajectory
from tests.test_rs_server_process import ServerProcess, robot_server

pytestmark = pytest.mark.slow


async def client(*args: str, timeout: float = 60.0) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "client",
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    out, err = await asyncio.wait_for(proc.communicate(), timeout)
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


@contextlib.asynccontextmanager
async def server(tmp_path: Path) -> AsyncIterator[tuple[ServerProcess, list[str]]]:
    async with robot_server(tmp_path, "--speedup", "4", "--no-stdin") as proc:
        ports = ["--motion-port", str(proc.ports["motion"]), "--state-port", str(proc.ports["state"])]
        yield proc, ports


async def test_commands_against_robot_server(tmp_path: Path) -> None:
    async with server(tmp_path) as (_, ports):
        code, out, err = await client("ping", "--count", "3", *ports)
        assert code == 0, err
        assert out.count("PING") == 3 and "3 replies" in out

        code, out, err = await client("status", *ports)
        assert code == 0, err
        state = json.loads(out)
        assert state["positions"] == [0.0] * 6
        assert state["status"]["in_motion"] == "FALSE" and state["status"]["drives_powered"] == "TRUE"

        goal = [0.2, 0.1, -0.1, 0.0, 0.5, 0.0]
        code, out, err = await client("move", "--joints", *map(str, goal), *ports)
        assert code == 0, err
        assert out.startswith("done: 2 points")

        code, out, err = await client("status", *ports)
        assert np.allclose(json.loads(out)["positions"], goal, atol=2e-3)

        # a Cartesian move keeps the orientation and reaches the position
        code, out, err = await client("move", "--pose", "0.36", "0.02", "0.12", *ports)
        assert code == 0, err

        path = tmp_path / "back.csv"
        here = np.array(json.loads((await client("status", *ports))[1])["positions"])
        Trajectory(np.array([0.0, 1.0, 2.0]), np.array([here, (here + goal) / 2, goal])).save(path)
        code, out, err = await client("run", str(path), *ports)
        assert code == 0, err
        assert "done: 3 points" in out

        record = tmp_path / "record.csv"
        code, out, err = await client("record", str(record), "--duration", "0.5", *ports)
        assert code == 0, err
        rows = record.read_text().splitlines()
        assert rows[0].startswith("time,position_joint_1") and len(rows) >= 5

        code, out, err = await client("monitor", "--duration", "2.5", *ports)
        assert code == 0, err
        assert "Hz" in out and "in_motion=FALSE" in out

        code, out, err = await client("stop", *ports)
        assert code == 0 and out.strip() == "stopped", err


async def test_failures_exit_non_zero_with_one_line(tmp_path: Path) -> None:
    async with server(tmp_path) as (_, ports):
        code, _, err = await client("move", "--joints", "9", "0", "0", "0", "0", "0", *ports)
        assert code == 1
        assert err.strip().count("\n") == 0 and "outside the joint limits" in err

        bad = tmp_path / "bad.csv"
        bad.write_text("time,a\n0,x\n")
        code, _, err = await client("run", str(bad), *ports)
        assert code == 1 and str(bad) in err and err.strip().count("\n") == 0

        far = tmp_path / "far.csv"
        Trajectory(np.array([0.0, 1.0]), np.array([[0.0] * 6, [3.0] + [0.0] * 5])).save(far)
        code, _, err = await client("run", str(far), *ports)
        assert code == 1 and "refused point 1" in err

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, _, err = await client("status", "--motion-port", str(port), "--state-port", str(port), "--timeout", "1")
    assert code == 1 and "cannot connect" in err and err.strip().count("\n") == 0
    code, _, err = await client("move", "--joints", "1")
    assert code == 2 and "needs 6 values" in err
    code, _, err = await client("move", "--pose", "0.3", "0.1")
    assert code == 2 and "X Y Z" in err
    code, _, err = await client("status", "--model", "no_such_robot")
    assert code == 2 and err.startswith("robot-client:")
    code, _, err = await client("teleport")
    assert code == 2


async def test_demo_command_short_simulated(tmp_path: Path) -> None:
    code, out, err = await client(
        "demo", "--short", "--simulated", "--embedded", "--policies", "linear", "quintic", "--output", str(tmp_path)
    )
    assert code == 0, err
    table = [line.split() for line in out.splitlines() if line.startswith(("linear ", "quintic "))]
    assert [row[0] for row in table] == ["linear", "quintic"]
    quintic = table[1]
    assert quintic[4] == "0"  # acceleration discontinuities
    assert (tmp_path / "demo_linear.csv").exists() and (tmp_path / "demo_quintic.csv").exists()
    assert "traces:" in out
