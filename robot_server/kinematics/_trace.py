"""Compile numeric Python into straight-line code with the model's constants folded in.

Kinematics code is written once, for floats, against an ``ops`` namespace (:class:`._ops.Ops`:
sqrt, atan2, cos, sin, acos, where, ...). Run it once with :class:`Var` placeholders for the
per-call inputs and :data:`TRACE_OPS`: every operation on a placeholder is recorded as one
operation node, every operation on plain numbers happens right away, and multiplying by 0 or 1 or
adding 0 disappears. :meth:`Tracer.compile` turns the recorded nodes that the outputs need into a
function whose body is only the arithmetic this particular robot needs, returning the same named
structure (NamedTuples, tuples) the traced code returned. It runs on floats with ``math``
functions (:data:`._ops.SCALAR_OPS`, one pose) or on numpy arrays (:data:`._ops.ARRAY_OPS`, a
batch): the same code, so the two cannot disagree.

Control flow may depend on the model (plain numbers), never on a placeholder; a per-call choice is
``ops.where(condition, a, b)``. With no placeholder among its arguments, :data:`TRACE_OPS`
computes right away (as :data:`._ops.SCALAR_OPS`), so traced code also evaluates plain floats.

The generated source is registered with :mod:`linecache` under a unique pseudo-filename
(``<generated NAME: LABEL #N>``): tracebacks, :func:`inspect.getsource` and debuggers show it.
"""

from __future__ import annotations

import itertools
import linecache
import weakref
from collections.abc import Callable, Iterator, Sequence
from types import FunctionType
from typing import Any, TypeAlias, TypeVar, overload

import numpy as np

from ._ops import ARRAY_OPS, OP_NAMES, SCALAR_OPS, Ops, TrigRoot

__all__ = [
    "Tracer",
    "Var",
    "Real",
    "Truth",
    "Flags",
    "Generated",
    "Ops",
    "SCALAR_OPS",
    "ARRAY_OPS",
    "TRACE_OPS",
    "snap",
]

#: constants this close to 0 or +-1 are those numbers (cos(pi/2) is 6e-17, not 0)
_SNAP = 1e-14

#: a value in traced code: a plain number (computed right away) or a placeholder
Real: TypeAlias = "float | Var"
#: a condition in traced code
Truth: TypeAlias = "bool | Var"
#: singularity flags (an ``int`` bit set) in traced code
Flags: TypeAlias = "int | Var"
#: a constant operand of a recorded operation
Constant: TypeAlias = float | int | bool | np.floating[Any] | np.integer[Any]
Operand: TypeAlias = "Var | Constant"

R = TypeVar("R")
#: a generated function ``f(*inputs, ops)``: its arity depends on the model and its values on the
#: ops (floats or arrays), so the caller states the result type, e.g. ``Generated[PoseBlock[float]]``
Generated: TypeAlias = Callable[..., R]


def snap(value: float) -> float:
    for target in (0.0, 1.0, -1.0):
        if abs(value - target) < _SNAP:
            return target
    return value


class _Node:
    """One recorded operation, ``target = op(args)``. ``op`` is an operator (``+``, ``<``, ``&``,
    ...), ``neg``, ``abs``, ``call`` (of the op ``detail``) or ``item`` (``args[0]`` followed by
    the accessor ``detail``)."""

    __slots__ = ("args", "detail", "op", "target")

    def __init__(self, target: Var, op: str, args: tuple[Operand, ...], detail: str) -> None:
        self.target = target
        self.op = op
        self.args = args
        self.detail = detail

    def render(self, texts: Sequence[str], scalar: bool) -> str:
        """The expression, given its operands' texts. On floats (``scalar``) ``where(c, a, b)`` is
        Python's ``(a if c else b)``: no call, and only the chosen side is computed."""
        op = self.op
        if op == "call":
            if scalar and self.detail == "where":
                condition, a, b = texts
                return f"({a} if {condition} else {b})"
            return f"{self.detail}({', '.join(texts)})"
        if op == "neg":
            return f"-{texts[0]}"
        if op == "abs":
            return f"abs({texts[0]})"
        if op == "item":
            return f"{texts[0]}{self.detail}"
        if op in ("&", "|"):
            return f"({texts[0]} {op} {texts[1]})"
        return f"{texts[0]} {op} {texts[1]}"

    def calls(self, scalar: bool) -> str | None:
        """The op this expression calls by name in generated code, if any."""
        if self.op != "call" or (scalar and self.detail == "where"):
            return None
        return self.detail


class _Line:
    """One statement of the generated body: ``target = text``, naming the values in ``uses``."""

    __slots__ = ("target", "text", "uses")

    def __init__(self, target: Var, text: str, uses: list[Var]) -> None:
        self.target = target
        self.text = text
        self.uses = uses


_serial = itertools.count(1)


class Tracer:
    """Records the operations on placeholders and compiles them (see the module doc)."""

    def __init__(self) -> None:
        self.nodes: dict[Var, _Node] = {}  # recorded values, in the order of recording
        self.count = 0
        self.known: dict[tuple[str, str, tuple[str, ...]], Var] = {}  # an operation -> the value holding it
        self.negated: dict[Var, Var] = {}  # -x -> x

    def input(self, name: str) -> Var:
        """A placeholder for the generated function's argument ``name``."""
        return Var(self, name)

    def record(self, op: str, args: tuple[Operand, ...], detail: str = "") -> Var:
        key = (op, detail, tuple(_text(a) for a in args))
        known = self.known.get(key)
        if known is not None:
            return known
        var = self.known[key] = Var(self, f"v{self.count}")
        self.count += 1
        self.nodes[var] = _Node(var, op, args, detail)
        return var

    def call(self, fn: str, *args: Operand) -> Var:
        return self.record("call", args, fn)

    def compile(
        self, name: str, inputs: Sequence[str], outputs: object, label: str, batch: bool = False
    ) -> Callable[..., Any]:
        """A function ``name(*inputs, ops)`` returning ``outputs``: the same structure of
        NamedTuples and tuples, with each placeholder replaced by its value per call.

        With ``batch`` (numpy arrays), each intermediate is deleted after its last use: keeping a
        thousand dead arrays alive costs more than the arithmetic (fresh memory every line).
        Without it (floats only), ``where(c, a, b)`` becomes Python's ``a if c else b``."""
        classes: dict[str, type] = {}
        returned = _construct(outputs, classes)
        needed = set(_placeholders(outputs))
        live = self._live(needed)
        lines = _inline(live, needed, scalar=not batch)
        called = {node.calls(scalar=not batch) for node in live}
        body = [f"def {name}({', '.join(inputs)}, ops):"]
        body += [f"    {fn} = ops.{fn}" for fn in OP_NAMES if fn in called]
        released = _releases(lines, needed) if batch else {}
        for i, line in enumerate(lines):
            body.append(f"    {line.target.name} = {line.text}")
            if i in released:
                body.append(f"    del {', '.join(sorted(released[i]))}")
        body.append(f"    return {returned}")
        source = "\n".join(body) + "\n"
        filename = f"<generated {name}: {label} #{next(_serial)}>"
        namespace: dict[str, object] = {"__name__": __name__, "_tuple_new": tuple.__new__, **classes}
        exec(compile(source, filename, "exec"), namespace)
        function = namespace[name]
        assert isinstance(function, FunctionType)
        # the source lives as long as the function (mtime None: linecache.checkcache keeps it)
        linecache.cache[filename] = (len(source), None, source.splitlines(keepends=True), filename)
        weakref.finalize(function, linecache.cache.pop, filename, None).atexit = False
        function.__doc__ = f"Generated code: {label} (``inspect.getsource`` shows it)."
        return function

    def _live(self, needed: set[Var]) -> list[_Node]:
        """Only the nodes the outputs (``needed``) depend on: tracing records every intermediate,
        used or not."""
        live = set(needed)
        kept = []
        for var in reversed(self.nodes):
            if var in live:
                node = self.nodes[var]
                live.update(a for a in node.args if isinstance(a, Var))
                kept.append(node)
        kept.reverse()
        return kept


def _placeholders(value: object) -> Iterator[Var]:
    if isinstance(value, Var):
        yield value
    elif isinstance(value, tuple | list):
        for item in value:
            yield from _placeholders(item)


def _construct(value: object, classes: dict[str, type]) -> str:
    """The expression that builds ``value`` (a NamedTuple, tuple or list of them or of values)
    in generated code; the NamedTuple classes it names are added to ``classes``."""
    if isinstance(value, tuple | list):
        items = [_construct(item, classes) for item in value]
        packed = f"({', '.join(items)}{',' if len(items) == 1 else ''})"
        cls = type(value)
        if not hasattr(cls, "_fields"):
            return packed
        cls_name = cls.__name__
        while classes.get(cls_name, cls) is not cls:
            cls_name += "_"
        classes[cls_name] = cls
        return f"_tuple_new({cls_name}, {packed})"  # a NamedTuple without its Python-level __new__
    return _text(value)


#: an inlined expression nests at most this deep (the parser's limit is 200 parentheses)
_MAX_DEPTH = 40


def _inline(nodes: list[_Node], returned: set[Var], scalar: bool) -> list[_Line]:
    """Values used once are written into the expression that uses them instead of a line of their
    own: the same operations in the same order, with far fewer local variables to store and load
    (a function with hundreds of locals also pays an extra instruction for each access past 255)."""
    recorded = {node.target for node in nodes}
    uses: dict[Var, int] = {}
    for node in nodes:
        for arg in node.args:
            if isinstance(arg, Var) and arg in recorded:
                uses[arg] = uses.get(arg, 0) + 1
    pending: dict[Var, tuple[str, int, list[Var]]] = {}  # value -> (its expression, nesting depth, names in it)
    out = []
    for node in nodes:
        depth = 0
        texts: list[str] = []
        named: list[Var] = []
        for arg in node.args:
            if not isinstance(arg, Var):
                texts.append(_text(arg))
            elif arg in pending:
                text, inner, inner_named = pending.pop(arg)
                depth = max(depth, inner + 1)
                texts.append(f"({text})")
                named += inner_named
            else:
                texts.append(arg.name)
                if arg in recorded:
                    named.append(arg)
        expr = node.render(texts, scalar)
        target = node.target
        if uses.get(target) == 1 and target not in returned and depth < _MAX_DEPTH:
            pending[target] = (expr, depth, named)
        else:
            out.append(_Line(target, expr, named))
    return out


def _releases(lines: list[_Line], keep: set[Var]) -> dict[int, list[str]]:
    """Per line, the values last used there (to ``del`` after it)."""
    last: dict[Var, int] = {}
    for i, line in enumerate(lines):
        for used in line.uses:
            last[used] = i
    dead: dict[int, list[str]] = {}
    for var, i in last.items():
        if var not in keep:
            dead.setdefault(i, []).append(var.name)
    return dead


def _text(value: object) -> str:
    if isinstance(value, Var):
        return value.name
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, int | np.integer):
        return repr(int(value))
    if isinstance(value, float | np.floating):
        return repr(float(value))
    raise TypeError(f"cannot trace a value of type {type(value).__name__}")


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.floating | np.integer) and not isinstance(value, bool)


class Var:
    """A per-call value while tracing: operations on it are recorded, not computed."""

    __slots__ = ("name", "tracer")

    def __init__(self, tracer: Tracer, name: str) -> None:
        self.tracer = tracer
        self.name = name

    def __repr__(self) -> str:
        return f"Var({self.name})"

    def _op(self, other: Real, op: str, reverse: bool = False) -> Real:
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
            raise TypeError(f"cannot trace {op!r} with an operand of type {type(other).__name__}")
        elif other is self and op == "-":
            return 0.0
        elif op in "+-" and other in self.tracer.negated:  # a + (-b) is a - b
            base = self.tracer.negated[other]
            if reverse:  # (-b) + a, (-b) - a
                return self - base if op == "+" else -(base + self)
            return self - base if op == "+" else self + base
        return self.tracer.record(op, (other, self) if reverse else (self, other))

    def __add__(self, o: Real) -> Real:
        return self._op(o, "+")

    def __radd__(self, o: float) -> Real:
        return self._op(o, "+", True)

    def __sub__(self, o: Real) -> Real:
        return self._op(o, "-")

    def __rsub__(self, o: float) -> Real:
        return self._op(o, "-", True)

    def __mul__(self, o: Real) -> Real:
        return self._op(o, "*")

    def __rmul__(self, o: float) -> Real:
        return self._op(o, "*", True)

    def __truediv__(self, o: Real) -> Real:
        return self._op(o, "/")

    def __rtruediv__(self, o: float) -> Real:
        return self._op(o, "/", True)

    def __neg__(self) -> Var:
        if self in self.tracer.negated:
            return self.tracer.negated[self]
        result = self.tracer.record("neg", (self,))
        self.tracer.negated[result] = self
        return result

    def __abs__(self) -> Real:  # not Var: so that abs() of a Real is a Real to mypy
        return self.tracer.record("abs", (self,))

    def _compare(self, o: Real, op: str) -> Var:
        return self.tracer.record(op, (self, o))

    def __lt__(self, o: Real) -> Var:
        return self._compare(o, "<")

    def __le__(self, o: Real) -> Var:
        return self._compare(o, "<=")

    def __gt__(self, o: Real) -> Var:
        return self._compare(o, ">")

    def __ge__(self, o: Real) -> Var:
        return self._compare(o, ">=")

    def _logic(self, o: int | Var, op: str) -> int | Var:
        if isinstance(o, bool):  # truth values: fold
            if op == "&":
                return self if o else False
            return True if o else self
        if isinstance(o, int) and o == 0:  # flag sets: x | 0 is x, x & 0 is 0
            return self if op == "|" else 0
        return self.tracer.record(op, (self, o))

    @overload
    def __and__(self, o: bool | Var) -> Truth: ...

    @overload
    def __and__(self, o: int) -> Flags: ...

    def __and__(self, o: int | Var) -> int | Var:
        return self._logic(o, "&")

    __rand__ = __and__

    @overload
    def __or__(self, o: bool | Var) -> Truth: ...

    @overload
    def __or__(self, o: int) -> Flags: ...

    def __or__(self, o: int | Var) -> int | Var:
        return self._logic(o, "|")

    __ror__ = __or__

    def __bool__(self) -> bool:
        raise TypeError("a traced value has no truth value at trace time; use ops.where")

    def __float__(self) -> float:
        raise TypeError("a traced value has no value at trace time")


def _tracer(*args: object) -> Tracer:
    for a in args:
        if isinstance(a, Var):
            return a.tracer
    raise AssertionError("no placeholder among the arguments")


class TraceOps:
    """:class:`._ops.Ops` while tracing: calls on placeholders are recorded; calls on plain
    numbers are computed right away (by :data:`._ops.SCALAR_OPS`)."""

    def sqrt(self, x: Real) -> Real:
        return x.tracer.call("sqrt", x) if isinstance(x, Var) else SCALAR_OPS.sqrt(x)

    def atan2(self, y: Real, x: Real) -> Real:
        if isinstance(y, Var) or isinstance(x, Var):
            return _tracer(y, x).call("atan2", y, x)
        return SCALAR_OPS.atan2(y, x)

    def cos(self, x: Real) -> Real:
        return x.tracer.call("cos", x) if isinstance(x, Var) else SCALAR_OPS.cos(x)

    def sin(self, x: Real) -> Real:
        return x.tracer.call("sin", x) if isinstance(x, Var) else SCALAR_OPS.sin(x)

    def acos(self, x: Real) -> Real:
        return x.tracer.call("acos", x) if isinstance(x, Var) else SCALAR_OPS.acos(x)

    def where(self, condition: Truth, a: Real, b: Real) -> Real:
        if not isinstance(condition, Var):
            return a if condition else b
        return condition.tracer.call("where", condition, a, b)

    def flag(self, condition: Truth, value: int) -> Flags:
        if not isinstance(condition, Var):
            return value if condition else 0
        return condition.tracer.call("where", condition, value, 0)

    def maximum(self, x: Real, y: Real, *rest: Real) -> Real:
        values = (x, y, *rest)
        constants = [v for v in values if not isinstance(v, Var)]
        if len(constants) == len(values):
            return SCALAR_OPS.maximum(*constants)
        return _tracer(*values).call("maximum", *values)

    def quartic(self, *k: Real) -> tuple[TrigRoot[Var], ...]:
        constants = [v for v in k if not isinstance(v, Var)]
        if len(constants) == len(k):
            roots = SCALAR_OPS.quartic(*constants)
            return tuple(TrigRoot(float(r.angle), bool(r.valid), bool(r.double)) for r in roots)
        tracer = _tracer(*k)
        packed = tracer.call("quartic", *k)
        angles = [tracer.record("item", (packed,), f"[{i}].angle") for i in range(4)]
        valid = [tracer.record("item", (packed,), f"[{i}].valid") for i in range(4)]
        double = [tracer.record("item", (packed,), f"[{i}].double") for i in range(4)]
        return tuple(TrigRoot(a, v, d) for a, v, d in zip(angles, valid, double, strict=True))


TRACE_OPS: Ops[Var] = TraceOps()
