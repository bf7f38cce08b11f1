"""``robot-server --fleet FILE.toml``: every controller of a fleet file in one process.

The file is read and checked whole (:mod:`.config`) before anything is bound; then every controller
starts and prints its ready line (``r1: robot-server ready: ...``), and the fleet prints one of its
own (``robot-server fleet ready: 3 controllers ...``), with the web view's address when ``--web`` is
given. Fault commands on stdin name their controller (``r2 estop``, or ``all estop``); each
controller's ``faults`` run at its controller times. On SIGINT or SIGTERM every robot decelerates
to rest, every connection closes, the records are written and the command exits 0. Log lines name
their controller (:mod:`.logs`).
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import logging
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from simple_message.endpoints import run

from ..cli import check_writable, freeze_startup_objects, read_stdin_lines, realtime, write_records
from ..emulator import FaultError
from ..realtime import normal_priority
from ..web import MAX_RATE, WebUnavailable, fleet_view
from .config import FleetError, load_fleet
from .logs import FORMAT, ControllerField
from .runner import Fleet, FleetCommandError

if TYPE_CHECKING:
    from ..web.fleet import FleetView

__all__ = ["FLEET_OPTIONS", "fleet_main"]

log = logging.getLogger("robot_server.fleet")

#: the command line's options that a fleet has as a whole (all others are a controller's, in the file)
FLEET_OPTIONS = (
    "fleet",
    "speedup",
    "web",
    "web_rate",
    "web_token",
    "log_level",
    "no_stdin",
    "imports",
    "realtime_priority",
)


def fleet_main(args: argparse.Namespace, given: list[str]) -> int:
    """Run ``args.fleet``; ``given`` are the controller options also given on the command line
    (refused: they belong in the file)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(FORMAT))
    handler.addFilter(ControllerField())
    logging.basicConfig(level=args.log_level, handlers=[handler])
    if given:
        options = ", ".join(f"--{name.replace('_', '-')}" for name in given)
        print(
            f"robot-server: {options}: a controller's setting; with --fleet it goes in the fleet file "
            f"([defaults] for all, or a [[controller]] table, as {given[0]} = ...)",
            file=sys.stderr,
        )
        return 2
    try:
        spec = load_fleet(args.fleet, speedup=args.speedup)
        for controller in spec.controllers:
            if controller.record is not None:
                check_writable(controller.record, f"{spec.path}: controller {controller.name}: record")
            if controller.config.capture is not None:
                check_writable(Path(controller.config.capture), f"{spec.path}: controller {controller.name}: capture")
        fleet = Fleet(spec)
        view = None
        if args.web is not None:
            if args.web_rate > MAX_RATE:
                raise ValueError(f"--web-rate is at most {MAX_RATE:g} updates a second")
            view = fleet_view(fleet.emulators, *args.web, rate=args.web_rate, token=args.web_token, run_as=fleet.run_as)
    except (FleetError, ValueError, OSError, WebUnavailable) as exc:
        print(f"robot-server: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print("robot-server: not enough memory for the records: a smaller record_seconds", file=sys.stderr)
        return 2
    try:
        code = run(_serve(fleet, view, read_stdin=not args.no_stdin, priority=args.realtime_priority))
    except (FleetError, OSError) as exc:  # a port taken between the check and the start
        print(f"robot-server: {exc}", file=sys.stderr)
        return 1
    failed = False
    for name, recorders in fleet.recorders.items():
        target = spec.named(name).record
        assert target is not None
        try:
            fleet.run_as(name, functools.partial(write_records, str(target), recorders, fleet[name]))
        except OSError as exc:
            print(f"robot-server: controller {name}: cannot write the record: {exc}", file=sys.stderr)
            failed = True
    return 1 if failed else code


async def _serve(fleet: Fleet, view: FleetView | None, *, read_stdin: bool, priority: int | None = None) -> int:
    loop = asyncio.get_running_loop()
    done = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, done.set)
    granted = False
    try:
        await fleet.start()
        lines = fleet.ready_lines()
        if view is not None:
            await view.start()
            lines[-1] += f", web view {view.token_url if view.token_generated else view.url}"
        granted = realtime(priority)
        for line in lines:
            print(line, flush=True)
        freeze_startup_objects()
        if read_stdin:
            _read_commands(fleet, loop)
        await done.wait()
    finally:
        log.info("shutting down: bringing %d controllers to rest", len(fleet))
        if view is not None:
            await view.close()
        await fleet.close()
        if granted:
            normal_priority()  # the records and the exit need no real-time priority
    return 0


def _apply(fleet: Fleet, line: str) -> None:
    try:
        fleet.command(line)
    except FleetCommandError as exc:  # no controller of the fleet named
        log.warning("%s", exc)
    except FaultError:  # logged as that controller's
        pass


def _read_commands(fleet: Fleet, loop: asyncio.AbstractEventLoop) -> None:
    """Fault commands from stdin (``NAME COMMAND``)."""
    read_stdin_lines(loop, functools.partial(_apply, fleet))
