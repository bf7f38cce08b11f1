"""The decoder run, in process (``--decoder-frames``): the same generator (:mod:`bench.fuzz.generator`)
without the restrictions of the server run (PINGs, both byte orders, both real sizes, more fatal
prefixes), fed to :class:`simple_message.framing.FrameDecoder` in random chunks (configured and
autodetected byte order), each frame given to :func:`simple_message.messages.decode` in both real
sizes, and the same chunks to :meth:`~simple_message.framing.FrameDecoder.feed_messages` (the Link's
path). Documented: ``next_frame`` raises :class:`~simple_message.errors.FrameError`, ``decode``
raises :class:`~simple_message.errors.MalformedMessage`, ``feed``/``feed_messages`` raise nothing.
Any other exception is a failure, reported with the reproducing bytes (hex); so is a decoded message
that does not re-encode to its frame (except a float32 signalling NaN, which comes back quieted, as
documented) and a ``feed_messages`` result that differs from ``feed`` + ``decode``.
"""

from __future__ import annotations

import random
import struct
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from .generator import Generator, load_corpus


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
