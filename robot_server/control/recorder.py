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
time of that instant). A recorder given the controller's ToolMeter may be left the instants' TCPs
to compute itself, from the instant's own numbers, when they are first read (the same values).

:meth:`Recorder.save` picks the format by the file's name: ``.csv`` (any other name too) the CSV,
every value to :data:`CSV_DECIMALS` decimals of its SI unit (1 nrad, 1 nm, 1 ns) without trailing
zeros and ``record.points`` as a whole number; ``.csv.gz`` (or ``.gz``) the same CSV compressed
with gzip; ``.npz`` numpy's zip of one exact array per column (``numpy.load(path)["joint_1"]``),
compressed. The CSV's numbers are formatted a block of rows at a time by :mod:`.csvnumbers`.
"""

from __future__ import annotations

import csv
import gzip
import io
import zipfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from .csvnumbers import CSV_DECIMALS, format_rows
from .tool import TOOL_FIELDS, ToolMeter, ToolState

if TYPE_CHECKING:
    from .controller import Tick

__all__ = ["CSV_DECIMALS", "QUANTITIES", "Recorder", "record_format"]

_T = TypeVar("_T", bound=np.generic)

#: a setpoint at an interpolation instant: position, velocity and acceleration of each joint
Setpoint = tuple[Sequence[float], Sequence[float], Sequence[float]]


class DriveState(Protocol):
    """The drives' actual state (:class:`~.servo.ServoDrives`), per joint."""

    @property
    def position(self) -> Sequence[float]: ...
    @property
    def velocity(self) -> Sequence[float]: ...
    @property
    def acceleration(self) -> Sequence[float]: ...


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

    def __init__(
        self,
        dof: int,
        capacity: int = 60_000,
        decimation: int = 1,
        tool_meter: ToolMeter | None = None,
        instants: int | None = None,
    ) -> None:
        if capacity < 1 or decimation < 1 or dof < 1:
            raise ValueError("capacity, decimation and dof must be >= 1")
        self.dof = dof
        self.capacity = capacity
        self.decimation = decimation
        #: computes, when it is read, the TCP of an interpolation instant the controller left
        #: uncomputed (``add(tick, instant_until=...)``): the controller's own ToolMeter; ``instants``:
        #: how many instants the ring's ticks can refer to at most (default one per tick; a
        #: controller leaves one per interpolation period: ``capacity // ticks_per_period + 2``;
        #: default ``capacity + 1``)
        self.tool_meter = tool_meter
        if instants is not None and instants < 2:
            raise ValueError("a recorder keeps at least 2 instants")
        self._time = np.zeros(capacity)
        self._data = np.zeros((capacity, len(QUANTITIES), dof))
        self._points = np.zeros(capacity, dtype=np.int64)
        self._tool = np.full((capacity, len(_TOOL)), np.nan)
        self._count = 0  # ticks stored so far (including overwritten ones)
        self._seen = 0
        # per row of the ring: the instant whose TCP the row holds but which is not computed yet
        # (its serial), -1: _tool holds the row's TCP; the instants' numbers (time, command position
        # and velocity, actual position and velocity) by serial, in a ring long enough for every
        # instant a row refers to (``instants``); the last instant: serial, and the time
        # before which a tick without a TCP is one of its period
        self._lazy = np.full(capacity, -1, dtype=np.int64)
        self._instants = np.zeros((0 if tool_meter is None else instants or capacity + 1, 1 + 4 * dof))
        self._instant_serials = np.full(len(self._instants), -1, dtype=np.int64)  # whose numbers each slot holds
        self._instant_count = 0
        self._instant: tuple[int, float, float] | None = None  # (serial, until, the instant's time)
        # the ticks added but not yet in the arrays (:meth:`_flush`, before anything reads them):
        # their numbers (time, then the quantities) one after another, their points, their TCPs
        # (each ToolState once) and which TCP each has (-1: none); the ticks of add_between, their
        # rows, shares and periods (each period's two setpoints once, position, velocity and
        # acceleration of each, one after another)
        self._flat: list[float] = []
        self._pending_points: list[int] = []
        self._tools: list[tuple[float, ...]] = []
        self._tool_rows: list[int] = []
        self._last_tool: ToolState | None = None
        self._between: list[tuple[int, float, int]] = []
        self._ends: list[float] = []
        self._last_ends: tuple[Setpoint, Setpoint] | None = None
        self._flat_between: list[float] = []  # a tick of add_between's: time, actual position, velocity, acceleration
        self._pending_instants: list[tuple[int, int]] = []  # (pending row, serial)

    def holds_instant(self, time: float) -> bool:
        """Whether the TCP of the instant at controller time ``time`` is this recorder's to
        compute (it was left it, and has not been cleared since): a controller that left it to
        another computes it itself before this one records the ticks that hold it."""
        return self._instant is not None and self._instant[2] == time

    def takes_instants(self, meter: ToolMeter) -> bool:
        """Whether a controller measuring with ``meter`` may leave this recorder the TCPs of its
        interpolation instants (:meth:`add` with ``instant_until``): it records every tick (the
        instant's own among them) and computes with that meter."""
        return self.tool_meter is meter and self.decimation == 1

    def add(self, tick: Tick, *, instant_until: float | None = None) -> None:
        """Record a tick. ``instant_until``: the tick is an interpolation instant's whose TCP the
        controller left uncomputed (its ``tool`` None; :meth:`takes_instants`): this recorder
        computes it from the tick's numbers when it is read (the same numbers as the controller's
        ToolMeter gives), for this tick and for the ticks without a TCP until controller time
        ``instant_until`` (its period's)."""
        seen = self._seen
        if seen % self.decimation:
            self._seen = seen + 1
            return
        # the numbers go to one flat list (no object per tick outlives the call: a list of ticks
        # kept until the flush costs more in the garbage collector than the flush itself)
        _append_whole(
            self._flat,
            ((tick[0],), tick[1], tick[2], tick[3], tick[4], tick[5], tick[6], tick[7]),
            1 + len(QUANTITIES) * self.dof,
            f"a recorded tick holds {len(QUANTITIES)} sequences of {self.dof} numbers",
        )
        self._seen = seen + 1
        if instant_until is not None:
            serial = self._instant_count
            self._instant_count = serial + 1
            self._instant = (serial, instant_until, tick[0])
            self._pending_instants.append((len(self._pending_points), serial))
        self._tool_row(tick[9], tick[0])
        points = self._pending_points
        points.append(tick[8])
        if len(points) >= _BLOCK:
            self._flush()

    def add_between(
        self,
        time: float,
        share: float,
        ends: tuple[Setpoint, Setpoint],
        drives: DriveState,
        *,
        points: int,
        tool: ToolState | None,
    ) -> None:
        """Record a tick whose command is the setpoint ``share`` of the way between the two of
        ``ends`` (each ``(position, velocity, acceleration)``, the interpolation instants around
        the tick), as :meth:`~.controller.Controller.step` makes it: ``(1 - share) x first + share
        x second`` of each, the following error the position's minus the actual one; ``drives``:
        the actual position, velocity and acceleration. The same numbers as :meth:`add` of that
        tick, computed for a block of ticks at once when they are written: what a moving
        controller's recorded period costs, without making its ticks."""
        seen = self._seen
        if seen % self.decimation:
            self._seen = seen + 1
            return
        flat = self._flat_between
        before = len(flat)
        _append_whole(
            flat,
            ((time,), drives.position, drives.velocity, drives.acceleration),
            1 + 3 * self.dof,
            f"the drives' state holds 3 sequences of {self.dof} numbers",
        )
        last = self._last_ends
        if last is None or last[0] is not ends[0] or last[1] is not ends[1]:  # once per period
            try:
                _append_whole(
                    self._ends,
                    (values for setpoint in ends for values in setpoint),
                    6 * self.dof,
                    f"a setpoint holds position, velocity and acceleration of {self.dof} joints",
                )
            except ValueError:
                del flat[before:]  # the tick refused whole
                raise
            self._last_ends = ends
        self._seen = seen + 1
        pending = self._pending_points
        self._between.append((len(pending), share, len(self._ends)))
        self._tool_row(tool, time)
        pending.append(points)
        if len(pending) >= _BLOCK:
            self._flush()

    def _tool_row(self, tool: ToolState | None, time: float) -> None:
        """Which TCP a tick has: one of the block's ToolStates (>= 0), none (-1), or that of an
        instant computed when read (-2 - its serial)."""
        if tool is None:
            instant = self._instant
            self._tool_rows.append(-2 - instant[0] if instant is not None and time < instant[1] else -1)
        else:
            if tool is not self._last_tool:  # a period's ticks share their ToolState
                self._last_tool = tool
                self._tools.append((*tool.values(), tool.time))
            self._tool_rows.append(len(self._tools) - 1)

    def _flush(self) -> None:
        """Write the ticks added since the last flush into the arrays, a block at a time (several
        times faster than a row at a time)."""
        count = len(self._pending_points)
        if not count:
            return
        dof = self.dof
        between = len(self._between)
        width = 1 + len(QUANTITIES) * dof
        flat = np.fromiter(self._flat, dtype=np.float64, count=len(self._flat))
        flat_between = np.fromiter(self._flat_between, dtype=np.float64, count=len(self._flat_between))
        if flat.size != (count - between) * width or flat_between.size != between * (1 + 3 * dof):
            self._forget_pending()
            raise ValueError(f"a recorded tick does not hold {len(QUANTITIES)} quantities of {dof} joints")
        if not between:
            table = flat.reshape(count, width)
        else:
            rows, shares, ends = (np.array(column) for column in zip(*self._between, strict=True))
            table = np.empty((count, width))
            made = np.ones(count, dtype=bool)
            made[rows] = False
            table[made] = flat.reshape(-1, width)
            drives = flat_between.reshape(between, 1 + 3 * dof)
            table[rows, 0] = drives[:, 0]
            table[rows, 1 + 3 * dof : 1 + 6 * dof] = drives[:, 1:]  # actual position, velocity, acceleration
            # (1 - f) x previous + f x next, per value: what the controller computes one tick at a time
            setpoints = np.array(self._ends).reshape(-1, 2, 3, dof)[ends // (6 * dof) - 1]
            f = shares[:, None, None]
            command = (1.0 - f) * setpoints[:, 0] + f * setpoints[:, 1]  # (ticks, 3, dof)
            table[rows, 1 : 1 + 3 * dof] = command.reshape(-1, 3 * dof)  # the three command quantities
            table[rows, 1 + 6 * dof :] = command[:, 0] - table[rows, 1 + 3 * dof : 1 + 4 * dof]  # error: - actual
        if self._pending_instants:  # the numbers an instant's TCP is computed from, when read
            rows, serials = (np.array(column) for column in zip(*self._pending_instants, strict=True))
            last = len(self._instants)  # (a ring shorter than the block's instants: its newest, each slot once)
            rows, serials = rows[-last:], serials[-last:]
            self._instants[serials % last] = table[rows][:, self._instant_columns]
            self._instant_serials[serials % last] = serials
        points = self._pending_points
        tools = np.vstack([np.array(self._tools).reshape(-1, len(_TOOL)), np.full((1, len(_TOOL)), np.nan)])
        codes = np.array(self._tool_rows, dtype=np.int64)
        self._forget_pending()
        kept = min(count, self.capacity)  # a block longer than the ring: its newest ticks
        first = (self._count + count - kept) % self.capacity
        table = table[-kept:]
        codes = codes[-kept:]
        tool = tools[np.where(codes >= 0, codes, -1)]  # -1: the NaN row (no TCP, or one computed when read)
        lazy = np.where(codes <= -2, -2 - codes, -1)
        kept_points = points[-kept:]
        at = 0
        while at < kept:  # one slice of the ring, or two where it wraps
            row = (first + at) % self.capacity
            n = min(kept - at, self.capacity - row)
            self._time[row : row + n] = table[at : at + n, 0]
            self._data[row : row + n] = table[at : at + n, 1:].reshape(n, len(QUANTITIES), dof)
            self._points[row : row + n] = kept_points[at : at + n]
            self._tool[row : row + n] = tool[at : at + n]
            self._lazy[row : row + n] = lazy[at : at + n]
            at += n
        self._count += count

    def _forget_pending(self) -> None:
        self._flat = []
        self._pending_points = []
        self._tools = []
        self._tool_rows = []
        self._last_tool = None
        self._between = []
        self._ends = []
        self._last_ends = None
        self._flat_between = []
        self._pending_instants = []

    @property
    def _instant_columns(self) -> NDArray[np.intp]:
        """The columns of a flat row an instant's TCP is computed from: time, command position and
        velocity, actual position and velocity."""
        dof = self.dof
        return np.concatenate([[0], np.arange(1, 1 + 2 * dof), np.arange(1 + 3 * dof, 1 + 5 * dof)]).astype(np.intp)

    def _check_instants(self, serials: NDArray[np.int64]) -> None:
        """Every instant ``serials`` names still in the instants' ring (ValueError: too short)."""
        if serials.size and (self._instant_serials[serials % len(self._instants)] != serials).any():
            raise ValueError(
                f"this recorder's ring of {len(self._instants)} instants is too short for its {self.capacity} ticks: "
                "give instants >= capacity // ticks per interpolation period + 2"
            )

    def _resolve(self) -> None:
        """Compute the TCPs the rows hold but the controller left uncomputed, each instant once."""
        self._flush()
        rows = np.flatnonzero(self._lazy >= 0)
        if not rows.size:
            return
        meter = self.tool_meter
        assert meter is not None, "only a recorder with a tool meter takes instants"
        serials, which = np.unique(self._lazy[rows], return_inverse=True)
        self._check_instants(serials)
        dof = self.dof
        computed = np.empty((serials.size, len(_TOOL)))
        for k, serial in enumerate(serials.tolist()):
            x = self._instants[serial % len(self._instants)].tolist()  # the tick's own floats
            state = meter.measure(
                x[0], x[1 : 1 + dof], x[1 + dof : 1 + 2 * dof], x[1 + 2 * dof : 1 + 3 * dof], x[1 + 3 * dof :]
            )
            computed[k, :-1] = state.values()
            computed[k, -1] = state.time
        self._tool[rows] = computed[which]
        self._lazy[rows] = -1

    def __len__(self) -> int:
        return min(self._count + len(self._pending_points), self.capacity)

    @property
    def dropped(self) -> int:
        """Recorded ticks overwritten because the buffer was full."""
        return max(0, self._count + len(self._pending_points) - self.capacity)

    def clear(self) -> None:
        self._count = 0
        self._seen = 0
        self._forget_pending()
        self._lazy[:] = -1
        self._instant = None

    @classmethod
    def from_columns(
        cls, dof: int, columns: Mapping[str, NDArray[np.generic]], *, decimation: int = 1, dropped: int = 0
    ) -> Recorder:
        """A recorder holding ``columns`` (oldest first: ``time``, one ``(ticks, dof)`` array per
        quantity of :data:`QUANTITIES`, ``points``, ``tool``), as if it had recorded them and
        overwritten ``dropped`` older ticks."""
        ticks = len(columns["time"])
        made = cls(dof, capacity=max(1, ticks), decimation=decimation)
        if ticks:
            shift = dropped % ticks  # the oldest row where the dropped ticks would have left it
            made._time[:] = np.roll(columns["time"], shift)
            for index, quantity in enumerate(QUANTITIES):
                made._data[:, index, :] = np.roll(columns[quantity], shift, axis=0)
            made._points[:] = np.roll(columns["points"], shift)
            made._tool[:] = np.roll(columns["tool"], shift, axis=0)
        made._count = ticks + dropped
        made._seen = (ticks + dropped) * decimation
        return made

    def copy(self) -> Recorder:
        """A copy that no longer grows: the same ticks, the same ``dropped``; the TCPs not computed
        yet are computed when the copy's are read."""
        columns: dict[str, NDArray[np.generic]] = {
            "time": self.time(),
            "points": self.points(),
            "tool": self._ordered(self._tool),
        }
        for quantity in QUANTITIES:
            columns[quantity] = self.get(quantity)
        made = Recorder.from_columns(self.dof, columns, decimation=self.decimation, dropped=self.dropped)
        lazy = self._ordered(self._lazy)
        if lazy.size and (lazy >= 0).any():
            made.tool_meter = self.tool_meter
            made._lazy[:] = np.roll(lazy, self.dropped % lazy.size)  # where from_columns put the rows
            made._instants = self._instants.copy()
            made._instant_serials = self._instant_serials.copy()
            made._instant_count = self._instant_count  # (recorded into, its instants follow these)
        return made

    @classmethod
    def from_npz(cls, path: str | Path, joint_names: Sequence[str]) -> Recorder:
        """What :meth:`to_npz` wrote, as a recorder (its ``time`` the controller's clock)."""
        dof = len(joint_names)
        header = cls(dof).header(joint_names)
        with np.load(path, allow_pickle=False) as archive:
            data = {name: archive[name] for name in header}
        columns: dict[str, NDArray[np.generic]] = {}
        at = 1
        for quantity in _ORDER:  # the header's order
            names = header[at : at + dof]
            columns[quantity] = np.stack([data[n] for n in names], axis=1) if names else np.zeros((0, dof))
            at += dof
        columns["time"], columns["points"] = data[header[at]], data[header[at + 1]]
        columns["tool"] = np.stack([data[n] for n in header[at + 2 :]], axis=1)
        return cls.from_columns(dof, columns)

    def time(self) -> NDArray[np.float64]:
        return self._ordered(self._time)

    def points(self) -> NDArray[np.int64]:
        """Points accepted by each recorded tick, oldest first."""
        return self._ordered(self._points)

    def tool(self) -> NDArray[np.float64]:
        """``(ticks, 17)``: the TCP as of each recorded tick (:data:`~.tool.TOOL_FIELDS`, then the
        controller time of the interpolation instant it was computed at); NaN without one."""
        self._resolve()
        return self._ordered(self._tool)

    def tool_time(self) -> NDArray[np.float64]:
        """``tool()``'s last column alone (the controller time of the instant each tick's TCP is of;
        NaN without one), without computing the TCPs not computed yet."""
        self._flush()
        times = self._tool[:, -1].copy()
        lazy = self._lazy >= 0
        self._check_instants(self._lazy[lazy])
        times[lazy] = self._instants[self._lazy[lazy] % len(self._instants), 0]
        return self._ordered(times)

    def get(self, quantity: str) -> NDArray[np.float64]:
        """``(ticks, dof)`` array of one of :data:`QUANTITIES`, oldest first."""
        return self._ordered(self._data[:, QUANTITIES.index(quantity), :])

    def _ordered(self, array: NDArray[_T]) -> NDArray[_T]:
        self._flush()
        n = len(self)
        if self._count <= self.capacity:
            return array[:n].copy()
        start = self._count % self.capacity
        return np.concatenate([array[start:], array[:start]])

    def header(self, joint_names: Sequence[str] | None = None) -> list[str]:
        names = list(joint_names) if joint_names is not None else [f"j{i + 1}" for i in range(self.dof)]
        return ["time"] + [_COLUMN[q].format(name) for q in _ORDER for name in names] + _TAIL + _TOOL

    def save(self, path: str | Path, joint_names: Sequence[str] | None = None) -> int:
        """Write the record in the format the file's name asks for (:func:`record_format`: CSV,
        gzip-compressed CSV or ``.npz``); returns the bytes written."""
        path = Path(path)
        if record_format(path) == "npz":
            self.to_npz(path, joint_names)
        else:
            self.to_csv(path, joint_names)
        return path.stat().st_size

    def to_csv(self, target: str | Path | io.TextIOBase, joint_names: Sequence[str] | None = None) -> None:
        """CSV with a header row (see the module doc); a path ending in ``.gz`` is compressed."""
        if isinstance(target, str | Path):
            if record_format(Path(target)) == "csv.gz":
                # level 1: about a third of the CSV's size; level 6 saves another tenth of it for
                # five times the time
                with gzip.open(target, "wb", compresslevel=1) as packed:
                    self._write_csv(packed.write, joint_names)
            else:
                with open(target, "wb") as plain:
                    self._write_csv(plain.write, joint_names)
        else:
            self._write_csv(lambda chunk: target.write(chunk.decode("utf-8")), joint_names)

    def to_npz(self, path: str | Path, joint_names: Sequence[str] | None = None) -> None:
        """The record as ``.npz`` (what :func:`numpy.savez_compressed` writes, readable by
        :func:`numpy.load`): one exact array per column of the CSV, under its name; ``record.points``
        as int64."""
        header = self.header(joint_names)
        # numpy's own writer, but at deflate level 1 (savez_compressed's level 6 takes half as long
        # again for a file 2 % smaller: doubles compress little)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
            for name, column in zip(header, self._columns(), strict=True):
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, column, allow_pickle=False)

    def _columns(self) -> Iterator[NDArray[np.float64] | NDArray[np.int64]]:
        """The record's columns in the header's order, oldest first, one at a time."""
        times = self.time()
        yield times - times[0] if times.size else times
        for q in _ORDER:
            block = self.get(q)
            for joint in range(self.dof):
                yield block[:, joint].copy()
        yield times
        yield self.points()
        tool = self.tool()
        for k in range(tool.shape[1]):
            yield tool[:, k].copy()

    def _write_csv(self, write: Callable[[bytes], object], joint_names: Sequence[str] | None) -> None:
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerow(self.header(joint_names))
        write(text.getvalue().encode("utf-8"))
        self._resolve()
        n = len(self)
        if not n:
            return
        first = (self._count - n) % self.capacity  # the oldest row of the ring
        start = self._time[first]
        columns = 1 + len(_ORDER) * self.dof + len(_TAIL) + len(_TOOL)
        whole = np.zeros(columns, dtype=bool)
        whole[1 + len(_ORDER) * self.dof + 1] = True  # record.points
        block = np.empty((_CSV_ROWS, columns))
        scratch = np.empty((_CSV_ROWS, columns, 6), dtype=np.uint32)
        for begin in range(0, n, _CSV_ROWS):
            rows = (first + np.arange(begin, min(n, begin + _CSV_ROWS))) % self.capacity
            out = block[: rows.size]
            at = 1 + len(_ORDER) * self.dof
            out[:, 0] = self._time[rows] - start
            data = self._data[rows]  # (rows, quantity, joint)
            for k, q in enumerate(_ORDER):
                index = QUANTITIES.index(q)
                out[:, 1 + k * self.dof : 1 + (k + 1) * self.dof] = data[:, index, :]
            out[:, at] = self._time[rows]
            out[:, at + 1] = self._points[rows]
            out[:, at + 2 :] = self._tool[rows]
            write(format_rows(out, whole, scratch))


#: ticks a recorder collects before it writes them into its arrays at once (:meth:`Recorder._flush`)
_BLOCK = 1024


def _append_whole(flat: list[float], parts: Iterable[Iterable[float]], length: int, problem: str) -> None:
    """The numbers of ``parts`` one after another at the end of ``flat``, all of them or none: a
    part that is not a sequence of numbers, or ``length`` numbers not there, is a ValueError
    ``problem`` and ``flat`` is as it was (a malformed tick refused whole, the block's others kept)."""
    before = len(flat)
    extend = flat.extend  # (not +=: a numpy array on the right would add, not extend)
    try:
        for part in parts:
            extend(part)
    except TypeError:
        del flat[before:]
        raise ValueError(problem) from None
    if len(flat) - before != length:
        del flat[before:]
        raise ValueError(problem)


#: rows formatted at once: the work space (200 kB) stays in the processor's cache; blocks of 512 rows
#: took a fifth longer, of 32 rows longer still (numpy's overhead per call)
_CSV_ROWS = 128


def record_format(path: Path) -> str:
    """``"npz"``, ``"csv.gz"`` (a name ending in ``.gz``) or ``"csv"`` (any other name)."""
    name = path.name.lower()
    return "npz" if name.endswith(".npz") else "csv.gz" if name.endswith(".gz") else "csv"
