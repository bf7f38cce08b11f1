"""``robot-server`` (also ``python -m robot_server``): the robot controller emulator as a command.

With no arguments it emulates the paper's robot (``jibot_zxs``) with the generic profile: motion
server on 127.0.0.1:11000, state server on 127.0.0.1:11002, real time, blend interpolation. It
prints one line on stdout when it accepts connections, logs to stderr, and on SIGINT or SIGTERM
decelerates the robot to rest, closes every connection and exits 0.

Faults are injected by typing commands on its standard input (or piping them in), one per line:
``estop``, ``drives off``, ``drives on``, ``alarm CODE [TEXT]``, ``reset``, ``stop``,
``mode auto|manual``, or scheduled with ``--fault SECONDS:COMMAND`` (controller time from start).

``--capture FILE.pcapng`` records every connection's traffic (every port, and the serial link) as a
pcapng file Wireshark opens (:mod:`simple_message.capture.writer`), bounded by ``--capture-max-mb``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import gc
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from simple_message.capture import DEFAULT_MAX_BYTES
from simple_message.cliargs import (
    ArgumentParser,
    add_capture_arguments,
    add_import_argument,
    add_log_level_argument,
    add_profile_wire_arguments,
    add_version_argument,
    non_negative_float,
    positive_float,
    positive_int,
    preimport,
    server_port,
)
from simple_message.endpoints import run

from .control import DEFAULT_POLICY, POLICIES, Recorder
from .emulator import FAULT_COMMANDS, PROFILES, Emulator, EmulatorConfig, FaultError
from .emulator.owner import OnDisconnect
from .emulator.server import MAX_STATE_RATE
from .fleet.config import MAX_CAPTURE_MB, MAX_INTERPOLATION_PERIOD, MAX_RECORD_SECONDS, MAX_SERVO_TICKS
from .loader import load_model, shipped_cells, shipped_models
from .model import ModelError
from .realtime import RealtimeUnavailable, normal_priority, priority_argument, use_realtime
from .web import MAX_RATE, TOKEN_ENV, WebUnavailable, web_address, web_view

if TYPE_CHECKING:
    from .web.server import WebView

log = logging.getLogger("robot_server.cli")

#: the record kept by default: the last minute (about 45 MB of CSV for six joints moving all the time)
DEFAULT_RECORD_SECONDS = 60.0

_EPILOG = "fault commands (stdin, one per line, or --fault SECONDS:COMMAND):\n" + "\n".join(
    f"  {name:<20} {text}" for name, text in FAULT_COMMANDS.items()
)


def _fault(text: str) -> tuple[float, str]:
    at, sep, command = text.partition(":")
    try:
        seconds = non_negative_float(at)
    except argparse.ArgumentTypeError:
        seconds = -1.0
    if not sep or seconds < 0.0 or not command.strip():
        raise argparse.ArgumentTypeError(f"expected SECONDS:COMMAND (e.g. 2.5:estop), not {text!r}")
    return seconds, command


def _profile_option(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE (e.g. speed=20), not {text!r}")
    return key.strip(), value.strip()


def _web_address(text: str) -> tuple[str, int]:
    try:
        return web_address(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="robot-server",
        description="A robot controller emulator speaking ROS-Industrial simple_message.\n\n"
        "It prints one line on stdout when it accepts connections, logs to stderr, and on SIGINT or SIGTERM "
        "decelerates the robot to rest, closes every connection and exits 0. Fault commands are typed on its "
        "standard input, one per line, or scheduled with --fault.",
        epilog=_EPILOG,
    )
    add_version_argument(p)
    p.add_argument(
        "--fleet",
        metavar="FILE.toml",
        help="run every controller of a fleet file in this one process (one [[controller]] table each, "
        "[defaults] for all; docs/fleet.md); the controllers' settings are the file's, the command line sets "
        "--speedup, --web, --web-token, --web-rate, --log-level and --no-stdin for the fleet",
    )
    p.add_argument(
        "--model",
        action="append",
        metavar="NAME|PATH",
        help="robot model, a shipped name or a .toml/.urdf file; repeat for more motion groups "
        f"(shipped: {', '.join(shipped_models())}; default: jibot_zxs)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to bind")
    p.add_argument(
        "--motion-port",
        type=server_port,
        metavar="PORT",
        help="motion port to bind, 0..65535, 0: any free port (default: the profile's, 11000; motoros 50240)",
    )
    p.add_argument(
        "--state-port",
        type=server_port,
        metavar="PORT",
        help="state port to bind, 0..65535, 0: any free port (default: the profile's, 11002; motoros 50241)",
    )
    p.add_argument(
        "--io-port",
        type=server_port,
        metavar="PORT",
        help="IO port to bind, for profiles that have one, 0..65535, 0: any free port (default: the profile's, "
        "50242 motoros)",
    )
    add_import_argument(p)  # e.g. a module that registers a profile or an interpolation policy
    p.add_argument(
        "--profile",
        default="generic",
        help="the controller family played (default: %(default)s; known: "
        + "; ".join(f"{name}: {entry.description}".replace("%", "%%") for name, entry in PROFILES.items())
        + ")",
    )
    add_profile_wire_arguments(p, ("little", "big", "auto"), "little; fanuc big")
    p.add_argument(
        "--reply-style",
        choices=("echo", "header"),
        help="generic replies echo the body (echo: the C++ library) or are header-only (header: as ABB's) "
        "(default: the profile's; echo for generic; the vendors' profiles reply their own way only)",
    )
    p.add_argument(
        "--state-rate",
        type=positive_float,
        metavar="HZ",
        help=f"state rounds per second, at most {MAX_STATE_RATE:g} (default: the controller's: 40 generic and "
        "motoros, 10 abb, 41.7 fanuc, 50 staubli)",
    )
    p.add_argument("--feedback", action="store_true", help="generic: JOINT_FEEDBACK to every state client")
    p.add_argument(
        "--cell",
        metavar="NAME|PATH",
        help="a cell file whose [supervision] (TCP speed limits, workspace zones) replaces the models' own "
        f"(shipped: {', '.join(shipped_cells())})",
    )
    p.add_argument(
        "--manual-motion",
        action="store_true",
        help="MANUAL mode accepts motion at the reduced TCP speed (ABB, Fanuc T1, the enabling device held) "
        "instead of refusing points",
    )
    p.add_argument(
        "--interpolation",
        default=DEFAULT_POLICY,
        metavar="POLICY",
        help="how points are joined (default: %(default)s): "
        + "; ".join(f"{name}: {entry.summary}" for name, entry in POLICIES.items()),
    )
    p.add_argument(
        "--interpolation-period",
        type=positive_float,
        default=0.004,
        metavar="SECONDS",
        help="the controller's interpolation period: a whole multiple of --servo-period",
    )
    p.add_argument(
        "--servo-period",
        type=positive_float,
        default=0.001,
        metavar="SECONDS",
        help="the servo loop's period (the drives' control tick)",
    )
    p.add_argument(
        "--queue-size", type=positive_int, default=64, metavar="POINTS", help="streamed points the controller queues"
    )
    p.add_argument(
        "--speedup",
        type=positive_float,
        default=1.0,
        metavar="FACTOR",
        help="run the controller this many times faster than real time",
    )
    p.add_argument("--serial", metavar="URL", help="also serve one link on this serial port (pyserial URL)")
    p.add_argument(
        "--on-disconnect",
        choices=[o.value for o in OnDisconnect],
        help="when the motion client goes away while the robot is busy: stop it (controlled, as MotoROS and "
        "Staubli do) or let the queued motion run to its end (as ABB and Fanuc do) (default: the controller's)",
    )
    p.add_argument(
        "--lenient",
        action="store_true",
        help="do not reproduce the played controller's harsh quirks (Fanuc's stalled or misframed input and its "
        "STOP that stops nothing, Staubli's lost framing, ABB's motion server dying on a message it does not "
        "expect): the message is dropped with a warning instead; the default reproduces them, each logged once",
    )
    p.add_argument(
        "--profile-option",
        type=_profile_option,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a setting of the played controller (repeatable): "
        + "; ".join(
            f"{name}: " + ", ".join(f"{key} ({text.replace('%', '%%')})" for key, text in entry.options.items())
            for name, entry in PROFILES.items()
            if entry.options
        ),
    )
    p.add_argument(
        "--max-connections",
        type=positive_int,
        default=128,
        metavar="N",
        help="connections per port where the profile has no limit of its own (default: %(default)s); a full "
        "port closes an idle connection (an incomplete frame, a peer that does not read, the longest silent) for a "
        "newcomer",
    )
    p.add_argument(
        "--frame-timeout",
        type=positive_float,
        default=5.0,
        metavar="SECONDS",
        help="close a connection that began a frame and sent nothing more for SECONDS (default: %(default)g)",
    )
    p.add_argument(
        "--record",
        metavar="FILE.csv",
        help="record every servo tick (command, actual, following error, points received, the TCP) and write it "
        "on exit, by the name's suffix: .csv (every value to 9 decimals), .csv.gz (the same, gzip: about a third of "
        "the size), .npz (numpy's compressed arrays, exact: about half); with several motion groups one file per group "
        "(FILE.g1.csv, ...)",
    )
    p.add_argument(
        "--record-seconds",
        type=positive_float,
        default=DEFAULT_RECORD_SECONDS,
        metavar="SECONDS",
        help=f"keep the last SECONDS of the record, at most {MAX_RECORD_SECONDS:g} (six joints moving: about 0.75 MB "
        "a second as .csv, 0.27 as .csv.gz, 0.35 as .npz, and 0.5 MB of memory; default: %(default)g)",
    )
    add_capture_arguments(p, "every connection's traffic (every port, and the serial link)", DEFAULT_MAX_BYTES / 1e6)
    p.add_argument(
        "--fault",
        type=_fault,
        action="append",
        default=[],
        metavar="SECONDS:COMMAND",
        help="apply a fault command (below) at SECONDS >= 0 of controller time from the start (repeatable)",
    )
    p.add_argument("--no-stdin", action="store_true", help="do not read fault commands from stdin")
    p.add_argument(
        "--realtime-priority",
        type=priority_argument,
        metavar="N",
        help="run the event loop (the control loops, state rounds, requests, the web view) at real-time priority N "
        "(1-99, SCHED_FIFO, as ros2_control's controller manager asks for 50 for its loop): fewer late control "
        "periods on a busy machine, but while busy the loop holds its CPU from every other process (keep a fleet well "
        "under a core, and mind --speedup and floods); needs CAP_SYS_NICE or ulimit -r (refused: a warning, and "
        "normal priority)",
    )
    p.add_argument(
        "--web",
        type=_web_address,
        metavar="[HOST:]PORT",
        help="serve a live web view of the controller there (3D robot, joint plots, STATUS, traffic, fault buttons; "
        "HOST default 127.0.0.1, PORT 0: any free one; needs the web extra: pip install 'simple-message-stack[web]')",
    )
    p.add_argument(
        "--web-token",
        metavar="TOKEN",
        default=os.environ.get(TOKEN_ENV) or None,
        help=f"what the web view's commands need (faults, reset, drives; default: ${TOKEN_ENV}); beyond loopback "
        "without one, a token is made and printed once in the ready line's address; without the token a page is "
        "read-only",
    )
    p.add_argument(
        "--web-rate",
        type=positive_float,
        default=30.0,
        metavar="HZ",
        help=f"updates per second sent to each web page, at most {MAX_RATE:g} (default: %(default)g)",
    )
    add_log_level_argument(p, default="INFO")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    failure = preimport(argv)  # modules that register profiles or policies, before the parser lists them
    if failure is not None:
        print(f"robot-server: {failure}", file=sys.stderr)
        return 2
    the_parser = parser()
    args = the_parser.parse_args(argv)
    if args.fleet is not None:
        from .fleet.command import FLEET_OPTIONS, fleet_main

        given = [
            name
            for name, value in vars(args).items()
            if name not in FLEET_OPTIONS and value != the_parser.get_default(name)
        ]
        return fleet_main(args, given)
    logging.basicConfig(
        level=args.log_level, stream=sys.stderr, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        if args.profile not in PROFILES:
            raise ValueError(f"unknown profile {args.profile!r} (known: {', '.join(sorted(PROFILES))})")
        if args.state_rate is not None and args.state_rate > MAX_STATE_RATE:
            raise ValueError(f"--state-rate is at most {MAX_STATE_RATE:g} Hz")
        if args.web_rate > MAX_RATE:
            raise ValueError(f"--web-rate is at most {MAX_RATE:g} updates a second")
        if args.record_seconds > MAX_RECORD_SECONDS:
            raise ValueError(f"--record-seconds is at most {MAX_RECORD_SECONDS:g} s")
        for option, period in (
            ("--interpolation-period", args.interpolation_period),
            ("--servo-period", args.servo_period),
        ):
            if period > MAX_INTERPOLATION_PERIOD:
                raise ValueError(f"{option} is at most {MAX_INTERPOLATION_PERIOD:g} s")
        if args.interpolation_period / args.servo_period > MAX_SERVO_TICKS:
            raise ValueError(
                f"--servo-period {args.servo_period:g} s is more than {MAX_SERVO_TICKS} ticks per "
                f"--interpolation-period {args.interpolation_period:g} s"
            )
        if args.capture_max_mb > MAX_CAPTURE_MB:
            raise ValueError(f"--capture-max-mb is at most {MAX_CAPTURE_MB:g}")
        for _, command in args.fault:
            _check_command(command)
        if args.record is not None:
            check_writable(Path(args.record))
        if args.capture is not None:
            check_writable(Path(args.capture), "--capture")
        config = EmulatorConfig(
            models=tuple(args.model or ["jibot_zxs"]),
            profile=args.profile,
            host=args.host,
            motion_port=args.motion_port,
            state_port=args.state_port,
            io_port=args.io_port,
            byte_order=args.byte_order,
            float64=args.float64,
            reply_style=args.reply_style,
            state_rate=args.state_rate,
            feedback=args.feedback,
            interpolation=args.interpolation,
            interpolation_period=args.interpolation_period,
            servo_period=args.servo_period,
            speedup=args.speedup,
            queue_capacity=args.queue_size,
            serial=args.serial,
            on_disconnect=args.on_disconnect,
            lenient=args.lenient,
            profile_options=tuple(args.profile_option),
            max_connections=args.max_connections,
            frame_timeout=args.frame_timeout,
            cell=args.cell,
            manual_motion=args.manual_motion,
            capture=args.capture,
            capture_max_bytes=max(1, round(args.capture_max_mb * 1e6)),
        )
        models = [load_model(m) for m in config.models]
        emulator = Emulator(config, models)
        recorders = emulator.record(args.record_seconds) if args.record else []
        view = None if args.web is None else web_view(emulator, *args.web, rate=args.web_rate, token=args.web_token)
    except (ValueError, ModelError, OSError, WebUnavailable) as exc:
        print(f"robot-server: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print("robot-server: not enough memory for the record: a smaller --record-seconds", file=sys.stderr)
        return 2
    try:
        code = run(  # on uvloop when installed
            _serve(emulator, args.fault, read_stdin=not args.no_stdin, view=view, priority=args.realtime_priority)
        )
    except OSError as exc:  # e.g. the port is taken
        print(f"robot-server: {exc}", file=sys.stderr)
        return 1
    try:
        write_records(args.record, recorders, emulator)
    except OSError as exc:
        print(f"robot-server: cannot write the record: {exc}", file=sys.stderr)
        return 1
    return code


def check_writable(path: Path, option: str = "--record") -> None:
    """Refuse a file the server could not write (a record when it exits, a capture when it
    starts): before the session, not after."""
    folder = path.parent
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a directory")
    if not folder.is_dir():
        raise ValueError(f"{option} {path}: no directory {folder}")
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ValueError(f"{option} {path}: not writable")


def write_records(path: str | None, recorders: list[Recorder], emulator: Emulator) -> None:
    if path is None:
        return
    target = Path(path)
    period = emulator.cell.config.servo_period
    for index, (recorder, group) in enumerate(zip(recorders, emulator.cell.groups, strict=True)):
        out = record_path(target, index)
        began = time.perf_counter()
        size = recorder.save(out, group.model.joint_names)
        spent = time.perf_counter() - began
        kept = len(recorder) * recorder.decimation * period
        dropped = (
            f"; {recorder.dropped} older ticks dropped, beyond --record-seconds {recorder.capacity * period:g}"
            if recorder.dropped
            else ""
        )
        log.info(
            "record of group %d: %d ticks written to %s (the last %.1f s, %.1f MB, in %.2f s%s)",
            index,
            len(recorder),
            out,
            kept,
            size / 1e6,
            spent,
            dropped,
        )


def record_path(target: Path, group: int) -> Path:
    """Where the record of motion group ``group`` goes: ``target`` for the first one, then
    ``run.g1.csv``, ``run.g1.csv.gz``, ``run.g1.npz`` (a name without a suffix: ``run.g1.csv``)."""
    if group == 0:
        return target
    name = target.name
    if name.lower().endswith(".csv.gz"):
        return target.with_name(f"{name[: -len('.csv.gz')]}.g{group}{name[-len('.csv.gz') :]}")
    return target.with_name(f"{target.stem}.g{group}{target.suffix or '.csv'}")


def _check_command(command: str) -> None:
    words = command.split()
    known = {name.split()[0] for name in FAULT_COMMANDS}
    if not words or words[0].lower() not in known:
        raise ValueError(f"unknown fault command {command!r}")


async def _serve(
    emulator: Emulator,
    faults: list[tuple[float, str]],
    read_stdin: bool,
    view: WebView | None = None,
    priority: int | None = None,
) -> int:
    loop = asyncio.get_running_loop()
    done = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, done.set)
    await emulator.start()
    ready = emulator.describe()
    if view is not None:
        try:
            await view.start()
        except BaseException:
            await emulator.close()
            raise
        ready += f", web view {view.token_url if view.token_generated else view.url}"
    granted = realtime(priority)
    print(ready, flush=True)
    freeze_startup_objects()
    if emulator.capture is not None:
        log.info("recording every connection to %s", emulator.capture.path)
    tasks = [loop.create_task(_scheduled(emulator, at, command)) for at, command in faults]
    if read_stdin:
        _read_commands(emulator, loop)
    try:
        await done.wait()
    finally:
        log.info("shutting down")
        for task in tasks:
            task.cancel()
        if view is not None:
            await view.close()
        await emulator.close()
        if granted:
            normal_priority()  # the records and the exit need no real-time priority
    return 0


def _apply(emulator: Emulator, command: str) -> None:
    try:
        applied = emulator.command(command)
    except FaultError as exc:
        log.warning("%s", exc)
        return
    log.info("applied: %s", applied)


async def _scheduled(emulator: Emulator, at: float, command: str) -> None:
    await emulator.clock.sleep_until(at)
    _apply(emulator, command)


def _read_commands(emulator: Emulator, loop: asyncio.AbstractEventLoop) -> None:
    """Fault commands from stdin, applied to ``emulator``."""
    read_stdin_lines(loop, functools.partial(_apply, emulator))


def realtime(priority: int | None) -> bool:
    """The event loop's thread at real-time ``priority`` (``--realtime-priority``), said in the
    log; refused, a warning and normal priority, as ros2_control's controller manager does.
    Whether it was granted (:func:`~.realtime.normal_priority` then undoes it)."""
    if priority is None:
        return False
    try:
        use_realtime(priority)
    except RealtimeUnavailable as exc:
        log.warning("--realtime-priority %d: %s; running at normal priority", priority, exc)
        return False
    log.info("running at real-time priority %d (SCHED_FIFO)", priority)
    return True


def freeze_startup_objects() -> None:
    """Keep what the server made to start (modules, models, tables, its listening sockets) out of
    the garbage collector's scans from now on (:func:`gc.freeze`): it lives as long as the
    process, and a full collection would otherwise walk all of it, stalling the control loop
    (27 ms once in a 20-controller fleet streaming, where the interpolation period is 4 ms).
    What is made later is collected as before. (No collection first: it would stall the running
    loop as long; the little garbage of the start stays.)"""
    gc.freeze()


def read_stdin_lines(loop: asyncio.AbstractEventLoop, handle: Callable[[str], None]) -> None:
    """Each non-blank line of stdin handed to ``handle`` on ``loop``, read by a daemon thread
    (works for terminals, pipes and files): the fault commands of a lone server and of a fleet."""

    def reader() -> None:
        # os.read on the descriptor, not sys.stdin: a daemon thread blocked inside the buffered
        # reader holds its lock, and interpreter shutdown then aborts on that lock
        pending = b""
        with contextlib.suppress(OSError, RuntimeError):
            while chunk := os.read(0, 4096):
                pending += chunk
                *lines, pending = pending.split(b"\n")
                for line in lines:
                    if line.strip():
                        loop.call_soon_threadsafe(handle, line.decode(errors="replace"))

    threading.Thread(target=reader, name="robot-server stdin", daemon=True).start()
