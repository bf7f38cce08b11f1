"""Emulator benchmark: state-topic period jitter, stop-and-wait streaming rate, CPU use.

    python bench/server.py [--quick]

The emulator runs as its own process (``python -m robot_server``, generic profile), as users run
it; the clients here speak raw bytes over loopback TCP.

* **Jitter**: with the state rate at 250 Hz (4 ms) and 1, 10 and 50 state clients connected, every
  client timestamps each JOINT_POSITION on arrival; jitter is ``|interval - 4 ms|`` over all
  clients. Measured at the clients, so it includes their own scheduling (all clients share this
  process's one event loop). Target on the CI machine class: p99 under 2 ms with 10 clients.
* **Streaming**: JOINT_TRAJ_PT requests sent stop-and-wait (one in flight, as the generic client
  does), each accepted at once (a large queue, 10 ms segments): points per second.
* **CPU**: the emulator's user + system CPU time over wall time (/proc), default settings (40 Hz
  state, one state client), idle and while it executes a long trajectory.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import os
import re
import statistics
import struct
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from codec import machine

JOINT_POSITION, JOINT_TRAJ_PT = 10, 11


class Server:
    def __init__(self, proc: asyncio.subprocess.Process, ports: dict[str, int]) -> None:
        self.proc, self.ports = proc, ports

    @classmethod
    async def start(cls, *args: str) -> Server:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "robot_server",
            "--motion-port",
            "0",
            "--state-port",
            "0",
            "--log-level",
            "WARNING",
            "--no-stdin",
            *args,
            stdout=asyncio.subprocess.PIPE,
        )
        assert proc.stdout is not None
        line = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).decode()
        ports = {name: int(port) for name, port in re.findall(r"(motion|state) [\d.]+:(\d+)", line)}
        return cls(proc, ports)

    def cpu_seconds(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    async def stop(self) -> None:
        self.proc.terminate()
        await asyncio.wait_for(self.proc.wait(), 30.0)


async def read_frame(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    prefix = await reader.readexactly(4)
    (length,) = struct.unpack("<i", prefix)
    data = await reader.readexactly(length)
    return struct.unpack_from("<i", data, 0)[0], data


async def arrivals(port: int, seconds: float, out: list[float]) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    end = time.perf_counter() + seconds
    try:
        while time.perf_counter() < end:
            msg_type, _ = await asyncio.wait_for(read_frame(reader), 5.0)
            if msg_type == JOINT_POSITION:
                out.append(time.perf_counter())
    finally:
        writer.close()


async def jitter(clients: int, seconds: float) -> tuple[float, float, float, int]:
    server = await Server.start("--state-rate", "250")
    try:
        stamps: list[list[float]] = [[] for _ in range(clients)]
        await asyncio.gather(*(arrivals(server.ports["state"], seconds, s) for s in stamps))
    finally:
        await server.stop()
    deviations = []
    for s in stamps:
        deviations += [abs((b - a) - 0.004) for a, b in itertools.pairwise(s[5:])]  # [5:]: connection set-up
    deviations.sort()
    p99 = deviations[int(0.99 * (len(deviations) - 1))]
    return statistics.median(deviations), p99, deviations[-1], len(deviations)


def jtp(seq: int, joints: list[float], duration: float) -> bytes:
    return struct.pack("<iiiii10fff", 64, JOINT_TRAJ_PT, 2, 0, seq, *joints, *[0.0] * 4, 0.0, duration)


async def streaming(points: int) -> float:
    server = await Server.start("--queue-size", str(points + 10))
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.ports["motion"])
        start = time.perf_counter()
        for seq in range(points):
            q = 0.0001 * seq  # quintic rest-to-rest steps within the acceleration limit
            writer.write(jtp(seq, [q] * 6, 0.0 if seq == 0 else 0.01))
            msg_type, data = await asyncio.wait_for(read_frame(reader), 10.0)
            assert msg_type == JOINT_TRAJ_PT and struct.unpack_from("<i", data, 8)[0] == 1, "point refused"
        rate = points / (time.perf_counter() - start)
        writer.close()
    finally:
        await server.stop()
    return rate


async def cpu(seconds: float) -> tuple[float, float]:
    server = await Server.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.ports["state"])
        drain = asyncio.create_task(_drain(reader))
        c0, t0 = server.cpu_seconds(), time.perf_counter()
        await asyncio.sleep(seconds)  # measuring an interval, not synchronising
        idle = (server.cpu_seconds() - c0) / (time.perf_counter() - t0)
        mreader, mwriter = await asyncio.open_connection("127.0.0.1", server.ports["motion"])
        for seq, q in enumerate((0.0, 2.0)):  # one slow move: seconds of motion
            mwriter.write(jtp(seq, [q] * 6, 0.0 if seq == 0 else seconds + 2.0))
            await asyncio.wait_for(read_frame(mreader), 10.0)
        c0, t0 = server.cpu_seconds(), time.perf_counter()
        await asyncio.sleep(seconds)
        moving = (server.cpu_seconds() - c0) / (time.perf_counter() - t0)
        drain.cancel()
        writer.close()
        mwriter.close()
    finally:
        await server.stop()
    return idle, moving


async def _drain(reader: asyncio.StreamReader) -> None:
    while await reader.read(65536):
        pass


async def run(quick: bool) -> None:
    seconds = 2.0 if quick else 5.0
    print(f"# emulator benchmark ({machine()})")
    print()
    print("| state clients | jitter p50 (ms) | p99 (ms) | max (ms) | intervals |")
    print("|---:|---:|---:|---:|---:|")
    for clients in (1, 10, 50):
        p50, p99, worst, n = await jitter(clients, seconds)
        print(f"| {clients} | {p50 * 1e3:.3f} | {p99 * 1e3:.3f} | {worst * 1e3:.3f} | {n} |")
    print()
    points = 500 if quick else 2000
    rate = await streaming(points)
    print("| measure | value |")
    print("|---|---:|")
    print(f"| stop-and-wait JOINT_TRAJ_PT streaming | {rate:,.0f} points/s |")
    idle, moving = await cpu(seconds)
    print(f"| emulator CPU, idle (40 Hz state, 1 client) | {idle * 100:.1f} % of one core |")
    print(f"| emulator CPU, moving | {moving * 100:.1f} % of one core |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    asyncio.run(run(parser.parse_args().quick))


if __name__ == "__main__":
    main()
