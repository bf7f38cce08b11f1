"""A bounded recorder of control ticks, exported as CSV.

It keeps the most recent ``capacity`` ticks in preallocated arrays (a ring buffer), so a long run
never grows memory; :attr:`Recorder.dropped` says how many older ticks were overwritten.

The CSV is the project's one layout for joint motion (``client.trajectory``), so a trace loads as a
trajectory: ``time`` (s from the first tick written), the actual position of each joint under its
name, ``<joint>.velocity`` and ``<joint>.acceleration`` (actual), then extra columns:
``<joint>.command_position``, ``<joint>.command_velocity``, ``<joint>.command_acceleration``,
``<joint>.following_error`` (SI units), ``record.controller_time`` (the controller's clock, s),
``record.points`` (how many points the controller had accepted by that tick: it steps where points
arrived), then the tool centre point as of the last interpolation instant (the controller computes
it once per interpolation period, so it holds between them): ``tool.command_x``, ``_y``, ``_z`` (m,
cell frame), ``tool.command_qw``, ``_qx``, ``_qy``, ``_qz`` (orientation quaternion),
``tool.command_speed`` (m/s), the same for ``tool.actual_...``, and ``tool.time`` (the controller
time of that instant).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import NDArray

from .tool import TOOL_FIELDS

if TYPE_CHECKING:
    from .controller import Tick

__all__ = ["Recorder", "QUANTITIES"]

_T = TypeVar("_T", bound=np.generic)

#: per joint, in this order after the time column
QUANTITIES = (
    "command_position",
    "command_velocity",
    "command_acceleration",
    "actual_position",
    "actual_velocity",
    "actual_acceleration",
    "following_error",
)

#: the CSV's columns per joint (``{}`` the joint's name), in this order after ``time``: the actual
#: motion as the trajectory layout's own columns, then the rest as extras
_COLUMN = {
    "actual_position": "{}",
    "actual_velocity": "{}.velocity",
    "actual_acceleration": "{}.acceleration",
    "command_position": "{}.command_position",
    "command_velocity": "{}.command_velocity",
    "command_acceleration": "{}.command_acceleration",
    "following_error": "{}.following_error",
}
_ORDER = tuple(_COLUMN)
_TAIL = ["record.controller_time", "record.points"]
_TOOL = [f"tool.{name}" for name in TOOL_FIELDS] + ["tool.time"]


class Recorder:
    """Keeps the last ``capacity`` ticks (every ``decimation``-th tick) of a ``dof``-joint controller."""

    def __init__(self, dof: int, capacity: int = 60_000, decimation: int = 1) -> None:
        if capacity < 1 or decimation < 1 or dof < 1:
            raise ValueError("capacity, decimation and dof must be >= 1")
        self.dof = dof
        self.capacity = capacity
        self.decimation = decimation
        self._time = np.zeros(capacity)
        self._data = np.zeros((capacity, len(QUANTITIES), dof))
        self._points = np.zeros(capacity, dtype=np.int64)
        self._tool = np.full((capacity, len(_TOOL)), np.nan)
        self._count = 0  # ticks stored so far (including overwritten ones)
        self._seen = 0

    def add(self, tick: Tick) -> None:
        seen = self._seen
        self._seen = seen + 1
        if seen % self.decimation:
            return
        row = self._count % self.capacity
        self._time[row] = tick.time
        self._data[row] = (
            tick.command_position,
            tick.command_velocity,
            tick.command_acceleration,
            tick.actual_position,
            tick.actual_velocity,
            tick.actual_acceleration,
            tick.following_error,
        )
        self._points[row] = tick.points
        tool = tick.tool
        if tool is not None:
            self._tool[row, :-1] = tool.values()
            self._tool[row, -1] = tool.time
        else:
            self._tool[row] = np.nan
        self._count += 1

    def __len__(self) -> int:
        return min(self._count, self.capacity)

    @property
    def dropped(self) -> int:
        """Recorded ticks overwritten because the buffer was full."""
        return max(0, self._count - self.capacity)

    def clear(self) -> None:
        self._count = 0
        self._seen = 0

    def time(self) -> NDArray[np.float64]:
        return self._ordered(self._time)

    def points(self) -> NDArray[np.int64]:
        """Points accepted by each recorded tick, oldest first."""
        return self._ordered(self._points)

    def tool(self) -> NDArray[np.float64]:
        """``(ticks, 17)``: the TCP as of each recorded tick (:data:`~.tool.TOOL_FIELDS`, then the
        controller time of the interpolation instant it was computed at); NaN without one."""
        return self._ordered(self._tool)

    def get(self, quantity: str) -> NDArray[np.float64]:
        """``(ticks, dof)`` array of one of :data:`QUANTITIES`, oldest first."""
        return self._ordered(self._data[:, QUANTITIES.index(quantity), :])

    def _ordered(self, array: NDArray[_T]) -> NDArray[_T]:
        n = len(self)
        if self._count <= self.capacity:
            return array[:n].copy()
        start = self._count % self.capacity
        return np.concatenate([array[start:], array[:start]])

    def header(self, joint_names: Sequence[str] | None = None) -> list[str]:
        names = list(joint_names) if joint_names is not None else [f"j{i + 1}" for i in range(self.dof)]
        return ["time"] + [_COLUMN[q].format(name) for q in _ORDER for name in names] + _TAIL + _TOOL

    def to_csv(self, target: str | Path | io.TextIOBase, joint_names: Sequence[str] | None = None) -> None:
        """CSV with a header row (see the module doc)."""
        if isinstance(target, str | Path):
            with open(target, "w", newline="") as stream:
                self._write(stream, joint_names)
        else:
            self._write(target, joint_names)

    def _write(self, stream: io.TextIOBase | io.TextIOWrapper, joint_names: Sequence[str] | None) -> None:
        writer = csv.writer(stream)
        writer.writerow(self.header(joint_names))
        times = self.time()
        start = float(times[0]) if times.size else 0.0
        data = np.concatenate([self.get(q) for q in _ORDER], axis=1)
        tool = self.tool()
        for t, row, n, tcp in zip(times.tolist(), data.tolist(), self.points().tolist(), tool.tolist(), strict=True):
            writer.writerow([repr(t - start)] + [repr(x) for x in row] + [repr(t), n] + [repr(x) for x in tcp])
