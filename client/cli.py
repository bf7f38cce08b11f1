"""``robot-client`` (also ``python -m client``): drive a simple_message controller from the shell.

Commands: ``ping``, ``status``, ``monitor``, ``move``, ``run FILE``, ``stop``, ``record FILE`` and
``demo`` (the paper's experiment; it starts an embedded emulator when no controller answers).
Angles in radians, lengths in metres. Exit status 0 on success, 1 when the robot or controller
failed (with one line saying why on stderr), 2 for bad arguments. SIGINT and SIGTERM stop a motion
under way (STOP sent and acknowledged) before the command exits (130 and 143). ``--capture
FILE.pcapng`` records the command's traffic as a pcapng file (:mod:`simple_message.capture.writer`).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import logging
import math
import os
import signal
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from robot_server.control import POLICIES, policy
from robot_server.kinematics import fk
from robot_server.loader import load_model, shipped_models
from robot_server.model import ModelError, RobotModel, rpy_matrix
from simple_message.capture import DEFAULT_MAX_BYTES, CaptureWriter
from simple_message.cliargs import (
    ArgumentParser,
    add_capture_arguments,
    add_import_argument,
    add_log_level_argument,
    add_profile_wire_arguments,
    add_version_argument,
    client_port,
    options_after_command,
    positive_float,
    positive_int,
    preimport,
)
from simple_message.constants import MsgType, TriState
from simple_message.dialects import DIALECTS, GENERIC, dialect
from simple_message.errors import SimpleMessageError
from simple_message.jsonio import message_to_json, symbolic_names
from simple_message.messages import Status, ToolPose
from simple_message.wire import ByteOrder, WireFormat

from .advice import after_refusal, instead
from .demo import PAPER_POLICIES, DemoConfig, format_table, run_demo
from .driver import STOP_SETTLE, DriverError, JointState, LineGoal, LineRefused, Mode, RobotDriver
from .errors import ExecutionAborted
from .identity import check_model
from .limits import check_limits, within_cubics, within_speeds
from .planner import Motion, Planner, PlanningError, pose
from .trajectory import Trajectory, TrajectoryError, recording
from .waiting import joints_still

__all__ = ["main", "parser"]

log = logging.getLogger("client.cli")


#: robot-client's exit statuses (README, "Exit status")
EXIT_DONE, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143

#: ``move --linear``'s TCP speed (m/s) when --tcp-speed is not given (the planner's own top speed)
DEFAULT_TCP_SPEED = 0.25


class CommandError(Exception):
    """A failure to report in one line (exit status 1: the robot or the controller)."""


class Terminated(Exception):
    """SIGTERM arrived: the command was cancelled as for SIGINT (the robot stopped), exit 143."""


def _run_main(main: Awaitable[None]) -> None:
    """``asyncio.run(main)``, with SIGTERM handled as asyncio handles SIGINT: the command is
    cancelled, so a motion under way is stopped (the driver sends STOP on cancellation), and then
    :class:`Terminated` is raised instead of the process dying with the robot moving."""

    async def guarded() -> None:
        task = asyncio.current_task()
        assert task is not None
        loop = asyncio.get_running_loop()
        terminated = False

        def on_term() -> None:
            nonlocal terminated
            terminated = True
            task.cancel()

        with contextlib.suppress(NotImplementedError, RuntimeError):  # no signals here (Windows, a thread)
            loop.add_signal_handler(signal.SIGTERM, on_term)
        try:
            await main
        except asyncio.CancelledError:
            if terminated:
                raise Terminated from None
            raise
        finally:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(signal.SIGTERM)

    asyncio.run(guarded())


_MODES = (
    "how the points go to the controller: stream (one request at a time, each acknowledged) or download (every "
    "point first, then the robot runs them) (default: the profile's: download for abb, which runs nothing "
    "else; stream for the others; fanuc and staubli take only streams; MotoROS has one way, its trajectory mode)"
)

_DESCRIPTIONS = {
    "ping": "Send PING requests on the motion port and print each round-trip time, then the minimum, median "
    "and maximum. A motion client: refused while another client moves the robot.",
    "status": "Wait for one joint state and STATUS on the state port and print them as one JSON object, with the "
    'tool centre point under "tool" when the controller sends TOOL_POSE (this project\'s extension; null '
    "otherwise). Only watches: connects the state port alone.",
    "monitor": "Print the joint state and STATUS once a second, with the rate at which they arrive, and the tool "
    "centre point's position (mm) and speed (mm/s) when the controller sends TOOL_POSE, for --duration seconds or "
    "until Ctrl-C. Only watches: connects the state port alone.",
    "move": "Plan a jerk-limited move from where the robot is to a joint configuration (--joints) or to a flange "
    "pose along a straight line (--pose), and execute it; a progress line on a terminal, then a report. With "
    "--linear the controller runs the straight line itself (CARTESIAN_LINE, this project's extension) when it "
    "can, at --tcp-speed; otherwise it is planned on the PC as without --linear. Ctrl-C stops the robot.",
    "run": "Execute a trajectory file (.csv or .json; a file that record wrote replays at the times the controller "
    "stamped its states with, where it says them), streamed or downloaded (--mode); --approach moves to its start "
    "first. Ctrl-C stops the robot.",
    "stop": "Stop the robot now and wait for the controller to acknowledge it. A motion client: refused while "
    "another client moves the robot.",
    "record": "Record the joint states from the state port to a trajectory file, CSV or JSON for a .json name (run "
    "FILE replays it), for --duration seconds or until Ctrl-C. Only watches: connects the state port alone.",
    "demo": "The paper's experiment: the robot draws a rectangle under each interpolation policy, then as four "
    "straight lines run by the controller (the 'controller MOVL' row, unless --no-movl), and the "
    "command prints a table of the results and writes the CSV traces and (with matplotlib) a figure to "
    "--output. It uses the controller at --host and the ports when one answers (not with --embedded), else "
    "an embedded emulator.",
}


def _common() -> ArgumentParser:
    """The options every command takes (before or after the command's name)."""
    common = ArgumentParser(add_help=False)
    common.add_argument("--host", default="127.0.0.1", help="controller address")
    common.add_argument(
        "--motion-port",
        type=client_port,
        metavar="PORT",
        help="the controller's motion port, 1..65535 (default: the profile's, 11000; motoros 50240)",
    )
    common.add_argument(
        "--state-port",
        type=client_port,
        metavar="PORT",
        help="the controller's state port, 1..65535 (default: the profile's, 11002; motoros 50241)",
    )
    common.add_argument(
        "--profile",
        choices=sorted(DIALECTS),
        default=GENERIC.name,
        help="the controller family (default: %(default)s): "
        + "; ".join(f"{name}: {entry.description}" for name, entry in sorted(DIALECTS.items())),
    )
    add_profile_wire_arguments(common, ("little", "big"), "fanuc: big")
    common.add_argument(
        "--j23-factor",
        type=int,
        choices=(-1, 0, 1),
        help="fanuc: the controller's J3 is the model's J3 minus this times J2, as fanuc_driver's J23_factor "
        "converts it (default: 1 for fanuc, 0 for the others)",
    )
    common.add_argument("--serial", metavar="URL", help="one serial link for motion and state (pyserial URL)")
    common.add_argument(
        "--model",
        default="jibot_zxs",
        metavar="NAME|PATH",
        help=f"robot model, a shipped name or a .toml/.urdf file ({', '.join(shipped_models())})",
    )
    common.add_argument(
        "--timeout", type=positive_float, default=5.0, metavar="SECONDS", help="connect and reply timeout"
    )
    add_capture_arguments(common, "the command's traffic", DEFAULT_MAX_BYTES / 1e6)
    add_log_level_argument(common)
    add_import_argument(common)  # e.g. a module that registers a dialect or an interpolation policy
    return common


def parser() -> argparse.ArgumentParser:
    common = _common()
    p = ArgumentParser(
        prog="robot-client",
        description="Drive a robot controller (or the emulator) over ROS-Industrial simple_message.",
        epilog="Angles in radians, lengths in metres. Run 'robot-client COMMAND -h' for a command's options; the "
        "options every command takes (--host, the ports, --profile, --model...) may also come before COMMAND. "
        "Exit status: 0 done, 1 the robot or the controller failed, 2 bad arguments or input, 130 interrupted, "
        "143 terminated (the robot stopped first).",
    )
    add_version_argument(p)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", help="what to do")

    def command(name: str, summary: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=[common], help=summary, description=_DESCRIPTIONS[name])

    ping = command("ping", "round-trip time of PING requests")
    ping.add_argument("--count", type=positive_int, default=5, metavar="N", help="PING requests to send, at least 1")
    command("status", "print the joint state, STATUS and tool pose once (JSON)")
    monitor = command("monitor", "live joint state, STATUS and tool pose, with rates")
    monitor.add_argument("--duration", type=positive_float, metavar="SECONDS", help="seconds (default: until Ctrl-C)")
    move = command("move", "move to a joint configuration or a Cartesian pose")
    target = move.add_mutually_exclusive_group(required=True)
    target.add_argument("--joints", type=float, nargs="+", metavar="Q", help="joint values (rad), one per joint")
    target.add_argument(
        "--pose",
        type=float,
        nargs="+",
        metavar="V",
        help="flange X Y Z (m) [ROLL PITCH YAW] (rad); a straight line, keeping the orientation if none given",
    )
    move.add_argument(
        "--speed",
        type=float,
        default=0.3,
        metavar="SHARE",
        help="share of the joint velocity, acceleration and jerk limits, in (0, 1] (default: %(default)s)",
    )
    move.add_argument("--mode", choices=[m.value for m in Mode], help=_MODES)
    move.add_argument(
        "--linear",
        action="store_true",
        help="with --pose: let the controller run the straight line (CARTESIAN_LINE) if it can; else it is planned "
        "on the PC, as without --linear",
    )
    move.add_argument(
        "--no-model-check",
        action="store_true",
        help="with --pose: do not compare --model with the robot the controller says it drives (its TOOL_POSE, or "
        "MotoROS's D-H table); a --pose move is refused when they differ by more than 1 mm",
    )
    move.add_argument(
        "--tcp-speed",
        type=float,
        metavar="M/S",
        help=f"with --linear: the tool's speed along the line, > 0 (default: {DEFAULT_TCP_SPEED})",
    )
    run = command("run", "execute a trajectory file (.csv or .json)")
    run.add_argument("file", type=Path, metavar="FILE", help="the trajectory file (.csv or .json)")
    run.add_argument("--mode", choices=[m.value for m in Mode], help=_MODES)
    run.add_argument(
        "--approach",
        action="store_true",
        help=f"first move to the trajectory's start by joints, at {APPROACH_SPEED * 100:g} %% of the joint limits, if "
        "the robot is not there (without it, a trajectory that starts away from the robot is refused)",
    )
    command("stop", "stop the robot now (a motion client: refused while another client moves the robot)")
    record = command("record", "record the joint states to a trajectory file (CSV, or JSON for a .json name)")
    record.add_argument(
        "file",
        type=Path,
        metavar="FILE",
        help="the file to write: CSV, or JSON for a .json name (replaced if it exists)",
    )
    record.add_argument("--duration", type=positive_float, metavar="SECONDS", help="seconds (default: until Ctrl-C)")
    demo = command("demo", "the paper's experiment: a rectangle under each policy")
    demo.add_argument(
        "--output", type=Path, default=Path("demo-output"), metavar="DIR", help="directory for CSV traces and figure"
    )
    demo.add_argument("--short", action="store_true", help="a small rectangle (quick)")
    demo.add_argument("--simulated", action="store_true", help="embedded emulator on a simulated clock (fastest)")
    demo.add_argument(
        "--speedup",
        type=positive_float,
        default=1.0,
        metavar="FACTOR",
        help="embedded emulator this many times faster than real time",
    )
    demo.add_argument("--embedded", action="store_true", help="do not look for a controller first")
    demo.add_argument(
        "--policies",
        nargs="+",
        default=list(PAPER_POLICIES),
        metavar="POLICY",
        help=f"controller policies to compare (default: {' '.join(PAPER_POLICIES)}; known: {', '.join(POLICIES)})",
    )
    demo.add_argument("--no-plot", action="store_true", help="no figure even if matplotlib is installed")
    demo.add_argument(
        "--no-model-check",
        action="store_true",
        help="against a running controller: do not compare --model with the robot it says it drives (its "
        "TOOL_POSE, or MotoROS's D-H table); the demo is refused when they differ by more than 1 mm",
    )
    demo.add_argument(
        "--no-movl",
        action="store_true",
        help="no 'controller MOVL' row (the rectangle as four straight lines run by the controller)",
    )
    return p


# -- commands -----------------------------------------------------------------------------------------


def _wire(args: argparse.Namespace) -> WireFormat:
    """The wire format asked for, the profile's where an option is not given."""
    wire = dialect(args.profile).wire
    if args.byte_order is not None:
        wire = wire.with_byte_order(ByteOrder.BIG if args.byte_order == "big" else ByteOrder.LITTLE)
    if args.float64 is not None:
        wire = WireFormat(wire.byte_order, 8)
    return wire


def _driver(args: argparse.Namespace, model: RobotModel, capture: CaptureWriter | None = None) -> RobotDriver:
    return RobotDriver(
        args.host,
        args.motion_port,
        args.state_port,
        profile=args.profile,
        wire=_wire(args),
        model=model,
        reply_timeout=args.timeout,
        serial=args.serial,
        tap=capture,
        j23_factor=args.j23_factor,
    )


def _count(count: int, one: str, many: str | None = None) -> str:
    """``1 point``, ``2 points``: a count and its noun, singular for one."""
    return f"{count} {one if count == 1 else many or one + 's'}"


def _status_dict(status: Status | None) -> dict[str, object] | None:
    """A STATUS as every command prints a message (``simple-message decode`` included): the
    numbers in ``body``, their symbolic names in ``names``."""
    if status is None:
        return None
    return message_to_json(status)


def _state_dict(state: JointState) -> dict[str, object]:
    """The joint state, the same keys whatever the controller sends (``velocities`` null when it
    sends none)."""
    return {
        "positions": [round(x, 6) for x in state.positions.tolist()],
        "velocities": None if state.velocities is None else [round(x, 6) for x in state.velocities.tolist()],
        "status": _status_dict(state.status),
    }


async def _ping(driver: RobotDriver, args: argparse.Namespace, out: TextIO) -> None:
    times = [await driver.ping() for _ in range(args.count)]
    for i, t in enumerate(times):
        print(f"PING {i + 1}: {t * 1000:.3f} ms", file=out)
    print(
        f"{_count(len(times), 'reply', 'replies')}, min/median/max {min(times) * 1000:.3f}/"
        f"{np.median(times) * 1000:.3f}/{max(times) * 1000:.3f} ms",
        file=out,
    )


def _tool_dict(pose: ToolPose | None) -> dict[str, object] | None:
    """A TOOL_POSE as ``status`` prints it (null when the controller sends none)."""
    if pose is None:
        return None
    fields = ("x", "y", "z", "qx", "qy", "qz", "qw", "speed", "time")
    return {name: round(float(getattr(pose, name)), 6) + 0.0 for name in fields}  # + 0.0: no -0.0


async def _status(driver: RobotDriver, _args: argparse.Namespace, out: TextIO) -> None:
    await driver.wait_state()
    # a controller with the extension sends TOOL_POSE with its next state round; the wait is a
    # few rounds at most, so a controller without it costs no more than that
    tool = await driver.subscribe_tool_pose()
    state = driver.joint_state
    assert state is not None
    print(json.dumps({**_state_dict(state), "tool": _tool_dict(tool)}), file=out)


async def _for(seconds: float | None, body: Callable[[], Awaitable[None]]) -> None:
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(seconds):
            await body()


async def _monitor(driver: RobotDriver, args: argparse.Namespace, out: TextIO) -> None:
    await driver.subscribe_tool_pose(wait=False)
    count, window = 0, time.monotonic()

    async def body() -> None:
        nonlocal count, window
        async for state in driver.states():
            count += 1
            now = time.monotonic()
            if now - window >= 1.0:
                rate = count / (now - window)
                status = symbolic_names(state.status) if state.status is not None else {}
                q = " ".join(f"{x:+.4f}" for x in state.positions.tolist())
                tool = driver.tool_pose
                tcp = (
                    ""
                    if tool is None
                    else f"  tcp=[{tool.x * 1000:+.1f} {tool.y * 1000:+.1f} {tool.z * 1000:+.1f}] mm "
                    f"{tool.speed * 1000:.1f} mm/s"
                )
                print(
                    f"{rate:6.1f} Hz  q=[{q}]{tcp}  in_motion={status.get('in_motion')} "
                    f"in_error={status.get('in_error')} e_stopped={status.get('e_stopped')} "
                    f"drives={status.get('drives_powered')}",
                    file=out,
                    flush=True,
                )
                count, window = 0, now

    await _for(args.duration, body)


async def _record(driver: RobotDriver, args: argparse.Namespace, out: TextIO) -> None:
    names = driver.model.joint_names if driver.model is not None else ()
    states: list[JointState] = []
    if driver.dialect.unknown_types:  # a TOPIC it may not know: ABB's, Fanuc's, Staubli's servers take none
        driver.ask_feedback()  # the controller's own time of each sample, where it sends it

    async def body() -> None:
        async for state in driver.states():
            states.append(state)

    try:
        await _for(args.duration, body)
    finally:
        if states:
            recorded = recording(
                [s.received for s in states],
                [s.positions.tolist() for s in states],
                [None if s.velocities is None else s.velocities.tolist() for s in states],
                names,
                [s.stamp for s in states],
            )
            recorded.save(args.file)
            print(
                f"{_count(len(recorded), 'joint state')} written to {args.file} (replay it with: run {args.file})",
                file=out,
            )
            if _ends_moving(recorded):
                print(
                    "note: the robot was still moving when the recording ended: run brings it to rest at the last "
                    "state, later than it passed it here",
                    file=out,
                )
        else:
            print("no joint state received: nothing written", file=out)


def _ends_moving(recorded: Trajectory) -> bool:
    """The robot was still moving at a recording's last state: by its velocities, or (none recorded)
    by the change from the state before."""
    if recorded.velocities is not None:
        return not joints_still(recorded.velocities[-1], None, 0.0)
    if len(recorded) < 2:
        return False
    moved = recorded.positions[-1] - recorded.positions[-2]
    return not joints_still(None, moved, float(recorded.times[-1] - recorded.times[-2]))


@contextlib.asynccontextmanager
async def _progress_line(out: TextIO, progress: Callable[[], Coroutine[None, None, None]]) -> AsyncIterator[None]:
    """Run ``progress`` (which rewrites one line) while the block runs, on a terminal only."""
    task = asyncio.get_running_loop().create_task(progress()) if out.isatty() else None
    try:
        yield
    finally:
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, DriverError):
                await task
            out.write("\n")


async def _execute(driver: RobotDriver, trajectory: Trajectory, mode: str | None, out: TextIO) -> None:
    """Run a trajectory with a progress line (on a terminal) and a final report."""
    total = trajectory.duration
    start = time.monotonic()
    goal = trajectory.positions[-1]

    async def progress() -> None:
        async for state in driver.states():
            elapsed = time.monotonic() - start
            share = min(1.0, elapsed / total) if total > 0 else 1.0
            error = float(np.max(np.abs(state.positions[: goal.size] - goal)))
            bar = "#" * int(share * 30)
            out.write(f"\r[{bar:<30}] {elapsed:6.2f}/{total:.2f} s  {error:.4f} rad from goal")
            out.flush()

    async with _progress_line(out, progress):
        final = await driver.execute(trajectory, mode)
    error = float(np.max(np.abs(final.positions[: goal.size] - goal)))
    print(
        f"done: {_count(len(trajectory), 'point')} in {time.monotonic() - start:.2f} s (planned {total:.2f} s), "
        f"{error:.2e} rad from the goal",
        file=out,
    )


async def _move(driver: RobotDriver, args: argparse.Namespace, out: TextIO) -> None:
    model = driver.model
    assert model is not None
    here = (await driver.wait_state()).positions[: model.dof]
    busy = driver.moving_elsewhere()  # a move is planned from the robot at rest, where it is
    if busy is not None:
        raise CommandError(busy)
    here = np.clip(here, model.lower, model.upper)
    planner = Planner(
        model,
        velocity_scale=args.speed,
        acceleration_scale=args.speed,
        jerk_scale=args.speed,
        joint_spacing=2 * math.pi,  # JOINT_TRAJ_PT points are joined at rest: one segment
        # --linear planned on the PC (no straight lines in the controller): the same top TCP speed
        **({"max_speed": _tcp_speed(args)} if args.linear else {}),
    )
    if args.joints is not None:
        motion = planner.joint_move(here, args.joints)
    else:
        confirmed = False  # the controller confirmed --model: the client's advice below rests on it
        if not args.no_model_check:
            check = await check_model(driver, model, skip="--no-model-check")
            confirmed = bool(check.agrees)
            if check.agrees is None:
                print(f"note: {check.how}", file=out, flush=True)
            else:
                log.info("%s", check.how)
        model_said = None if confirmed else f"--model {model.name}, which the controller did not confirm"
        values = args.pose
        rotation = fk(model, here)[:3, :3] if len(values) == 3 else rpy_matrix(*values[3:])
        target = pose(values[:3], rotation)
        if args.linear:
            if await driver.supports_lines():
                print("the controller runs the straight line (CARTESIAN_LINE)", file=out, flush=True)
                try:
                    await _move_line(driver, LineGoal.from_pose(target), args, out)
                except LineRefused as exc:  # the next step depends on the controller's reason
                    where, ways = after_refusal(exc.result, model, here, target, planner, speed=_tcp_speed(args))
                    raise CommandError(_advised(str(exc), where, ways, model_said)) from None
                return
            print("the controller has no straight-line motion: planned on the PC", file=out, flush=True)
        try:
            motion = planner.linear_moves(here, [target])
        except PlanningError as exc:
            ways = instead(model, here, target, planner, linear=False)
            raise PlanningError(_advised(str(exc), None, ways, model_said)) from None
    await _execute(driver, _handed(motion, driver, model), args.mode, out)


def _handed(motion: Motion, driver: RobotDriver, model: RobotModel) -> Trajectory:
    """A planned motion as the controller takes it: JOINT_TRAJ_PT points are joined at rest by the
    controllers that take them (retimed for it); MotoROS joins JOINT_TRAJ_PT_FULL points by cubics
    through their positions and velocities and runs them as given, so the plan is kept within the
    acceleration limit for those (:func:`.limits.within_cubics`)."""
    if driver.dialect.point_type == MsgType.JOINT_TRAJ_PT:
        return motion.sparse(rest_to_rest=True)
    return within_cubics(motion.sparse(), model)


def _advised(refusal: str, where: str | None, ways: list[str], unconfirmed: str | None = None) -> str:
    """A refusal with where the client's check places it and what would run instead; both are
    worked out on the client's model, and when the controller did not confirm it (``unconfirmed``:
    which model, in words) they say so."""
    text = refusal
    if where is not None:
        text += f"; by the client's check of the line on its model: {where}"
    if ways:
        text += "; instead: " + "; or ".join(ways)
    if unconfirmed is not None and (where is not None or ways):
        text += f" (worked out on {unconfirmed})"
    return text


def _tcp_speed(args: argparse.Namespace) -> float:
    return float(args.tcp_speed) if args.tcp_speed is not None else DEFAULT_TCP_SPEED


async def _move_line(driver: RobotDriver, goal: LineGoal, args: argparse.Namespace, out: TextIO) -> None:
    """One straight line run by the controller, with a progress line (on a terminal) and a report."""
    start = time.monotonic()
    target = np.asarray(goal.position, dtype=float)

    async def progress() -> None:
        async for _ in driver.states():
            tool = driver.tool_pose
            if tool is None:
                continue
            away = float(np.linalg.norm(np.array([tool.x, tool.y, tool.z]) - target))
            out.write(
                f"\r{time.monotonic() - start:6.2f} s  {tool.speed * 1000:7.1f} mm/s  {away * 1000:8.2f} mm from goal"
            )
            out.flush()

    async with _progress_line(out, progress):
        final = await driver.move_lines([goal], speed=_tcp_speed(args))
    error = float(np.linalg.norm(np.array([final.x, final.y, final.z]) - target))
    print(f"done: a straight line in {time.monotonic() - start:.2f} s, {error * 1000:.3f} mm from the goal", file=out)


#: ``run --approach``: the share of the joint limits the move to the trajectory's start takes
APPROACH_SPEED = 0.2
#: ``run --approach`` moves to the start when it is farther than this (rad or m, any joint)
APPROACH_MIN = 1e-5


async def _run(driver: RobotDriver, args: argparse.Namespace, out: TextIO) -> None:
    trajectory: Trajectory = args.trajectory  # read and checked before connecting
    model = driver.model
    assert model is not None
    here = (await driver.wait_state()).positions[: model.dof]
    start = trajectory.positions[0]
    gap = float(np.max(np.abs(start - here)))
    if driver.check_limits and trajectory.dof == model.dof:
        # the file's own limits before the robot moves to its start (execute checks them again)
        timed = driver.dialect.timed
        check_limits(
            within_speeds(trajectory, model, velocities=driver.dialect.motion_control) if timed else trajectory,
            model,
            speeds=timed,
        )
    # --approach also closes a gap within the client's tolerance that a controller may not take
    # (MotoROS refuses a start 0.5 mrad off: INVALID, DATA_START_POS)
    if gap > driver.goal_tolerance or (args.approach and gap > APPROACH_MIN):
        busy = driver.moving_elsewhere()
        if busy is not None:
            raise CommandError(busy)
        if not args.approach:
            raise CommandError(
                f"{args.file} starts {gap:.4g} rad away from the robot's position (tolerance {driver.goal_tolerance}): "
                f"add --approach to move there first (a joint move at {APPROACH_SPEED * 100:g} % of the joint limits)"
            )
        share = APPROACH_SPEED
        planner = Planner(
            model,
            velocity_scale=share,
            acceleration_scale=share,
            jerk_scale=share,
            joint_spacing=2 * math.pi,
        )
        approach = _handed(planner.joint_move(np.clip(here, model.lower, model.upper), start), driver, model)
        print(
            f"approach: to the start of {args.file}, {gap:.4g} rad away, at {share * 100:g} % of the joint limits "
            f"({approach.duration:.2f} s)",
            file=out,
            flush=True,
        )
        await _execute(driver, approach, args.mode, out)
    try:
        await _execute(driver, trajectory, args.mode, out)
    except ExecutionAborted as exc:
        if exc.confirmed < 0 and "DATA_START_POS" in str(exc) and not args.approach:
            raise CommandError(
                f"{exc}: the robot is {gap:.4g} rad from the start of {args.file}, more than the controller takes; "
                "add --approach to move there first"
            ) from None
        raise


async def _stop(driver: RobotDriver, _args: argparse.Namespace, out: TextIO) -> None:
    await driver.stop()
    print("stopped", file=out)


_COMMANDS = {
    "ping": _ping,
    "status": _status,
    "monitor": _monitor,
    "move": _move,
    "run": _run,
    "stop": _stop,
    "record": _record,
}


#: the commands that move the robot (Ctrl-C waits for it to come to rest)
_MOVING = {"move", "run"}

#: the commands that only watch: they connect the state port alone, so they never take the motion
#: port from the client that moves the robot
_WATCHING = {"status", "monitor", "record"}


async def _with_driver(args: argparse.Namespace, model: RobotModel, out: TextIO) -> None:
    with _capture(args) as capture:
        driver = _driver(args, model, capture)
        await driver.connect(args.timeout, motion=args.command not in _WATCHING)
        try:
            await _COMMANDS[args.command](driver, args, out)
        except asyncio.CancelledError:  # Ctrl-C, SIGTERM: a motion under way was stopped (STOP acknowledged)
            if args.command in _MOVING:
                await _after_interrupt(driver)  # not leaving while the robot brakes
            raise
        finally:
            await driver.close()


#: a robot that moved less than this (rad, every joint) from Ctrl-C until it was at rest was not moving
NOT_MOVED = 1e-5


async def _after_interrupt(driver: RobotDriver) -> None:
    """After Ctrl-C (or SIGTERM) cancelled a command that moves the robot (a motion under way was
    sent STOP, and the controller acknowledged it): wait, at most :data:`STOP_SETTLE` s, for the
    robot to be at rest, so that the client does not leave while the robot brakes (the controller
    would take that for a lost client), and say where it came to rest, or that it was not moving."""
    before = driver.joint_state  # the latest state when the command was cancelled
    if before is None:
        return  # no joint state yet: nothing was sent to move the robot
    rest = await driver.settle_after_stop(STOP_SETTLE)
    if rest is None:
        if driver.status is not None and driver.status.in_motion == TriState.TRUE:
            print(
                f"robot-client: STOP sent, but the robot was still moving after {STOP_SETTLE:g} s",
                file=sys.stderr,
                flush=True,
            )
        return
    q = " ".join(f"{round(float(x), 4) + 0.0:.4f}" for x in rest.positions)  # + 0.0: no -0.0000
    moved = float(np.max(np.abs(rest.positions - before.positions)))
    still = before.velocities is None or joints_still(before.velocities, None, 0.0)
    if moved < NOT_MOVED and still:
        print(f"robot-client: the robot was not moving: it is at rest at [{q}]", file=sys.stderr, flush=True)
    else:
        print(f"robot-client: stopped: the robot is at rest at [{q}]", file=sys.stderr, flush=True)


def _capture(args: argparse.Namespace) -> contextlib.AbstractContextManager[CaptureWriter | None]:
    """The ``--capture`` file's writer (closed after the driver), or nothing."""
    if args.capture is None:
        return contextlib.nullcontext()
    max_bytes = max(1, round(args.capture_max_mb * 1e6))
    return CaptureWriter(args.capture, max_bytes=max_bytes, application=f"robot-client {args.command}")


async def _demo(args: argparse.Namespace, out: TextIO) -> None:
    with _capture(args) as capture:
        await _run_demo(args, out, capture)


async def _run_demo(args: argparse.Namespace, out: TextIO, capture: CaptureWriter | None) -> None:
    config = DemoConfig(
        model=args.model,
        output=args.output,
        simulated=args.simulated,
        speedup=args.speedup,
        host=None if args.embedded else args.host,
        motion_port=args.motion_port,
        state_port=args.state_port,
        profile=args.profile,
        wire=_wire(args),
        policies=tuple(args.policies),
        plot=not args.no_plot,
        movl=not args.no_movl,
        tap=capture,
        model_check=not args.no_model_check,
    )
    if args.short:
        config = dataclasses.replace(config, width=0.06, height=0.04)
    result = await run_demo(
        config, progress=lambda line: print(line, file=out, flush=True), interrupted=_after_interrupt
    )
    print(file=out)
    print(format_table(result.rows), file=out)
    print(file=out)
    print(f"traces: {', '.join(str(f) for f in result.files)}", file=out)
    if result.figure is not None:
        print(f"figure: {result.figure}", file=out)
    elif config.plot and result.no_figure is not None:
        print(f"figure: not drawn ({result.no_figure})", file=out)


def _writable(path: str) -> None:
    """Refuse, before connecting, a file that cannot be written (a missing directory...)."""
    target = Path(path)
    folder = target.parent
    if not folder.is_dir():
        raise ValueError(f"{path}: cannot write it: no directory {folder}")
    if not os.access(target if target.exists() else folder, os.W_OK) or target.is_dir():
        raise ValueError(f"{path}: cannot write it: permission denied or a directory")


def _check_arguments(args: argparse.Namespace, model: RobotModel) -> None:
    """Usage errors found before connecting (exit status 2)."""
    if args.command == "demo":
        for name in args.policies:
            policy(name)  # ValueError naming the known ones
    if args.command == "run":
        # a TrajectoryError (a ValueError) names the file; columns are matched to the joints by name
        loaded = Trajectory.load(args.file)
        try:
            args.trajectory = loaded.for_joints(model.joint_names)
        except TrajectoryError as exc:
            raise TrajectoryError(f"{args.file}: {exc}") from None
    if args.command == "record":
        _writable(args.file)
    if args.capture is not None:
        _writable(args.capture)
    if args.command != "move":
        return
    if not 0.0 < args.speed <= 1.0:
        raise ValueError(f"--speed must be in (0, 1], not {args.speed}")
    if args.linear and args.pose is None:
        raise ValueError("--linear needs --pose (a straight line to a pose)")
    if not args.linear and args.tcp_speed is not None:
        raise ValueError("--tcp-speed needs --linear")
    if args.tcp_speed is not None and not (math.isfinite(args.tcp_speed) and args.tcp_speed > 0.0):
        raise ValueError(f"--tcp-speed must be > 0 (m/s), not {args.tcp_speed}")
    if args.joints is not None and len(args.joints) != model.dof:
        raise ValueError(f"--joints needs {_count(model.dof, 'value')} for {model.name}, not {len(args.joints)}")
    if args.pose is not None and len(args.pose) not in (3, 6):
        raise ValueError("--pose takes X Y Z or X Y Z ROLL PITCH YAW")
    if not all(math.isfinite(x) for x in (args.joints or args.pose)):
        raise ValueError("move targets must be finite numbers")


def main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    failure = preimport(argv)  # modules that register dialects or policies, before the parser lists them
    if failure is not None:
        print(f"robot-client: {failure}", file=sys.stderr)
        return EXIT_USAGE
    top = parser()
    args = top.parse_args(options_after_command(sys.argv[1:] if argv is None else argv, _common(), top))
    stream = out if out is not None else sys.stdout
    logging.basicConfig(
        level=args.log_level, stream=sys.stderr, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if args.serial is not None and args.command == "demo":
        print(
            "robot-client: demo runs over TCP (its embedded emulator too); --serial is not supported", file=sys.stderr
        )
        return EXIT_USAGE
    try:
        model = load_model(args.model)
        _check_arguments(args, model)
    except (ModelError, OSError, ValueError) as exc:
        print(f"robot-client: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        if args.command == "demo":
            _run_main(_demo(args, stream))
        else:
            _run_main(_with_driver(args, model, stream))
    except KeyboardInterrupt:
        print("robot-client: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Terminated:
        print("robot-client: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except (CommandError, DriverError, PlanningError, SimpleMessageError, OSError) as exc:
        print(f"robot-client: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except Exception as exc:  # a defect of ours: still one line, never a traceback on the terminal
        logging.getLogger("client").debug("internal error", exc_info=True)
        print(
            f"robot-client: internal error: {type(exc).__name__}: {exc} (please report it; --log-level debug shows "
            "where)",
            file=sys.stderr,
        )
        return EXIT_FAILED
    return EXIT_DONE
