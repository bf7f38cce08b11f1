"""The fleet file: many controllers for ``robot-server --fleet FILE.toml``, read strictly.

::

    [defaults]                 # any controller key but name: where a controller does not set it
    profile = "generic"
    host = "127.0.0.1"

    [[controller]]
    name = "r1"                # required, unique: letters, digits, _ and -
    profile = "motoros"
    model = "jibot_zxs"        # or a list, one model per motion group
    motion_port = 50240
    state_port = 50241
    io_port = 50242
    faults = ["2.5:estop"]     # fault commands at controller times (s), as --fault

A controller's keys are ``robot-server``'s options with underscores (:data:`CONTROLLER_KEYS`); a
key left out takes ``[defaults]``'s value, else the option's default (the profile's well-known ports
among them). The whole file is checked before anything is bound: an unknown table or key (with the
closest known name), a value of the wrong type, two controllers of one name, two ports that would
be one (the same port on the same address, or on a wildcard address), and a port another program
holds are refused with a :class:`FleetError` that names the file, the controller and the key.
What the fleet shares (its clock's ``--speedup``, the web view, the log level) is set on the
command line, not here.
"""

from __future__ import annotations

import contextlib
import ipaddress
import math
import re
import socket
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._strict import did_you_mean
from ..emulator import FAULT_COMMANDS, EmulatorConfig
from ..emulator.owner import OnDisconnect
from ..emulator.server import MAX_STATE_RATE

__all__ = ["CONTROLLER_KEYS", "ControllerSpec", "FleetError", "FleetSpec", "load_fleet", "parse_fleet"]


class FleetError(ValueError):
    """A fleet file that cannot run: the message names the file, the controller and the key."""


#: the longest record a controller keeps (s of controller time), as ``--record-seconds``
MAX_RECORD_SECONDS = 3600.0
#: the longest interpolation (and servo) period a controller takes (s): a real one's is milliseconds
MAX_INTERPOLATION_PERIOD = 1.0
#: the most servo ticks in one interpolation period (a servo period too short for its interpolation's)
MAX_SERVO_TICKS = 1000
#: the largest capture bound (MB)
MAX_CAPTURE_MB = 1e6
#: a controller's name: what stdin's fault commands and the web view's addresses use
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,62}")
#: a name stdin's commands keep for every controller at once
ALL = "all"


def _text(value: object) -> str:
    if not isinstance(value, str):
        raise TypeError(f"must be a string, not {value!r}")
    return value


def _choice(*choices: str) -> Callable[[object], str]:
    def read(value: object) -> str:
        text = _text(value)
        if text not in choices:
            raise TypeError(f"{text!r} is not one of {', '.join(repr(c) for c in choices)}")
        return text

    return read


def _flag(value: object) -> bool:
    if not isinstance(value, bool):
        raise TypeError(f"must be true or false, not {value!r}")
    return value


def _integer(low: int, high: int | None = None) -> Callable[[object], int]:
    def read(value: object) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"must be a whole number, not {value!r}")
        if value < low or (high is not None and value > high):
            raise TypeError(f"must be {low}..{high}, not {value}" if high is not None else f"must be >= {low}")
        return value

    return read


def _positive(high: float | None = None) -> Callable[[object], float]:
    def read(value: object) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise TypeError(f"must be a finite number, not {value!r}")
        if not value > 0.0 or (high is not None and value > high):
            raise TypeError(f"must be > 0 and at most {high:g}, not {value}" if high else f"must be > 0, not {value}")
        return float(value)

    return read


def _port(value: object) -> int:
    return _integer(0, 65535)(value)


def _models(value: object) -> tuple[str, ...]:
    if isinstance(value, str):
        return (value,)
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return tuple(value)
    raise TypeError(f"must be a model (a shipped name or a file) or a non-empty list of them, not {value!r}")


def _numbers(value: object) -> tuple[float, ...]:
    if not isinstance(value, list) or not value:
        raise TypeError(f"must be a list of numbers, not {value!r}")
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise TypeError(f"must be a list of finite numbers, not {value!r}")
    return tuple(float(v) for v in value)


def _options(value: object) -> tuple[tuple[str, str], ...]:
    if not isinstance(value, dict):
        raise TypeError(f"must be a table of KEY = VALUE, not {value!r}")
    pairs = []
    for key, item in value.items():
        if isinstance(item, bool):
            item = "true" if item else "false"
        if not isinstance(item, str | int | float):
            raise TypeError(f"{key}: must be a string or a number, not {item!r}")
        pairs.append((key, str(item)))
    return tuple(pairs)


def _faults(value: object) -> tuple[tuple[float, str], ...]:
    if not isinstance(value, list):
        raise TypeError(f'must be a list of "SECONDS:COMMAND" strings, not {value!r}')
    known = {name.split()[0] for name in FAULT_COMMANDS}
    faults = []
    for item in value:
        at, sep, command = _text(item).partition(":")
        try:
            seconds = float(at)
        except ValueError:
            seconds = -1.0
        words = command.split()
        if not sep or not seconds >= 0.0 or not math.isfinite(seconds) or not words:
            raise TypeError(f'expected "SECONDS:COMMAND" (e.g. "2.5:estop"), not {item!r}')
        if words[0].lower() not in known:
            raise TypeError(f"unknown fault command {command.strip()!r} (known: {', '.join(sorted(known))})")
        faults.append((seconds, command.strip()))
    return tuple(faults)


#: every key a ``[[controller]]`` table may hold, with its reader (a TypeError says what is wrong)
CONTROLLER_KEYS: dict[str, Callable[[object], object]] = {
    "name": _text,
    "profile": _text,
    "model": _models,
    "host": _text,
    "motion_port": _port,
    "state_port": _port,
    "io_port": _port,
    "byte_order": _choice("little", "big", "auto"),
    "float64": _flag,
    "reply_style": _choice("echo", "header"),
    "state_rate": _positive(MAX_STATE_RATE),
    "feedback": _flag,
    "interpolation": _text,
    "interpolation_period": _positive(MAX_INTERPOLATION_PERIOD),
    "servo_period": _positive(MAX_INTERPOLATION_PERIOD),
    "queue_size": _integer(1),
    "on_disconnect": _choice(*(o.value for o in OnDisconnect)),
    "lenient": _flag,
    "profile_options": _options,
    "max_connections": _integer(1),
    "frame_timeout": _positive(),
    "cell": _text,
    "manual_motion": _flag,
    "initial_position": _numbers,
    "faults": _faults,
    "serial": _text,
    "capture": _text,
    "capture_max_mb": _positive(MAX_CAPTURE_MB),
    "record": _text,
    "record_seconds": _positive(MAX_RECORD_SECONDS),
}
#: the file's own tables
_TABLES = ("defaults", "controller")
#: keys of EmulatorConfig spelt otherwise in the file (the file follows the command line's options)
_RENAMED = {"model": "models", "queue_size": "queue_capacity"}
#: keys that are the controller's but not EmulatorConfig's
_OWN = ("name", "faults", "record", "record_seconds", "capture_max_mb")


@dataclass(frozen=True)
class ControllerSpec:
    """One controller of a fleet: its name, its emulator's configuration, and what the command
    does around it (scheduled faults, the record written on exit)."""

    name: str
    config: EmulatorConfig
    faults: tuple[tuple[float, str], ...] = ()
    record: Path | None = None
    record_seconds: float = 60.0


@dataclass(frozen=True)
class FleetSpec:
    """A fleet file read and checked: its controllers in the file's order."""

    path: Path
    controllers: tuple[ControllerSpec, ...] = field(default_factory=tuple)

    def named(self, name: str) -> ControllerSpec:
        for spec in self.controllers:
            if spec.name == name:
                return spec
        raise KeyError(name)


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def load_fleet(path: str | Path, *, speedup: float = 1.0, check_ports: bool = True) -> FleetSpec:
    """Read and check the fleet file ``path`` (see the module doc); ``check_ports`` also refuses a
    port another program holds now. Raises :class:`FleetError`."""
    path = Path(path)
    try:
        with open(path, "rb") as stream:
            data = tomllib.load(stream)
    except tomllib.TOMLDecodeError as exc:
        raise FleetError(f"{path}: not valid TOML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FleetError(f"{path}: cannot read: {exc}") from None
    return parse_fleet(data, path, speedup=speedup, check_ports=check_ports)


def parse_fleet(
    data: Mapping[str, Any], path: str | Path = "<fleet>", *, speedup: float = 1.0, check_ports: bool = True
) -> FleetSpec:
    """:func:`load_fleet` of a file already parsed as TOML."""
    path = Path(path)
    for key, value in data.items():
        if key not in _TABLES:
            kind = "table" if isinstance(value, dict | list) else "key outside any table"
            raise FleetError(f"{path}: [{key}]: unknown {kind}{did_you_mean(key, _TABLES, lambda k: f'[{k}]')}")
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise FleetError(f"{path}: defaults: must be a table [defaults], not {defaults!r}")
    if "name" in defaults:
        raise FleetError(f"{path}: [defaults] name: every controller has a name of its own")
    common = _read(path, "[defaults]", defaults)
    tables = data.get("controller", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise FleetError(f"{path}: controller: must be [[controller]] tables, one per controller")
    if not tables:
        raise FleetError(f"{path}: no [[controller]] table: a fleet needs at least one controller")
    specs: list[ControllerSpec] = []
    seen: dict[str, int] = {}
    for index, table in enumerate(tables, 1):
        where = f"[[controller]] {_ordinal(index)}"
        name = table.get("name")
        if name is None:
            raise FleetError(f"{path}: {where}: name: missing (each controller needs a name)")
        if not isinstance(name, str) or NAME.fullmatch(name) is None or name == ALL:
            raise FleetError(
                f"{path}: {where}: name: {name!r} is not a name (letters, digits, _ and -, at most 63, not {ALL!r})"
            )
        if name in seen:
            raise FleetError(
                f"{path}: {where}: name: {name!r} is the name of the {_ordinal(seen[name])} controller too"
            )
        seen[name] = index
        where = f"controller {name}"
        values = {**common, **_read(path, where, table)}
        specs.append(_spec(path, where, name, values, speedup))
    _check_ports(path, specs, check_ports)
    _check_files(path, specs)
    return FleetSpec(path, tuple(specs))


def _check_files(path: Path, specs: Sequence[ControllerSpec]) -> None:
    """No two controllers write one record or capture file."""
    for key in ("record", "capture"):
        seen: dict[Path, str] = {}
        for spec in specs:
            target = spec.record if key == "record" else spec.config.capture
            if target is None:
                continue
            resolved = Path(target).expanduser().resolve()
            if resolved in seen:
                raise FleetError(
                    f"{path}: controller {spec.name}: {key}: {target} is controller {seen[resolved]}'s {key} too "
                    "(one file per controller)"
                )
            seen[resolved] = spec.name


def _read(path: Path, where: str, table: Mapping[str, Any]) -> dict[str, object]:
    values = {}
    for key, value in table.items():
        reader = CONTROLLER_KEYS.get(key)
        if reader is None:
            raise FleetError(f"{path}: {where}: {key}: unknown key{did_you_mean(key, list(CONTROLLER_KEYS))}")
        try:
            values[key] = reader(value)
        except TypeError as exc:
            raise FleetError(f"{path}: {where}: {key}: {exc}") from None
    return values


def _spec(path: Path, where: str, name: str, values: dict[str, object], speedup: float) -> ControllerSpec:
    options: dict[str, Any] = {_RENAMED.get(k, k): v for k, v in values.items() if k not in _OWN}
    if "capture_max_mb" in values:
        options["capture_max_bytes"] = max(1, round(float(str(values["capture_max_mb"])) * 1e6))
    try:
        config = EmulatorConfig(**options, speedup=speedup)
    except ValueError as exc:
        raise FleetError(f"{path}: {where}: {exc}") from None
    if config.interpolation_period / config.servo_period > MAX_SERVO_TICKS:
        raise FleetError(
            f"{path}: {where}: servo_period: {config.servo_period:g} s is more than {MAX_SERVO_TICKS} ticks per "
            f"interpolation period ({config.interpolation_period:g} s)"
        )
    emulated = config.emulated
    if "io_port" in values and emulated.default_port("io") is None:
        raise FleetError(f"{path}: {where}: io_port: the {config.profile} profile serves no io port")
    record = values.get("record")
    seconds = values.get("record_seconds", 60.0)
    assert isinstance(seconds, float)
    faults = values.get("faults", ())
    assert isinstance(faults, tuple)
    return ControllerSpec(name, config, faults, None if record is None else Path(str(record)), seconds)


def _wildcard(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return host == ""


def _check_ports(path: Path, specs: Sequence[ControllerSpec], probe: bool) -> None:
    """No two ports of the fleet are one, and (``probe``) no other program holds one."""
    taken: dict[int, list[tuple[str, str, str]]] = {}
    for spec in specs:
        cfg = spec.config
        for role in ("motion", "state", "io"):
            chosen = cfg.port(role)
            if chosen is None or chosen == 0:
                continue
            port = int(chosen)  # a profile's well-known port is an IntEnum, which getaddrinfo refuses
            for other, key, host in taken.get(port, []):
                if host == cfg.host or _wildcard(host) or _wildcard(cfg.host):
                    whose = "this controller's" if other == spec.name else f"controller {other}'s"
                    raise FleetError(f"{path}: controller {spec.name}: {role}_port: {port} is {whose} {key} too")
            taken.setdefault(port, []).append((spec.name, f"{role}_port", cfg.host))
            if probe:
                _probe(path, spec.name, role, cfg.host, port)


def _probe(path: Path, name: str, role: str, host: str, port: int) -> None:
    """Bind ``host:port`` as the server will (address reuse, as asyncio's servers) and let it go."""
    try:
        infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise FleetError(f"{path}: controller {name}: host: {host!r}: {exc.strerror}") from None
    for family, kind, proto, _, address in infos:
        with contextlib.closing(socket.socket(family, kind, proto)) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind(address)
            except OSError as exc:
                raise FleetError(
                    f"{path}: controller {name}: {role}_port: cannot bind {host}:{port}: {exc.strerror or exc}"
                ) from None
