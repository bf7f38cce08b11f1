"""Model files are read strictly (issue 36): every kind of mistake is a ModelError that names the
file, the table and the key, with the value as the file writes it, in the file's units, and an
unknown name comes with the closest known one. Also: every shipped file still loads, a URDF keeps
its foreign elements, and every shipped model file cites only what exists."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import pytest

from robot_server.loader import load_model, load_supervision, shipped_cells, shipped_models
from robot_server.model import ModelError

from .refdata import DATA

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "robot_server" / "models"

# A made-up 6R arm in mm and degrees; each test breaks one line of it.
ARM = """\
[robot]
name = "irb120_like"
source = "made up for tests/test_rs_model_file.py"

[units]
length = "mm"
angle = "deg"

[dh]
convention = "standard"
joints = [
  { name = "joint_1", theta = 0, d = 290, a = 0,   alpha = -90 },
  { name = "joint_2", theta = 0, d = 0,   a = 270, alpha = 0 },
  { name = "joint_3", theta = 0, d = 0,   a = 70,  alpha = -90 },
  { name = "joint_4", theta = 0, d = 302, a = 0,   alpha = 90 },
  { name = "joint_5", theta = 0, d = 0,   a = 0,   alpha = -90 },
  { name = "joint_6", theta = 0, d = 72,  a = 0,   alpha = 0 },
]

[limits]
position_min = [-165, -110, -110, -160, -120, -400]
position_max = [ 165,  110,   70,  160,  120,  400]
velocity     = [250, 250, 250, 320, 320, 420]
acceleration = [600, 600, 600, 900, 900, 900]
jerk         = [30000, 30000, 30000, 40000, 40000, 40000]

[tool]
xyz = [0, 0, 50]
"""


def error_of(tmp_path: Path, old: str, new: str, name: str = "irb120.toml") -> tuple[Path, str]:
    """The ModelError's message for ARM with ``old`` replaced by ``new``, and the file's path."""
    assert old in ARM
    path = tmp_path / name
    path.write_text(ARM.replace(old, new))
    with pytest.raises(ModelError) as info:
        load_model(path)
    return path, str(info.value)


def test_the_unbroken_file_loads(tmp_path: Path) -> None:
    path = tmp_path / "irb120.toml"
    path.write_text(ARM)
    model = load_model(path)
    assert model.upper[1] == pytest.approx(math.radians(110)) and model.tool[2, 3] == pytest.approx(0.05)


# -- one test per kind of mistake -----------------------------------------------------------------------


def test_an_unknown_table_is_named_with_the_closest_known_one(tmp_path: Path) -> None:
    path, message = error_of(tmp_path, "[limits]", "[limit]")
    assert message == f"{path}: [limit]: unknown table; did you mean [limits]?"
    path, message = error_of(tmp_path, "[tool]", "[tcp]")  # a synonym no spelling resembles
    assert message == f"{path}: [tcp]: unknown table; did you mean [tool]?"
    path, message = error_of(tmp_path, "[tool]", "[gripper]")  # nothing close: the known ones
    assert message == (
        f"{path}: [gripper]: unknown table "
        "(known: [robot], [units], [dh], [limits], [base], [tool], [motors], [supervision])"
    )


def test_an_unknown_key_is_named_with_the_closest_known_one(tmp_path: Path) -> None:
    path, message = error_of(tmp_path, "velocity     =", "velocities =")
    assert message == f"{path}: [limits] velocities: unknown key; did you mean velocity?"
    path, message = error_of(tmp_path, '{ name = "joint_3", theta = 0, d = 0,   a = 70,  alpha', "{ alfa")
    assert message == f"{path}: [dh] joints[2].alfa: unknown key; did you mean alpha?"
    path, message = error_of(tmp_path, 'angle = "deg"', 'angle = "deg"\nlenght = "mm"')
    assert message == f"{path}: [units] lenght: unknown key; did you mean length?"
    path, message = error_of(tmp_path, "xyz = [0, 0, 50]", "offset = [0, 0, 50]")
    assert message == f"{path}: [tool] offset: unknown key (known: xyz, rpy)"


def test_a_value_of_the_wrong_type_is_named_with_the_value(tmp_path: Path) -> None:
    velocity = "velocity     = [250, 250, 250, 320, 320, 420]"
    path, message = error_of(tmp_path, velocity, 'velocity = "fast"')
    assert message == f"{path}: [limits] velocity: must be a list of 6 numbers, one per joint, not 'fast'"
    path, message = error_of(tmp_path, velocity, 'velocity = [250, 250, "x", 320, 320, 420]')
    assert message == f"{path}: [limits] velocity[2]: must be a finite number, not 'x'"
    path, message = error_of(tmp_path, 'angle = "deg"', "angle = 1")
    assert message == f"{path}: [units] angle: must be a string, not 1"
    path, message = error_of(tmp_path, 'angle = "deg"', 'angle = "degrees"')
    assert message == f"{path}: [units] angle: 'degrees' is not one of 'rad', 'deg'"
    path, message = error_of(tmp_path, "xyz = [0, 0, 50]", "xyz = [0, 50]")
    assert message == f"{path}: [tool] xyz: must be a list of 3 numbers, not [0, 50]"
    path = tmp_path / "irb120.toml"
    path.write_text("tool = 50\n" + ARM[: ARM.index("[tool]")])  # a key before the first table
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: [tool]: must be a table, not 50"


def test_an_inverted_limit_shows_the_files_values_in_degrees(tmp_path: Path) -> None:
    path, message = error_of(tmp_path, "position_min = [-165, -110,", "position_min = [-165, 130,")
    assert message == f"{path}: [limits] position_min: joint 2 (joint_2): 130 deg is not below position_max = 110 deg"
    assert "2.2689" not in message  # not 130 deg in radians, as the model's own check prints it
    path, message = error_of(tmp_path, "position_max = [ 165,  110,", "position_max = [ 165,  -110,")
    assert message == (
        f"{path}: [limits] position_min: joint 2 (joint_2): -110 deg is not below position_max = -110 deg"
    )
    path, message = error_of(tmp_path, "velocity     = [250, 250, 250,", "velocity = [250, 250, -10.5,")
    assert message == f"{path}: [limits] velocity: joint 3 (joint_3): -10.5 deg/s must be > 0"
    path, message = error_of(tmp_path, "jerk         = [30000,", "jerk = [0,")
    assert message == f"{path}: [limits] jerk: joint 1 (joint_1): 0 deg/s^3 must be > 0"


def test_the_limits_of_a_prismatic_joint_are_in_the_files_length_unit(tmp_path: Path) -> None:
    old = '{ name = "joint_3", theta = 0, d = 0,   a = 70,  alpha = -90 }'
    quill = '{ name = "quill", theta = 0, d = 0, a = 70, alpha = -90, type = "prismatic" }'
    path = tmp_path / "quill.toml"
    text = ARM.replace(old, quill)
    path.write_text(text.replace("position_max = [ 165,  110,   70,", "position_max = [ 165,  110, -120,"))
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert (
        str(info.value)
        == f"{path}: [limits] position_min: joint 3 (quill): -110 mm is not below position_max = -120 mm"
    )
    path.write_text(text.replace("acceleration = [600, 600, 600,", "acceleration = [600, 600, -600,"))
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: [limits] acceleration: joint 3 (quill): -600 mm/s^2 must be > 0"


def test_a_missing_limit_is_named(tmp_path: Path) -> None:
    path, message = error_of(tmp_path, "position_max = [ 165,  110,   70,  160,  120,  400]\n", "")
    assert message == (
        f"{path}: [limits] position_max: missing; position_min is given, so give both "
        "(or neither, for the emulator's default range ±π)"
    )
    path, message = error_of(tmp_path, "position_min = [-165, -110, -110, -160, -120, -400]\n", "")
    assert message.startswith(f"{path}: [limits] position_min: missing; position_max is given")
    path, message = error_of(tmp_path, "velocity     = [250, 250, 250, 320, 320, 420]", "velocity = [250, 250]")
    assert message == f"{path}: [limits] velocity: 2 values for 6 joints: joint 3 (joint_3) has no value"
    path, message = error_of(tmp_path, 'name = "irb120_like"\n', "")
    assert message == f"{path}: [robot] name: missing"
    path, message = error_of(tmp_path, "[units]", "[unit]")
    assert message == f"{path}: [unit]: unknown table; did you mean [units]?"  # before it is missed


def test_the_defaults_of_limits_a_file_leaves_out_are_unchanged(tmp_path: Path) -> None:
    text = ARM[: ARM.index("[limits]")]
    path = tmp_path / "bare.toml"
    path.write_text(text)
    model = load_model(path)
    assert model.upper == pytest.approx([math.pi] * 6) and model.lower == pytest.approx([-math.pi] * 6)
    assert model.max_velocity == pytest.approx([math.pi] * 6)
    assert model.max_acceleration == pytest.approx([10.0] * 6) and model.max_jerk == pytest.approx([500.0] * 6)


# -- the other TOML files: a URDF's sidecar, cell files -----------------------------------------------------


def test_a_urdf_sidecar_is_read_as_strictly(tmp_path: Path) -> None:
    shutil.copy(DATA / "jibot_zxs.urdf", tmp_path / "arm.urdf")
    sidecar = tmp_path / "arm.frames.toml"
    sidecar.write_text('[units]\nlength = "mm"\n[tcp]\nxyz = [0, 0, 100]\n')
    with pytest.raises(ModelError) as info:
        load_model(tmp_path / "arm.urdf")
    assert str(info.value) == f"{sidecar}: [tcp]: unknown table; did you mean [tool]?"
    sidecar.write_text("[limits]\nvelocity = [1, 1, 1, 1, 1, 1]\n")  # a URDF's limits are in the URDF
    with pytest.raises(ModelError) as info:
        load_model(tmp_path / "arm.urdf")
    assert str(info.value) == f"{sidecar}: [limits]: unknown table (known: [units], [base], [tool], [supervision])"
    sidecar.write_text("[base]\nrpy = [0, 0, 90]\nxzy = [0, 0, 1]\n")
    with pytest.raises(ModelError) as info:
        load_model(tmp_path / "arm.urdf")
    assert str(info.value) == f"{sidecar}: [base] xzy: unknown key; did you mean xyz?"


def test_a_supervision_table_shows_its_values_in_the_files_unit(tmp_path: Path) -> None:
    path = tmp_path / "arm.toml"
    path.write_text(ARM + "\n[supervision]\nmanual_speed = -250\n")
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: [supervision] manual_speed: -250 mm/s must be > 0"
    path.write_text(ARM + "\n[supervision]\nallowed = { lower = [0, 0, 900], upper = [500, 500, 800] }\n")
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: [supervision] allowed: lower z = 900 mm is not below upper z = 800 mm"


def test_a_cell_file_keeps_its_own_tables_but_not_misspelt_ones(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text('[units]\nlength = "mm"\n[supervision]\nfloor = -200\n[robots]\nnames = ["a"]\n')
    assert load_supervision(cell).floor == pytest.approx(-0.2)  # [robots]: the cell's own business
    cell.write_text('[unit]\nlength = "mm"\n[supervision]\nfloor = -200\n')  # would be metres: 200 m down
    with pytest.raises(ModelError) as info:
        load_supervision(cell)
    assert str(info.value) == f"{cell}: [unit]: unknown table; did you mean [units]?"
    cell.write_text("[supervison]\nfloor = -200\n[supervision]\n")
    with pytest.raises(ModelError) as info:
        load_supervision(cell)
    assert str(info.value) == f"{cell}: [supervison]: unknown table; did you mean [supervision]?"


# -- URDF: a foreign format --------------------------------------------------------------------------------

_URDF = """<?xml version="1.0"?>
<robot name="two" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material>
  <link name="a"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual>
    <inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="b"/>
  <link name="c"/>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" velocity="1" effort="10"/><dynamics damping="0.1" friction="0"/>
    <safety_controller soft_lower_limit="-0.9" soft_upper_limit="0.9" k_position="10" k_velocity="1"/>
    <calibration rising="0"/></joint>
  <joint name="j2" type="prismatic"><parent link="b"/><child link="c"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.3" velocity="0.5" effort="10"/><mimic joint="j1" multiplier="1"/></joint>
  <transmission name="t1"><type>transmission_interface/SimpleTransmission</type>
    <joint name="j1"><hardwareInterface>PositionJointInterface</hardwareInterface></joint></transmission>
  <gazebo reference="a"><material>Gazebo/Grey</material></gazebo>
</robot>
"""


def test_a_urdf_keeps_the_elements_the_loader_does_not_read(tmp_path: Path) -> None:
    path = tmp_path / "two.urdf"
    path.write_text(_URDF)
    model = load_model(path)
    assert model.joint_names == ("j1", "j2") and model.upper[1] == pytest.approx(0.3)


def test_an_inverted_urdf_limit_names_the_file_and_the_joint(tmp_path: Path) -> None:
    path = tmp_path / "two.urdf"
    path.write_text(_URDF.replace('lower="-1" upper="1"', 'lower="1.5" upper="-1.5"'))
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: joint 'j1' limit.lower = 1.5 rad is not below limit.upper = -1.5 rad"
    path.write_text(_URDF.replace('lower="0" upper="0.3"', 'upper="0"'))
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: joint 'j2' limit.lower = 0 (not given) m is not below limit.upper = 0 m"
    path.write_text(_URDF.replace('velocity="0.5"', 'velocity="-0.5"'))
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: joint 'j2' limit.velocity = -0.5 m/s must be > 0"


# -- the shipped files ---------------------------------------------------------------------------------------


def test_every_shipped_file_loads() -> None:
    assert len(shipped_models()) >= 4 and shipped_cells()
    for name in shipped_models():
        assert load_model(name).dof == 6
    for name in shipped_cells():
        assert load_supervision(name).has_zones


# A citation of a file of this repository: a path with a folder and a file suffix, or a bare
# Markdown name; a URL (https://..., github.com/...) cites something else. "#anchor" names a heading.
_URL = re.compile(r"(?:https?://|\b[\w-]+(?:\.[\w-]+)+/)\S*")
_REPO_PATH = re.compile(r"(?<![\w./-])((?:[\w-]+/)+[\w.-]*\.[A-Za-z]+|[\w-]+\.md)(?:#([\w-]+))?")


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def broken_citations(text: str) -> list[str]:
    """The repository paths (and #anchors) ``text`` cites that the repository does not have."""
    broken = []
    for match in _REPO_PATH.finditer(_URL.sub(" ", text)):
        path, anchor = REPO / match[1], match[2]
        if not path.is_file():
            broken.append(match[1])
        elif anchor is not None:
            headings = re.findall(r"^#+ (.+)$", path.read_text(encoding="utf-8"), flags=re.MULTILINE)
            if anchor not in {_slug(h) for h in headings}:
                broken.append(match[0])
    return broken


def test_the_citation_check_finds_what_the_repository_does_not_have() -> None:
    old = (
        "D-H convention (docs/motion.md §1.2); this is the table as motion.md §1.3 reads it. It agrees\n"
        "with the independent reference cases in conformance/fk_reference.json to 1e-12.\n"
        "(docs/kinematics.md#no-such-heading), rad/s^2, 1/s, client/demo.py, tests/data/README.md,\n"
        "https://github.com/ros-industrial/kuka_experimental/blob/melodic-devel/kuka_kr6_support/urdf/x.xacro\n"
        "github.com/ros-industrial/kuka_experimental, docs/kinematics.md#adding-a-model"
    )
    assert broken_citations(old) == [
        "docs/motion.md",
        "motion.md",
        "conformance/fk_reference.json",
        "docs/kinematics.md#no-such-heading",
    ]


@pytest.mark.parametrize("path", sorted(MODELS.iterdir()), ids=lambda p: p.name)
def test_every_shipped_model_file_cites_only_what_the_repository_has(path: Path) -> None:
    assert broken_citations(path.read_text(encoding="utf-8")) == []
