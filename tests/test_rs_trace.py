"""The tracer behind the generated kinematics: its source is visible (linecache), its outputs are
named, and the code it generates needs nothing but the :class:`Ops` protocol."""

from __future__ import annotations

import gc
import inspect
import linecache
import math
import textwrap
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest

import robot_server
from robot_server.kinematics import (
    BatchSolutions,
    Branch,
    ChainFunctions,
    Ops,
    PoseBlock,
    PoseJacobian,
    chain_functions,
    closed_form,
    fk,
    fk_batch,
    ik_numeric,
    jacobian,
)
from robot_server.kinematics._ops import ARRAY_OPS, OP_NAMES, SCALAR_OPS, TrigRoot
from robot_server.kinematics._quartic import trig_quadratic_roots
from robot_server.kinematics._trace import TRACE_OPS, Real, Tracer, Var
from robot_server.kinematics.numeric import Errors, Step, _context
from robot_server.loader import load_model, shipped_models

from .refdata import DATA

SKEW = str(DATA / "skew_arm.toml")


def generated_functions(name: str) -> dict[str, Callable[..., Any]]:
    """Every generated function of a model, by role."""
    model = load_model(name)
    functions: dict[str, Callable[..., Any]] = dict(chain_functions(model)._asdict())
    context = _context(model)
    functions.update(iteration=context.iteration, check=context.check)
    solver = closed_form(model)
    if solver is not None:
        functions.update(solver=solver._solver, batch_solver=solver._batch_solver)
    return functions


# -- the generated source: linecache, not __doc__ -------------------------------------------------


def test_a_traceback_through_generated_code_shows_the_generated_line() -> None:
    model = load_model("puma560")
    pose = chain_functions(model).pose
    with pytest.raises(TypeError) as info:
        pose(0.1, "not a number", 0.3, 0.4, 0.5, 0.6, SCALAR_OPS)
    frame = traceback.extract_tb(info.value.__traceback__)[-1]
    assert frame.filename == pose.__code__.co_filename
    assert frame.filename.startswith("<generated chain: kinematics of puma560 #")
    assert frame.name == "chain"
    assert frame.lineno is not None
    source_line = inspect.getsource(pose).splitlines()[frame.lineno - 1]
    assert frame.line == source_line.strip()
    assert "cos(q1)" in source_line or "sin(q1)" in source_line
    # the formatted traceback prints it too (as a test runner or a log would)
    printed = "".join(traceback.format_exception(info.value))
    assert f'File "{frame.filename}", line {frame.lineno}, in chain\n    {source_line.strip()}' in printed


@pytest.mark.parametrize("name", [*shipped_models(), SKEW])
def test_generated_source_is_in_linecache_under_a_unique_name_not_in_the_docstring(name: str) -> None:
    functions = generated_functions(name)
    filenames = set()
    for function in functions.values():
        code = function.__code__
        source = inspect.getsource(function)
        assert source.startswith(f"def {code.co_name}(")
        assert "".join(linecache.getlines(code.co_filename)) == source
        assert "def " not in (function.__doc__ or "")
        filenames.add(code.co_filename)
    assert len(filenames) == len(functions)  # one pseudo-file per generated function
    # the source compiles back to the same function
    compile(inspect.getsource(functions["pose"]), "<check>", "exec")


def test_the_linecache_entry_goes_with_the_function() -> None:
    tracer = Tracer()
    x = tracer.input("x")
    function = tracer.compile("double", ["x"], (x * 2.0,), "a test")
    filename = function.__code__.co_filename
    assert filename in linecache.cache
    assert function(3.0, SCALAR_OPS) == (6.0,)
    del function
    gc.collect()
    assert filename not in linecache.cache


def test_where_is_a_conditional_expression_on_floats_and_a_call_on_arrays() -> None:
    tracer = Tracer()
    x = tracer.input("x")
    outputs = (TRACE_OPS.where(x > 0.0, x * 2.0, -x), TRACE_OPS.flag(x > 1.0, 4))
    scalar = tracer.compile("f", ["x"], outputs, "a test")
    batch = tracer.compile("f_batch", ["x"], outputs, "a test", batch=True)
    assert "where" not in inspect.getsource(scalar)
    assert " if " in inspect.getsource(scalar)
    assert "where = ops.where" in inspect.getsource(batch)
    assert scalar(3.0, SCALAR_OPS) == (6.0, 4) and scalar(-3.0, SCALAR_OPS) == (3.0, 0)
    values, flags = batch(np.array([3.0, -3.0, 0.5]), ARRAY_OPS)
    assert values.tolist() == [6.0, 3.0, 1.0] and flags.tolist() == [4, 0, 0]


def test_traced_values_have_no_value_at_trace_time() -> None:
    x = Tracer().input("x")
    with pytest.raises(TypeError, match=r"use ops\.where"):
        bool(x > 0.0)
    with pytest.raises(TypeError, match="no value at trace time"):
        float(x)


# -- named outputs ----------------------------------------------------------------------------


class _Polar(NamedTuple):
    radius: Real
    angle: Real
    both: tuple[Real, Real]


def test_the_generated_function_returns_the_traced_named_tuple() -> None:
    tracer = Tracer()
    x, y = tracer.input("x"), tracer.input("y")
    radius, angle = TRACE_OPS.sqrt(x * x + y * y), TRACE_OPS.atan2(y, x)
    function = tracer.compile("polar", ["x", "y"], _Polar(radius, angle, (radius, angle)), "a test")
    result = function(3.0, 4.0, SCALAR_OPS)
    assert type(result) is _Polar
    assert result == _Polar(5.0, math.atan2(4.0, 3.0), (5.0, math.atan2(4.0, 3.0)))


@pytest.mark.parametrize("name", shipped_models())
def test_chain_functions_return_named_poses_and_jacobians(name: str) -> None:
    model = load_model(name)
    functions = chain_functions(model)
    assert isinstance(functions, ChainFunctions)
    q = np.random.default_rng(3).uniform(model.lower, model.upper, size=(5, model.dof))
    pose = functions.pose(*q[0], SCALAR_OPS)
    assert type(pose) is PoseBlock
    assert pose._fields == ("r00", "r01", "r02", "px", "r10", "r11", "r12", "py", "r20", "r21", "r22", "pz")
    t = fk(model, q[0])
    assert np.array_equal(pose.matrix(), t)
    assert (pose.px, pose.py, pose.pz) == tuple(t[:3, 3]) == pose.position
    assert np.array_equal(pose.rotation, t[:3, :3])
    both = functions.pose_and_jacobian(*q[0], SCALAR_OPS)
    assert type(both) is PoseJacobian and both.pose == pose
    assert np.array_equal(np.array(both.jacobian), jacobian(model, q[0]))
    batch = functions.pose_batch(*q.T, ARRAY_OPS)
    assert type(batch) is PoseBlock
    assert np.allclose(np.broadcast_to(batch.px, 5), fk_batch(model, q)[:, 0, 3], rtol=0.0, atol=1e-15)


def test_closed_form_branches_and_batch_solutions_are_named() -> None:
    model = load_model("kuka_kr6_r900_sixx")
    solver = closed_form(model)
    assert solver is not None
    q = np.array([0.3, -0.4, 0.5, 0.7, 0.2, -0.2])
    t = fk(model, q)
    (r00, r01, r02, px), (r10, r11, r12, py), (r20, r21, r22, pz), _ = t.tolist()
    branches = solver._solver(r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz, *q, SCALAR_OPS)
    assert len(branches) == 8 and all(type(b) is Branch for b in branches)
    assert any(b.valid and np.allclose(b.q, q, atol=1e-9) and b.flags == 0 for b in branches)
    result = solver.solve_batch(np.stack([t, t]))
    assert isinstance(result, BatchSolutions)
    assert result.q.shape == (2, 8, 6) and result.valid.shape == result.flags.shape == (2, 8)
    solutions, valid, flags = result  # still unpacks
    assert solutions is result.q and valid is result.valid and flags is result.flags


def test_numeric_iteration_and_check_are_named() -> None:
    model = load_model("ur5")
    context = _context(model)
    q = [0.1, -0.5, 0.6, 0.2, 0.3, 0.4]
    target = [x for row in fk(model, [0.2, -0.4, 0.5, 0.3, 0.2, 0.5])[:3].tolist() for x in row]
    step = context.iteration(*q, *target, SCALAR_OPS)
    errors = context.check(*q, *target, SCALAR_OPS)
    assert type(step) is Step and type(errors) is Errors
    assert len(step.q) == model.dof
    assert step.squared_position == errors.squared_position > 0.0
    assert step.squared_orientation == errors.squared_orientation > 0.0


def test_the_quartic_returns_four_named_roots() -> None:
    # F(q) = cos q - 0.5 (as cos^2 + sin^2 = 1 times -0.5): roots at +-pi/3
    roots = trig_quadratic_roots(SCALAR_OPS, 0.0, 1.0, 0.0, -0.5, -0.5, 0.0)
    assert len(roots) == 4 and all(type(r) is TrigRoot for r in roots)
    found = sorted(round(math.remainder(r.angle, 2 * math.pi), 9) for r in roots if r.valid)
    assert found[0] == pytest.approx(-math.pi / 3) and found[-1] == pytest.approx(math.pi / 3)


# -- the ops protocol -----------------------------------------------------------------------------


class NumpyScalarOps:
    """A second implementation of :class:`Ops`, on numpy float64 scalars, with exactly the
    protocol's members (``__slots__ = ()``: anything else the generated code asked for would
    raise AttributeError)."""

    __slots__ = ()

    def sqrt(self, x: float) -> float:
        return float(np.sqrt(np.maximum(x, 0.0)))

    def atan2(self, y: float, x: float) -> float:
        return float(np.arctan2(y, x))

    def cos(self, x: float) -> float:
        return float(np.cos(x))

    def sin(self, x: float) -> float:
        return float(np.sin(x))

    def acos(self, x: float) -> float:
        return float(np.arccos(np.clip(x, -1.0, 1.0)))

    def where(self, condition: object, a: float, b: float) -> float:
        return a if condition else b

    def flag(self, condition: object, value: int) -> int:
        return value if condition else 0

    def maximum(self, x: float, y: float, *rest: float) -> float:
        return float(np.max([x, y, *rest]))

    def quartic(self, *k: float) -> tuple[TrigRoot[float], ...]:
        return trig_quadratic_roots(self, *k)


def test_every_ops_implementation_satisfies_the_protocol() -> None:
    for ops in (SCALAR_OPS, ARRAY_OPS, TRACE_OPS, NumpyScalarOps()):
        assert isinstance(ops, Ops)
        assert all(callable(getattr(ops, name)) for name in OP_NAMES)
    assert not isinstance(object(), Ops)


@pytest.mark.parametrize("name", [*shipped_models(), SKEW])
def test_generated_code_runs_on_a_second_ops_implementation(name: str) -> None:
    functions = generated_functions(name)
    model = load_model(name)
    ops = NumpyScalarOps()
    rng = np.random.default_rng(17)
    for q in rng.uniform(model.lower, model.upper, size=(20, model.dof)):
        pose = functions["pose"](*q, ops)
        assert np.allclose(pose.matrix(), fk(model, q), rtol=0.0, atol=1e-12)
        both = functions["pose_and_jacobian"](*q, ops)
        assert np.allclose(both.jacobian, jacobian(model, q), rtol=0.0, atol=1e-12)
        target = fk(model, rng.uniform(model.lower, model.upper))
        flat = [x for row in target[:3].tolist() for x in row]
        mine = functions["iteration"](*q, *flat, ops)
        reference = functions["iteration"](*q, *flat, SCALAR_OPS)
        assert np.allclose(mine.q, reference.q, rtol=1e-9, atol=1e-9)
        if "solver" in functions:
            r = target[:3, :3].ravel().tolist()
            p = target[:3, 3].tolist()
            mine = functions["solver"](*r, *p, *q, ops)
            reference = functions["solver"](*r, *p, *q, SCALAR_OPS)
            for a, b in zip(mine, reference, strict=True):
                assert a.valid == b.valid and a.flags == b.flags
                if b.valid:
                    assert np.allclose(a.q, b.q, rtol=0.0, atol=1e-7)


def test_traced_code_evaluates_plain_floats_like_the_scalar_ops() -> None:
    """With no placeholder, TRACE_OPS computes right away: kinematics code run eagerly on floats."""
    for x, y in [(0.3, -0.7), (-1.0, 0.0), (2.0, 1e-300)]:
        assert TRACE_OPS.atan2(y, x) == SCALAR_OPS.atan2(y, x)
        assert TRACE_OPS.sqrt(x) == SCALAR_OPS.sqrt(x)
        assert TRACE_OPS.acos(x) == SCALAR_OPS.acos(x)
        assert TRACE_OPS.where(x > y, x, y) == max(x, y)
        assert TRACE_OPS.maximum(x, y, 0.5) == max(x, y, 0.5)
    traced: object = TRACE_OPS.quartic(0.0, 1.0, 0.0, -0.5, -0.5, 0.0)
    assert traced == SCALAR_OPS.quartic(0.0, 1.0, 0.0, -0.5, -0.5, 0.0)
    v = Tracer().input("v")
    assert isinstance(TRACE_OPS.cos(v), Var) and isinstance(TRACE_OPS.flag(v > 0.0, 2), Var)


def test_numeric_ik_is_unchanged_through_the_named_outputs() -> None:
    model = load_model("ur5")
    target = fk(model, [0.2, -0.4, 0.5, 0.3, 0.2, 0.5])
    result = ik_numeric(model, target, [0.1, -0.5, 0.6, 0.2, 0.3, 0.4], rng=np.random.default_rng(1))
    assert result.success and np.allclose(fk(model, result.q), target, atol=1e-6)


_MYPY_SNIPPET = """
from __future__ import annotations

import math

from robot_server.kinematics import Ops, chain_functions
from robot_server.kinematics._ops import TrigRoot
from robot_server.kinematics._quartic import trig_quadratic_roots
from robot_server.loader import load_model


class MathOps:
    def sqrt(self, x: float) -> float:
        return math.sqrt(max(x, 0.0))

    atan2 = staticmethod(math.atan2)
    cos = staticmethod(math.cos)
    sin = staticmethod(math.sin)
{acos}
    def where(self, condition: object, a: float, b: float) -> float:
        return a if condition else b

    def flag(self, condition: object, value: int) -> int:
        return value if condition else 0

    maximum = staticmethod(max)

    def quartic(self, *k: float) -> tuple[TrigRoot[float], ...]:
        return trig_quadratic_roots(self, *k)


ops: Ops[float] = MathOps()
pose = chain_functions(load_model("puma560")).pose(0.1, 0.2, 0.3, 0.4, 0.5, 0.6, ops)
x: float = pose.px
"""

_ACOS = """
    def acos(self, x: float) -> float:
        return math.acos(min(1.0, max(-1.0, x)))
"""


@pytest.mark.slow
def test_an_ops_implementation_and_the_named_outputs_type_check(tmp_path: Path) -> None:
    api = pytest.importorskip("mypy.api")
    root = Path(robot_server.__file__).resolve().parents[1]
    config = tmp_path / "mypy.ini"
    # the project's own settings for the untyped third-party packages robot_server imports
    untyped = "[mypy-ruckig,ruckig.*,serial,serial.*]\nignore_missing_imports = true\n"
    config.write_text(f"[mypy]\nmypy_path = {root}\nstrict = true\npython_version = 3.11\n{untyped}")
    good, bad = tmp_path / "good_ops.py", tmp_path / "bad_ops.py"
    good.write_text(textwrap.dedent(_MYPY_SNIPPET).replace("{acos}", _ACOS))
    bad.write_text(
        textwrap.dedent(_MYPY_SNIPPET).replace("{acos}", "").replace("x: float = pose.px", "x: str = pose.px")
    )
    cache = ["--config-file", str(config), "--cache-dir", str(tmp_path / "cache")]
    out, err, status = api.run([*cache, str(good)])
    assert status == 0, out + err
    out, err, status = api.run([*cache, str(bad)])
    assert status == 1
    assert 'variable has type "Ops[float]"' in out and "acos" in out  # the missing member is named
    assert 'expression has type "float", variable has type "str"' in out  # the named output is typed
