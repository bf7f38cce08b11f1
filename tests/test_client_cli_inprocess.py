"""``robot-client`` in process: ``main(argv, out)`` for every command against an emulator on
127.0.0.1 (free ports), and the failures a user meets (exit status 1 with one line, 2 for usage).

``main`` runs its own event loop (``asyncio.run``), so it runs in a worker thread while the
emulator serves on the test's loop. tests/test_client_cli.py runs the installed command as a
process against a ``robot-server`` process.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import io
import json
import runpy
import socket
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from client import cli
from client.trajectory import Trajectory
from robot_server.emulator import Emulator, EmulatorConfig
from simple_message.constants import RobotMode
from tests.fakecontroller import JOINT_TRAJ_PT, FakeController, Reply
from tests.rawpeer import Frame
from tests.stepped import poll

#: bound of one command (s of wall time): the moves below take well under a second
COMMAND_TIMEOUT = 60.0


class Terminal(io.StringIO):
    """An output that says it is a terminal (the commands draw a progress line there)."""

    def isatty(self) -> bool:
        return True


async def client(*argv: str, out: io.StringIO | None = None) -> tuple[int, str]:
    """``robot-client argv`` in a worker thread: its exit status and what it printed."""
    out = out if out is not None else io.StringIO()
    async with asyncio.timeout(COMMAND_TIMEOUT):
        code = await asyncio.to_thread(cli.main, list(argv), out)
    return code, out.getvalue()


@contextlib.asynccontextmanager
async def controller(**options: Any) -> AsyncIterator[tuple[Emulator, list[str]]]:
    """An emulator on free loopback ports (8x real time), and the options that reach it."""
    options.setdefault("speedup", 8.0)
    config = EmulatorConfig(motion_port=0, state_port=0, io_port=0, state_rate=100.0, **options)
    async with Emulator(config) as emu:
        ports = ["--motion-port", str(emu.ports["motion"]), "--state-port", str(emu.ports["state"])]
        if config.profile != "generic":
            ports += ["--profile", config.profile]
        yield emu, ports


def positions(emu: Emulator) -> np.ndarray:
    return np.array(emu.cell.groups[0].command.actual_position)


@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_the_watching_commands_never_take_the_motion_port_from_its_client(profile: str, tmp_path: Path) -> None:
    # a controller serves one motion client, and a newcomer at rest replaces an idle one (MotoROS's
    # rule): status, monitor and record only watch, so they connect the state port alone
    async with controller(profile=profile) as (emu, ports):
        _, writer = await asyncio.open_connection("127.0.0.1", emu.ports["motion"])
        try:
            await poll(lambda: emu.owner.owner is not None, 10.0)
            owner = emu.owner.owner
            for argv in (
                ["status"],
                ["monitor", "--duration", "0.2"],
                ["record", "--duration", "0.2", str(tmp_path / "r.csv")],
            ):
                code, out = await client(*argv, *ports)
                assert code == 0, out
                assert emu.owner.owner is owner and not owner.connection.closed, argv
        finally:
            writer.close()


REFUSALS = [
    ("estop", "the controller is e-stopped"),
    ("drives_off", "the drives are off"),
    ("alarm", "it is in error (code 42)"),
    ("manual", "it is in MANUAL mode"),
]


#: MotoROS's START_TRAJ_MODE, which the driver sends when the controller is not ready, turns the
#: drives on and resets alarms itself: only an e-stop and MANUAL mode keep it from moving
CASES = [("generic", *r) for r in REFUSALS] + [("motoros", *r) for r in REFUSALS if r[0] in ("estop", "manual")]


@pytest.mark.parametrize(("profile", "fault", "says"), CASES, ids=[f"{p}-{f}" for p, f, _ in CASES])
async def test_every_refusal_says_why(
    profile: str, fault: str, says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async with controller(profile=profile) as (emu, ports):
        cell = emu.cell
        {"estop": cell.estop, "drives_off": cell.drives_off, "alarm": lambda: cell.alarm(42, "test"),
         "manual": lambda: cell.set_mode(RobotMode.MANUAL)}[fault]()  # fmt: skip
        path = tmp_path / "path.csv"
        path.write_text("time,q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0,0\n1,0.1,0,0,0,0,0\n")
        code, _ = await client("run", str(path), *ports)
        err = capsys.readouterr().err
        assert code == 1 and says in err, err
        assert positions(emu)[0] == 0.0  # nothing moved


@pytest.mark.parametrize(
    ("rows", "says"),
    [
        ("0,0,0,0,0,0,0\n1,20,0,0,0,0,0", "point 1: joint 1 (joint_1) at 20 is beyond its upper limit 2.967 rad"),
        ("0,0,0,0,0,0,0\n0.01,1,0,0,0,0,0", "segment 0->1: joint 1 (joint_1) would move at 100 rad/s on average"),
    ],
    ids=["beyond a limit", "too fast"],
)
async def test_a_trajectory_beyond_the_models_limits_is_refused_before_anything_is_sent(
    rows: str, says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async with controller() as (emu, ports):
        path = tmp_path / "path.csv"
        path.write_text(f"time,q1,q2,q3,q4,q5,q6\n{rows}\n")
        code, _ = await client("run", str(path), *ports)
        err = capsys.readouterr().err
        assert code == 1 and says in err, err
        assert emu.cell.groups[0].points_accepted == 0  # nothing reached the controller


@pytest.mark.parametrize("feedback", [False, True], ids=["JOINT_POSITION", "JOINT_POSITION and JOINT_FEEDBACK"])
async def test_record_writes_one_sample_per_state_round(feedback: bool, tmp_path: Path) -> None:
    # a round is JOINT_POSITION (and JOINT_FEEDBACK) and STATUS: each used to be a sample of its
    # own, copies 0.2 ms apart; counted against the rounds the emulator sent, not the clock
    async with controller(feedback=feedback) as (emu, ports):
        before = emu.state_stats.sent
        path = tmp_path / "rec.csv"
        code, out = await client("record", "--duration", "0.5", str(path), *ports)
        rounds = emu.state_stats.sent - before
        assert code == 0, out
        samples = len(path.read_text().splitlines()) - 1
        assert 0 < samples <= rounds, (samples, rounds)


async def test_ping_status_stop_and_monitor(capsys: pytest.CaptureFixture[str]) -> None:
    async with controller() as (_, ports):
        code, out = await client("ping", "--count", "3", *ports)
        assert code == 0
        lines = out.splitlines()
        assert [line.split(":")[0] for line in lines[:3]] == ["PING 1", "PING 2", "PING 3"]
        assert lines[3].startswith("3 replies, min/median/max")

        code, out = await client("status", *ports)
        assert code == 0
        state = json.loads(out)
        assert state["positions"] == [0.0] * 6 and state["velocities"] is None  # the same keys in every profile
        # the STATUS as simple-message decode prints it: numbers in body, symbolic names beside
        assert state["status"]["name"] == "STATUS"
        assert state["status"]["body"] == {
            "drives_powered": 1,
            "e_stopped": 0,
            "error_code": 0,
            "in_error": 0,
            "in_motion": 0,
            "mode": 2,
            "motion_possible": 1,
        }
        assert state["status"]["names"] == {
            "comm_type": "TOPIC",
            "reply_code": "INVALID",
            "drives_powered": "TRUE",
            "e_stopped": "FALSE",
            "in_error": "FALSE",
            "in_motion": "FALSE",
            "mode": "AUTO",
            "motion_possible": "TRUE",
        }

        code, out = await client("stop", *ports)
        assert (code, out) == (0, "stopped\n")

        # a rate line per second of states
        code, out = await client("monitor", "--duration", "1.5", *ports)
        assert code == 0
        assert " Hz  q=[+0.0000 " in out and "in_motion=FALSE in_error=FALSE e_stopped=FALSE drives=TRUE" in out
    assert capsys.readouterr().err == ""


async def test_move_to_joints_then_along_a_line_and_run_a_file(tmp_path: Path) -> None:
    goal = [0.2, 0.1, -0.1, 0.0, 0.5, 0.0]
    async with controller() as (emu, ports):
        code, out = await client("move", "--joints", *map(str, goal), *ports)
        assert code == 0 and out.startswith("done: 2 points")
        assert np.allclose(positions(emu), goal, atol=2e-3)

        # a Cartesian move that keeps the orientation, drawn with a progress bar on a terminal
        terminal = Terminal()
        code, out = await client("move", "--pose", "0.34", "0.05", "0.06", "--speed", "0.5", *ports, out=terminal)
        assert code == 0
        assert out.startswith("\r[") and "rad from goal" in out and "\ndone: " in out

        # a pose with an orientation (about the one above), downloaded
        pose = ["0.35", "0.06", "0.04", "-3.1416", "-0.5", "0.2"]
        code, out = await client("move", "--pose", *pose, "--mode", "download", *ports)
        assert code == 0, out

        here = positions(emu)
        path = tmp_path / "back.csv"
        Trajectory(np.array([0.0, 0.5, 1.0]), np.array([here, (here + goal) / 2, goal])).save(path)
        code, out = await client("run", str(path), *ports)
        assert code == 0 and out.startswith("done: 3 points")
        assert np.allclose(positions(emu), goal, atol=2e-3)


@pytest.mark.slow
async def test_a_recording_is_replayed_by_run_as_it_is(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # record a move another client makes, then run the recording: the robot goes the same way
    record = tmp_path / "record.csv"
    goal = np.array([0.3, -0.2, 0.1, 0.0, 0.2, 0.0])
    async with controller(speedup=1.0) as (emu, ports):  # a recording is in wall-clock time
        recorder = asyncio.create_task(client("record", str(record), "--duration", "4", *ports))
        code, out = await client("move", "--joints", *map(str, goal), *ports)
        assert code == 0, capsys.readouterr().err
        code, out = await recorder
        assert code == 0
        rows = record.read_text().splitlines()
        assert out == f"{len(rows) - 1} joint states written to {record} (replay it with: run {record})\n"
        # the emulator sends JOINT_FEEDBACK to a recorder (it asks): velocities too, and the sample times
        names = [f"joint_{j}" for j in range(1, 7)]
        assert rows[0] == ",".join(["time", *names, *(f"{n}.velocity" for n in names)])
        assert rows[1].startswith("0.0,")  # a trajectory's first time
        recorded = Trajectory.load(record)
        assert np.allclose(recorded.positions[-1], goal, atol=2e-3)
        code, out = await client("move", "--joints", *map(str, recorded.positions[0]), *ports)  # back to its start
        assert code == 0, capsys.readouterr().err
        code, out = await client("run", str(record), *ports)
        assert code == 0 and out.startswith(f"done: {len(recorded)} points"), (out, capsys.readouterr().err)
        assert np.allclose(positions(emu), goal, atol=2e-3)


async def test_motoros_move(capsys: pytest.CaptureFixture[str]) -> None:
    async with controller(profile="motoros") as (emu, ports):
        code, out = await client("move", "--joints", "0.1", "0", "0", "0", "0", "0.1", *ports)
        assert code == 0, capsys.readouterr().err
        assert out.startswith("done: ") and np.allclose(positions(emu)[[0, 5]], 0.1, atol=2e-3)
        code, out = await client("stop", *ports)
        assert (code, out) == (0, "stopped\n")


async def test_failures_exit_1_or_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    def one_line() -> str:
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("robot-client: "), err
        return err

    async with controller() as (emu, ports):
        assert (await client("move", "--joints", "9", "0", "0", "0", "0", "0", *ports))[0] == 1
        assert "outside the joint limits" in one_line()

        bad = tmp_path / "bad.csv"
        bad.write_text("time,a\n0,x\n")
        assert (await client("run", str(bad), *ports))[0] == 2  # bad input, nothing sent: a usage error
        assert str(bad) in one_line()

        far = tmp_path / "far.csv"
        Trajectory(np.array([0.0, 1.0]), np.array([[0.0] * 6, [3.0] + [0.0] * 5])).save(far)
        assert (await client("run", str(far), *ports))[0] == 1
        assert "point 1: joint 1 (joint_1) at 3 is beyond its upper limit" in one_line()

        elsewhere = tmp_path / "elsewhere.csv"
        Trajectory(np.array([0.0, 1.0]), np.array([[0.5] * 6, [0.6] * 6])).save(elsewhere)
        assert (await client("run", str(elsewhere), *ports))[0] == 1
        assert (
            f"{elsewhere} starts 0.5 rad away from the robot's position (tolerance 0.01): add --approach" in one_line()
        )

        emu.cell.estop()
        assert (await client("move", "--joints", "0.1", "0", "0", "0", "0", "0", *ports))[0] == 1
        one_line()
        assert not emu.cell.in_motion

    with socket.socket() as closed:  # bound, not listening: every connection is refused
        closed.bind(("127.0.0.1", 0))
        port = str(closed.getsockname()[1])
        # refused is said at once, as refused (it used to wait out the timeout and say "timed out")
        code, _ = await client("ping", "--motion-port", port, "--state-port", port, "--timeout", "30")
    assert code == 1
    assert f"cannot connect to motion 127.0.0.1:{port}: connection refused (is the controller" in one_line()


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["move", "--joints", "1"], "needs 6 values"),
        (["move", "--pose", "0.3", "0.1"], "X Y Z"),
        (["move", "--joints", "0", "0", "0", "0", "0", "nan"], "finite"),
        (["move", "--joints", *["0"] * 6, "--speed", "1.5"], "--speed must be in (0, 1]"),
        (["status", "--model", "no_such_robot"], "no_such_robot"),
        (["demo", "--serial", "/dev/null"], "--serial is not supported"),
        (["demo", "--policies", "no_such_policy"], "no_such_policy"),
        (["status", "--import", "tests.no_such_module"], "cannot import tests.no_such_module"),
    ],
)
def test_bad_arguments_exit_2_before_connecting(
    argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(argv, io.StringIO()) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("robot-client: ") and words in err, err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["teleport"], "invalid choice"),
        (["status", "--timeout", "0"], "must be > 0"),
        (["status", "--timeout", "inf"], "must be > 0"),
        (["status", "--motion-port", "0"], "a port is 1..65535"),
        (["move"], "one of the arguments --joints --pose is required"),
    ],
)
def test_malformed_arguments_are_usage_errors(argv: list[str], words: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    assert words in capsys.readouterr().err


def test_help_names_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for command in ("ping", "status", "monitor", "move", "run", "stop", "record", "demo"):
        assert f"    {command} " in out, command


@pytest.mark.usefixtures("plain_imports")
def test_python_dash_m_client_is_the_command(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sys, "argv", ["client", "move", "--joints", "1"])
    with pytest.raises(SystemExit) as info:
        runpy.run_module("client", run_name="__main__", alter_sys=True)
    assert info.value.code == 2
    assert "needs 6 values" in capsys.readouterr().err


@pytest.fixture(scope="session")
def plotting() -> bool:
    """Whether the plot extra (matplotlib) is installed. Its fonts are opened here, once: its font
    cache keeps them open for the life of the process, and a session fixture is set up before the
    leak guard looks at a test's descriptors."""
    if importlib.util.find_spec("matplotlib") is None:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = plt.figure()
    figure.text(0.5, 0.5, "rad/s²")
    figure.canvas.draw()
    plt.close(figure)
    return True


@pytest.mark.slow
def test_demo_without_a_controller_runs_the_embedded_emulator_and_draws_the_figure(
    tmp_path: Path, plotting: bool
) -> None:
    out = io.StringIO()
    argv = ["demo", "--short", "--simulated", "--policies", "linear", "quintic", "--output", str(tmp_path)]
    with socket.socket() as closed:  # where the demo looks for a controller first: refused
        closed.bind(("127.0.0.1", 0))
        port = str(closed.getsockname()[1])
        assert cli.main([*argv, "--motion-port", port, "--state-port", port], out) == 0
    text = out.getvalue()
    table = [line.split() for line in text.splitlines() if line.startswith(("linear ", "quintic "))]
    assert [row[0] for row in table] == ["linear", "quintic"]
    assert table[1][4] == "0"  # the quintic's acceleration discontinuities
    assert "linear: embedded emulator (simulated clock) ..." in text
    assert f"traces: {tmp_path / 'demo_waypoints.csv'}" in text
    assert (tmp_path / "demo_linear.csv").exists() and (tmp_path / "demo_quintic.csv").exists()
    if plotting:
        assert f"figure: {tmp_path / 'demo_fig6.png'}" in text and (tmp_path / "demo_fig6.png").stat().st_size > 0
    else:
        assert "figure: not drawn" in text


async def test_demo_runs_the_rectangle_on_a_controller_that_answers(tmp_path: Path) -> None:
    """The scripted fake controller (tests/fakecontroller.py) answers each point 30 ms late and
    jumps to it: the demo runs its rectangle there and reports on the joint states it saw."""

    def late_success(_frame: Frame, _count: int) -> Reply:
        return Reply("success", delay=0.03)

    async with FakeController(late_success) as fake:
        ports = ["--motion-port", str(fake.ports["motion"]), "--state-port", str(fake.ports["state"])]
        code, out = await client("demo", "--short", "--no-plot", "--output", str(tmp_path), *ports)
        assert code == 0, out
        assert fake.overlapping == 0
        points = fake.frames(JOINT_TRAJ_PT)
    assert f"a controller answers at 127.0.0.1:{ports[1]}: running the rectangle there" in out
    assert len(points) > 11  # the approach, then the rectangle's waypoints
    row = next(line.split() for line in out.splitlines() if line.startswith("controller's own"))
    assert len(row) == 9 and row[-1] == "n/a"  # no following error from joint states alone
    assert "controller MOVL: skipped" in out  # the fake does not answer CARTESIAN_LINE
    lines = (tmp_path / "demo_controller.csv").read_text().splitlines()
    assert lines[0].startswith("time,") and len(lines) > 4


async def test_an_internal_error_is_one_line_not_a_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    async def broken(*_: object) -> None:
        raise ValueError("the record is too short to analyse")

    monkeypatch.setattr(cli, "_with_driver", broken)
    code, _ = await client("status", "--motion-port", "1", "--state-port", "1")
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert err.startswith("robot-client: internal error: ValueError: the record is too short to analyse"), err


async def test_watching_commands_say_when_the_controller_closed_the_connection(
    capsys: pytest.CaptureFixture[str],
) -> None:
    async with controller() as (emu, ports):
        recording = asyncio.create_task(client("monitor", "--duration", "30", *ports))
        # watching: the client connected, had its first state and asked for TOOL_POSE on the state port
        # (a session alone may still be the client connecting, whose end reads as a refused connection)
        await poll(lambda: any(s.data.get("tool_pose") for s in emu.state_server.sessions), 10.0)
        await emu.state_server.close()  # the controller goes away
        code, _ = await recording
    err = capsys.readouterr().err
    assert code == 1 and "the controller closed the state connection" in err, err


async def test_run_takes_the_columns_by_joint_name(tmp_path: Path) -> None:
    async with controller() as (emu, ports):
        path = tmp_path / "named.csv"
        names = [f"joint_{j}" for j in range(6, 0, -1)]  # the robot's joints, in reverse order
        path.write_text("time," + ",".join(names) + "\n0,0,0,0,0,0,0\n1,0.3,0,0,0,0,0\n")
        code, out = await client("run", str(path), *ports)
        assert code == 0, out
        assert np.allclose(positions(emu), [0, 0, 0, 0, 0, 0.3], atol=2e-3)  # joint_6 moved, not joint_1
        bad = tmp_path / "bad.csv"
        bad.write_text("time,a,b,c,d,e,f\n0,0,0,0,0,0,0\n")
        assert (await client("run", str(bad), *ports))[0] == 2  # names no joint of the robot: bad input
