"""The command, ``python -m bench.fuzz`` (from the repository's root): its options, the runs they ask
for (each profile's server run, then the decoder run), the table and the exit status.
"""

from __future__ import annotations

import argparse
import importlib
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from .decoder import DecoderReport, fuzz_decoder
from .report import HANG_AFTER, ProfileReport, decoder_details, details, table
from .run import Options
from .server import fuzz_server


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m bench.fuzz",
        description="Fuzz robot-server (every port of each profile) and the sans-I/O decoder with random and "
        "mutated frames that are never valid motion commands; prints a table, exits 1 on any failure.",
        epilog="What is sent (never a valid motion command), what is measured and what counts as a failure: "
        "the docstrings of bench/fuzz/ (its __init__.py says which module has what).",
    )
    p.add_argument("--profile", nargs="+", default=["generic", "motoros"], help="default: generic motoros")
    p.add_argument("--frames", type=int, default=1_000_000, help="frames per profile (default %(default)s)")
    p.add_argument("--seconds", type=float, default=300.0, help="time limit per profile (default %(default)s)")
    p.add_argument("--connections", type=int, default=8, help="concurrent connections per port (default 8)")
    p.add_argument(
        "--motion-connections",
        type=int,
        default=1,
        help="motion-port connections (default 1: the server takes one motion client at a time, a newcomer "
        "replaces it; more fuzzes that churn)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch", type=int, default=128, help="frames per write (default %(default)s)")
    p.add_argument("--window", type=int, default=4, help="unanswered batches per connection (default 4)")
    p.add_argument("--probe-interval", type=float, default=0.5, metavar="S", help="PING probe period (default 0.5)")
    p.add_argument(
        "--hang-after",
        type=float,
        default=HANG_AFTER,
        metavar="S",
        help="a PING unanswered, or the state port silent, this long is a hang (default %(default)s)",
    )
    p.add_argument("--decoder-frames", type=int, default=1_000_000, help="0: no decoder run (default %(default)s)")
    p.add_argument("--decoder-seconds", type=float, default=None, help="time limit of the decoder run")
    p.add_argument("--host", default="127.0.0.1", help="a running server's address (default 127.0.0.1)")
    p.add_argument("--motion-port", type=int, help="target a running server (one --profile)")
    p.add_argument("--state-port", type=int)
    p.add_argument("--io-port", type=int)
    p.add_argument("--server-log", type=Path, help="a running server's log file (for tracebacks)")
    p.add_argument("--server-pid", type=int, help="a running server's process id (for RSS and crashes)")
    p.add_argument("--byte-order", choices=("little", "big", "auto"), default="little", help="a running server's")
    p.add_argument("--float64", action="store_true", help="a running server's reals are float64")
    p.add_argument(
        "--server-args",
        default="",
        metavar="ARGS",
        help="more robot-server arguments, e.g. --server-args='--byte-order auto' or --server-args=--float64",
    )
    p.add_argument("--log-dir", type=Path, help="where the server logs go (default: a temporary directory)")
    p.add_argument("--keep-logs", action="store_true", help="keep the logs also when nothing failed")
    p.add_argument("--fatal-rate", type=float, default=1 / 1000, help="units that end a connection (default 0.001)")
    p.add_argument("--max-rss-growth", type=float, help="MB; a larger growth counts as a failure")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


def options_from(args: argparse.Namespace) -> Options:
    return Options(
        profiles=tuple(args.profile),
        frames=args.frames,
        seconds=args.seconds,
        connections=max(1, args.connections),
        motion_connections=max(1, args.motion_connections),
        seed=args.seed,
        batch=max(1, args.batch),
        window=max(1, args.window),
        probe_interval=args.probe_interval,
        hang_after=args.hang_after,
        decoder_frames=args.decoder_frames,
        host=args.host,
        motion_port=args.motion_port,
        state_port=args.state_port,
        io_port=args.io_port,
        server_log=args.server_log,
        server_pid=args.server_pid,
        byte_order=args.byte_order,
        float64=args.float64,
        server_args=tuple(shlex.split(args.server_args)),
        log_dir=args.log_dir,
        keep_logs=args.keep_logs,
        fatal_rate=args.fatal_rate,
        quiet=args.quiet,
    )


async def _main(options: Options, decoder_seconds: float | None) -> tuple[list[ProfileReport], DecoderReport | None]:
    reports = []
    for profile in options.profiles:
        if not options.quiet:
            print(f"# {profile}: up to {options.frames:,} frames or {options.seconds:g} s", file=sys.stderr)
        reports.append(await fuzz_server(profile, options))
    decoder = None
    if options.decoder_frames > 0:
        if not options.quiet:
            print(f"# decoder: {options.decoder_frames:,} frames", file=sys.stderr)
        decoder = fuzz_decoder(options.decoder_frames, options.seed, seconds=decoder_seconds)
    return reports, decoder


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    options = options_from(args)
    if options.external and len(options.profiles) != 1:
        parser().error("a running server (--motion-port) is fuzzed with exactly one --profile")
    if options.external and options.state_port is None:
        parser().error("a running server needs --state-port too (the motion monitor)")
    try:
        from simple_message.endpoints import run

        reports, decoder = run(_main(options, args.decoder_seconds))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (RuntimeError, OSError) as exc:  # robot-server did not start, a port is not there...
        print(f"python -m bench.fuzz: {exc}", file=sys.stderr)
        return 2
    # the benchmarks' machine line; imported by name, as bench/codec.py is a script outside the typed tree
    machine = importlib.import_module("bench.codec").machine
    print(f"# {machine()}; seed {options.seed}")
    print()
    print(table(reports, decoder))
    print()
    for r in reports:
        print(details(r))
    if decoder is not None:
        print(decoder_details(decoder))
    failures = sum(r.failures for r in reports) + (decoder.failure_count if decoder else 0)
    if args.max_rss_growth is not None:
        grown = [r for r in reports if r.rss_growth is not None and r.rss_growth > args.max_rss_growth]
        for r in grown:
            print(f"RSS growth of {r.profile}: {r.rss_growth:+.1f} MB > {args.max_rss_growth} MB")
        failures += len(grown)
    print()
    print(f"{'FAILED' if failures else 'passed'}: {failures} failures")
    return 1 if failures else 0
