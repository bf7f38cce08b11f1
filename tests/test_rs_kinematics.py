"""Robot models and forward kinematics against the independent reference cases."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from robot_server.kinematics import fk, fk_batch, link_frames
from robot_server.loader import load_model, shipped_models
from robot_server.model import ModelError

from .refdata import DATA

REFERENCE = json.loads((DATA / "fk_reference.json").read_text())


def test_jibot_is_shipped_and_loads_in_si_units() -> None:
    assert "jibot_zxs" in shipped_models()
    model = load_model("jibot_zxs")
    assert model.dof == 6 and model.convention == "modified"
    assert model.max_velocity == pytest.approx([math.pi] * 6)
    assert model.max_acceleration == pytest.approx([10.0] * 6, rel=1e-5)
    assert model.joints[3].dh == pytest.approx((0.0, 0.25, 0.07, math.pi / 2))


@pytest.mark.parametrize("case", REFERENCE["cases"], ids=[c["name"] for c in REFERENCE["cases"]])
def test_fk_matches_every_reference_case(case: dict) -> None:  # type: ignore[type-arg]
    model = load_model("jibot_zxs")
    T = fk(model, case["q_rad"])
    assert np.max(np.abs(T - np.array(case["T"]))) < 1e-9
    # the wrist centre is the flange minus d6 along its z axis
    assert np.allclose(T[:3, 3] - 0.095 * T[:3, 2], case["wrist_centre"], atol=1e-9)


def test_home_pose_of_the_papers_robot() -> None:
    """q2 = +pi/2 gives the usual L pose with the flange at (0.345, 0, 0.659) m (docs/kinematics.md)."""
    T = fk(load_model("jibot_zxs"), [0, math.pi / 2, 0, 0, 0, 0])
    assert T[:3, 3] == pytest.approx([0.345, 0.0, 0.659], abs=1e-12)


def test_batch_fk_equals_single_fk() -> None:
    model = load_model("jibot_zxs")
    rng = np.random.default_rng(7)
    q = rng.uniform(-math.pi, math.pi, size=(500, 6))
    batch = fk_batch(model, q)
    assert batch.shape == (500, 4, 4)
    for i in range(0, 500, 37):
        assert np.max(np.abs(batch[i] - fk(model, q[i]))) < 1e-12
    cases = np.array([c["q_rad"] for c in REFERENCE["cases"]])
    expected = np.array([c["T"] for c in REFERENCE["cases"]])
    assert np.max(np.abs(fk_batch(model, cases) - expected)) < 1e-9


def test_standard_dh_equivalent_gives_the_same_flange(tmp_path: Path) -> None:
    rows = "\n".join(
        f"  {{ alpha = {r['alpha_i']}, a = {r['a_i']}, d = {r['d_i']}, theta = 0 }},"
        for r in REFERENCE["equivalent_standard_dh"]
    )
    path = tmp_path / "sdh.toml"
    path.write_text(
        f'[robot]\nname = "jibot_sdh"\n[units]\nlength = "m"\nangle = "rad"\n'
        f'[dh]\nconvention = "standard"\njoints = [\n{rows}\n]\n'
    )
    sdh = load_model(path)
    mdh = load_model("jibot_zxs")
    rng = np.random.default_rng(1)
    for q in rng.uniform(-math.pi, math.pi, size=(200, 6)):
        assert np.max(np.abs(fk(sdh, q) - fk(mdh, q))) < 1e-12
    assert len(link_frames(sdh, np.zeros(6))) == 7


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[robot\nname=", "not valid TOML"),
        ('[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n', "missing table [dh]"),
        (
            '[robot]\nname = "x"\n[units]\nlength = "in"\nangle = "rad"\n[dh]\nconvention = "standard"\njoints = []\n',
            "[units] length",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "weird"\njoints = []\n',
            "[dh] convention",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "standard"\n'
            'joints = [{ alpha = 0, a = "long", d = 0 }]\n',
            "[dh] joints[0].a: must be a finite number",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "standard"\n'
            "joints = [{ alpha = 0, d = 0 }]\n",
            "[dh] joints[0].a: missing",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "standard"\n'
            "joints = [{ alpha = 0, a = 0, d = 0 }]\n[limits]\nvelocity = [1, 2]\n",
            "[limits] velocity: 2 values for 1 joint",
        ),
    ],
)
def test_bad_model_files_name_the_file_and_the_field(tmp_path: Path, text: str, message: str) -> None:
    assert_load_error(tmp_path / "bad.toml", text, message)


def assert_load_error(path: Path, text: str, message: str) -> None:
    """Loading ``text`` from ``path`` fails with a ModelError naming the file and ``message``."""
    path.write_text(text)
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(path) in str(info.value) and message in str(info.value)


def test_unknown_model_name() -> None:
    with pytest.raises(ModelError, match="jibot_zxs"):
        load_model("no_such_robot")


# -- URDF ---------------------------------------------------------------------------------------


def test_urdf_of_the_dh_robot_gives_the_same_flange_poses() -> None:
    dh = load_model("jibot_zxs")
    urdf = load_model(DATA / "jibot_zxs.urdf")
    assert urdf.convention == "urdf" and urdf.dof == 6
    assert urdf.joint_names == tuple(f"joint_{i}" for i in range(1, 7))  # the tool0 branch, not "base"
    assert np.allclose(urdf.lower, dh.lower) and np.allclose(urdf.upper, dh.upper)
    q = np.random.default_rng(5).uniform(dh.lower, dh.upper, size=(1000, 6))
    assert np.max(np.abs(fk_batch(urdf, q) - fk_batch(dh, q))) < 1e-12


def test_a_urdf_takes_its_base_and_tool_frames_from_a_sidecar_file(tmp_path: Path) -> None:
    # the robot 1 m up on a pedestal turned 90 degrees, a 100 mm tool along the flange's z
    shutil.copy(DATA / "jibot_zxs.urdf", tmp_path / "arm.urdf")
    (tmp_path / "arm.frames.toml").write_text(
        '[units]\nlength = "mm"\nangle = "deg"\n[base]\nxyz = [0, 0, 1000]\nrpy = [0, 0, 90]\n'
        "[tool]\nxyz = [0, 0, 100]\n"
    )
    plain, framed = load_model(DATA / "jibot_zxs.urdf"), load_model(tmp_path / "arm.urdf")
    q = np.random.default_rng(7).uniform(plain.lower, plain.upper, size=(100, 6))
    base = np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 1.0], [0, 0, 0, 1]])
    tool = np.eye(4)
    tool[2, 3] = 0.1
    assert np.allclose(fk_batch(framed, q), base @ fk_batch(plain, q) @ tool, atol=1e-12)
    (tmp_path / "arm.frames.toml").write_text('[units]\nlength = "furlong"\n')
    with pytest.raises(ModelError, match=r"arm.frames.toml.*length"):
        load_model(tmp_path / "arm.urdf")


def test_shipped_urdf_model_kuka() -> None:
    model = load_model("kuka_kr6_r900_sixx")
    assert model.dof == 6 and model.convention == "urdf"
    assert model.upper[1] == pytest.approx(math.radians(45))
    assert model.max_velocity[5] == pytest.approx(math.radians(615))
    # q = 0: the arm stretched forward, flange at x = 25 + 455 + 420 + 80 mm, z = 400 + 35 mm
    assert np.allclose(fk(model, [0] * 6)[:3, 3], [0.98, 0.0, 0.435], atol=1e-12)


_URDF_HEAD = '<robot name="r"><link name="a"/><link name="b"/><link name="c"/>'
_GOOD_JOINT = (
    '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
    '<limit lower="-1" upper="1" velocity="1"/></joint>'
)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("<robot name='r'><link name='a'>", "not well-formed XML"),
        ("<model/>", "not <robot>"),
        (_URDF_HEAD + _GOOD_JOINT.replace('<limit lower="-1" upper="1" velocity="1"/>', "") + "</robot>", "no <limit>"),
        (_URDF_HEAD + _GOOD_JOINT.replace('lower="-1"', 'lower="minus one"') + "</robot>", "limit.lower"),
        (_URDF_HEAD + _GOOD_JOINT.replace('xyz="0 0 1"', 'xyz="0 0"') + "</robot>", "axis.xyz"),
        (_URDF_HEAD + _GOOD_JOINT.replace('xyz="0 0 1"', 'xyz="0 0 0"') + "</robot>", "zero vector"),
        (_URDF_HEAD + _GOOD_JOINT.replace("revolute", "floating") + "</robot>", "type 'floating'"),
        (_URDF_HEAD + _GOOD_JOINT.replace('link="b"', 'link="zz"') + "</robot>", "undefined link 'zz'"),
        (_URDF_HEAD + _GOOD_JOINT.replace('<parent link="a"/>', "") + "</robot>", "missing <parent"),
        (
            _URDF_HEAD
            + _GOOD_JOINT
            + _GOOD_JOINT.replace('name="j1"', 'name="j2"').replace('link="a"', 'link="c"')
            + "</robot>",
            "closed loop: link 'b'",
        ),
        (
            '<robot name="r"><link name="a"/><link name="b"/>'
            + _GOOD_JOINT
            + _GOOD_JOINT.replace('name="j1"', 'name="j2"')
            .replace('"a"', '"x"')
            .replace('"b"', '"a"')
            .replace('"x"', '"b"')
            + "</robot>",
            "cycle",
        ),
    ],
)
def test_bad_urdf_names_file_and_field(tmp_path: Path, text: str, message: str) -> None:
    assert_load_error(tmp_path / "bad.urdf", text, message)
