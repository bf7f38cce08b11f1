"""What ``robot_controller(...)`` is asked for, read as ``robot-server`` reads a controller's options.

The keyword settings are ``robot-server``'s options with underscores, the keys of a fleet file's
``[[controller]]`` table (:data:`robot_server.fleet.config.CONTROLLER_KEYS`). They are read by the
fleet file's own reader, so a misspelt or ill-typed one is refused with the same message the file
would get (naming the key, with the closest known name), and they become the same
:class:`~robot_server.emulator.EmulatorConfig`. For ``process=True`` the same settings are written
back as the command's options (:func:`command_line`).
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from ..emulator.profiles import PROFILES, profile_named
from ..fleet.config import CONTROLLER_KEYS, NAME, ControllerSpec, FleetError, parse_fleet

__all__ = ["Settings", "SettingsError", "Speedup", "command_line", "read_settings"]

#: a clock ``speedup`` times as fast as real time, or ``"step"``: the test moves it
Speedup = float | Literal["step"]
#: what ``parse_fleet`` calls the "file" the settings came from
_SOURCE = "robot_controller()"
#: keys without a ``robot-server`` option of their own (``name`` names the handle and its files)
_NO_OPTION = ("name", "initial_position")


class SettingsError(ValueError):
    """Settings ``robot_controller`` cannot start a controller with; the message names the key."""


@dataclass(frozen=True)
class Settings:
    """One controller's settings, checked."""

    name: str
    spec: ControllerSpec
    #: the fleet keys as given (and the ports the fixture chose), for the command line
    values: Mapping[str, object]
    #: a float (1.0: real time) or ``"step"``
    speedup: Speedup
    process: bool

    @property
    def stepped(self) -> bool:
        return self.speedup == "step"


def _speedup(value: object, process: bool) -> Speedup:
    if value is None:
        return 1.0
    if value == "step":
        if process:
            raise SettingsError(
                'speedup="step": a robot-server process keeps its own clock; step the clock in process (process=False)'
            )
        return "step"
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise SettingsError(f'speedup must be a number > 0, "step" or None (real time), not {value!r}')
    return float(value)


def _check_host(name: str, host: str) -> None:
    """The fixture's controllers are reached on loopback: ``host`` is a loopback address (127.0.0.0/8,
    ``::1``), ``localhost``, or a wildcard (``""``, ``0.0.0.0``, ``::``: every interface, loopback
    among them); else :class:`SettingsError`, naming the key and the value. Other names are not
    looked up: a typo would surface as the resolver's error deep in the start, and a name of
    another interface would have the controller listen where the test cannot be sure to reach it."""
    if host == "" or host.lower() == "localhost":
        return
    known = '127.0.0.1 (or another of 127.0.0.0/8), ::1 or localhost; 0.0.0.0, :: or "" to listen on every interface'
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        raise SettingsError(
            f"robot_controller({name}): host: {host!r} is not an IP address (a name other than localhost is not "
            f"looked up): give {known}"
        ) from None
    if not (address.is_loopback or address.is_unspecified):
        raise SettingsError(f"robot_controller({name}): host: {host!r} is not a loopback address: give {known}")


def _plain(value: object) -> object:
    """A Python value as TOML would give it to the fleet reader (lists, not tuples; paths as text)."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def read_settings(
    name: str,
    profile: str,
    model: str | Path | Sequence[str | Path],
    *,
    speedup: object,
    process: bool,
    settings: Mapping[str, object],
    capture: Path | None = None,
    record: Path | None = None,
) -> Settings:
    """Check one controller's settings; the ports not given are 0 (free ones), the capture and
    (process) record go to ``capture`` and ``record`` unless the settings name files of their own
    (``capture=None``: no capture). A setting given as None keeps its default. Raises
    :class:`SettingsError`."""
    if not isinstance(name, str) or NAME.fullmatch(name) is None:
        raise SettingsError(f"name: {name!r} is not a controller name (letters, digits, _ and -, at most 63)")
    clock = _speedup(speedup, process)
    if profile not in PROFILES:
        raise SettingsError(f"unknown profile {profile!r} (known: {', '.join(sorted(PROFILES))})")
    for key in ("profile", "model"):
        if key in settings:
            raise SettingsError(f"{key}: give it as robot_controller({key}=...), once")
    values: dict[str, object] = {"name": name, "profile": profile, "model": _plain(model)}
    # a setting given as None keeps its default; capture=None records no traffic
    values.update({k: _plain(v) for k, v in settings.items() if v is not None})
    if "capture" in settings and settings["capture"] is None:
        capture = None
    values.setdefault("motion_port", 0)
    values.setdefault("state_port", 0)
    if profile_named(profile).default_port("io") is not None:
        values.setdefault("io_port", 0)
    if capture is not None:
        values.setdefault("capture", str(capture))
    if process and record is not None:
        values.setdefault("record", str(record))
    try:
        spec = parse_fleet({"controller": [values]}, _SOURCE, speedup=1.0 if clock == "step" else clock).controllers[0]
    except FleetError as exc:
        text = str(exc).replace(f"{_SOURCE}: controller {name}: ", f"robot_controller({name}): ", 1)
        raise SettingsError(text) from None
    _check_host(name, spec.config.host)
    if process:
        for key in _NO_OPTION[1:]:
            if key in values:
                raise SettingsError(f"robot_controller({name}): {key}: robot-server has no such option (process=False)")
        given = values.get("record")
        if given is not None and not str(given).endswith(".npz"):  # the handle reads it back exactly
            raise SettingsError(
                f"robot_controller({name}): record: a process's record is read back from .npz, not {given!r}"
            )
        if values.get("float64") is False and spec.config.emulated.dialect.wire.real_size == 8:
            raise SettingsError(
                f"robot_controller({name}): float64: robot-server cannot turn its profile's float64 off"
            )
    return Settings(name, spec, values, clock, process)


def command_line(settings: Settings) -> list[str]:
    """The ``robot-server`` options of ``settings`` (a process's), as its parser reads them."""
    argv: list[str] = []
    for key, value in settings.values.items():
        if key in _NO_OPTION:
            continue
        option = "--" + key.replace("_", "-")
        if key == "model":
            models = value if isinstance(value, list) else [value]
            for item in models:
                argv += ["--model", str(item)]
        elif key == "profile_options":
            assert isinstance(value, Mapping)
            for k, v in value.items():
                text = ("true" if v else "false") if isinstance(v, bool) else str(v)
                argv += ["--profile-option", f"{k}={text}"]
        elif key == "faults":
            assert isinstance(value, list)
            for fault in value:
                argv += ["--fault", str(fault)]
        elif isinstance(value, bool):
            if value:
                argv.append(option)
        else:
            argv += [option, str(value)]
    if settings.speedup not in ("step", 1.0):
        argv += ["--speedup", repr(settings.speedup)]
    return argv


#: every key has its command-line twin (but those in ``_NO_OPTION``): checked by the tests
OPTION_KEYS = tuple(k for k in CONTROLLER_KEYS if k not in _NO_OPTION)
