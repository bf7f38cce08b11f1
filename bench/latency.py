"""Round-trip latency and request/reply throughput against the project's own server over loopback.

The server runs in a child process (its own core, as a controller would), the client here. PING
latency is measured over 10,000 requests, one at a time; JOINT_TRAJ_PT throughput stop-and-wait
(one request in flight, as the generic streamer sends) and pipelined (16 in flight). Each event loop
available is measured: the default one and, if installed, uvloop. Target (issue 3): PING p50 at
most 100 us on the CI machine class.

    python bench/latency.py [--count 10000]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--count", type=int, default=10_000)
    parser.add_argument("--serve", metavar="LOOP", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        run_loop(args.serve, lambda: serve(args.serve))
        return
    loops = ["asyncio"]
    try:
        import uvloop  # noqa: F401

        loops.append("uvloop")
    except ImportError:
        pass
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from codec import machine  # the benchmarks' shared machine description

    print(f"# simple_message loopback latency: {machine()}; server in a child process")
    print()
    print("| event loop | PING p50 us | p99 us | max us | mean us | JOINT_TRAJ_PT req/s, 1 in flight | 16 in flight |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for loop_name in [*loops, "echo"]:
        child = subprocess.Popen(
            [sys.executable, __file__, "--serve", loop_name],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
        )
        try:
            assert child.stdout is not None
            port = int(child.stdout.readline())
            if loop_name == "echo":
                r: dict[str, float] = asyncio.run(measure_echo(port, args.count))
                print(
                    f"| floor: bare asyncio echo, no protocol | {r['p50']:.0f} | {r['p99']:.0f} | {r['max']:.0f} "
                    f"| {r['mean']:.0f} | | |"
                )
                continue
            r = run_loop(loop_name, lambda port=port: measure(port, args.count))  # type: ignore[assignment]
        finally:
            if child.stdin is not None:
                child.stdin.close()
            child.wait(timeout=10)
        print(
            f"| {loop_name} | {r['p50']:.0f} | {r['p99']:.0f} | {r['max']:.0f} | {r['mean']:.0f} "
            f"| {r['serial']:,.0f} | {r['pipelined']:,.0f} |"
        )
    if len(loops) == 1:
        print("\n(uvloop is not installed; `pip install uvloop` to measure it too)")


if __name__ == "__main__":
    main()
