"""The frames the fuzzer sends: random, built from the known layouts, and mutated.

From a corpus of the reference C++ library's vectors (``tests/data/vectors_*.txt``, both byte
orders) and the FS100 capture, and frames built here from each known type's layout with random
fields (interesting ints and reals, NaN, infinities, extremes), in the server's byte order and both
real sizes (float32 and float64 bodies), mutated: bit flips, byte sets, truncation, extension,
inserted and deleted bytes, another msg_type, comm_type (0, 4+, negative...) or reply_code,
header-only frames of every known type, unknown types, the other byte order, wrong length prefixes
(slightly off: the stream goes out of step), huge, negative and below-12 length prefixes (fatal: the
server must close), random garbage. Most frames keep an honest length prefix, so that the server
goes on parsing bodies rather than reconnecting; about 1 in 1000 ends its connection
(``--fatal-rate``). PING frames (type 1) are the markers and are not fuzzed at the server (the
decoder fuzz covers them): every type-1 reply is then a marker's.

For a server, motion-type frames are poisoned so that none is a valid motion command
(:mod:`bench.fuzz.safety`); for the decoder, anything goes.
"""

from __future__ import annotations

import math
import random
import re
import struct
from collections.abc import Callable, Iterable
from pathlib import Path

from .protocol import (
    HEADER,
    INT,
    KNOWN_TYPES,
    LAYOUTS,
    MAX_LENGTH,
    MOTION_TYPES,
    MOTO_COMMANDS,
    PING,
    UNKNOWN_TYPES,
    frame_of,
    ping_request,
)
from .safety import poison_bytes, unsafe_reason

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"

INTS: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6, 7, 8, 10, 15, 63, 64, 100, 1000, -1, -2, -3, -4, -5, -7, 200101)
INTS += (200121, 200130, 2001, 3001, 3003, 5008, 2**31 - 1, -(2**31), 0x7F7F7F7F)
NAN, INF = math.nan, math.inf
REALS: tuple[float, ...] = (0.0, -0.0, 1.0, -1.0, 0.5, 0.1, 1e-45, 1e-38, 3.14159, 6.3, 1e3, 1e6, -1e6, 3.4e38)
REALS += (-3.4e38, INF, -INF, NAN, 14400.0, 1e9, 0.004, 1e-6)
POISON_REALS = (NAN, INF, -INF, 1e6, -1e6, 1e30, -3.0e38, 1234.5, 4.0e3)
COMM_TYPES = (1, 2, 2, 2, 2, 2, 2, 3, 0, 4, 5, -1, 255, 2**31 - 1)
REPLY_CODES = (0, 0, 0, 0, 1, 2, 3, -1, 7)
FATAL_LENGTHS = (-1, -12, -(2**31), 0, 1, 4, 8, 11, MAX_LENGTH + 1, 2**20, 2**31 - 1, 0x7F7F7F7F)
_F32_MAX = 3.4028234663852886e38


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
                    length = INT[">"].unpack_from(payload, pos)[0]
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
        """A motion-type frame that is invalid for sure (:mod:`bench.fuzz.safety`): poisoned positions
        or an unknown command, random other fields, any comm_type; escalates the poison until the
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
        I4 = INT[order]
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
        msg_type = INT[self.order].unpack_from(frame, 4)[0]
        if msg_type == PING and self.server:
            status = struct.pack(self.order + "7i", *(rng.choice(INTS) for _ in range(7)))
            frame = frame_of(self.order, 13, 1, 0, status)
        if unsafe_reason(frame) is not None:
            frame = self._poison_frame(frame)
            if unsafe_reason(frame) is not None:  # a STOP: sequence -4 stays
                return self.poisoned_motion(self.order, 4, INT[self.order].unpack_from(frame, 4)[0])
        if rng.random() < 0.5:
            frame = self._mutate(frame)
        return frame

    def _poison_frame(self, frame: bytes) -> bytes:
        """The frame with every real of its body (float32) as 0x7F/0xFF bytes after its ints: enough
        for the layouts of the motion types."""
        order = self.order
        msg_type = INT[order].unpack_from(frame, 4)[0]
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
            return INT[self.order].pack(rng.choice(FATAL_LENGTHS)) + base[4:]
        if op == 2:  # garbage
            return rng.randbytes(rng.randint(1, 64))
        if op == 3:  # the other byte order, whole frame
            other = ">" if self.order == "<" else "<"
            return self.well_formed(other) if rng.random() < 0.5 else self.poisoned_motion(other)
        if op == 4:  # a huge plausible-looking length (the server waits for it, then the stream ends)
            return INT[self.order].pack(rng.randint(MAX_LENGTH // 2, MAX_LENGTH)) + base[4:]
        return INT[self.order].pack(rng.randint(-(2**31), 2**31 - 1)) + base[4:]  # any length prefix


def _cumulative(weights: Iterable[float]) -> Iterable[float]:
    total = 0.0
    for w in weights:
        total += w
        yield total
