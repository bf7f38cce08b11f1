"""The review of issue 36's client side: the next step after a refused straight line follows the
controller's reason; Ctrl-C during ``robot-client demo`` stops the robot and says where it rests
(and says so when it was not moving); a mistake before the command is named as it is; the D-H
comparison with a MotoROS controller counts the axes, takes angles modulo a turn and names
``--no-model-check``.

The commands run against an emulator on free loopback ports: in process (``main()`` in a worker
thread, tests/test_client_cli_inprocess.py), or, for the real signals, ``robot-client`` as a
process (with ``robot-server`` as a process, as tests/test_fault_matrix.py does, or the emulator in
process on a clock the test advances). Every wait is bounded.
"""

from __future__ import annotations

import asyncio
import io
import logging
import math
import signal
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from client import cli
from client.advice import after_refusal
from client.demo import DemoConfig, plan_rectangle
from client.identity import ModelMismatch, check_model
from client.planner import Planner
from client.trajectory import Trajectory
from robot_server.kinematics import fk
from robot_server.loader import load_model
from robot_server.model import RobotModel
from simple_message.constants import LineResult
from simple_message.dialects import dialect
from simple_message.messages import DhLink, GetDhParametersReply
from tests.stepped import poll, settle, stepped_emulator
from tests.test_client_cli_inprocess import client, controller
from tests.test_fault_matrix import FAR, FAR_SECONDS, HOME, SIGNAL_IDS, SIGNALS, Watch, dist, server

ROOT = Path(__file__).resolve().parent.parent
#: off the wrist singularity of q = 0 (the rectangle's centre configuration)
CENTRE = ["0", "0.3", "-0.2", "0", "0.9", "0"]
#: bound (s) of a client process's run after the signal
EXIT_WITHIN = 20.0


# -- the next step after a refused straight line follows the controller's reason ---------------------


async def test_a_tcp_speed_refusal_asks_for_a_lower_tcp_speed_not_another_way(
    capsys: pytest.CaptureFixture[str],
) -> None:
    async with controller(cell="cell_example") as (_emu, ports):  # AUTO limit 1.5 m/s
        code, out = await client("move", "--joints", *CENTRE, *ports)
        assert code == 0, out
        code, out = await client("move", "--pose", "0.3", "0.05", "0.1", "--linear", "--tcp-speed", "2", *ports)
    err = capsys.readouterr().err
    assert code == cli.EXIT_FAILED, out
    assert "the controller refused line 0: TCP_SPEED (the speed is more than the controller allows)" in err
    assert err.rstrip().endswith(
        "; instead: a lower --tcp-speed than 2 m/s (the controller's TCP speed limit is below it)"
    ), err
    assert "without --linear" not in err and "--joints" not in err and "client's check" not in err


async def test_a_tcp_speed_refusal_names_the_limit_the_models_supervision_gives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "jibot_limited.toml"
    shipped = (ROOT / "robot_server" / "models" / "jibot_zxs.toml").read_text(encoding="utf-8")
    model.write_text(shipped + "\n[supervision]\nauto_speed = 1000  # mm/s, as [units] says\n", encoding="utf-8")
    async with controller(models=(str(model),)) as (_emu, ports):  # the model's own supervision
        code, out = await client("move", "--joints", *CENTRE, "--model", str(model), *ports)
        assert code == 0, out
        code, out = await client(
            "move", "--pose", "0.3", "0.05", "0.1", "--linear", "--tcp-speed", "1.2", "--model", str(model), *ports
        )
    err = capsys.readouterr().err
    assert code == cli.EXIT_FAILED, out
    assert "TCP_SPEED" in err
    assert (
        "; instead: a lower --tcp-speed than 1.2 m/s: at most 1 m/s, the AUTO limit of --model jibot_zxs's "
        "[supervision] (the controller's, unless its cell file sets another)"
    ) in err


async def test_a_workspace_refusal_points_at_the_zones_and_claims_no_other_way_runs(
    capsys: pytest.CaptureFixture[str],
) -> None:
    async with controller(cell="cell_example") as (emu, ports):
        code, out = await client("move", "--joints", *CENTRE, *ports)
        assert code == 0, out
        target = ["0.3", "-0.32", "0.1"]  # inside the cell's forbidden box 'fixture'
        code, out = await client("move", "--pose", *target, "--linear", *ports)
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert "the controller refused line 0: WORKSPACE (it leaves the allowed workspace)" in err
        assert "; instead: a target, or a path through other poses, outside the cell's zones (" in err
        assert "the client does not know the controller's zones" in err
        assert "without --linear" not in err and "move --joints" not in err and "client's check" not in err
        # what the old advice claimed would run does not: the same line planned on the PC is refused too
        code, _ = await client("move", "--pose", *target, *ports)
        assert code == cli.EXIT_FAILED
        assert "refused" in capsys.readouterr().err
        assert emu.cell.error_code == 0  # refused before moving into the zone


async def test_an_unreachable_line_says_where_and_claims_nothing_that_would_not_run(
    capsys: pytest.CaptureFixture[str],
) -> None:
    async with controller() as (_emu, ports):
        code, out = await client("move", "--joints", *CENTRE, *ports)
        assert code == 0, out
        code, out = await client("move", "--pose", "0.9", "0", "0.3", "--linear", *ports)
    err = capsys.readouterr().err
    assert code == cli.EXIT_FAILED, out
    assert "UNREACHABLE (the target, or a point of the line, is out of reach)" in err
    assert "; by the client's check of the line on its model: line 0 leaves the reachable space at (" in err
    assert "instead" not in err  # out of reach any way


@pytest.mark.parametrize("result", [LineResult.NOT_READY, LineResult.BUSY, LineResult.INVALID, LineResult.SEQUENCE])
def test_a_refusal_of_the_request_itself_gets_no_other_way(result: LineResult) -> None:
    model = load_model("jibot_zxs")
    here = np.array([float(v) for v in CENTRE])
    target = fk(model, here)
    target[0, 3] += 0.05
    planner = Planner(model)
    assert after_refusal(result, model, here, target, planner, speed=0.1) == (None, [])
    _, ways = after_refusal(LineResult.SINGULAR, model, here, target, planner, speed=0.1)
    assert ways and ways[0].startswith("without --linear")  # the same line runs on the PC: it is fine


# -- Ctrl-C during the demo against a running controller, and with nothing moving --------------------


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS, ids=SIGNAL_IDS)
async def test_robot_client_demo_signalled_during_motion_stops_the_robot_and_says_where(
    tmp_path: Path, sig: signal.Signals, code: int, word: str
) -> None:
    start, _, _ = plan_rectangle(load_model("jibot_zxs"), DemoConfig(width=0.06, height=0.04))  # --short
    # the server lets a departed client's motion run on: only the client's own STOP stops the robot
    async with server(tmp_path, "generic", "--no-stdin", "--on-disconnect", "continue") as proc:
        watch = await Watch.connect(proc.ports["state"])
        ports = ["--motion-port", str(proc.ports["motion"]), "--state-port", str(proc.ports["state"])]
        demo = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "client", "demo", "--short", "--no-plot", "--output", str(tmp_path / "out"), *ports,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            await watch.away_from(HOME, 0.1)  # on its way to the rectangle's first corner
            demo.send_signal(sig)
            out, err = await asyncio.wait_for(demo.communicate(), EXIT_WITHIN)
        finally:
            if demo.returncode is None:
                demo.kill()
                await demo.wait()
        said = err.decode()
        lines = said.splitlines()
        assert demo.returncode == code, said
        assert "a controller answers at 127.0.0.1:" in out.decode()
        assert len(lines) == 2 and lines[1] == f"robot-client: {word}", said
        assert lines[0].startswith("robot-client: stopped: the robot is at rest at ["), said
        reported = [float(x) for x in lines[0].split("[", 1)[1].rstrip("]").split()]
        await watch.until(lambda: watch.state("in_motion") == 0, what="at rest")
        first, second = await watch.rounds_from_now(2)
        assert dist(first, second) < 1e-3, (first, second)
        assert dist(reported, first) < 2e-3, (reported, first)
        assert dist(first, list(start)) > 0.1  # stopped short of the corner: the client's STOP
        log = proc.log.read_text()
        assert "the motion client left with the robot busy" not in log  # not while it braked
        assert "the queued motion runs on" not in log
        await watch.close()
        assert await proc.terminate() == 0


@pytest.mark.slow
async def test_robot_client_interrupted_before_the_robot_moved_says_it_was_not_moving(tmp_path: Path) -> None:
    path = tmp_path / "far.csv"
    Trajectory(np.array([0.0, FAR_SECONDS]), np.array([HOME, FAR])).save(path)
    # the controller's clock stands still until the test advances it: the robot cannot have moved
    async with stepped_emulator() as (emu, clock):
        ports = ["--motion-port", str(emu.ports["motion"]), "--state-port", str(emu.ports["state"])]
        run = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "client", "run", str(path), *ports,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            await poll(lambda: emu.cell.groups[0].points_accepted >= 2, EXIT_WITHIN)  # sent: the client waits
            stops = emu.cell.interruptions
            run.send_signal(signal.SIGINT)
            await poll(lambda: emu.cell.interruptions > stops, EXIT_WITHIN)  # its STOP arrived
            await settle(emu, clock)  # the queue dropped, the controller at rest
            _, err = await asyncio.wait_for(run.communicate(), EXIT_WITHIN)
        finally:
            if run.returncode is None:
                run.kill()
                await run.wait()
    said = err.decode()
    assert run.returncode == cli.EXIT_INTERRUPTED, said
    assert said.splitlines() == [
        "robot-client: the robot was not moving: it is at rest at [0.0000 0.0000 0.0000 0.0000 0.0000 0.0000]",
        "robot-client: interrupted",
    ], said


# -- a mistake before the command ---------------------------------------------------------------------

COMMANDS = "ping, status, monitor, move, run, stop, record, demo"


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (
            ["--motion-port", "31500"],
            f"robot-client: error: a command is missing: --motion-port 31500 must be followed by one of {COMMANDS} "
            "(robot-client [OPTIONS] COMMAND [OPTIONS])",
        ),
        (["--profile", "motoros"], "a command is missing: --profile motoros must be followed by one of ping, "),
        (["--bogus", "status"], "robot-client: error: --bogus is not an option of any robot-client command (see "),
        (["--bogus"], "robot-client: error: --bogus is not an option of any robot-client command (see "),
        (
            ["--motoin-port", "31500", "status"],
            "--motoin-port is not an option of any robot-client command (did you mean --motion-port?)",
        ),
        (["--cout", "3", "ping"], "--cout is not an option of any robot-client command (did you mean --count?)"),
        # the options that may come before the command are offered first: --model, not move's --mode
        (
            ["--modle", "puma560", "status"],
            "--modle is not an option of any robot-client command (did you mean --model?)",
        ),
        (["--mod", "puma560", "status"], "--mod is not an option of any robot-client command (did you mean --model?)"),
        (["--mode", "download", "status"], "a command's own options go after it (move, run take --mode)"),
        (["--count", "3"], "--count is not an option of robot-client itself: a command's own options go after it"),
    ],
)
def test_a_mistake_before_the_command_says_what_it_is(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv, io.StringIO())
    assert exit_.value.code == cli.EXIT_USAGE == 2
    err = capsys.readouterr().err
    assert says in err, err
    assert "invalid choice" not in err and len(err.splitlines()) == 1


@pytest.mark.parametrize(("flag", "shows"), [("--help", "usage: robot-client"), ("--version", "robot-client ")])
def test_help_and_version_after_options_with_no_command_are_answered(
    flag: str, shows: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--profile", "motoros", flag], io.StringIO())
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(shows)


# -- the D-H comparison ------------------------------------------------------------------------------


def _links(model: RobotModel) -> list[DhLink]:
    rows = [joint.dh for joint in model.joints]
    return [DhLink(*row) for row in rows if row is not None]


class _MotoRos:
    """A driver as check_model sees one: a MotoROS dialect that answers GET_DH_PARAMETERS."""

    def __init__(self, reply: GetDhParametersReply) -> None:
        self.dialect = dialect("motoros")
        self.reply = reply

    async def _request(self, _msg: Any) -> GetDhParametersReply:
        return self.reply


async def _check(reply: GetDhParametersReply, model: RobotModel) -> str:
    """check_model's answer as robot-client move gets it: how it agrees, or the mismatch's text."""
    driver: Any = _MotoRos(reply)
    try:
        check = await check_model(driver, model, skip="--no-model-check")
    except ModelMismatch as exc:
        return f"mismatch: {exc}"
    return f"{check.agrees}: {check.how}"


async def test_a_d_h_table_with_fewer_axes_than_the_model_is_a_mismatch_naming_the_counts() -> None:
    model = load_model("jibot_zxs")
    said = await _check(GetDhParametersReply([_links(model)[:4]], axes=4), model)
    assert said == (
        "mismatch: --model jibot_zxs is not the controller's robot: the controller's D-H table has 4 axes per group, "
        "--model jibot_zxs has 6 joints; give --model the model the controller runs, or --no-model-check to skip "
        "this check"
    )


async def test_a_d_h_table_that_ends_before_the_models_joints_is_a_mismatch_naming_the_row() -> None:
    model = load_model("jibot_zxs")
    said = await _check(GetDhParametersReply([_links(model)[:5]]), model)  # 8 axes on the wire, 5 used
    assert said.startswith(
        "mismatch: --model jibot_zxs is not the controller's robot: its D-H table differs from the controller's "
        "(joint 6 "
    ), said
    assert said.endswith(", or --no-model-check to skip this check")


async def test_a_last_d_h_row_of_zeros_is_an_axis_all_the_same() -> None:
    """PUMA 560's last D-H row is all zero: the table still has 6 axes, and it agrees."""
    model = load_model("puma560")
    assert not any(model.joints[5].dh or (1.0,))  # the shipped model's last row is all zero
    said = await _check(GetDhParametersReply([_links(model)]), model)
    assert said.startswith("True:"), said


async def test_an_axis_beyond_the_models_joints_is_a_mismatch() -> None:
    model = load_model("jibot_zxs")
    said = await _check(GetDhParametersReply([[*_links(model), DhLink(0.0, 0.1, 0.0, math.pi / 2)]]), model)
    assert said.startswith(
        "mismatch: --model jibot_zxs is not the controller's robot: the controller's D-H table has 7 axes in group 0, "
        "--model jibot_zxs has 6 joints (axis 7: theta 0, d 0.1, a 0, alpha 1.571)"
    ), said
    assert said.endswith("; give --model the model the controller runs, or --no-model-check to skip this check")


async def test_d_h_angles_compare_modulo_a_turn() -> None:
    model = load_model("jibot_zxs")
    turned = [
        DhLink(link.theta + 2 * math.pi * (k % 3 - 1), link.d, link.a, link.alpha - 2 * math.pi * (k % 2))
        for k, link in enumerate(_links(model))
    ]
    assert await _check(GetDhParametersReply([turned]), model) == (
        "True: --model jibot_zxs agrees with the controller's D-H table"
    )
    off = [*turned[:2], DhLink(turned[2].theta + 0.01, turned[2].d, turned[2].a, turned[2].alpha), *turned[3:]]
    said = await _check(GetDhParametersReply([off]), model)
    assert said.startswith("mismatch: --model jibot_zxs is not the controller's robot: its D-H table differs ")
    assert "joint 3 theta is " in said and said.endswith(", or --no-model-check to skip this check")


async def test_a_d_h_table_that_agrees_padded_or_in_millimetres_agrees() -> None:
    model = load_model("jibot_zxs")
    links = _links(model)
    assert (await _check(GetDhParametersReply([links]), model)).startswith("True: ")  # padded to 8 axes
    millimetres = [DhLink(k.theta, k.d * 1000, k.a * 1000, k.alpha) for k in links]
    assert (await _check(GetDhParametersReply([millimetres], axes=6), model)).startswith("True: ")
    nan = [DhLink(math.nan, k.d, k.a, k.alpha) for k in links]
    assert (await _check(GetDhParametersReply([nan]), model)).startswith("mismatch: ")


#: the paper's robot with a seventh axis after its flange (a model file of robot_server.loader)
SEVEN_AXES = """
[robot]
name = "jibot_seven"

[units]
length = "mm"
angle = "deg"

[dh]
convention = "modified"
joints = [
  { name = "joint_1", alpha =  0, a =  0, d = 339, theta = 0 },
  { name = "joint_2", alpha = 90, a =  0, d =   0, theta = 0 },
  { name = "joint_3", alpha =  0, a = 250, d =   0, theta = 0 },
  { name = "joint_4", alpha = 90, a = 70, d = 250, theta = 0 },
  { name = "joint_5", alpha = -90, a = 0, d =   0, theta = 0 },
  { name = "joint_6", alpha = 90, a =  0, d =  95, theta = 0 },
  { name = "joint_7", alpha = -90, a =  0, d =  60, theta = 0 },
]

[limits]
position_min = [-170, -120, -170, -200, -120, -360, -170]
position_max = [ 170,  120,  170,  200,  120,  360,  170]
velocity     = [180, 180, 180, 180, 180, 180, 180]
acceleration = [572.958, 572.958, 572.958, 572.958, 572.958, 572.958, 572.958]
jerk         = [28647.9, 28647.9, 28647.9, 28647.9, 28647.9, 28647.9, 28647.9]
"""


async def test_a_motoros_controller_with_a_seventh_axis_is_not_a_six_joint_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    seven = tmp_path / "jibot_seven.toml"
    seven.write_text(SEVEN_AXES, encoding="utf-8")
    assert load_model(str(seven)).dof == 7
    async with controller(profile="motoros", models=(str(seven),)) as (emu, ports):
        before = np.array(emu.cell.groups[0].command.command_position)
        code, out = await client("move", "--pose", "0.4", "0.05", "0.2", *ports)  # --model jibot_zxs
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert (
            "robot-client: --model jibot_zxs is not the controller's robot: the controller's D-H table has 7 axes in "
            "group 0, --model jibot_zxs has 6 joints (axis 7: "
        ) in err
        assert err.rstrip().endswith(
            "; give --model the model the controller runs, or --no-model-check to skip this check"
        )
        assert np.array_equal(np.array(emu.cell.groups[0].command.command_position), before)  # nothing moved


async def test_run_approach_checks_the_file_before_it_moves_the_robot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file whose third point is beyond a joint's limit: refused before the approach moves the
    robot (docs/trajectories.md: "refused before anything is sent")."""
    beyond = tmp_path / "beyond.csv"
    Trajectory(
        np.array([0.0, 1.0, 2.0]),
        np.array([[0.3, 0.0, 0.0, 0.0, 0.0, 0.0], [0.4, 0.0, 0.0, 0.0, 0.0, 0.0], [9.0, 0.0, 0.0, 0.0, 0.0, 0.0]]),
    ).save(beyond)
    async with controller() as (emu, ports):
        here = np.array(emu.cell.groups[0].command.command_position)
        code, out = await client("run", str(beyond), "--approach", *ports)
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert "point 2: joint 1 (joint_1) at 9 is beyond its upper limit" in err, err
        assert "approach:" not in out
        assert emu.cell.groups[0].trajectories == 0
        assert np.array_equal(np.array(emu.cell.groups[0].command.command_position), here)


async def test_run_approach_closes_a_gap_motoros_would_refuse(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """MotoROS refuses a start 0.5 mrad off (DATA_START_POS), well inside the client's 0.01 rad
    tolerance: without --approach the refusal says to add it; with it the robot goes there first."""
    path = tmp_path / "line.csv"
    Trajectory(
        np.array([0.0, 0.5, 1.0]),
        np.array([[0.003, 0.0, 0.0, 0.0, 0.0, 0.0], [0.1, 0.0, 0.0, 0.0, 0.0, 0.0], [0.2, 0.0, 0.0, 0.0, 0.0, 0.0]]),
        np.array([[0.0] * 6, [0.2, 0, 0, 0, 0, 0], [0.0] * 6]),
    ).save(path)
    async with controller(profile="motoros") as (emu, ports):
        code, out = await client("run", str(path), *ports)
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert "DATA_START_POS" in err and "add --approach to move there first" in err, err
        code, out = await client("run", str(path), "--approach", *ports)
        assert code == 0, capsys.readouterr().err
        assert f"approach: to the start of {path}, 0.003 rad away" in out
        end = np.array(emu.cell.groups[0].command.command_position)
        assert abs(end[0] - 0.2) < 1e-4


async def test_the_controller_log_says_a_stopped_trajectory_stopped(caplog: pytest.LogCaptureFixture) -> None:
    """A trajectory cut short by STOP is logged as stopped with the points received, not as done."""
    import contextlib

    from client.driver import RobotDriver
    from tests.stepped import advance_until

    caplog.set_level(logging.INFO, logger="robot_server.emulator.cell")
    model = load_model("jibot_zxs")
    async with contextlib.AsyncExitStack() as stack:
        emu, clock = await stack.enter_async_context(stepped_emulator(state_rate=100.0))
        driver = RobotDriver(motion_port=emu.ports["motion"], state_port=emu.ports["state"], model=model)
        await stack.enter_async_context(driver)
        here = driver.joint_state.positions if driver.joint_state is not None else np.zeros(6)
        motion = Planner(model, velocity_scale=0.3, acceleration_scale=0.3, jerk_scale=0.3).joint_move(
            here, [0.6, 0.3, -0.3, 0.5, 0.4, 0.6]
        )
        sent = motion.sparse(rest_to_rest=True)
        task = asyncio.create_task(driver.execute(sent))
        ctl = emu.cell.groups[0]
        await advance_until(clock, lambda: ctl.command.actual_position[0] > 0.05, what="moving")
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            async with asyncio.timeout(10.0):
                await task
        await settle(emu, clock)
    ended = [r.getMessage() for r in caplog.records if "trajectory 1 " in r.getMessage() and "after" in r.getMessage()]
    said = f"group 0: trajectory 1 stopped: {len(sent)} points received, at rest after "
    assert len(ended) == 1 and ended[0].startswith(said), ended


async def test_advice_on_a_model_the_controller_did_not_confirm_says_so(capsys: pytest.CaptureFixture[str]) -> None:
    """With --no-model-check the client's line check and the joints it suggests rest on --model alone."""
    kuka = ["--model", "kuka_kr6_r900_sixx"]
    async with controller(models=("kuka_kr6_r900_sixx",)) as (_emu, ports):
        code, out = await client("move", "--joints", "0", "-1.2", "1.2", "0", "0.5", "0", *kuka, *ports)
        assert code == 0, out
        code, out = await client("move", "--pose", "0.5", "0", "0.3", "--linear", "--no-model-check", *kuka, *ports)
        err = capsys.readouterr().err
        assert code == cli.EXIT_FAILED, out
        assert "the controller refused line 0: SINGULAR" in err and "; instead: " in err
        assert err.rstrip().endswith(
            "(worked out on --model kuka_kr6_r900_sixx, which the controller did not confirm)"
        ), err


def test_a_recording_that_ends_moving_is_told_apart() -> None:
    t = np.array([0.0, 0.025, 0.05])
    q = np.array([[0.0] * 6, [0.0] * 6, [0.01, 0, 0, 0, 0, 0]])
    assert cli._ends_moving(Trajectory(t, q))  # 0.4 rad/s from the state before
    assert not cli._ends_moving(Trajectory(t, np.zeros((3, 6))))
    assert not cli._ends_moving(Trajectory(t, q, np.zeros((3, 6))))  # velocities recorded: they say at rest
    assert cli._ends_moving(Trajectory(t, np.zeros((3, 6)), np.array([[0.0] * 6, [0.0] * 6, [0.3] + [0.0] * 5])))
    assert not cli._ends_moving(Trajectory(t[:1], q[:1]))
