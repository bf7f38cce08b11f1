"""Property tests: round trips in every wire format, any chunking, and garbage streams."""

from __future__ import annotations

import contextlib
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simple_message import (
    BE32,
    BE64,
    LE32,
    LE64,
    FrameDecoder,
    FrameError,
    MalformedMessage,
    Message,
    WireFormat,
    decode,
    encode,
)
from simple_message.messages import MESSAGE_CLASSES
from simple_message.wire import ByteOrder

from .strategies import messages

WIRES = {"le32": LE32, "be32": BE32, "le64": LE64}
FAST = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_every_message_round_trips(wire: WireFormat) -> None:
    @FAST
    @given(messages(wire))
    def check(msg: Message) -> None:
        frame = encode(msg, wire)
        back = decode(frame, wire)
        assert back == msg
        assert encode(back, wire) == frame

    check()


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_nan_and_infinity_reencode_byte_exact(wire: WireFormat) -> None:
    @FAST
    @given(messages(wire, allow_nan=True))
    def check(msg: Message) -> None:
        frame = encode(msg, wire)
        assert encode(decode(frame, wire), wire) == frame

    check()


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_any_chunking_of_a_stream_gives_the_same_messages(wire: WireFormat) -> None:
    @FAST
    @given(st.lists(messages(wire), min_size=1, max_size=8), st.data())
    def check(msgs: list[Message], data: st.DataObject) -> None:
        stream = b"".join(encode(m, wire) for m in msgs)
        cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=20)))
        dec = FrameDecoder(wire.byte_order)
        got = []
        for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
            dec.feed(stream[a:b])
            got.extend(decode(f, wire) for f in dec)
        assert got == msgs
        assert dec.buffered == 0

    check()


@settings(max_examples=500, deadline=None)
@given(
    st.binary(max_size=2000),
    st.lists(st.integers(1, 300), min_size=1, max_size=30),
    st.sampled_from([None, "little", "big"]),
)
def test_garbage_never_raises_anything_untyped(garbage: bytes, chunks: list[int], order: str | None) -> None:
    dec = FrameDecoder(order, max_length=1024)  # type: ignore[arg-type]
    pos = 0
    wire = LE32
    for size in chunks * 10:
        if pos >= len(garbage):
            break
        dec.feed(garbage[pos : pos + size])
        pos += size
        assert dec.buffered <= 4 + 1024
        try:
            for frame in dec:
                with contextlib.suppress(MalformedMessage):
                    decode(frame, wire.with_byte_order(dec.byte_order or wire.byte_order))
        except FrameError:
            assert dec.failed
            break


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=16, max_size=600), st.sampled_from(list(WIRES.values())))
def test_random_frames_decode_or_fail_typed_and_reencode(body: bytes, wire: WireFormat) -> None:
    # Give the random bytes a consistent length prefix so that decode sees a well-delimited frame.
    prefix = wire.struct("i").pack(len(body) - 4)
    frame = prefix + body[4:]
    try:
        msg = decode(frame, wire)
    except MalformedMessage as exc:
        assert exc.reply_code == 2
        return
    again = encode(msg, wire)
    if again != frame:
        # The only permitted difference: float32 signalling NaNs come back quieted (see simple_message.messages).
        assert wire.real_size == 4
        assert any(math.isnan(v) for v in _reals(msg))


def _reals(msg: Message) -> list[float]:
    out: list[float] = []

    def walk(value: object) -> None:
        if isinstance(value, float):
            out.append(value)
        elif isinstance(value, tuple | list):
            for v in value:
                walk(v)
        elif hasattr(value, "__dataclass_fields__"):
            for name in value.__dataclass_fields__:
                walk(getattr(value, name))

    walk(msg)
    return out


# -- feed_messages (cut and decode in one pass) against feed + decode ---------------------------

ALL_WIRES = {**WIRES, "be64": BE64}


def _plain(dec: FrameDecoder, data: bytes, wire: WireFormat) -> list[object]:
    """feed + decode, as a Link does: in the detected byte order (with ``wire``'s real size)."""
    dec.feed(data)
    if dec.detected and dec.byte_order is not None:
        wire = wire.with_byte_order(dec.byte_order)
    out: list[object] = []
    with contextlib.suppress(FrameError):
        for frame in dec:
            try:
                out.append(decode(frame, wire))
            except MalformedMessage as exc:
                out.append(exc)
    return out


def _key(item: object, wire: WireFormat) -> object:
    """Comparable even with NaNs (re-encoded bytes) and errors (their fields)."""
    if isinstance(item, MalformedMessage):
        return (MalformedMessage, str(item), item.msg_type, item.comm_type, item.reply_code, item.frame)
    assert isinstance(item, Message)
    return (type(item), encode(item, wire))


@pytest.mark.parametrize("wire", ALL_WIRES.values(), ids=ALL_WIRES.keys())
def test_feed_messages_equals_feed_and_decode_for_every_message_type(wire: WireFormat) -> None:
    """Random messages of every type, each repeated to make runs of one header, in any chunking."""

    @FAST
    @given(st.lists(st.tuples(messages(wire), st.integers(1, 3)), min_size=1, max_size=8), st.data())
    def check(items: list[tuple[Message, int]], data: st.DataObject) -> None:
        msgs = [m for m, count in items for _ in range(count)]
        stream = b"".join(encode(m, wire) for m in msgs)
        cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
        fast, plain = FrameDecoder(wire.byte_order), FrameDecoder(wire.byte_order)
        got: list[object] = []
        want: list[object] = []
        for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
            got.extend(fast.feed_messages(stream[a:b], wire))
            want.extend(_plain(plain, stream[a:b], wire))
        assert got == want == msgs
        assert [type(m) for m in got] == [type(m) for m in want]
        assert fast.frames_decoded == len(msgs) and fast.buffered == 0

    check()


def _any_header(wire: WireFormat) -> st.SearchStrategy[bytes]:
    """A frame of a known type (or any) with a header that may not fit its body."""
    return st.builds(
        lambda msg_type, comm, reply, body: wire.header.pack(12 + len(body), msg_type, comm, reply) + body,
        st.sampled_from(sorted(MESSAGE_CLASSES)) | st.integers(-3, 3),
        st.integers(0, 4),
        st.integers(0, 3),
        st.binary(max_size=160),
    )


def _part(wire: WireFormat) -> st.SearchStrategy[bytes]:
    frames = messages(wire).map(lambda m: encode(m, wire)) | _any_header(wire)
    return st.tuples(frames | st.binary(max_size=64), st.integers(1, 3)).map(lambda pc: pc[0] * pc[1])


@settings(max_examples=500, deadline=None)
@given(
    st.sampled_from(list(ALL_WIRES.values())).flatmap(lambda w: st.lists(_part(w), max_size=8)),
    st.lists(st.integers(1, 300), min_size=1, max_size=30),
    st.sampled_from([None, "little", "big"]),
    st.sampled_from(list(ALL_WIRES.values())),
)
def test_feed_messages_equals_feed_and_decode_on_garbage(
    parts: list[bytes], chunks: list[int], order: str | None, wire: WireFormat
) -> None:
    """Whatever the bytes (frames of any wire format, runs of them, headers that do not fit their
    body, random bytes): the same messages, errors, framing error and leftover as the plain path."""
    stream = b"".join(parts)
    fast = FrameDecoder(None if order is None else ByteOrder(order), max_length=1024)
    plain = FrameDecoder(None if order is None else ByteOrder(order), max_length=1024)
    got: list[object] = []
    want: list[object] = []
    pos = 0
    for size in chunks * 10:
        if pos >= len(stream):
            break
        chunk = stream[pos : pos + size]
        pos += size
        got.extend(fast.feed_messages(chunk, wire))
        want.extend(_plain(plain, chunk, wire))
        assert fast.buffered <= 4 + 1024
    assert [_key(g, wire) for g in got] == [_key(w, wire) for w in want]
    assert (fast.failed, fast.buffered, fast.frames_decoded) == (plain.failed, plain.buffered, plain.frames_decoded)
    assert (fast.byte_order, fast.detected) == (plain.byte_order, plain.detected)
    if fast.error is not None:
        assert plain.error is not None
        assert (str(fast.error), fast.error.length) == (str(plain.error), plain.error.length)
