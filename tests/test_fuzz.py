"""bench/fuzz, short: its safety model, the decoder fuzz, and a server run per profile.

The tool is the package ``bench.fuzz``, importable because the repository's root is on ``sys.path``
under pytest (as for ``tests.rawpeer``). The server runs start a ``robot-server`` child process on
free loopback ports; every wait in them is bounded, and nothing here asserts wall-clock time.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import struct
from pathlib import Path
from typing import Any

import pytest

from bench import fuzz
from simple_message import BE32, BE64, LE32, LE64, decode
from simple_message.errors import MalformedMessage
from simple_message.messages import JointTraj, JointTrajPt, JointTrajPtFull, JointTrajPtFullEx, MotoMotionCtrl, Ping
from tests.rawpeer import RawPeer, joint_traj_pt, vectors

#: small runs: what the tool is for at scale, in a few seconds
SERVER_FRAMES = 20_000
DECODER_FRAMES = 20_000
#: RSS growth of a short run: the server's warm-up (allocator arenas, caches) is included, a leak
#: of the order of a frame's size per frame (20,000 x ~100 bytes = 2 MB) on top would still fit: this
#: bound catches runaway growth; the 5 MB target is for long runs (python -m bench.fuzz)
MAX_RSS_GROWTH_MB = 30.0


def _plausible(x: float) -> bool:
    return math.isfinite(x) and abs(x) <= fuzz.PLAUSIBLE


def _motion_command(msg: object) -> bool:
    """Whether the project's decoder reads ``msg`` as a motion command the fuzzer must never send."""
    if isinstance(msg, JointTrajPt):
        return msg.sequence == -4 or _plausible(msg.joint_data[0])
    if isinstance(msg, JointTrajPtFull):
        return msg.sequence == -4 or _plausible(msg.positions[0])
    if isinstance(msg, MotoMotionCtrl):
        return msg.command in fuzz.MOTO_COMMANDS
    if isinstance(msg, JointTrajPtFullEx):
        return msg.sequence == -4 or any(_plausible(g.positions[0]) for g in msg.groups)
    if isinstance(msg, JointTraj):
        return any(_plausible(p.joint_data[0]) for p in msg.points)
    return False


# -- the safety check and the model of the server's framing ---------------------------------------


def test_reference_motion_vectors_are_refused_and_poisoned_ones_pass() -> None:
    v = vectors("<")
    for name in ("JOINT_TRAJ_PT_REQUEST_SEQ3", "JOINT_TRAJ_PT_FULL_REQUEST", "JOINT_TRAJ_PT_REQUEST_STOP_ALLZERO"):
        assert fuzz.unsafe_reason(v[name]) is not None, name
    point = bytearray(v["JOINT_TRAJ_PT_REQUEST_SEQ3"])
    for bad in (math.nan, math.inf, -math.inf, 1e6):
        struct.pack_into("<f", point, 20, bad)  # position 0
        assert fuzz.unsafe_reason(bytes(point)) is None, bad
    struct.pack_into("<i", point, 16, -4)  # a STOP stays refused, whatever its positions
    assert fuzz.unsafe_reason(bytes(point)) is not None
    # header-only and truncated bodies fit no layout; a longer body is read from its end too
    assert fuzz.unsafe_reason(fuzz.frame_of("<", 11, 2, 0, b"")) is None
    assert fuzz.unsafe_reason(fuzz.frame_of("<", 14, 2, 0, v["JOINT_TRAJ_PT_FULL_REQUEST"][16:-1])) is None
    padded = fuzz.frame_of("<", 11, 2, 0, b"\x7f" * 8 + v["JOINT_TRAJ_PT_REQUEST_SEQ3"][16:])
    assert fuzz.unsafe_reason(padded) is not None
    # the big-endian reading of the same bytes counts as much as the little-endian one
    assert fuzz.unsafe_reason(vectors(">")["JOINT_TRAJ_PT_REQUEST_SEQ3"]) is not None
    # MOTO_MOTION_CTRL: no known command, whatever else
    ctrl = struct.pack("<3i10f", 0, 0, 200121, *[0.0] * 10)
    assert fuzz.unsafe_reason(fuzz.frame_of("<", 2001, 2, 0, ctrl)) is not None
    ctrl = struct.pack("<3i10f", 0, 0, 200200, *[0.0] * 10)
    assert fuzz.unsafe_reason(fuzz.frame_of("<", 2001, 2, 0, ctrl)) is None


@pytest.mark.parametrize(("order", "real"), [("<", 4), ("<", 8), (">", 4), ("auto", 4)])
def test_nothing_the_server_can_cut_decodes_as_a_motion_command(order: str, real: int) -> None:
    """The generator and the framing model, checked against the project's own decoder: of 20,000
    units as a connection would send them, no frame the server cuts decodes (in either real size)
    as a motion command, and none is a PING (the markers' type)."""
    rng = random.Random(7)
    corpus = fuzz.load_corpus()
    shadow = fuzz.Shadow(order)
    gen_order = "<" if order == "auto" else order
    gen = fuzz.Generator(rng, gen_order, real, corpus)
    streams: list[list[bytes]] = [[]]
    sent = 0
    while sent < 20_000:
        unit = shadow.add(gen.unit())
        if unit is None:
            filler = shadow.filler(rng)
            unit = None if filler is None else shadow.add(filler)
            if unit is None:  # stuck: the connection would end here
                shadow, streams = fuzz.Shadow(order), [*streams, []]
                continue
        streams[-1].append(unit)
        sent += 1
        if shadow.fatal:
            shadow, streams = fuzz.Shadow(order), [*streams, []]
    prefix = "<" if order in ("<", "auto") else ">"
    wires = (LE32, LE64) if prefix == "<" else (BE32, BE64)
    cut = 0
    for stream in streams:
        data, pos = b"".join(stream), 0
        while len(data) - pos >= 4:
            (length,) = struct.unpack_from(prefix + "i", data, pos)
            if not 12 <= length <= fuzz.MAX_LENGTH or len(data) - pos < 4 + length:
                break
            frame = data[pos : pos + 4 + length]
            pos += 4 + length
            cut += 1
            for wire in wires:
                try:
                    msg = decode(frame, wire)
                except MalformedMessage:
                    continue
                assert not _motion_command(msg), frame.hex()
                assert not isinstance(msg, Ping), frame.hex()
    assert cut > 15_000


# -- the decoder -----------------------------------------------------------------------------------


def test_decoder_fuzz_raises_documented_errors_only() -> None:
    report = fuzz.fuzz_decoder(DECODER_FRAMES, seed=3)
    assert report.frames >= DECODER_FRAMES
    undocumented = {
        kind: entry for kind, entry in report.failures.items() if kind.split(":")[0] in ("feed", "next_frame", "decode")
    }
    assert not undocumented, {kind: (n, what, data.hex()) for kind, (n, what, data) in undocumented.items()}
    assert set(report.exceptions) <= {"decode: MalformedMessage", "next_frame: FrameError"}, report.exceptions
    assert report.exceptions["decode: MalformedMessage"] > 0 and report.exceptions["next_frame: FrameError"] > 0


def test_decoder_fuzz_every_frame_re_encodes_exactly_and_both_paths_agree() -> None:
    report = fuzz.fuzz_decoder(DECODER_FRAMES, seed=3)
    assert report.failure_count == 0, {kind: (n, what, data.hex()) for kind, (n, what, data) in report.failures.items()}


# -- the server, one short run per profile ---------------------------------------------------------


@pytest.mark.slow
async def test_the_monitor_sees_motion(tmp_path: Path) -> None:
    """What makes "0 motion" mean something: the fuzzer's state monitor counts motion as soon as the
    robot moves. The motion is a valid two-point trajectory streamed here, by a raw client (the
    fuzzer never sends one)."""
    options = fuzz.Options(profiles=("generic",), quiet=True)
    proc, target = await fuzz.start_server("generic", options, tmp_path / "robot-server.log")
    report = fuzz.ProfileReport("generic")
    run = fuzz.FuzzRun(options, "generic", target, report)
    ready = asyncio.Event()
    monitor = asyncio.create_task(run.monitor(ready))
    peer: RawPeer | None = None
    try:
        await asyncio.wait_for(ready.wait(), 10.0)
        await asyncio.wait_for(run.state_rounds(3), 10.0)
        assert report.motion == 0 and report.state_messages > 0
        peer = await RawPeer.connect(target.ports["motion"])
        template = vectors("<")["JOINT_TRAJ_PT_REQUEST_SEQ3"]
        for seq, q in enumerate(([0.0] * 6, [0.05] * 6)):
            reply = await peer.request(joint_traj_pt(template, seq, q, 0.5, 0.0), timeout=5.0)
            assert reply.reply_code == 1
        async with asyncio.timeout(10.0):
            while report.motion == 0:
                await run.state_rounds(1)
        assert report.max_deviation > 1e-6 or "in_motion" in report.motion_detail
    finally:
        run.stop()
        monitor.cancel()
        await asyncio.gather(monitor, return_exceptions=True)
        if peer is not None:
            await peer.close()
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
        await asyncio.wait_for(proc.wait(), 30.0)


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_invalid_frames_never_crash_hang_or_move_the_robot(profile: str, tmp_path: Path) -> None:
    options = fuzz.Options(
        profiles=(profile,),
        frames=SERVER_FRAMES,
        seconds=60.0,  # a bound: the frame count ends the run long before
        connections=4,
        seed=11,
        decoder_frames=0,
        probe_interval=0.25,
        # the benchmark's 1 s would measure the machine here (CI, two busy cores): a real hang is
        # a server that never answers, and 10 s tells it apart from a slow machine
        hang_after=10.0,
        log_dir=tmp_path,
        quiet=True,
    )
    report: Any = await fuzz.fuzz_server(profile, options)
    summary = fuzz.details(report)
    assert report.frames >= SERVER_FRAMES, summary
    assert report.crashes == 0, summary
    assert report.hangs == 0, summary
    assert report.motion == 0, summary
    assert report.state_messages > 0, summary  # the monitor saw the robot throughout
    assert report.tracebacks == 0, summary
    assert report.exit_code == 0, summary
    assert report.probes > 0 and set(report.ports) >= {"motion", "state"}, summary
    assert all(p.frames > 0 for p in report.ports.values()), summary
    assert report.rss_growth is not None and report.rss_growth <= MAX_RSS_GROWTH_MB, summary
