"""Fleet benchmark: what a controller costs in a ``robot-server --fleet`` process, against one process each.

Plain script; prints tables. Targets (issue 38), on the machine it runs on:

* at rest, >= 100 controllers per core: each <= 1 % of a core and <= 10 MB of memory (the fleet's
  resident memory divided by its controllers);
* moving, >= 20 controllers per core in real time: every one streaming trajectories, the fleet's
  control wake-ups with 0 overruns (a wake-up more than one interpolation period late);
* the state rounds on time: lateness p99 <= 1 ms for every controller of a 50-controller fleet
  with a state client each (as the fleet measures it when each round goes out, and as the clients
  see it: how long after its place on the controller's schedule each round arrived).

Idle: a fleet of N controllers of every profile in turn (generic, motoros, abb, fanuc, staubli),
measured for ``--seconds`` after two seconds of settling: CPU time of the process (utime + stime)
per controller, its resident memory per controller. The comparison row: N ``robot-server``
processes, one controller each, measured in the same run the same way (summed). Moving: N generic
controllers, each with a client (this project's RobotDriver, in a separate process) streaming a
two-second swing back and forth for the whole window; each N at normal priority, then at real-time
priority (``--realtime-priority 50``, when the system grants it), with a sentinel on every CPU (a
timer at the highest real-time priority) whose late wake-ups, the stalls of that CPU, are shown
beside the fleet's overruns.
Jitter: 50 controllers of every profile at rest, each with a raw state client (a separate
process) that timestamps every round for ``--jitter-seconds`` (30) once every client has been
connected for a second (the fleet's own view covers its whole run, the connections' arrival
included); beside it, measured just before in the same run, a bare timer's lateness alone (the
machine's floor: what no process here does better).

``--soak MINUTES``: a 50-controller fleet with clients connecting, streaming, stopping and vanishing
(FIN and RST) at random for MINUTES; prints the fleet's RSS every minute and of it the private
anonymous memory (RssAnon: the heap, what a leak grows; the flatness is judged on it, as the kernel
may drop the shared libraries' pages from RSS at any time), its errors (tracebacks, ERROR lines)
and its overruns. ``--soak-clients N`` sessions run at once (default 6: the fleet stays below a core
on the 2-core VM; 12 saturate it, its controllers' time then falls behind the wall clock and the
backlog of waiting clients is what the memory measures).

    python bench/fleet.py [--counts 1,10,50,100,200] [--process-counts 1,10,50] [--moving 20,40] [--jitter 50]
                          [--seconds 10] [--jitter-seconds 30] [--skip idle,moving,jitter]
                          [--soak MINUTES [--soak-clients 6]]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import logging
import math
import os
import platform
import random
import re
import signal
import socket
import struct
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

PROFILES = ("generic", "motoros", "abb", "fanuc", "staubli")
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
PORTS = r"(?P<profile>\w+) profile, .*?motion [\d.]+:(?P<motion>\d+), state [\d.]+:(?P<state>\d+)"
READY = re.compile(r"^(?P<name>[\w-]+): robot-server ready: " + PORTS)
SINGLE = re.compile(
    r"^robot-server ready: (?P<profile>\w+) profile, .*?motion [\d.]+:(?P<motion>\d+), state [\d.]+:(?P<state>\d+)"
)
OVERRUNS = re.compile(r"control loop \(.*?\): (\d+) wake-ups, (\d+) overruns.*?latest ([\d.]+) ms")
STATE_REPORT = re.compile(
    r"state topics: (\d+) rounds, (\d+) skipped, lateness p99 ([\d.]+) ms \(the worst controller's p99 ([\d.]+) ms\), "
    r"latest ([\d.]+) ms"
)
#: the state rate of each profile (Hz): what a client's intervals are compared with
RATES = {"generic": 40.0, "motoros": 40.0, "abb": 10.0, "fanuc": 1 / 0.024, "staubli": 50.0}


@dataclass
class Controller:
    name: str
    profile: str
    motion: int
    state: int


@dataclass
class Running:
    """One or more robot-server processes and their controllers."""

    procs: list[asyncio.subprocess.Process]
    logs: list[Path]
    controllers: list[Controller] = field(default_factory=list)

    def cpu(self) -> float:
        """CPU seconds used so far by the processes together."""
        total = 0
        for proc in self.procs:
            with open(f"/proc/{proc.pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])
        return total / CLOCK_TICKS

    def rss(self, field: str = "VmRSS") -> float:
        """Resident memory of the processes together (MB): all of it (``VmRSS``), or the private
        anonymous memory alone (``RssAnon``: the heap; what a leak grows; the shared libraries'
        pages, which the kernel may drop and read again, are ``RssFile``)."""
        total = 0
        for proc in self.procs:
            with open(f"/proc/{proc.pid}/status") as status:
                for line in status:
                    if line.startswith(field + ":"):
                        total += int(line.split()[1])
        return total / 1024

    async def stop(self) -> list[str]:
        """SIGINT every process, wait (bounded), return their logs."""
        for proc in self.procs:
            if proc.returncode is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.procs:
            try:
                await asyncio.wait_for(proc.wait(), 60.0)
            except TimeoutError:
                proc.kill()
                await proc.wait()
        return [log.read_text(errors="replace") for log in self.logs]


def fleet_file(count: int, profiles: Sequence[str], folder: Path) -> Path:
    lines = []
    for k in range(count):
        profile = profiles[k % len(profiles)]
        lines += ["[[controller]]", f'name = "c{k}"', f'profile = "{profile}"', "motion_port = 0", "state_port = 0"]
        if profile == "motoros":
            lines.append("io_port = 0")
        lines.append("")
    path = folder / f"fleet{count}.toml"
    path.write_text("\n".join(lines))
    return path


async def _spawn(args: Sequence[str], log: Path, *, stdin: bool = False) -> asyncio.subprocess.Process:
    with log.open("wb") as err:
        return await asyncio.create_subprocess_exec(
            sys.executable, "-m", "robot_server", *args, *([] if stdin else ["--no-stdin"]),
            stdin=asyncio.subprocess.PIPE if stdin else None, stdout=asyncio.subprocess.PIPE, stderr=err,
        )  # fmt: skip


@contextlib.asynccontextmanager
async def fleet(
    count: int, profiles: Sequence[str], folder: Path, *, stdin: bool = False, extra: Sequence[str] = ()
) -> AsyncIterator[Running]:
    log = folder / f"fleet{count}.log"
    proc = await _spawn(["--fleet", str(fleet_file(count, profiles, folder)), *extra], log, stdin=stdin)
    running = Running([proc], [log])
    try:
        assert proc.stdout is not None
        async with asyncio.timeout(120.0):
            while len(running.controllers) < count:
                line = (await proc.stdout.readline()).decode()
                if not line:
                    raise RuntimeError(f"the fleet ended: {log.read_text()[-2000:]}")
                match = READY.match(line)
                if match:
                    running.controllers.append(
                        Controller(match["name"], match["profile"], int(match["motion"]), int(match["state"]))
                    )
            await proc.stdout.readline()  # the fleet's own ready line
        yield running
    finally:
        await running.stop()


@contextlib.asynccontextmanager
async def processes(count: int, profiles: Sequence[str], folder: Path) -> AsyncIterator[Running]:
    running = Running([], [])
    try:
        for k in range(count):
            profile = profiles[k % len(profiles)]
            log = folder / f"single{k}.log"
            extra = ["--io-port", "0"] if profile == "motoros" else []
            proc = await _spawn(["--profile", profile, "--motion-port", "0", "--state-port", "0", *extra], log)
            running.procs.append(proc)
            running.logs.append(log)
        for k, proc in enumerate(running.procs):
            assert proc.stdout is not None
            line = (await asyncio.wait_for(proc.stdout.readline(), 120.0)).decode()
            match = SINGLE.match(line)
            if match is None:
                raise RuntimeError(f"robot-server did not start: {line!r} {running.logs[k].read_text()[-2000:]}")
            running.controllers.append(Controller(f"p{k}", match["profile"], int(match["motion"]), int(match["state"])))
        yield running
    finally:
        await running.stop()


async def measure(running: Running, seconds: float, beside: Running | None = None) -> tuple[float, float, float]:
    """(share of a core, resident MB) of the processes over ``seconds`` after 2 s of settling, and
    the share of a core of the processes ``beside`` them (e.g. their clients) meanwhile."""
    await asyncio.sleep(2.0)
    cpu0, wall0 = running.cpu(), time.monotonic()
    other0 = beside.cpu() if beside is not None else 0.0
    await asyncio.sleep(seconds)
    wall = time.monotonic() - wall0
    other = (beside.cpu() - other0) / wall if beside is not None else 0.0
    return (running.cpu() - cpu0) / wall, running.rss(), other


# -- idle ----------------------------------------------------------------------------------------


async def idle(counts: Sequence[int], process_counts: Sequence[int], seconds: float, folder: Path) -> None:
    print("\n## At rest (no clients): cost per controller\n")
    print("| controllers | how | CPU per controller (% of a core) | RSS per controller (MB) | CPU total (%) |", end="")
    print(" RSS total (MB) |")
    print("|---:|---|---:|---:|---:|---:|")
    rows: list[tuple[int, str, float, float]] = []
    for count in sorted(set(counts) | set(process_counts)):
        if count in counts:
            async with fleet(count, PROFILES, folder) as running:
                share, rss, _ = await measure(running, seconds)
            rows.append((count, "one fleet process", share, rss))
            print(_idle_row(count, "one fleet process", share, rss), flush=True)
        if count in process_counts:
            async with processes(count, PROFILES, folder) as running:
                share, rss, _ = await measure(running, seconds)
            print(_idle_row(count, "one process each", share, rss), flush=True)
    good = [r for r in rows if r[0] >= 100 and r[2] / r[0] <= 0.01 and r[3] / r[0] <= 10.0]
    print(f"\ntarget (>= 100 controllers per core, <= 1 % and <= 10 MB each): {'met' if good else 'NOT met'}")


def _idle_row(count: int, how: str, share: float, rss: float) -> str:
    return f"| {count} | {how} | {100 * share / count:.3f} | {rss / count:.2f} | {100 * share:.1f} | {rss:.0f} |"


# -- moving --------------------------------------------------------------------------------------


#: the interpolation period of the moving fleet (a wake-up later than this is an overrun)
MOVING_PERIOD = 0.004


#: how late a wake-up of a sentinel (a timer at the highest real-time priority on one CPU) is when
#: that CPU did not run it: a stall of the CPU (its usual lateness is tens of microseconds: it runs
#: before anything else of this machine the moment it is due)
STALL = 0.001
#: the sentinels' period
SENTINEL_PERIOD = 0.002
#: the real-time priority the moving fleet is run at in its second row (ros2_control's default)
FLEET_PRIORITY = 50


async def moving(counts: Sequence[int], seconds: float, folder: Path) -> None:
    print("\n## Moving: every controller streaming (a RobotDriver each, in another process)\n")
    print(
        f"Each fleet at normal priority, then at real-time priority {FLEET_PRIORITY} (`--realtime-priority`, "
        f"when the system grants it). Meanwhile a sentinel on every CPU: a timer woken every "
        f"{SENTINEL_PERIOD * 1e3:g} ms at the highest real-time priority (it runs the moment it is due, "
        f"before anything else of this machine); its wake-ups {STALL * 1e3:g} ms late or more are stalls of its "
        "CPU (the hypervisor's or the kernel's), shown beside the fleet's overruns, not taken from them.\n"
    )
    print("| controllers | priority | CPU per controller (% of a core) | CPU total (%) | wake-ups | overruns |", end="")
    print(" latest wake-up (ms) | the CPUs' stalls meanwhile (latest, ms) | trajectories run | the clients' CPU (%) |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    verdicts: list[tuple[int, str, str]] = []
    for count in counts:
        floor_wakes, _, floor_latest, floor_over = await floor(MOVING_PERIOD, seconds + 4.0)
        print(
            f"| (a bare timer alone every {MOVING_PERIOD * 1e3:g} ms for as long, just before: the machine's floor, "
            "a lower bound: the control loop waits on the event loop's timer) "
            f"| normal | | | {floor_wakes} | {floor_over} | {floor_latest:.3f} | | | |"
        )
        for priority in (None, FLEET_PRIORITY):
            overruns = await _moving_row(count, seconds, folder, priority)
            if overruns is not None:
                verdicts.append((count, "normal" if priority is None else f"real-time {priority}", overruns))
    print()
    for count, how, overruns in verdicts:
        if count < 20:
            verdict = "not judged (the target is for 20 and more)"
        else:
            verdict = "met" if overruns == "0" else "NOT met"
        target = "0 at 20 per core"
        print(f"{count} controllers at {how} priority: {overruns} overruns (target, issue 38: {target}): {verdict}")


async def _moving_row(count: int, seconds: float, folder: Path, priority: int | None) -> str | None:
    """One row of the moving table; the fleet's overruns (None when the row could not be run: the
    real-time priority refused, said in the table)."""
    extra = [] if priority is None else ["--realtime-priority", str(priority)]
    how = "normal" if priority is None else f"real-time {priority}"
    children: list[asyncio.subprocess.Process] = []
    try:
        for cpu in sorted(os.sched_getaffinity(0)):  # before the fleet: their start costs it nothing
            sentinel = await asyncio.create_subprocess_exec(
                sys.executable, __file__, "_sentinel", str(SENTINEL_PERIOD * 1e3), str(seconds + 12.0), str(cpu),
                stdout=asyncio.subprocess.PIPE,
            )  # fmt: skip
            children.append(sentinel)
            assert sentinel.stdout is not None
            async with asyncio.timeout(30.0):
                if (await sentinel.stdout.readline()).strip() != b"ready":
                    raise RuntimeError("a sentinel did not start")
        async with fleet(count, ("generic",), folder, extra=extra) as running:
            started = running.logs[0].read_text()
            if priority is not None and "running at real-time priority" not in started:
                refused = re.search(r"--realtime-priority \d+: (.*)", started)
                print(f"| {count} | {how}: {refused[1] if refused else 'refused'} | | | | | | | | |", flush=True)
                return None
            ports = ",".join(f"{c.motion}:{c.state}" for c in running.controllers)
            client = await asyncio.create_subprocess_exec(
                sys.executable, __file__, "_stream", ports, str(seconds + 4.0), stdout=asyncio.subprocess.PIPE
            )
            children.append(client)
            share, _, client_share = await measure(running, seconds, Running([client], []))
            out, _ = await asyncio.wait_for(client.communicate(), 120.0)
            log = (await running.stop())[0]
        watched = [(await asyncio.wait_for(s.communicate(), 120.0))[0].decode() for s in children[:-1]]
    finally:
        for child in children:
            if child.returncode is None:
                child.kill()
                await asyncio.wait_for(child.wait(), 30.0)
    runs = out.decode().strip()
    match = OVERRUNS.search(log)
    wakes, overruns, latest = (match[1], match[2], match[3]) if match else ("?", "?", "?")
    stalls, stall_latest, policies = 0, 0.0, set()
    for text in watched:
        _, stalled, latest_ms, policy = text.split()
        stalls += int(stalled)
        stall_latest = max(stall_latest, float(latest_ms))
        policies.add(policy)
    watch = f"{stalls} ({stall_latest:.3f})" + ("" if policies == {"real-time"} else " (sentinels at normal priority)")
    errors = log.count("Traceback")
    print(
        f"| {count} | {how} | {100 * share / count:.2f} | {100 * share:.0f} | {wakes} | {overruns} | {latest} "
        f"| {watch} | {runs}" + (f" ({errors} tracebacks)" if errors else "") + f" | {100 * client_share:.0f} |",
        flush=True,
    )
    return overruns


def _sentinel(period_ms: str, seconds: float, cpu: int) -> None:
    """(child) On CPU ``cpu`` at the highest real-time priority (SCHED_FIFO, when allowed), a bare
    timer (the OS's own sleep: nothing imported, no event loop) woken every ``period_ms`` for
    ``seconds``. Prints ``ready`` once started, then its wake-ups, how many were :data:`STALL` late
    or more, the latest (ms) and its scheduling (``real-time`` or ``normal``)."""
    os.sched_setaffinity(0, {cpu})
    policy = "real-time"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(os.sched_get_priority_max(os.SCHED_FIFO)))
    except (PermissionError, AttributeError):
        policy = "normal"
    print("ready", flush=True)
    period = float(period_ms) / 1e3
    stalls = 0
    latest = 0.0
    wakes = 0
    start = time.monotonic()
    for k in range(1, round(seconds / period) + 1):
        deadline = start + k * period
        now = time.monotonic()
        if deadline > now:
            time.sleep(deadline - now)
            now = time.monotonic()
        wakes += 1
        late = now - deadline
        latest = max(latest, late)
        stalls += late >= STALL
    print(f"{wakes} {stalls} {latest * 1e3:.3f} {policy}")


async def _stream_client(ports: str, seconds: float) -> None:
    """(child) Stream a swing back and forth to every controller until ``seconds`` have passed."""
    import numpy as np

    from client.driver import RobotDriver
    from client.trajectory import Trajectory
    from robot_server import load_model

    model = load_model("jibot_zxs")
    times = np.linspace(0.0, 2.0, 41)
    shape = (1 - np.cos(np.pi * times / 2.0)) / 2
    swing = np.array([0.4, -0.3, 0.2, 0.0, 0.3, 0.0])
    out = Trajectory(times, np.outer(shape, swing))
    back = Trajectory(times, np.outer(1.0 - shape, swing))
    end = time.monotonic() + seconds
    done = 0

    failed: dict[str, int] = {}

    async def one(motion: int, state: int) -> None:
        nonlocal done
        try:
            async with RobotDriver("127.0.0.1", motion, state, model=model) as robot:
                trajectories = (out, back)
                k = 0
                while time.monotonic() < end:
                    await robot.execute(trajectories[k % 2])
                    k += 1
                    done += 1
        except Exception as exc:  # the controller fell behind (no state within the driver's watchdog...)
            reason = f"{type(exc).__name__}: {str(exc)[:60]}"
            failed[reason] = failed.get(reason, 0) + 1

    pairs = [tuple(int(p) for p in item.split(":")) for item in ports.split(",")]
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(seconds + 30.0):
            await asyncio.gather(*(one(m, s) for m, s in pairs))
    gave_up = sum(failed.values())
    print(f"{done}" + (f", {gave_up} clients gave up" if gave_up else ""))
    for reason, count in failed.items():
        print(f"{count} x {reason}", file=sys.stderr)


# -- jitter --------------------------------------------------------------------------------------


#: the clients' first second (all of them connecting at once, the fleet accepting them) is not timed
WARM_UP_S = 1.0
#: the bare timer's period (s): a wake-up every 2 ms, as the state rounds' slots
FLOOR_PERIOD = 0.002


async def jitter(count: int, seconds: float, folder: Path) -> None:
    print(f"\n## State rounds: {count} controllers of every profile at rest, a state client each, {seconds:g} s\n")
    wakes, p99, latest, _ = await floor(FLOOR_PERIOD, seconds)
    async with fleet(count, PROFILES, folder) as running:
        spec = ",".join(f"{c.state}:{c.profile}" for c in running.controllers)
        client = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "_watch", spec, str(seconds), stdout=asyncio.subprocess.PIPE
        )
        # the fleet's CPU while the clients are timed: what 50 controllers at rest with a client each cost
        await asyncio.sleep(WARM_UP_S)
        cpu0, wall0 = running.cpu(), time.monotonic()
        out, _ = await asyncio.wait_for(client.communicate(), seconds + 120.0)
        share = (running.cpu() - cpu0) / (time.monotonic() - wall0)
        log = (await running.stop())[0]
    print("| seen by | rounds | lateness p99, all (ms) | the worst controller's p99 (ms) | max (ms) |")
    print("|---|---:|---:|---:|---:|")
    print(out.decode().strip())
    match = STATE_REPORT.search(log)
    if match:
        print(
            f"| the fleet (lateness when each round went out; its whole run, the clients connecting included) "
            f"| {match[1]} ({match[2]} skipped) | {match[3]} | {match[4]} | {match[5]} |"
        )
    print(
        f"| a bare timer alone, every {FLOOR_PERIOD * 1e3:g} ms (the machine's floor, just before; lateness) "
        f"| {wakes} | {p99:.3f} | | {latest:.3f} |"
    )
    overruns = OVERRUNS.search(log)
    if overruns:
        print(f"\ncontrol wake-ups meanwhile: {overruns[1]}, overruns {overruns[2]}, latest {overruns[3]} ms")
    print(f"the fleet's CPU meanwhile: {100 * share:.1f} % of a core ({100 * share / count:.2f} % per controller)")


async def _watch_client(spec: str, seconds: float) -> None:
    """(child) Timestamp every state round of every controller for ``seconds`` after the first
    :data:`WARM_UP_S` (every client connected by then); print their lateness."""
    items = [(int(p), profile) for p, profile in (item.split(":") for item in spec.split(","))]
    rounds: list[list[float]] = [[] for _ in items]
    #: chunks closer than this are one round (a round is a few frames written together)
    gap = 0.004
    timing = False

    class Watch(asyncio.Protocol):
        def __init__(self, index: int) -> None:
            self.index = index
            self.last = 0.0

        def data_received(self, data: bytes) -> None:
            now = time.monotonic()
            if now - self.last > gap and timing:
                rounds[self.index].append(now)
            self.last = now

    loop = asyncio.get_running_loop()
    transports = []
    for index, (port, _) in enumerate(items):
        transport, _ = await loop.create_connection(lambda i=index: Watch(i), "127.0.0.1", port)  # type: ignore[misc]
        transports.append(transport)
    await asyncio.sleep(WARM_UP_S)
    timing = True
    await asyncio.sleep(seconds)
    for transport in transports:
        transport.close()
    # Each controller's rounds are due on one grid (origin + k x period, the fleet's clock being the
    # same CLOCK_MONOTONIC). The grid is placed where the controller's earliest rounds arrive (the
    # 1st percentile of the offsets from the nearest grid point), so a constant delay of the
    # delivery does not count; the fleet's own row is the lateness from the deadline. Each slot's
    # first arrival is its round (a round a stall cut in two counts once), up to a tenth of a
    # period early read as on time and up to 0.9 of a period late as late; a slot with no round is
    # a round missed (skipped by the fleet, or later than that). Each late round counts once,
    # unlike the interval between two rounds, which a late round makes long and the next short.
    lateness: list[float] = []
    worst = 0.0
    missed = 0
    for (_, profile), seen in zip(items, rounds, strict=True):
        if len(seen) < 2:
            continue
        period = 1.0 / RATES[profile]
        offsets = sorted(t - round((t - seen[0]) / period) * period for t in seen)
        origin = offsets[len(offsets) // 100]
        slots: dict[int, float] = {}
        for t in seen:
            x = (t - origin) / period
            k = math.floor(x + 0.1)
            slots.setdefault(k, max(0.0, x - k) * period)
        missed += max(slots) - min(slots) + 1 - len(slots)
        late = sorted(slots.values())
        lateness += late
        worst = max(worst, late[int(0.99 * (len(late) - 1))])
    lateness.sort()
    p99 = lateness[int(0.99 * (len(lateness) - 1))] if lateness else float("nan")
    peak = lateness[-1] if lateness else float("nan")
    print(
        f"| the clients (each round's arrival after the grid of its controller's earliest rounds; "
        f"from {WARM_UP_S:g} s after all connected) | {len(lateness)} ({missed} missed) | {p99 * 1e3:.3f} "
        f"| {worst * 1e3:.3f} | {peak * 1e3:.3f} |"
    )


async def _floor(period_ms: str, seconds: float) -> None:
    """(child) The machine's own wake-up lateness: a bare timer (the fleet's precise ticker) woken
    every ``period_ms`` for ``seconds``, nothing else running. Prints the wake-ups, the lateness
    p99 and maximum (ms), and how many were later than the period, space-separated."""
    from robot_server.emulator.ticker import Ticker

    period = float(period_ms) / 1e3
    ticker = Ticker()
    late: list[float] = []
    start = time.monotonic()
    for k in range(1, round(seconds / period) + 1):
        deadline = start + k * period
        await ticker.sleep_until(deadline)
        late.append(time.monotonic() - deadline)
    ticker.close()
    late.sort()
    over = sum(1 for x in late if x > period)
    print(f"{len(late)} {late[int(0.99 * (len(late) - 1))] * 1e3:.3f} {late[-1] * 1e3:.3f} {over}")


async def floor(period: float, seconds: float) -> tuple[int, float, float, int]:
    """:func:`_floor` in a child process: (wake-ups, lateness p99 ms, latest ms, later than the period)."""
    child = await asyncio.create_subprocess_exec(
        sys.executable, __file__, "_floor", str(period * 1e3), str(seconds), stdout=asyncio.subprocess.PIPE
    )
    out, _ = await asyncio.wait_for(child.communicate(), seconds + 60.0)
    wakes, p99, latest, over = out.decode().split()
    return int(wakes), float(p99), float(latest), int(over)


# -- soak ----------------------------------------------------------------------------------------

#: the soak's first minutes, when the controllers first serve clients (first plans, caches)
WARM_UP = 5


async def soak(minutes: float, clients: int, folder: Path) -> None:
    print(
        f"\n## Soak: 50 controllers of every profile, {clients} clients at a time coming and going at random "
        f"for {minutes:g} min\n"
    )
    async with fleet(50, PROFILES, folder, stdin=True) as running:
        spec = ",".join(f"{c.motion}:{c.state}:{c.profile}" for c in running.controllers)
        operator = asyncio.ensure_future(_operator(running.procs[0]))
        client = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "_chaos", spec, str(minutes * 60.0), str(clients), stdout=asyncio.subprocess.PIPE
        )
        print("| minute | RSS (MB) | of it private, RssAnon (MB) | CPU over the minute (% of a core) |")
        print("|---:|---:|---:|---:|")
        await asyncio.sleep(5.0)
        samples = [running.rss("RssAnon")]
        cpu0, wall0 = running.cpu(), time.monotonic()
        print(f"| 0 | {running.rss():.1f} | {samples[0]:.1f} | |", flush=True)
        for minute in range(1, int(minutes) + 1):
            await asyncio.sleep(max(0.0, wall0 + 60.0 - time.monotonic()))
            cpu1, wall1 = running.cpu(), time.monotonic()
            anon = running.rss("RssAnon")
            samples.append(anon)
            share = 100 * (cpu1 - cpu0) / (wall1 - wall0)
            print(f"| {minute} | {running.rss():.1f} | {anon:.1f} | {share:.0f} |", flush=True)
            cpu0, wall0 = cpu1, wall1
        out, _ = await asyncio.wait_for(client.communicate(), 300.0)
        operator.cancel()
        log = (await running.stop())[0]
    print(f"\nclients: {out.decode().strip()}")
    low, high = min(samples), max(samples)
    print(f"RssAnon: first {samples[0]:.1f} MB, last {samples[-1]:.1f} MB, range {low:.1f}..{high:.1f} MB")
    drift = max(abs(s - samples[0]) for s in samples)
    print(f"private memory flat within +-5 MB: {'yes' if drift <= 5.0 else 'NO'} (largest change {drift:.1f} MB)")
    if len(samples) > WARM_UP + 1:
        warm = samples[WARM_UP:]
        print(
            f"after the first {WARM_UP} minutes (every controller has served clients): {min(warm):.1f}..{max(warm):.1f}"
            f" MB, largest change from minute {WARM_UP} {max(abs(s - warm[0]) for s in warm):.1f} MB"
        )
    errors = [line for line in log.splitlines() if " ERROR " in line]
    print(f"tracebacks: {log.count('Traceback')}; ERROR lines: {len(errors)} (a played controller's own failures among")
    print("them: ABB's RAPID motion server stopping on garbage, as it does), the first:")
    for line in errors[:5]:
        print(f"  {line[:300]}")
    overruns = OVERRUNS.search(log)
    if overruns:
        print(f"control wake-ups: {overruns[1]}, overruns {overruns[2]}, latest {overruns[3]} ms")


async def _operator(proc: asyncio.subprocess.Process) -> None:
    """The cell's operator: every 20 s, resets every controller (a RAPID motion server that stopped on
    garbage starts again, an alarm a client caused is cleared), as one would at the pendant."""
    assert proc.stdin is not None
    while True:
        await asyncio.sleep(20.0)
        proc.stdin.write(b"all reset\n")
        await proc.stdin.drain()


async def _chaos_client(spec: str, seconds: float, workers: int = 6) -> None:
    """(child) Clients connect, stream, stop and vanish (FIN or RST) at random, for ``seconds``."""
    import numpy as np

    from client.driver import RobotDriver
    from client.trajectory import Trajectory
    from robot_server import load_model

    # the chaos's own aborts (a STOP not sent on a connection it cut) are counted, not logged
    logging.getLogger("client").setLevel(logging.ERROR)
    model = load_model("jibot_zxs")
    items = [(int(m), int(s), profile) for m, s, profile in (item.split(":") for item in spec.split(","))]
    end = time.monotonic() + seconds
    counts = {"sessions": 0, "streamed": 0, "stopped": 0, "rst": 0, "fin": 0, "garbage": 0, "failed": 0}
    reasons: collections.Counter[str] = collections.Counter()
    rng = random.Random(38)

    def swing(start: np.ndarray, amplitude: float) -> Trajectory:
        """From where the robot is (an earlier session may have left it anywhere on its way) to a
        goal of its own."""
        times = np.linspace(0.0, 1.0, 21)
        shape = (1 - np.cos(np.pi * times)) / 2
        goal = np.array([amplitude, -amplitude / 2, 0.1, 0.0, 0.2, 0.0])
        return Trajectory(times, start + np.outer(shape, goal - start))

    async def session(motion: int, state: int, profile: str) -> None:
        counts["sessions"] += 1
        what = rng.random()
        if what < 0.2:  # a raw client that sends garbage, or nothing, and vanishes
            _, writer = await asyncio.open_connection("127.0.0.1", rng.choice((motion, state)))
            if rng.random() < 0.5:
                writer.write(bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 200))))
                counts["garbage"] += 1
            await asyncio.sleep(rng.uniform(0.0, 0.5))
            _vanish(writer, rng, counts)
            return
        robot = RobotDriver("127.0.0.1", motion, state, profile=profile, model=model, goal_timeout=20.0)
        try:
            await robot.connect()
            start = (await robot.wait_state(5.0)).positions[:6]
        except BaseException:  # refused (another client moves that robot...): what it opened is closed
            await robot.close()
            raise
        task = asyncio.ensure_future(robot.execute(swing(start, rng.uniform(0.05, 0.4))))
        try:
            await asyncio.sleep(rng.uniform(0.1, 2.0))
            if task.done():
                counts["streamed"] += 1
                task.result()
            elif rng.random() < 0.5:
                await robot.stop()
                counts["stopped"] += 1
        finally:
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
            connection = robot.motion.connection
            if connection is not None and rng.random() < 0.3:  # the client vanishes: RST, nothing said
                sock = connection.transport.get_extra_info("socket")
                if sock is not None:
                    with contextlib.suppress(OSError):  # the controller closed it first: no RST to send
                        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                connection.transport.abort()
                counts["rst"] += 1
            else:
                counts["fin"] += 1
            await robot.close()

    async def worker() -> None:
        while time.monotonic() < end:
            motion, state, profile = rng.choice(items)
            try:
                async with asyncio.timeout(30.0):
                    await session(motion, state, profile)
            except Exception as exc:  # a refusal, a busy controller, a reset connection: the chaos itself
                counts["failed"] += 1
                reasons[_reason(exc)] += 1
            await asyncio.sleep(rng.uniform(0.0, 0.2))

    await asyncio.gather(*(worker() for _ in range(workers)))
    print(", ".join(f"{k} {v}" for k, v in counts.items()))
    why = "; ".join(f"{n} x {why}" for why, n in reasons.most_common(6)) or "none failed"
    print(f"why sessions failed (the most frequent): {why}")


def _reason(exc: BaseException) -> str:
    """An exception's kind and message, numbers (ports, times, counts) taken out: failures that
    differ in those only are counted as one."""
    return f"{type(exc).__name__}: {re.sub(r'[0-9]+(?:[.][0-9]+)*', '#', str(exc))[:90]}"


def _vanish(writer: asyncio.StreamWriter, rng: random.Random, counts: dict[str, int]) -> None:
    sock = writer.get_extra_info("socket")
    if sock is not None and rng.random() < 0.5:  # RST: linger 0
        with contextlib.suppress(OSError):  # the controller closed it first: no RST to send
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        counts["rst"] += 1
    else:
        counts["fin"] += 1
    writer.close()


# -- main ----------------------------------------------------------------------------------------


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


async def main(args: argparse.Namespace) -> None:
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    print(f"# Fleet benchmark: {machine}, Python {platform.python_version()}")
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        folder = Path(tmp)
        if args.soak is not None:
            await soak(args.soak, args.soak_clients, folder)
            return
        skip = set(args.skip.split(",")) if args.skip else set()
        if "idle" not in skip:
            await idle(_ints(args.counts), _ints(args.process_counts), args.seconds, folder)
        if "moving" not in skip:
            await moving(_ints(args.moving), args.seconds, folder)
        if "jitter" not in skip:
            for count in _ints(args.jitter):
                await jitter(count, args.jitter_seconds, folder)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1].startswith("_"):
        if sys.argv[1] == "_sentinel":  # no event loop: the OS's own sleep
            _sentinel(sys.argv[2], float(sys.argv[3]), int(sys.argv[4]))
            sys.exit(0)
        child = {"_stream": _stream_client, "_watch": _watch_client, "_chaos": _chaos_client, "_floor": _floor}[
            sys.argv[1]
        ]
        asyncio.run(child(sys.argv[2], float(sys.argv[3]), *map(int, sys.argv[4:])))
        sys.exit(0)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", default="1,10,50,100,200", help="fleet sizes at rest")
    parser.add_argument("--process-counts", default="1,10,50", help="one-process-per-controller comparison sizes")
    parser.add_argument("--moving", default="20,40", help="fleet sizes moving")
    parser.add_argument("--jitter", default="50", help="fleet sizes whose state rounds are timed (a client each)")
    parser.add_argument("--seconds", type=float, default=10.0, help="each measurement's window")
    parser.add_argument(
        "--jitter-seconds",
        type=float,
        default=30.0,
        help="the state rounds' window (a p99 per controller needs hundreds of its rounds: 30 s is 750 at 25 Hz)",
    )
    parser.add_argument("--skip", default="", help="idle, moving, jitter: parts to leave out")
    parser.add_argument("--soak", type=float, metavar="MINUTES", help="run the soak instead of the tables")
    parser.add_argument(
        "--soak-clients", type=_positive, default=6, metavar="N", help="the soak's sessions at a time (>= 1)"
    )
    asyncio.run(main(parser.parse_args()))
