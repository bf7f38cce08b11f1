"""The server run, once per ``--profile``: the server started or found, fuzzed (:mod:`bench.fuzz.run`),
stopped, and its log read.

``robot-server`` is started as a child process on free loopback ports (``--motion-port 0`` ...:
the server picks them, no race), its log (``--log-level INFO``) going to a file; or a running server
is targeted (``--motion-port`` given; tracebacks are then counted only with ``--server-log``, RSS
only with ``--server-pid``, and the server's byte order and real size must be given:
``--byte-order``, ``--float64``).

Afterwards: whether the process exited 0 within 30 s of SIGTERM (else a **crash**), and the
``Traceback`` lines in its log, its size and lines per second. The last batches of every connection
are kept: a traceback's log line names the connection (the client port), whose last frames are
written to ``fuzz-<profile>-<port>.txt`` (``NAME HEX`` lines, readable by ``simple-message
decode``).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from .report import PortStats, ProfileReport
from .run import FuzzRun, Options, Target, rss_mb

#: fuzz connections per port where the server allows fewer than asked: one motion client at a time on
#: every profile (a newcomer replaces it while the robot is at rest), MotoROS's one IO client and
#: four state clients (the monitor takes one place, and one is left free for reconnections)
PORT_CAPS = {"motion": 1}
PROFILE_CAPS = {"motoros": {"state": 2, "io": 1}}


async def start_server(profile: str, options: Options, log_path: Path) -> tuple[asyncio.subprocess.Process, Target]:
    """``robot-server`` for ``profile`` on free loopback ports, logging (INFO) to ``log_path``, and
    ready (its ready line read: ports, byte order, real size); ``options.server_args`` appended."""
    exe = Path(sys.executable).with_name("robot-server")
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "robot_server"]
    command += ["--profile", profile, "--host", "127.0.0.1", "--motion-port", "0", "--state-port", "0"]
    if profile == "motoros":
        command += ["--io-port", "0"]
    command += ["--no-stdin", "--log-level", "INFO", *options.server_args]
    with log_path.open("wb") as log:
        proc = await asyncio.create_subprocess_exec(
            *command, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, stderr=log
        )
    assert proc.stdout is not None
    try:
        line = (await asyncio.wait_for(proc.stdout.readline(), 60.0)).decode(errors="replace")
    except TimeoutError:
        line = ""
    if not line.startswith("robot-server ready"):
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        await asyncio.wait_for(proc.wait(), 20.0)
        raise RuntimeError(f"robot-server did not start ({line.strip() or 'no ready line'}): {_tail(log_path).strip()}")
    ports = {name: int(port) for name, port in re.findall(r"(motion|state|io) 127\.0\.0\.1:(\d+)", line)}
    order = "auto" if "auto-detected" in line else ">" if "big-endian" in line else "<"
    real = 8 if "float64" in line else 4
    return proc, Target("127.0.0.1", ports, order, real, proc.pid, log_path)


def _tail(path: Path, size: int = 2000) -> str:
    return path.read_text(errors="replace")[-size:]


def _keep(report: ProfileReport, folder: Path) -> None:
    """Move the server log and the dumps out of a temporary ``folder`` that is about to go."""
    kept = Path(tempfile.mkdtemp(prefix="fuzz-kept-"))
    for item in folder.iterdir():
        item.rename(kept / item.name)
    report.dumps = [kept / d.name for d in report.dumps]
    if report.log_path is not None:
        report.log_path = kept / report.log_path.name


async def fuzz_server(profile: str, options: Options) -> ProfileReport:
    """One profile's server run (the module doc): start ``robot-server`` (or target the running one),
    fuzz every port, watch, stop, and read the log."""
    report = ProfileReport(profile, hang_after=options.hang_after)
    proc: asyncio.subprocess.Process | None = None
    tmp: tempfile.TemporaryDirectory[str] | None = None
    if options.external:
        ports = {"motion": options.motion_port, "state": options.state_port, "io": options.io_port}
        order = {"little": "<", "big": ">", "auto": "auto"}[options.byte_order]
        target = Target(
            options.host,
            {k: v for k, v in ports.items() if v is not None},
            order,
            8 if options.float64 else 4,
            options.server_pid,
            options.server_log,
        )
    else:
        if options.log_dir is None:
            tmp = tempfile.TemporaryDirectory(prefix="fuzz-")
            log_dir = Path(tmp.name)
        else:
            log_dir = options.log_dir
            log_dir.mkdir(parents=True, exist_ok=True)
        try:
            proc, target = await start_server(profile, options, log_dir / f"robot-server-{profile}.log")
        except BaseException:
            if tmp is not None:
                tmp.cleanup()
            raise
    report.log_path = target.log
    log_offset = target.log.stat().st_size if target.log is not None and options.external else 0
    try:
        await _fuzz(profile, options, target, report, proc)
    finally:
        if proc is not None and proc.returncode is None:
            proc.send_signal(signal.SIGTERM)
            try:
                report.exit_code = await asyncio.wait_for(proc.wait(), 30.0)
            except TimeoutError:
                proc.kill()
                report.exit_code = await asyncio.wait_for(proc.wait(), 10.0)
                report.notes.append("the server did not exit within 30 s of SIGTERM: killed")
                report.crashes += 1
            if report.exit_code != 0 and report.crashes == 0:
                report.notes.append(f"the server exited {report.exit_code} after SIGTERM")
                report.crashes += 1
        if target.log is not None and target.log.exists():
            _read_log(report, target.log, log_offset)
        keep = options.keep_logs or report.failures > 0
        if tmp is not None:
            if keep:
                _keep(report, Path(tmp.name))
            else:
                report.log_path = None
            tmp.cleanup()
    return report


async def _fuzz(
    profile: str, options: Options, target: Target, report: ProfileReport, proc: asyncio.subprocess.Process | None
) -> None:
    run = FuzzRun(options, profile, target, report)
    roles = [r for r in ("motion", "state", "io") if r in target.ports]
    caps = {**PORT_CAPS, **PROFILE_CAPS.get(profile, {}), "motion": options.motion_connections}
    for role in roles:
        report.ports[role] = PortStats()

    crashed = False

    def is_crashed() -> bool:
        return crashed or run.gone or (proc is not None and proc.returncode is not None)

    run.crashed = is_crashed
    tasks: list[asyncio.Task[None]] = []
    ready = asyncio.Event()
    monitor = asyncio.create_task(run.monitor(ready))
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(ready.wait(), 10.0)  # a first STATUS: the robot's state is known
    if not ready.is_set():
        report.notes.append("monitor: no STATUS within 10 s of connecting")
    if target.pid is not None:
        report.rss_before = rss_mb(target.pid)
        report.rss_max = report.rss_before
    start = time.monotonic()
    run.deadline = start + options.seconds
    waiter: asyncio.Task[Any] | None = None
    if proc is not None:
        waiter = asyncio.create_task(proc.wait())
    tasks.append(asyncio.create_task(run.probe()))
    tasks.append(asyncio.create_task(run.sample_rss()))
    tasks.append(asyncio.create_task(run.progress(start)))
    index = 0
    for role in roles:
        for _ in range(min(options.connections, caps.get(role, options.connections))):
            tasks.append(asyncio.create_task(run.worker(role, index)))
            index += 1
    stopper = asyncio.create_task(run.stopping.wait())
    try:
        waits: set[asyncio.Future[Any]] = {stopper}
        if waiter is not None:
            waits.add(waiter)
        done, _ = await asyncio.wait(waits, timeout=options.seconds + 5.0, return_when=asyncio.FIRST_COMPLETED)
        if waiter is not None and waiter in done:
            crashed = True
            report.crashes += 1
            report.exit_code = proc.returncode if proc is not None else None
            report.notes.append(f"the server exited during the run (status {report.exit_code})")
    finally:
        run.stop()
        report.seconds = time.monotonic() - start
        for task in tasks:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(task), 15.0)
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        stopper.cancel()
    if not is_crashed():
        # every fuzz connection is closed: one more probe (the server has caught up), then RSS
        if not await run._probe_once():
            report.notes.append("the server did not answer a PING after the run")
        # a few more state rounds, for motion that would come late
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(run.state_rounds(6), 2.0)
        if target.pid is not None:
            report.rss_after = rss_mb(target.pid)
            if report.rss_after is not None:
                report.rss_max = max(report.rss_max or 0.0, report.rss_after)
    monitor.cancel()
    await asyncio.gather(monitor, return_exceptions=True)
    if waiter is not None and not waiter.done():
        waiter.cancel()
        await asyncio.gather(waiter, return_exceptions=True)


_PEER = re.compile(r"\('127\.0\.0\.1', (\d+)\)")


def _read_log(report: ProfileReport, path: Path, offset: int) -> None:
    """Tracebacks, size and lines of the server's log (from ``offset``), and reproduction dumps."""
    rings = report.rings
    tracebacks = 0
    lines = 0
    previous = ""
    excerpt: list[str] = []
    collecting = False
    ports: list[int] = []
    with path.open("rb") as f:
        f.seek(offset)
        for raw in f:
            lines += 1
            line = raw.decode(errors="replace")
            if "Traceback" in line:
                tracebacks += 1
                match = _PEER.search(previous)
                if match and int(match.group(1)) not in ports:
                    ports.append(int(match.group(1)))
                if not excerpt:
                    excerpt = [previous.rstrip(), line.rstrip()]
                    collecting = True
            elif excerpt and collecting:
                if line[:4].isdigit() or len(excerpt) >= 40:  # the next log record
                    collecting = False
                else:
                    excerpt.append(line.rstrip())
            previous = line
    report.tracebacks = tracebacks
    report.log_lines = lines
    report.log_bytes = path.stat().st_size - offset
    report.traceback_excerpt = "\n".join(excerpt)
    for port in ports[:5]:
        for role, by_port in rings.items():
            batches = by_port.get(port)
            if batches:
                dump = path.with_name(f"fuzz-{report.profile}-{role}-{port}.txt")
                with dump.open("w") as out:
                    out.write(f"# the last {len(batches)} batches sent on {role} connection client port {port}\n")
                    for b, units in enumerate(batches):
                        for u, unit in enumerate(units):
                            out.write(f"b{b}u{u} {unit.hex()}\n")
                report.dumps.append(dump)
