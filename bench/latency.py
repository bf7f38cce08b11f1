"""Round-trip latency and request/reply throughput against the project's own server over loopback.

The server runs in a child process (its own core, as a controller would), the client here. PING
latency is measured over 10,000 requests, one at a time; JOINT_TRAJ_PT throughput stop-and-wait
(one request in flight, as the generic streamer sends) and pipelined (16 in flight). Each event loop
available is measured: the default one and, if installed, uvloop. Target (issue 3): PING p50 at
most 100 us on the CI machine class.

When the reference C++ peer is built (shared/peer beside this repository: sm_client and sm_server on the
ROS-Industrial C++ simple_message library; found with --peer DIR, else $SM_PEER_DIR, else /work/peer-build/bin),
the same C++ client (`sm_client 127.0.0.1 PORT ping N`) also measures a `robot-server` process and the C++
`sm_server`, in alternating runs, with the ratio between them (target, issue 38: robot-server's PING p50 at most
1.0x the C++ server's; issue 16 asked 1.5x); a blocking raw-socket Python client measures both again for the p90
(sm_client prints p50, p99 and max only). The C++ decode rate (`sm_client decode N`) is printed too; bench/codec.py
compares it with this package's. Loopback (127.0.0.1) only. On a small VM the placement of the processes decides
much of a round trip (a wake-up on the other core costs tens of us): --pin same or split makes runs comparable.

--server-loop asyncio,uvloop measures robot-server on each event loop (forced; default: as the command picks it, uvloop
when installed once it runs through simple_message.endpoints.run, asyncio's own loop after the README's plain
`pip install -e .`, which installs no uvloop: measure `--server-loop default,asyncio` to see both where uvloop is
installed), and --baseline DIR the robot-server of another
checkout too (e.g. `git worktree add /tmp/base HEAD~1`), all in the same alternation; --peer-only skips the asyncio
client's table.

    python bench/latency.py [--count 10000] [--peer DIR] [--peer-runs 5] [--pin none|same|split]
                            [--server-loop LOOPS] [--baseline DIR] [--peer-only]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import re
import selectors
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from simple_message import LE32, JointTrajPt, MsgType, Ping
from simple_message.connection import Connection
from simple_message.endpoints import Server
from simple_message.transport import open_tcp


async def serve_echo() -> None:
    """The floor: a bare asyncio-streams echo server, no protocol at all."""

    async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while data := await reader.read(65536):
            writer.write(data)

    server = await asyncio.start_server(echo, "127.0.0.1", 0)
    print(server.sockets[0].getsockname()[1], flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    server.close()


async def measure_echo(port: int, count: int) -> dict[str, float]:
    reader, writer = await open_tcp("127.0.0.1", port)
    frame = Ping().encode(LE32)
    samples = []
    for i in range(count + 500):
        t0 = time.perf_counter_ns()
        writer.write(frame)
        await reader.readexactly(len(frame))
        if i >= 500:
            samples.append(time.perf_counter_ns() - t0)
    writer.close()
    samples.sort()
    return {
        "p50": samples[len(samples) // 2] / 1000,
        "p99": samples[int(len(samples) * 0.99)] / 1000,
        "max": samples[-1] / 1000,
        "mean": statistics.fmean(samples) / 1000,
    }


async def serve(loop_name: str) -> None:
    if loop_name == "echo":
        await serve_echo()
        return
    server = Server(LE32, name="bench")
    server.handle(MsgType.JOINT_TRAJ_PT, lambda msg, session: None)
    port = await server.serve_tcp("127.0.0.1", 0)
    print(port, flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)  # until the parent closes stdin
    await server.close()


async def measure(port: int, count: int) -> dict[str, float]:
    conn = Connection(await open_tcp("127.0.0.1", port), LE32, name="bench").start()
    ping = Ping()
    for _ in range(500):  # warm-up
        await conn.request(ping, timeout=5)
    samples = []
    clock = time.perf_counter_ns
    for _ in range(count):
        t0 = clock()
        await conn.request(ping, timeout=5)
        samples.append(clock() - t0)
    samples.sort()
    point = JointTrajPt(0, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 0.5, 0.1)
    t0 = time.perf_counter()
    for _ in range(count):
        await conn.request(point, timeout=5)
    serial_rate = count / (time.perf_counter() - t0)

    async def lane(n: int) -> None:
        for _ in range(n):
            await conn.request(point, timeout=5)

    t0 = time.perf_counter()
    await asyncio.gather(*(lane(count // 16) for _ in range(16)))
    pipelined_rate = (count // 16) * 16 / (time.perf_counter() - t0)
    await conn.close()
    return {
        "p50": samples[len(samples) // 2] / 1000,
        "p99": samples[int(len(samples) * 0.99)] / 1000,
        "max": samples[-1] / 1000,
        "mean": statistics.fmean(samples) / 1000,
        "serial": serial_rate,
        "pipelined": pipelined_rate,
    }


def run_loop(loop_name: str, coro_factory: object) -> object:
    if loop_name == "uvloop":
        import uvloop

        return uvloop.run(coro_factory())  # type: ignore[operator]
    return asyncio.run(coro_factory())  # type: ignore[operator]


# The reference C++ peer (issues 16, 38): the same C++ client against robot-server and the C++ server.

DEFAULT_PEER_DIR = Path("/work/peer-build/bin")
PEER_SOURCE = Path(__file__).resolve().parents[2] / "shared" / "peer"  # the peer's sources, beside the repository
BUILD_HINT = (
    f"build it as {PEER_SOURCE}/README.md says: mkdir -p ic && git --git-dir=PATH/TO/industrial_core.git archive "
    f"HEAD simple_message | tar -x -C ic && {PEER_SOURCE}/build.sh ic /work/peer-build"
)
SM_CLIENT_PING = re.compile(r"ping n=(\d+) p50_us=([\d.]+) p99_us=([\d.]+) max_us=([\d.]+)")
SM_CLIENT_DECODE = re.compile(r"msgs_per_s=(\d+)")
ROBOT_SERVER_READY = re.compile(r"motion 127\.0\.0\.1:(\d+)")
DECODE_COUNT = 1_000_000
START_TIMEOUT = 30.0  # s for a server to accept connections
STOP_TIMEOUT = 10.0  # s for a child to exit once asked to
WARMUP = 50  # requests before the samples, as sm_client does


class PeerError(RuntimeError):
    """A server or the C++ client did not start, did not answer in time, or printed something unexpected."""


def find_peer(option: str | None) -> tuple[Path | None, Path]:
    """The directory holding sm_client and sm_server (None when not built), and where it was looked for.

    ``--peer DIR``, else ``$SM_PEER_DIR``, else /work/peer-build/bin; DIR may also be build.sh's OUT_DIR.
    """
    where = Path(option or os.environ.get("SM_PEER_DIR") or DEFAULT_PEER_DIR)
    for candidate in (where, where / "bin"):
        if all(os.access(candidate / name, os.X_OK) for name in ("sm_client", "sm_server")):
            return candidate, where
    return None, where


def read_line(stream: IO[bytes] | None, timeout: float, what: str) -> str:
    """One line from a child's stdout, waiting at most ``timeout`` seconds for it."""
    if stream is None:
        raise PeerError(f"{what}: no stdout")
    fd = stream.fileno()
    data = b""
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        while not data.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or not selector.select(left):
                raise PeerError(f"{what}: no line on stdout within {timeout:.0f} s")
            byte = os.read(fd, 1)  # one byte at a time: nothing past the line is consumed
            if not byte:
                raise PeerError(f"{what}: exited before printing a line")
            data += byte
    return data.decode(errors="replace").strip()


@contextlib.contextmanager
def running(
    cmd: Sequence[str],
    *,
    stdin: int | None = None,
    stdout: int | None = subprocess.PIPE,
    stderr: IO[bytes] | int | None = None,
    env: dict[str, str] | None = None,
    cwd: Path | None = None,
) -> Iterator[subprocess.Popen[bytes]]:
    """A child process, always ended on leaving (also on Ctrl-C): its stdin closed (the bench's own servers exit
    then), SIGTERM if it is still running (robot-server stops cleanly), SIGKILL if that does not end it in time."""
    proc = subprocess.Popen(list(cmd), stdin=stdin, stdout=stdout, stderr=stderr, env=env, cwd=cwd)
    try:
        yield proc
    finally:
        try:
            if proc.stdin is not None:
                proc.stdin.close()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(STOP_TIMEOUT)
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(STOP_TIMEOUT)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(STOP_TIMEOUT)
        finally:
            if proc.poll() is None:  # interrupted while waiting (a second Ctrl-C)
                proc.kill()
            if proc.stdout is not None:
                proc.stdout.close()


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def wait_accepting(port: int, proc: subprocess.Popen[bytes], timeout: float) -> bool:
    """Whether 127.0.0.1:port accepts a connection within ``timeout`` seconds while ``proc`` runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.05)
    return False


@contextlib.contextmanager
def cpp_server(peer: Path) -> Iterator[int]:
    """The C++ sm_server on free ports (it takes no port 0); yields its motion port."""
    for _ in range(3):  # a free port can be taken between the probe and sm_server's bind
        motion, state = free_port(), free_port()
        with running(
            [str(peer / "sm_server"), str(motion), str(state)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        ) as proc:
            if wait_accepting(motion, proc, START_TIMEOUT):
                yield motion
                return
    raise PeerError("sm_server did not accept connections")


#: how a robot-server variant is started: its event loop forced, then the command's own main()
LAUNCH = (
    "import asyncio, sys\n"
    "if sys.argv[1] == 'uvloop':\n"
    "    import uvloop\n"
    "    asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())\n"
    "from robot_server.cli import main\n"
    "sys.exit(main(sys.argv[2:]))"
)


@dataclass(frozen=True)
class Variant:
    """One robot-server to measure: its name in the tables, the checkout it runs from, its event loop
    (``default``: whatever the command picks; ``asyncio`` or ``uvloop``: forced)."""

    name: str
    root: Path
    loop: str = "default"

    def env(self, base: dict[str, str]) -> dict[str, str]:
        env = {**base, "PYTHONPATH": str(self.root)}
        if self.loop != "default":
            env["SIMPLE_MESSAGE_LOOP"] = self.loop  # honoured by simple_message.endpoints.run
        return env


@contextlib.contextmanager
def robot_server(env: dict[str, str], variant: Variant | None = None) -> Iterator[int]:
    """A robot-server process (default generic profile, jibot_zxs, real time) on free ports; yields its motion
    port. ``variant``: from another checkout and/or on a forced event loop (default: this checkout, as it is)."""
    args = ["--host", "127.0.0.1", "--motion-port", "0", "--state-port", "0", "--no-stdin", "--log-level", "WARNING"]
    cwd = None
    if variant is None:
        cmd = [sys.executable, "-m", "robot_server", *args]
    else:
        cmd = [sys.executable, "-c", LAUNCH, variant.loop, *args]
        env = variant.env(env)
        cwd = variant.root  # python -c puts the working directory first on sys.path
    with tempfile.TemporaryFile() as log, running(cmd, stderr=log, env=env, cwd=cwd) as proc:
        try:
            line = read_line(proc.stdout, START_TIMEOUT, "robot-server")
        except PeerError as e:
            log.seek(0)
            raise PeerError(f"{e}: {log.read()[-800:].decode(errors='replace')}") from None
        match = ROBOT_SERVER_READY.search(line)
        if match is None:
            raise PeerError(f"robot-server: unexpected first line {line!r}")
        yield int(match.group(1))


def run_client(args: Sequence[str], timeout: float) -> str:
    """The C++ client's output; the client is killed if it takes longer than ``timeout`` (or on Ctrl-C)."""
    try:
        done = subprocess.run(list(args), capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        raise PeerError(f"{' '.join(args)}: no result within {timeout:.0f} s") from None
    if done.returncode != 0:
        raise PeerError(f"{' '.join(args)}: exit {done.returncode}: {(done.stdout + done.stderr).strip()[-300:]}")
    return done.stdout


def sm_client_ping(peer: Path, port: int, count: int) -> dict[str, float]:
    out = run_client([str(peer / "sm_client"), "127.0.0.1", str(port), "ping", str(count)], 30 + count * 0.005)
    match = SM_CLIENT_PING.search(out)
    if match is None:
        raise PeerError(f"sm_client ping: unexpected output {out.strip()!r}")
    return {"p50": float(match.group(2)), "p99": float(match.group(3)), "max": float(match.group(4))}


def sm_client_decode(peer: Path, count: int) -> float:
    out = run_client([str(peer / "sm_client"), "decode", str(count)], 60)
    match = SM_CLIENT_DECODE.search(out)
    if match is None:
        raise PeerError(f"sm_client decode: unexpected output {out.strip()!r}")
    return float(match.group(1))


def raw_ping(port: int, count: int) -> list[int]:
    """PING round trips (ns) from a blocking raw-socket client, one request in flight: the least Python a client
    can put in the way, for the p90 that sm_client does not print."""
    frame = Ping().encode(LE32)
    buf = bytearray(4096)
    view = memoryview(buf)
    samples = []
    clock = time.perf_counter_ns
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for i in range(count + WARMUP):
            t0 = clock()
            s.sendall(frame)
            got, need = 0, 4
            while got < need:
                n = s.recv_into(view[got:])
                if not n:
                    raise PeerError("raw client: the server closed the connection")
                got += n
                if need == 4 and got >= 4:
                    need = 4 + int.from_bytes(buf[:4], "little")
                    if need > len(buf) or need < 16:
                        raise PeerError(f"raw client: reply of {need} bytes")
            t1 = clock()
            _, msg_type, comm_type, reply_code = struct.unpack_from("<4i", buf)
            if (msg_type, comm_type, reply_code) != (MsgType.PING, 3, 1) or got != need:
                raise PeerError(f"raw client: unexpected reply {bytes(buf[:got]).hex()}")
            if i >= WARMUP:
                samples.append(t1 - t0)
    return samples


@contextlib.contextmanager
def affinity(cpus: set[int] | None) -> Iterator[None]:
    """This process on ``cpus`` (None: unchanged) for the block; children started in it inherit the set."""
    if cpus is None:
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, cpus)
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def placement(pin: str) -> tuple[set[int] | None, set[int] | None, str]:
    """The CPUs of the servers and of the client for ``--pin``, and a description."""
    cpus = sorted(os.sched_getaffinity(0))
    if pin == "same" or (pin == "split" and len(cpus) < 2):
        return {cpus[0]}, {cpus[0]}, f"servers and client pinned to CPU {cpus[0]}"
    if pin == "split":
        return {cpus[1]}, {cpus[0]}, f"servers pinned to CPU {cpus[1]}, client to CPU {cpus[0]}"
    return None, None, "not pinned (the OS places them)"


def spread(values: list[float]) -> str:
    """Median of the runs and their range."""
    return f"{statistics.median(values):.0f} ({min(values):.0f}-{max(values):.0f})"


def compare_with_peer(
    peer: Path, count: int, runs: int, env: dict[str, str], pin: str, variants: Sequence[Variant | None]
) -> None:
    """The same C++ client against each robot-server variant and the C++ server, alternating runs (the order
    rotates from run to run), every server up throughout (so that all are measured under the same background
    load); then the C++ decode rate."""
    cpp_name = "C++ sm_server"
    names = [cpp_name, *("robot-server" if v is None else v.name for v in variants)]
    cpp: dict[str, list[dict[str, float]]] = {name: [] for name in names}
    raw: dict[str, list[int]] = {name: [] for name in names}
    server_cpus, client_cpus, where = placement(pin)
    with contextlib.ExitStack() as servers:
        with affinity(server_cpus):
            ports = {cpp_name: servers.enter_context(cpp_server(peer))}
            for name, variant in zip(names[1:], variants, strict=True):
                ports[name] = servers.enter_context(robot_server(env, variant))
        servers.enter_context(affinity(client_cpus))
        for run in range(runs):
            for name in names[run % len(names) :] + names[: run % len(names)]:
                cpp[name].append(sm_client_ping(peer, ports[name], count))
        for run in range(runs):
            for name in names[run % len(names) :] + names[: run % len(names)]:
                raw[name] += raw_ping(ports[name], count)
    print()
    print(f"# against the reference C++ peer in {peer} (ROS-Industrial simple_message, industrial_core); {where}")
    print()
    print(
        f"| PING, C++ client `sm_client 127.0.0.1 PORT ping {count}`, {runs} alternating runs: median (range) "
        "| p50 us | p90 us | p99 us | max us |"
    )
    print("|---|---:|---:|---:|---:|")
    for name in names:
        r = cpp[name]
        print(
            f"| {name} | {spread([x['p50'] for x in r])} | n/a | {spread([x['p99'] for x in r])} "
            f"| {max(x['max'] for x in r):.0f} |"
        )
    for name in names[1:]:
        ratio = {
            q: statistics.median(x[q] for x in cpp[name]) / statistics.median(x[q] for x in cpp[cpp_name])
            for q in ("p50", "p99")
        }
        paired = [b["p50"] / a["p50"] for a, b in zip(cpp[cpp_name], cpp[name], strict=True)]
        print(
            f"| ratio {name} / C++ (target p50 <= 1.0x; p50 run pairs {min(paired):.2f}-{max(paired):.2f}x) "
            f"| {ratio['p50']:.2f}x | | {ratio['p99']:.2f}x | |"
        )
    print()
    print(
        f"| PING, blocking raw-socket Python client, {runs} alternating runs of {count}, pooled | p50 us | p90 us "
        "| p99 us | max us |"
    )
    print("|---|---:|---:|---:|---:|")
    pct: dict[str, dict[str, float]] = {}
    for name in names:
        s = sorted(raw[name])
        pct[name] = {
            q: s[min(int(len(s) * f), len(s) - 1)] / 1000 for q, f in (("p50", 0.5), ("p90", 0.9), ("p99", 0.99))
        }
        pct[name]["max"] = s[-1] / 1000
        print(f"| {name} | " + " | ".join(f"{pct[name][q]:.0f}" for q in ("p50", "p90", "p99", "max")) + " |")
    for name in names[1:]:
        print(
            f"| ratio {name} / C++ | "
            + " | ".join(f"{pct[name][q] / pct[cpp_name][q]:.2f}x" for q in ("p50", "p90", "p99"))
            + " | |"
        )
    print("\n(sm_client prints p50, p99 and max only: the p90 is the raw-socket client's)")
    rates = [sm_client_decode(peer, DECODE_COUNT) for _ in range(3)]
    print()
    print("| C++ decode: frame from its bytes + JOINT_TRAJ_PT message (`sm_client decode`), best of 3 | msg/s |")
    print("|---|---:|")
    print(f"| {DECODE_COUNT:,} frames (runs: {', '.join(f'{x / 1e6:.2f} M' for x in rates)}) | {max(rates):,.0f} |")


def variants_of(loops: str, baseline: str | None) -> list[Variant | None]:
    """The robot-server variants of ``--server-loop`` and ``--baseline``."""
    here = Path(__file__).resolve().parents[1]
    chosen = [loop.strip() for loop in loops.split(",") if loop.strip()]
    roots = [("robot-server", here)]
    if baseline is not None:
        roots.append((f"baseline {Path(baseline).name or baseline}", Path(baseline).resolve()))
    out: list[Variant | None] = []
    for label, root in roots:
        for loop in chosen:
            if loop == "default" and root == here:
                out.append(None)  # exactly as users start it
            else:
                out.append(Variant(label if loop == "default" else f"{label} ({loop})", root, loop))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--count", type=int, default=10_000)
    parser.add_argument(
        "--peer",
        metavar="DIR",
        help="where the C++ peer's sm_client and sm_server are (default: $SM_PEER_DIR, else /work/peer-build/bin)",
    )
    parser.add_argument("--peer-runs", type=int, default=5, help="alternating runs per server against the C++ peer")
    parser.add_argument(
        "--pin",
        choices=["none", "same", "split"],
        default="none",
        help="against the C++ peer: servers and client on one CPU (same), on two (split), or where the OS puts them",
    )
    parser.add_argument(
        "--server-loop",
        default="default",
        metavar="LOOPS",
        help="against the C++ peer: robot-server's event loop, comma-separated (default: as the command picks it; "
        "asyncio or uvloop: forced), each measured in the same alternation",
    )
    parser.add_argument(
        "--baseline",
        metavar="DIR",
        help="against the C++ peer: also measure the robot-server of another checkout (e.g. a git worktree of an "
        "older commit), in the same alternation",
    )
    parser.add_argument("--peer-only", action="store_true", help="only the comparison with the C++ peer")
    parser.add_argument("--serve", metavar="LOOP", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        run_loop(args.serve, lambda: serve(args.serve))
        return
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from codec import machine  # the benchmarks' shared machine description

    print(f"# {machine()}")
    print()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    if not args.peer_only:
        python_client(args.count, env)
    peer, where = find_peer(args.peer)
    if peer is None:
        print(f"\n(C++ reference peer not built: no sm_client/sm_server in {where}; {BUILD_HINT}, or --peer DIR)")
        return
    try:
        compare_with_peer(
            peer, args.count, max(args.peer_runs, 1), env, args.pin, variants_of(args.server_loop, args.baseline)
        )
    except PeerError as e:
        print(f"\n(comparison with the C++ peer in {peer} failed: {e})")
        sys.exit(1)


def python_client(count: int, env: dict[str, str]) -> None:
    """The asyncio client against the bench's own server on each event loop, and the bare echo floor."""
    loops = ["asyncio"]
    try:
        import uvloop  # noqa: F401

        loops.append("uvloop")
    except ImportError:
        pass
    print("# simple_message loopback latency: the asyncio client against the bench's server in a child process")
    print()
    print("| event loop | PING p50 us | p99 us | max us | mean us | JOINT_TRAJ_PT req/s, 1 in flight | 16 in flight |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for loop_name in [*loops, "echo"]:
        with running([sys.executable, __file__, "--serve", loop_name], stdin=subprocess.PIPE, env=env) as child:
            port = int(read_line(child.stdout, START_TIMEOUT, f"bench server ({loop_name})"))
            if loop_name == "echo":
                r: dict[str, float] = asyncio.run(measure_echo(port, count))
                print(
                    f"| floor: bare asyncio echo, no protocol | {r['p50']:.0f} | {r['p99']:.0f} | {r['max']:.0f} "
                    f"| {r['mean']:.0f} | | |"
                )
                continue
            r = run_loop(loop_name, lambda port=port: measure(port, count))  # type: ignore[assignment]
        print(
            f"| {loop_name} | {r['p50']:.0f} | {r['p99']:.0f} | {r['max']:.0f} | {r['mean']:.0f} "
            f"| {r['serial']:,.0f} | {r['pipelined']:,.0f} |"
        )
    if len(loops) == 1:
        print("\n(uvloop is not installed; `pip install uvloop` to measure it too)")


if __name__ == "__main__":
    main()
