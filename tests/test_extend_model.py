"""Extending the emulator with a robot model, end to end: the worked example of CONTRIBUTING.md,
"Adding a robot model".

A new model is one TOML file (or a URDF). Here the test writes two into ``tmp_path``, as a user
would keep them outside the package: a made-up 6R arm with a spherical wrist (its geometry like a
small ABB arm's, in mm and degrees, standard D-H) and a 4-axis SCARA with a prismatic joint
(metres, modified D-H). Each is loaded by its path, checked in SI units, put through the
kinematics (FK/IK round trips), and moved by the emulator over TCP, selected by the same path.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np
import pytest

from robot_server import Array
from robot_server.cli import parser
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.kinematics import closed_form, fk, ik, ik_numeric
from robot_server.kinematics.__main__ import main as kinematics_main
from robot_server.loader import load_model, shipped_models
from robot_server.model import JointType, ModelError, RobotModel
from simple_message import LE32, Client, CommType, JointPosition, JointTrajPt, MsgType, ReplyCode
from tests.test_rs_server_process import robot_server

# -- the new models: what a contributor writes (one file each) --------------------------------------

ACME_ARM = """\
# ACME A6: a made-up 6R arm for the extension test (geometry like a small ABB arm's).
[robot]
name = "acme_a6"
description = "ACME A6 6R arm, spherical wrist (made up for tests/test_extend_model.py)"
source = "invented: d1 290, a2 270, a3 70, d4 302, d6 72 mm"

[units]
length = "mm"
angle = "deg"

[dh]
convention = "standard"   # row i = (theta_offset_i, d_i, a_i, alpha_i); A_i = Rz Tz Tx Rx
joints = [
  { name = "base",     theta =   0, d = 290, a =   0, alpha = -90 },
  { name = "shoulder", theta = -90, d =   0, a = 270, alpha =   0 },
  { name = "elbow",    theta =   0, d =   0, a =  70, alpha = -90 },
  { name = "wrist_1",  theta =   0, d = 302, a =   0, alpha =  90 },
  { name = "wrist_2",  theta =   0, d =   0, a =   0, alpha = -90 },
  { name = "flange",   theta = 180, d =  72, a =   0, alpha =   0 },
]

[limits]
# positions in the angle unit; speeds, accelerations and jerks per second in it too
position_min = [-165, -110, -110, -160, -120, -400]
position_max = [ 165,  110,   70,  160,  120,  400]
velocity     = [250, 250, 250, 320, 320, 420]
acceleration = [600, 600, 600, 900, 900, 900]
jerk         = [30000, 30000, 30000, 40000, 40000, 40000]

[tool]
xyz = [0, 0, 50]   # a 50 mm tool along the flange's z
"""

ACME_SCARA = """\
# ACME S4: a made-up SCARA (RRPR) for the extension test.
[robot]
name = "acme_s4"
description = "ACME S4 SCARA: two arms, a quill, a wrist (made up for tests/test_extend_model.py)"

[units]
length = "m"
angle = "rad"

[dh]
convention = "modified"   # row i = (alpha_{i-1}, a_{i-1}, d_i, theta_offset_i)
joints = [
  { name = "arm_1", alpha = 0, a = 0,    d = 0.4, theta = 0 },
  { name = "arm_2", alpha = 0, a = 0.35, d = 0,   theta = 0 },
  { name = "quill", alpha = 0, a = 0.3,  d = 0,   theta = 0, type = "prismatic" },
  { name = "wrist", alpha = 0, a = 0,    d = 0,   theta = 0 },
]

[limits]
position_min = [-2.5, -2.5, -0.2, -6.0]
position_max = [ 2.5,  2.5,  0.0,  6.0]
velocity     = [3.0, 3.0, 1.0, 6.0]
acceleration = [10.0, 10.0, 5.0, 20.0]
jerk         = [500.0, 500.0, 200.0, 1000.0]
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture
def arm(tmp_path: Path) -> Path:
    return write(tmp_path, "acme_a6", ACME_ARM)


@pytest.fixture
def scara(tmp_path: Path) -> Path:
    return write(tmp_path, "acme_s4", ACME_SCARA)


# -- loading ------------------------------------------------------------------------------------------


def test_a_model_file_loads_by_path_in_si_units(arm: Path) -> None:
    assert "acme_a6" not in shipped_models()  # a user's model: nothing in the package changes
    model = load_model(arm)
    again = load_model(str(arm))  # a path as text too (what --model passes)
    assert [j.dh for j in again.joints] == [j.dh for j in model.joints]
    assert model.name == "acme_a6" and model.dof == 6 and model.convention == "standard"
    assert model.joint_names == ("base", "shoulder", "elbow", "wrist_1", "wrist_2", "flange")
    assert model.lower[2] == pytest.approx(math.radians(-110)) and model.upper[5] == pytest.approx(math.radians(400))
    assert model.max_velocity == pytest.approx(np.radians([250, 250, 250, 320, 320, 420]))
    assert model.joints[1].dh == pytest.approx((-math.pi / 2, 0.0, 0.27, 0.0))  # (theta, d, a, alpha)
    assert model.tool[:3, 3] == pytest.approx([0.0, 0.0, 0.05])
    # q = 0: the upper arm up, the forearm forward; flange + tool 0.374 + 0.07 + 0.05 m out in x
    assert fk(model, np.zeros(6))[:3, 3] == pytest.approx([0.302 + 0.072 + 0.05, 0.0, 0.29 + 0.27 + 0.07])


def test_a_broken_model_file_names_the_file_and_the_field(tmp_path: Path) -> None:
    text = ACME_ARM.replace("velocity     = [250, 250, 250, 320, 320, 420]", "velocity = [1]")
    path = write(tmp_path, "broken", text)
    with pytest.raises(
        ModelError, match=r"broken\.toml: \[limits\] velocity: 1 value for 6 joints: joint 2 \(shoulder\) has no value"
    ):
        load_model(path)
    with pytest.raises(ModelError, match="no such model file, and not a shipped model"):
        load_model(tmp_path / "missing.toml")


# -- kinematics ---------------------------------------------------------------------------------------


def random_configurations(model: RobotModel, count: int, seed: int) -> Array:
    """Configurations well inside the limits (the wrist not straight, away from its singularity)."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(0.8 * model.lower, 0.8 * model.upper, size=(count, model.dof))
    if model.dof == 6:
        q[:, 4] = np.where(np.abs(q[:, 4]) < 0.2, 0.5, q[:, 4])
    return q


def test_fk_ik_round_trip_on_the_new_arm_in_closed_form(arm: Path) -> None:
    model = load_model(arm)
    assert closed_form(model) is not None  # spherical wrist: every solution, in closed form
    for q in random_configurations(model, 20, seed=11):
        pose = fk(model, q)
        solutions = ik(model, pose, all=True)
        assert 1 <= len(solutions) <= 8
        for solution in solutions:  # every one reaches the pose, within the limits
            assert np.abs(fk(model, solution.q) - pose).max() < 1e-9
            assert model.within_limits(np.array(solution.q), tol=1e-9)
        # the one nearest the configuration the pose came from is that configuration
        nearest = ik(model, pose, seed=q)
        assert np.allclose(nearest[0].q, q, atol=1e-8)
        # the numeric solver agrees, from a nearby seed
        numeric = ik_numeric(model, pose, q + 0.05)
        assert numeric.success and np.abs(fk(model, numeric.q) - pose).max() < 1e-6


def test_fk_ik_round_trip_on_the_new_scara_numerically(scara: Path) -> None:
    model = load_model(scara)
    revolute, prismatic = JointType.REVOLUTE, JointType.PRISMATIC
    assert [j.type for j in model.joints] == [revolute, revolute, prismatic, revolute]
    assert closed_form(model) is None  # not a 6R arm: ik() solves numerically
    for q in random_configurations(model, 10, seed=5):
        pose = fk(model, q)
        assert pose[2, 3] == pytest.approx(0.4 + q[2])  # the quill moves the flange along z
        solution = ik(model, pose, seed=q + 0.05)[0]
        assert np.abs(fk(model, solution.q) - pose).max() < 1e-6


def test_the_kinematics_command_takes_the_model_by_path(arm: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert kinematics_main(["fk", "--model", str(arm), "0", "0", "0", "0", "0", "0"]) == 0
    assert '"T"' in capsys.readouterr().out


# -- the emulator ---------------------------------------------------------------------------------------


async def move(path: Path, goal: Array) -> tuple[Array, Array]:
    """Stream the robot of the model file at ``path`` from where it stands to ``goal`` through the
    emulator (simulated clock, TCP on loopback); the commanded position at rest and the state topic's."""
    config = EmulatorConfig(models=(path,), motion_port=0, state_port=0, simulated=True)
    async with Emulator(config) as emu:
        ctl = emu.cell.groups[0]
        start = np.array(ctl.command.command_position)
        motion = Client.tcp("127.0.0.1", emu.ports["motion"], LE32, reconnect=None)
        state = Client.tcp("127.0.0.1", emu.ports["state"], LE32, reconnect=None)
        topics = state.subscribe(msg_types=[MsgType.JOINT_POSITION])
        async with motion, state:
            via = (start + goal) / 2.0
            for sequence, target in enumerate((start, via, goal)):
                request = JointTrajPt(sequence, tuple(target.tolist()), velocity=0.5)
                reply = await motion.request(request, timeout=10.0)
                assert (reply.comm_type, reply.reply_code) == (CommType.SERVICE_REPLY, ReplyCode.SUCCESS)
            expected = goal.astype(np.float32).astype(float)  # reals are float32 on this wire
            await emu.wait_until(
                lambda: not emu.cell.in_motion and np.allclose(ctl.command.command_position, expected, atol=1e-9),
                timeout=30.0,
            )
            while True:  # the state topic (40 Hz of wall-clock time) catches up
                message = await topics.get(timeout=10.0)
                assert isinstance(message, JointPosition)
                reported = np.array(message.joint_data[: len(goal)])
                if np.allclose(reported, expected, atol=1e-6):
                    break
    return np.array(ctl.command.command_position), reported


async def test_the_emulator_moves_the_new_arm_to_a_pose_solved_by_ik(arm: Path) -> None:
    model = load_model(arm)
    target = fk(model, np.radians([30.0, 20.0, -30.0, 40.0, 50.0, 60.0]))
    goal = np.array(ik(model, target, seed=np.zeros(6))[0].q)  # the solution nearest the robot at q = 0
    command, reported = await move(arm, goal)
    assert np.abs(fk(model, command) - target).max() < 1e-5  # float32 joints on the wire: micrometres
    assert np.abs(fk(model, reported) - target).max() < 1e-5


async def test_the_emulator_moves_the_new_scara_and_its_quill(scara: Path) -> None:
    goal = np.array([0.8, -1.2, -0.15, 2.0])
    command, _ = await move(scara, goal)
    assert fk(load_model(scara), command)[2, 3] == pytest.approx(0.25, abs=1e-6)  # the quill went down 0.15 m


def test_the_command_line_takes_model_files_by_path(arm: Path, scara: Path) -> None:
    args = parser().parse_args(["--model", str(arm), "--model", str(scara)])
    config = EmulatorConfig(models=tuple(args.model), motion_port=0, state_port=0)
    assert [load_model(m).name for m in config.models] == ["acme_a6", "acme_s4"]  # two motion groups


@pytest.mark.slow
async def test_robot_server_moves_a_model_given_by_path(arm: Path, tmp_path: Path) -> None:
    """``robot-server --model PATH``: the command, as a process. Joint 6 goes to 378 degrees, within
    this arm's limits (400) and beyond those of the default model (360), which would refuse it."""
    goal = np.array([0.3, 0.2, -0.3, 0.5, 0.6, math.radians(378.0)])
    async with robot_server(tmp_path, "--model", str(arm), "--speedup", "4", "--no-stdin") as server:
        motion = Client.tcp("127.0.0.1", server.ports["motion"], LE32, reconnect=None)
        state = Client.tcp("127.0.0.1", server.ports["state"], LE32, reconnect=None)
        topics = state.subscribe(msg_types=[MsgType.JOINT_POSITION])
        async with motion, state:
            for sequence, target in enumerate((np.zeros(6), goal)):
                reply = await motion.request(JointTrajPt(sequence, tuple(target.tolist()), velocity=1.0), 10.0)
                assert reply.reply_code == ReplyCode.SUCCESS
            async with asyncio.timeout(20.0):  # state topics until the robot is at the goal
                while True:
                    message = await topics.get()
                    assert isinstance(message, JointPosition)
                    if np.allclose(message.joint_data[:6], goal, atol=1e-5):
                        break
        assert await server.terminate() == 0
