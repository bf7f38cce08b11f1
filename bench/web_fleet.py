"""Web view benchmark: what the fleet's web view costs a fleet at rest, with no page, the index or a page open.

Plain script; prints a table. Target (issue 38): a fleet's controllers at rest cost (almost) nothing
more with ``--web`` while no page is open; the index costs little per controller while it is open.

A fleet of N controllers of every profile in turn (generic, motoros, abb, fanuc, staubli), no
clients, runs in this process with its web view on 127.0.0.1; the CPU time of the process (every
thread) is measured for ``--seconds`` after one second of settling, in each of these cases, all in
the same run:

* no web view (the fleet alone);
* the web view, no page open (each controller's page samples only while open: nothing runs);
* the web view with every controller sampled as if a page of each were open, but none is: what each
  controller's view cost with no page before it sampled only while open (the comparison row);
* the index open: another process reads ``/fleet.json`` every ``INDEX_PERIOD`` seconds, as the
  index page does;
* one controller's page open: another process reads its WebSocket at the default 30 updates a second.

It also times, in the process and without HTTP, one ``/fleet.json`` answer (per request and per
controller) and one sample of a controller's page (``Feed.sample``, per profile): ``rate`` of those a
second is what each controller cost with no page before, whatever else loads the machine.

    python bench/web_fleet.py [--counts 20,50,100] [--seconds 5] [--runs 1]

A count beyond what the machine runs at rest (the fleet alone near 100 % of a core) measures nothing:
the fleet is behind and the cases only share what is left.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import platform
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path

from robot_server.fleet import Fleet, load_fleet
from robot_server.web import fleet_view
from robot_server.web.fleet import INDEX_PERIOD, FleetView

PROFILES = ("generic", "motoros", "abb", "fanuc", "staubli")
CASES = ("no web view", "web view, no page", "every controller sampled (before)", "index open", "one page open")


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def fleet_file(count: int, folder: Path) -> Path:
    lines = []
    for k in range(count):
        profile = PROFILES[k % len(PROFILES)]
        lines += ["[[controller]]", f'name = "c{k}"', f'profile = "{profile}"', "motion_port = 0", "state_port = 0"]
        if profile == "motoros":
            lines.append("io_port = 0")
        lines.append("")
    path = folder / f"fleet{count}.toml"
    path.write_text("\n".join(lines))
    return path


@contextlib.asynccontextmanager
async def running(count: int, folder: Path, web: bool) -> AsyncIterator[tuple[Fleet, FleetView | None]]:
    fleet = Fleet(load_fleet(fleet_file(count, folder)))
    view = fleet_view(fleet.emulators, "127.0.0.1", 0, run_as=fleet.run_as) if web else None
    await fleet.start()
    try:
        if view is not None:
            await view.start()
        yield fleet, view
    finally:
        if view is not None:
            await view.close()
        await fleet.close()


@contextlib.asynccontextmanager
async def client(kind: str, url: str, seconds: float) -> AsyncIterator[None]:
    """Another process reading the index (``index``) or one page's WebSocket (``page``)."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, __file__, "--client", kind, url, str(seconds + 5.0), stdout=asyncio.subprocess.DEVNULL
    )  # fmt: skip
    try:
        yield
    finally:
        if proc.returncode is None:
            proc.terminate()
        await proc.wait()


async def measure(seconds: float) -> float:
    await asyncio.sleep(1.0)  # settling
    cpu0, wall0 = cpu(), time.monotonic()
    await asyncio.sleep(seconds)  # measuring an interval
    return (cpu() - cpu0) / (time.monotonic() - wall0)


async def case(count: int, how: str, seconds: float, folder: Path) -> float:
    async with running(count, folder, how != CASES[0]) as (_, view):
        if how == CASES[2]:
            assert view is not None
            for controller in view.controllers.values():
                controller._first_page()  # sampling as if a page were open
        if how == CASES[3]:
            assert view is not None
            async with client("index", view.url + "fleet.json", seconds):
                return await measure(seconds)
        if how == CASES[4]:
            assert view is not None
            async with client("page", view.controller_url("c0") + "ws", seconds):
                return await measure(seconds)
        return await measure(seconds)


async def summary_time(count: int, folder: Path) -> float:
    async with running(count, folder, True) as (_, view):
        assert view is not None
        rounds = 20
        began = time.perf_counter()
        for _ in range(rounds):
            view.summary()
        return (time.perf_counter() - began) / rounds


async def sample_time(folder: Path) -> dict[str, float]:
    """One ``Feed.sample`` per profile (s), the median of 200."""
    async with running(len(PROFILES), folder, True) as (fleet, view):
        assert view is not None
        times = {}
        for name, controller in view.controllers.items():
            spent = []
            for _ in range(200):
                began = time.perf_counter()
                controller.feed.sample()
                spent.append(time.perf_counter() - began)
            times[fleet[name].config.profile] = statistics.median(spent)
        return times


async def main(args: argparse.Namespace) -> None:
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    print(f"# Web view of a fleet at rest ({machine}; {args.seconds:g} s per case, median of {args.runs})\n")
    print("| controllers | case | CPU total (% of a core) | CPU per controller (%) ", end="")
    print("| over no web view (% per controller) |")
    print("|---:|---|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for count in args.counts:
            base = 0.0
            for how in CASES:
                share = statistics.median([await case(count, how, args.seconds, folder) for _ in range(args.runs)])
                if how == CASES[0]:
                    base = share
                extra = "" if how == CASES[0] else f"{100 * (share - base) / count:+.3f}"
                print(f"| {count} | {how} | {100 * share:.1f} | {100 * share / count:.3f} | {extra} |", flush=True)
        print(f"\n/fleet.json, made in the process (the index reads it every {INDEX_PERIOD:g} s while open):\n")
        print("| controllers | one answer (ms) | per controller (us) |")
        print("|---:|---:|---:|")
        for count in args.counts:
            spent = await summary_time(count, folder)
            print(f"| {count} | {1e3 * spent:.2f} | {1e6 * spent / count:.1f} |", flush=True)
        rate = 30.0
        print(f"\nOne sample of a controller's page, and {rate:g} a second (the default rate) as a share of a core:\n")
        print("| profile | one sample (us) | at 30 a second (% of a core) |")
        print("|---|---:|---:|")
        for profile, spent in (await sample_time(folder)).items():
            print(f"| {profile} | {1e6 * spent:.1f} | {100 * rate * spent:.3f} |", flush=True)


def run_client(kind: str, url: str, seconds: float) -> None:
    import aiohttp

    async def index() -> None:
        async with aiohttp.ClientSession() as http:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                async with http.get(url) as response:
                    await response.json()
                await asyncio.sleep(INDEX_PERIOD)  # the index page's period

    async def page() -> None:
        async with aiohttp.ClientSession() as http, http.ws_connect(url) as ws, asyncio.timeout(seconds):
            async for _ in ws:
                pass

    with contextlib.suppress(TimeoutError, aiohttp.ClientError):
        asyncio.run(index() if kind == "index" else page())


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", type=_ints, default=[20, 50, 100], help="fleet sizes (default 20,50,100)")
    parser.add_argument("--seconds", type=float, default=5.0, help="measured seconds per case (default 5)")
    parser.add_argument("--runs", type=int, default=1, help="runs per case, the median kept (default 1)")
    parser.add_argument("--client", nargs=3, metavar=("KIND", "URL", "SECONDS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        run_client(args.client[0], args.client[1], float(args.client[2]))
    else:
        import logging

        logging.basicConfig(level=logging.WARNING)
        asyncio.run(main(args))
