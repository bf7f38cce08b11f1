"""Compile numeric Python into straight-line code with the model's constants folded in.

Kinematics code is written once, for floats, against an ``ops`` namespace (sqrt, atan2, cos, sin,
acos, where). Run it once with :class:`Var` placeholders for the per-call inputs: every operation
on a placeholder is recorded as one line of code, every operation on plain numbers happens right
away, and multiplying by 0 or 1 or adding 0 disappears. The result is a function whose body is only
the arithmetic this particular robot needs. It runs on floats with ``math`` functions (one pose)
or on numpy arrays with numpy functions (a batch): the same code, so the two cannot disagree.

Control flow may depend on the model (plain numbers), never on a placeholder; a per-call choice is
``ops.where(condition, a, b)``.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ._quartic import trig_quadratic_roots

__all__ = ["Tracer", "Var", "SCALAR_OPS", "ARRAY_OPS", "TRACE_OPS"]

#: constants this close to 0 or +-1 are those numbers (cos(pi/2) is 6e-17, not 0)
_SNAP = 1e-14


def snap(value: float) -> float:
    for target in (0.0, 1.0, -1.0):
        if abs(value - target) < _SNAP:
            return target
    return value


class Tracer:
    """Collects the recorded lines and names the intermediate values."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.count = 0
        self.known: dict[str, Var] = {}  # expression -> the value already holding it
        self.negated: dict[str, Var] = {}  # name of -x -> x

    def emit(self, expr: str) -> Var:
        if expr in self.known:
            return self.known[expr]
        name = f"v{self.count}"
        self.count += 1
        self.lines.append(f"    {name} = {expr}")
        var = self.known[expr] = Var(self, name)
        return var

    def compile(
        self, name: str, inputs: Sequence[str], outputs: Sequence[Any], label: str, batch: bool = False
    ) -> Callable[..., Any]:
        """A function ``name(*inputs, ops)`` returning the tuple of ``outputs``.

        With ``batch`` (numpy arrays), each intermediate is deleted after its last use: keeping a
        thousand dead arrays alive costs more than the arithmetic (fresh memory every line).
        Without it (floats only), ``where(c, a, b)`` becomes Python's ``a if c else b``: no call,
        and only the chosen side is computed."""
        returned = ", ".join(_text(o) for o in outputs)
        lines = _live(self.lines, set(_NAME.findall(returned)))
        if not batch:
            lines = [_WHERE.sub(r"(\2 if \1 else \3)", line) for line in lines]
        lines = _inline(lines, set(_NAME.findall(returned)))
        if batch:
            lines = _with_releases(lines, set(_NAME.findall(returned)))
        text = "\n".join(lines)
        body = [f"def {name}({', '.join(inputs)}, ops):"]
        body += [f"    {f} = ops.{f}" for f in _OPS if f"{f}(" in text]
        body += lines
        body.append(f"    return ({returned},)")
        source = "\n".join(body)
        namespace: dict[str, Any] = {}
        exec(compile(source, f"<{label}>", "exec"), namespace)
        function: Callable[..., Any] = namespace[name]
        function.__doc__ = source
        return function


#: a recorded ``where`` (its arguments are names or numbers)
_WHERE = re.compile(r"\bwhere\(([^,()]+), ([^,()]+), ([^,()]+)\)")
_OPS = ("sqrt", "atan2", "cos", "sin", "acos", "where", "maximum", "quartic")
_NAME = re.compile(r"\bv\d+\b")


def _live(lines: list[str], needed: set[str]) -> list[str]:
    """Only the lines the outputs depend on (tracing records every intermediate, used or not)."""
    kept = []
    for line in reversed(lines):
        target, expr = line.split("=", 1)
        if target.strip() in needed:
            needed.update(_NAME.findall(expr))
            kept.append(line)
    kept.reverse()
    return kept


#: an inlined expression nests at most this deep (the parser's limit is 200 parentheses)
_MAX_DEPTH = 40


def _inline(lines: list[str], returned: set[str]) -> list[str]:
    """Values used once are written into the expression that uses them instead of a line of their
    own: the same operations in the same order, with far fewer local variables to store and load
    (a function with hundreds of locals also pays an extra instruction for each access past 255)."""
    uses: dict[str, int] = {}
    for line in lines:
        for used in _NAME.findall(line.split("=", 1)[1]):
            uses[used] = uses.get(used, 0) + 1
    pending: dict[str, tuple[str, int]] = {}  # name -> (its expression, nesting depth)
    out = []
    for line in lines:
        target, expr = (part.strip() for part in line.split("=", 1))
        depth = 0

        def substitute(match: re.Match[str]) -> str:
            nonlocal depth
            name = match.group(0)
            if name not in pending:
                return name
            text, inner = pending.pop(name)
            depth = max(depth, inner + 1)
            return f"({text})"

        expr = _NAME.sub(substitute, expr)
        if uses.get(target) == 1 and target not in returned and depth < _MAX_DEPTH:
            pending[target] = (expr, depth)
        else:
            out.append(f"    {target} = {expr}")
    return out


def _with_releases(lines: list[str], keep: set[str]) -> list[str]:
    last: dict[str, int] = {}
    for i, line in enumerate(lines):
        for used in _NAME.findall(line.split("=", 1)[1]):
            last[used] = i
    dead: dict[int, list[str]] = {}
    for var, i in last.items():
        if var not in keep:
            dead.setdefault(i, []).append(var)
    out = []
    for i, line in enumerate(lines):
        out.append(line)
        if i in dead:
            out.append(f"    del {', '.join(sorted(dead[i]))}")
    return out


def _text(value: Any) -> str:
    if isinstance(value, Var):
        return value.name
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, int | float | np.floating | np.integer):
        return repr(float(value)) if not isinstance(value, int | np.integer) else repr(int(value))
    raise TypeError(f"cannot trace a value of type {type(value).__name__}")


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float | np.floating | np.integer) and not isinstance(value, bool)


class Var:
    """A per-call value while tracing: operations on it are recorded, not computed."""

    __slots__ = ("name", "tracer")

    def __init__(self, tracer: Tracer, name: str) -> None:
        self.tracer = tracer
        self.name = name

    def _op(self, other: Any, op: str, reverse: bool = False) -> Any:
        if isinstance(other, bool):
            other = int(other)
        if _is_number(other):
            k = snap(float(other))
            if op == "*" and k == 0.0:
                return 0.0
            if (op == "*" and k == 1.0) or (op in "+-" and k == 0.0 and not (reverse and op == "-")):
                return self
            if op == "/" and not reverse and k == 1.0:
                return self
            if op == "*" and k == -1.0:
                return -self
            if op == "-" and reverse and k == 0.0:
                return -self
        elif not isinstance(other, Var):
            return NotImplemented
        elif other is self and op == "-":
            return 0.0
        elif op in "+-" and other.name in self.tracer.negated:  # a + (-b) is a - b
            base = self.tracer.negated[other.name]
            if reverse:  # (-b) + a, (-b) - a
                return self - base if op == "+" else -(base + self)
            return self - base if op == "+" else self + base
        a, b = (_text(other), self.name) if reverse else (self.name, _text(other))
        return self.tracer.emit(f"{a} {op} {b}")

    def __add__(self, o: Any) -> Any:
        return self._op(o, "+")

    def __radd__(self, o: Any) -> Any:
        return self._op(o, "+", True)

    def __sub__(self, o: Any) -> Any:
        return self._op(o, "-")

    def __rsub__(self, o: Any) -> Any:
        return self._op(o, "-", True)

    def __mul__(self, o: Any) -> Any:
        return self._op(o, "*")

    def __rmul__(self, o: Any) -> Any:
        return self._op(o, "*", True)

    def __truediv__(self, o: Any) -> Any:
        return self._op(o, "/")

    def __rtruediv__(self, o: Any) -> Any:
        return self._op(o, "/", True)

    def __neg__(self) -> Var:
        if self.name in self.tracer.negated:
            return self.tracer.negated[self.name]
        result = self.tracer.emit(f"-{self.name}")
        self.tracer.negated[result.name] = self
        return result

    def __abs__(self) -> Var:
        return self.tracer.emit(f"abs({self.name})")

    def _compare(self, o: Any, op: str) -> Var:
        return self.tracer.emit(f"{self.name} {op} {_text(o)}")

    def __lt__(self, o: Any) -> Var:
        return self._compare(o, "<")

    def __le__(self, o: Any) -> Var:
        return self._compare(o, "<=")

    def __gt__(self, o: Any) -> Var:
        return self._compare(o, ">")

    def __ge__(self, o: Any) -> Var:
        return self._compare(o, ">=")

    def _logic(self, o: Any, op: str) -> Any:
        if isinstance(o, bool):  # truth values: fold
            if op == "&":
                return self if o else False
            return True if o else self
        if isinstance(o, int) and o == 0:  # flag sets: x | 0 is x, x & 0 is 0
            return self if op == "|" else 0
        return self.tracer.emit(f"({self.name} {op} {_text(o)})")

    def __and__(self, o: Any) -> Any:
        return self._logic(o, "&")

    __rand__ = __and__

    def __or__(self, o: Any) -> Any:
        return self._logic(o, "|")

    __ror__ = __or__

    def __bool__(self) -> bool:
        raise TypeError("a traced value has no truth value at trace time; use ops.where")


def _first_var(*args: Any) -> Tracer | None:
    for a in args:
        if isinstance(a, Var):
            return a.tracer
    return None


class _TraceOps:
    """The ``ops`` namespace while tracing: calls on placeholders are recorded."""

    @staticmethod
    def _call(fn: str, *args: Any) -> Any:
        tracer = _first_var(*args)
        if tracer is None:
            return getattr(SCALAR_OPS, fn)(*args)
        return tracer.emit(f"{fn}({', '.join(_text(a) for a in args)})")

    def sqrt(self, x: Any) -> Any:
        return self._call("sqrt", x)

    def atan2(self, y: Any, x: Any) -> Any:
        return self._call("atan2", y, x)

    def cos(self, x: Any) -> Any:
        return self._call("cos", x)

    def sin(self, x: Any) -> Any:
        return self._call("sin", x)

    def acos(self, x: Any) -> Any:
        return self._call("acos", x)

    def where(self, c: Any, a: Any, b: Any) -> Any:
        if not isinstance(c, Var):
            return a if c else b
        return self._call("where", c, a, b)

    def maximum(self, *x: Any) -> Any:
        return self._call("maximum", *x)

    def quartic(self, *k: Any) -> tuple[Any, ...]:
        tracer = _first_var(*k)
        if tracer is None:
            return SCALAR_OPS.quartic(*k)
        packed = tracer.emit(f"quartic({', '.join(_text(a) for a in k)})")
        return tuple(tracer.emit(f"{packed.name}[{i}]") for i in range(12))


class _ScalarOps:
    @staticmethod
    def sqrt(x: float) -> float:
        return math.sqrt(x) if x > 0.0 else 0.0

    atan2 = staticmethod(math.atan2)
    cos = staticmethod(math.cos)
    sin = staticmethod(math.sin)

    @staticmethod
    def acos(x: float) -> float:
        return math.acos(1.0 if x > 1.0 else (-1.0 if x < -1.0 else x))

    @staticmethod
    def where(c: Any, a: Any, b: Any) -> Any:
        return a if c else b

    maximum = staticmethod(max)

    def quartic(self, *k: float) -> tuple[Any, ...]:
        return trig_quadratic_roots(self, *k)


class _ArrayOps:
    @staticmethod
    def sqrt(x: Any) -> Any:
        return np.sqrt(np.maximum(x, 0.0))

    atan2 = staticmethod(np.arctan2)
    cos = staticmethod(np.cos)
    sin = staticmethod(np.sin)

    @staticmethod
    def acos(x: Any) -> Any:
        return np.arccos(np.clip(x, -1.0, 1.0))

    where = staticmethod(np.where)

    @staticmethod
    def maximum(*x: Any) -> Any:
        return functools.reduce(np.maximum, x)

    def quartic(self, *k: Any) -> tuple[Any, ...]:
        return trig_quadratic_roots(self, *k)


SCALAR_OPS = _ScalarOps()
ARRAY_OPS = _ArrayOps()
TRACE_OPS = _TraceOps()
