"""The paper's experiment (its Fig. 6): the flange traces the edges of a rectangle, planned as
sparse Cartesian waypoints, executed under each interpolation policy of the controller, and, for
comparison, run by the controller itself as four straight lines.

:func:`run_demo` plans the rectangle with :class:`~.planner.Planner` (straight lines through the
corners, one waypoint every ``spacing`` metres, on one IK branch), then for each policy (``linear``
= not interpolated, ``cubic``, ``quintic``, ``ruckig``) runs an embedded emulator with that policy
on free loopback ports, drives the robot to the first corner with a joint move, and sends the
rectangle's waypoints as JOINT_TRAJ_PT (streamed; downloaded on a simulated clock, where a stream
would run dry between points). The emulator records every servo tick of the rectangle, and
:func:`analyse` turns that record into one table row.

**The "controller MOVL" row** (``DemoConfig.movl``, on by default): after the same joint move to
the first corner, an embedded emulator (its default policy: lines do not go through it) runs the
rectangle as four CARTESIAN_LINE requests (this project's extension, docs/protocol.md), one per
edge, blend radius 0 (an exact stop at each corner), at the TCP speed ``DemoConfig.speed``
(0.06 m/s). That is the speed the planned rows are timed at: the planner's ``max_speed``, which
every edge reaches at 0.5 m/s² and cruises at, so the waypoints are 25 mm / 0.06 m/s apart in time.
(Between two waypoints the policies that join them at rest go faster and slower around that
mean, the quintic up to 1.875 times it; the linear policy holds it.) With the same nominal speed
the cycle times compare. The controller accelerates along a line within its own limits (2 m/s²
and 20 m/s³ on the emulator, ``robot_server.control.cartesian.LineLimits``), not the planner's
0.5 m/s². The row comes from the emulator's record, like the others.

If a controller already answers on the given ports, the rectangle runs there once instead (its
interpolation is its own business) and the row is computed from the joint states it publishes;
the MOVL row then runs there too if the controller has straight lines
(:meth:`~.driver.RobotDriver.supports_lines`), and is skipped, with a line saying so, if not.
The options that only choose how the embedded emulator runs (``simulated``, ``speedup``,
``policies`` other than the paper's) are then not used: a line names those given
(:func:`embedded_only`) and says that ``--embedded`` runs them.

**The table** (all from the controller's record, or from the published joint states):

* cycle time: from the first commanded motion until the robot is at the last corner for good
  (every joint within 1 mrad of it from then on);
* peak joint acceleration and jerk: finite differences of the commanded positions at the
  interpolation instants (what the drives are asked to do, including a step's impulse);
* acceleration discontinuities: events where some joint's acceleration changes, between two
  interpolation instants, by more than its jerk limit allows in that time;
* path deviation: the largest distance of the actual flange (forward kinematics of the actual
  joint positions) from the rectangle's edges, in mm;
* corner error: the largest, over the rectangle's four corners, of the distance from the corner
  to the closest point of the actual flange's path (the polyline through its positions at the
  instants the other columns use), in mm: how far the robot cut (or missed) a corner;
* following error: the largest command - actual joint difference, in mrad.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import logging
import math
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from robot_server import Array, Recorder
from robot_server.control import DEFAULT_POLICY
from robot_server.kinematics import closed_form, fk, fk_batch, rotation_to_quaternion
from robot_server.loader import load_model
from robot_server.model import RobotModel
from simple_message.connection import Tap
from simple_message.wire import DEFAULT_FORMAT, WireFormat

from .driver import DriverError, LineGoal, Mode, RobotDriver
from .identity import check_model
from .planner import Motion, Planner, PlanningError, pose
from .trajectory import Trajectory, recording

__all__ = [
    "DemoConfig",
    "DemoRow",
    "DemoResult",
    "analyse",
    "corner_error",
    "embedded_only",
    "plan_rectangle",
    "run_demo",
    "format_table",
    "MOVL",
]

log = logging.getLogger(__name__)

#: where the rectangle's centre is: the flange pose at this configuration of the paper's robot (a
#: tilted tool, well away from the wrist, shoulder and elbow singularities)
CENTRE_CONFIGURATION = (0.0, 0.3, -0.2, 0.0, 0.9, 0.0)
#: "arrived" for the cycle time: every joint this close to the goal (rad) from then on
SETTLED_POSITION = 1e-3
#: the policies of the paper's table: its rest-to-rest shapes and ruckig
PAPER_POLICIES = ("linear", "cubic", "quintic", "ruckig")
#: the row of the rectangle run as the controller's own straight lines
MOVL = "controller MOVL"


@dataclass(frozen=True)
class DemoConfig:
    """What the demo does (SI units)."""

    model: str = "jibot_zxs"
    width: float = 0.16  # m, along the base y axis
    height: float = 0.10  # m, along the base x axis
    speed: float = 0.06  # m/s, the flange's top speed along an edge
    acceleration: float = 0.5  # m/s^2
    spacing: float = 0.025  # m between sparse waypoints
    #: the controller's interpolation policies to compare (the paper's shapes and ruckig; add
    #: "blend" to see the emulator's default)
    policies: tuple[str, ...] = PAPER_POLICIES
    output: Path = Path("demo-output")
    #: embedded emulator: a simulated clock (as fast as possible) instead of real time
    simulated: bool = False
    speedup: float = 1.0
    #: an external controller to try first (None: always the embedded emulator)
    host: str | None = "127.0.0.1"
    motion_port: int | None = None
    state_port: int | None = None
    #: the controller family (a :mod:`simple_message.dialects` name)
    profile: str = "generic"
    wire: WireFormat = DEFAULT_FORMAT
    plot: bool = True
    #: also run the rectangle as four straight lines of the controller (the "controller MOVL" row)
    movl: bool = True
    #: sees every connection's traffic (robot-client demo --capture: a CaptureWriter)
    tap: Tap | None = None
    #: compare the model with the one a running controller says it drives (robot-client demo
    #: --no-model-check turns it off)
    model_check: bool = True


@dataclass(frozen=True)
class DemoRow:
    policy: str
    cycle_time: float  # s
    peak_acceleration: float  # rad/s^2
    peak_jerk: float  # rad/s^3
    discontinuities: int
    path_deviation: float  # m
    corner_error: float  # m
    following_error: float | None  # rad (None: not known from joint states alone)
    source: str  # "controller record" or "joint states"


@dataclass
class DemoResult:
    rows: list[DemoRow]
    waypoints: Trajectory
    files: list[Path] = field(default_factory=list)
    figure: Path | None = None
    external: str | None = None  # the controller used, if not the embedded emulator
    #: why there is no figure, when one was asked for
    no_figure: str | None = None


# -- planning ----------------------------------------------------------------------------------------


def rectangle_corners(model: RobotModel, width: float, height: float) -> tuple[Array, Array]:
    """The rectangle's five corners (back to the first) and the tool orientation."""
    centre = fk(model, CENTRE_CONFIGURATION)
    c = centre[:3, 3]
    offsets = np.array(
        [
            (-height / 2, -width / 2, 0),
            (height / 2, -width / 2, 0),
            (height / 2, width / 2, 0),
            (-height / 2, width / 2, 0),
        ]
    )
    corners = c + np.vstack([offsets, offsets[:1]])
    return corners, centre[:3, :3]


def plan_rectangle(model: RobotModel, config: DemoConfig) -> tuple[Array, Motion, Array]:
    """Start configuration (first corner), the planned rectangle, and its corners."""
    ik = closed_form(model)
    if ik is None:
        raise PlanningError(f"the demo needs a model with closed-form IK; {model.name} has none")
    corners, rotation = rectangle_corners(model, config.width, config.height)
    first = ik.solve(pose(corners[0], rotation), CENTRE_CONFIGURATION)
    if first is None:
        raise PlanningError(f"{model.name} cannot reach the rectangle's first corner")
    planner = _planner(model, config)
    motion = planner.linear_moves(first.q, [pose(p, rotation) for p in corners[1:]])
    return np.array(first.q), motion, corners


def _planner(model: RobotModel, config: DemoConfig) -> Planner:
    # a joint move is one segment; the scales leave room for a rest-to-rest quintic (peak speed
    # 1.875 x the mean) over the time a jerk-limited profile takes
    return Planner(
        model,
        velocity_scale=0.3,
        acceleration_scale=0.3,
        jerk_scale=0.3,
        max_speed=config.speed,
        max_acceleration=config.acceleration,
        waypoint_spacing=config.spacing,
        joint_spacing=2 * math.pi,
    )


# -- analysis ----------------------------------------------------------------------------------------


def distance_to_path(points: Array, corners: Array) -> Array:
    """Distance of each point ``(N, 3)`` from the polyline through ``corners``."""
    a, b = corners[:-1], corners[1:]
    d = b - a
    best = np.full(points.shape[0], np.inf)
    for k in range(a.shape[0]):
        rel = points - a[k]
        u = np.clip(rel @ d[k] / float(d[k] @ d[k]), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(rel - u[:, None] * d[k], axis=1))
    return best


def corner_error(path: Array, corners: Array) -> float:
    """The largest, over ``corners`` ``(M, 3)`` (a closed polyline's last corner, the first again,
    counted once), of the distance from the corner to the closest point of the polyline through
    ``path`` ``(N, 3)``."""
    targets = corners[:-1] if corners.shape[0] > 1 and np.allclose(corners[0], corners[-1]) else corners
    if path.shape[0] == 1:
        return float(np.max(np.linalg.norm(targets - path[0], axis=1)))
    a, d = path[:-1], np.diff(path, axis=0)
    length = np.einsum("ij,ij->i", d, d)
    worst = 0.0
    for corner in targets:
        rel = corner - a
        u = np.clip(np.einsum("ij,ij->i", rel, d) / np.where(length > 0, length, 1.0), 0.0, 1.0)
        worst = max(worst, float(np.min(np.linalg.norm(rel - u[:, None] * d, axis=1))))
    return worst


def drive_differences(command: Array, dt: float) -> tuple[Array, Array, Array]:
    """The drive's view of a commanded motion, the one definition the demo's table, traces and
    figure share: velocity, acceleration and jerk as the first, second and third differences of
    the commanded positions ``(N, dof)`` sampled every ``dt`` (the controller's interpolation
    period), divided by ``dt``, ``dt²``, ``dt³``: ``N - 1``, ``N - 2`` and ``N - 3`` rows."""
    velocity = np.diff(command, axis=0) / dt
    acceleration = np.diff(velocity, axis=0) / dt
    jerk = np.diff(acceleration, axis=0) / dt
    return velocity, acceleration, jerk


#: what the table's columns mean (printed under it)
GLOSSARY = (
    "cycle time: from the last command sample before the motion starts to the first at which the robot stays "
    "settled at the goal",
    "peak acc, peak jerk: the largest magnitude over all joints of the second and third differences of the "
    "commanded positions at the interpolation instants (every 4 ms), divided by 4 ms squared and cubed: what the "
    "drives receive (the traces' <joint>.drive_acceleration column and the figure plot the same)",
    "acc discontinuities: runs of interpolation instants where that acceleration changes by more than the joint's "
    "jerk limit allows in one period",
    "path deviation: the largest distance of the actual flange position from the rectangle's edges",
    "corner error: the largest, over the rectangle's corners, of the distance from the corner to the closest point "
    "of the actual flange's path",
    "following error: the largest |command - actual| joint position at any servo tick",
    f"{MOVL}: the rectangle run by the controller as four straight lines (CARTESIAN_LINE), exact stops at the "
    "corners, at the TCP speed the waypoints of the other rows are timed at",
    "controller's own (an external controller, not the embedded emulator): the same formulas on the joint states "
    "it publishes (about 40 Hz), taken as both command and actual; no following error",
)


def analyse(
    policy: str,
    model: RobotModel,
    corners: Array,
    *,
    times: Array,
    command: Array,
    actual: Array,
    following_error: Array | None,
    source: str = "controller record",
) -> DemoRow:
    """One table row from a record: ``times`` (s) at a constant period, ``command`` and ``actual``
    joint positions ``(N, dof)`` (the command at the controller's interpolation instants)."""
    if times.size < 4:
        raise ValueError("the record is too short to analyse")
    dt = float(np.median(np.diff(times)))
    goal = command[-1]
    start = times[_motion_start(command)]
    unsettled = np.max(np.abs(actual - goal), axis=1) > SETTLED_POSITION
    late = np.flatnonzero(unsettled)
    end = times[min(late[-1] + 1, times.size - 1)] if late.size else times[0]
    _, acceleration, jerk = drive_differences(command, dt)
    jumps = np.any(np.abs(np.diff(acceleration, axis=0)) > model.max_jerk * dt * (1 + 1e-6), axis=1)
    # one discontinuity is a run of consecutive jumps (an impulse shows up as two)
    events = int(np.count_nonzero(jumps[1:] & ~jumps[:-1]) + (1 if jumps.size and jumps[0] else 0))
    flange = fk_batch(model, actual)[:, :3, 3]
    return DemoRow(
        policy=policy,
        cycle_time=float(end - start),
        peak_acceleration=float(np.max(np.abs(acceleration))),
        peak_jerk=float(np.max(np.abs(jerk))) if jerk.size else 0.0,
        discontinuities=events,
        path_deviation=float(np.max(distance_to_path(flange, corners))),
        corner_error=corner_error(flange, corners),
        following_error=None if following_error is None else float(np.max(np.abs(following_error))),
        source=source,
    )


def _motion_start(command: Array) -> int:
    """Index of the last sample before the command first moves (0 if it never does)."""
    moved = np.flatnonzero(np.max(np.abs(command - command[0]), axis=1) > 1e-9)
    return max(0, int(moved[0]) - 1) if moved.size else 0


def _interpolation_rows(record: Recorder, servo_period: float, ticks_per_interpolation: int) -> NDArray[np.bool_]:
    index = np.rint(record.time() / servo_period).astype(np.int64)
    rows: NDArray[np.bool_] = index % ticks_per_interpolation == 0
    return rows


def format_table(rows: Sequence[DemoRow]) -> str:
    """The table as aligned text."""
    header = (
        "policy",
        "cycle time (s)",
        "peak acc (rad/s²)",
        "peak jerk (rad/s³)",
        "acc discontinuities",
        "path deviation (mm)",
        "corner error (mm)",
        "following error (mrad)",
    )
    lines = [
        (
            r.policy,
            f"{r.cycle_time:.3f}",
            f"{r.peak_acceleration:.2f}",
            f"{r.peak_jerk:.1f}",
            str(r.discontinuities),
            f"{r.path_deviation * 1000:.3f}",
            f"{r.corner_error * 1000:.3f}",
            "n/a" if r.following_error is None else f"{r.following_error * 1000:.3f}",
        )
        for r in rows
    ]
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]
    out = ["  ".join(h.rjust(w) if i else h.ljust(w) for i, (h, w) in enumerate(zip(header, widths, strict=True)))]
    out += [
        "  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(line, widths, strict=True)))
        for line in lines
    ]
    out += ["", *(f"* {entry}" for entry in GLOSSARY)]
    return "\n".join(out)


# -- running -----------------------------------------------------------------------------------------


async def _approach(driver: RobotDriver, planner: Planner, start: Array, mode: Mode) -> None:
    state = await driver.wait_state()
    here = np.clip(state.positions, planner.model.lower, planner.model.upper)
    if float(np.max(np.abs(here - start))) <= 1e-4:
        return
    # one segment: the controller joins points rest to rest, so a joint move's intermediate
    # points would only make it stop and go
    await driver.execute(planner.joint_move(here, start).sparse(rest_to_rest=True), mode)


@dataclass(frozen=True)
class _Plan:
    model: RobotModel
    start: Array  # the first corner's configuration
    waypoints: Trajectory
    corners: Array
    rotation: Array  # the tool's orientation all along

    def lines(self) -> list[LineGoal]:
        """The rectangle as straight lines of the controller: to each corner after the first."""
        orientation = rotation_to_quaternion(self.rotation)
        return [LineGoal(corner, orientation) for corner in self.corners[1:]]


async def _embedded_run(config: DemoConfig, plan: _Plan, policy: str | None) -> tuple[DemoRow, Recorder, int]:
    """One row on an embedded emulator: the waypoints under ``policy``, or (None) the rectangle as
    the controller's straight lines (its default policy)."""
    from robot_server import Emulator, EmulatorConfig  # the emulator is loaded when a demo needs it

    model, waypoints = plan.model, plan.waypoints
    emulator_config = EmulatorConfig(
        models=(config.model,),
        motion_port=0,
        state_port=0,
        simulated=config.simulated,
        speedup=config.speedup,
        state_rate=100.0,
        interpolation=DEFAULT_POLICY if policy is None else policy,
    )
    mode = Mode.DOWNLOAD if config.simulated else Mode.STREAM
    async with Emulator(emulator_config, [model]) as emu:
        driver = RobotDriver(
            "127.0.0.1",
            emu.ports["motion"],
            emu.ports["state"],
            model=model,
            goal_tolerance=SETTLED_POSITION,
            watchdog=2.0,
            tcp_tolerance=1e-4,
            tap=config.tap,
        )
        async with driver:
            await _approach(driver, _planner(model, config), plan.start, mode)
            [record] = emu.record(waypoints.duration + 30.0)
            try:
                if policy is None:
                    await driver.move_lines(plan.lines(), speed=config.speed)
                else:
                    await driver.execute(waypoints, mode)
                # let the record reach the settled robot (the goal is seen a state period late at most)
                await emu.settle(10.0)
            finally:
                emu.stop_recording()
    servo = emulator_config.servo_period
    ticks = round(emulator_config.interpolation_period / servo)
    rows = _interpolation_rows(record, servo, ticks)
    row = analyse(
        MOVL if policy is None else policy,
        plan.model,
        plan.corners,
        times=record.time()[rows],
        command=record.get("command_position")[rows],
        actual=record.get("actual_position")[rows],
        following_error=record.get("following_error"),
    )
    return row, record, ticks


def _drive_acceleration(record: Recorder, ticks: int) -> Array:
    """The drive's acceleration (:func:`drive_differences`) at each servo tick of a record: computed
    at the interpolation instants, each value held from its instant to the next (NaN before the
    first two instants)."""
    times = record.time()
    servo = float(np.median(np.diff(times))) if times.size > 1 else 1.0
    rows = _interpolation_rows(record, servo, ticks)
    command = record.get("command_position")
    _, acceleration, _ = drive_differences(command[rows], servo * ticks)
    held = np.full(command.shape, np.nan)
    instants = np.flatnonzero(rows)
    for k in range(acceleration.shape[0]):  # the acceleration known at instant k + 2 holds until the next
        stop = instants[k + 3] if k + 3 < instants.size else command.shape[0]
        held[instants[k + 2] : stop] = acceleration[k]
    return held


def _save_trace(path: Path, record: Recorder, model: RobotModel, ticks: int) -> None:
    """A policy's trace: the record in the trajectory layout, plus ``<joint>.drive_acceleration``
    (the table's acceleration, see :data:`GLOSSARY`) as an extra column."""
    buffer = io.StringIO()
    record.to_csv(buffer, model.joint_names)
    lines = buffer.getvalue().splitlines()
    held = _drive_acceleration(record, ticks)
    extra = ",".join(f"{name}.drive_acceleration" for name in model.joint_names)
    rows = [f"{lines[0]},{extra}"]
    for line, values in zip(lines[1:], held.tolist(), strict=True):
        rows.append(line + "," + ",".join("" if np.isnan(v) else repr(v) for v in values))
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


async def _external_run(
    driver: RobotDriver, config: DemoConfig, plan: _Plan, *, lines: bool = False
) -> tuple[DemoRow, Array, Array]:
    """The rectangle on a controller found on the ports: the waypoints, streamed, or (``lines``) its
    own straight lines; the row from the joint states it publishes meanwhile."""
    await _approach(driver, _planner(plan.model, config), plan.start, Mode.STREAM)
    times: list[float] = []
    positions: list[Array] = []

    async def watch() -> None:
        async for state in driver.states():
            times.append(state.received)
            positions.append(state.positions)

    watcher = asyncio.get_running_loop().create_task(watch())
    try:
        if lines:
            await driver.move_lines(plan.lines(), speed=config.speed)
        else:
            await driver.execute(plan.waypoints, Mode.STREAM)
    finally:
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError, DriverError):
            await watcher
    t = np.array(times) - times[0]
    q = np.array(positions)
    row = analyse(
        MOVL if lines else "controller's own",
        plan.model,
        plan.corners,
        times=t,
        command=q,
        actual=q,
        following_error=None,
        source="joint states",
    )
    return row, t, q


async def _probe(config: DemoConfig, model: RobotModel) -> RobotDriver | None:
    if config.host is None:
        return None
    driver = RobotDriver(
        config.host,
        config.motion_port,
        config.state_port,
        profile=config.profile,
        wire=config.wire,
        model=model,
        goal_tolerance=SETTLED_POSITION * 5,
        tap=config.tap,
    )
    try:
        await driver.connect(timeout=1.0)
    except DriverError as exc:
        log.info("no controller at %s (%s): using the embedded emulator", config.host, exc)
        return None
    return driver


def embedded_only(config: DemoConfig) -> list[str]:
    """The options of ``config`` that only the embedded emulator takes, as given (not defaults)."""
    given = []
    if config.simulated:
        given.append("--simulated")
    if config.speedup != 1.0:
        given.append(f"--speedup {config.speedup:g}")
    if tuple(config.policies) != PAPER_POLICIES:
        given.append(f"--policies {' '.join(config.policies)}")
    return given


async def run_demo(
    config: DemoConfig,
    progress: Callable[[str], None] = print,
    *,
    interrupted: Callable[[RobotDriver], Awaitable[None]] | None = None,
) -> DemoResult:
    """Plan and run the experiment (see the module doc); writes CSV files (and a figure).

    Cancelled (Ctrl-C) while it drives a controller found on the ports, the motion under way is
    stopped (the driver sends STOP), then ``interrupted`` is awaited with that controller's driver
    before it is closed: ``robot-client`` waits there for the robot to come to rest and says where."""
    model = load_model(config.model)
    start, motion, corners = plan_rectangle(model, config)
    waypoints = motion.sparse()
    plan = _Plan(model, start, waypoints, corners, rectangle_corners(model, config.width, config.height)[1])
    out = Path(config.output)
    result = DemoResult([], waypoints)
    result.files.append(_save_waypoints(out, waypoints))
    perimeter = 2 * (config.width + config.height)
    progress(
        f"rectangle {config.width * 1000:g} x {config.height * 1000:g} mm on {model.name}: {len(waypoints)} waypoints "
        f"every {config.spacing * 1000:g} mm along {perimeter * 1000:g} mm, {waypoints.duration:.2f} s as planned"
    )
    external = await _probe(config, model)
    if external is not None:
        result.external = f"{external.host}:{external.motion_port}"
        progress(f"a controller answers at {result.external}: running the rectangle there")
        try:
            if config.model_check:  # the rectangle is planned with config.model
                check = await check_model(external, model, skip="--no-model-check")
                if check.agrees is None:
                    progress(f"note: {check.how}")
            ignored = embedded_only(config)
            if ignored:
                progress(
                    f"ignored here: {', '.join(ignored)} (they choose how the embedded emulator runs; a running "
                    "controller interpolates its own way, in real time): add --embedded to run them"
                )
            row, t, q = await _external_run(external, config, plan)
            result.rows.append(row)
            trace = out / "demo_controller.csv"
            recording(t.tolist(), q.tolist(), joint_names=model.joint_names).save(trace)
            result.files.append(trace)
            if config.movl:
                if await external.supports_lines():
                    progress(f"{MOVL}: the rectangle as the controller's straight lines (CARTESIAN_LINE) ...")
                    row, t, q = await _external_run(external, config, plan, lines=True)
                    result.rows.append(row)
                    trace = out / "demo_controller_movl.csv"
                    recording(t.tolist(), q.tolist(), joint_names=model.joint_names).save(trace)
                    result.files.append(trace)
                else:
                    progress(f"{MOVL}: skipped: the controller has no straight-line motion (no CARTESIAN_LINE)")
        except asyncio.CancelledError:  # Ctrl-C: the motion under way was sent STOP
            if interrupted is not None:
                await interrupted(external)  # not closing while the robot brakes
            raise
        finally:
            await external.close()
        return result
    records: dict[str, Recorder] = {}
    clock = "simulated clock" if config.simulated else ("real time" if config.speedup == 1 else f"{config.speedup:g}x")
    for policy in config.policies:
        progress(f"{policy}: embedded emulator ({clock}) ...")
        begun = time.perf_counter()
        row, record, ticks = await _embedded_run(config, plan, policy)
        result.rows.append(row)
        records[policy] = record
        trace = out / f"demo_{policy}.csv"
        _save_trace(trace, record, model, ticks)
        result.files.append(trace)
        progress(f"{policy}: done in {time.perf_counter() - begun:.1f} s, trace {trace}")
    if config.movl:
        progress(f"{MOVL}: embedded emulator ({clock}), the rectangle as four straight lines (CARTESIAN_LINE) ...")
        begun = time.perf_counter()
        row, record, ticks = await _embedded_run(config, plan, None)
        result.rows.append(row)
        trace = out / "demo_movl.csv"
        _save_trace(trace, record, model, ticks)
        result.files.append(trace)
        progress(f"{MOVL}: done in {time.perf_counter() - begun:.1f} s, trace {trace}")
    if config.plot:
        if "linear" not in records or "quintic" not in records:
            result.no_figure = "it compares the linear and quintic runs: give both in --policies"
        else:
            result.figure = _figure(records, waypoints, model, out, ticks)
            if result.figure is None:
                result.no_figure = "matplotlib is not installed: pip install -e '.[plot]' (the plot extra)"
    return result


def _save_waypoints(out: Path, waypoints: Trajectory) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "demo_waypoints.csv"
    waypoints.save(path)
    return path


def _figure(
    records: dict[str, Recorder], waypoints: Trajectory, model: RobotModel, out: Path, ticks: int
) -> Path | None:
    """Fig. 6 of the paper: one joint before (linear, not interpolated) and after (quintic)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    before, after = records.get("linear"), records.get("quintic")
    if before is None or after is None:
        return None
    joint = int(np.argmax(np.ptp(waypoints.positions, axis=0)))
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 8))
    for label, record in (("before interpolation (linear)", before), ("after interpolation (quintic)", after)):
        command = record.get("command_position")
        t = record.time() - record.time()[_motion_start(command)]  # 0: the motion starts
        # the drive's view, as the table measures it: differences at the interpolation instants
        rows = _interpolation_rows(record, float(np.median(np.diff(record.time()))), ticks)
        dt = float(np.median(np.diff(t[rows])))
        velocity, acceleration, _ = drive_differences(command[rows], dt)
        instants = t[rows]
        axes[0].plot(t, command[:, joint], label=label, linewidth=0.8)
        axes[1].step(instants[1:], velocity[:, joint], where="post", label=label, linewidth=0.8)
        axes[2].step(instants[2:], acceleration[:, joint], where="post", label=label, linewidth=0.8)
    for ax, unit in zip(axes, ("position (rad)", "velocity (rad/s)", "acceleration (rad/s²)"), strict=True):
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
    axes[0].plot(waypoints.times, waypoints.positions[:, joint], "k.", label="waypoints")
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{model.joint_names[joint]} tracing the rectangle, before and after interpolation")
    path = out / "demo_fig6.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
