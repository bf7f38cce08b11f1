"""Fuzz and fault tool: random and mutated frames against ``robot-server`` and the sans-I/O decoder.

Plain script; prints one table and exits 1 if any failure count is non-zero::

    python bench/fuzz.py            # both profiles, 1,000,000 frames each, then 1,000,000 through the decoder
    python bench/fuzz.py --profile generic --frames 20000 --decoder-frames 20000   # a quick look
    python bench/fuzz.py --server-args='--byte-order auto'          # more robot-server arguments
    python bench/fuzz.py --profile motoros --host 127.0.0.1 --motion-port 50240 --state-port 50241 \\
        --io-port 50242 --server-log server.log --server-pid 1234      # a server that is already running

**The server run** (once per ``--profile``): ``robot-server`` is started as a child process on free
loopback ports (``--motion-port 0`` ...: the server picks them, no race), its log (``--log-level
INFO``) going to a file; or a running server is targeted (``--motion-port`` given; tracebacks are
then counted only with ``--server-log``, RSS only with ``--server-pid``, and the server's byte order
and real size must be given: ``--byte-order``, ``--float64``). Every port of the profile (motion,
state, and io for motoros) is driven over ``--connections`` concurrent connections each, fewer where
the server takes fewer: the motion port has one client at a time on every profile (a newcomer
replaces it while the robot is at rest), so it gets one connection with ``--connections`` times
the window instead; MotoROS takes one IO client and four state clients (the monitor has one
place, one is left free for reconnections: two fuzz). Until ``--frames`` frames are sent or
``--seconds`` have passed, each connection writes batches of ``--batch`` frames at once (coalesced
frames), one in 20 split over several writes at random byte offsets, and reads whatever comes back
(in either byte order where the server detects it: until a connection's first frame is read, it
gets the topics in the order of the last motion client). Meanwhile:

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
  process exited (a **crash**); and afterwards, ``Traceback`` lines in its log, its size and lines
  per second. The last batches of every connection are kept: a traceback's log line names the
  connection (the client port), whose last frames are written to ``fuzz-<profile>-<port>.txt``
  (``NAME HEX`` lines, readable by ``simple-message decode``). The table is followed by details per
  profile: frames per port, how many the server confirmably processed (before an answered marker),
  connections and how they ended, probes, state messages, RSS over the run.

**Frames.** From a corpus of the reference C++ library's vectors (``tests/data/vectors_*.txt``, both
byte orders) and the FS100 capture, and frames built here from each known type's layout with
random fields (interesting ints and reals, NaN, infinities, extremes), in the server's byte order
and both real sizes (float32 and float64 bodies), mutated: bit flips, byte sets, truncation,
extension, inserted and deleted bytes, another msg_type, comm_type (0, 4+, negative...) or
reply_code, header-only frames of every known type, unknown types, the other byte order, wrong
length prefixes (slightly off: the stream goes out of step), huge, negative and below-12 length
prefixes (fatal: the server must close), random garbage. Most frames keep an honest length prefix,
so that the server goes on parsing bodies rather than reconnecting; about 1 in 1000 ends its
connection (``--fatal-rate``). PING frames (type 1) are the markers and are not fuzzed at the server (the decoder fuzz
covers them): every type-1 reply is then a marker's.

**Never a valid motion command.** The point is to show that invalid frames never move the robot, so
no frame the server can cut from what is sent may be a valid motion command. A per-connection model
of the server's framing (:class:`Shadow`: the length prefix in the server's byte order, 12 to 64 KiB
or the connection ends) cuts every batch exactly as the server will, and every frame it cuts,
whatever mutation made it, is checked by :func:`unsafe_reason` before a byte is written; a frame
that fails is not sent (counted as *rejected*). After a length prefix the server must refuse, at
most 8 more bytes follow (never a whole frame), and the connection is closed once the server has;
when no unit may follow an incomplete frame (wrong length prefixes), the frame is completed with
0x7F/0xFF bytes if that passes the check, else the connection is closed (*abandoned*): what the
server holds then is never completed. The check reads the frame with :mod:`struct` only,
not with the project's decoder, so that a bug shared by our decoder and our server cannot hide. It
reads msg_type in both byte orders; for the motion types below it reads the body in that order under
every layout with both real sizes (float32 and float64), at the start of the body *and* aligned to
its end (the C++ library accepts a longer body, reading fields from the end, simple-message.md
§1.5); a layout the body is too short for does not apply (so a header-only or truncated body is
invalid). A position is *plausible* if it is finite and at most 1e3 in magnitude (1e3 rad or m is
beyond any joint's limit). The frame may be sent only if, under every layout that applies:

* JOINT_TRAJ_PT (11): position 0 is not plausible and the sequence is not -4 (STOP: a valid command,
  excluded as well);
* JOINT_TRAJ (12): the body is shorter than one point and its count (56 bytes), or made of the
  bytes 0x7F and 0xFF only (then every real at any offset, either byte order, either size, is NaN or
  at least 2^127 in magnitude);
* JOINT_TRAJ_PT_FULL (14): position 0 is not plausible (whatever ``valid_fields`` says: it is
  not trusted to hide the positions) and the sequence is not -4;
* MOTO_MOTION_CTRL (2001): the command is not one of MotoROS's (200100-200199): no valid motion
  control at all, not even CHECK_MOTION_READY or START_TRAJ_MODE, which do not move a robot
  themselves;
* JOINT_TRAJ_PT_FULL_EX (2016): for each group count 1-4 the body can hold, position 0 of every
  group is not plausible, and the sequence is not -4.

The generator poisons these frames on purpose (position 0, all positions, or every real field, with
NaN, infinities, 1e6 and more, or the bytes 0x7F/0xFF; commands outside the range; sequences other
than -4, reserved ones like -7 included; any comm_type), then mutates them like the others; what
the check refuses is generated again. Other fields are free: velocities, times, groups, comm_type
0, 4 and more, ``valid_fields``. Nothing else moves a robot: MOTO_MOTION_CTRL is never valid, IO
writes and SELECT_TOOL are allowed.

**The decoder run** (``--decoder-frames``): the same generator without those restrictions (PINGs,
both byte orders, both real sizes, more fatal prefixes), fed to
:class:`simple_message.framing.FrameDecoder` in random chunks (configured and autodetected byte
order), each frame given to :func:`simple_message.messages.decode` in both real sizes, and the same
chunks to :meth:`~simple_message.framing.FrameDecoder.feed_messages` (the Link's path). Documented:
``next_frame`` raises :class:`~simple_message.errors.FrameError`, ``decode`` raises
:class:`~simple_message.errors.MalformedMessage`, ``feed``/``feed_messages`` raise nothing. Any other
exception is a failure, reported with the reproducing bytes (hex); so is a decoded message that
does not re-encode to its frame (except a float32 signalling NaN, which comes back quieted, as
documented) and a ``feed_messages`` result that differs from ``feed`` + ``decode``.

**Failures** (exit status 1): crashes (the server exited, or did not exit 0 within 30 s of SIGTERM),
hangs (probes unanswered within 1 s, stalled connections, state silences over 1 s), tracebacks,
motion, a monitor that saw no state at all, decoder failures, and with ``--max-rss-growth MB`` an
RSS growth above it. The RSS growth includes the server's warm-up (its first 10 % of the frames
or so, reported apart).

Targets: at least 1,000,000 frames per profile with 0 crashes, 0 hangs, 0 tracebacks, 0 motion and
an RSS growth of at most 5 MB; at least 1,000,000 frames through the decoder with documented errors
only.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib
import math
import random
import re
import shlex
import signal
import socket
import struct
import sys
import tempfile
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"

# -- the protocol, as far as this tool needs it (simple-message.md §1-§4, §8.1) ------------------

HEADER = 16  # length prefix + msg_type + comm_type + reply_code
MAX_LENGTH = 64 * 1024  # the server's default largest length prefix (simple_message.framing)
PING = 1
MOTION_TYPES = frozenset({11, 12, 14, 2001, 2016, 65001})  # 65001: the project's CARTESIAN_LINE
#: MotoROS closes its motion connection on these (§8.1): sent rarely there, or every frame would
#: cost a reconnection
MOTOROS_CLOSING = frozenset({13, 15, 2002, 2017})
#: body layouts per type, (request or topic, reply); "r" is one real, "I" an unsigned int
LAYOUTS: dict[int, tuple[str, str]] = {
    1: ("", ""),
    2: ("", "3i"),
    10: ("i10r", "i10r"),
    13: ("7i", "7i"),
    15: ("2i31r", "2i31r"),
    2002: ("5i10r", "5i10r"),
    2003: ("I", "Ii"),
    2004: ("Ii", "Ii"),
    2005: ("II", "i"),
    2006: ("i", "i"),
    2007: ("I", "Ii"),
    2008: ("Ii", "Ii"),
    2009: ("II", "i"),
    2010: ("i", "i"),
    2011: ("ii", "ii"),
    2012: ("I", "Ii"),
    2013: ("II", "i"),
    2017: ("i" + "2i31r" * 4, "i" + "2i31r" * 4),
    2018: ("3i", "3i"),
    2020: ("", "128r"),
    65002: ("2i9r", "2i9r"),  # the project's TOOL_POSE (its subscription on the state port)
}
KNOWN_TYPES = tuple(sorted(set(LAYOUTS) | MOTION_TYPES))
UNKNOWN_TYPES: tuple[int, ...] = (0, -1, 3, 9, 16, 17, 19, 20, 21, 22, 999, 1000, 1300, 1400, 2000, 2014, 2015)
UNKNOWN_TYPES += (2019, 2021, 3000, 65003, 65535, 65536, 2**31 - 1, -(2**31))
MOTO_COMMANDS = range(200100, 200200)  # every MOTO_MOTION_CTRL command MotoROS has, and spares
#: a position is plausible when finite and at most this far from zero (rad or m)
PLAUSIBLE = 1e3
POISON_BYTES = b"\x7f\xff"

INTS: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6, 7, 8, 10, 15, 63, 64, 100, 1000, -1, -2, -3, -4, -5, -7, 200101)
INTS += (200121, 200130, 2001, 3001, 3003, 5008, 2**31 - 1, -(2**31), 0x7F7F7F7F)
NAN, INF = math.nan, math.inf
REALS: tuple[float, ...] = (0.0, -0.0, 1.0, -1.0, 0.5, 0.1, 1e-45, 1e-38, 3.14159, 6.3, 1e3, 1e6, -1e6, 3.4e38)
REALS += (-3.4e38, INF, -INF, NAN, 14400.0, 1e9, 0.004, 1e-6)
POISON_REALS = (NAN, INF, -INF, 1e6, -1e6, 1e30, -3.0e38, 1234.5, 4.0e3)
COMM_TYPES = (1, 2, 2, 2, 2, 2, 2, 3, 0, 4, 5, -1, 255, 2**31 - 1)
REPLY_CODES = (0, 0, 0, 0, 1, 2, 3, -1, 7)
FATAL_LENGTHS = (-1, -12, -(2**31), 0, 1, 4, 8, 11, MAX_LENGTH + 1, 2**20, 2**31 - 1, 0x7F7F7F7F)

_INT = {o: struct.Struct(o + "i") for o in "<>"}
_INT2 = {o: struct.Struct(o + "ii") for o in "<>"}
_HEAD = {o: struct.Struct(o + "4i") for o in "<>"}
_REAL = {(o, r): struct.Struct(o + ("f" if r == 4 else "d")) for o in "<>" for r in (4, 8)}
_F32_MAX = 3.4028234663852886e38


#: any byte -> 0x7F or 0xFF (by its high bit): random bytes made poison
_TO_POISON = bytes(0x7F if b < 0x80 else 0xFF for b in range(256))


def poison_bytes(rng: random.Random, n: int) -> bytes:
    """``n`` random bytes among 0x7F and 0xFF (every real read from them is NaN or huge)."""
    return rng.randbytes(n).translate(_TO_POISON)


def _plausible(value: float) -> bool:
    return abs(value) <= PLAUSIBLE  # False for NaN and infinities


# -- the safety check: what may be sent (the module doc) -----------------------------------------


def unsafe_reason(frame: bytes) -> str | None:
    """``None`` if ``frame`` (prefix, header, body) is certainly not a valid motion command under any
    byte order, real size or layout, else why it might be one (the module doc has the rule).

    Reads the frame with :mod:`struct` only: independent of the project's decoder.
    """
    if len(frame) < HEADER:
        return None
    body = frame[HEADER:]
    for order in "<>":
        (msg_type,) = _INT[order].unpack_from(frame, 4)
        if msg_type in MOTION_TYPES:
            reason = _motion_body_reason(msg_type, body, order)
            if reason is not None:
                return f"type {msg_type} ({'little' if order == '<' else 'big'}-endian): {reason}"
    return None


def _alignments(n: int, size: int) -> tuple[int, ...]:
    """Offsets a layout of ``size`` bytes can be read at in a body of ``n`` (start, end-aligned)."""
    if n < size:
        return ()
    return (0,) if n == size else (0, n - size)


def _motion_body_reason(msg_type: int, body: bytes, order: str) -> str | None:
    n = len(body)
    if not body.strip(POISON_BYTES):  # only 0x7F and 0xFF bytes: every real anywhere is invalid
        return None
    integer = _INT[order].unpack_from
    if msg_type == 12:
        return None if n < 56 else "JOINT_TRAJ body of 56+ bytes with bytes other than 0x7F/0xFF"
    for r in (4, 8):
        real = _REAL[order, r].unpack_from
        if msg_type == 11:
            size = 4 + 12 * r
            for off in _alignments(n, size):
                if integer(body, off)[0] == -4:
                    return f"sequence -4 (STOP) at body offset {off}"
                if _plausible(real(body, off + 4)[0]):
                    return f"plausible position 0 (float{8 * r}, body offset {off})"
        elif msg_type == 14:
            size = 12 + 31 * r
            for off in _alignments(n, size):
                if integer(body, off + 4)[0] == -4:
                    return f"sequence -4 (STOP) at body offset {off}"
                if _plausible(real(body, off + 12 + r)[0]):
                    return f"plausible position 0 (float{8 * r}, body offset {off})"
        elif msg_type == 65001:  # robot_id, sequence, x, y, z, ...
            size = 8 + 9 * r
            for off in _alignments(n, size):
                if integer(body, off + 4)[0] == -4:
                    return f"sequence -4 (STOP) at body offset {off}"
                if _plausible(real(body, off + 8)[0]):
                    return f"plausible position x (float{8 * r}, body offset {off})"
        elif msg_type == 2001:
            size = 12 + 10 * r
            for off in _alignments(n, size):
                if integer(body, off + 8)[0] in MOTO_COMMANDS:
                    return f"a MotoROS command (float{8 * r}, body offset {off})"
        else:  # 2016
            stride = 8 + 31 * r
            for groups in range(1, 5):
                for off in _alignments(n, 8 + groups * stride):
                    if integer(body, off + 4)[0] == -4:
                        return f"sequence -4 at body offset {off}"
                    for g in range(groups):
                        if _plausible(real(body, off + 8 + g * stride + 8 + r)[0]):
                            return f"plausible position 0 of group {g} of {groups} (float{8 * r}, offset {off})"
    return None


class Shadow:
    """The server's framing of one connection, modelled: cuts what is sent exactly as the server
    will, checks every frame it cuts, and says when the server will close the connection.

    ``order`` is the server's byte order (``"<"``, ``">"``, or ``"auto"``: decided by the first
    length prefix, little-endian if plausible, as the server detects it).
    """

    __slots__ = ("fatal", "max_length", "order", "pending", "prefix", "rare", "rng", "type1")

    def __init__(
        self,
        order: str,
        max_length: int = MAX_LENGTH,
        *,
        rare: frozenset[int] = frozenset(),
        rng: random.Random | None = None,
    ) -> None:
        self.order = order
        #: types the server would cut that are let through only 2 % of the time (MotoROS closes its
        #: motion connection on them: each would cost a reconnection); not a safety matter
        self.rare = rare
        self.rng = rng or random.Random(0)
        self.prefix = _INT[order] if order in "<>" else None
        self.max_length = max_length
        #: bytes of an incomplete frame the server holds
        self.pending = b""
        #: a fatal length prefix was sent: the server closes; nothing more may be sent
        self.fatal = False
        #: type-1 frames (PING) the server cut so far
        self.type1 = 0

    def add(self, unit: bytes, *, marker: bool = False) -> bytes | None:
        """What of ``unit`` may be sent next (all of it, or up to a fatal length prefix and a few
        bytes after it), the model updated; ``None`` if it may not be sent (a frame the server would
        cut is unsafe, or of type 1 and not a ``marker``), the model unchanged."""
        if self.fatal:
            return None
        pending = self.pending
        buf = pending + unit if pending else unit
        end = len(buf)
        pos = 0
        prefix = self.prefix
        type1 = 0
        fatal_at = -1
        while end - pos >= 4:
            if prefix is None:
                prefix = _detect(buf)
                if prefix is None:
                    fatal_at = pos
                    break
            (length,) = prefix.unpack_from(buf, pos)
            if length < 12 or length > self.max_length:
                fatal_at = pos
                break
            stop = pos + 4 + length
            if stop > end:
                break
            frame = buf if pos == 0 and stop == end else buf[pos:stop]
            msg_type = prefix.unpack_from(frame, 4)[0]
            if msg_type == PING:
                if not marker:
                    return None
                type1 += 1
            elif msg_type in self.rare and self.rng.random() >= 0.02:
                return None
            if unsafe_reason(frame) is not None:
                return None
            pos = stop
        self.prefix = prefix
        self.type1 += type1
        if fatal_at >= 0:
            self.fatal = True
            self.pending = b""
            keep = fatal_at + 4 + min(8, end - fatal_at - 4) - len(pending)
            return unit[: max(keep, 0)]
        self.pending = buf[pos:] if pos < end else b""
        return unit

    def filler(self, rng: random.Random) -> bytes | None:
        """Bytes 0x7F/0xFF that complete the incomplete frame the server holds (``None`` if there is
        none, or its length prefix is not complete): a way out when no generated unit may follow."""
        if len(self.pending) < 4 or self.prefix is None:
            return None
        missing = 4 + self.prefix.unpack_from(self.pending, 0)[0] - len(self.pending)
        return poison_bytes(rng, missing)


def _detect(buf: bytes) -> struct.Struct | None:
    """The server's byte-order detection from a first length prefix (simple_message.framing)."""
    for order in "<>":
        length = _INT[order].unpack_from(buf, 0)[0]
        if 12 <= length <= MAX_LENGTH:
            return _INT[order]
    return None


# -- frames --------------------------------------------------------------------------------------


def frame_of(order: str, msg_type: int, comm: int, reply: int, body: bytes) -> bytes:
    return _HEAD[order].pack(12 + len(body), msg_type, comm, reply) + body


def ping_request(order: str) -> bytes:
    return frame_of(order, PING, 2, 0, b"")


def load_corpus() -> dict[str, list[bytes]]:
    """The reference vectors by byte order (``"<"``, ``">"``), and the FS100 capture's frames."""
    corpus: dict[str, list[bytes]] = {"<": [], ">": []}
    for order, name in (("<", "vectors_le.txt"), (">", "vectors_be.txt")):
        path = DATA / name
        if path.exists():
            for line in path.read_text().splitlines():
                if line.strip() and not line.startswith("#"):
                    corpus[order].append(bytes.fromhex(line.split()[-1]))
    capture = DATA / "motoman_fs100_simple_move.segments.txt"
    if capture.exists():  # big-endian MotoROS frames, one or more per TCP segment
        for line in capture.read_text().splitlines():
            if line.strip() and not line.startswith("#"):
                payload = bytes.fromhex(line.split()[-1])
                pos = 0
                while len(payload) - pos >= HEADER:
                    length = _INT[">"].unpack_from(payload, pos)[0]
                    if not 12 <= length <= len(payload) - pos - 4:
                        break
                    corpus[">"].append(payload[pos : pos + 4 + length])
                    pos += 4 + length
    return corpus


_SEGMENTS: dict[str, list[tuple[str, int]]] = {}


def _segments(layout: str) -> list[tuple[str, int]]:
    """``"i10r"`` -> ``[("i", 1), ("r", 10)]``."""
    segments = _SEGMENTS.get(layout)
    if segments is None:
        segments = _SEGMENTS[layout] = [(c, int(n or 1)) for n, c in re.findall(r"(\d*)([iIr])", layout)]
    return segments


#: values per pool of packed random fields
POOL_VALUES = 1 << 16
_POOLS: dict[tuple[str, int], bytes] = {}


def _pool(order: str, real: int) -> bytes:
    """``POOL_VALUES`` random fields packed in ``order``: reals of ``real`` bytes (half interesting
    values, half uniform in [-4, 4]), int32 for ``real`` 0 (70 % interesting values), reals of
    ``-real`` bytes that are no plausible position for ``real`` < 0 (:data:`POISON_REALS`)."""
    pool = _POOLS.get((order, real))
    if pool is None:
        rng = random.Random(f"pool {order} {real}")
        if real < 0:
            bad = [rng.choice(POISON_REALS) for _ in range(POOL_VALUES)]
            if real == -4:
                bad = [math.inf if math.isfinite(x) and abs(x) > _F32_MAX else x for x in bad]
            pool = struct.pack(f"{order}{POOL_VALUES}{'f' if real == -4 else 'd'}", *bad)
        elif real == 0:
            ints = [
                rng.choice(INTS) if rng.random() < 0.7 else rng.randint(-(2**31), 2**31 - 1) for _ in range(POOL_VALUES)
            ]
            pool = struct.pack(f"{order}{POOL_VALUES}i", *ints)
        else:
            reals = [rng.choice(REALS) if rng.random() < 0.5 else rng.uniform(-4.0, 4.0) for _ in range(POOL_VALUES)]
            if real == 4:
                reals = [math.copysign(_F32_MAX, x) if math.isfinite(x) and abs(x) > _F32_MAX else x for x in reals]
            pool = struct.pack(f"{order}{POOL_VALUES}{'f' if real == 4 else 'd'}", *reals)
        _POOLS[order, real] = pool
    return pool


class Generator:
    """Random and mutated frames (see the module doc). ``order``/``real``: the peer's wire format;
    ``server``: frames for a server (PING rare, as it is the marker; fatal units rare), else for the
    decoder (anything)."""

    def __init__(
        self,
        rng: random.Random,
        order: str,
        real: int,
        corpus: dict[str, list[bytes]],
        *,
        server: bool = True,
        fatal_rate: float = 1 / 1000,
        rare_types: frozenset[int] = frozenset(),
    ) -> None:
        self.rng = rng
        self.order = order
        self.real = real
        self.corpus = corpus
        self.server = server
        self.fatal_rate = fatal_rate
        self.rare_types = rare_types
        kinds: list[tuple[Callable[[], bytes], float]] = [
            (self.well_formed, 26.0),
            (self.poisoned_motion, 22.0),
            (self.other_size, 10.0),
            (self.vector, 14.0),
            (self.header_only, 7.0),
            (self.unknown_type, 5.0),
            (self.mutated, 16.0),
        ]
        self._kinds = [k for k, _ in kinds]
        self._cum = list(_cumulative(w for _, w in kinds))

    # the mix

    def unit(self) -> bytes:
        """One unit to send: mostly one frame with an honest length prefix."""
        rng = self.rng
        if rng.random() < self.fatal_rate:
            return self.dishonest()
        kind = rng.choices(self._kinds, cum_weights=self._cum)[0]
        return kind()

    # values

    def _reals(self, count: int, order: str, real: int) -> bytes:
        """``count`` random reals, packed (a slice of a pool: :func:`_pool`)."""
        pool = _pool(order, real)
        k = self.rng.randrange(POOL_VALUES - count) * real
        return pool[k : k + count * real]

    def _ints(self, count: int, order: str) -> bytes:
        pool = _pool(order, 0)
        k = self.rng.randrange(POOL_VALUES - count) * 4
        return pool[k : k + count * 4]

    def _body(self, layout: str, order: str, real: int) -> bytes:
        """A body of ``layout`` with random fields."""
        return b"".join(
            self._reals(n, order, real) if code == "r" else self._ints(n, order) for code, n in _segments(layout)
        )

    def _type(self) -> int:
        rng = self.rng
        while True:
            t = rng.choice(KNOWN_TYPES)
            if t not in self.rare_types or rng.random() < 0.02:
                return t

    def _comm(self) -> int:
        return self.rng.choice(COMM_TYPES)

    def _reply(self, comm: int) -> int:
        rng = self.rng
        if comm == 3:
            return rng.choice((1, 1, 2, 0, 3))
        return rng.choice(REPLY_CODES)

    # kinds of units

    def well_formed(self, order: str | None = None, real: int | None = None) -> bytes:
        """A frame of a non-motion known type in its own layout, random fields."""
        order = order or self.order
        real = real or self.real
        rng = self.rng
        msg_type = self._type()
        if msg_type in MOTION_TYPES:
            return self.poisoned_motion(order, real, msg_type)
        if msg_type == PING:
            if self.server:
                msg_type = 13
            elif rng.random() < 0.3:  # REP-I0006's PING with ten ints
                return frame_of(order, PING, self._comm(), 0, struct.pack(order + "10i", *[0] * 10))
        comm = self._comm()
        layout = LAYOUTS[msg_type][1 if comm == 3 else 0]
        body = self._body(layout, order, real) if layout else b""
        return frame_of(order, msg_type, comm, self._reply(comm), body)

    def other_size(self) -> bytes:
        """A frame with the other real size's bodies (float64 on a float32 server, and back)."""
        other = 8 if self.real == 4 else 4
        if self.rng.random() < 0.5:
            return self.poisoned_motion(self.order, other)
        return self.well_formed(self.order, other)

    def _poison(self, count: int, order: str, real: int) -> bytes:
        """``count`` packed reals none of which is a plausible position (NaN, infinities, 1e6...)."""
        pool = _pool(order, -real)
        k = self.rng.randrange(POOL_VALUES - count) * real
        return pool[k : k + count * real]

    def poisoned_motion(self, order: str | None = None, real: int | None = None, msg_type: int | None = None) -> bytes:
        """A motion-type frame that is invalid for sure (the module doc): poisoned positions or an
        unknown command, random other fields, any comm_type; escalates the poison until the
        independent check accepts it."""
        order = order or self.order
        real = real or self.real
        rng = self.rng
        msg_type = msg_type or rng.choice((11, 11, 14, 14, 2001, 2016, 12))
        comm = self._comm()
        reply = self._reply(comm)
        for how in ("slot0", "positions", "bytes", "all"):
            frame = frame_of(order, msg_type, comm, reply, self._motion_body(msg_type, order, real, how))
            if unsafe_reason(frame) is None:
                return frame
        # never reached in practice: the last form is made of 0x7F/0xFF bytes only
        return frame_of(order, msg_type, comm, reply, poison_bytes(rng, 8))

    def _sequence(self) -> int:
        rng = self.rng
        return rng.choice((0, 1, 2, 3, 10, -1, -2, -3, -5, -7, 2**31 - 1, -(2**31), rng.randint(-100, 1000)))

    def _motion_body(self, msg_type: int, order: str, real: int, how: str) -> bytes:
        """``how``: ``slot0`` (position 0 poisoned), ``positions`` (all ten), ``bytes`` (every real as
        0x7F/0xFF bytes, the ints random), ``all`` (the whole body 0x7F/0xFF bytes)."""
        rng = self.rng
        I4 = _INT[order]
        if how == "all" or msg_type == 12:
            size = {11: 4 + 12 * real, 12: rng.choice((0, 4, 20, 56, 4 + 52, 108, 524)), 14: 12 + 31 * real}
            size |= {2001: 12 + 10 * real, 2016: 8 + rng.randint(1, 4) * (8 + 31 * real), 65001: 8 + 9 * real}
            return poison_bytes(rng, size[msg_type])

        def reals(count: int) -> bytes:
            if how == "bytes":
                return poison_bytes(rng, count * real)
            return self._reals(count, order, real)

        def positions() -> bytes:
            if how == "slot0":
                return self._poison(1, order, real) + reals(9)
            if how == "bytes":
                return poison_bytes(rng, 10 * real)
            return self._poison(10, order, real)

        if msg_type == 11:
            return I4.pack(self._sequence()) + positions() + reals(2)
        if msg_type == 14:
            head = I4.pack(rng.choice((0, 0, 1, 3, -1, 4))) + I4.pack(self._sequence())
            fields = I4.pack(rng.choice((0x07, 0x0F, 0x03, 0x02, 0, 0x1F, -1)))
            return head + fields + reals(1) + positions() + reals(20)
        if msg_type == 65001:  # robot_id, sequence, x (poisoned), then y ... blend radius
            head = I4.pack(rng.choice((0, 0, 1, -1, 4))) + I4.pack(self._sequence())
            return head + (self._poison(1, order, real) if how != "bytes" else poison_bytes(rng, real)) + reals(8)
        if msg_type == 2001:
            command = rng.choice((0, -1, 1, 200000, 200099, 200200, 200300, 2001, 14, 2**31 - 1, -(2**31)))
            if command in MOTO_COMMANDS:  # (never: the choices are outside), kept for the reader
                command = 0
            return I4.pack(rng.choice((0, 1, -1, 4))) + I4.pack(self._sequence()) + I4.pack(command) + reals(10)
        # 2016: number of valid groups, sequence, then groups
        groups = rng.randint(1, 4)
        head = I4.pack(rng.choice((groups, 4, 0, -1, 5, groups + 1))) + I4.pack(self._sequence())
        parts = [head]
        for g in range(groups):
            parts.append(I4.pack(rng.choice((g, 0, 1, -1, 4))) + I4.pack(rng.choice((0x07, 0x0F, 0, 0x02))))
            parts.append(reals(1) + positions() + reals(20))
        return b"".join(parts)

    def vector(self) -> bytes:
        """A reference vector (the server's byte order), its motion frames poisoned, maybe mutated."""
        rng = self.rng
        frames = self.corpus.get(self.order) or [ping_request(self.order)]
        frame = rng.choice(frames)
        msg_type = _INT[self.order].unpack_from(frame, 4)[0]
        if msg_type == PING and self.server:
            status = struct.pack(self.order + "7i", *(rng.choice(INTS) for _ in range(7)))
            frame = frame_of(self.order, 13, 1, 0, status)
        if unsafe_reason(frame) is not None:
            frame = self._poison_frame(frame)
            if unsafe_reason(frame) is not None:  # a STOP: sequence -4 stays
                return self.poisoned_motion(self.order, 4, _INT[self.order].unpack_from(frame, 4)[0])
        if rng.random() < 0.5:
            frame = self._mutate(frame)
        return frame

    def _poison_frame(self, frame: bytes) -> bytes:
        """The frame with every real of its body (float32) as 0x7F/0xFF bytes after its ints: enough
        for the layouts of the motion types."""
        order = self.order
        msg_type = _INT[order].unpack_from(frame, 4)[0]
        ints = {11: 4, 14: 12, 2001: 12, 2016: 8, 65001: 8}.get(msg_type, 0)
        body = frame[HEADER:]
        return frame[:HEADER] + body[:ints] + poison_bytes(self.rng, len(body) - ints)

    def header_only(self) -> bytes:
        comm = self._comm()
        msg_type = self._type()
        if msg_type == PING and self.server:
            msg_type = 2
        return frame_of(self.order, msg_type, comm, self._reply(comm), b"")

    def unknown_type(self) -> bytes:
        rng = self.rng
        msg_type = rng.choice(UNKNOWN_TYPES) if rng.random() < 0.8 else rng.randint(-(2**31), 2**31 - 1)
        if msg_type == PING or msg_type in MOTION_TYPES:
            msg_type = 3
        n = rng.choice((0, 4, 8, 12, 40, 52, 64, rng.randint(0, 200)))
        body = rng.randbytes(n)
        comm = self._comm()
        return frame_of(self.order, msg_type, comm, self._reply(comm), body)

    def mutated(self) -> bytes:
        rng = self.rng
        base = rng.choice((self.well_formed, self.poisoned_motion, self.vector, self.header_only))()
        for _ in range(rng.randint(1, 3)):
            base = self._mutate(base)
        return base

    def _mutate(self, frame: bytes) -> bytes:
        """One mutation that keeps the length prefix honest (the frame stays delimited)."""
        rng = self.rng
        order = self.order
        buf = bytearray(frame)
        op = rng.randrange(9)
        if op == 0:  # bit flips, in the header now and then
            low = 4 if rng.random() < 0.2 else min(HEADER, len(buf) - 1)
            for _ in range(rng.randint(1, 8)):
                k = rng.randrange(low, len(buf))
                buf[k] ^= 1 << rng.randrange(8)
        elif op == 1 and len(buf) > HEADER:  # a byte set to something interesting
            k = rng.randrange(HEADER, len(buf))
            buf[k] = rng.choice((0x00, 0xFF, 0x7F, 0x80, 0x01, rng.getrandbits(8)))
        elif op == 2:  # truncation
            buf = buf[: rng.randint(HEADER, len(buf))]
        elif op == 3:  # extension
            n = rng.choice((1, 2, 3, 4, 8, 40, rng.randint(1, 64)))
            tail = rng.choice((bytes(n), rng.randbytes(n), b"\x7f" * n))
            buf += tail
        elif op == 4 and len(buf) > HEADER:  # bytes inserted or deleted inside the body
            k = rng.randrange(HEADER, len(buf) + 1)
            if rng.random() < 0.5:
                buf[k:k] = rng.randbytes(rng.randint(1, 8))
            else:
                del buf[k : k + rng.randint(1, 8)]
        elif op == 5:  # another type
            t = rng.choice(KNOWN_TYPES) if rng.random() < 0.7 else rng.choice(UNKNOWN_TYPES)
            struct.pack_into(order + "i", buf, 4, t)
        elif op == 6:  # another comm_type
            struct.pack_into(order + "i", buf, 8, self._comm())
        elif op == 7:  # another reply_code
            struct.pack_into(order + "i", buf, 12, rng.choice(REPLY_CODES))
        else:  # header only
            buf = buf[:HEADER]
        struct.pack_into(order + "i", buf, 0, len(buf) - 4)
        return bytes(buf)

    def dishonest(self) -> bytes:
        """A unit that breaks the framing: a wrong, huge or negative length prefix, garbage, the
        other byte order. The server goes out of step or closes the connection."""
        rng = self.rng
        op = rng.randrange(6)
        base = self.well_formed() if rng.random() < 0.5 else self.poisoned_motion()
        if op == 0:  # slightly wrong length prefix
            buf = bytearray(base)
            delta = rng.choice((-8, -4, -1, 1, 4, 8, rng.randint(-40, 40)))
            struct.pack_into(self.order + "i", buf, 0, max(12, len(buf) - 4 + delta))
            return bytes(buf)
        if op == 1:  # fatal length prefix
            return _INT[self.order].pack(rng.choice(FATAL_LENGTHS)) + base[4:]
        if op == 2:  # garbage
            return rng.randbytes(rng.randint(1, 64))
        if op == 3:  # the other byte order, whole frame
            other = ">" if self.order == "<" else "<"
            return self.well_formed(other) if rng.random() < 0.5 else self.poisoned_motion(other)
        if op == 4:  # a huge plausible-looking length (the server waits for it, then the stream ends)
            return _INT[self.order].pack(rng.randint(MAX_LENGTH // 2, MAX_LENGTH)) + base[4:]
        return _INT[self.order].pack(rng.randint(-(2**31), 2**31 - 1)) + base[4:]  # any length prefix


def _cumulative(weights: Iterable[float]) -> Iterable[float]:
    total = 0.0
    for w in weights:
        total += w
        yield total


# -- the decoder, in process ---------------------------------------------------------------------


@dataclass
class DecoderReport:
    """What the decoder run found."""

    frames: int = 0  # frames cut by FrameDecoder and decoded
    units: int = 0  # units generated and fed
    decodes: int = 0  # decode() calls
    seconds: float = 0.0
    #: exceptions by "api: type" (documented ones included)
    exceptions: Counter[str] = field(default_factory=Counter)
    #: undocumented exceptions, re-encode and path mismatches, by kind: [count, an example's
    #: message, the shortest reproducing bytes]
    failures: dict[str, list[Any]] = field(default_factory=dict)
    failure_count: int = 0
    quieted_nans: int = 0  # float32 signalling NaNs that came back quieted (documented)

    def fail(self, kind: str, what: str, data: bytes) -> None:
        self.failure_count += 1
        entry = self.failures.setdefault(kind, [0, what, data])
        entry[0] += 1
        if len(data) < len(entry[2]):
            entry[1], entry[2] = what, data


def fuzz_decoder(frames: int, seed: int = 0, *, seconds: float | None = None, batch: int = 64) -> DecoderReport:
    """Feed ``frames`` random and mutated frames through FrameDecoder, decode and feed_messages
    (both byte orders, both real sizes, configured and detected byte order; the module doc)."""
    from simple_message.errors import FrameError, MalformedMessage
    from simple_message.framing import FrameDecoder
    from simple_message.messages import Message, decode
    from simple_message.wire import ByteOrder, WireFormat

    rng = random.Random(seed)
    corpus = load_corpus()
    report = DecoderReport()
    wires = {(o, r): WireFormat(ByteOrder.LITTLE if o == "<" else ByteOrder.BIG, r) for o in "<>" for r in (4, 8)}
    gens = {
        (o, r): Generator(random.Random(rng.getrandbits(64)), o, r, corpus, server=False, fatal_rate=0.01)
        for o in "<>"
        for r in (4, 8)
    }
    start = time.perf_counter()
    deadline = None if seconds is None else start + seconds
    while report.frames < frames and (deadline is None or time.perf_counter() < deadline):
        order, real = rng.choice("<>"), rng.choice((4, 4, 8))
        gen = gens[order, real]
        units = [gen.unit() for _ in range(rng.randint(1, batch))]
        report.units += len(units)
        stream = b"".join(units)
        chunks = _chunks(rng, stream)
        detect = rng.random() < 0.25
        byte_order = None if detect else (ByteOrder.LITTLE if order == "<" else ByteOrder.BIG)
        wire = wires[order, real]
        # feed + next_frame + decode
        decoder = FrameDecoder(byte_order)
        cut: list[bytes] = []
        dead = False
        for chunk in chunks:
            try:
                decoder.feed(chunk)
            except Exception as exc:
                kind = f"feed: {type(exc).__name__}"
                report.exceptions[kind] += 1
                report.fail(kind, f"FrameDecoder.feed raised {type(exc).__name__}: {exc}", stream)
                dead = True
                break
            while True:
                try:
                    frame = decoder.next_frame()
                except FrameError as exc:
                    report.exceptions[f"next_frame: {type(exc).__name__}"] += 1
                    dead = True
                    break
                except Exception as exc:
                    kind = f"next_frame: {type(exc).__name__}"
                    report.exceptions[kind] += 1
                    report.fail(kind, f"FrameDecoder.next_frame raised {type(exc).__name__}: {exc}", stream)
                    dead = True
                    break
                if frame is None:
                    break
                cut.append(frame)
            if dead:
                break
        detected = decoder.byte_order
        frame_order = order if detected is None else ("<" if detected is ByteOrder.LITTLE else ">")
        plain: list[bytes | tuple[str, bytes]] = []
        for frame in cut:
            report.frames += 1
            for r in (4, 8):
                w = wires[frame_order, r]
                report.decodes += 1
                try:
                    msg = decode(frame, w)
                except MalformedMessage as exc:
                    report.exceptions[f"decode: {type(exc).__name__}"] += 1
                    if r == real:
                        plain.append(("malformed", exc.frame))
                    continue
                except Exception as exc:
                    kind = f"decode: {type(exc).__name__}"
                    report.exceptions[kind] += 1
                    report.fail(kind, f"decode(frame, {w}) raised {type(exc).__name__}: {exc}", frame)
                    if r == real:
                        plain.append(("raised", frame))
                    continue
                encoded = _reencode(report, msg, w, frame)
                if r == real:
                    plain.append(encoded if encoded is not None else ("unencodable", frame))
        # feed_messages: the same chunks, the Link's path
        fast = FrameDecoder(byte_order)
        got: list[bytes | tuple[str, bytes]] = []
        for chunk in chunks:
            try:
                items = fast.feed_messages(chunk, wire)
            except Exception as exc:
                kind = f"feed_messages: {type(exc).__name__}"
                report.exceptions[kind] += 1
                report.fail(kind, f"FrameDecoder.feed_messages raised {type(exc).__name__}: {exc}", stream)
                got = plain  # not compared again
                break
            for item in items:
                if isinstance(item, MalformedMessage):
                    got.append(("malformed", item.frame))
                elif isinstance(item, Message):
                    try:
                        got.append(item.encode(_fast_wire(fast, wire, wires)))
                    except Exception:
                        got.append(("unencodable", b""))
        if got is not plain and not _same_results(got, plain):
            report.fail("feed_messages != feed + decode", "feed_messages disagrees with feed + decode", stream)
    report.seconds = time.perf_counter() - start
    return report


def _fast_wire(decoder: Any, wire: Any, wires: dict[tuple[str, int], Any]) -> Any:
    """The wire feed_messages decoded in: ``wire``, in the detected byte order once detected."""
    from simple_message.wire import ByteOrder

    detected = decoder.byte_order
    if detected is None:
        return wire
    return wires["<" if detected is ByteOrder.LITTLE else ">", wire.real_size]


def _same_results(a: Sequence[bytes | tuple[str, bytes]], b: Sequence[bytes | tuple[str, bytes]]) -> bool:
    if len(a) != len(b):
        return False
    for x, y in zip(a, b, strict=True):
        if x == y:
            continue
        if isinstance(x, bytes) and isinstance(y, bytes) and _snan_only(x, y) is not None:
            continue
        if isinstance(x, tuple) and isinstance(y, tuple) and {x[0], y[0]} <= {"unencodable", "raised"}:
            continue
        return False
    return True


def _reencode(report: DecoderReport, msg: Any, wire: Any, frame: bytes) -> bytes | None:
    try:
        again: bytes = msg.encode(wire)
    except Exception as exc:
        kind = f"encode: {type(exc).__name__}"
        report.exceptions[kind] += 1
        report.fail(kind, f"a decoded {type(msg).__name__} does not encode in {wire}: {exc}", frame)
        return None
    if again != frame:
        quieted = _snan_only(frame, again) if wire.real_size == 4 else None
        if quieted is None:
            what = f"decoded in {wire}, re-encodes to {len(again)} bytes: {again.hex()[:96]}..."
            report.fail(f"re-encode: {type(msg).__name__} differs", what, frame)
        else:
            report.quieted_nans += quieted
    return again


def _snan_only(original: bytes, again: bytes) -> int | None:
    """How many float32 signalling NaNs explain every difference (each came back quieted), or None."""
    if len(original) != len(again):
        return None
    count = 0
    for k in range(0, len(original) - 3, 4):
        a, b = original[k : k + 4], again[k : k + 4]
        if a == b:
            continue
        ok = False
        for order in "<>":
            (wa,) = struct.unpack(order + "I", a)
            (wb,) = struct.unpack(order + "I", b)
            if wa & 0x7F800000 == 0x7F800000 and wa & 0x003FFFFF and not wa & 0x00400000 and wb == wa | 0x00400000:
                ok = True
        if not ok:
            return None
        count += 1
    return count


def _chunks(rng: random.Random, data: bytes) -> list[bytes]:
    """``data`` cut at random places (sometimes byte by byte, sometimes whole)."""
    mode = rng.random()
    if mode < 0.3 or len(data) < 2:
        return [data]
    if mode < 0.35:
        return [data[k : k + 1] for k in range(min(len(data), 200))] + ([data[200:]] if len(data) > 200 else [])
    cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, rng.randint(1, 8))))
    return [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]


# -- the server run ------------------------------------------------------------------------------

#: fuzz connections per port where the server allows fewer than asked: one motion client at a time on
#: every profile (a newcomer replaces it while the robot is at rest), MotoROS's one IO client and
#: four state clients (the monitor takes one place, and one is left free for reconnections)
PORT_CAPS = {"motion": 1}
PROFILE_CAPS = {"motoros": {"state": 2, "io": 1}}
CONNECT_TIMEOUT = 5.0
STALL_TIMEOUT = 10.0  # s without an answer to an outstanding marker: the connection is stalled
CLOSE_TIMEOUT = 5.0  # s for the server to close a connection after a fatal length prefix
#: s without an answer to a fresh PING, or of state silence, that counts as a hang (the default)
HANG_AFTER = 1.0
KEEP_BATCHES = 8  # batches kept per connection for a traceback's reproduction
KEEP_CLOSED = 64  # closed connections whose batches are kept, per port


@dataclass
class Options:
    """Everything the command line sets (``main`` has the help)."""

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
class PortStats:
    frames: int = 0
    bytes: int = 0
    confirmed: int = 0  # frames before a marker the server answered
    connections: int = 0
    connect_failures: int = 0
    rejected: int = 0  # units the safety model refused (generated again)
    fatal: int = 0  # connections ended by a fatal length prefix (the server must close)
    unclosed: int = 0  # ... that the server did not close within CLOSE_TIMEOUT
    server_closed: int = 0  # connections the server closed otherwise (MotoROS rules, limits)
    stalls: int = 0
    abandoned: int = 0  # connections ended because no safe unit could follow
    bad_replies: int = 0  # replies that could not be framed
    markers: int = 0


@dataclass
class ProfileReport:
    """What one profile's server run found (the table's row and the details below it)."""

    profile: str
    hang_after: float = HANG_AFTER
    ports: dict[str, PortStats] = field(default_factory=dict)
    seconds: float = 0.0
    crashes: int = 0
    exit_code: int | None = None
    hangs: int = 0  # failed probes + stalled connections + state gaps
    probes: int = 0
    probe_failures: int = 0
    probe_max: float = 0.0
    state_messages: int = 0
    state_gaps: int = 0
    state_max_gap: float = 0.0
    motion: int = 0
    motion_detail: str = ""
    max_deviation: float = 0.0
    tracebacks: int | None = None
    traceback_excerpt: str = ""
    rss_before: float | None = None
    rss_after: float | None = None
    rss_max: float | None = None
    #: (frames sent, RSS MB) every probe interval
    rss_samples: list[tuple[int, float]] = field(default_factory=list)
    log_path: Path | None = None
    log_bytes: int = 0
    log_lines: int = 0
    dumps: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: the last batches of each connection by port role and client port (for ``_read_log``)
    rings: dict[str, dict[int, deque[list[bytes]]]] = field(default_factory=dict, repr=False)

    @property
    def frames(self) -> int:
        return sum(p.frames for p in self.ports.values())

    @property
    def confirmed(self) -> int:
        return sum(p.confirmed for p in self.ports.values())

    @property
    def connections(self) -> int:
        return sum(p.connections for p in self.ports.values())

    @property
    def rss_growth(self) -> float | None:
        if self.rss_before is None or self.rss_after is None:
            return None
        return self.rss_after - self.rss_before

    @property
    def failures(self) -> int:
        blind = 1 if self.state_messages == 0 else 0  # the monitor saw nothing: motion unknown
        return self.crashes + self.hangs + (self.tracebacks or 0) + self.motion + blind


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


class _Sink(asyncio.Protocol):
    """One fuzz connection's receiving side: frames the replies (struct) and counts PING replies.

    ``either``: frames may come in either byte order (an autodetecting server sends topics in the
    order of the last motion client until this connection's first frame is read): each frame's
    length prefix is read in ``order``, else in the other order when only that one is plausible.
    """

    def __init__(self, order: str, *, either: bool = False) -> None:
        self.order = order
        self.either = either
        self.transport: asyncio.Transport | None = None
        self.rbuf = b""
        self.type1 = 0
        self.bad = False
        self.outstanding: deque[int] = deque()  # frames sent up to each unanswered marker
        self.confirmed = 0
        self.closed = False
        self.paused = False
        self._wake: asyncio.Future[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def data_received(self, data: bytes) -> None:
        if self.bad:
            return
        buf = self.rbuf + data if self.rbuf else data
        pos, end = 0, len(buf)
        head = _INT2[self.order]
        other = _INT2[">" if self.order == "<" else "<"]
        woke = False
        while end - pos >= 8:
            length, msg_type = head.unpack_from(buf, pos)
            if not 12 <= length <= MAX_LENGTH and self.either:
                length, msg_type = other.unpack_from(buf, pos)
            if not 12 <= length <= MAX_LENGTH:
                self.bad = True
                break
            if pos + 4 + length > end:
                break
            if msg_type == PING:
                self.type1 += 1
                if self.outstanding:
                    self.confirmed = self.outstanding.popleft()
                    woke = True
            pos += 4 + length
        self.rbuf = buf[pos:]
        if woke:
            self.notify()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        self.notify()

    def alive(self) -> bool:
        return not self.closed

    def pause_writing(self) -> None:
        self.paused = True

    def resume_writing(self) -> None:
        self.paused = False
        self.notify()

    def notify(self) -> None:
        if self._wake is not None and not self._wake.done():
            self._wake.set_result(None)

    async def wait(self, timeout: float) -> bool:
        """Until something happens (a marker answered, room to write, closed); False on timeout."""
        self._wake = asyncio.get_running_loop().create_future()
        try:
            await asyncio.wait_for(self._wake, timeout)
        except TimeoutError:
            return False
        finally:
            self._wake = None
        return True


async def _keepalive(writer: asyncio.StreamWriter, frame: bytes, stop: asyncio.Event) -> None:
    while not stop.is_set() and not writer.is_closing():
        writer.write(frame)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 2.0)


async def _connect(loop: asyncio.AbstractEventLoop, sink: _Sink, host: str, port: int) -> asyncio.Transport:
    transport, _ = await asyncio.wait_for(loop.create_connection(lambda: sink, host, port), CONNECT_TIMEOUT)
    return transport


@dataclass
class Target:
    """The server fuzzed: where, its byte order and real size, its process and log if known."""

    host: str
    ports: dict[str, int]
    order: str  # "<", ">", "auto"
    real: int
    pid: int | None
    log: Path | None


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
        self.sinks: set[_Sink] = set()
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
            sink = _Sink(order, either=self.target.order == "auto")
            try:
                if use_gate:
                    async with self.gate:
                        transport = await _connect(loop, sink, self.target.host, port)
                else:
                    transport = await _connect(loop, sink, self.target.host, port)
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
        sink: _Sink,
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
                if _HEAD[order].unpack(reply) != (12, PING, 3, 1):
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
            keepalive = asyncio.create_task(_keepalive(writer, ping_request(order), self.stopping))
            try:
                while True:
                    prefix = await reader.readexactly(4)
                    head = _detect(prefix)
                    if head is None:
                        report.notes.append(f"monitor: a state frame that cannot be framed: {prefix.hex()}")
                        break
                    rest = await reader.readexactly(head.unpack(prefix)[0])
                    order = "<" if head is _INT["<"] else ">"
                    msg_type = _INT[order].unpack_from(rest, 0)[0]
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
                        robot = _INT[order].unpack_from(body, 0)[0]
                        key, values = (15, robot), struct.unpack_from(f"{order}10{rc}", body, 8 + real)
                    elif msg_type == 13 and len(body) >= 28:
                        report.state_messages += 1
                        in_motion = _INT[order].unpack_from(body, 16)[0]
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


# -- the table -----------------------------------------------------------------------------------


def _mb(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.1f}"


def table(reports: Sequence[ProfileReport], decoder: DecoderReport | None) -> str:
    out = [
        "| profile | frames | connections | crashes | hangs | tracebacks | motion | RSS before/after/growth (MB) "
        "| log lines/s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in reports:
        growth = r.rss_growth
        rss = f"{_mb(r.rss_before)} / {_mb(r.rss_after)} / " + ("n/a" if growth is None else f"{growth:+.1f}")
        tb = "n/a" if r.tracebacks is None else str(r.tracebacks)
        rate = f"{r.log_lines / r.seconds:.1f}" if r.seconds and r.tracebacks is not None else "n/a"
        out.append(
            f"| {r.profile} | {r.frames:,} | {r.connections:,} | {r.crashes} | {r.hangs} | {tb} | {r.motion} "
            f"| {rss} | {rate} |"
        )
    if decoder is not None:
        documented = ", ".join(f"{k} {v:,}" for k, v in sorted(decoder.exceptions.items()))
        out.append("")
        out.append("| decoder (in process) | frames | decode calls | seconds | exceptions | failures |")
        out.append("|---|---:|---:|---:|---|---:|")
        out.append(
            f"| FrameDecoder + decode + feed_messages, both byte orders, float32/64 | {decoder.frames:,} "
            f"| {decoder.decodes:,} | {decoder.seconds:.1f} | {documented or 'none'} | {decoder.failure_count} |"
        )
    return "\n".join(out)


def details(r: ProfileReport) -> str:
    out = [f"## {r.profile}: {r.seconds:.1f} s, {r.frames / max(r.seconds, 1e-9):,.0f} frames/s"]
    for role, p in r.ports.items():
        out.append(
            f"  {role}: {p.frames:,} frames ({p.bytes / 1e6:.1f} MB), {p.confirmed:,} confirmed processed, "
            f"{p.connections:,} connections ({p.fatal:,} ended by a bad length prefix, {p.unclosed} of them not "
            f"closed by the server; {p.server_closed:,} closed by the server otherwise; {p.connect_failures} "
            f"connect failures, {p.abandoned} abandoned), {p.rejected:,} units refused by the safety check, "
            f"{p.stalls} stalls, "
            f"{p.bad_replies} unframeable replies"
        )
    out.append(
        f"  probes: {r.probes} ({r.probe_failures} failed, slowest {r.probe_max * 1000:.0f} ms); state messages "
        f"{r.state_messages:,} (longest silence {r.state_max_gap * 1000:.0f} ms, {r.state_gaps} over "
        f"{r.hang_after:g} s); largest position change {r.max_deviation:g}"
    )
    if r.rss_samples:
        step = max(1, len(r.rss_samples) // 8)
        timeline = ", ".join(f"{f / 1000:,.0f}k: {m:.1f}" for f, m in [*r.rss_samples[::step], r.rss_samples[-1]])
        out.append(f"  RSS (MB) by frames sent: {timeline}")
        warm = next((m for f, m in r.rss_samples if f >= r.frames // 10), None)
        if warm is not None and r.rss_after is not None:
            out.append(f"  RSS growth after the first 10 % of the frames (warm-up): {r.rss_after - warm:+.1f} MB")
    out.append(
        f"  RSS max {_mb(r.rss_max)} MB; log {r.log_bytes / 1e6:.1f} MB, {r.log_lines:,} lines"
        + (f" ({r.log_path})" if r.log_path else "")
        + (f"; exit status {r.exit_code}" if r.exit_code is not None else "")
    )
    for note in r.notes[:20]:
        out.append(f"  note: {note}")
    if len(r.notes) > 20:
        out.append(f"  ... {len(r.notes) - 20} more notes")
    if r.traceback_excerpt:
        out.append("  first traceback:")
        out += ["    " + line for line in r.traceback_excerpt.splitlines()]
    for dump in r.dumps:
        out.append(f"  last frames of a connection that caused a traceback: {dump}")
    return "\n".join(out)


def decoder_details(d: DecoderReport) -> str:
    out = [
        f"## decoder: {d.units:,} units fed, {d.frames:,} frames cut, {d.decodes:,} decodes in {d.seconds:.1f} s "
        f"({d.frames / max(d.seconds, 1e-9):,.0f} frames/s); {d.quieted_nans:,} float32 signalling NaNs quieted "
        "(documented)"
    ]
    for kind, (count, what, data) in sorted(d.failures.items()):
        out.append(f"  FAILURE {kind}: {count:,} times; the shortest: {what}\n    bytes ({len(data)}): {data.hex()}")
    return "\n".join(out)


# -- the command ---------------------------------------------------------------------------------


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bench/fuzz.py",
        description="Fuzz robot-server (every port of each profile) and the sans-I/O decoder with random and "
        "mutated frames that are never valid motion commands; prints a table, exits 1 on any failure.",
        epilog="What is sent (never a valid motion command), what is measured and what counts as a failure: "
        "the docstring at the top of bench/fuzz.py.",
    )
    p.add_argument("--profile", nargs="+", default=["generic", "motoros"], help="default: generic motoros")
    p.add_argument("--frames", type=int, default=1_000_000, help="frames per profile (default %(default)s)")
    p.add_argument("--seconds", type=float, default=300.0, help="time limit per profile (default %(default)s)")
    p.add_argument("--connections", type=int, default=8, help="concurrent connections per port (default 8)")
    p.add_argument(
        "--motion-connections",
        type=int,
        default=1,
        help="motion-port connections (default 1: the server takes one motion client at a time, a newcomer "
        "replaces it; more fuzzes that churn)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch", type=int, default=128, help="frames per write (default %(default)s)")
    p.add_argument("--window", type=int, default=4, help="unanswered batches per connection (default 4)")
    p.add_argument("--probe-interval", type=float, default=0.5, metavar="S", help="PING probe period (default 0.5)")
    p.add_argument(
        "--hang-after",
        type=float,
        default=HANG_AFTER,
        metavar="S",
        help="a PING unanswered, or the state port silent, this long is a hang (default %(default)s)",
    )
    p.add_argument("--decoder-frames", type=int, default=1_000_000, help="0: no decoder run (default %(default)s)")
    p.add_argument("--decoder-seconds", type=float, default=None, help="time limit of the decoder run")
    p.add_argument("--host", default="127.0.0.1", help="a running server's address (default 127.0.0.1)")
    p.add_argument("--motion-port", type=int, help="target a running server (one --profile)")
    p.add_argument("--state-port", type=int)
    p.add_argument("--io-port", type=int)
    p.add_argument("--server-log", type=Path, help="a running server's log file (for tracebacks)")
    p.add_argument("--server-pid", type=int, help="a running server's process id (for RSS and crashes)")
    p.add_argument("--byte-order", choices=("little", "big", "auto"), default="little", help="a running server's")
    p.add_argument("--float64", action="store_true", help="a running server's reals are float64")
    p.add_argument(
        "--server-args",
        default="",
        metavar="ARGS",
        help="more robot-server arguments, e.g. --server-args='--byte-order auto' or --server-args=--float64",
    )
    p.add_argument("--log-dir", type=Path, help="where the server logs go (default: a temporary directory)")
    p.add_argument("--keep-logs", action="store_true", help="keep the logs also when nothing failed")
    p.add_argument("--fatal-rate", type=float, default=1 / 1000, help="units that end a connection (default 0.001)")
    p.add_argument("--max-rss-growth", type=float, help="MB; a larger growth counts as a failure")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


def options_from(args: argparse.Namespace) -> Options:
    return Options(
        profiles=tuple(args.profile),
        frames=args.frames,
        seconds=args.seconds,
        connections=max(1, args.connections),
        motion_connections=max(1, args.motion_connections),
        seed=args.seed,
        batch=max(1, args.batch),
        window=max(1, args.window),
        probe_interval=args.probe_interval,
        hang_after=args.hang_after,
        decoder_frames=args.decoder_frames,
        host=args.host,
        motion_port=args.motion_port,
        state_port=args.state_port,
        io_port=args.io_port,
        server_log=args.server_log,
        server_pid=args.server_pid,
        byte_order=args.byte_order,
        float64=args.float64,
        server_args=tuple(shlex.split(args.server_args)),
        log_dir=args.log_dir,
        keep_logs=args.keep_logs,
        fatal_rate=args.fatal_rate,
        quiet=args.quiet,
    )


async def _main(options: Options, decoder_seconds: float | None) -> tuple[list[ProfileReport], DecoderReport | None]:
    reports = []
    for profile in options.profiles:
        if not options.quiet:
            print(f"# {profile}: up to {options.frames:,} frames or {options.seconds:g} s", file=sys.stderr)
        reports.append(await fuzz_server(profile, options))
    decoder = None
    if options.decoder_frames > 0:
        if not options.quiet:
            print(f"# decoder: {options.decoder_frames:,} frames", file=sys.stderr)
        decoder = fuzz_decoder(options.decoder_frames, options.seed, seconds=decoder_seconds)
    return reports, decoder


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    options = options_from(args)
    if options.external and len(options.profiles) != 1:
        parser().error("a running server (--motion-port) is fuzzed with exactly one --profile")
    if options.external and options.state_port is None:
        parser().error("a running server needs --state-port too (the motion monitor)")
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        from simple_message.endpoints import run

        reports, decoder = run(_main(options, args.decoder_seconds))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (RuntimeError, OSError) as exc:  # robot-server did not start, a port is not there...
        print(f"bench/fuzz.py: {exc}", file=sys.stderr)
        return 2
    machine = importlib.import_module("codec").machine  # the benchmarks' machine line (bench/codec.py)
    print(f"# {machine()}; seed {options.seed}")
    print()
    print(table(reports, decoder))
    print()
    for r in reports:
        print(details(r))
    if decoder is not None:
        print(decoder_details(decoder))
    failures = sum(r.failures for r in reports) + (decoder.failure_count if decoder else 0)
    if args.max_rss_growth is not None:
        grown = [r for r in reports if r.rss_growth is not None and r.rss_growth > args.max_rss_growth]
        for r in grown:
            print(f"RSS growth of {r.profile}: {r.rss_growth:+.1f} MB > {args.max_rss_growth} MB")
        failures += len(grown)
    print()
    print(f"{'FAILED' if failures else 'passed'}: {failures} failures")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
