"""Jacobian, closed-form and numeric inverse kinematics on the shipped models."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from robot_server.kinematics import (
    IKFailed,
    IKSolution,
    Singularity,
    closed_form,
    fk,
    fk_batch,
    ik,
    ik_numeric,
    jacobian,
    manipulability,
    rotation_error,
    singularity_measure,
)
from robot_server.kinematics.__main__ import main as kinematics_main
from robot_server.kinematics._trace import SCALAR_OPS
from robot_server.kinematics.numeric import damped_step
from robot_server.loader import load_model, shipped_models
from robot_server.model import RobotModel

from .refdata import DATA

SKEW = str(DATA / "skew_arm.toml")  # the general (quartic) position case
SPHERICAL = ["jibot_zxs", "puma560", "kuka_kr6_r900_sixx", SKEW]
REFERENCE = json.loads((DATA / "fk_reference.json").read_text())


def pose_error(model: RobotModel, q: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    t = fk(model, q)
    return float(np.linalg.norm(t[:3, 3] - target[:3, 3])), float(
        np.linalg.norm(rotation_error(target[:3, :3].tolist(), t[:3].ravel().tolist()))
    )


def wrapped_equal(a: np.ndarray, b: np.ndarray, tol: float = 1e-7) -> bool:
    return bool(np.all(np.abs(np.remainder(np.asarray(a) - np.asarray(b) + math.pi, 2 * math.pi) - math.pi) < tol))


def unlimited(model: RobotModel) -> RobotModel:
    joints = tuple(dataclasses.replace(j, position=(-2 * math.pi, 2 * math.pi)) for j in model.joints)
    return dataclasses.replace(model, joints=joints)


# -- Jacobian -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", shipped_models())
def test_jacobian_matches_finite_differences(name: str) -> None:
    model = load_model(name)
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = rng.uniform(model.lower, model.upper)
        jac = jacobian(model, q)
        t0 = fk(model, q)
        h = 1e-7
        for i in range(model.dof):
            dq = q.copy()
            dq[i] += h
            t1 = fk(model, dq)
            linear = (t1[:3, 3] - t0[:3, 3]) / h
            angular = np.array(rotation_error(t1[:3, :3].tolist(), t0[:3].ravel().tolist())) / h
            assert np.allclose(jac[:3, i], linear, atol=1e-5)
            assert np.allclose(jac[3:, i], angular, atol=1e-5)


def test_manipulability_and_singularity_measure_vanish_at_the_wrist_singularity() -> None:
    model = load_model("jibot_zxs")
    regular = [0.1, 1.2, -0.4, 0.3, 0.8, 0.2]
    singular = [0.1, 1.2, -0.4, 0.3, 0.0, 0.2]
    assert manipulability(model, regular) > 1e-3
    assert manipulability(model, singular) < 1e-8  # sqrt of a determinant rounded near 1e-19
    assert 0.0 < singularity_measure(model, regular) <= 1.0
    assert singularity_measure(model, singular) < 1e-10


# -- closed form --------------------------------------------------------------------------------


def test_closed_form_is_detected_from_the_geometry() -> None:
    assert {name: closed_form(load_model(name)) is not None for name in shipped_models()} == {
        "jibot_zxs": True,
        "puma560": True,
        "kuka_kr6_r900_sixx": True,  # a URDF model
        "ur5": False,  # offset wrist
    }
    assert closed_form(load_model(str(DATA / "jibot_zxs.urdf"))) is not None
    cases = {name: getattr(closed_form(load_model(name)), "case", None) for name in SPHERICAL}
    assert cases == {
        "jibot_zxs": "intersecting",
        "puma560": "intersecting",
        "kuka_kr6_r900_sixx": "offset",  # shoulder offset, axes 2 and 3 parallel: a quadratic
        SKEW: "general",
    }


@pytest.mark.slow
@pytest.mark.parametrize("name", SPHERICAL)
def test_closed_form_on_10000_random_poses(name: str) -> None:
    model = load_model(name)
    solver = closed_form(model)
    assert solver is not None
    rng = np.random.default_rng(2024)
    q = rng.uniform(model.lower, model.upper, size=(10_000, 6))
    poses = fk_batch(model, q)
    solutions, valid, flags = solver.solve_batch(poses)
    assert not np.isnan(solutions[valid]).any()
    # every returned solution reproduces its pose to 1e-9 and lies within the limits
    rows, slots = np.nonzero(valid)
    reached = fk_batch(model, solutions[rows, slots])
    assert np.max(np.abs(reached - poses[rows])) < 1e-9
    assert np.all(solutions[rows, slots] >= model.lower - 1e-12)
    assert np.all(solutions[rows, slots] <= model.upper + 1e-12)
    # for non-singular poses the generating configuration is among the solutions (modulo 2 pi)
    singular = (flags != 0).any(axis=1)
    diff = np.remainder(solutions - q[:, None, :] + math.pi, 2 * math.pi) - math.pi
    found = (np.max(np.abs(np.nan_to_num(diff, nan=1.0)), axis=2) < 1e-7).any(axis=1)
    assert np.all(found | singular)
    assert singular.mean() < 0.01
    # the single-pose solver agrees with the batch
    for i in range(0, 10_000, 97):
        single = solver.solve_all(poses[i])
        assert len(single) == valid[i].sum()
        for s in single:
            assert any(wrapped_equal(s.q, solutions[i, j], 1e-9) for j in np.nonzero(valid[i])[0])


@pytest.mark.parametrize("name", SPHERICAL)
def test_nearest_in_floats_is_solve(name: str) -> None:
    """The control loop's float form of :meth:`solve` gives the same solution, seeded anywhere."""
    model = load_model(name)
    solver = closed_form(model)
    assert solver is not None
    rng = np.random.default_rng(19)
    q = rng.uniform(model.lower, model.upper, size=(200, 6))
    seeds = q + rng.normal(0.0, 0.3, size=q.shape)
    for pose, seed in zip(fk_batch(model, q), seeds, strict=True):
        expected = solver.solve(pose, seed)
        got = solver.nearest(pose[:3, :3].reshape(9).tolist(), pose[:3, 3].tolist(), seed.tolist())
        if expected is None:
            assert got is None
        else:
            assert got is not None and got.singular == expected.singular
            assert np.allclose(got.q, expected.q, rtol=0.0, atol=1e-12)


def test_reference_solution_sets_of_non_singular_cases() -> None:
    model = unlimited(load_model("jibot_zxs"))
    solver = closed_form(model)
    assert solver is not None
    checked = 0
    for case in REFERENCE["cases"]:
        if case["wrist_singular"] or case["shoulder_singular"]:
            continue
        ours = [np.array(s.q) for s in solver.solve_all(np.array(case["T"]))]
        theirs = [np.array(q) for q in case["ik_solutions_rtb_analytic"]]
        assert len(ours) == len(theirs) == case["n_ik_solutions_rtb_analytic"]
        for q in theirs:
            assert any(wrapped_equal(q, o, 1e-7) for o in ours)
        checked += 1
    assert checked >= 10


@pytest.mark.parametrize("name", SPHERICAL)
def test_wrist_singularity_is_flagged_keeps_the_seed_q4_and_has_no_nan(name: str) -> None:
    model = load_model(name)
    solver = closed_form(model)
    assert solver is not None
    # find q5 with axes 4 and 6 aligned: where the manipulability vanishes along q5
    q = np.array([0.3, -0.4, 0.5, 0.7, 0.0, -0.2])
    q5 = min(np.linspace(-1.5, 1.5, 3001), key=lambda v: manipulability(model, [*q[:4], v, q[5]]))
    q[4] = q5
    target = fk(model, q)
    seed = np.array([0.3, -0.4, 0.5, 1.1, q5, 0.0])
    solutions = solver.solve_all(target, seed)
    assert solutions
    assert any(s.singular & Singularity.WRIST for s in solutions)
    for s in solutions:
        assert all(math.isfinite(v) for v in s.q)
        pos, ori = pose_error(model, np.array(s.q), target)
        assert pos < 1e-9 and ori < 1e-9
        if s.singular & Singularity.WRIST:
            assert s.q[3] == pytest.approx(1.1, abs=1e-9) or wrapped_equal([s.q[3]], [1.1 + math.pi], 1e-6)


def _shoulder_singular(model: RobotModel) -> np.ndarray:
    """A configuration with the wrist centre on axis 1 (the base z axis): with q1 = 0 the centre
    stays in the x-z plane, so bisect on q2 for x = 0."""

    def centre_x(q2: float) -> float:
        return float(wrist_centre(model, np.array([0.0, q2, 0.4, 0.2, 0.5, 0.1]))[0])

    grid = np.linspace(model.lower[1], model.upper[1], 721)
    for a, b in itertools.pairwise(grid):
        if centre_x(a) * centre_x(b) < 0:
            for _ in range(80):
                m = (a + b) / 2
                a, b = (a, m) if centre_x(a) * centre_x(m) < 0 else (m, b)
            return np.array([0.0, (a + b) / 2, 0.4, 0.2, 0.5, 0.1])
    raise AssertionError("no shoulder singularity on the q2 grid")


@pytest.mark.parametrize("name", ["jibot_zxs", "kuka_kr6_r900_sixx"])
def test_shoulder_singularity_is_flagged_and_keeps_the_seed_q1(name: str) -> None:
    model = load_model(name)
    solver = closed_form(model)
    assert solver is not None
    q = _shoulder_singular(model)
    target = fk(model, q)
    solutions = solver.solve_all(target, [0.9, 0, 0, 0, 0, 0])
    assert solutions and all(s.singular & Singularity.SHOULDER for s in solutions)
    # the two shoulder sides meet here, not the elbow branches (on the KUKA: q3 = 0.4 and -0.23)
    assert not any(s.singular & Singularity.ELBOW for s in solutions)
    for s in solutions:
        pos, ori = pose_error(model, np.array(s.q), target)
        assert pos < 1e-9 and ori < 1e-9


def wrist_centre(model: RobotModel, q: np.ndarray) -> np.ndarray:
    solver = closed_form(model)
    assert solver is not None
    t = fk(model, q)
    return t[:3, 3] + t[:3, :3] @ (solver.r0.T @ np.array(solver.c_flange))


@pytest.mark.parametrize("name", ["jibot_zxs", "puma560", "kuka_kr6_r900_sixx"])
def test_elbow_singularity_merges_the_branches(name: str) -> None:
    model = load_model(name)
    solver = closed_form(model)
    assert solver is not None

    # the elbow alone sets the wrist centre's distance from o2 (on axis 2; at q1 = 0 it is where
    # the model has it); the elbow is singular where that distance is largest (arm stretched):
    # golden-section search on q3 (it finds that q3 only to ~1e-8: the distance is flat there)
    def reach(q3: float) -> float:
        return -float(np.linalg.norm(wrist_centre(model, np.array([0.0, 0.3, q3, 0.4, 0.6, 0.1])) - solver.o2))

    grid = np.linspace(model.lower[2], model.upper[2], 3601)
    q3 = float(min(grid, key=reach))
    lo, hi = q3 - 0.002, q3 + 0.002
    for _ in range(80):
        a, b = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
        lo, hi = (lo, b) if reach(a) < reach(b) else (a, hi)
    singular_q3 = (lo + hi) / 2

    def solve(dq3: float) -> tuple[np.ndarray, list[IKSolution]]:
        q = np.array([0.2, 0.3, singular_q3 + dq3, 0.4, 0.6, 0.1])
        target = fk(model, q)
        solutions = solver.solve_all(target, q)
        assert solutions
        for s in solutions:
            pos, ori = pose_error(model, np.array(s.q), target)
            assert pos < 1e-9 and ori < 1e-9
        return q, solutions

    # at the singularity (and within the flag's band, |1 - cos dq3| <= 1e-12: 1.4e-6 rad) the
    # elbow-up and -down branches are flagged as merged, whatever the last bit of the rounding
    # (the KUKA's used to be flagged only when |X| / |n| rounded to 1 or above). The pose fixes
    # q3 there only to about the square root of the rounding, hence 1e-6, not 1e-9
    for dq3 in (0.0, 1e-8, -1e-8, 3e-8, -3e-8, 1e-7, -1e-7, 1e-6, -1e-6):
        q, solutions = solve(dq3)
        merged = [s for s in solutions if s.singular & Singularity.ELBOW]
        assert any(wrapped_equal(s.q, q, 1e-6) for s in merged), dq3
        if solver.case == "intersecting":
            assert merged == solutions
            assert len(solutions) <= 4  # elbow up and down coincide
        # else the other shoulder side (if within the limits) has a regular elbow-up and elbow-down
    # off it, two regular branches: q itself and its elbow mirrored about the singular q3
    for dq3 in (1e-4, -1e-4):
        q, solutions = solve(dq3)
        assert not any(s.singular & Singularity.ELBOW for s in solutions)
        assert any(wrapped_equal(s.q, q, 1e-7) for s in solutions)
        assert any(abs(s.q[2] - (singular_q3 - dq3)) < 1e-6 for s in solutions)


def test_limits_shift_by_two_pi_and_nearest_to_seed() -> None:
    model = load_model("jibot_zxs")  # joint 6 spans -360..360 deg
    solver = closed_form(model)
    assert solver is not None
    q = np.array([0.2, 0.3, -0.5, 0.4, 0.6, 5.0])
    target = fk(model, q)
    near = solver.solve(target, q)
    assert near is not None and np.allclose(near.q, q, atol=1e-9)  # 5.0, not 5.0 - 2 pi
    default = solver.solve_all(target)
    assert any(np.allclose(s.q[:5], q[:5], atol=1e-9) and s.q[5] == pytest.approx(5.0 - 2 * math.pi) for s in default)
    assert all(model.within_limits(np.array(s.q), 1e-12) for s in default)


def test_unreachable_pose_gives_no_solution_not_nan() -> None:
    model = load_model("kuka_kr6_r900_sixx")
    solver = closed_form(model)
    assert solver is not None
    far = np.eye(4)
    far[:3, 3] = (3.0, 0.0, 0.5)
    assert solver.solve_all(far) == []
    q, valid, _ = solver.solve_batch(np.stack([far, fk(model, [0.1, -1.0, 1.0, 0.2, 0.3, 0.4])]))
    assert not valid[0].any() and valid[1].any() and np.isnan(q[0]).all()
    with pytest.raises(IKFailed, match="out of reach"):
        ik(model, far)


# -- numeric ------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("name", [*shipped_models(), "urdf:jibot"])
def test_numeric_ik_on_1000_random_poses(name: str) -> None:
    model = load_model(DATA / "jibot_zxs.urdf") if name == "urdf:jibot" else load_model(name)
    rng = np.random.default_rng(99)
    solved = 0
    for _ in range(1000):
        target = fk(model, rng.uniform(model.lower, model.upper))
        result = ik_numeric(model, target, rng.uniform(model.lower, model.upper), rng=rng)
        pos, ori = pose_error(model, np.array(result.q), target)
        assert pos == pytest.approx(result.position_error, abs=1e-12)
        if result.success:
            solved += 1
            assert pos <= 1e-6 and ori <= 1e-6
            assert model.within_limits(np.array(result.q), 1e-12)
        else:
            assert result.position_error > 1e-6 or result.orientation_error > 1e-6
    assert solved >= 999


def _urdf_chain(joints: list[tuple[str, str, str, float, float]]) -> str:
    """A URDF serial chain: per joint (type, origin xyz, axis xyz, lower, upper)."""
    links = "".join(f'<link name="l{i}"/>' for i in range(len(joints) + 1))
    body = "".join(
        f'<joint name="j{i + 1}" type="{kind}"><parent link="l{i}"/><child link="l{i + 1}"/>'
        f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{axis}"/>'
        f'<limit lower="{lo}" upper="{hi}" velocity="1"/></joint>'
        for i, (kind, xyz, axis, lo, hi) in enumerate(joints)
    )
    return f'<robot name="chain">{links}{body}</robot>'


_PLANAR = [("revolute", "0 0 0", "0 0 1", -3, 3), ("revolute", "0.4 0 0", "0 0 1", -2.5, 2.5)]
_PLANAR += [("revolute", "0.3 0 0", "0 0 1", -2.5, 2.5)]
_SEVEN = [
    ("revolute", "0 0 0.3", "0 0 1", -3, 3),
    ("revolute", "0 0 0.1", "0 1 0", -2, 2),
    ("prismatic", "0 0 0.4", "0 0 1", 0, 0.3),
    ("revolute", "0 0 0.2", "0 1 0", -2, 2),
    ("revolute", "0 0 0.3", "0 0 1", -3, 3),
    ("revolute", "0 0 0.3", "0 1 0", -2, 2),
    ("revolute", "0 0 0.1", "0 0 1", -3, 3),
]


@pytest.mark.slow
@pytest.mark.parametrize(("joints", "required"), [(_PLANAR, 100), (_SEVEN, 95)], ids=["planar-3R", "7-axis-prismatic"])
def test_numeric_ik_on_other_chains(
    tmp_path: Path, joints: list[tuple[str, str, str, float, float]], required: int
) -> None:
    """Fewer and more joints than six (the smaller normal system; redundancy, a prismatic joint):
    poses the chain itself reaches are solved within tolerance and limits, or reported failed."""
    path = tmp_path / "chain.urdf"
    path.write_text(_urdf_chain(joints))
    model = load_model(path)
    assert closed_form(model) is None
    rng = np.random.default_rng(8)
    solved = 0
    for _ in range(100):
        target = fk(model, rng.uniform(model.lower, model.upper))
        result = ik_numeric(model, target, rng.uniform(model.lower, model.upper), rng=rng)
        pos, ori = pose_error(model, np.array(result.q), target)
        if result.success:
            solved += 1
            assert pos <= 1e-6 and ori <= 1e-6 and model.within_limits(np.array(result.q), 1e-12)
        else:
            assert pos == pytest.approx(result.position_error, abs=1e-12)
            assert result.position_error > 1e-6 or result.orientation_error > 1e-6
    assert solved >= required


def test_numeric_ik_reports_failure_with_the_best_residual() -> None:
    model = load_model("ur5")
    far = np.eye(4)
    far[:3, 3] = (2.0, 0.0, 0.0)
    result = ik_numeric(model, far, attempts=3, rng=np.random.default_rng(1))
    assert not result.success
    assert 1.0 < result.position_error < 2.1
    assert result.attempts == 3 and all(math.isfinite(v) for v in result.q)
    with pytest.raises(IKFailed, match="best residual"):
        ik(model, far)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def test_rotation_error_is_exact_up_to_and_at_pi() -> None:
    rng = np.random.default_rng(3)
    base = rotation(rng.normal(size=3), 0.7)
    flat = np.hstack([base, np.zeros((3, 1))]).ravel().tolist()
    for angle in [0.0, 1e-13, 1e-7, 0.3, 2.0, math.pi - 1e-3, math.pi - 1e-7, math.pi - 1e-12, math.pi]:
        for _ in range(20):
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            error = np.array(rotation_error((rotation(axis, angle) @ base).tolist(), flat))
            assert np.linalg.norm(error) == pytest.approx(angle, abs=1e-9)
            if angle > 1e-12:
                cosine = float(error @ axis) / np.linalg.norm(error)
                if angle > math.pi - 1e-6:  # +axis and -axis are (nearly) the same rotation
                    cosine = abs(cosine)
                assert cosine > 1.0 - 1e-6


@pytest.mark.parametrize(("rows", "cols"), [(6, 6), (6, 4), (6, 7), (3, 6)])
def test_damped_step_matches_the_normal_equations(rows: int, cols: int) -> None:
    rng = np.random.default_rng(rows * 10 + cols)
    for damping in (1e-9, 1e-3, 0.5):
        jac = rng.normal(size=(rows, cols))
        e = rng.normal(size=rows)
        step = damped_step(SCALAR_OPS, jac.tolist(), e.tolist(), damping)
        expected = np.linalg.solve(jac.T @ jac + damping * np.eye(cols), jac.T @ e)
        assert np.allclose(step, expected, rtol=1e-6, atol=1e-9)
    rank_one = np.outer(rng.normal(size=rows), rng.normal(size=cols))  # singular: still finite
    assert all(math.isfinite(x) for x in damped_step(SCALAR_OPS, rank_one.tolist(), [1.0] * rows, 1e-9))


# -- the command --------------------------------------------------------------------------------


def test_command_fk_ik_models(capsys: pytest.CaptureFixture[str]) -> None:
    assert kinematics_main(["fk", "--model", "puma560", "0.1", "0.2", "0.3", "0.4", "0.5", "0.6"]) == 0
    pose = json.loads(capsys.readouterr().out)
    assert np.allclose(pose["T"], fk(load_model("puma560"), [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]))
    seed = ["0.1", "0.2", "0.3", "0.4", "0.5", "0.6"]
    assert kinematics_main(["ik", "--model", "puma560", "--pose", json.dumps(pose), "--seed", *seed]) == 0
    (q,) = json.loads(capsys.readouterr().out)["solutions"]
    assert np.allclose(q, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], atol=1e-9)
    assert kinematics_main(["ik", "--model", "puma560", "--pose", json.dumps(pose["T"]), "--all"]) == 0
    assert len(json.loads(capsys.readouterr().out)["solutions"]) > 1
    assert kinematics_main(["models"]) == 0
    names = [m["name"] for m in json.loads(capsys.readouterr().out)["models"]]
    assert names == shipped_models()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["fk", "--model", "puma560", "0.1"], "has 6 joints"),
        (["fk", "--model", "nosuch", "0"], "not a shipped model"),
        (["ik", "--model", "puma560", "--pose", "[1, 2"], "not valid JSON"),
        (["ik", "--model", "puma560", "--pose", "[[1, 0], [0, 1]]"], "4x4"),
        (["ik", "--model", "puma560", "--pose", json.dumps((2 * np.eye(4)).tolist())], "homogeneous"),
        (["ik", "--model", "puma560", "--pose", json.dumps(np.eye(4).tolist())], "out of reach"),
    ],
)
def test_command_errors_are_clear(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert kinematics_main(argv) == 2
    assert message in capsys.readouterr().err
