"""Codec benchmark: encode/decode rates per message type and frame-decoder throughput.

Plain script; prints a table. Targets: decoding at least 300,000 JOINT_TRAJ_PT frames per second on
one core, frame cutting included (issue 2); 1,000,000 on the path a Link takes,
``FrameDecoder.feed_messages`` (issue 16); 200,000 messages per second decoded from a 100 MB
pcapng of the project's own traffic (issue 20; ``--capture-mb`` sets its size); JOINT_TRAJ_PT cut
and decoded at least at the reference C++ library's rate, both measured in the same run (issue 38).

Columns: ``cut+decode`` is ``feed`` + ``decode`` of each frame, each message dropped at once;
``kept`` the same with the messages of a call kept until its end; ``feed_messages`` cuts and decodes
in one pass and returns the call's messages in a list (iterated, as a Link does, whose event queue
keeps them too). Keeping ~1000 messages alive makes the garbage collector run during the call (most
visible with the three-array types), so ``kept`` is the like-for-like comparison. Each call takes
1000 coalesced frames of one type, which ``feed_messages`` decodes as one run; the mixed-stream
table below shows both paths on a random mix of four types (runs of about one frame).

When the reference C++ peer is built (shared/peer beside this repository; ``--peer DIR``, else
``$SM_PEER_DIR``, else /work/peer-build/bin: see bench/latency.py), its ``sm_client decode N`` (a frame
from its bytes, then its JOINT_TRAJ_PT message, one frame at a time) and this package's JOINT_TRAJ_PT
paths are measured in alternating runs of about the same length (``--runs``, default 5), ``--pin
same`` keeping this process and the C++ client on one CPU; the table gives each one's median and
range and the ratio of the medians to the C++ rate, with the target.

    python bench/codec.py [--seconds 0.5] [--capture-mb 100] [--peer DIR] [--runs 5] [--pin none|same]
                          [--peer-only]
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import random
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from simple_message import (
    LE32,
    CommType,
    FrameDecoder,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    Message,
    ReplyCode,
    Status,
    decode,
    encode,
)
from simple_message.capture import CapturedMessage, CaptureWriter, captured_messages
from simple_message.connection import TapLink


def rate(fn: Callable[[], object], seconds: float, batch: int = 1000) -> float:
    """Calls per second of ``fn``, best of three runs of about ``seconds`` each."""
    best = 0.0
    for _ in range(3):
        n = 0
        start = time.perf_counter()
        deadline = start + seconds
        while True:
            for _ in range(batch):
                fn()
            n += batch
            now = time.perf_counter()
            if now >= deadline:
                break
        best = max(best, n / (now - start))
    return best


def once(fn: Callable[[], object], seconds: float, batch: int = 1) -> float:
    """Calls per second of ``fn`` over one run of at least ``seconds`` (for runs alternated with another
    program's, each measured once)."""
    n = 0
    start = time.perf_counter()
    deadline = start + seconds
    while True:
        for _ in range(batch):
            fn()
        n += batch
        now = time.perf_counter()
        if now >= deadline:
            return n / (now - start)


def machine() -> str:
    """Python version, CPU model and core count, for the benchmark tables."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"Python {platform.python_version()}, {model}, {os.cpu_count()} cores"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=0.5)
    parser.add_argument("--capture-mb", type=float, default=100.0, help="size of the capture decoded (MB)")
    parser.add_argument(
        "--peer",
        metavar="DIR",
        help="where the C++ peer's sm_client is (default: $SM_PEER_DIR, else /work/peer-build/bin)",
    )
    parser.add_argument("--runs", type=int, default=5, help="alternating runs against the C++ library")
    parser.add_argument(
        "--pin",
        choices=["none", "same"],
        default="none",
        help="against the C++ library: this process and the C++ client on one CPU (same), or where the OS puts them",
    )
    parser.add_argument("--peer-only", action="store_true", help="only the comparison with the C++ library")
    args = parser.parse_args()
    if not args.peer_only:
        tables(args.seconds, args.capture_mb)
    compare_with_peer(args.peer, max(args.runs, 1), args.pin, args.seconds, header=args.peer_only)


def tables(seconds: float, capture_mb: float) -> None:
    """The package's own rates (no comparison)."""
    q = [0.1, -0.2, 0.3, -0.4, 0.5, -0.6]
    samples: list[tuple[str, Message]] = [
        ("JOINT_TRAJ_PT", JointTrajPt(7, q, 0.5, 0.1)),
        ("JOINT_TRAJ_PT_FULL", JointTrajPtFull(0, 7, 0x0F, 1.5, q, q, q)),
        ("JOINT_FEEDBACK", JointFeedback(0, 0x0E, 1.5, q, q, q)),
    ]
    print(f"# simple_message codec benchmark: {machine()}")
    print()
    print(
        f"| {'message':<22} | {'encode msg/s':>14} | {'decode msg/s':>14} | {'cut+decode msg/s':>17} "
        f"| {'kept msg/s':>11} | {'feed_messages msg/s':>20} |"
    )
    print(f"|{'-' * 24}|{'-' * 16}|{'-' * 16}|{'-' * 19}|{'-' * 13}|{'-' * 22}|")
    for name, msg in samples:
        frame = encode(msg, LE32)
        enc = rate(lambda m=msg: encode(m, LE32), seconds)
        dec = rate(lambda f=frame: decode(f, LE32), seconds)
        # Frame cutting plus decoding, from a stream of 1000 coalesced frames per feed.
        chunk = frame * 1000
        decoder = FrameDecoder()

        def cut_and_decode(chunk: bytes = chunk, decoder: FrameDecoder = decoder) -> None:
            decoder.feed(chunk)
            for f in decoder:
                decode(f, LE32)

        both = rate(cut_and_decode, seconds, batch=1) * 1000

        def cut_and_decode_kept(chunk: bytes = chunk, decoder: FrameDecoder = decoder) -> None:
            decoder.feed(chunk)
            for _m in [decode(f, LE32) for f in decoder]:
                pass

        kept = rate(cut_and_decode_kept, seconds, batch=1) * 1000

        def feed_messages(chunk: bytes = chunk, decoder: FrameDecoder = decoder) -> None:
            for _m in decoder.feed_messages(chunk, LE32):
                pass

        one_pass = rate(feed_messages, seconds, batch=1) * 1000
        print(f"| {name:<22} | {enc:>14,.0f} | {dec:>14,.0f} | {both:>17,.0f} | {kept:>11,.0f} | {one_pass:>20,.0f} |")

    # Frame-decoder throughput on a 10 MB mixed stream fed in 64 KiB reads (as a socket delivers it).
    rng = random.Random(1)
    mix = [encode(m, LE32) for _, m in samples] + [encode(Status(1, 0, 0, 0, 1, 2, 1), LE32)]
    parts: list[bytes] = []
    size = 0
    while size < 10_000_000:
        f = rng.choice(mix)
        parts.append(f)
        size += len(f)
    stream = b"".join(parts)
    chunks = [stream[i : i + 65536] for i in range(0, len(stream), 65536)]
    best = 0.0
    frames = 0
    for _ in range(3):
        decoder = FrameDecoder()
        frames = 0
        start = time.perf_counter()
        for c in chunks:
            decoder.feed(c)
            for _f in decoder:
                frames += 1
        best = max(best, len(stream) / (time.perf_counter() - start))
    print()
    print("| frame decoder, 10 MB mixed stream in 64 KiB reads | MB/s | frames/s |")
    print("|---|---:|---:|")
    print(f"| {len(stream) / 1e6:.1f} MB, {frames:,} frames | {best / 1e6:,.1f} | {best / len(stream) * frames:,.0f} |")

    # The same stream cut and decoded: feed + decode of each frame, and feed_messages.
    def plain() -> None:
        decoder = FrameDecoder()
        for c in chunks:
            decoder.feed(c)
            for f in decoder:
                decode(f, LE32)

    def plain_kept() -> None:
        decoder = FrameDecoder()
        for c in chunks:
            decoder.feed(c)
            for _m in [decode(f, LE32) for f in decoder]:
                pass

    def one_pass() -> None:
        decoder = FrameDecoder()
        for c in chunks:
            for _m in decoder.feed_messages(c, LE32):
                pass

    print()
    print("| the same stream cut and decoded | msg/s |")
    print("|---|---:|")
    for label, fn in (("feed + decode", plain), ("feed + decode, kept", plain_kept), ("feed_messages", one_pass)):
        print(f"| {label} | {rate(fn, seconds, batch=1) * frames:,.0f} |")
    capture_rate(capture_mb)


JTP_POINT = JointTrajPt(7, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 0.5, 2.0)  # sm_client decode's point (sm_client.cpp)


#: the row of ``feed_messages`` measured with the process's start-up objects frozen out of the
#: garbage collector's scans (``gc.freeze``), as a robot-server or a fleet runs once it is ready:
#: a collection then walks what the decoding made, not every module and table of the process
FROZEN = "`feed_messages`, the start-up objects frozen (`gc.freeze`), as robot-server runs once ready"


def compare_with_peer(peer_option: str | None, runs: int, pin: str, seconds: float, *, header: bool) -> None:
    """JOINT_TRAJ_PT cut and decoded here and by the C++ library (``sm_client decode``), alternating."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from latency import BUILD_HINT, DECODE_COUNT, PeerError, find_peer, sm_client_decode

    if header:
        print(f"# simple_message codec benchmark: {machine()}")
    peer, where = find_peer(peer_option)
    if peer is None:
        print(f"\n(C++ reference peer not built: no sm_client in {where}; {BUILD_HINT}, or --peer DIR)")
        return
    frame = encode(JTP_POINT, LE32)
    chunk = frame * 1000
    decoder = FrameDecoder()

    def feed_messages() -> None:
        for _m in decoder.feed_messages(chunk, LE32):
            pass

    def feed_and_decode() -> None:
        decoder.feed(chunk)
        for f in decoder:
            decode(f, LE32)

    def decode_frames() -> None:
        for _ in range(1000):
            decode(frame, LE32)

    def feed_messages_no_gc() -> None:
        gc.disable()
        try:
            feed_messages()
        finally:
            gc.enable()

    paths: list[tuple[str, Callable[[], None]]] = [
        ("`feed_messages`: 1000 coalesced frames cut and decoded in one pass (every connection's path)", feed_messages),
        (FROZEN, feed_messages),
        ("`feed` + `decode` of each frame (the cut+decode column)", feed_and_decode),
        ("`decode(frame)`, one whole frame at a time (what sm_client decode does per frame)", decode_frames),
        ("(for scale: `feed_messages` with the garbage collector off, as the package never runs)", feed_messages_no_gc),
    ]
    cpp: list[float] = []
    rates: dict[str, list[float]] = {name: [] for name, _ in paths}
    before = os.sched_getaffinity(0)
    cpu = min(before)
    if pin == "same":
        os.sched_setaffinity(0, {cpu})  # sm_client inherits it
    try:
        for _ in range(runs):
            try:
                cpp.append(sm_client_decode(peer, DECODE_COUNT))
            except PeerError as e:
                print(f"\n(sm_client decode failed: {e})")
                return
            for name, fn in paths:
                if name == FROZEN:  # as robot-server runs once ready (robot_server.cli.freeze_startup_objects)
                    gc.collect()
                    gc.freeze()
                try:
                    rates[name].append(once(fn, seconds) * 1000)
                finally:
                    gc.unfreeze()
    finally:
        os.sched_setaffinity(0, before)
    where_run = f"pinned to CPU {cpu}" if pin == "same" else "not pinned"
    print()
    print(
        f"| JOINT_TRAJ_PT cut+decode against the C++ library ({peer}), {runs} alternating runs, {where_run}: "
        "median (range) | msg/s | ratio to C++ (target, issue 38: feed_messages >= 1.0x) |"
    )
    print("|---|---:|---:|")
    print(f"| C++ `sm_client decode {DECODE_COUNT}` | {spread(cpp)} | |")
    cpp_median = statistics.median(cpp)
    for name, _ in paths:
        ratio = statistics.median(rates[name]) / cpp_median
        paired = [p / c for p, c in zip(rates[name], cpp, strict=True)]
        print(f"| {name} | {spread(rates[name])} | {ratio:.2f}x (run pairs {min(paired):.2f}-{max(paired):.2f}x) |")


def spread(values: list[float]) -> str:
    """Median and range of the runs."""
    return f"{statistics.median(values):,.0f} ({min(values) / 1e6:.2f}-{max(values) / 1e6:.2f} M)"


def write_capture(path: str, megabytes: float) -> int:
    """A pcapng of the project's own traffic, as robot-server --capture writes it (the
    CaptureWriter, through its Tap interface): a state connection publishing JOINT_POSITION and
    STATUS every 4 ms (and JOINT_FEEDBACK every other round) in one write, and a motion
    connection streaming JOINT_TRAJ_PT requests and their replies. Returns the messages written."""
    writer = CaptureWriter(path, max_bytes=10**12, files=1)
    state = TapLink("state", ("127.0.0.1", 11002), ("127.0.0.1", 40001), accepted=True)
    motion = TapLink("motion", ("127.0.0.1", 11000), ("127.0.0.1", 40002), accepted=True)
    t = 1_700_000_000_000_000_000
    writer.opened(state, t)
    writer.opened(motion, t)
    status = encode(Status(1, 0, 0, 0, 1, 2, 1), LE32)
    reply = encode(JointTrajPt(0, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS), LE32)
    messages, k = 0, 0
    target = megabytes * 1e6
    while True:
        k += 1
        t += 4_000_000
        q = (0.001 * k,) * 6
        chunk = encode(JointPosition(0, q), LE32) + status
        messages += 2
        if k % 2 == 0:
            chunk += encode(JointFeedback(0, 2, 0.0, q), LE32)
            messages += 1
        writer.data(state, True, chunk, t)
        if k % 3 == 0:
            writer.data(motion, False, encode(JointTrajPt(k, q, 0.5, 0.1), LE32), t + 1000)
            writer.data(motion, True, reply, t + 2000)
            messages += 2
        if k % 5000 == 0 and os.path.getsize(path) >= target:
            break
    writer.closed(state, False, t)
    writer.closed(motion, False, t)
    writer.close()
    return messages


def capture_rate(megabytes: float) -> None:
    """Messages per second decoded from a capture of the project's own traffic (target: 200,000)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "traffic.pcapng")
        written = write_capture(path, megabytes)
        size = os.path.getsize(path)
        best = 0.0
        for _ in range(3):
            t0 = time.perf_counter()
            decoded = sum(1 for item in captured_messages(path, LE32, True) if isinstance(item, CapturedMessage))
            best = max(best, decoded / (time.perf_counter() - t0))
        assert decoded == written, (decoded, written)
    print()
    print("| capture decode (`captured_messages`: read, TCP reassembled, cut, decoded) | messages | msg/s |")
    print("|---|---:|---:|")
    print(f"| {size / 1e6:.0f} MB pcapng of the project's own traffic | {decoded:,} | {best:,.0f} |")


if __name__ == "__main__":
    main()
