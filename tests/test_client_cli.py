"""``robot-client`` as a user runs it: a real process against a real ``robot-server`` process.

These prove the installed entry point and the two processes together; every command and failure
is tested in process (coverage, speed) in tests/test_client_cli_inprocess.py."""

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
        names = state["status"]["names"]
        assert names["in_motion"] == "FALSE" and names["drives_powered"] == "TRUE"

        goal = [0.2, 0.1, -0.1, 0.0, 0.5, 0.0]
        code, out, err = await client("move", "--joints", *map(str, goal), *ports)
        assert code == 0, err
        assert out.startswith("done: 2 points")

        code, out, err = await client("status", *ports)
        assert np.allclose(json.loads(out)["positions"], goal, atol=2e-3)

        code, out, err = await client("stop", *ports)
        assert code == 0 and out.strip() == "stopped", err


async def test_failures_exit_non_zero_with_one_line(tmp_path: Path) -> None:
    async with server(tmp_path) as (_, ports):
        code, _, err = await client("move", "--joints", "9", "0", "0", "0", "0", "0", *ports)
        assert code == 1
        assert err.strip().count("\n") == 0 and "outside the joint limits" in err

    with socket.socket() as closed:  # bound, not listening: every connection is refused
        closed.bind(("127.0.0.1", 0))
        port = str(closed.getsockname()[1])
        code, _, err = await client("status", "--motion-port", port, "--state-port", port, "--timeout", "1")
    assert code == 1 and "cannot connect" in err and err.strip().count("\n") == 0
    code, _, err = await client("move", "--joints", "1")
    assert code == 2 and "needs 6 values" in err and err.startswith("robot-client:")
    code, _, err = await client("teleport")
    assert code == 2 and "invalid choice" in err
