"""Straight-line forward kinematics generated per model.

A D-H or URDF chain is mostly constants: twists of 0 or +-pi/2, zero offsets, unit axes. Multiplying
4x4 matrices at run time repeats the same zero products for every configuration. Instead, when a
model is first used, we multiply its fixed transforms *symbolically* (constants folded, zeros and
ones dropped) and compile the result into one Python function of the joint values. The same
function serves one configuration (``math.cos``/``math.sin`` on floats) and a batch (``np.cos`` /
``np.sin`` on columns), so scalar and batch kinematics can never disagree.

A symbolic entry is a float (a constant) or a ``(coefficient, name)`` pair (a variable, scaled).
A 3x4 matrix is the top three rows of a homogeneous transform; its last row is implicitly 0 0 0 1.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model import JointType, RobotModel

Entry = float | tuple[float, str]
Sym = list[list[Entry]]

#: Fixed-matrix entries this close to 0 or +-1 are those numbers (cos(pi/2) is 6e-17, not 0).
_SNAP = 1e-14


def _snap(value: float) -> float:
    for target in (0.0, 1.0, -1.0):
        if abs(value - target) < _SNAP:
            return target
    return float(value)


class _Emitter:
    """Collects assignment lines and hands out fresh variable names."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.count = 0

    def assign(self, expr: str) -> str:
        name = f"v{self.count}"
        self.count += 1
        self.lines.append(f"    {name} = {expr}")
        return name

    def sum(self, terms: list[tuple[float, tuple[str, ...]]], constant: float) -> Entry:
        """An entry for ``constant + sum(coef * prod(factors))``, folding what can be folded."""
        merged: dict[tuple[str, ...], float] = {}
        for coef, factors in terms:
            key = tuple(sorted(factors))
            merged[key] = merged.get(key, 0.0) + coef
        live = [(c, f) for f, c in merged.items() if c != 0.0]
        if not live:
            return constant
        if len(live) == 1 and constant == 0.0 and len(live[0][1]) == 1:
            return (live[0][0], live[0][1][0])
        parts = []
        for coef, factors in live:
            product = "*".join(factors)
            if coef == 1.0:
                parts.append(f"+ {product}")
            elif coef == -1.0:
                parts.append(f"- {product}")
            else:
                parts.append(f"+ {coef!r}*{product}")
        expr = " ".join(parts).removeprefix("+ ")
        if constant != 0.0:
            expr = f"{constant!r} + {expr}"
        return (1.0, self.assign(expr))


def _times(a: Entry, b: Entry) -> tuple[float, tuple[str, ...]] | float:
    if isinstance(a, float):
        if isinstance(b, float):
            return a * b
        return (a * b[0], (b[1],)) if a != 0.0 else 0.0
    if isinstance(b, float):
        return (a[0] * b, (a[1],)) if b != 0.0 else 0.0
    return (a[0] * b[0], (a[1], b[1]))


def _matmul(em: _Emitter, a: Sym, b: Sym) -> Sym:
    out: Sym = []
    for r in range(3):
        row: list[Entry] = []
        for j in range(4):
            constant = 0.0
            terms: list[tuple[float, tuple[str, ...]]] = []
            for k in range(3):
                p = _times(a[r][k], b[k][j])
                if isinstance(p, float):
                    constant += p
                else:
                    terms.append(p)
            if j == 3:
                last = a[r][3]
                if isinstance(last, float):
                    constant += last
                else:
                    terms.append((last[0], (last[1],)))
            row.append(em.sum(terms, constant))
        out.append(row)
    return out


def _const(matrix: NDArray[np.float64]) -> Sym:
    return [[_snap(float(matrix[r, j])) for j in range(4)] for r in range(3)]


def _is_identity(sym: Sym) -> bool:
    return all(sym[r][j] == (1.0 if r == j else 0.0) for r in range(3) for j in range(4))


def _motion(em: _Emitter, i: int, kind: JointType, axis: NDArray[np.float64], offset: float) -> Sym:
    """The joint's motion as a symbolic matrix of the joint variable ``q{i}``."""
    x, y, z = (_snap(float(v)) for v in axis)
    theta = f"q{i}" if offset == 0.0 else em.assign(f"q{i} + {offset!r}")
    if kind is JointType.PRISMATIC:
        return [
            [1.0, 0.0, 0.0, (x, theta) if x else 0.0],
            [0.0, 1.0, 0.0, (y, theta) if y else 0.0],
            [0.0, 0.0, 1.0, (z, theta) if z else 0.0],
        ]
    c = em.assign(f"cos({theta})")
    s = em.assign(f"sin({theta})")
    if x == 0.0 and y == 0.0 and abs(z) == 1.0:
        return [[(1.0, c), (-z, s), 0.0, 0.0], [(z, s), (1.0, c), 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    if y == 0.0 and z == 0.0 and abs(x) == 1.0:
        return [[1.0, 0.0, 0.0, 0.0], [0.0, (1.0, c), (-x, s), 0.0], [0.0, (x, s), (1.0, c), 0.0]]
    if x == 0.0 and z == 0.0 and abs(y) == 1.0:
        return [[(1.0, c), 0.0, (y, s), 0.0], [0.0, 1.0, 0.0, 0.0], [(-y, s), 0.0, (1.0, c), 0.0]]
    # Rodrigues: R = c I + s [axis]x + (1 - c) axis axis^T
    v = em.assign(f"1.0 - {c}")
    a = (x, y, z)
    cross = ((0.0, -z, y), (z, 0.0, -x), (-y, x, 0.0))
    rows: Sym = []
    for r in range(3):
        row: list[Entry] = []
        for j in range(3):
            terms: list[tuple[float, tuple[str, ...]]] = []
            if r == j:
                terms.append((1.0, (c,)))
            if cross[r][j]:
                terms.append((cross[r][j], (s,)))
            if a[r] * a[j]:
                terms.append((a[r] * a[j], (v,)))
            row.append(em.sum(terms, 0.0))
        row.append(0.0)
        rows.append(row)
    return rows


def _literal(entry: Entry) -> str:
    if isinstance(entry, float):
        return repr(entry)
    coef, name = entry
    return name if coef == 1.0 else (f"-{name}" if coef == -1.0 else f"{coef!r}*{name}")


Compiled = Callable[..., tuple[Any, ...]]


def compile_chain(model: RobotModel, with_axes: bool) -> Compiled:
    """A function ``f(q0, ..., q{n-1}, cos, sin)`` returning the flange's top 3x4 block row-major
    (12 values), followed, if ``with_axes``, by each joint's world axis and a point on it (6 values
    per joint: ax, ay, az, px, py, pz), the inputs of the geometric Jacobian."""
    em = _Emitter()
    t = _const(model.base)
    axes: list[Entry] = []
    for i, joint in enumerate(model.joints):
        pre = _const(joint.pre)
        if not _is_identity(pre):
            t = _matmul(em, t, pre)
        if with_axes:
            x, y, z = (_snap(float(v)) for v in joint.axis)
            for r in range(3):
                terms = []
                constant = 0.0
                for k, w in enumerate((x, y, z)):
                    p = _times(t[r][k], w)
                    if isinstance(p, float):
                        constant += p
                    else:
                        terms.append(p)
                axes.append(em.sum(terms, constant))
            axes.extend(t[r][3] for r in range(3))
        t = _matmul(em, t, _motion(em, i, joint.type, joint.axis, joint.offset))
        post = _const(joint.post)
        if not _is_identity(post):
            t = _matmul(em, t, post)
    tool = _const(model.tool)
    if not _is_identity(tool):
        t = _matmul(em, t, tool)
    outputs = [t[r][j] for r in range(3) for j in range(4)] + axes
    args = ", ".join(f"q{i}" for i in range(model.dof))
    source = "\n".join(
        [f"def chain({args}, cos, sin):", *em.lines, f"    return ({', '.join(_literal(e) for e in outputs)},)"]
    )
    namespace: dict[str, Any] = {}
    exec(compile(source, f"<kinematics of {model.name}>", "exec"), namespace)  # noqa: S102 - generated above
    function: Compiled = namespace["chain"]
    function.__doc__ = source
    return function
