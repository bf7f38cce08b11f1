"""Joint trajectories: time-stamped waypoints, and their CSV and JSON files.

A :class:`Trajectory` is what a planner hands over and what the driver sends: ``times`` (s, from
the start, strictly increasing, the first 0), ``positions`` (n x dof, rad or m) and, optionally,
``velocities`` and ``accelerations`` of the same shape. Units are SI.

**CSV**, the one layout the project reads and writes for joint motion (a trajectory file for
``robot-client run``, a ``robot-client record`` recording, which ``run`` replays as it is, and the
demo's waypoints): a header line naming the columns, then one point per line::

    time,<joint 1>,...,<joint N>[,<joint 1>.velocity,...][,<joint 1>.acceleration,...][,<extra>...]

``time`` first (s from the start: the first is 0, strictly increasing), then one column per joint
named by the joint (``q1``... or the model's names) with its position, then optionally
``<joint>.velocity`` and ``<joint>.acceleration`` for every joint. Any further column whose name
has a dot and is not one of those (``<joint>.effort``, ``note.source``...) is an *extra*: kept by
whoever wrote it, ignored on reading. Lines starting with ``#`` are comments.

**JSON**::

    {"joint_names": [...], "points": [{"time": 0.0, "positions": [...], "velocities": [...],
     "accelerations": [...]}, ...]}

``velocities`` and ``accelerations`` are optional, but all points must have them or none.
Every reader error is a :class:`TrajectoryError` naming the file, and the line or point.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robot_server import Array

__all__ = ["Trajectory", "TrajectoryError", "recording"]


class TrajectoryError(ValueError):
    """A trajectory that cannot be used: malformed file, non-increasing times, wrong shapes..."""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Time-stamped joint waypoints (see the module doc)."""

    times: Array
    positions: Array
    velocities: Array | None = None
    accelerations: Array | None = None
    joint_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float).reshape(-1)
        positions = np.atleast_2d(np.asarray(self.positions, dtype=float))
        n = times.size
        if n == 0:
            raise TrajectoryError("a trajectory needs at least one point")
        if positions.shape[0] != n:
            raise TrajectoryError(f"{n} times but {positions.shape[0]} positions")
        dof = positions.shape[1]
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "positions", positions)
        for name in ("velocities", "accelerations"):
            value = getattr(self, name)
            if value is not None:
                array = np.atleast_2d(np.asarray(value, dtype=float))
                if array.shape != positions.shape:
                    raise TrajectoryError(f"{name} have shape {array.shape}, positions {positions.shape}")
                object.__setattr__(self, name, array)
        for name in ("times", "positions", "velocities", "accelerations"):
            value = getattr(self, name)
            if value is not None and not np.all(np.isfinite(value)):
                raise TrajectoryError(f"{name} contain NaN or infinity")
        if abs(times[0]) > 1e-12:
            raise TrajectoryError(f"the first point's time must be 0, not {times[0]}")
        if n > 1 and not np.all(np.diff(times) > 0.0):
            k = int(np.argmax(np.diff(times) <= 0.0)) + 1
            raise TrajectoryError(f"times must increase: point {k} at {times[k]} s follows {times[k - 1]} s")
        names = tuple(self.joint_names) or tuple(f"q{i + 1}" for i in range(dof))
        if len(names) != dof or len(set(names)) != dof:
            raise TrajectoryError(f"{len(names)} joint names for {dof} joints (names must be distinct)")
        object.__setattr__(self, "joint_names", names)

    @property
    def dof(self) -> int:
        return int(self.positions.shape[1])

    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def for_joints(self, names: Sequence[str]) -> Trajectory:
        """This trajectory for a robot whose joints are ``names``, in that order: its columns taken
        by name when it names them (in any order), by position when they are the defaults ``q1``...
        Raises :class:`TrajectoryError` when the count differs or a name is not one of ``names``."""
        defaults = tuple(f"q{j + 1}" for j in range(self.dof))
        if self.dof != len(names):
            raise TrajectoryError(f"the trajectory has {self.dof} joints, the robot {len(names)} ({', '.join(names)})")
        if self.joint_names == defaults or tuple(self.joint_names) == tuple(names):
            return self
        unknown = [n for n in self.joint_names if n not in names]
        if unknown:
            raise TrajectoryError(
                f"the trajectory names joints the robot does not have: {', '.join(unknown)} (its joints: "
                f"{', '.join(names)}; or q1...q{len(names)} for the robot's order)"
            )
        order = [self.joint_names.index(n) for n in names]

        def pick(values: Array | None) -> Array | None:
            return None if values is None else values[:, order]

        return Trajectory(
            self.times, self.positions[:, order], pick(self.velocities), pick(self.accelerations), tuple(names)
        )

    # -- files -------------------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        """Read a ``.csv`` or ``.json`` file."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise TrajectoryError(f"{path}: {exc.strerror or exc}") from None
        except UnicodeDecodeError as exc:
            raise TrajectoryError(f"{path}: not a text file in UTF-8 (byte {exc.start})") from None
        try:
            if path.suffix.lower() == ".json":
                return cls._from_json(text)
            return cls._from_csv(text)
        except TrajectoryError as exc:
            raise TrajectoryError(f"{path}: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write a ``.csv`` or ``.json`` file (by its suffix)."""
        path = Path(path)
        path.write_text(self.to_json() if path.suffix.lower() == ".json" else self.to_csv(), encoding="utf-8")

    def to_csv(self) -> str:
        header = ["time", *self.joint_names]
        columns = [self.times[:, None], self.positions]
        if self.velocities is not None:
            header += [f"{n}.velocity" for n in self.joint_names]
            columns.append(self.velocities)
        if self.accelerations is not None:
            header += [f"{n}.acceleration" for n in self.joint_names]
            columns.append(self.accelerations)
        rows = np.hstack(columns)
        lines = [",".join(header)] + [",".join(repr(float(x)) for x in row) for row in rows]
        return "\n".join(lines) + "\n"

    def to_json(self) -> str:
        points: list[dict[str, Any]] = []
        for k in range(len(self)):
            point: dict[str, Any] = {"time": float(self.times[k]), "positions": self.positions[k].tolist()}
            if self.velocities is not None:
                point["velocities"] = self.velocities[k].tolist()
            if self.accelerations is not None:
                point["accelerations"] = self.accelerations[k].tolist()
            points.append(point)
        return json.dumps({"joint_names": list(self.joint_names), "points": points}, indent=1) + "\n"

    @classmethod
    def _from_csv(cls, text: str) -> Trajectory:
        lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip() and not line.startswith("#")]
        if not lines:
            raise TrajectoryError("empty file")
        header = next(csv.reader([lines[0][1]]))
        header = [h.strip() for h in header]
        if not header or header[0] != "time":
            raise TrajectoryError(f"line {lines[0][0]}: the first column must be 'time', not {header[:1]}")
        names = [h for h in header[1:] if "." not in h]
        velocity = [f"{n}.velocity" for n in names]
        acceleration = [f"{n}.acceleration" for n in names]
        has_v = bool(names) and all(v in header for v in velocity)
        has_a = bool(names) and all(a in header for a in acceleration)
        known = {"time", *names, *velocity, *acceleration}
        if not names or header[: 1 + len(names)] != ["time", *names] or len(set(header)) != len(header):
            raise TrajectoryError(
                f"line {lines[0][0]}: columns must be time, the joints, then optionally <joint>.velocity "
                "and <joint>.acceleration for every joint, and extra columns named with a dot"
            )
        partial = [h for h in header if h in known and h not in ("time", *names)]
        if (any(h.endswith(".velocity") for h in partial) and not has_v) or (
            any(h.endswith(".acceleration") for h in partial) and not has_a
        ):
            raise TrajectoryError(f"line {lines[0][0]}: velocities or accelerations are given for some joints only")
        stray = [h for h in header if h.endswith((".velocity", ".acceleration")) and h not in known]
        if stray:
            raise TrajectoryError(f"line {lines[0][0]}: columns {stray} name no joint column")
        take = [
            header.index(h) for h in ("time", *names, *(velocity if has_v else []), *(acceleration if has_a else []))
        ]
        rows = []
        for number, line in lines[1:]:
            cells = next(csv.reader([line]))
            if len(cells) != len(header):
                raise TrajectoryError(f"line {number}: {len(cells)} values, the header has {len(header)}")
            try:
                rows.append([float(cells[i]) for i in take])
            except ValueError:
                raise TrajectoryError(f"line {number}: not a number in {line.strip()!r}") from None
        if not rows:
            raise TrajectoryError("no waypoints")
        data = np.array(rows)
        n = len(names)
        return cls(
            data[:, 0],
            data[:, 1 : 1 + n],
            data[:, 1 + n : 1 + 2 * n] if has_v else None,
            data[:, 1 + n * (2 if has_v else 1) :] if has_a else None,
            tuple(names),
        )

    @classmethod
    def _from_json(cls, text: str) -> Trajectory:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise TrajectoryError(f"not valid JSON: {exc}") from None
        if not isinstance(data, dict) or not isinstance(data.get("points"), list) or not data["points"]:
            raise TrajectoryError('expected {"points": [...]} with at least one point')
        points = data["points"]
        fields: dict[str, list[Any]] = {"time": [], "positions": [], "velocities": [], "accelerations": []}
        for k, point in enumerate(points):
            if not isinstance(point, dict) or "time" not in point or "positions" not in point:
                raise TrajectoryError(f"point {k}: needs 'time' and 'positions'")
            for key, values in fields.items():
                if key in point:
                    values.append(point[key])
        for key in ("velocities", "accelerations"):
            if fields[key] and len(fields[key]) != len(points):
                raise TrajectoryError(f"{key} are given for some points but not all")
        try:
            times = np.array(fields["time"], dtype=float)
            positions = np.array(fields["positions"], dtype=float)
            velocities = np.array(fields["velocities"], dtype=float) if fields["velocities"] else None
            accelerations = np.array(fields["accelerations"], dtype=float) if fields["accelerations"] else None
        except (TypeError, ValueError):
            raise TrajectoryError("times and joint values must be numbers, every point with as many joints") from None
        names = data.get("joint_names") or ()
        if not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
            raise TrajectoryError("joint_names must be a list of strings")
        return cls(times, positions, velocities, accelerations, tuple(names))


def recording(
    times: Sequence[float],
    positions: Sequence[Sequence[float]],
    velocities: Sequence[Sequence[float] | None] | None = None,
    joint_names: Sequence[str] = (),
    stamps: Sequence[float | None] | None = None,
) -> Trajectory:
    """Joint states as received (``time.monotonic()`` stamps) of a controller that publishes them
    periodically (every ROS-Industrial controller does), as a :class:`Trajectory` in the one CSV
    layout, velocities kept when every state has them; ``robot-client run`` replays its file.

    Where the controller says when each state was sampled (``stamps``, its own clock: the
    emulator's JOINT_FEEDBACK time), those times are the trajectory's: a controller publishes at
    its servo ticks nearest its state period (a 25 ms period on 4 ms ticks is 24, 24, 28... ms),
    and positions put on an even grid instead read as accelerations that alternate in sign, beyond
    the limits the robot was recorded within. A state stamped no later than the one before it
    (the same sample sent again) is left out, and so are unstamped states before the first stamped
    one (sent before the controller took the request for stamps).

    Receipt times are not send times: a busy client reads a late state together with the next one,
    microseconds apart, which would make a segment no controller runs. So each state gets a slot of
    the publishing period P (the span over the count): a state received at t was sent in the last
    period before it, slot ``ceil(t / P - 1)``, and at least one slot after the state before it
    (a state received more than a period late pushes the ones after it by a slot). Where every state
    carries velocities (MotoROS's JOINT_FEEDBACK) the moving segments are then timed by them
    (:func:`_timed_by_velocity`). Times from 0."""
    if not times:
        raise TrajectoryError("no joint state was recorded")
    stamped = [k for k, x in enumerate(stamps or ()) if x is not None]
    if stamps is not None and len(stamps) == len(times) and stamped and stamped == list(range(stamped[0], len(stamps))):
        # the states before the first stamped one came before the controller took the request
        # for stamps (a round or two): the recording starts at the first stamped state
        clock = [float(x) if x is not None else float("nan") for x in stamps]
        first = stamped[0]
        keep = [first]
        for k in range(first + 1, len(clock)):
            if clock[k] > clock[keep[-1]]:
                keep.append(k)
        with_velocity = velocities is not None and all(velocities[k] is not None for k in keep)
        return Trajectory(
            np.array([clock[k] - clock[first] for k in keep], dtype=float),
            np.array([positions[k] for k in keep], dtype=float),
            np.array([velocities[k] for k in keep], dtype=float) if with_velocity and velocities is not None else None,
            joint_names=tuple(joint_names),
        )
    keep = list(range(len(times)))
    arrived = np.array(times, dtype=float)
    t = arrived - arrived[0]
    if len(t) > 1 and t[-1] > 0.0:
        period = float(t[-1]) / (len(t) - 1)
        slots = np.maximum(np.ceil(t / period - 1.0), 0.0)
        slots[0] = 0.0
        for k in range(1, slots.size):
            slots[k] = max(slots[k], slots[k - 1] + 1.0)
        t = slots * period
    elif len(t) > 1:  # every state at one instant: one state
        keep, t = [len(t) - 1], np.zeros(1)
    with_velocity = velocities is not None and all(velocities[k] is not None for k in keep)
    q = np.array([positions[k] for k in keep], dtype=float)
    v = np.array([velocities[k] for k in keep], dtype=float) if with_velocity and velocities is not None else None
    if v is not None and len(t) > 2:
        t = _timed_by_velocity(t, q, v)
    return Trajectory(t, q, v, joint_names=tuple(joint_names))


#: a segment is re-timed from its velocities when its joint's mean speed is at least this share of
#: the recording's top speed (slower, the ratio of two small numbers is noise; positions are float32,
#: 6e-8 rad apart near 1 rad, and 1 % of a 3 rad/s joint covers 7.5e-4 rad in 25 ms) ...
_RETIME_SPEED = 0.01
#: ... and the time found is within these multiples of the publishing period (else: the slot's). A
#: controller that samples on its servo ticks and publishes on a timer has intervals of 12 to 36 ms
#: for a 25 ms period (measured on the emulator: a round that came late is followed by one 12 ms
#: after it); the ends of a motion, slow but braking hardest, are where a slot's time costs most
_RETIME_RANGE = (0.2, 4.0)


def _timed_by_velocity(t: Array, q: Array, v: Array) -> Array:
    """Sample times made consistent with the velocities a controller sends with each state (MotoROS's
    JOINT_FEEDBACK, without a time): a moving segment takes the distance a joint covers over that
    joint's mean speed at its two ends, where receipt times (even on a grid of the publishing period)
    jitter by a servo tick or more. That is exact at a constant acceleration, but a drive's measured
    speed is a difference over its last servo period, half a period late: for a joint speeding up or
    slowing down the quotient is off by that lag times its change of speed over its mean speed (a
    joint braking at 10 rad/s^2 from 1.3 rad/s: 1 ms of 28). So the segment is timed by the joint whose
    speed changes least for its mean speed, among those moving (one cruising is exact). Slow and
    standing segments keep their slots."""
    h = np.diff(t)
    period = float(np.median(h))
    dq = np.diff(q, axis=0)
    top = float(np.max(np.abs(v)))
    if top <= 0.0:
        return t
    mean = 0.5 * (v[:-1] + v[1:]) * np.sign(dq)  # > 0: moving the way it went
    moving = mean >= _RETIME_SPEED * top
    with np.errstate(divide="ignore", invalid="ignore"):
        change = np.where(moving, np.abs(np.diff(v, axis=0)) / mean, np.inf)
    joint = np.argmin(change, axis=1)
    rows = np.arange(dq.shape[0])
    chosen = mean[rows, joint]
    with np.errstate(divide="ignore", invalid="ignore"):
        estimate = np.where(moving[rows, joint], np.abs(dq[rows, joint]) / chosen, np.inf)
    usable = moving[rows, joint] & (estimate >= _RETIME_RANGE[0] * period)
    usable &= estimate <= _RETIME_RANGE[1] * period
    h = np.where(usable, estimate, h)
    return np.concatenate([[0.0], np.cumsum(h)])
