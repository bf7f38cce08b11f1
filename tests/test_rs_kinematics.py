"""Robot models and forward kinematics against the independent reference cases."""

from __future__ import annotations

import json
import math
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


def test_home_pose_of_motion_md() -> None:
    """q2 = +pi/2 gives the usual L pose with the flange at (0.345, 0, 0.659) m (motion.md §1.2)."""
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
            "units.length",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "weird"\njoints = []\n',
            "dh.convention",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "standard"\n'
            'joints = [{ alpha = 0, a = "long", d = 0 }]\n',
            "dh.joints[0].a",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "standard"\n'
            "joints = [{ alpha = 0, d = 0 }]\n",
            "dh.joints[0].a",
        ),
        (
            '[robot]\nname = "x"\n[units]\nlength = "m"\nangle = "rad"\n[dh]\nconvention = "standard"\n'
            "joints = [{ alpha = 0, a = 0, d = 0 }]\n[limits]\nvelocity = [1, 2]\n",
            "limits.velocity",
        ),
    ],
)
def test_bad_model_files_name_the_file_and_the_field(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(path) in str(info.value) and message in str(info.value)


def test_unknown_model_name() -> None:
    with pytest.raises(ModelError, match="jibot_zxs"):
        load_model("no_such_robot")
