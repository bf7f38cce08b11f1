"""One profile's server run in progress (:class:`FuzzRun`): the fuzz connections, the probe, the
state monitor and the RSS sampler, all on one event loop; :mod:`bench.fuzz.server` starts and ends it.

Every port of the profile (motion, state, and io for motoros) is driven over ``--connections``
concurrent connections each, fewer where the server takes fewer: the motion port has one client at a
time on every profile (a newcomer replaces it while the robot is at rest), so it gets one connection
with ``--connections`` times the window instead; MotoROS takes one IO client and four state clients
(the monitor has one place, one is left free for reconnections: two fuzz). Until ``--frames`` frames
are sent or ``--seconds`` have passed, each connection writes batches of ``--batch`` frames at once
(coalesced frames), one in 20 split over several writes at random byte offsets, and reads whatever
comes back (in either byte order where the server detects it: until a connection's first frame is
read, it gets the topics in the order of the last motion client). Meanwhile:

* a **monitor** on the state port reads JOINT_POSITION (10), JOINT_FEEDBACK (15) and STATUS (13)
  with :mod:`struct` (not the project's decoder) from start to end: any joint position more than
  1e-6 rad away from the first one seen, or ``in_motion`` TRUE, counts as **motion**; a state
  silence of more than 1 s counts as a **hang**. It sends a PING every 2 s (harmless: a state port
  never closes a client for being silent, but a server with other rules may);
* a **probe** opens a fresh connection to the motion port every ``--probe-interval`` seconds and
  sends a PING, which must be answered within 1 s, else a **hang** (a connection closed without the
  answer counts too; the motion fuzzer does not reconnect while the probe runs, since a newcomer
  replaces the motion client);
* every fuzz connection's batches end with a PING *marker* (when the stream is at a frame
  boundary), at most ``--window`` markers unanswered per connection: flow control, and the count of
  frames the server confirmably processed. A connection that gets no answer for 10 s is a
  **hang** (stalled) too;
* the server's RSS (``VmRSS`` of ``/proc/PID/status``) before, during (max) and after; whether the
  process exited (a **crash**).
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import struct
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .connection import CONNECT_TIMEOUT, Sink, connect, keep_alive
from .generator import Generator, load_corpus
from .protocol import HEAD, HEADER, INT, MOTOROS_CLOSING, PING, detect, frame_of, ping_request
from .report import HANG_AFTER, PortStats, ProfileReport
from .safety import Shadow

STALL_TIMEOUT = 10.0  # s without an answer to an outstanding marker: the connection is stalled
CLOSE_TIMEOUT = 5.0  # s for the server to close a connection after a fatal length prefix
KEEP_BATCHES = 8  # batches kept per connection for a traceback's reproduction
KEEP_CLOSED = 64  # closed connections whose batches are kept, per port


@dataclass
class Options:
    """Everything the command line sets (:mod:`bench.fuzz.cli` has the help)."""

    profiles: tuple[str, ...] = ("generic", "motoros")
    frames: int = 1_000_000
    seconds: float = 300.0
    connections: int = 8
    #: the motion port takes one client at a time (a newcomer replaces it): more is churn on purpose
    motion_connections: int = 1
    seed: int = 0
    batch: int = 128
    window: int = 4
    probe_interval: float = 0.5
    hang_after: float = HANG_AFTER
    decoder_frames: int = 1_000_000
    host: str = "127.0.0.1"
    motion_port: int | None = None
    state_port: int | None = None
    io_port: int | None = None
    server_log: Path | None = None
    server_pid: int | None = None
    byte_order: str = "little"  # of a running server: little, big, auto
    float64: bool = False  # of a running server
    server_args: tuple[str, ...] = ()
    log_dir: Path | None = None
    keep_logs: bool = False
    fatal_rate: float = 1 / 1000
    quiet: bool = False

    @property
    def external(self) -> bool:
        return self.motion_port is not None


@dataclass
class Target:
    """The server fuzzed: where, its byte order and real size, its process and log if known."""

    host: str
    ports: dict[str, int]
    order: str  # "<", ">", "auto"
    real: int
    pid: int | None
    log: Path | None


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        return None
    return None


def _alive(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists()


class FuzzRun:
    """One profile's server run in progress."""

    def __init__(self, options: Options, profile: str, target: Target, report: ProfileReport) -> None:
        self.options = options
        self.profile = profile
        self.target = target
        self.report = report
        self.corpus = load_corpus()
        self.stopping = asyncio.Event()
        self.state_tick = asyncio.Event()  # set by the monitor at each state message
        self.total = 0
        #: the motion probe and the motion fuzzers take turns connecting (a newcomer replaces the client)
        self.gate = asyncio.Lock()
        self.rings = report.rings
        self.sinks: set[Sink] = set()
        self.closed_order: dict[str, deque[int]] = {}
        self.seed = random.Random(f"{options.seed}:{profile}")
        self.deadline = 0.0
        self.crashed: Callable[[], bool] = lambda: False
        self.gone = False  # a running server's process ended (``--server-pid``)

    def stop(self) -> None:
        self.stopping.set()
        for sink in self.sinks:
            sink.notify()

    # the fuzz connections

    async def worker(self, role: str, index: int) -> None:
        port = self.target.ports[role]
        stats = self.report.ports[role]
        use_gate = role == "motion"
        loop = asyncio.get_running_loop()
        rings = self.rings.setdefault(role, {})
        closed = self.closed_order.setdefault(role, deque())
        rng = random.Random(self.seed.getrandbits(64) ^ index)
        while not self.stopping.is_set():
            order = self.target.order
            if order == "auto":
                order = rng.choice("<<>")  # the connection's first frame decides
            sink = Sink(order, either=self.target.order == "auto")
            try:
                if use_gate:
                    async with self.gate:
                        transport = await connect(loop, sink, self.target.host, port)
                else:
                    transport = await connect(loop, sink, self.target.host, port)
            except (OSError, TimeoutError):
                stats.connect_failures += 1
                if self.crashed():
                    return
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.stopping.wait(), 0.05)  # a tool's back-off, not a sync
                continue
            stats.connections += 1
            local = transport.get_extra_info("sockname")[1]
            ring: deque[list[bytes]] = deque(maxlen=KEEP_BATCHES)
            rings[local] = ring
            self.sinks.add(sink)
            try:
                await self._drive(role, rng, order, sink, transport, stats, ring)
            finally:
                self.sinks.discard(sink)
                stats.confirmed += sink.confirmed
                if sink.bad:
                    stats.bad_replies += 1
                    self.report.notes.append(f"{role}: a reply could not be framed: {sink.rbuf[:64].hex()}")
                if self.stopping.is_set():
                    transport.abort()
                else:
                    transport.close()
                closed.append(local)
                while len(closed) > KEEP_CLOSED:
                    rings.pop(closed.popleft(), None)

    async def _drive(
        self,
        role: str,
        rng: random.Random,
        order: str,
        sink: Sink,
        transport: asyncio.Transport,
        stats: PortStats,
        ring: deque[list[bytes]],
    ) -> None:
        options = self.options
        rare = MOTOROS_CLOSING if self.profile == "motoros" and role == "motion" else frozenset()
        # the motion port has one client: it gets more batches in flight, for its share of the frames
        window = options.window * (max(1, options.connections // options.motion_connections) if role == "motion" else 1)
        gen = Generator(rng, order, self.target.real, self.corpus, fatal_rate=options.fatal_rate, rare_types=rare)
        shadow = Shadow(self.target.order if self.target.order == "auto" else order, rare=rare, rng=rng)
        sent = 0
        if self.target.order == "auto":  # the first frame decides the connection's order: an honest one
            first = shadow.add(gen.well_formed())
            if first is not None:
                transport.write(first)
                ring.append([first])
                sent = 1
                stats.frames += 1
                stats.bytes += len(first)
                self.total += 1
        marker = ping_request(order)
        while not self.stopping.is_set():
            while (len(sink.outstanding) >= window or sink.paused) and not sink.closed:
                if not await sink.wait(STALL_TIMEOUT) and not self.stopping.is_set():
                    stats.stalls += 1
                    self.report.notes.append(
                        f"{role} connection (client port {transport.get_extra_info('sockname')[1]}) stalled: "
                        f"{len(sink.outstanding)} markers unanswered for {STALL_TIMEOUT:g} s"
                    )
                    return
                if self.stopping.is_set():
                    return
            if sink.closed:
                stats.server_closed += 1
                return
            units: list[bytes] = []
            stuck = False
            frames = 0
            for _ in range(options.batch):
                aligned = not shadow.pending
                for _attempt in range(8):
                    unit = shadow.add(gen.unit())
                    if unit is not None:
                        break
                    stats.rejected += 1
                else:  # nothing may follow what the server holds: complete it with poison, or give up
                    filler = shadow.filler(rng)
                    unit = None if filler is None else shadow.add(filler)
                    if unit is None:
                        stuck = True
                        break
                if shadow.fatal and aligned:  # a marker just before it: what came before is confirmed
                    units.append(marker)
                    shadow.type1 += 1
                    sink.outstanding.append(sent + frames)
                    stats.markers += 1
                units.append(unit)
                frames += 1
                if shadow.fatal:
                    break
            if not shadow.fatal and not shadow.pending:
                m = shadow.add(marker, marker=True)
                if m is not None:
                    units.append(m)
                    sink.outstanding.append(sent + frames)
                    stats.markers += 1
            data = b"".join(units)
            ring.append(units)
            if rng.random() < 0.05 and len(data) > 1:  # split across writes
                cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, rng.randint(1, 3))))
                pieces = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
                for piece in pieces:
                    if not sink.alive():
                        break
                    transport.write(piece)
                    if piece is not pieces[-1]:  # let it go out alone
                        await asyncio.sleep(0 if rng.random() < 0.8 else 0.002)
            else:
                transport.write(data)
            sent += frames
            stats.frames += frames
            stats.bytes += len(data)
            self.total += frames
            if self.total >= options.frames or time.monotonic() >= self.deadline:
                self.stop()
            if stuck:  # the server holds part of a frame that nothing safe completes: this connection ends
                stats.abandoned += 1
                return
            if shadow.fatal:
                stats.fatal += 1
                deadline = time.monotonic() + CLOSE_TIMEOUT
                while not sink.closed and not self.stopping.is_set() and time.monotonic() < deadline:
                    await sink.wait(deadline - time.monotonic())
                if not sink.closed and not self.stopping.is_set():
                    stats.unclosed += 1
                    self.report.notes.append(
                        f"{role}: the server did not close the connection within {CLOSE_TIMEOUT:g} s of a bad "
                        f"length prefix; last units: {' '.join(u.hex() for u in units[-2:])}"
                    )
                return

    # the probe, the monitor, the RSS sampler

    async def probe(self) -> None:
        interval = self.options.probe_interval
        while not self.stopping.is_set():
            async with self.gate:  # the motion fuzzer does not take the port back meanwhile
                await self._probe_once()
            if self.crashed():
                return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), interval)

    async def _probe_once(self) -> bool:
        report = self.report
        report.probes += 1
        order = "<" if self.target.order == "auto" else self.target.order
        start = time.monotonic()
        problem = ""
        writer: asyncio.StreamWriter | None = None
        try:
            async with asyncio.timeout(report.hang_after):
                reader, writer = await asyncio.open_connection(self.target.host, self.target.ports["motion"])
                writer.write(ping_request(order))
                reply = await reader.readexactly(HEADER)
                if HEAD[order].unpack(reply) != (12, PING, 3, 1):
                    problem = f"unexpected reply {reply.hex()}"
        except TimeoutError:
            problem = f"no reply within {report.hang_after:g} s"
        except (OSError, asyncio.IncompleteReadError) as exc:
            problem = f"{type(exc).__name__}: {exc}"
        finally:
            if writer is not None:
                writer.close()
        elapsed = time.monotonic() - start
        report.probe_max = max(report.probe_max, elapsed)
        if problem:
            report.probe_failures += 1
            report.hangs += 1
            if report.probe_failures <= 5:
                report.notes.append(f"probe {report.probes} at {elapsed:.3f} s: {problem}")
        return not problem

    async def monitor(self, ready: asyncio.Event) -> None:
        """The state port, read with struct: motion and silence (the module doc)."""
        report = self.report
        real = self.target.real
        rc = "f" if real == 4 else "d"
        reference: dict[tuple[int, int], tuple[float, ...]] = {}
        last = time.monotonic()
        while True:
            try:
                reader, writer = await asyncio.wait_for(
                    asyncio.open_connection(self.target.host, self.target.ports["state"]), CONNECT_TIMEOUT
                )
            except (OSError, TimeoutError) as exc:
                report.notes.append(f"monitor: cannot connect to the state port: {exc}")
                return
            order = "<" if self.target.order == "auto" else self.target.order
            if self.profile == "generic":  # ask for JOINT_FEEDBACK too (any JOINT_FEEDBACK frame)
                writer.write(frame_of(order, 15, 1, 0, struct.pack(f"{order}2i31{rc}", 0, 0, *[0.0] * 31)))
            # a PING now and then: a full server closes a client silent for 10 s to make room
            keepalive = asyncio.create_task(keep_alive(writer, ping_request(order), self.stopping))
            try:
                while True:
                    prefix = await reader.readexactly(4)
                    head = detect(prefix)
                    if head is None:
                        report.notes.append(f"monitor: a state frame that cannot be framed: {prefix.hex()}")
                        break
                    rest = await reader.readexactly(head.unpack(prefix)[0])
                    order = "<" if head is INT["<"] else ">"
                    msg_type = INT[order].unpack_from(rest, 0)[0]
                    if msg_type not in (10, 13, 15, 2017):  # the keepalive's answers
                        continue
                    now = time.monotonic()
                    gap = now - last
                    last = now
                    report.state_max_gap = max(report.state_max_gap, gap)
                    if gap > report.hang_after and ready.is_set():
                        report.state_gaps += 1
                        report.hangs += 1
                        report.notes.append(f"state port silent for {gap:.2f} s")
                    self.state_tick.set()
                    body = rest[12:]
                    key: tuple[int, int] | None = None
                    values: tuple[float, ...] = ()
                    if msg_type == 10 and len(body) >= 4 + 10 * real:
                        key, values = (10, 0), struct.unpack_from(f"{order}10{rc}", body, 4)
                    elif msg_type == 15 and len(body) >= 8 + 11 * real:
                        robot = INT[order].unpack_from(body, 0)[0]
                        key, values = (15, robot), struct.unpack_from(f"{order}10{rc}", body, 8 + real)
                    elif msg_type == 13 and len(body) >= 28:
                        report.state_messages += 1
                        in_motion = INT[order].unpack_from(body, 16)[0]
                        if in_motion == 1 and ready.is_set():
                            self._motion(f"STATUS in_motion TRUE ({body.hex()})")
                        ready.set()
                        continue
                    if key is None:
                        continue
                    report.state_messages += 1
                    ref = reference.setdefault(key, values)
                    deviation = max((abs(a - b) for a, b in zip(values, ref, strict=True)), default=0.0)
                    if not deviation <= 1e-6:  # NaN counts too
                        report.max_deviation = max(report.max_deviation, deviation)
                        self._motion(f"type {key[0]} group {key[1]}: {values} from {ref}")
            except (OSError, asyncio.IncompleteReadError):
                pass
            finally:
                keepalive.cancel()
                writer.close()
            if self.stopping.is_set() or self.crashed():
                return
            report.notes.append("monitor: the state connection was closed by the server; reconnecting")

    async def state_rounds(self, count: int) -> None:
        """Until the monitor has read ``count`` more state messages."""
        target = self.report.state_messages + count
        while self.report.state_messages < target:
            self.state_tick.clear()
            await self.state_tick.wait()

    def _motion(self, what: str) -> None:
        report = self.report
        report.motion += 1
        if not report.motion_detail:
            report.motion_detail = what
            report.notes.append(f"MOTION: {what}")

    async def sample_rss(self) -> None:
        pid = self.target.pid
        if pid is None:
            return
        while not self.stopping.is_set():
            rss = rss_mb(pid)
            if rss is not None:
                self.report.rss_max = max(self.report.rss_max or 0.0, rss)
                self.report.rss_samples.append((self.total, rss))
            elif self.options.external and not _alive(pid):  # a running server's end
                self.report.crashes += 1
                self.report.notes.append(f"the server (pid {pid}) is gone")
                self.gone = True
                self.stop()
                return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), self.options.probe_interval)

    async def progress(self, start: float) -> None:
        if self.options.quiet:
            return
        while not self.stopping.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), 10.0)
            elapsed = time.monotonic() - start
            rate = self.total / max(elapsed, 1e-9)
            print(
                f"  {self.profile}: {self.total:,} frames in {elapsed:.0f} s ({rate:,.0f}/s), "
                f"{self.report.connections:,} connections, {self.report.hangs} hangs, {self.report.motion} motion",
                file=sys.stderr,
                flush=True,
            )
