"""Emulator benchmark: state-topic period jitter, the web view's cost, stop-and-wait streaming rate, CPU use.

    python bench/server.py [--quick] [--clients 1,10,50] [--runs N] [--pin none|same|split]
                           [--only jitter|web|streaming] [--web-clients 1,50] [--rt]

The emulator runs as its own process (``python -m robot_server``, generic profile), as users run
it; the clients here speak raw bytes over loopback TCP.

* **Jitter**: with the state rate at 250 Hz (4 ms) and 1, 10 and 50 state clients connected, jitter
  is ``|interval - 4 ms|`` between consecutive state rounds of one client, pooled over all clients.
  The clients run in a child process of their own (one non-blocking ``selectors`` loop, no asyncio)
  and each round is timestamped twice:

  - *sent*: the kernel's receive timestamp (``SO_TIMESTAMPNS``) of the round's last frame (STATUS).
    On loopback that is the moment the emulator's ``send`` ran, so this is the emulator's own
    jitter, whatever the measuring process's scheduling. (The round's *last* frame: TCP merges
    segments that wait in the receive queue and keeps the newest timestamp, so an earlier frame's
    stamp can be a later frame's.)
  - *read*: ``perf_counter`` when the client has read the round's JOINT_POSITION, what a client
    sees (its own scheduling included: 50 clients share the measuring process's one core).

  Target (issue 16): p99 at most 1 ms with 50 clients. ``--pin split`` puts the emulator and the
  clients on different CPUs, ``same`` on one; the median and range over ``--runs`` runs are printed.
  On a machine shared with other work, their load decides the tail (a busy CPU delays the
  emulator's wake-up by a scheduler slice, milliseconds): ``--rt`` runs the emulator and the clients
  on SCHED_FIFO, which leaves that load out and measures the emulator alone.
* **Web view** (issue 22): the same jitter with 1 and 50 state clients, and the control loop's
  overruns (wake-ups more than one interpolation period late) and latest wake-up, as the emulator
  logs them when it closes, with ``--web`` off, on with no page, and on with 5 pages reading 60
  updates a second (WebSocket clients in a process of their own that parse every update as the page
  does; a browser's drawing is the browser's CPU, not the controller's). Target: the p99 jitter
  rises by at most 0.5 ms with the 5 pages open.
* **Streaming**: JOINT_TRAJ_PT requests sent stop-and-wait (one in flight, as the generic client
  does), each accepted at once (a large queue, 10 ms segments): points per second.
* **CPU**: the emulator's user + system CPU time over wall time (/proc), default settings (40 Hz
  state, one state client), idle and while it executes a long trajectory.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import os
import re
import selectors
import socket
import statistics
import struct
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from codec import machine

JOINT_POSITION, JOINT_TRAJ_PT, STATUS = 10, 11, 13
STATE_RATE = 250.0
PERIOD_NS = round(1e9 / STATE_RATE)
WARMUP = 0.5  # s of rounds dropped after the clients connected
PAGES = 5  # web pages open in the web part
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; SCM_TIMESTAMPNS has the same value


class Server:
    def __init__(self, proc: asyncio.subprocess.Process, ports: dict[str, int]) -> None:
        self.proc, self.ports = proc, ports
        self.web_url: str | None = None

    @classmethod
    async def start(cls, *args: str, cpus: set[int] | None = None, log: bool = False) -> Server:
        """``log``: at INFO level, stderr kept for :meth:`stop` to return (the closing statistics)."""
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "robot_server",
            "--motion-port",
            "0",
            "--state-port",
            "0",
            "--log-level",
            "INFO" if log else "WARNING",
            "--no-stdin",
            *args,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE if log else None,
        )
        if cpus is not None:
            os.sched_setaffinity(proc.pid, cpus)
        assert proc.stdout is not None
        line = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).decode()
        ports = {name: int(port) for name, port in re.findall(r"(motion|state) [\d.]+:(\d+)", line)}
        server = cls(proc, ports)
        web = re.search(r"web view (http://\S+/)", line)
        server.web_url = web.group(1) if web else None
        return server

    def cpu_seconds(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    async def stop(self) -> str:
        """Terminate it; its log (what ``log=True`` kept, else "")."""
        self.proc.terminate()
        err = self.proc.stderr
        text = (await asyncio.wait_for(err.read(), 30.0)).decode(errors="replace") if err is not None else ""
        await asyncio.wait_for(self.proc.wait(), 30.0)
        return text


async def read_frame(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    prefix = await reader.readexactly(4)
    (length,) = struct.unpack("<i", prefix)
    data = await reader.readexactly(length)
    return struct.unpack_from("<i", data, 0)[0], data


def measure_state(port: int, clients: int, seconds: float) -> dict[str, list[list[int]]]:
    """The measuring child: ``clients`` connections to the state port, read with one selector; per
    client, the kernel stamps of each round's STATUS and the read times of each JOINT_POSITION (ns)."""
    sel = selectors.DefaultSelector()
    socks = []
    for i in range(clients):
        sock = socket.create_connection(("127.0.0.1", port), timeout=10.0)
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        sock.setblocking(False)
        # per client: [bytes of the part being read, bytes it needs, reading a body?]
        sel.register(sock, selectors.EVENT_READ, [i, bytearray(), 4, False])
        socks.append(sock)
    sent: list[list[int]] = [[] for _ in range(clients)]
    read: list[list[int]] = [[] for _ in range(clients)]
    anc_size = socket.CMSG_SPACE(16)
    clock = time.perf_counter_ns
    start = clock()
    begin = start + int(WARMUP * 1e9)
    end = begin + int(seconds * 1e9)
    while (now := clock()) < end:
        for key, _ in sel.select((end - now) / 1e9):
            sock, state = key.fileobj, key.data
            assert isinstance(sock, socket.socket)
            i, part, need, body = state
            while True:
                try:
                    # never past the current frame: the timestamp is then that of this frame's bytes
                    data, anc, _, _ = sock.recvmsg(need - len(part), anc_size)
                except BlockingIOError:
                    break
                if not data:
                    raise SystemExit(f"client {i}: the emulator closed the connection")
                part += data
                if len(part) < need:
                    continue
                if not body:
                    need, body = 4 + int.from_bytes(part[:4], "little"), True
                    continue
                t = clock()
                msg_type = int.from_bytes(part[4:8], "little")
                if t >= begin:
                    if msg_type == JOINT_POSITION:
                        read[i].append(t)
                    elif msg_type == STATUS:
                        for level, kind, cdata in anc:
                            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                                sec, nsec = struct.unpack("qq", cdata[:16])
                                sent[i].append(sec * 1_000_000_000 + nsec)
                part.clear()
                need, body = 4, False
            state[1:] = [part, need, body]
    for sock in socks:
        sock.close()
    return {"sent": sent, "read": read}


def deviations(stamps: list[list[int]]) -> list[float]:
    """``|interval - period|`` in seconds, pooled over clients."""
    out: list[float] = []
    for s in stamps:
        out += [abs((b - a) - PERIOD_NS) / 1e9 for a, b in itertools.pairwise(s)]
    out.sort()
    return out


def summary(dev: list[float]) -> dict[str, float]:
    if not dev:
        return {"p50": float("nan"), "p99": float("nan"), "max": float("nan"), "n": 0}
    return {"p50": dev[len(dev) // 2], "p99": dev[int(0.99 * (len(dev) - 1))], "max": dev[-1], "n": len(dev)}


async def measured(
    args: list[str], clients: int, seconds: float, pin: str, rt: bool, pages: int = 0
) -> tuple[dict[str, list[list[int]]], list[int], str]:
    """An emulator with ``args``, ``clients`` state clients measuring it for ``seconds`` in a child
    process (and ``pages`` web pages in another): their timestamps, each page's message count, and
    the emulator's log (INFO)."""
    server_cpus, client_cpus = placement(pin)
    server = await Server.start("--state-rate", f"{STATE_RATE:g}", *args, cpus=server_cpus, log=True)
    counts: list[int] = []
    try:
        if rt:
            await asyncio.sleep(0.2)  # its threads started (the ones started later inherit the policy)
            real_time(server.proc.pid)
        cmds = [[sys.executable, __file__, "--measure-state", str(server.ports["state"]), str(clients), str(seconds)]]
        if pages:
            assert server.web_url is not None
            cmds.append([sys.executable, __file__, "--measure-pages", server.web_url, str(pages), str(seconds + 1.0)])
        children = [await asyncio.create_subprocess_exec(*cmd, stdout=asyncio.subprocess.PIPE) for cmd in cmds]
        for child in children:
            if client_cpus is not None:
                os.sched_setaffinity(child.pid, client_cpus)
            if rt:
                real_time(child.pid)
        outs = [await asyncio.wait_for(c.communicate(), seconds + 60.0) for c in children]
        failed = [c.returncode for c in children if c.returncode != 0]
        if failed:
            raise RuntimeError(f"the measuring clients failed (exit {failed})")
        stamps = json.loads(outs[0][0])
        if pages:
            counts = json.loads(outs[1][0])["messages"]
    finally:
        log = await server.stop()
    return stamps, counts, log


async def jitter(clients: int, seconds: float, pin: str, rt: bool = False) -> dict[str, dict[str, float]]:
    stamps, _, _ = await measured([], clients, seconds, pin, rt)
    return {kind: summary(deviations(stamps[kind])) for kind in ("sent", "read")}


async def web_pages(pages: int | None, clients: int, seconds: float, pin: str, rt: bool = False) -> dict[str, float]:
    """State-topic jitter (``clients`` state clients) and the control loop's overruns with the web
    view off (``pages`` None) or on with ``pages`` pages reading it (WebSocket clients that parse
    every update as the page does; with many state clients the traffic list is busy)."""
    args = [] if pages is None else ["--web", "0", "--web-rate", "60"]
    stamps, counts, log = await measured(args, clients, seconds, pin, rt, pages or 0)
    found = re.search(r"control loop: (\d+) wake-ups, (\d+) overruns .*?latest ([\d.]+) ms", log)
    if found is None:
        raise RuntimeError("the emulator did not log its control-loop statistics:\n" + log[-2000:])
    result = summary(deviations(stamps["sent"]))
    result.update(
        wakes=int(found.group(1)),
        overruns=int(found.group(2)),
        latest=float(found.group(3)) / 1e3,
        updates=(statistics.median(counts) / (seconds + 1.0)) if counts else 0.0,
    )
    return result


def measure_pages(url: str, pages: int, seconds: float) -> dict[str, list[int]]:
    """``pages`` WebSocket clients on the web view for ``seconds``: messages each received."""
    import aiohttp

    async def page(session: aiohttp.ClientSession, counts: list[int], i: int) -> None:
        async with session.ws_connect(url + "ws") as ws:
            async for msg in ws:
                json.loads(msg.data)  # what a page does with each
                counts[i] += 1

    async def main() -> list[int]:
        counts = [0] * pages
        async with aiohttp.ClientSession() as session:
            tasks = [asyncio.create_task(page(session, counts, i)) for i in range(pages)]
            await asyncio.sleep(seconds)  # measuring an interval
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        return counts

    return {"messages": asyncio.run(main())}


def real_time(pid: int) -> None:
    """Every thread of ``pid`` on SCHED_FIFO (priority 10): other processes' load no longer delays it."""
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(ProcessLookupError):
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(10))


def rt_allowed() -> bool:
    try:
        real_time(os.getpid())
    except PermissionError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


def placement(pin: str) -> tuple[set[int] | None, set[int] | None]:
    """The CPUs of the emulator and of the measuring clients for ``--pin``."""
    cpus = sorted(os.sched_getaffinity(0))
    if pin == "same" or (pin == "split" and len(cpus) < 2):
        return {cpus[0]}, {cpus[0]}
    if pin == "split":
        return {cpus[1]}, {cpus[0]}
    return None, None


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


def spread(values: list[float]) -> str:
    """Median over runs, in ms, with the range when there are several runs."""
    ms = [v * 1e3 for v in values]
    if len(ms) == 1:
        return f"{ms[0]:.3f}"
    return f"{statistics.median(ms):.3f} ({min(ms):.3f}-{max(ms):.3f})"


async def run(
    quick: bool, clients: list[int], runs: int, pin: str, only: str | None, rt: bool, web_clients: list[int]
) -> None:
    seconds = 2.0 if quick else 5.0
    if rt and not rt_allowed():
        print("(--rt: SCHED_FIFO is not permitted here (CAP_SYS_NICE); measuring without it)")
        rt = False
    where = pin_text(pin) + ("; both on SCHED_FIFO (other processes' load left out)" if rt else "")
    print(f"# emulator benchmark ({machine()}); emulator and clients: {where}")
    if only in (None, "jitter"):
        print()
        print(
            f"| state clients, {STATE_RATE:g} Hz | sent: jitter p50 (ms) | p99 (ms) | max (ms) "
            "| read: jitter p50 (ms) | p99 (ms) | max (ms) | intervals |"
        )
        print("|---:|---:|---:|---:|---:|---:|---:|---:|")
        for n in clients:
            results = [await jitter(n, seconds, pin, rt) for _ in range(runs)]
            cells = [spread([r[kind][q] for r in results]) for kind in ("sent", "read") for q in ("p50", "p99", "max")]
            intervals = int(statistics.median(r["sent"]["n"] for r in results))
            print(f"| {n} | " + " | ".join(cells) + f" | {intervals} |")
        if runs > 1:
            print(f"\n(median over {runs} runs, range in brackets)")
    if only in (None, "web"):
        print()
        print(
            f"| state clients ({STATE_RATE:g} Hz) | web view | state jitter p50 (ms) | p99 (ms) | max (ms) "
            "| control-loop overruns | latest wake-up (ms) | updates/s per page |"
        )
        print("|---:|---|---:|---:|---:|---:|---:|---:|")
        rises = []
        for n in web_clients:
            p99 = {}
            for label, pages in (("off", None), ("on, 0 pages", 0), (f"on, {PAGES} pages", PAGES)):
                results = [await web_pages(pages, n, seconds, pin, rt) for _ in range(runs)]
                cells = [spread([r[q] for r in results]) for q in ("p50", "p99", "max")]
                overruns = "/".join(str(r["overruns"]) for r in results)
                latest = spread([r["latest"] for r in results])
                updates = statistics.median(r["updates"] for r in results)
                p99[pages] = statistics.median(r["p99"] for r in results)
                print(f"| {n} | {label} | " + " | ".join(cells) + f" | {overruns} | {latest} | {updates:.1f} |")
            rises.append(f"{(p99[PAGES] - p99[0]) * 1e3:+.3f} ms with {n} state client{'s' if n > 1 else ''}")
        print(f"\np99 jitter rise with {PAGES} pages open over none: {', '.join(rises)} (target: at most +0.5 ms)")
        if runs > 1:
            print(f"(median over {runs} runs, range in brackets; overruns per run)")
    if only in (None, "streaming"):
        print()
        points = 500 if quick else 2000
        rate = await streaming(points)
        print("| measure | value |")
        print("|---|---:|")
        print(f"| stop-and-wait JOINT_TRAJ_PT streaming | {rate:,.0f} points/s |")
        idle, moving = await cpu(seconds)
        print(f"| emulator CPU, idle (40 Hz state, 1 client) | {idle * 100:.1f} % of one core |")
        print(f"| emulator CPU, moving | {moving * 100:.1f} % of one core |")


def pin_text(pin: str) -> str:
    server_cpus, client_cpus = placement(pin)
    if server_cpus is None or client_cpus is None:
        return "not pinned"
    if server_cpus == client_cpus:
        return f"both on CPU {min(server_cpus)}"
    return f"emulator on CPU {min(server_cpus)}, clients on CPU {min(client_cpus)}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--clients", default="1,10,50", help="state client counts (default 1,10,50)")
    parser.add_argument("--web-clients", default="1,50", help="state client counts of the web view part (default 1,50)")
    parser.add_argument("--runs", type=int, default=1, help="jitter runs per client count (default 1)")
    parser.add_argument("--pin", choices=["none", "same", "split"], default="none", help="CPU placement")
    parser.add_argument("--only", choices=["jitter", "web", "streaming"], help="one part only")
    parser.add_argument(
        "--rt",
        action="store_true",
        help="jitter: emulator and clients on SCHED_FIFO (needs CAP_SYS_NICE), so that the load of other processes on "
        "a shared machine is left out of the measure",
    )
    parser.add_argument("--measure-state", nargs=3, metavar=("PORT", "CLIENTS", "SECONDS"), help=argparse.SUPPRESS)
    parser.add_argument("--measure-pages", nargs=3, metavar=("URL", "PAGES", "SECONDS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure_pages:
        url, pages, seconds = args.measure_pages
        json.dump(measure_pages(url, int(pages), float(seconds)), sys.stdout)
        return
    if args.measure_state:
        port, clients, seconds = args.measure_state
        json.dump(measure_state(int(port), int(clients), float(seconds)), sys.stdout)
        return
    clients = [int(n) for n in args.clients.split(",")]
    web_clients = [int(n) for n in args.web_clients.split(",")]
    asyncio.run(run(args.quick, clients, max(1, args.runs), args.pin, args.only, args.rt, web_clients))


if __name__ == "__main__":
    main()
