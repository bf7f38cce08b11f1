"""``simple-message conformance server|client``: the suites' command line.

``server HOST`` probes a running server and prints the report; ``client`` plays a controller until
the client under test is done (``--duration``, or the client gone for ``--linger`` seconds, or
Ctrl-C) and prints the report. Both write ``--json FILE`` and ``--junit FILE`` and exit 0 when no
rule FAILed, 1 when one did, 2 when the suite could not run (bad options, a port in use).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from ..cliargs import ArgumentParser, client_port, non_negative_float, positive_float, positive_int, server_port
from .report import Report
from .server import EXPECTATIONS, ServerSuite, ServerSuiteOptions

__all__ = ["add_conformance_parser"]

_PROFILES = tuple(EXPECTATIONS)

_SERVER = """Probe a running simple_message server (a robot controller, or robot-server) and report, rule
by rule, whether it speaks the protocol as the real peers do: PASS, FAIL, WARN (works, but not as
the real peers do) or SKIP (does not apply, or needs --allow-motion), each with its evidence (frames
sent and received, in hex and decoded). Without --allow-motion nothing is sent that can move the
robot: PINGs, requests of an unknown type, STOP, and the malformed frames of the reference
library's list, each on its own connection. Exit 0 when no rule FAILed."""

_ALLOW_MOTION = (
    "THE ROBOT WILL MOVE. Send trajectory points: a small move of one joint and back, a move stopped once "
    "a tenth is done, a point beyond the limits that must be refused; on MotoROS, trajectory mode on and off. Only "
    "after STATUS says the robot is idle, in AUTO and not in error. Clear the cell and keep the "
    "e-stop at hand"
)

_CLIENT = """Play a robot controller for a simple_message client under test and judge the client: one
point in flight, sequence numbers, point fields, the first point at the current position, STOP,
its reaction to an injected BUSY (MotoROS), FAILURE and dropped connection, and no point resent
after a reconnect. The suite listens on the profile's ports and passes everything on to a
controller: robot-server, started for the run, unless --controller names one. Point the client at
the suite, run it (e.g. three trajectories and a stop), then stop the suite with Ctrl-C, or let
--duration or --linger end it. The injections come in this order: BUSY on the first trajectory's
point 2, FAILURE on the second trajectory's point 1, the connection dropped after the third
trajectory's point 1. Exit 0 when no rule FAILed."""


def add_conformance_parser(sub: argparse._SubParsersAction[ArgumentParser]) -> None:
    """Add ``conformance`` with its ``server`` and ``client`` suites to ``sub``."""
    from ..cliargs import add_import_argument

    conf = sub.add_parser(
        "conformance",
        help="judge a simple_message server or client against the real peers' behaviour",
        description="A conformance suite for simple_message servers (controllers) and clients.",
        epilog="Run 'simple-message conformance SUITE --help' for a suite's options.",
    )
    suites = conf.add_subparsers(dest="suite", required=True, metavar="SUITE", help="which side to judge")
    srv = suites.add_parser("server", help="probe a running server (controller)", description=_SERVER)
    srv.add_argument("host", metavar="HOST", help="the server's address")
    _add_profile(srv, "the family the server belongs to")
    for role in ("motion", "state", "io"):
        srv.add_argument(
            f"--{role}-port",
            type=client_port,
            metavar="PORT",
            help=f"its {role} port (default: the profile's"
            + ("; probed only for motoros or when given)" if role == "io" else ")"),
        )
    srv.add_argument(
        "--byte-order",
        choices=("little", "big", "auto"),
        default="auto",
        help="the byte order the server must speak (default: auto, detected from its first state frame)",
    )
    srv.add_argument("--float64", action="store_true", help="the server must send float64 reals (default: detected)")
    srv.add_argument("--allow-motion", action="store_true", help=_ALLOW_MOTION)
    srv.add_argument(
        "--amplitude", type=positive_float, default=0.01, metavar="RAD", help="the small move (default: 0.01)"
    )
    srv.add_argument(
        "--joint", type=positive_int, default=1, metavar="N", help="the joint that moves, 1-based (default: 1)"
    )
    srv.add_argument(
        "--tolerance", type=positive_float, default=0.001, metavar="RAD", help="target reached within (default: 0.001)"
    )
    srv.add_argument(
        "--move-time", type=positive_float, default=2.0, metavar="SECONDS", help="the small move's time (default: 2)"
    )
    srv.add_argument(
        "--observe",
        type=positive_float,
        default=3.0,
        metavar="SECONDS",
        help="watch the state topics this long before any motion (default: 3)",
    )
    srv.add_argument(
        "--state-rate",
        type=positive_float,
        metavar="HZ",
        help="the joint-state rate expected (default: any above 1 Hz)",
    )
    srv.add_argument(
        "--reply-timeout", type=positive_float, default=2.0, metavar="SECONDS", help="per reply (default: 2)"
    )
    srv.add_argument(
        "--unknown-type",
        type=positive_int,
        default=65535,
        metavar="TYPE",
        help="the msg_type sent as one nobody knows (default: 65535)",
    )
    srv.add_argument(
        "--only", action="append", default=[], metavar="RULE", help="run only the rules matching (glob; repeatable)"
    )
    srv.add_argument(
        "--skip", action="append", default=[], metavar="RULE", help="leave out the rules matching (glob; repeatable)"
    )
    _add_report_arguments(srv)
    add_import_argument(srv)
    srv.set_defaults(func=_server)

    cli = suites.add_parser("client", help="play a controller and judge the client that connects", description=_CLIENT)
    _add_profile(cli, "the controller family played")
    cli.add_argument("--host", default="127.0.0.1", help="the address to listen on (default: 127.0.0.1)")
    cli.add_argument(
        "--port",
        "--motion-port",
        dest="motion_port",
        type=server_port,
        metavar="PORT",
        help="the motion port to listen on (default: the profile's; 0: any free port)",
    )
    cli.add_argument("--state-port", type=server_port, metavar="PORT", help="the state port (default: the profile's)")
    cli.add_argument(
        "--io-port", type=server_port, metavar="PORT", help="the IO port (motoros; default: the profile's)"
    )
    cli.add_argument(
        "--byte-order", choices=("little", "big"), help="the byte order the controller speaks (default: the profile's)"
    )
    cli.add_argument("--float64", action="store_true", help="float64 reals (the FLOAT64 build)")
    cli.add_argument(
        "--controller",
        metavar="HOST:MOTION,STATE[,IO]",
        help="pass the client's traffic to this controller (default: start robot-server for the run)",
    )
    cli.add_argument(
        "--inject",
        default="busy,failure,drop",
        metavar="LIST",
        help="what to inject, comma-separated from busy, failure, drop; 'none' for nothing (default: all)",
    )
    cli.add_argument(
        "--start-tolerance",
        type=positive_float,
        default=0.001,
        metavar="RAD",
        help="a trajectory's first point within this of the current position (default: 0.001)",
    )
    cli.add_argument("--duration", type=positive_float, metavar="SECONDS", help="end the run after this long")
    cli.add_argument(
        "--linger",
        type=non_negative_float,
        default=5.0,
        metavar="SECONDS",
        help="end the run this long after the client closed its last connection (default: 5)",
    )
    _add_report_arguments(cli)
    add_import_argument(cli)
    cli.set_defaults(func=_client)


def _add_profile(parser: argparse.ArgumentParser, what: str, choices: Sequence[str] = _PROFILES) -> None:
    parser.add_argument(
        "--profile",
        choices=tuple(choices),
        default="generic",
        metavar="PROFILE",
        help=f"{what}: {', '.join(choices)} (default: generic)",
    )


def _add_report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the report as JSON")
    parser.add_argument("--junit", type=Path, metavar="FILE", help="also write the report as JUnit XML")
    parser.add_argument(
        "--evidence", action="store_true", help="print every rule's evidence (default: failed and warned)"
    )


def _finish(report: Report, args: argparse.Namespace) -> int:
    print(report.table(evidence=args.evidence), flush=True)
    try:
        if args.json is not None:
            args.json.write_text(report.dumps() + "\n", encoding="utf-8")
        if args.junit is not None:
            args.junit.write_text(report.junit(), encoding="utf-8")
    except OSError as exc:
        print(f"simple-message conformance: cannot write the report: {exc}", file=sys.stderr)
        return 2
    return report.exit_code


def _fail(message: str) -> int:
    print(f"simple-message conformance: {message}", file=sys.stderr)
    return 2


def _server(args: argparse.Namespace) -> int:
    try:
        options = ServerSuiteOptions(
            host=args.host,
            profile=args.profile,
            motion_port=args.motion_port,
            state_port=args.state_port,
            io_port=args.io_port,
            byte_order=None if args.byte_order == "auto" else args.byte_order,
            float_size=8 if args.float64 else None,
            allow_motion=args.allow_motion,
            amplitude=args.amplitude,
            joint=args.joint,
            tolerance=args.tolerance,
            observe=args.observe,
            move_time=args.move_time,
            reply_timeout=args.reply_timeout,
            state_rate=args.state_rate,
            unknown_type=args.unknown_type,
            only=tuple(args.only),
            skip=tuple(args.skip),
        )
    except ValueError as exc:
        return _fail(str(exc))
    report, interrupted = asyncio.run(_interruptible(ServerSuite(options)))
    code = _finish(report, args)
    if interrupted:
        print("simple-message conformance: interrupted; the rules not run are missing from the report", file=sys.stderr)
        return code or 2
    return code


async def _interruptible(suite: ServerSuite) -> tuple[Report, bool]:
    """Run the server suite; SIGINT or SIGTERM (a CI job's timeout) ends it the way a failing rule
    would: the motion under way is stopped (a STOP, and MotoROS's trajectory mode off), the
    connections closed, and the rules run so far reported."""
    task = asyncio.current_task()
    assert task is not None
    interrupted = False

    def interrupt() -> None:
        nonlocal interrupted
        interrupted = True
        task.cancel()

    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, interrupt)
    try:
        await suite.run()
    except asyncio.CancelledError:
        if not interrupted:
            raise
        task.uncancel()
    return suite.report, interrupted


def _client(args: argparse.Namespace) -> int:
    from .client import ClientSuiteOptions, run_client_suite

    inject = (
        frozenset()
        if args.inject.strip() == "none"
        else frozenset(p.strip() for p in args.inject.split(",") if p.strip())
    )
    unknown = inject - {"busy", "failure", "drop"}
    if unknown:
        return _fail(f"--inject: unknown {', '.join(sorted(unknown))} (known: busy, failure, drop, none)")
    upstream = None
    if args.controller:
        try:
            upstream = _controller(args.controller)
        except (ValueError, argparse.ArgumentTypeError) as exc:
            return _fail(f"--controller {args.controller}: {exc}")
    try:
        options = ClientSuiteOptions(
            profile=args.profile,
            host=args.host,
            motion_port=args.motion_port,
            state_port=args.state_port,
            io_port=args.io_port,
            byte_order=args.byte_order,
            float64=args.float64,
            upstream=upstream,
            inject=inject,
            start_tolerance=args.start_tolerance,
            duration=args.duration,
            linger=args.linger,
        )
    except ValueError as exc:
        return _fail(str(exc))

    def ready(ports: dict[str, int]) -> None:
        listening = ", ".join(f"{role} {args.host}:{port}" for role, port in ports.items())
        print(f"conformance client suite ready: {args.profile} profile, {listening}", flush=True)

    async def run() -> Report:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, stop.set)
        return await run_client_suite(options, on_ready=ready, stop=stop)

    try:
        report = asyncio.run(run())
    except (OSError, ValueError, RuntimeError) as exc:
        return _fail(str(exc))
    return _finish(report, args)


def _controller(text: str) -> dict[str, tuple[str, int]]:
    host, sep, ports = text.rpartition(":")
    if not sep or not host:
        raise ValueError("expected HOST:MOTION,STATE[,IO]")
    numbers = [client_port(p) for p in ports.split(",")]
    if len(numbers) not in (2, 3):
        raise ValueError("give the motion and state ports, and the IO port for motoros")
    roles = ("motion", "state", "io")
    return {role: (host.strip("[]"), port) for role, port in zip(roles, numbers, strict=False)}
