"""Many monitoring clients at once: N clients x M PINGs each against a `robot-server` process with its
default settings, all connected together, each one PING in flight at a time (target, issue 17: 100 x 100
all answered correctly; a hundred monitoring clients is normal in a lab).

The clients connect to the state port (the motion port takes one client: robot_server/emulator/owner.py),
which answers PING while it publishes its topics; the topics are skipped. Every reply is checked byte for
byte against the reference PING reply. Reports the round-trip p50/p99/max over all requests, how many were
answered, and the server's refused and evicted connections (none expected). Loopback (127.0.0.1) only.

    python bench/clients.py [--clients 100] [--pings 100] [--runs 3] [--profile generic|motoros]
"""

from __future__ import annotations

import argparse
import asyncio
import re
import statistics
import struct
import sys
import time

PING = struct.pack("<iiii", 12, 1, 2, 0)
PING_REPLY = struct.pack("<iiii", 12, 1, 3, 1)
SERVICE_REPLY = 3
#: the state connections MotoROS serves (and the emulator's motoros profile)
MOTOROS_STATE_SLOTS = 4


async def start_server(profile: str) -> tuple[asyncio.subprocess.Process, int]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "robot_server",
        "--profile",
        profile,
        "--motion-port",
        "0",
        "--state-port",
        "0",
        "--io-port",
        "0",
        "--no-stdin",
        "--log-level",
        "WARNING",
        stdout=asyncio.subprocess.PIPE,
    )
    assert proc.stdout is not None
    line = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).decode()
    found = re.search(r"state [\d.]+:(\d+)", line)
    if found is None:
        proc.kill()
        raise SystemExit(f"robot-server did not start: {line!r}")
    return proc, int(found.group(1))


async def client(port: int, pings: int, go: asyncio.Event) -> tuple[list[float], int]:
    """``pings`` round trips, one at a time; returns the times (s) and the wrong replies."""
    reader, writer = await asyncio.wait_for(asyncio.open_connection("127.0.0.1", port), 10.0)
    times: list[float] = []
    wrong = 0
    try:
        await go.wait()
        for _ in range(pings):
            start = time.perf_counter()
            writer.write(PING)
            async with asyncio.timeout(10.0):
                while True:  # skip the topics the state port publishes meanwhile
                    prefix = await reader.readexactly(4)
                    (length,) = struct.unpack("<i", prefix)
                    frame = prefix + await reader.readexactly(length)
                    if struct.unpack_from("<i", frame, 8)[0] == SERVICE_REPLY:
                        break
            times.append(time.perf_counter() - start)
            wrong += frame != PING_REPLY
    finally:
        writer.close()
    return times, wrong


async def run(clients: int, pings: int, profile: str) -> dict[str, float]:
    proc, port = await start_server(profile)
    try:
        go = asyncio.Event()
        tasks = [asyncio.create_task(client(port, pings, go)) for _ in range(clients)]
        await asyncio.sleep(0.5)  # let every client connect before the first PING (not a measurement)
        go.set()
        results = await asyncio.gather(*tasks, return_exceptions=True)
    finally:
        proc.terminate()
        await asyncio.wait_for(proc.wait(), 20.0)
    times = [t for r in results if not isinstance(r, BaseException) for t in r[0]]
    wrong = sum(r[1] for r in results if not isinstance(r, BaseException))
    failed = sum(isinstance(r, BaseException) for r in results)
    times.sort()
    return {
        "answered": len(times) - wrong,
        "wrong": wrong,
        "failed clients": failed,
        "p50 ms": 1e3 * statistics.median(times) if times else float("nan"),
        "p99 ms": 1e3 * times[int(0.99 * (len(times) - 1))] if times else float("nan"),
        "max ms": 1e3 * times[-1] if times else float("nan"),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clients", type=int, default=None, help="default 100 (MotoROS: 4, its state slots)")
    parser.add_argument("--pings", type=int, default=100)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--profile", default="generic", choices=["generic", "motoros"])
    args = parser.parse_args()
    if args.clients is None:
        args.clients = MOTOROS_STATE_SLOTS if args.profile == "motoros" else 100
    if args.profile == "motoros" and args.clients > MOTOROS_STATE_SLOTS:
        print(
            f"note: MotoROS serves {MOTOROS_STATE_SLOTS} state clients, as the real one; the others are refused",
            file=sys.stderr,
        )
    print(f"{args.clients} clients x {args.pings} PINGs on the state port, {args.profile} profile")
    print("| run | answered | wrong | failed clients | p50 ms | p99 ms | max ms |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    complete = True
    for k in range(args.runs):
        r = asyncio.run(run(args.clients, args.pings, args.profile))
        print(
            f"| {k + 1} | {int(r['answered'])}/{args.clients * args.pings} | {int(r['wrong'])} | "
            f"{int(r['failed clients'])} | {r['p50 ms']:.3f} | {r['p99 ms']:.3f} | {r['max ms']:.3f} |"
        )
        complete = complete and r["answered"] == args.clients * args.pings
    return 0 if complete else 1  # every PING of every run answered correctly, or a failure


if __name__ == "__main__":
    sys.exit(main())
