"""Cartesian supervision settings (robot_server/workspace.py): validation, TOML parsing and loading,
and the geometry the controller uses to check TCP positions and paths against workspace zones."""

from __future__ import annotations

import dataclasses
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_server.kinematics import fk, fk_batch
from robot_server.loader import load_model, load_supervision, shipped_cells, shipped_models
from robot_server.model import ModelError
from robot_server.workspace import (
    FLOOR_ALARM,
    FORBIDDEN_ZONE_ALARM,
    TCP_SPEED_ALARM,
    ZONE_ALARM,
    Box,
    Supervision,
    Violation,
    alarm_code,
    densify,
    first_violation,
    parse_supervision,
    point_violation,
    resample_count,
)

from .refdata import DATA

MODELS = Path(__file__).resolve().parent.parent / "robot_server" / "models"

#: a cell used throughout: allowed x 0.1..0.6, y -0.5..0.5, z -0.2..1; floor 0.05; two forbidden boxes
CELL = Supervision(
    allowed=Box((0.1, -0.5, -0.2), (0.6, 0.5, 1.0), "cell"),
    floor=0.05,
    forbidden=(
        Box((0.3, 0.3, 0.3), (0.4, 0.4, 0.4), "pillar"),
        Box((0.2, -0.2, 0.1), (0.5, 0.0, 0.2), "fixture"),
    ),
)


# -- validation ---------------------------------------------------------------------------------------


def test_a_box_is_validated_and_keeps_floats() -> None:
    box = Box([0, 0, 0], np.array([1, 2, 3]), "b")  # type: ignore[arg-type]
    assert box.lower == (0.0, 0.0, 0.0) and box.upper == (1.0, 2.0, 3.0)
    assert all(type(v) is float for v in (*box.lower, *box.upper))
    assert box.bounds == (0.0, 0.0, 0.0, 1.0, 2.0, 3.0)
    assert box.contains(1.0, 2.0, 3.0) and not box.contains(1.0, 2.0, 3.0001)  # the faces belong to it
    assert box.contains_points(np.array([[0.5, 0.5, 0.5], [0, 0, -1]])).tolist() == [True, False]
    assert box.describe() == "x 0..1, y 0..2, z 0..3 m"


@pytest.mark.parametrize(
    ("lower", "upper", "message"),
    [
        ((0, 0, 0), (1, 0, 1), r"box 'b': lower y = 0 must be less than upper y = 0"),
        ((0, 2, 0), (1, 1, 1), r"lower y = 2 must be less than upper y = 1"),
        ((0, 0, math.nan), (1, 1, 1), r"box 'b' lower z = nan must be a finite number"),
        ((0, 0, 0), (1, 1, math.inf), r"upper z = inf must be a finite number"),
        ((0, 0), (1, 1, 1), r"lower must be 3 numbers"),
        ((0, 0, 0), "abc", r"upper must be 3 numbers"),
        ((True, 0, 0), (1, 1, 1), r"lower x = True must be a finite number"),
    ],
)
def test_a_bad_box_is_refused(lower: Any, upper: Any, message: str) -> None:
    with pytest.raises(ModelError, match=message):
        Box(lower, upper, "b")


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"manual_speed": 0.0}, r"supervision manual_speed = 0\.0 must be a finite number > 0"),
        ({"manual_speed": math.nan}, r"manual_speed = nan"),
        ({"auto_speed": -1.0}, r"supervision auto_speed = -1\.0 must be"),
        ({"auto_speed": True}, r"auto_speed = True must be"),
        ({"tolerance": 0}, r"supervision tolerance = 0 must be"),
        ({"floor": math.inf}, r"supervision floor = inf must be a finite number"),
        ({"allowed": (0, 0, 0)}, r"supervision allowed must be a Box"),
        ({"forbidden": Box((0, 0, 0), (1, 1, 1))}, r"supervision forbidden must be a sequence of Box"),
        ({"forbidden": (Box((0, 0, 0), (1, 1, 1)), "x")}, r"supervision forbidden\[1\] must be a Box"),
        (
            {"allowed": Box((0, 0, 0), (1, 1, 1)), "floor": 1.5},
            r"floor z = 1\.5 m is above the allowed box's top z = 1 m",
        ),
    ],
)
def test_bad_supervision_settings_name_the_field(fields: dict[str, Any], message: str) -> None:
    with pytest.raises(ModelError, match=message):
        Supervision(**fields)


def test_supervision_defaults_and_helpers() -> None:
    default = Supervision()
    assert (default.manual_speed, default.auto_speed, default.tolerance) == (0.25, None, 0.001)
    assert not default.has_zones and point_violation(default, 1e9, -1e9, -1e9) is None
    assert default.speed_limit(manual=True) == 0.25 and default.speed_limit(manual=False) is None
    assert Supervision(auto_speed=2).speed_limit(manual=False) == 2.0
    assert Supervision(floor=0).has_zones and CELL.has_zones
    assert Supervision(allowed=Box((0, 0, 0), (1, 1, 1))).has_zones
    listed = Supervision(forbidden=[Box((0, 0, 0), (1, 1, 1))])  # type: ignore[arg-type]
    assert isinstance(listed.forbidden, tuple) and listed.has_zones
    assert listed == Supervision(forbidden=(Box((0, 0, 0), (1, 1, 1)),))
    assert dataclasses.replace(CELL, floor=None).floor is None  # replace recomputes the flat bounds
    assert point_violation(dataclasses.replace(CELL, floor=None), 0.2, 0.0, 0.0) is None


# -- alarm codes and messages -------------------------------------------------------------------------


def test_alarm_codes() -> None:
    assert (TCP_SPEED_ALARM, ZONE_ALARM, FLOOR_ALARM, FORBIDDEN_ZONE_ALARM) == (4400, 4500, 4501, 4510)
    at = (0.0, 0.0, 0.0)
    assert alarm_code(Violation("allowed", -1, 0, at)) == 4500
    assert alarm_code(Violation("floor", -1, 0, at)) == 4501
    assert [alarm_code(Violation("forbidden", i, 0, at)) for i in (0, 1, 87, 88, 89, 500)] == [
        4511,
        4512,
        4598,
        4599,
        4599,
        4599,
    ]
    assert Violation("forbidden", 2, 0, at).code == 4513
    with pytest.raises(ValueError, match="unknown violation kind"):
        alarm_code(Violation("ceiling", -1, 0, at))


def test_violation_messages() -> None:
    floor = point_violation(CELL, 0.512, 0.1, 0.02)
    assert floor is not None and floor.message == "TCP at (0.512, 0.100, 0.020) m is below the floor z = 0.05 m"
    fixture = point_violation(CELL, 0.25, -0.1, 0.15)
    assert fixture is not None and fixture.message == (
        "TCP at (0.250, -0.100, 0.150) m enters forbidden zone 2 'fixture' (x 0.2..0.5, y -0.2..0, z 0.1..0.2 m)"
    )
    outside = point_violation(CELL, 0.7, 0.1, 1.5)
    assert outside is not None and outside.message == (
        "TCP at (0.700, 0.100, 1.500) m leaves the allowed workspace 'cell' x 0.1..0.6, z -0.2..1 m"
    )
    unnamed = point_violation(Supervision(forbidden=(Box((0, 0, 0), (1, 1, 1)),)), 0.5, 0.5, 0.5)
    assert unnamed is not None and unnamed.message == (
        "TCP at (0.500, 0.500, 0.500) m enters forbidden zone 1 (x 0..1, y 0..1, z 0..1 m)"
    )


# -- point and path checks ----------------------------------------------------------------------------


def test_point_violation_kinds_and_boundaries() -> None:
    assert point_violation(CELL, 0.5, 0.4, 0.6) is None
    assert point_violation(CELL, 0.6, 0.5, 1.0) is None  # on the allowed box's faces: inside
    assert point_violation(CELL, 0.5, 0.0, 0.05) is None  # on the floor: allowed
    v = point_violation(CELL, 0.4, 0.4, 0.4)  # on a forbidden box's corner: entered
    assert v is not None and (v.kind, v.index, v.sample, v.zone) == ("forbidden", 0, 0, CELL.forbidden[0])
    v = point_violation(CELL, 0.5, 0.0, -0.3)  # below the floor and outside the box: the box first
    assert v is not None and (v.kind, v.index, v.zone, v.code) == ("allowed", -1, CELL.allowed, ZONE_ALARM)
    v = point_violation(CELL, 0.5, 0.0, 0.0)
    assert v is not None and (v.kind, v.floor, v.code) == ("floor", 0.05, FLOOR_ALARM)
    v = point_violation(CELL, np.float64(0.3), np.float64(-0.1), np.float64(0.15))
    assert v is not None and v.kind == "forbidden" and v.index == 1 and type(v.position[0]) is float
    v = point_violation(CELL, math.nan, 0.0, 0.5)  # not a number: never inside the allowed box
    assert v is not None and v.kind == "allowed"
    assert point_violation(Supervision(floor=0.0), 0.0, 0.0, math.nan) is not None
    # overlapping forbidden boxes: the first in the order is reported
    two = Supervision(forbidden=(Box((0, 0, 0), (1, 1, 1), "a"), Box((0.5, 0.5, 0.5), (2, 2, 2), "b")))
    v = point_violation(two, 0.7, 0.7, 0.7)
    assert v is not None and v.index == 0


def test_first_violation_reports_the_earliest_sample() -> None:
    inside = [0.5, 0.4, 0.6]
    path = np.array([inside, inside, [0.3, -0.1, 0.15], [0.5, 0.0, 0.0], [0.7, 0.0, 0.5]])
    v = first_violation(CELL, path)
    assert v is not None and (v.kind, v.index, v.sample, v.position) == ("forbidden", 1, 2, (0.3, -0.1, 0.15))
    v = first_violation(CELL, path[[0, 1, 3, 2, 4]])
    assert v is not None and (v.kind, v.sample) == ("floor", 2)
    v = first_violation(CELL, path[[0, 4, 3, 2]])
    assert v is not None and (v.kind, v.sample, v.zone) == ("allowed", 1, CELL.allowed)
    assert first_violation(CELL, path[:2]) is None
    assert first_violation(CELL, np.empty((0, 3))) is None
    assert first_violation(Supervision(), path) is None
    # at one sample: the allowed box, then the floor, then the forbidden boxes in order
    both = Supervision(allowed=Box((0, 0, 0), (1, 1, 1)), floor=0.5)
    v = first_violation(both, [[0.5, 0.5, 0.6], [0.5, 2.0, 0.1]])
    assert v is not None and (v.kind, v.sample) == ("allowed", 1)
    under = Supervision(floor=0.5, forbidden=(Box((0, 0, 0), (1, 1, 1)),))
    v = first_violation(under, [[2.0, 2.0, 2.0], [0.5, 0.5, 0.1]])
    assert v is not None and (v.kind, v.sample) == ("floor", 1)
    with pytest.raises(ValueError, match=r"an \(N, 3\) array"):
        first_violation(CELL, [0.1, 0.2, 0.3])


def test_a_path_through_a_zone_between_far_samples_is_found_after_densify() -> None:
    # two samples 0.4 m apart on either side of the 0.1 m pillar: the samples alone miss it
    path = np.array([[0.5, 0.2, 0.35], [0.15, 0.45, 0.35]])
    assert first_violation(CELL, path) is None
    dense = densify(path, CELL.tolerance)
    v = first_violation(CELL, dense)
    assert v is not None and (v.kind, v.index) == ("forbidden", 0)
    assert CELL.forbidden[0].contains(*v.position)
    assert 0 < v.sample < len(dense) - 1
    # the sample found is within the tolerance of where the line enters the box (at y = 0.3, t = 0.4)
    entry = path[0] + 0.4 * (path[1] - path[0])
    assert np.linalg.norm(np.array(v.position) - entry) <= CELL.tolerance


def test_densify() -> None:
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.3, 0.4], [1.0, 0.3, 0.4001]])
    step = 0.1
    dense = densify(path, step)
    assert len(dense) == resample_count(path, step) == 1 + 10 + 1 + 5 + 1
    gaps = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    assert gaps.max() <= step * (1 + 1e-12)
    # every original point is kept, in order
    kept = [int(np.flatnonzero(np.all(dense == p, axis=1))[0]) for p in path]
    assert kept == sorted(kept) and kept[0] == 0 and kept[-1] == len(dense) - 1
    assert np.allclose(dense[:11, 0], np.linspace(0.0, 1.0, 11)) and not dense[:11, 1:].any()
    # fewer than two points: a copy
    one = np.array([[1.0, 2.0, 3.0]])
    assert densify(one, 0.1).tolist() == one.tolist() and densify(one, 0.1) is not one
    assert densify(np.empty((0, 3)), 0.1).shape == (0, 3) and resample_count(one, 0.1) == 1
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="step must be"):
            densify(path, bad)
    with pytest.raises(ValueError, match="finite"):
        densify(np.array([[0, 0, 0], [math.inf, 0, 0]]), 0.1)


finite = st.floats(-1.0, 1.5, allow_nan=False)
points = st.tuples(finite, finite, finite)


@settings(max_examples=300, deadline=None)
@given(st.lists(points, min_size=1, max_size=30))
def test_point_violation_agrees_with_first_violation(path: list[tuple[float, float, float]]) -> None:
    # snap some coordinates onto the zones' faces, where the comparisons matter most
    faces = sorted({*CELL.allowed.bounds, *CELL.forbidden[0].bounds, *CELL.forbidden[1].bounds, 0.05})  # type: ignore[union-attr]
    snapped = [tuple(min(faces, key=lambda f: abs(f - c)) if abs(c * 1e3) % 7 < 1 else c for c in p) for p in path]
    each = [point_violation(CELL, *p) for p in snapped]
    expected = next(((i, v) for i, v in enumerate(each) if v is not None), None)
    found = first_violation(CELL, np.array(snapped))
    if expected is None:
        assert found is None
    else:
        i, v = expected
        assert found == v._replace(sample=i)


# -- parsing --------------------------------------------------------------------------------------------

TABLE_MM = {
    "manual_speed": 200,
    "auto_speed": 1500.0,
    "tolerance": 2,
    "floor": -100,
    "allowed": {"lower": [-800, -800, -400], "upper": [800, 800, 1100]},
    "forbidden": [
        {"name": "fixture", "lower": [200, -550, -200], "upper": [500, -300, 150]},
        {"lower": [-500, -100, 0], "upper": [-300, 100, 300]},
    ],
}
EXPECTED = Supervision(
    manual_speed=0.2,
    auto_speed=1.5,
    tolerance=0.002,
    floor=-0.1,
    allowed=Box((-0.8, -0.8, -0.4), (0.8, 0.8, 1.1)),
    forbidden=(Box((0.2, -0.55, -0.2), (0.5, -0.3, 0.15), "fixture"), Box((-0.5, -0.1, 0.0), (-0.3, 0.1, 0.3))),
)


def assert_same(a: Supervision, b: Supervision) -> None:
    assert (a.manual_speed, a.auto_speed, a.tolerance, a.floor) == pytest.approx(
        (b.manual_speed, b.auto_speed, b.tolerance, b.floor)
    )
    assert (a.allowed is None) == (b.allowed is None)
    boxes = [
        *([(a.allowed, b.allowed)] if a.allowed and b.allowed else []),
        *zip(a.forbidden, b.forbidden, strict=True),
    ]
    assert len(a.forbidden) == len(b.forbidden)
    for x, y in boxes:
        assert x.name == y.name and x.bounds == pytest.approx(y.bounds)


def test_parse_in_mm_and_in_m() -> None:
    assert_same(parse_supervision(TABLE_MM, length_scale=1e-3, where="cell.toml"), EXPECTED)
    metres = {
        "manual_speed": 0.2,
        "auto_speed": 1.5,
        "tolerance": 0.002,
        "floor": -0.1,
        "allowed": {"lower": [-0.8, -0.8, -0.4], "upper": [0.8, 0.8, 1.1]},
        "forbidden": [
            {"name": "fixture", "lower": [0.2, -0.55, -0.2], "upper": [0.5, -0.3, 0.15]},
            {"lower": [-0.5, -0.1, 0], "upper": [-0.3, 0.1, 0.3]},
        ],
    }
    assert parse_supervision(metres, length_scale=1.0, where="cell.toml") == EXPECTED
    assert parse_supervision({}, length_scale=1e-3, where="x") == Supervision()  # all defaults
    assert parse_supervision({"floor": 0}, length_scale=1e-3, where="x") == Supervision(floor=0.0)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"manual_sped": 250}, r"cell\.toml: \[supervision\] manual_sped: unknown key; did you mean manual_speed\?$"),
        ({"ceiling": 250}, r"cell\.toml: \[supervision\] ceiling: unknown key \(known: manual_speed, auto_speed, "),
        (
            {"allowed": {"lower": [0, 0, 0], "upper": [1, 1, 1], "colour": 1}},
            r"\[supervision\] allowed\.colour: unknown key \(known: name, lower, upper\)",
        ),
        (
            {"forbidden": [{"lower": [0, 0, 0], "uper": [1, 1, 1]}]},
            r"\[supervision\] forbidden\[0\]\.uper: unknown key; did you mean upper\?",
        ),
        ({"manual_speed": "fast"}, r"cell\.toml: \[supervision\] manual_speed: must be a finite number, not 'fast'"),
        ({"floor": True}, r"\[supervision\] floor: must be a finite number, not True"),
        ({"manual_speed": -250}, r"cell\.toml: \[supervision\] manual_speed: -250 mm/s must be > 0$"),  # file units
        ({"tolerance": 0}, r"cell\.toml: \[supervision\] tolerance: 0 mm must be > 0$"),
        ({"allowed": [0, 0, 0]}, r"\[supervision\] allowed: must be a table"),
        ({"allowed": {"lower": [0, 0, 0]}}, r"\[supervision\] allowed\.upper: missing"),
        ({"allowed": {"lower": [0, 0], "upper": [1, 1, 1]}}, r"\[supervision\] allowed\.lower: must be a list of 3"),
        (
            {"allowed": {"lower": [0, 0, 2], "upper": [1, 1, 1]}},
            r"\[supervision\] allowed: lower z = 2 mm is not below upper z = 1 mm$",
        ),
        (
            {"floor": 1500, "allowed": {"lower": [0, 0, 0], "upper": [1, 1, 1000.5]}},
            r"\[supervision\] floor: 1500 mm is above the top of the allowed box, z = 1000\.5 mm",
        ),
        ({"forbidden": {"lower": [0, 0, 0], "upper": [1, 1, 1]}}, r"\[supervision\] forbidden: must be a list"),
        ({"forbidden": [[0, 0, 0]]}, r"\[supervision\] forbidden\[0\]: must be a table"),
        ({"forbidden": [{"name": 3, "lower": [0, 0, 0], "upper": [1, 1, 1]}]}, r"forbidden\[0\]\.name: must be a str"),
    ],
)
def test_parse_errors_name_the_file_and_the_field(table: dict[str, Any], message: str) -> None:
    with pytest.raises(ModelError, match=message):
        parse_supervision(table, length_scale=1e-3, where="cell.toml")


def test_parse_refuses_a_non_table() -> None:
    with pytest.raises(ModelError, match=r"cell\.toml: \[supervision\]: must be a table"):
        parse_supervision([1, 2], length_scale=1.0, where="cell.toml")  # type: ignore[arg-type]


# -- loading --------------------------------------------------------------------------------------------

SUPERVISION_MM = """
[supervision]
manual_speed = 200
auto_speed = 1500.0
tolerance = 2
floor = -100
allowed = { lower = [-800, -800, -400], upper = [800, 800, 1100] }
forbidden = [
  { name = "fixture", lower = [200, -550, -200], upper = [500, -300, 150] },
  { lower = [-500, -100, 0], upper = [-300, 100, 300] },
]
"""


def test_shipped_models_have_the_default_supervision() -> None:
    assert "cell_example" not in shipped_models() and shipped_cells() == ["cell_example"]
    for name in shipped_models():
        assert load_model(name).supervision == Supervision()


def test_a_toml_model_takes_its_supervision_table(tmp_path: Path) -> None:
    text = (MODELS / "jibot_zxs.toml").read_text()  # a model in mm
    path = tmp_path / "arm.toml"
    path.write_text(text + SUPERVISION_MM)
    model = load_model(path)
    assert_same(model.supervision, EXPECTED)
    assert model.dof == 6 and len(model.motors) == 6  # the rest of the file as before
    path.write_text(text + "\n[supervision]\nceiling = 2000\n")
    with pytest.raises(ModelError, match=r"arm\.toml: \[supervision\] ceiling: unknown key"):
        load_model(path)
    path.write_text("supervision = 3\n" + text)
    with pytest.raises(ModelError, match=r"arm\.toml: \[supervision\]: must be a table"):
        load_model(path)


def test_a_urdf_takes_its_supervision_from_the_sidecar_file(tmp_path: Path) -> None:
    shutil.copy(DATA / "jibot_zxs.urdf", tmp_path / "arm.urdf")
    assert load_model(tmp_path / "arm.urdf").supervision == Supervision()  # no sidecar
    sidecar = tmp_path / "arm.frames.toml"
    sidecar.write_text('[units]\nlength = "mm"\n[base]\nxyz = [0, 0, 1000]\n' + SUPERVISION_MM)
    model = load_model(tmp_path / "arm.urdf")
    assert_same(model.supervision, EXPECTED)
    assert model.base[2, 3] == pytest.approx(load_model(DATA / "jibot_zxs.urdf").base[2, 3] + 1.0)  # [base] too
    sidecar.write_text("[supervision]\nfloor = 0.5\n")  # metres by default
    assert load_model(tmp_path / "arm.urdf").supervision == Supervision(floor=0.5)
    sidecar.write_text("[supervision]\nfloor = 0.5\nroof = 2\n")
    with pytest.raises(ModelError, match=r"arm\.frames\.toml: \[supervision\] roof: unknown key"):
        load_model(tmp_path / "arm.urdf")


def test_a_cell_file_loads_in_its_length_unit(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text('[units]\nlength = "mm"\nangle = "deg"\n' + SUPERVISION_MM)
    assert_same(load_supervision(cell), EXPECTED)
    assert_same(load_supervision(str(cell)), EXPECTED)
    cell.write_text("[supervision]\nallowed = { lower = [-1, -1, 0], upper = [1, 1, 2] }\n[robots]\nx = 1\n")
    assert load_supervision(cell) == Supervision(allowed=Box((-1, -1, 0), (1, 1, 2)))  # metres by default


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, r"missing\.toml: no such cell file, and not a shipped cell \(cell_example\)"),
        ("[supervision\n", r"bad\.toml: not valid TOML"),
        (
            '[units]\nlength = "furlong"\n[supervision]\n',
            r"bad\.toml: \[units\] length: 'furlong' is not one of 'm', 'mm'",
        ),
        ('[units]\nangle = "grad"\n[supervision]\n', r"bad\.toml: \[units\] angle: 'grad' is not one of"),
        # other tables are the cell's own business, but not a misspelling of the two it reads
        ('[unit]\nlength = "mm"\n[supervision]\n', r"bad\.toml: \[unit\]: unknown table; did you mean \[units\]\?"),
        ('[units]\nlenght = "mm"\n[supervision]\n', r"bad\.toml: \[units\] lenght: unknown key; did you mean length\?"),
        ("[units]\n[robot]\n", r"bad\.toml: missing table \[supervision\]"),
        ("[supervision]\nfloor = [1]\n", r"bad\.toml: \[supervision\] floor: must be a finite number"),
        ("[supervision]\nforbidden = 1\n", r"bad\.toml: \[supervision\] forbidden: must be a list"),
    ],
)
def test_a_bad_cell_file_is_named(tmp_path: Path, text: str | None, message: str) -> None:
    path = tmp_path / ("missing.toml" if text is None else "bad.toml")
    if text is not None:
        path.write_text(text)
    with pytest.raises(ModelError, match=message):
        load_supervision(path)


def test_the_example_cell_holds_the_robot_at_rest_and_the_papers_rectangle() -> None:
    cell = load_supervision("cell_example")
    assert cell == load_supervision(MODELS / "cell_example.toml")
    assert cell.manual_speed == pytest.approx(0.25) and cell.auto_speed == pytest.approx(1.5)
    assert cell.tolerance == pytest.approx(0.001) and cell.floor == pytest.approx(-0.2)
    assert [box.name for box in cell.forbidden] == ["fixture"]
    model = load_model("jibot_zxs")
    assert point_violation(cell, *fk(model, np.zeros(6))[:3, 3]) is None  # at rest at q = 0
    # the paper's rectangle (client/demo.py: 160 x 100 mm around the flange at this configuration)
    centre = fk(model, [0.0, 0.3, -0.2, 0.0, 0.9, 0.0])[:3, 3]
    corners = centre + np.array([[-0.05, -0.08, 0], [0.05, -0.08, 0], [0.05, 0.08, 0], [-0.05, 0.08, 0]])
    assert first_violation(cell, densify(np.vstack([corners, corners[:1]]), cell.tolerance)) is None
    # a joint move from q = 0 to the rectangle's centre configuration
    q = np.linspace(0.0, 1.0, 500)[:, None] * np.array([0.0, 0.3, -0.2, 0.0, 0.9, 0.0])
    assert first_violation(cell, fk_batch(model, q)[:, :3, 3]) is None
    # every reachable flange position is inside the allowed box; the floor and the fixture are reachable
    q = np.random.default_rng(3).uniform(model.lower, model.upper, size=(20000, 6))
    reach = fk_batch(model, q)[:, :3, 3]
    assert cell.allowed is not None and cell.allowed.contains_points(reach).all()
    assert cell.floor is not None and (reach[:, 2] < cell.floor).any()
    assert cell.forbidden[0].contains_points(reach).any()
