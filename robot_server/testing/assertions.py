"""Assertions about a recorded motion, for tests of a robot application run against the emulator.

A test drives an emulated controller, then asks of the servo ticks it recorded (a
:class:`~robot_server.control.recorder.Recorder`, with the :class:`~robot_server.model.RobotModel`
that names the joints and gives their limits): did the robot get where it should
(:func:`assert_reached`), stay inside a joint envelope (:func:`assert_within_joints`) or a box of the
cell (:func:`assert_within_box`), keep within its joints' limits (:func:`assert_within_limits`), come
to rest soon enough after a STOP (:func:`assert_stopped_within`)?

The ``source`` of each is anything with a ``record`` and a ``model`` (:class:`MotionSource`): the
handle of the pytest plugin's controller, or :class:`Recorded` around a recorder of one's own. Times
are the controller's clock (the record's ``record.controller_time``), units SI per joint (rad or m).

A failure raises :class:`MotionAssertionError` (an :class:`AssertionError`, so pytest reports it as a
failed assertion) whose message says where (the joint, or the TCP's axis), when (the controller time
of the first violation, and how long it lasted), and by how much (the value, the bound, the excess,
with units), then a short table of the motion around that moment. Given ``plot_dir`` and with
matplotlib installed (the ``plot`` extra), it also draws the offending quantity over that stretch of
time into a PNG file there, and the message names the file. The checks work on the record's arrays
at once (numpy), not tick by tick. They decide whether the motion failed and its facts; the message
and the plot are written by :mod:`.failures`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..arrays import Array
from ..control.points import Limits
from ..kinematics.rotations import rotation_to_quaternion
from ..model import JointType
from .failures import joints_off, orientation_off, out_of_bounds, position_off, table

if TYPE_CHECKING:
    from ..control.recorder import Recorder
    from ..model import RobotModel

__all__ = [
    "LimitReport",
    "MotionAssertionError",
    "MotionSource",
    "Recorded",
    "Side",
    "assert_reached",
    "assert_stopped_within",
    "assert_within_box",
    "assert_within_joints",
    "assert_within_limits",
]

#: which of the record's two motions an assertion reads: what the controller commanded, what the
#: drives did, or both
Side = Literal["actual", "command", "both"]

#: the columns of the tool in Recorder.tool(): (x, y, z, qw, qx, qy, qz, speed) per side, then time
_TOOL_OFFSET = {"command": 0, "actual": 8}
_TOOL_TIME = 16
#: controller times this close count as the same (the clock's own rounding)
_TIME_EPS = 1e-9
#: what the low and the high bound of each kind of check are called in a message
_ENVELOPE = ("the envelope's lower bound", "the envelope's upper bound")
_BOX = ("the box's lower side", "the box's upper side")
_LIMITS = ("the lower limit", "the upper limit")
_SPEEDS = ("minus the limit", "the limit")
_TOLERANCE = ("", "the tolerance")


class MotionSource(Protocol):
    """What an assertion reads: a controller's record and the model of its robot."""

    @property
    def record(self) -> Recorder: ...

    @property
    def model(self) -> RobotModel: ...


@dataclass(frozen=True)
class Recorded:
    """A :class:`MotionSource` made of a recorder of one's own (``Controller.run_for(s, recorder)``,
    ``Emulator.record``) and the model it was recorded with."""

    record: Recorder
    model: RobotModel


class MotionAssertionError(AssertionError):
    """A motion assertion failed. Besides the message, the facts it states, for a test that wants
    them: ``where`` (a joint's name, or ``"TCP x"`` ...), ``time`` (controller time of the first
    violation, s), ``duration`` (how long it lasted, s; None: to the end of the record), ``value``,
    ``bound`` and ``excess`` (in ``unit``), and ``plot`` (the PNG drawn, if one was)."""

    def __init__(
        self,
        message: str,
        *,
        where: str | None = None,
        time: float | None = None,
        duration: float | None = None,
        value: float | None = None,
        bound: float | None = None,
        excess: float | None = None,
        unit: str = "",
        plot: Path | None = None,
    ) -> None:
        super().__init__(message)
        self.where = where
        self.time = time
        self.duration = duration
        self.value = value
        self.bound = bound
        self.excess = excess
        self.unit = unit
        self.plot = plot


@dataclass(frozen=True)
class LimitReport:
    """What :func:`assert_within_limits` measured: per joint, the largest magnitude of each
    derivative (``velocity``, ``acceleration``, ``jerk``) over the ticks checked, beside the model's
    limits. The jerk is reported, not enforced: ``jerk_exceeded`` names the joints above their jerk
    limit (a rest-to-rest cubic's steps of acceleration), which do not fail the assertion."""

    joint_names: tuple[str, ...]
    units: tuple[str, ...]
    velocity: Array
    acceleration: Array
    jerk: Array
    limits: Limits
    jerk_exceeded: tuple[str, ...] = field(default=())

    def __str__(self) -> str:
        rows = [
            (
                name,
                f"{self.velocity[j]:.4g} / {self.limits.max_velocity[j]:.4g} {unit}/s",
                f"{self.acceleration[j]:.4g} / {self.limits.max_acceleration[j]:.4g} {unit}/s²",
                f"{self.jerk[j]:.4g} / {self.limits.max_jerk[j]:.4g} {unit}/s³",
            )
            for j, (name, unit) in enumerate(zip(self.joint_names, self.units, strict=True))
        ]
        return table(("joint", "peak velocity / limit", "peak acceleration / limit", "peak jerk / limit"), rows)


# -- the assertions -------------------------------------------------------------------------------


def assert_reached(
    source: MotionSource,
    joints: Sequence[float] | Mapping[str, float] | ArrayLike | None = None,
    *,
    pose: ArrayLike | None = None,
    tol: float | Sequence[float] = 1e-3,
    pose_tol: float = 1e-3,
    angle_tol: float = 1e-3,
    side: Side = "actual",
    at: float | None = None,
    settled: bool = False,
    rest_velocity: float = 1e-3,
    plot_dir: str | Path | None = None,
) -> None:
    """The robot ended at ``joints`` (one position per joint, or ``{name: position}`` for some of
    them) within ``tol`` (rad or m; one value, or one per joint given), and/or with its TCP at
    ``pose``: a position ``(x, y, z)`` (m, cell frame) within ``pose_tol`` (m, the distance), or a
    position and orientation, ``(x, y, z, qw, qx, qy, qz)`` or a 4x4 transform, also within
    ``angle_tol`` (rad) of that orientation. Tolerances are > 0.

    "Ended" is the record's last tick, or its last tick at or before the controller time ``at``.
    With ``settled``, the robot must also be at rest there: every joint slower than
    ``rest_velocity`` (rad/s or m/s). On failure the message says how far off the robot ended and
    whether (and when) it had been within tolerance before."""
    if joints is None and pose is None:
        raise TypeError("assert_reached needs joints, pose or both")
    name = "assert_reached"
    record, model = source.record, source.model
    times = record.time()
    rows = np.flatnonzero(times <= at + _TIME_EPS) if at is not None else np.arange(times.size)
    if rows.size == 0:
        when = f" at or before t = {at:.4f} s" if at is not None else ""
        raise MotionAssertionError(f"{name}: the record holds no tick{when}")
    last = int(rows[-1])
    sides = _sides(side)
    units = _units(model)
    if joints is not None:
        index, target = _joint_targets(model, joints)
        tolerance = _per_joint(tol, index.size, "tol")
        if not np.all(tolerance > 0):
            raise ValueError(f"{name}: tol must be > 0")
        for s in sides:
            positions = record.get(f"{s}_position")[: last + 1]
            _check_joints_reached(
                name,
                model,
                times[: last + 1],
                positions,
                side=s,
                index=index,
                target=target,
                tol=tolerance,
                plot_dir=plot_dir,
            )
    if pose is not None:
        position, orientation = _pose(pose)
        if not (pose_tol > 0 and angle_tol > 0):
            raise ValueError(f"{name}: pose_tol and angle_tol must be > 0")
        for s in sides:
            _check_pose_reached(
                name,
                record,
                times[last],
                side=s,
                position=position,
                orientation=orientation,
                tol=pose_tol,
                angle_tol=angle_tol,
                plot_dir=plot_dir,
            )
    if settled:
        for s in sides:
            speed = np.abs(record.get(f"{s}_velocity")[last])
            fast = np.flatnonzero(speed > rest_velocity)
            if fast.size:
                j = int(fast[np.argmax(speed[fast])])
                unit = f"{units[j]}/s"
                raise MotionAssertionError(
                    f"{name}: {model.joint_names[j]} was still moving at t = {times[last]:.4f} s ({s} speed "
                    f"{speed[j]:.4g} {unit} > rest velocity {rest_velocity:.4g} {unit}, by "
                    f"{speed[j] - rest_velocity:.4g} {unit})",
                    where=model.joint_names[j],
                    time=float(times[last]),
                    value=float(speed[j]),
                    bound=rest_velocity,
                    excess=float(speed[j] - rest_velocity),
                    unit=unit,
                )


def assert_within_joints(
    source: MotionSource,
    lower: float | Sequence[float] | ArrayLike,
    upper: float | Sequence[float] | ArrayLike,
    *,
    side: Side = "actual",
    start: float | None = None,
    end: float | None = None,
    plot_dir: str | Path | None = None,
) -> None:
    """Every tick's joint positions stayed within ``lower`` .. ``upper`` (one value for every joint,
    or one per joint; ``-inf``/``inf`` for no bound), the actual positions, the commanded ones or
    both (``side``), over the whole record or the controller times ``start`` .. ``end``."""
    name = "assert_within_joints"
    record, model = source.record, source.model
    times, keep = _window(name, record, start, end)
    low, high = _per_joint(lower, model.dof, "lower"), _per_joint(upper, model.dof, "upper")
    if np.any(low > high):
        raise ValueError(f"{name}: lower is above upper for {_names(model, np.flatnonzero(low > high))}")
    units = _units(model)
    series = [
        _Series(
            times, record.get(f"{s}_position")[keep], low, high, model.joint_names, f"{s} position", units, _ENVELOPE
        )
        for s in _sides(side)
    ]
    _check(name, series, plot_dir)


def assert_within_box(
    source: MotionSource,
    lower_xyz: Sequence[float] | ArrayLike,
    upper_xyz: Sequence[float] | ArrayLike,
    *,
    side: Side = "actual",
    start: float | None = None,
    end: float | None = None,
    plot_dir: str | Path | None = None,
) -> None:
    """The TCP stayed inside the box ``lower_xyz`` .. ``upper_xyz`` (m, cell frame; ``-inf``/``inf``
    for an open side): the actual TCP, the commanded one or both (``side``), as the controller
    computed it at each interpolation instant (the record's ``tool.*`` columns), over the whole
    record or the controller times ``start`` .. ``end``."""
    name = "assert_within_box"
    record = source.record
    low, high = _per_joint(lower_xyz, 3, "lower_xyz"), _per_joint(upper_xyz, 3, "upper_xyz")
    if np.any(low > high):
        raise ValueError(f"{name}: lower_xyz is above upper_xyz on {'xyz'[int(np.argmax(low > high))]}")
    times, tool = _instants_of_tool(name, record, start, end)
    axes = ("TCP x", "TCP y", "TCP z")
    series = [
        _Series(
            times, tool[:, _TOOL_OFFSET[s] : _TOOL_OFFSET[s] + 3], low, high, axes, f"{s} position", ("m",) * 3, _BOX
        )
        for s in _sides(side)
    ]
    _check(name, series, plot_dir)


def assert_within_limits(
    source: MotionSource,
    *,
    side: Side = "command",
    rtol: float = 1e-6,
    start: float | None = None,
    end: float | None = None,
    plot_dir: str | Path | None = None,
) -> LimitReport:
    """The motion never left the model's joint position limits, nor exceeded its velocity and
    acceleration limits (:meth:`Limits.from_model`); each bound is widened by ``rtol`` of itself
    (at least of 1), for rounding. The jerk is measured and reported (the returned
    :class:`LimitReport`, and a failure's message), never enforced.

    ``side="command"`` (the default) checks what the controller asked of the drives, as they see
    it: the commanded positions at the interpolation instants and their first, second and third
    differences (never larger than the planned derivatives' largest values, so a limit kept is
    never reported broken, while a step of velocity shows as the acceleration it asks for).
    ``"actual"`` checks the drives' own positions, velocities and accelerations, tick by tick:
    a drive's loop overshoots the planned acceleration when it catches up (about twice it at the
    start of a fast move), so that side fails often by design of the drive, not of the motion."""
    name = "assert_within_limits"
    record, model = source.record, source.model
    times, keep = _window(name, record, start, end)
    limits = Limits.from_model(model)
    units = _units(model)
    dof = model.dof
    series: list[_Series] = []
    peaks = {"velocity": np.zeros(dof), "acceleration": np.zeros(dof), "jerk": np.zeros(dof)}

    def widen(low: Array, high: Array) -> tuple[Array, Array]:
        return low - rtol * np.maximum(1.0, np.abs(low)), high + rtol * np.maximum(1.0, np.abs(high))

    for s in _sides(side):
        positions = record.get(f"{s}_position")[keep]
        if s == "command":
            instants = _instant_rows(record)[keep]
            at = times[instants] if instants.any() else times
            sampled = positions[instants] if instants.any() else positions
            period = float(np.median(np.diff(at))) if at.size > 1 else 1.0
            velocity = np.diff(sampled, axis=0) / period
            acceleration = np.diff(velocity, axis=0) / period
            jerk = np.diff(acceleration, axis=0) / period
            derivative_times = (at[1:], at[2:])
        else:
            velocity, acceleration = record.get("actual_velocity")[keep], record.get("actual_acceleration")[keep]
            tick = float(np.median(np.diff(times))) if times.size > 1 else 1.0
            jerk = np.diff(acceleration, axis=0) / tick
            derivative_times = (times, times)
        low, high = widen(limits.lower, limits.upper)
        series.append(_Series(times, positions, low, high, model.joint_names, f"{s} position", units, _LIMITS))
        for label, values, limit, t, unit in (
            ("velocity", velocity, limits.max_velocity, derivative_times[0], "/s"),
            ("acceleration", acceleration, limits.max_acceleration, derivative_times[1], "/s²"),
        ):
            low, high = widen(-limit, limit)
            per_second = tuple(u + unit for u in units)
            series.append(_Series(t, values, low, high, model.joint_names, f"{s} {label}", per_second, _SPEEDS))
            if values.size:
                peaks[label] = np.maximum(peaks[label], np.max(np.abs(values), axis=0))
        if jerk.size:
            peaks["jerk"] = np.maximum(peaks["jerk"], np.max(np.abs(jerk), axis=0))
    exceeded = tuple(model.joint_names[j] for j in np.flatnonzero(peaks["jerk"] > limits.max_jerk * (1 + rtol)))
    report = LimitReport(
        model.joint_names, units, peaks["velocity"], peaks["acceleration"], peaks["jerk"], limits, exceeded
    )
    notes = [f"jerk (reported, not enforced): above the limit on {', '.join(exceeded)}"] if exceeded else []
    if side != "actual":
        notes.append(
            "command velocity and acceleration: differences of the commanded positions at the interpolation "
            "instants (what the drives are asked for)"
        )
    _check(name, series, plot_dir, extra=[*notes, "peaks over the ticks checked:", str(report)])
    return report


def assert_stopped_within(
    source: MotionSource,
    since: float,
    ms: float,
    *,
    tol: float = 1e-3,
    side: Side = "actual",
    plot_dir: str | Path | None = None,
) -> float:
    """After controller time ``since`` (when the STOP was sent), every joint's speed was at most
    ``tol`` (rad/s or m/s) within ``ms`` milliseconds, and stayed so to the end of the record.
    ``side="actual"`` (the default) reads the drives' speeds, ``"command"`` the commanded ones.
    Returns how long the robot took to come to rest for good (s after ``since``). A record that
    ends before ``since + ms`` with the robot still moving cannot tell: that fails too."""
    name = "assert_stopped_within"
    if not (ms >= 0 and tol >= 0 and math.isfinite(ms) and math.isfinite(tol) and math.isfinite(since)):
        raise ValueError(f"{name}: since must be finite, ms and tol finite and >= 0")
    record, model = source.record, source.model
    times = record.time()
    deadline = since + ms / 1000.0
    after = times >= since - _TIME_EPS
    if not after.any():
        ends = f"ends at t = {times[-1]:.4f} s" if times.size else "is empty"
        raise MotionAssertionError(f"{name}: the record {ends}, before the stop at t = {since:.4f} s")
    if times[0] > since + _TIME_EPS:
        warnings.warn(
            f"{name}: the record starts at t = {times[0]:.4f} s, after the stop", RuntimeWarning, stacklevel=2
        )
    units = _units(model)
    speeds = [(s, np.abs(record.get(f"{s}_velocity")[after])) for s in _sides(side)]
    t = times[after]
    moving = np.zeros(t.size, dtype=bool)
    for _, speed in speeds:
        moving |= np.any(speed > tol, axis=1)
    late = np.flatnonzero(moving)
    still = bool(late.size) and late[-1] + 1 >= t.size
    if still and t[-1] < deadline - _TIME_EPS:
        raise MotionAssertionError(
            f"{name}: the record ends at t = {t[-1]:.4f} s, {(t[-1] - since) * 1000:.4g} ms after the stop at "
            f"t = {since:.4f} s, with the robot still moving: record until t = {deadline:.4f} s ({ms:g} ms after "
            "the stop) to tell whether it stopped in time",
            time=float(t[-1]),
        )
    at_rest = float(t[late[-1] + 1] - since) if late.size and not still else 0.0
    if not late.size or t[late[-1]] < deadline - _TIME_EPS:
        return at_rest
    checked = t >= deadline - _TIME_EPS
    low, high, per_second = np.full(model.dof, -np.inf), np.full(model.dof, tol), tuple(f"{u}/s" for u in units)
    series = [
        _Series(
            t[checked], speed[checked], low, high, model.joint_names, f"{s} speed", per_second, _TOLERANCE, "was still"
        )
        for s, speed in speeds
    ]
    rest = (
        "it was still moving at the end of the record"
        if still
        else f"it came to rest for good at t = {since + at_rest:.4f} s, {at_rest * 1000:.4g} ms after the stop"
    )
    context = f"the stop at t = {since:.4f} s allowed {ms:g} ms (to t = {deadline:.4f} s); {rest}"
    # the plot and the table show the whole stop, not just what is late
    _check(
        name,
        series,
        plot_dir,
        extra=[context],
        full=(t, [speed for _, speed in speeds]),
        marks=((since, "stop"), (deadline, "deadline")),
    )
    return at_rest


# -- finding the first violation ------------------------------------------------------------------


@dataclass(frozen=True)
class _Series:
    """Values over time that must stay within bounds: one column per joint or axis."""

    times: Array  # (N,)
    values: Array  # (N, k)
    low: Array  # (k,)
    high: Array  # (k,)
    where: tuple[str, ...]  # per column: the joint or the axis
    what: str  # the quantity ("actual position")
    units: tuple[str, ...]
    bound_names: tuple[str, str]  # what the low and the high bound are called
    went: str = "went"  # how the headline puts it: "joint_1 actual position went above ..."


@dataclass(frozen=True)
class _Found:
    """The first violation of a series: its column and rows, and how many there were in all."""

    column: int
    first: int
    last: int  # the last row of that excursion
    worst: int  # its row of the largest excess
    excursions: int  # over every column
    columns: tuple[int, ...]  # every column with an excursion
    largest: tuple[int, int]  # (row, column) of the largest excess of all


def _excess(series: _Series) -> Array:
    """How far each value is beyond its bounds (<= 0: within; NaN counts as within)."""
    values = series.values
    with np.errstate(invalid="ignore"):
        excess = np.maximum(values - series.high, series.low - values)
    return np.where(np.isnan(excess), -np.inf, excess)


def _first(excess: Array) -> _Found | None:
    out = excess > 0
    if not out.any():
        return None
    first = int(np.argmax(out.any(axis=1)))
    column = int(np.argmax(np.where(out[first], excess[first], -np.inf)))
    run = out[first:, column]
    back = np.flatnonzero(~run)
    last = first + (int(back[0]) - 1 if back.size else run.size - 1)
    worst = first + int(np.argmax(excess[first : last + 1, column]))
    starts = out.copy()
    starts[1:] &= ~out[:-1]
    largest = np.unravel_index(int(np.argmax(np.where(out, excess, -np.inf))), excess.shape)
    return _Found(
        column,
        first,
        last,
        worst,
        int(starts.sum()),
        tuple(int(c) for c in np.flatnonzero(out.any(axis=0))),
        (int(largest[0]), int(largest[1])),
    )


def _check(
    name: str,
    series: Sequence[_Series],
    plot_dir: str | Path | None,
    *,
    extra: Sequence[str] = (),
    full: tuple[Array, Sequence[Array]] | None = None,
    marks: Sequence[tuple[float, str]] = (),
) -> None:
    """Raise for the earliest violation of any of ``series``. ``full`` (times and values per series)
    is what to plot instead of the checked ticks; ``marks`` are times to draw as lines, with their labels."""
    found: list[tuple[float, int, _Series, _Found, Array]] = []
    for k, s in enumerate(series):
        if s.times.size == 0:
            continue
        excess = _excess(s)
        f = _first(excess)
        if f is not None:
            found.append((float(s.times[f.first]), k, s, f, excess))
    if not found:
        return
    _, k, s, f, excess = min(found, key=lambda item: (item[0], item[1]))
    c, t = f.column, s.times
    value = float(s.values[f.first, c])
    bound = float(s.high[c] if value > s.high[c] else s.low[c])
    duration = float(t[f.last + 1] - t[f.first]) if f.last + 1 < t.size else None
    others = [(other, g, other_excess) for _, j, other, g, other_excess in found if j != k]
    message, plot = out_of_bounds(
        name,
        s,
        f,
        excess,
        others,
        value=value,
        bound=bound,
        duration=duration,
        plot_dir=plot_dir,
        extra=extra,
        full=(full[0], full[1][k]) if full is not None else None,
        marks=marks,
    )
    raise MotionAssertionError(
        message,
        where=s.where[c],
        time=float(t[f.first]),
        duration=duration,
        value=value,
        bound=bound,
        excess=float(excess[f.first, c]),
        unit=s.units[c],
        plot=plot,
    )


# -- assert_reached's parts -----------------------------------------------------------------------


def _check_joints_reached(
    name: str,
    model: RobotModel,
    times: Array,
    positions: Array,
    *,
    side: str,
    index: NDArray[np.intp],
    target: Array,
    tol: Array,
    plot_dir: str | Path | None,
) -> None:
    """Fail unless the joints ``index`` ended (the last row) within ``tol`` of ``target``."""
    units = _units(model)
    error = positions[:, index] - target
    excess = np.abs(error[-1]) - tol
    if not np.any(excess > 0):
        return
    k = int(np.argmax(np.where(excess > 0, excess / tol, -np.inf)))
    j = int(index[k])
    joint, unit = model.joint_names[j], units[j]
    inside = np.all(np.abs(error) <= tol, axis=1)
    message, plot = joints_off(
        name,
        model,
        times,
        positions,
        side=side,
        index=index,
        target=target,
        tol=tol,
        units=units,
        error=error,
        excess=excess,
        k=k,
        inside=inside,
        plot_dir=plot_dir,
    )
    raise MotionAssertionError(
        message,
        where=joint,
        time=float(times[-1]),
        value=float(positions[-1, j]),
        bound=float(target[k]),
        excess=float(excess[k]),
        unit=unit,
        plot=plot,
    )


def _check_pose_reached(
    name: str,
    record: Recorder,
    at: float,
    *,
    side: str,
    position: Array,
    orientation: Array | None,
    tol: float,
    angle_tol: float,
    plot_dir: str | Path | None,
) -> None:
    times, tool = _instants_of_tool(name, record, None, at)
    o = _TOOL_OFFSET[side]
    xyz, quaternion = tool[:, o : o + 3], tool[:, o + 3 : o + 7]
    offset = xyz - position
    distance = np.linalg.norm(offset, axis=1)
    angle = _angle(quaternion, orientation) if orientation is not None else np.zeros(times.size)
    if distance[-1] > tol:
        axis = int(np.argmax(np.abs(offset[-1])))
        inside = (distance <= tol) & (angle <= angle_tol)
        message, plot = position_off(
            name,
            times,
            side=side,
            position=position,
            xyz=xyz,
            offset=offset,
            distance=distance,
            angle=angle,
            tol=tol,
            angle_tol=angle_tol,
            axis=axis,
            inside=inside,
            plot_dir=plot_dir,
        )
        raise MotionAssertionError(
            message,
            where=f"TCP {'xyz'[axis]}",
            time=float(times[-1]),
            value=float(distance[-1]),
            bound=tol,
            excess=float(distance[-1] - tol),
            unit="m",
            plot=plot,
        )
    if orientation is not None and angle[-1] > angle_tol:
        inside = (distance <= tol) & (angle <= angle_tol)
        message, plot = orientation_off(
            name,
            times,
            side=side,
            quaternion=quaternion,
            orientation=orientation,
            distance=distance,
            angle=angle,
            tol=tol,
            angle_tol=angle_tol,
            inside=inside,
            plot_dir=plot_dir,
        )
        raise MotionAssertionError(
            message,
            where="TCP orientation",
            time=float(times[-1]),
            value=float(angle[-1]),
            bound=angle_tol,
            excess=float(angle[-1] - angle_tol),
            unit="rad",
            plot=plot,
        )


def _joint_targets(
    model: RobotModel, joints: Sequence[float] | Mapping[str, float] | ArrayLike
) -> tuple[NDArray[np.intp], Array]:
    if isinstance(joints, Mapping):
        unknown = [n for n in joints if n not in model.joint_names]
        if unknown:
            known = ", ".join(model.joint_names)
            raise ValueError(f"{model.name} has no joint {', '.join(map(repr, unknown))} (its joints: {known})")
        index = np.array([model.joint_names.index(n) for n in joints], dtype=np.intp)
        return index, _finite_target(np.array(list(joints.values()), dtype=float))
    target = np.asarray(joints, dtype=float).reshape(-1)
    if target.size != model.dof:
        raise ValueError(f"joints: {target.size} values for the {model.dof} joints of {model.name}")
    return np.arange(model.dof, dtype=np.intp), _finite_target(target)


def _finite_target(target: Array) -> Array:
    """A target with a NaN would be reached by any motion (every comparison with it is false)."""
    if not np.isfinite(target).all():
        raise ValueError(f"joints: the target must be finite, not {target.tolist()}")
    return target


def _pose(pose: ArrayLike) -> tuple[Array, Array | None]:
    """A target pose as (position, unit quaternion or None)."""
    array = np.asarray(pose, dtype=float)
    if array.shape == (4, 4):
        return array[:3, 3].copy(), rotation_to_quaternion(array)
    flat = array.reshape(-1)
    if flat.size == 3:
        return flat.copy(), None
    if flat.size == 7:
        norm = float(np.linalg.norm(flat[3:]))
        if not norm > 0.0:
            raise ValueError("pose: the quaternion (qw, qx, qy, qz) is zero")
        return flat[:3].copy(), flat[3:] / norm
    raise ValueError(
        f"pose: (x, y, z), (x, y, z, qw, qx, qy, qz) or a 4x4 transform, not an array of shape {array.shape}"
    )


def _angle(quaternions: Array, target: Array) -> Array:
    """The rotation angle (rad) between each unit quaternion ``(n, 4)`` and ``target``."""
    dot = np.abs(quaternions @ target) / np.linalg.norm(quaternions, axis=1)
    return np.asarray(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)), dtype=float)


# -- reading the record ---------------------------------------------------------------------------


def _sides(side: Side) -> tuple[str, ...]:
    if side == "both":
        return ("command", "actual")
    if side not in ("actual", "command"):
        raise ValueError(f"side must be 'actual', 'command' or 'both', not {side!r}")
    return (side,)


def _units(model: RobotModel) -> tuple[str, ...]:
    return tuple("m" if joint.type == JointType.PRISMATIC else "rad" for joint in model.joints)


def _names(model: RobotModel, index: Sequence[int] | NDArray[np.intp]) -> str:
    return ", ".join(model.joint_names[int(j)] for j in index)


def _per_joint(value: float | Sequence[float] | ArrayLike, n: int, what: str) -> Array:
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(n, float(array))
    array = array.reshape(-1)
    if array.size != n:
        raise ValueError(f"{what}: one value or {n}, not {array.size}")
    if np.isnan(array).any():  # a NaN bound or tolerance would pass every motion
        raise ValueError(f"{what} has a NaN")
    return array


def _dropped(name: str, record: Recorder) -> None:
    if record.dropped:
        warnings.warn(
            f"{name}: the record dropped its {record.dropped} oldest ticks (its capacity is {record.capacity}): "
            f"only the last {len(record)} are checked",
            RuntimeWarning,
            stacklevel=4,
        )


def _window(name: str, record: Recorder, start: float | None, end: float | None) -> tuple[Array, NDArray[np.bool_]]:
    """The record's times within ``start`` .. ``end`` and which rows they are; at least one."""
    _dropped(name, record)
    times = record.time()
    keep = np.ones(times.size, dtype=bool)
    if start is not None:
        keep &= times >= start - _TIME_EPS
    if end is not None:
        keep &= times <= end + _TIME_EPS
    if not keep.any():
        raise MotionAssertionError(f"{name}: the record holds no tick{_between(start, end)}")
    return times[keep], keep


def _between(start: float | None, end: float | None) -> str:
    if start is None and end is None:
        return ""
    low, high = start if start is not None else -math.inf, end if end is not None else math.inf
    return f" between t = {low:.4f} s and t = {high:.4f} s"


def _instant_rows(record: Recorder) -> NDArray[np.bool_]:
    """The rows at interpolation instants: where the tool was computed at the tick's own time."""
    times = record.time()
    with np.errstate(invalid="ignore"):
        return np.asarray(np.abs(record.tool_time() - times) <= _TIME_EPS)


def _instants_of_tool(name: str, record: Recorder, start: float | None, end: float | None) -> tuple[Array, Array]:
    """The TCP once per interpolation instant (the tool holds between them): times and rows."""
    _dropped(name, record)
    tool = record.tool()
    at = tool[:, _TOOL_TIME]
    new = np.isfinite(at)
    new[1:] &= at[1:] != at[:-1]
    if start is not None:
        new &= at >= start - _TIME_EPS
    if end is not None:
        new &= at <= end + _TIME_EPS
    if not new.any():
        raise MotionAssertionError(f"{name}: the record holds no TCP{_between(start, end)} (no tool.* values)")
    return at[new], tool[new]
