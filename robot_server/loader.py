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
are shipped examples, not models). Every value is converted to SI on load. Every error names the
file and the field (:class:`~.model.ModelError`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .model import Joint, JointType, ModelError, MotorParameters, RobotModel, rot_x, rot_z, trans, transform
from .urdf import load_urdf
from .workspace import Supervision, parse_supervision

__all__ = ["load_model", "load_toml", "shipped_models", "model_from_dh", "load_supervision", "shipped_cells"]

Matrix = NDArray[np.float64]
_LENGTH = {"m": 1.0, "mm": 1e-3}
_ANGLE = {"rad": 1.0, "deg": math.pi / 180.0}
_DH_KEYS = {"name", "alpha", "a", "d", "theta", "type"}


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


class _Fields:
    """Typed access to a TOML table with errors that name the file and the field."""

    def __init__(self, path: Path, table: Any, where: str) -> None:
        if not isinstance(table, dict):
            raise ModelError(f"{path}: {where or 'the file'} must be a table")
        self.path = path
        self.table = table
        self.where = where

    def _name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def sub(self, key: str, required: bool = True) -> _Fields | None:
        if key not in self.table:
            if required:
                raise ModelError(f"{self.path}: missing table [{self._name(key)}]")
            return None
        return _Fields(self.path, self.table[key], self._name(key))

    def text(self, key: str, default: str | None = None, choices: dict[str, Any] | None = None) -> str:
        value = self.table.get(key, default)
        if value is None:
            raise ModelError(f"{self.path}: missing field {self._name(key)}")
        if not isinstance(value, str):
            raise ModelError(f"{self.path}: field {self._name(key)} must be a string, not {value!r}")
        if choices is not None and value not in choices:
            raise ModelError(f"{self.path}: field {self._name(key)} = {value!r} is not one of {sorted(choices)}")
        return value

    def number(self, key: str, default: float | None = None) -> float:
        value = self.table.get(key, default)
        if value is None:
            raise ModelError(f"{self.path}: missing field {self._name(key)}")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ModelError(f"{self.path}: field {self._name(key)} must be a finite number, not {value!r}")
        return float(value)

    def numbers(self, key: str, count: int, default: list[float] | None = None) -> list[float]:
        value = self.table.get(key, default)
        if value is None:
            raise ModelError(f"{self.path}: missing field {self._name(key)}")
        if not isinstance(value, list) or len(value) != count:
            raise ModelError(f"{self.path}: field {self._name(key)} must be a list of {count} numbers, not {value!r}")
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ModelError(f"{self.path}: field {self._name(key)}[{i}] must be a finite number, not {v!r}")
        return [float(v) for v in value]


def load_toml(path: Path) -> RobotModel:
    try:
        with open(path, "rb") as stream:
            data = tomllib.load(stream)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ModelError(f"{path}: cannot read: {exc}") from None
    top = _Fields(path, data, "")
    robot = top.sub("robot")
    units = top.sub("units")
    dh = top.sub("dh")
    assert robot is not None and units is not None and dh is not None
    length = _LENGTH[units.text("length", choices=_LENGTH)]
    angle = _ANGLE[units.text("angle", choices=_ANGLE)]
    convention = dh.text("convention", choices={"standard": 0, "modified": 0})
    rows = dh.table.get("joints")
    if not isinstance(rows, list) or not rows:
        raise ModelError(f"{path}: field dh.joints must be a non-empty list of joint tables")
    n = len(rows)
    limits = top.sub("limits", required=False)
    defaults = _default_limits(n, angle)
    lo = limits.numbers("position_min", n, defaults["position_min"]) if limits else defaults["position_min"]
    hi = limits.numbers("position_max", n, defaults["position_max"]) if limits else defaults["position_max"]
    vel = limits.numbers("velocity", n, defaults["velocity"]) if limits else defaults["velocity"]
    acc = limits.numbers("acceleration", n, defaults["acceleration"]) if limits else defaults["acceleration"]
    jerk = limits.numbers("jerk", n, defaults["jerk"]) if limits else defaults["jerk"]
    table: list[tuple[str, JointType, float, float, float, float]] = []
    for i, row in enumerate(rows):
        f = _Fields(path, row, f"dh.joints[{i}]")
        unknown = set(row) - _DH_KEYS
        if unknown:
            raise ModelError(f"{path}: dh.joints[{i}] has unknown field(s) {sorted(unknown)}")
        kind = JointType(f.text("type", "revolute", choices={t.value: t for t in JointType}))
        table.append(
            (
                f.text("name", f"joint_{i + 1}"),
                kind,
                f.number("alpha") * angle,
                f.number("a") * length,
                f.number("d") * length,
                f.number("theta", 0.0) * angle,
            )
        )
    scales = [angle if kind is JointType.REVOLUTE else length for _, kind, *_ in table]
    base = top.sub("base", required=False)
    tool = top.sub("tool", required=False)
    model = model_from_dh(
        robot.text("name"),
        convention,
        table,
        position=[(a * s, b * s) for a, b, s in zip(lo, hi, scales, strict=True)],
        velocity=[v * s for v, s in zip(vel, scales, strict=True)],
        acceleration=[v * s for v, s in zip(acc, scales, strict=True)],
        jerk=[v * s for v, s in zip(jerk, scales, strict=True)],
        base=_pose(base, length, angle),
        tool=_pose(tool, length, angle),
        description=robot.text("description", ""),
        source=robot.text("source", ""),
    )
    motors = top.sub("motors", required=False)
    if motors is not None:
        model = dataclasses.replace(model, motors=_motors(motors, n))
    if "supervision" in data:
        model = dataclasses.replace(
            model, supervision=parse_supervision(data["supervision"], length_scale=length, where=str(path))
        )
    return model


_MOTOR_FIELDS = tuple(f.name for f in dataclasses.fields(MotorParameters))


def _motors(table: _Fields, n: int) -> tuple[MotorParameters, ...]:
    """``[motors]``: per field a list of n numbers in SI units; a missing field takes the default."""
    unknown = set(table.table) - set(_MOTOR_FIELDS)
    if unknown:
        raise ModelError(
            f"{table.path}: [motors] has unknown field(s) {sorted(unknown)} (known: {list(_MOTOR_FIELDS)})"
        )
    columns = {key: table.numbers(key, n) for key in _MOTOR_FIELDS if key in table.table}
    motors = []
    for i in range(n):
        try:
            motors.append(MotorParameters(**{key: values[i] for key, values in columns.items()}))
        except ModelError as exc:
            raise ModelError(f"{table.path}: [motors] joint {i + 1}: {exc}") from None
    return tuple(motors)


def _default_limits(n: int, angle: float) -> dict[str, list[float]]:
    """motion.md §5 emulator defaults, expressed in the file's angle unit."""
    return {
        "position_min": [-math.pi / angle] * n,
        "position_max": [math.pi / angle] * n,
        "velocity": [math.pi / angle] * n,
        "acceleration": [10.0 / angle] * n,
        "jerk": [500.0 / angle] * n,
    }


def _with_frames(model: RobotModel, frames: Path) -> RobotModel:
    """A URDF model with the frames of its sidecar file ``<name>.frames.toml``, if there is one:
    ``[base]`` (where the robot stands in the cell: put before the URDF's root) and ``[tool]`` (the
    TCP: put after the chain's tip), each ``xyz`` and ``rpy``, in the file's ``[units]`` (default
    ``m`` and ``rad``). A URDF carries neither; the sidecar keeps the URDF itself untouched."""
    if not frames.exists():
        return model
    try:
        data = tomllib.loads(frames.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ModelError(f"{frames}: {exc}") from None
    top = _Fields(frames, data, "")
    units = top.sub("units", required=False)
    length = _LENGTH[units.text("length", "m", choices=_LENGTH)] if units is not None else 1.0
    angle = _ANGLE[units.text("angle", "rad", choices=_ANGLE)] if units is not None else 1.0
    base = _pose(top.sub("base", required=False), length, angle)
    tool = _pose(top.sub("tool", required=False), length, angle)
    model = dataclasses.replace(model, base=base @ model.base, tool=model.tool @ tool)
    if "supervision" in data:
        model = dataclasses.replace(
            model, supervision=parse_supervision(data["supervision"], length_scale=length, where=str(frames))
        )
    return model


def load_supervision(name_or_path: str | Path) -> Supervision:
    """A cell file's supervision settings: a TOML file with a ``[supervision]`` table (see
    :func:`~.workspace.parse_supervision`) in the length unit of its optional ``[units]``
    (``length = "m" | "mm"``, default ``m``), or a shipped cell file by name (``cell_example``).
    Other tables are ignored (a cell file may describe more than the supervision)."""
    text = str(name_or_path)
    shipped = _shipped(cells=True)
    path = shipped.get(text, Path(text))
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        names = ", ".join(sorted(shipped)) or "none"
        raise ModelError(f"{text}: no such cell file, and not a shipped cell ({names})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelError(f"{path}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{path}: not valid TOML: {exc}") from None
    top = _Fields(path, data, "")
    units = top.sub("units", required=False)
    length = _LENGTH[units.text("length", "m", choices=_LENGTH)] if units is not None else 1.0
    if units is not None and "angle" in units.table:
        units.text("angle", choices=_ANGLE)
    if "supervision" not in data:
        raise ModelError(f"{path}: missing table [supervision] (a cell file's TCP speed limits and zones)")
    return parse_supervision(data["supervision"], length_scale=length, where=str(path))


def _pose(table: _Fields | None, length: float, angle: float) -> Matrix:
    if table is None:
        return np.eye(4)
    xyz = table.numbers("xyz", 3, [0.0, 0.0, 0.0])
    rpy = table.numbers("rpy", 3, [0.0, 0.0, 0.0])
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
