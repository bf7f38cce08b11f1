"""Load robot models: TOML D-H files, URDF files (:mod:`.urdf`) and the models shipped with the package.

A TOML model states its units (``[units] length = "m" | "mm"``, ``angle = "rad" | "deg"``), its
optional ``[base]`` and ``[tool]`` frames (``xyz``, ``rpy``: where the robot stands in the cell, and
the TCP from the flange; identity by default) and its D-H convention (``[dh] convention =
"standard" | "modified"``); see ``models/jibot_zxs.toml`` for a complete, commented example. A URDF
model takes its base and tool frames from a sidecar file of the same name, ``<name>.frames.toml``
(``[units]``, ``[base]``, ``[tool]`` as above; no sidecar: identity). Either file may hold a
``[supervision]`` table, the TCP speed limits and workspace zones of :mod:`.workspace`, in the cell
frame and the file's length unit. A *cell file* (:func:`load_supervision`) holds such a table on
its own, with optional ``[units]``: the cell's zones, apart from any robot (``models/cell_*.toml``
are shipped examples, not models). Every value is converted to SI on load.

These files are read strictly, so that a mistake is never silently replaced by a default. A
:class:`~.model.ModelError` names the file, the table and the key, with the value as the file
writes it and in its units, for: an unknown table or key (with the closest known name:
``arm.toml: [limit]: unknown table; did you mean [limits]?``), a value of the wrong type or count,
a missing required table or key, a position range given by one end only, an inverted position range
(``[limits] position_min: joint 2 (joint_2): 130 deg is not below position_max = 120 deg``) and a
speed, acceleration or jerk limit that is not above 0. A cell file may hold tables of its own
besides ``[units]`` and ``[supervision]`` (those two are read strictly).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._strict import closest, did_you_mean, show
from .model import Joint, JointType, ModelError, MotorParameters, RobotModel, rot_x, rot_z, trans, transform
from .urdf import load_urdf
from .workspace import Supervision, parse_supervision

__all__ = ["load_model", "load_toml", "shipped_models", "model_from_dh", "load_supervision", "shipped_cells"]

Matrix = NDArray[np.float64]
_LENGTH = {"m": 1.0, "mm": 1e-3}
_ANGLE = {"rad": 1.0, "deg": math.pi / 180.0}

# What each file may hold: every other table or key is an error naming the closest of these.
_MODEL_TABLES = ("robot", "units", "dh", "limits", "base", "tool", "motors", "supervision")
_SIDECAR_TABLES = ("units", "base", "tool", "supervision")  # <name>.frames.toml beside a URDF
_CELL_TABLES = ("units", "supervision")
#: names no spelling resembles: [tcp] is the tool frame
_TABLE_ALIASES = {"tcp": "tool"}
_ROBOT_KEYS = ("name", "description", "source")
_UNITS_KEYS = ("length", "angle")
_DH_TABLE_KEYS = ("convention", "joints")
_DH_KEYS = ("name", "type", "alpha", "a", "d", "theta")
_LIMIT_KEYS = ("position_min", "position_max", "velocity", "acceleration", "jerk")
#: each limit's unit after the joint's own (deg, rad, mm or m), for messages in the file's units
_LIMIT_UNITS = {"position_min": "", "position_max": "", "velocity": "/s", "acceleration": "/s^2", "jerk": "/s^3"}
#: the emulator's defaults for a limit a file does not give, SI (rad or m, per second...)
_DEFAULT_LIMITS = {
    "position_min": -math.pi,
    "position_max": math.pi,
    "velocity": math.pi,
    "acceleration": 10.0,
    "jerk": 500.0,
}
_POSE_KEYS = ("xyz", "rpy")
_MOTOR_FIELDS = tuple(f.name for f in dataclasses.fields(MotorParameters))


_SUFFIXES = (".toml", ".urdf")
#: shipped files that are not models: cell files (``cell_*.toml``) and URDF sidecars
_CELL_PREFIX = "cell_"
_SIDECAR_SUFFIX = ".frames.toml"


def _shipped(cells: bool = False) -> dict[str, Path]:
    """Shipped models by name, or (``cells``) the shipped cell files ``cell_*.toml``."""
    folder = resources.files("robot_server") / "models"
    found: dict[str, Path] = {}
    for entry in folder.iterdir():
        if entry.name.endswith(_SIDECAR_SUFFIX) or entry.name.startswith(_CELL_PREFIX) != cells:
            continue
        for suffix in _SUFFIXES[:1] if cells else _SUFFIXES:
            if entry.name.endswith(suffix):
                found[entry.name[: -len(suffix)]] = Path(str(entry))
    return found


def shipped_models() -> list[str]:
    """Names of the models shipped in the package (``robot_server/models/*.toml`` and ``*.urdf``)."""
    return sorted(_shipped())


def shipped_cells() -> list[str]:
    """Names of the example cell files shipped in the package (``robot_server/models/cell_*.toml``)."""
    return sorted(_shipped(cells=True))


def load_model(name_or_path: str | Path) -> RobotModel:
    """A shipped model by name (``jibot_zxs``), or a model file by path (``.toml`` or ``.urdf``)."""
    text = str(name_or_path)
    shipped = _shipped()
    path = shipped.get(text, Path(text))
    if not path.exists():
        raise ModelError(f"{text}: no such model file, and not a shipped model ({', '.join(sorted(shipped))})")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return load_toml(path)
    if suffix == ".urdf":
        return _with_frames(load_urdf(path), path.with_suffix(".frames.toml"))
    raise ModelError(f"{path}: unknown model file type {path.suffix!r} (expected .toml or .urdf)")


def _read(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as stream:
            return tomllib.load(stream)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{path}: not valid TOML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelError(f"{path}: cannot read: {exc}") from None


def _real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _bracket(name: str) -> str:
    return f"[{name}]"


def _check_tables(path: Path, data: dict[str, Any], known: Sequence[str], *, lenient: bool = False) -> None:
    """The file's top level holds only the ``known`` tables, each a table. ``lenient`` (a cell file,
    which may describe more than its supervision) lets other tables pass unless their name is close
    to a known one's (a misspelling)."""
    for key, value in data.items():
        if key in known:
            if not isinstance(value, dict):
                raise ModelError(f"{path}: [{key}]: must be a table, not {value!r}")
            continue
        if lenient and closest(key, known, _TABLE_ALIASES) is None:
            continue
        hint = did_you_mean(key, known, _bracket, _TABLE_ALIASES)
        if isinstance(value, dict):
            raise ModelError(f"{path}: [{key}]: unknown table{hint}")
        raise ModelError(f"{path}: {key}: unknown key outside any table{hint}")


class _Table:
    """One table of a TOML file, read strictly: every key known (an unknown one is an error that
    suggests the closest known name), every value of its type. Errors name the file, the table and
    the key: ``arm.toml: [limits] velocity: ...``; ``prefix`` names a row inside the table
    (``joints[2].``)."""

    def __init__(self, path: Path, data: dict[str, Any], table: str, keys: Sequence[str], prefix: str = "") -> None:
        self.path = path
        self.data = data
        self.table = table
        self.prefix = prefix
        for key in data:
            if key not in keys:
                raise self.error(key, "unknown key" + did_you_mean(key, keys))

    def error(self, key: str, problem: str) -> ModelError:
        return ModelError(f"{self.path}: [{self.table}] {self.prefix}{key}: {problem}")

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def text(self, key: str, default: str | None = None, choices: Sequence[str] | None = None) -> str:
        if key not in self.data:
            if default is None:
                raise self.error(key, "missing")
            return default
        value = self.data[key]
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, not {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"{value!r} is not one of {', '.join(repr(c) for c in choices)}")
        return value

    def number(self, key: str, default: float | None = None) -> float:
        if key not in self.data:
            if default is None:
                raise self.error(key, "missing")
            return default
        value = self.data[key]
        if not _real(value):
            raise self.error(key, f"must be a finite number, not {value!r}")
        return float(value)

    def numbers(self, key: str, count: int | None = None) -> list[float] | None:
        """A list of finite numbers (``count`` of them, if given), or None if the key is absent."""
        if key not in self.data:
            return None
        value = self.data[key]
        expected = f"a list of {count} numbers" if count is not None else "a list of numbers"
        if not isinstance(value, list):
            raise self.error(key, f"must be {expected}, not {value!r}")
        for i, v in enumerate(value):
            if not _real(v):
                raise self.error(f"{key}[{i}]", f"must be a finite number, not {v!r}")
        if count is not None and len(value) != count:
            raise self.error(key, f"must be {expected}, not {value!r}")
        return [float(v) for v in value]

    def per_joint(self, key: str, names: Sequence[str]) -> list[float] | None:
        """One number per joint, or None if the key is absent; a joint without one is an error."""
        n = len(names)
        value = self.data.get(key)
        if value is not None and not isinstance(value, list):
            raise self.error(key, f"must be a list of {n} numbers, one per joint, not {value!r}")
        values = self.numbers(key)
        if values is not None and len(values) < n:
            missing = len(values)
            joint = f"joint {missing + 1} ({names[missing]})"
            raise self.error(key, f"{_count(missing, 'value')} for {_count(n, 'joint')}: {joint} has no value")
        if values is not None and len(values) > n:
            raise self.error(key, f"{_count(len(values), 'value')} for {_count(n, 'joint')}")
        return values


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _table(path: Path, data: dict[str, Any], name: str, keys: Sequence[str], required: bool = False) -> _Table | None:
    """The top-level table ``name`` (checked a table by :func:`_check_tables`), or None if absent."""
    if name not in data:
        if required:
            raise ModelError(f"{path}: missing table [{name}]")
        return None
    return _Table(path, data[name], name, keys)


def _required(path: Path, data: dict[str, Any], name: str, keys: Sequence[str]) -> _Table:
    table = _table(path, data, name, keys, required=True)
    assert table is not None
    return table


def load_toml(path: Path) -> RobotModel:
    """A model from a TOML D-H file, read strictly (module doc); every error names the file, the
    table and the key, with the value in the file's units."""
    data = _read(path)
    _check_tables(path, data, _MODEL_TABLES)
    robot = _required(path, data, "robot", _ROBOT_KEYS)
    units = _required(path, data, "units", _UNITS_KEYS)
    length_unit = units.text("length", choices=tuple(_LENGTH))
    angle_unit = units.text("angle", choices=tuple(_ANGLE))
    length, angle = _LENGTH[length_unit], _ANGLE[angle_unit]
    dh = _required(path, data, "dh", _DH_TABLE_KEYS)
    convention = dh.text("convention", choices=("standard", "modified"))
    table: list[tuple[str, JointType, float, float, float, float]] = []
    for i, row in enumerate(_rows(dh)):
        kind = JointType(row.text("type", JointType.REVOLUTE.value, choices=tuple(t.value for t in JointType)))
        table.append(
            (
                row.text("name", f"joint_{i + 1}"),
                kind,
                row.number("alpha") * angle,
                row.number("a") * length,
                row.number("d") * length,
                row.number("theta", 0.0) * angle,
            )
        )
    joints = [(name, kind) for name, kind, *_ in table]
    position, velocity, acceleration, jerk = _limits(
        _table(path, data, "limits", _LIMIT_KEYS), joints, (length_unit, angle_unit)
    )
    model = model_from_dh(
        robot.text("name"),
        convention,
        table,
        position=position,
        velocity=velocity,
        acceleration=acceleration,
        jerk=jerk,
        base=_pose(_table(path, data, "base", _POSE_KEYS), length, angle),
        tool=_pose(_table(path, data, "tool", _POSE_KEYS), length, angle),
        description=robot.text("description", ""),
        source=robot.text("source", ""),
    )
    motors = _table(path, data, "motors", _MOTOR_FIELDS)
    if motors is not None:
        model = dataclasses.replace(model, motors=_motors(motors, [name for name, _ in joints]))
    if "supervision" in data:
        supervision = parse_supervision(data["supervision"], length_scale=length, where=str(path), unit=length_unit)
        model = dataclasses.replace(model, supervision=supervision)
    return model


def _rows(dh: _Table) -> list[_Table]:
    """``[dh] joints``: a non-empty list of joint tables, each read strictly."""
    rows = dh.data.get("joints")
    if rows is None:
        raise dh.error("joints", "missing")
    if not isinstance(rows, list) or not rows:
        raise dh.error("joints", f"must be a non-empty list of joint tables, not {rows!r}")
    tables = []
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise dh.error(f"joints[{i}]", f"must be a table {{ alpha = ..., a = ..., d = ... }}, not {row!r}")
        tables.append(_Table(dh.path, row, dh.table, _DH_KEYS, prefix=f"joints[{i}]."))
    return tables


def _limits(
    table: _Table | None, joints: Sequence[tuple[str, JointType]], units: tuple[str, str]
) -> tuple[list[tuple[float, float]], list[float], list[float], list[float]]:
    """``[limits]`` in SI units: (position range, velocity, acceleration, jerk) per joint. A key the
    file does not give takes the emulator's default (``_DEFAULT_LIMITS``, SI); a position range is
    given whole or not at all. Checked in the file's units, so that an error shows the file's values."""
    names = [name for name, _ in joints]
    columns = {key: table.per_joint(key, names) if table is not None else None for key in _LIMIT_KEYS}
    lows, highs = columns["position_min"], columns["position_max"]
    if table is not None and (lows is None) != (highs is None):
        given, missing = ("position_min", "position_max") if highs is None else ("position_max", "position_min")
        raise table.error(
            missing, f"missing; {given} is given, so give both (or neither, for the emulator's default range ±π)"
        )
    length_unit, angle_unit = units
    si: dict[str, list[float]] = {key: [] for key in _LIMIT_KEYS}
    for i, (name, kind) in enumerate(joints):
        unit = length_unit if kind is JointType.PRISMATIC else angle_unit
        scale = _LENGTH[length_unit] if kind is JointType.PRISMATIC else _ANGLE[angle_unit]
        joint = f"joint {i + 1} ({name})"
        if lows is not None and highs is not None and not lows[i] < highs[i]:
            assert table is not None
            raise table.error(
                "position_min",
                f"{joint}: {show(lows[i])} {unit} is not below position_max = {show(highs[i])} {unit}",
            )
        for key, suffix in _LIMIT_UNITS.items():
            values = columns[key]
            if values is None:
                si[key].append(_DEFAULT_LIMITS[key])
                continue
            if key in ("velocity", "acceleration", "jerk") and not values[i] > 0:
                assert table is not None
                raise table.error(key, f"{joint}: {show(values[i])} {unit}{suffix} must be > 0")
            si[key].append(values[i] * scale)
    position = list(zip(si["position_min"], si["position_max"], strict=True))
    return position, si["velocity"], si["acceleration"], si["jerk"]


def _motors(table: _Table, names: Sequence[str]) -> tuple[MotorParameters, ...]:
    """``[motors]``: per field a list of one number per joint in SI units; a missing field takes the default."""
    columns = {key: values for key in _MOTOR_FIELDS if (values := table.per_joint(key, names)) is not None}
    motors = []
    for i in range(len(names)):
        try:
            motors.append(MotorParameters(**{key: values[i] for key, values in columns.items()}))
        except ModelError as exc:
            raise ModelError(f"{table.path}: [motors] joint {i + 1}: {exc}") from None
    return tuple(motors)


def _with_frames(model: RobotModel, frames: Path) -> RobotModel:
    """A URDF model with the frames of its sidecar file ``<name>.frames.toml``, if there is one:
    ``[base]`` (where the robot stands in the cell: put before the URDF's root) and ``[tool]`` (the
    TCP: put after the chain's tip), each ``xyz`` and ``rpy``, in the file's ``[units]`` (default
    ``m`` and ``rad``), and ``[supervision]``; read as strictly as a TOML model. A URDF carries
    neither; the sidecar keeps the URDF itself untouched."""
    if not frames.exists():
        return model
    data = _read(frames)
    _check_tables(frames, data, _SIDECAR_TABLES)
    units = _table(frames, data, "units", _UNITS_KEYS)
    length_unit = units.text("length", "m", choices=tuple(_LENGTH)) if units is not None else "m"
    angle_unit = units.text("angle", "rad", choices=tuple(_ANGLE)) if units is not None else "rad"
    length, angle = _LENGTH[length_unit], _ANGLE[angle_unit]
    base = _pose(_table(frames, data, "base", _POSE_KEYS), length, angle)
    tool = _pose(_table(frames, data, "tool", _POSE_KEYS), length, angle)
    model = dataclasses.replace(model, base=base @ model.base, tool=model.tool @ tool)
    if "supervision" in data:
        supervision = parse_supervision(data["supervision"], length_scale=length, where=str(frames), unit=length_unit)
        model = dataclasses.replace(model, supervision=supervision)
    return model


def load_supervision(name_or_path: str | Path) -> Supervision:
    """A cell file's supervision settings: a TOML file with a ``[supervision]`` table (see
    :func:`~.workspace.parse_supervision`) in the length unit of its optional ``[units]``
    (``length = "m" | "mm"``, default ``m``), or a shipped cell file by name (``cell_example``).
    ``[units]`` and ``[supervision]`` are read strictly; other tables are left alone (a cell file may
    describe more than the supervision), unless the name is close to one of these two (``[unit]``:
    an error that suggests ``[units]``)."""
    text = str(name_or_path)
    shipped = _shipped(cells=True)
    path = shipped.get(text, Path(text))
    if not path.exists():
        names = ", ".join(sorted(shipped)) or "none"
        raise ModelError(f"{text}: no such cell file, and not a shipped cell ({names})")
    data = _read(path)
    _check_tables(path, data, _CELL_TABLES, lenient=True)
    units = _table(path, data, "units", _UNITS_KEYS)
    length_unit = units.text("length", "m", choices=tuple(_LENGTH)) if units is not None else "m"
    if units is not None and "angle" in units:
        units.text("angle", choices=tuple(_ANGLE))
    if "supervision" not in data:
        raise ModelError(f"{path}: missing table [supervision] (a cell file's TCP speed limits and zones)")
    return parse_supervision(data["supervision"], length_scale=_LENGTH[length_unit], where=str(path), unit=length_unit)


def _pose(table: _Table | None, length: float, angle: float) -> Matrix:
    if table is None:
        return np.eye(4)
    xyz = table.numbers("xyz", 3) or [0.0, 0.0, 0.0]
    rpy = table.numbers("rpy", 3) or [0.0, 0.0, 0.0]
    return transform(
        (xyz[0] * length, xyz[1] * length, xyz[2] * length), (rpy[0] * angle, rpy[1] * angle, rpy[2] * angle)
    )


def model_from_dh(
    name: str,
    convention: str,
    rows: list[tuple[str, JointType, float, float, float, float]],
    *,
    position: list[tuple[float, float]],
    velocity: list[float],
    acceleration: list[float],
    jerk: list[float],
    base: Matrix | None = None,
    tool: Matrix | None = None,
    description: str = "",
    source: str = "",
) -> RobotModel:
    """A model from D-H rows ``(name, type, alpha, a, d, theta_offset)`` in SI units.

    For ``modified`` rows alpha and a are Craig's alpha_{i-1} and a_{i-1}. A prismatic joint's
    variable is d (its row's d is the offset); a revolute joint's is theta.
    """
    z = np.array([0.0, 0.0, 1.0])
    joints = []
    for i, (jname, kind, alpha, a, d, theta) in enumerate(rows):
        revolute = kind is JointType.REVOLUTE
        if convention == "standard":
            # A = Rz(theta) Tz(d) Tx(a) Rx(alpha)
            pre = np.eye(4) if revolute else rot_z(theta)
            post = (trans(0, 0, d) if revolute else np.eye(4)) @ trans(a, 0, 0) @ rot_x(alpha)
        elif convention == "modified":
            # A = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta) Tz(d)
            pre = rot_x(alpha) @ trans(a, 0, 0) @ (np.eye(4) if revolute else rot_z(theta))
            post = trans(0, 0, d) if revolute else np.eye(4)
        else:
            raise ModelError(f"model {name!r}: unknown D-H convention {convention!r} (standard or modified)")
        joints.append(
            Joint(
                name=jname,
                type=kind,
                pre=pre,
                axis=z,
                post=post,
                offset=theta if revolute else d,
                position=position[i],
                velocity=velocity[i],
                acceleration=acceleration[i],
                jerk=jerk[i],
                dh=(theta, d, a, alpha),
            )
        )
    return RobotModel(
        name=name,
        joints=tuple(joints),
        base=np.eye(4) if base is None else base,
        tool=np.eye(4) if tool is None else tool,
        description=description,
        source=source,
        convention=convention,
    )
