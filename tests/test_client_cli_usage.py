"""``robot-client`` as a user meets it in the second hour (issue 36): the options every command
takes given before the command, the refusals with the controller's reason and a next step, the
model the controller runs, a recording's replay, the demo against a running controller."""

from __future__ import annotations

import asyncio
import contextlib
import io
import logging
from pathlib import Path

import numpy as np
import pytest

from client import cli
from client.driver import RobotDriver
from client.trajectory import Trajectory
from robot_server.emulator.generic import _WANTS_FEEDBACK
from robot_server.loader import load_model
from tests.stepped import poll
from tests.test_client_cli_inprocess import client, controller


async def test_the_common_options_may_come_before_the_command() -> None:
    async with controller(profile="motoros") as (_emu, ports):
        code, out = await client(*ports, "status")  # --profile motoros --motion-port ... status
        assert code == 0, out
        assert '"positions"' in out


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--count", "3", "ping"], "--count is not an option of robot-client itself: a command's own options go after"),
        (["--timeout", "-1", "status"], "argument --timeout: must be > 0"),
        (["--profile", "motorxs", "status"], "argument --profile: invalid choice: 'motorxs'"),
        (["--profile", "motoros", "stauts"], "argument COMMAND: invalid choice: 'stauts'"),
        (["--mode", "download", "status"], "--mode is not an option of robot-client itself"),  # not --model
    ],
)
def test_a_mistake_before_the_command_is_named_as_it_is(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv, io.StringIO())
    assert exit_.value.code == cli.EXIT_USAGE
    assert says in capsys.readouterr().err


async def test_the_demo_against_a_running_controller_names_the_options_it_does_not_use(tmp_path: Path) -> None:
    async with controller() as (_emu, ports):
        code, out = await client(
            "demo", *ports, "--short", "--simulated", "--policies", "quintic", "ruckig", "--no-plot", "--no-movl",
            "--output", str(tmp_path),
        )  # fmt: skip
    assert code == 0, out
    assert "a controller answers at 127.0.0.1:" in out
    assert (
        "ignored here: --simulated, --policies quintic ruckig (they choose how the embedded emulator runs; a "
        "running controller interpolates its own way, in real time): add --embedded to run them"
    ) in out
    docs = (Path(__file__).parents[1] / "docs" / "demo.md").read_text()
    shown = next(line for line in docs.splitlines() if line.startswith("ignored here:"))
    assert shown in out  # the docs show what the command prints


async def test_the_demo_says_nothing_is_ignored_when_nothing_is(tmp_path: Path) -> None:
    async with controller() as (_emu, ports):
        code, out = await client("demo", *ports, "--short", "--no-plot", "--no-movl", "--output", str(tmp_path))
    assert code == 0, out
    assert "ignored here" not in out


@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_a_second_motion_client_is_told_that_another_client_moves_the_robot(
    profile: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    model = load_model("jibot_zxs")
    elsewhere = tmp_path / "elsewhere.csv"
    Trajectory(np.array([0.0, 2.0]), np.array([[0.0] * 6, [0.2] * 6]), joint_names=model.joint_names).save(elsewhere)
    async with controller(profile=profile, speedup=1.0) as (emu, ports):
        owner = RobotDriver("127.0.0.1", emu.ports["motion"], emu.ports["state"], profile=profile, model=model)
        await owner.connect(10.0)
        start = owner.joint_state
        assert start is not None
        goal = start.positions.copy()
        goal[0] += 1.0
        slow = Trajectory(np.array([0.0, 60.0]), np.stack([start.positions, goal]))  # moving for the whole test
        moving = asyncio.get_running_loop().create_task(owner.execute(slow))
        try:
            await poll(lambda: emu.cell.in_motion, 10.0)
            for argv in (
                ["move", "--joints", "0", "0", "0", "0", "0", "0"],
                ["move", "--pose", "0.3", "0", "0.3"],
                ["run", str(elsewhere)],  # the driver's own check (RobotDriver.execute)
            ):
                code, _ = await client(*argv, *ports)
                err = capsys.readouterr().err
                assert code == cli.EXIT_FAILED
                assert "another motion client is moving the robot: the controller closed this client's motion " in err
                assert "away from the robot's position" not in err
            assert emu.owner.refused >= 3
            assert emu.cell.in_motion  # the owner's motion runs on
        finally:
            moving.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await moving
            await owner.close()


@pytest.mark.parametrize(("profile", "compared"), [("generic", "TOOL_POSE"), ("motoros", "D-H table")])
async def test_a_pose_move_with_a_model_that_is_not_the_controllers_is_refused_naming_model(
    profile: str, compared: str, capsys: pytest.CaptureFixture[str]
) -> None:
    async with controller(profile=profile, models=("puma560",)) as (emu, ports):
        code, out = await client("move", "--joints", "0", "0.3", "-0.2", "0", "0.9", "0", "--model", "puma560", *ports)
        assert code == 0, out  # out of the wrist singularity of the zero pose
        before = np.array(emu.cell.groups[0].command.command_position)
        code, out = await client("move", "--pose", "0.4", "0.05", "0.2", *ports)  # --model jibot_zxs, the default
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert "robot-client: --model jibot_zxs is not the controller's robot: " in err
        assert "give --model the model the controller runs" in err
        assert err.rstrip().endswith(", or --no-model-check to skip this check"), err  # and how to skip the check
        assert (compared == "TOOL_POSE") == ("mm and" in err)  # TOOL_POSE: how far apart the tools are
        assert np.array_equal(np.array(emu.cell.groups[0].command.command_position), before)  # nothing moved
        code, out = await client("move", "--pose", "0.5", "0.1", "0.3", "--model", "puma560", *ports)
        assert code == 0, capsys.readouterr().err
        assert "note:" not in out  # the controller said which robot it drives


async def test_a_controller_that_says_nothing_of_its_model_gets_a_note_that_the_result_rests_on_model() -> None:
    async with controller(profile="abb") as (_emu, ports):
        code, out = await client("move", "--joints", "0", "0.3", "-0.2", "0", "0.9", "0", *ports)
        assert code == 0, out
        code, out = await client("move", "--pose", "0.45", "0.05", "0.4", *ports)
    assert code == 0, out
    assert out.count("note: the controller says nothing about its robot model") == 1
    assert "the Cartesian result rests on --model jibot_zxs being the controller's robot" in out


async def test_a_refused_line_says_where_as_the_controller_does_and_what_runs_instead(
    capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    kuka = ["--model", "kuka_kr6_r900_sixx"]
    async with controller(models=("kuka_kr6_r900_sixx",)) as (_emu, ports):
        code, out = await client("move", "--joints", "0", "-1.2", "1.2", "0", "0.5", "0", *kuka, *ports)
        assert code == 0, out
        code, out = await client("move", "--pose", "0.5", "0", "0.3", "--linear", *kuka, *ports)
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert "the controller refused line 0: SINGULAR (it passes a singularity)" in err
        # where and how close: the controller's own words, which only its log had
        logged = next(r.getMessage() for r in caplog.records if "CARTESIAN_LINE 0 refused" in r.getMessage())
        where = logged.split("singular: ", 1)[1]
        assert where.startswith("line 0 passes a singularity at (0.6135, 0.0000, 0.6283) m (38% along")
        assert f"by the client's check of the line on its model: {where}" in err
        assert "instead: without --linear (the same straight line planned on the PC) it runs; or by joints" in err
        suggested = err.split("robot-client move --joints ", 1)[1].split()[:6]
        code, out = await client("move", "--pose", "0.5", "0", "0.3", *kuka, *ports)  # without --linear: it runs
        assert code == 0, capsys.readouterr().err
        code, out = await client("move", "--joints", "0", "-1.2", "1.2", "0", "0.5", "0", *kuka, *ports)
        assert code == 0, out
        code, out = await client("move", "--joints", *suggested, *kuka, *ports)  # the suggestion runs too
        assert code == 0, capsys.readouterr().err


async def test_a_recording_keeps_the_controllers_times_and_run_approach_goes_to_its_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    states = tmp_path / "states.csv"
    async with controller(speedup=2.0) as (emu, ports):
        recorder = asyncio.get_running_loop().create_task(
            client("record", str(states), "--duration", "2", *ports, out=io.StringIO())
        )
        await poll(lambda: any(s.data.get(_WANTS_FEEDBACK) for s in emu.state_sessions()), 10.0)  # recording
        code, out = await client(
            "move", "--joints", "0.8", "0.4", "-0.4", "0.2", "0.4", "0.1", "--speed", "0.5", *ports
        )
        assert code == 0, out
        code, out = await recorder
        assert code == 0, out
        recorded = Trajectory.load(states)
        # the controller's own sample times (JOINT_FEEDBACK's): whole servo ticks, not an even grid
        ticks = np.diff(recorded.times) / emu.cell.config.servo_period
        assert np.allclose(ticks, np.round(ticks), atol=1e-3)
        assert recorded.velocities is not None
        code, _ = await client("run", str(states), *ports)  # the robot is at the recording's end
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED
        assert f"{states} starts " in err and "add --approach to move there first" in err
        code, out = await client("run", str(states), "--approach", *ports)
        assert code == 0, capsys.readouterr().err
        assert f"approach: to the start of {states}, " in out
        end = np.array(emu.cell.groups[0].command.command_position)
        assert np.max(np.abs(end - recorded.positions[-1])) < 1e-3


async def test_the_controller_log_says_a_straight_line_ended_not_the_trajectory_before_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="robot_server.emulator.cell")
    async with controller() as (_emu, ports):
        code, out = await client("move", "--joints", "0", "0.3", "-0.2", "0", "0.9", "0", *ports)
        assert code == 0, out
        code, out = await client("move", "--pose", "0.3", "0.05", "0.1", "--linear", *ports)
        assert code == 0, out
    done = [r.getMessage() for r in caplog.records if " done: " in r.getMessage()]
    assert len(done) == 2, done
    assert done[0].startswith("group 0: trajectory 1 done: 2 points, settled after "), done
    assert done[1].startswith("group 0: straight lines done: 1 line, settled after "), done


async def test_the_demo_against_a_controller_with_another_robot_is_refused_naming_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async with controller(models=("puma560",)) as (_emu, ports):
        code, _ = await client("demo", *ports, "--short", "--no-plot", "--output", str(tmp_path))
    assert code == cli.EXIT_FAILED
    err = capsys.readouterr().err
    assert "robot-client: --model jibot_zxs is not the controller's robot: " in err
    assert err.rstrip().endswith(", or --no-model-check to skip this check")  # demo takes it too
    assert cli.parser().parse_args(["demo", "--no-model-check"]).no_model_check is True


@pytest.mark.parametrize("attempt", range(4))
async def test_motoros_resets_an_alarm_at_start_traj_mode_and_the_run_is_not_aborted_by_a_stale_status(
    attempt: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # START_TRAJ_MODE resets the alarm; a STATUS published before it, read after its reply, showed
    # the alarm and aborted the run now and then (it depends on the two connections' timing)
    async with controller(profile="motoros") as (emu, ports):
        emu.cell.alarm(1234, "test")
        path = tmp_path / "path.csv"
        path.write_text("time,q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0,0\n1,0.1,0,0,0,0,0\n")
        code, out = await client("run", str(path), *ports)
        assert code == 0, capsys.readouterr().err
        assert out.startswith("done: 2 points")
