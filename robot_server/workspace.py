"""Cartesian supervision of the tool centre point (TCP): speed limits and workspace zones.

Real controllers supervise where the TCP is and how fast it moves, independently of the joint
limits: a reduced TCP speed in manual (teach) mode (250 mm/s, the usual teach-mode limit of
ISO 10218-1), an optional maximum in automatic mode, and workspace zones (ABB World Zones and
SafeMove, Fanuc DCS position check, Yaskawa FSU). This module holds those settings
(:class:`Supervision`, read from TOML by :func:`parse_supervision`) and the pure geometry that
checks positions against them (:func:`point_violation`, :func:`first_violation`, :func:`densify`).
It decides nothing: the controller raises the alarms and refuses the motions.

**Units and frames.** Everything here is SI: positions in metres, speeds in m/s. Positions are
those of the TCP (the model's flange with its tool, what :func:`robot_server.kinematics.fk`
gives) in the *cell* (world) frame, the frame the model's ``[base]`` places the robot in: zones
belong to the cell, not to the robot, so moving the robot on its base does not move them. A TOML
``[supervision]`` table is written in its file's length unit (``[units] length = "m" | "mm"``),
speeds in that unit per second, and converted on load.

**The rules.** A position ``(x, y, z)`` is checked against, in this order:

* ``allowed``: an axis-aligned :class:`Box` the TCP must stay inside. Its faces belong to it
  (``lower <= p <= upper`` on every axis is inside); outside is a violation of kind
  ``"allowed"``. No box: no such rule.
* ``floor``: the height of a horizontal plane; the TCP must stay at ``z >= floor`` (on the plane
  is allowed). Below it is a violation of kind ``"floor"``.
* ``forbidden``: boxes the TCP must stay outside of. Their faces belong to them (touching a face
  is entering: the conservative side); entering box ``i`` (0-based in the tuple) is a violation
  of kind ``"forbidden"`` with ``index = i``. Boxes are checked in order: the first one entered
  is reported.

A position that is not a number (NaN) violates the allowed box and the floor when they are set
(a comparison with NaN is false, so it is never *inside*); it never enters a forbidden box.

**Speeds.** ``manual_speed`` is the TCP speed limit in MANUAL (teach) mode (default 0.25 m/s),
``auto_speed`` an optional limit in AUTO mode (None: none). :meth:`Supervision.speed_limit`
gives the one in force. Measuring the speed is the controller's business.

**Paths.** :func:`first_violation` checks a sampled TCP path, an ``(N, 3)`` array in time order,
and reports the earliest sample that violates a rule (at one sample: the allowed box first, then
the floor, then the forbidden boxes in order). It sees the samples only: a path that passes
through a forbidden corner between two samples far apart is missed. ``tolerance`` (default
1 mm) is the sampling step path checks guarantee: :func:`densify` inserts linearly interpolated
points so that consecutive points are at most that far apart, and a path check of the densified
samples cannot miss a zone by more than the tolerance (a box thinner than it, or a corner clipped
by less, may pass between two points). Linear interpolation between samples is only as good as
the samples: sample a curved path (a joint move) densely enough that its chords are within the
tolerance of the arc before densifying.

**Alarms.** This emulator's alarm codes, in the style of the controller's ``4100 + joint``
(following error), ``4200 + joint`` (soft limit) and ``4300`` (motion failure):

* :data:`TCP_SPEED_ALARM` ``4400``: the actual TCP speed exceeded the limit in force;
* :data:`ZONE_ALARM` ``4500``: the TCP left the allowed box;
* :data:`FLOOR_ALARM` ``4501``: the TCP went below the floor;
* :data:`FORBIDDEN_ZONE_ALARM` ``4510 + n``: the TCP entered forbidden box ``n`` (1-based), for
  ``n`` up to 89; beyond, every box gives ``4599``.

:func:`alarm_code` maps a :class:`Violation` to its code.

**Errors.** Invalid settings raise :class:`~robot_server.model.ModelError` naming the field
(and, from :func:`parse_supervision`, the file).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._strict import did_you_mean, show
from .arrays import Array

__all__ = [
    "Box",
    "Supervision",
    "Violation",
    "TCP_SPEED_ALARM",
    "ZONE_ALARM",
    "FLOOR_ALARM",
    "FORBIDDEN_ZONE_ALARM",
    "alarm_code",
    "point_violation",
    "first_violation",
    "densify",
    "resample_count",
    "parse_supervision",
]

Vector3 = tuple[float, float, float]

#: alarm code: the actual TCP speed exceeded the limit in force (manual_speed in MANUAL, auto_speed in AUTO)
TCP_SPEED_ALARM = 4400
#: alarm code: the TCP left the allowed box
ZONE_ALARM = 4500
#: alarm code: the TCP went below the floor
FLOOR_ALARM = 4501
#: alarm code of entering forbidden box n (1-based) is this plus n, for n up to 89; 4599 beyond
FORBIDDEN_ZONE_ALARM = 4510
_FORBIDDEN_LAST = 89

_AXES = "xyz"


def _error(message: str) -> Exception:
    """A :class:`~.model.ModelError` (imported here: :mod:`.model` imports this module)."""
    from .model import ModelError

    return ModelError(message)


def _real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _num(value: float) -> str:
    return f"{value:.6g}"


def _vector(value: object, what: str) -> Vector3:
    if isinstance(value, str | bytes) or not isinstance(value, Sequence | np.ndarray) or len(value) != 3:
        raise _error(f"{what} must be 3 numbers (x, y, z), not {value!r}")
    items = [v.item() if isinstance(v, np.generic) else v for v in value]
    for axis, v in zip(_AXES, items, strict=True):
        if not _real(v):
            raise _error(f"{what} {axis} = {v!r} must be a finite number")
    return (float(items[0]), float(items[1]), float(items[2]))


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the cell frame, metres: ``lower`` and ``upper`` corners ``(x, y, z)``,
    ``lower < upper`` on every axis. Its faces belong to it."""

    lower: Vector3
    upper: Vector3
    name: str = ""

    def __post_init__(self) -> None:
        label = f"box {self.name!r}" if self.name else "box"
        if not isinstance(self.name, str):
            raise _error(f"box name must be a string, not {self.name!r}")
        lower = _vector(self.lower, f"{label} lower")
        upper = _vector(self.upper, f"{label} upper")
        for axis, lo, hi in zip(_AXES, lower, upper, strict=True):
            if not lo < hi:
                raise _error(f"{label}: lower {axis} = {_num(lo)} must be less than upper {axis} = {_num(hi)}")
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def bounds(self) -> tuple[float, float, float, float, float, float]:
        """``(x0, y0, z0, x1, y1, z1)``: the lower corner, then the upper."""
        return (*self.lower, *self.upper)

    def contains(self, x: float, y: float, z: float) -> bool:
        """Whether the point is inside or on a face."""
        x0, y0, z0 = self.lower
        x1, y1, z1 = self.upper
        return x0 <= x <= x1 and y0 <= y <= y1 and z0 <= z <= z1

    def contains_points(self, positions: ArrayLike) -> NDArray[np.bool_]:
        """Per row of an ``(N, 3)`` array, whether it is inside or on a face."""
        p = _positions(positions)
        inside: NDArray[np.bool_] = np.all((p >= self.lower) & (p <= self.upper), axis=1)
        return inside

    def describe(self) -> str:
        """``x 0.1..0.6, y -0.2..0.2, z 0..0.5 m``."""
        return (
            ", ".join(f"{a} {_num(lo)}..{_num(hi)}" for a, lo, hi in zip(_AXES, self.lower, self.upper, strict=True))
            + " m"
        )


@dataclass(frozen=True)
class Supervision:
    """A controller's Cartesian supervision settings, SI units (see the module's documentation).

    ``manual_speed``: the TCP speed limit in MANUAL (teach) mode, m/s. ``auto_speed``: the limit
    in AUTO mode (None: none). ``allowed``: the box the TCP must stay in (None: anywhere).
    ``forbidden``: boxes it must stay out of. ``floor``: the TCP must stay at ``z >= floor``
    (None: no floor). ``tolerance``: the sampling step, m, that path checks guarantee.
    """

    manual_speed: float = 0.25
    auto_speed: float | None = None
    allowed: Box | None = None
    forbidden: tuple[Box, ...] = ()
    floor: float | None = None
    tolerance: float = 0.001
    # the zones as flat tuples of floats, for point_violation's plain comparisons
    _allowed_bounds: tuple[float, ...] | None = field(init=False, repr=False, compare=False, default=None)
    _forbidden_bounds: tuple[tuple[float, ...], ...] = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        def positive(name: str, value: object) -> None:
            if not _real(value) or not value > 0:  # type: ignore[operator]
                raise _error(f"supervision {name} = {value!r} must be a finite number > 0")

        positive("manual_speed", self.manual_speed)
        if self.auto_speed is not None:
            positive("auto_speed", self.auto_speed)
        positive("tolerance", self.tolerance)
        if self.floor is not None and not _real(self.floor):
            raise _error(f"supervision floor = {self.floor!r} must be a finite number (or None)")
        if self.allowed is not None and not isinstance(self.allowed, Box):
            raise _error(f"supervision allowed must be a Box (or None), not {self.allowed!r}")
        if isinstance(self.forbidden, Box) or not isinstance(self.forbidden, Sequence):
            raise _error(f"supervision forbidden must be a sequence of Box, not {self.forbidden!r}")
        forbidden = tuple(self.forbidden)
        for i, box in enumerate(forbidden):
            if not isinstance(box, Box):
                raise _error(f"supervision forbidden[{i}] must be a Box, not {box!r}")
        if self.floor is not None and self.allowed is not None and self.floor > self.allowed.upper[2]:
            raise _error(
                f"supervision floor z = {_num(self.floor)} m is above the allowed box's top "
                f"z = {_num(self.allowed.upper[2])} m: no position would be allowed"
            )
        for name in ("manual_speed", "auto_speed", "tolerance", "floor"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, float(value))
        object.__setattr__(self, "forbidden", forbidden)
        object.__setattr__(self, "_allowed_bounds", None if self.allowed is None else self.allowed.bounds)
        object.__setattr__(self, "_forbidden_bounds", tuple(box.bounds for box in forbidden))

    @property
    def has_zones(self) -> bool:
        """Whether any position rule is set (an allowed box, a floor or a forbidden box)."""
        return self.allowed is not None or self.floor is not None or bool(self.forbidden)

    def speed_limit(self, manual: bool) -> float | None:
        """The TCP speed limit in force, m/s: ``manual_speed`` in MANUAL (teach) mode, else ``auto_speed``."""
        return self.manual_speed if manual else self.auto_speed

    def watches(self, manual: bool) -> bool:
        """Whether the TCP is supervised at all (a speed limit in force or any zone)."""
        return self.speed_limit(manual) is not None or self.has_zones


class Violation(NamedTuple):
    """A position that breaks a rule of a :class:`Supervision`.

    ``kind``: ``"allowed"`` (outside the allowed box), ``"floor"`` (below the floor) or
    ``"forbidden"`` (inside forbidden box ``index``, 0-based; ``index`` is -1 for the other kinds).
    ``sample``: the row of the checked array (0 for :func:`point_violation`). ``position``: the
    TCP position, m. ``zone`` is the box concerned (allowed or forbidden), ``floor`` the floor's
    height (for ``"floor"``).
    """

    kind: str
    index: int  # type: ignore[assignment]  # (shadows tuple.index, which no one calls on a violation)
    sample: int
    position: Vector3
    zone: Box | None = None
    floor: float | None = None

    @property
    def code(self) -> int:
        """The alarm code (:func:`alarm_code`)."""
        return alarm_code(self)

    @property
    def message(self) -> str:
        """What happened, for an operator: ``TCP at (0.512, 0.100, 0.020) m is below the floor z = 0.05 m``."""
        x, y, z = self.position
        where = f"TCP at ({x:.3f}, {y:.3f}, {z:.3f}) m"
        if self.kind == "floor":
            return f"{where} is below the floor z = {_num(self.floor if self.floor is not None else math.nan)} m"
        box = self.zone
        name = f" {box.name!r}" if box is not None and box.name else ""
        extent = f" ({box.describe()})" if box is not None else ""
        if self.kind == "forbidden":
            return f"{where} enters forbidden zone {self.index + 1}{name}{extent}"
        if box is None:
            return f"{where} leaves the allowed workspace"
        outside = [
            f"{a} {_num(lo)}..{_num(hi)}"
            for a, v, lo, hi in zip(_AXES, self.position, box.lower, box.upper, strict=True)
            if not lo <= v <= hi
        ]
        return f"{where} leaves the allowed workspace{name} " + (
            ", ".join(outside) + " m" if outside else box.describe()
        )


def alarm_code(violation: Violation) -> int:
    """The alarm code of a violation: :data:`ZONE_ALARM`, :data:`FLOOR_ALARM`, or
    :data:`FORBIDDEN_ZONE_ALARM` plus the forbidden box's 1-based number (at most 89: 4599)."""
    if violation.kind == "allowed":
        return ZONE_ALARM
    if violation.kind == "floor":
        return FLOOR_ALARM
    if violation.kind == "forbidden":
        return FORBIDDEN_ZONE_ALARM + min(violation.index + 1, _FORBIDDEN_LAST)
    raise ValueError(f"unknown violation kind {violation.kind!r}")


# -- checks ----------------------------------------------------------------------------------------------


def point_violation(supervision: Supervision, x: float, y: float, z: float) -> Violation | None:
    """The rule one TCP position breaks (the first in the order allowed box, floor, forbidden
    boxes), or None. Plain float comparisons: cheap enough for every interpolation tick."""
    a = supervision._allowed_bounds
    if a is not None and not (a[0] <= x <= a[3] and a[1] <= y <= a[4] and a[2] <= z <= a[5]):
        return Violation("allowed", -1, 0, (float(x), float(y), float(z)), supervision.allowed)
    floor = supervision.floor
    if floor is not None and not z >= floor:
        return Violation("floor", -1, 0, (float(x), float(y), float(z)), None, floor)
    for i, b in enumerate(supervision._forbidden_bounds):
        if b[0] <= x <= b[3] and b[1] <= y <= b[4] and b[2] <= z <= b[5]:
            return Violation("forbidden", i, 0, (float(x), float(y), float(z)), supervision.forbidden[i])
    return None


def _positions(positions: ArrayLike) -> Array:
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions must be an (N, 3) array, not of shape {p.shape}")
    return p


def _first(mask: NDArray[np.bool_]) -> int | None:
    index = int(np.argmax(mask)) if mask.size else 0
    return index if mask.size and mask[index] else None


def first_violation(supervision: Supervision, positions: ArrayLike) -> Violation | None:
    """The earliest sample of a TCP path ``(N, 3)`` (m, cell frame, in time order) that breaks a
    rule, or None. At one sample the allowed box comes first, then the floor, then the forbidden
    boxes in order. Only the samples are checked: :func:`densify` the path first to check it
    between them within ``supervision.tolerance``."""
    p = _positions(positions)
    found: tuple[int, str, int, Box | None, float | None] | None = None
    end = len(p)  # a later rule matters only strictly before the best sample so far
    if supervision.allowed is not None:
        box = supervision.allowed
        outside = ~np.all((p >= box.lower) & (p <= box.upper), axis=1)
        sample = _first(outside)
        if sample is not None:
            found, end = (sample, "allowed", -1, box, None), sample
    if supervision.floor is not None and end:
        below = ~(p[:end, 2] >= supervision.floor)
        sample = _first(below)
        if sample is not None:
            found, end = (sample, "floor", -1, None, supervision.floor), sample
    for i, box in enumerate(supervision.forbidden):
        if not end:
            break
        head = p[:end]
        sample = _first(np.all((head >= box.lower) & (head <= box.upper), axis=1))
        if sample is not None:
            found, end = (sample, "forbidden", i, box, None), sample
    if found is None:
        return None
    sample, kind, index, zone, floor = found
    x, y, z = (float(v) for v in p[sample])
    return Violation(kind, index, sample, (x, y, z), zone, floor)


def _segments(p: Array, step: float) -> NDArray[np.int64]:
    if not (_real(step) and step > 0):
        raise ValueError(f"step must be a finite number > 0, not {step!r}")
    lengths = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if not np.all(np.isfinite(lengths)):
        raise ValueError("positions must be finite")
    counts: NDArray[np.int64] = np.maximum(np.ceil(lengths / step), 1).astype(np.int64)
    return counts


def resample_count(positions: ArrayLike, step: float) -> int:
    """How many points :func:`densify` would give (to bound the work before doing it)."""
    p = _positions(positions)
    return len(p) if len(p) < 2 else int(_segments(p, step).sum()) + 1


def densify(positions: ArrayLike, step: float) -> Array:
    """The polyline through ``positions`` ``(N, 3)`` with linearly interpolated points inserted so
    that consecutive points are at most ``step`` apart. Every original point is kept, in order;
    each segment is cut into equal parts."""
    p = _positions(positions)
    if len(p) < 2:
        return p.copy()
    counts = _segments(p, step)
    segment = np.repeat(np.arange(len(counts)), counts)
    starts = np.cumsum(counts) - counts
    fraction = (np.arange(segment.size) - starts[segment]) / counts[segment]
    out = np.empty((segment.size + 1, 3))
    out[:-1] = p[segment] + fraction[:, None] * (p[segment + 1] - p[segment])
    out[-1] = p[-1]
    return out


# -- settings from TOML -------------------------------------------------------------------------------------

_KEYS = ("manual_speed", "auto_speed", "tolerance", "floor", "allowed", "forbidden")
_BOX_KEYS = ("name", "lower", "upper")
_UNIT_OF_SCALE = {1.0: "m", 1e-3: "mm"}


def parse_supervision(
    table: Mapping[str, Any], *, length_scale: float, where: str, unit: str | None = None
) -> Supervision:
    """The settings of a TOML ``[supervision]`` table, given in the file's length unit
    (``length_scale`` converts it to metres; speeds are in that unit per second)::

        [supervision]
        manual_speed = 250            # MANUAL (teach) mode TCP speed limit (default 250 mm/s)
        auto_speed = 1000             # AUTO mode limit (default: none)
        tolerance = 1                 # path check sampling step (default 1 mm)
        floor = -200                  # the TCP stays at z >= floor (default: no floor)
        allowed = { lower = [-800, -800, -400], upper = [800, 800, 1100] }
        forbidden = [{ name = "fixture", lower = [200, -550, -200], upper = [500, -300, 150] }]

    Read strictly: errors are :class:`~.model.ModelError` naming ``where`` (the file), the table and
    the key, an unknown key with the closest known one (``cell.toml: [supervision] manual_sped:
    unknown key; did you mean manual_speed?``), and a wrong value as the file writes it, in
    ``unit``, the file's length unit (default: the name of ``length_scale``, ``m`` or ``mm``).
    """
    if not (_real(length_scale) and length_scale > 0):
        raise ValueError(f"length_scale must be a finite number > 0, not {length_scale!r}")
    if unit is None:
        unit = _UNIT_OF_SCALE.get(length_scale, f"x {length_scale:g} m")
    if not isinstance(table, Mapping):
        raise _error(f"{where}: [supervision]: must be a table, not {table!r}")

    def error(key: str, problem: str) -> Exception:
        return _error(f"{where}: [supervision] {key}: {problem}")

    def check_keys(mapping: Mapping[str, Any], known: Sequence[str], prefix: str) -> None:
        for key in mapping:
            if key not in known:
                raise error(f"{prefix}{key}", "unknown key" + did_you_mean(key, known))

    check_keys(table, _KEYS, "")

    def number(key: str, unit_of_key: str, positive: bool = True) -> float | None:
        if key not in table:
            return None
        value = table[key]
        if not _real(value):
            raise error(key, f"must be a finite number, not {value!r}")
        if positive and not value > 0:
            raise error(key, f"{show(float(value))} {unit_of_key} must be > 0")
        return float(value)

    def box(value: object, what: str) -> tuple[Vector3, Vector3, str]:
        """A box's corners in the file's unit, and its name."""
        if not isinstance(value, Mapping):
            raise error(what, f"must be a table {{ lower = [x, y, z], upper = [x, y, z] }}, not {value!r}")
        check_keys(value, _BOX_KEYS, f"{what}.")
        name = value.get("name", "")
        if not isinstance(name, str):
            raise error(f"{what}.name", f"must be a string, not {name!r}")
        corners = []
        for key in ("lower", "upper"):
            if key not in value:
                raise error(f"{what}.{key}", "missing")
            corner = value[key]
            if not isinstance(corner, list) or len(corner) != 3 or not all(_real(v) for v in corner):
                raise error(f"{what}.{key}", f"must be a list of 3 finite numbers, not {corner!r}")
            corners.append((float(corner[0]), float(corner[1]), float(corner[2])))
        for axis, lo, hi in zip(_AXES, corners[0], corners[1], strict=True):
            if not lo < hi:
                raise error(what, f"lower {axis} = {show(lo)} {unit} is not below upper {axis} = {show(hi)} {unit}")
        return corners[0], corners[1], name

    def scaled(corners: tuple[Vector3, Vector3, str]) -> Box:
        lower, upper, name = corners
        return Box(
            (lower[0] * length_scale, lower[1] * length_scale, lower[2] * length_scale),
            (upper[0] * length_scale, upper[1] * length_scale, upper[2] * length_scale),
            name,
        )

    allowed = box(table["allowed"], "allowed") if "allowed" in table else None
    forbidden: list[tuple[Vector3, Vector3, str]] = []
    if "forbidden" in table:
        boxes = table["forbidden"]
        if not isinstance(boxes, list):
            raise error("forbidden", f"must be a list of tables, not {boxes!r}")
        forbidden = [box(b, f"forbidden[{i}]") for i, b in enumerate(boxes)]
    speeds = {
        "manual_speed": number("manual_speed", f"{unit}/s"),
        "auto_speed": number("auto_speed", f"{unit}/s"),
        "tolerance": number("tolerance", unit),
        "floor": number("floor", unit, positive=False),
    }
    floor = speeds["floor"]
    if floor is not None and allowed is not None and floor > allowed[1][2]:
        raise error(
            "floor",
            f"{show(floor)} {unit} is above the top of the allowed box, z = {show(allowed[1][2])} {unit}: "
            "no position would be allowed",
        )
    settings: dict[str, Any] = {key: value * length_scale for key, value in speeds.items() if value is not None}
    try:
        return Supervision(
            allowed=None if allowed is None else scaled(allowed),
            forbidden=tuple(scaled(b) for b in forbidden),
            **settings,
        )
    except ValueError as exc:
        raise _error(f"{where}: {exc}") from None
