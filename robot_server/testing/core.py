"""What both kinds of emulated controller a test starts do: the one in this process
(:mod:`.inprocess`) and the ``robot-server`` process (:mod:`.process`).

A :class:`Core` lives on one event loop (the test's own, or a thread's for a sync test): its
coroutines run there, and so do its plain methods when a sync test calls them (the handle,
:mod:`.handle`, carries them over). Times are controller time unless said otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from simple_message.constants import RobotMode, TriState
from simple_message.messages import Status

from ..control import Recorder
from ..model import RobotModel
from .settings import Settings

__all__ = ["ControllerError", "ControllerTimeout", "Core", "describe_status", "loopback"]


class ControllerError(RuntimeError):
    """A controller that could not start or stop, or something it cannot give (a process's record
    while it runs)."""


class ControllerTimeout(TimeoutError):
    """What a test waited for did not happen within its limit; the message says where the robot
    was then."""


class Core(Protocol):
    """One emulated controller (see the module doc)."""

    settings: Settings
    #: the address a client connects to
    host: str
    #: the ports served, by role (motion, state, io)
    ports: dict[str, int]
    models: list[RobotModel]
    #: the pcapng file of every connection's traffic (None: none is kept)
    capture_path: Path | None
    closed: bool

    async def start(self) -> None: ...

    async def close(self) -> None:
        """Bring the robot to rest, close every connection and free the ports (again: nothing)."""

    def joints(self, group: int = 0) -> tuple[float, ...]: ...

    def status(self) -> Status: ...

    def time(self) -> float: ...

    def in_motion(self) -> bool: ...

    def records(self) -> list[Recorder]: ...

    async def fault(self, command: str) -> str: ...

    async def wait_idle(self, timeout: float) -> float: ...

    async def advance(self, seconds: float) -> float: ...

    async def advance_until(
        self, predicate: Callable[[], bool], limit: float, dt: float | None, what: str
    ) -> float: ...

    def describe(self) -> str:
        """The controller's state as of now, for a failed test's report."""


def bounded(name: str, value: float, *, positive: bool = False) -> float:
    """A wait's length as given by a test: a finite number of seconds, >= 0 (> 0 when ``positive``),
    else ValueError naming the argument (a NaN or infinite limit would make a wait that never ends,
    a negative one a wait that silently does not happen)."""
    seconds = float(value)
    if not math.isfinite(seconds) or seconds < 0.0 or (positive and seconds == 0.0):
        raise ValueError(f"{name} must be a finite number of seconds {'> 0' if positive else '>= 0'}, not {value!r}")
    return seconds


def loopback(host: str) -> str:
    """The address a client on this machine reaches a server bound to ``host`` at."""
    return {"": "127.0.0.1", "0.0.0.0": "127.0.0.1", "::": "::1"}.get(host, host)


def _tri(value: int) -> str:
    try:
        return TriState(value).name
    except ValueError:
        return str(value)


def describe_status(status: Status | None) -> str:
    """STATUS in one line, by name."""
    if status is None:
        return "STATUS: none received"
    try:
        mode = RobotMode(status.mode).name
    except ValueError:
        mode = str(status.mode)
    return (
        f"STATUS: drives_powered {_tri(status.drives_powered)}, e_stopped {_tri(status.e_stopped)}, "
        f"in_error {_tri(status.in_error)} (error_code {status.error_code}), in_motion {_tri(status.in_motion)}, "
        f"mode {mode}, motion_possible {_tri(status.motion_possible)}"
    )


def describe_joints(joints: tuple[float, ...] | None) -> str:
    if joints is None:
        return "joints: none received"
    return "joints: [" + ", ".join(f"{q:.6f}" for q in joints) + "]"


def describe_file(path: Path | None, what: str) -> str | None:
    if path is None:
        return None
    try:
        size = f"{path.stat().st_size / 1e3:.1f} kB"
    except OSError:
        size = "not written"
    return f"{what}: {path} ({size})"
