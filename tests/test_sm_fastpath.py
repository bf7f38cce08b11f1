"""The fast paths give exactly what the general paths give (issue 38).

* a long run of frames with one header, decoded by ``iter_unpack`` (``_Codec.unpack_run``), against
  ``feed`` + ``decode`` of each frame, wherever the run ends (frames of whole words and not);
* one whole frame taken by the decoder and the link without events (``FrameDecoder.one_message``,
  ``Link.receive_one``), against ``feed_messages`` and ``receive_data`` + ``next_event``;
* a server's standing PING reply (``Link.take_standing``, ``Connection.standing_for``), against
  the same reads with the standing replies off: the same bytes written, in the same writes, the same
  handler calls and deliveries, the same frames counted.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from typing import Any, ClassVar

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simple_message import (
    BE32,
    BE64,
    LE32,
    LE64,
    CommType,
    FrameDecoder,
    JointFeedback,
    JointTrajPt,
    JointTrajPtFull,
    Message,
    MsgType,
    Ping,
    ReplyCode,
    Status,
    WireFormat,
    decode,
    encode,
)
from simple_message.constants import RobotMode, TriState
from simple_message.endpoints import Server, Session
from simple_message.errors import LocalProtocolError, MalformedMessage
from simple_message.link import Link, NeedData, Received, Request
from simple_message.messages import MESSAGE_CLASSES, register, scoped_registry

from .strategies import messages

WIRES = {"le32": LE32, "be32": BE32, "le64": LE64, "be64": BE64}
FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def plain(data: bytes, wire: WireFormat) -> list[object]:
    """What the fast paths stand for: feed, then decode every frame (errors returned)."""
    dec = FrameDecoder(wire.byte_order)
    dec.feed(data)
    out: list[object] = []
    for frame in dec:
        try:
            out.append(decode(frame, wire))
        except MalformedMessage as exc:
            out.append(exc)
    return out


def key(item: object, wire: WireFormat) -> object:
    """Comparable even with NaNs (re-encoded bytes) and errors (their fields)."""
    if isinstance(item, MalformedMessage):
        return (MalformedMessage, str(item), item.msg_type, item.comm_type, item.reply_code, item.frame)
    assert isinstance(item, Message)
    return (type(item), encode(item, wire), item.comm_type.__class__, item.reply_code.__class__)


# -- runs of one header -------------------------------------------------------------------------


FIXED = sorted({cls for pair in MESSAGE_CLASSES.values() for cls in pair if cls.LAYOUT}, key=lambda c: c.__name__)


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
@pytest.mark.parametrize("cls", FIXED, ids=lambda c: c.__name__)
def test_a_long_run_of_every_fixed_layout_ends_where_its_header_changes(cls: type[Message], wire: WireFormat) -> None:
    """A run of 40 frames of one class (its fields varying), then the same type with another
    reply_code, then a frame cut short: every frame as decode() makes it, the cut one held."""
    comm = int(CommType.SERVICE_REPLY) if MESSAGE_CLASSES[cls.MSG_TYPE][1] is cls else int(CommType.TOPIC)
    values = {name: (k if code in ("i", "I") else 0.25 * k) for k, (name, code) in enumerate(cls.LAYOUT)}

    def make(n: int, reply: int) -> bytes:
        fields = {
            name: ([v + n] * 3 if code[1:] else v + n)
            for (name, code), v in zip(cls.LAYOUT, values.values(), strict=True)
        }
        return encode(cls(**fields, comm_type=comm, reply_code=reply), wire)

    frames = [make(n, 1) for n in range(40)] + [make(40, 2), make(41, 2)]
    stream = b"".join(frames) + frames[0][:-1]
    dec = FrameDecoder(wire.byte_order)
    got = dec.feed_messages(stream, wire)
    assert [key(m, wire) for m in got] == [key(m, wire) for m in plain(stream, wire)]
    assert len(got) == 42 and dec.frames_decoded == 42 and dec.buffered == len(frames[0]) - 1


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
@pytest.mark.parametrize("field", ["length", "msg_type", "comm_type", "reply_code"])
def test_a_run_ends_at_any_frame_whose_header_differs(wire: WireFormat, field: str) -> None:
    """A run of JOINT_TRAJ_PT broken at every position k by a frame that differs in one header field."""
    q = [0.5, -0.25, 0.125]
    for k in range(1, 30):
        msgs: list[Message] = [JointTrajPt(n, q, 0.5, 0.1) for n in range(k)]
        other: Message = {
            "length": JointTrajPtFull(0, k, 0x0F, 1.5, q, q, q),
            "msg_type": JointFeedback(0, 0x0E, 1.5, q, q, q, comm_type=CommType.SERVICE_REQUEST),
            "comm_type": JointTrajPt(k, q, 0.5, 0.1, comm_type=CommType.TOPIC),
            "reply_code": JointTrajPt(k, q, 0.5, 0.1, reply_code=ReplyCode.SUCCESS),
        }[field]
        msgs += [other] + [JointTrajPt(n, q, 0.5, 0.1) for n in range(12)]
        stream = b"".join(encode(m, wire) for m in msgs)
        got = FrameDecoder(wire.byte_order).feed_messages(stream, wire)
        assert [key(m, wire) for m in got] == [key(m, wire) for m in plain(stream, wire)]


def test_long_runs_decode_as_frame_by_frame_wherever_they_end() -> None:
    """feed_messages on long runs, in every wire format, of a message of whole words (JOINT_TRAJ_PT)
    and of a registered one whose frames are not (22 bytes), each run ended by a frame differing in
    its reply_code and followed by more of the run's frames, cut into reads anywhere: what feed +
    decode of each frame gives."""
    from dataclasses import dataclass

    @dataclass(frozen=True, slots=True)
    class Odd(Message):
        MSG_TYPE: ClassVar[int] = 9001
        LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("a", "i"), ("b", "h"))
        a: int = 0
        b: int = 0

    with scoped_registry():
        register(Odd)
        for wire in WIRES.values():
            makers: list[Callable[[int, int], Message]] = [
                lambda n, reply: JointTrajPt(n, [0.5, -0.25], 0.5, 0.1, reply_code=reply),
                lambda n, reply: Odd(n, n % 100, reply_code=reply),
            ]
            for make in makers:
                for run in (63, 64, 65, 66, 129, 300):
                    msgs = [make(n, 0) for n in range(run)] + [make(run, 1)] + [make(n, 0) for n in range(130)]
                    stream = b"".join(encode(m, wire) for m in msgs)
                    want = [key(m, wire) for m in plain(stream, wire)]
                    for read in (len(stream), 4096, 777):
                        dec = FrameDecoder(wire.byte_order)
                        got: list[object] = []
                        for i in range(0, len(stream), read):
                            got.extend(dec.feed_messages(stream[i : i + read], wire))
                        assert [key(m, wire) for m in got] == want, (wire, run, read)
                        assert dec.frames_decoded == len(msgs) and dec.buffered == 0


def test_a_run_gives_enum_members_and_exact_classes() -> None:
    stream = encode(Status(1, 0, 0, 0, 1, 2, 1), LE32) * 20
    got = FrameDecoder().feed_messages(stream, LE32)
    assert all(type(m) is Status for m in got) and len(got) == 20
    last = got[-1]
    assert isinstance(last, Status)
    assert last.drives_powered is TriState.TRUE and last.mode is RobotMode.AUTO and last.comm_type is CommType.TOPIC


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_long_runs_of_random_messages_in_any_chunking(wire: WireFormat) -> None:
    @FAST
    @given(st.lists(st.tuples(messages(wire), st.integers(1, 24)), min_size=1, max_size=5), st.data())
    def check(items: list[tuple[Message, int]], data: st.DataObject) -> None:
        stream = b"".join(encode(m, wire) * count for m, count in items)
        cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
        dec = FrameDecoder(wire.byte_order)
        got: list[object] = []
        for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
            got.extend(dec.feed_messages(stream[a:b], wire))
        assert [key(m, wire) for m in got] == [key(m, wire) for m in plain(stream, wire)]
        assert dec.frames_decoded == sum(count for _, count in items) and dec.buffered == 0

    check()


# -- one whole frame: FrameDecoder.one_message, Link.receive_one ----------------------------------


def _frames(wire: WireFormat) -> st.SearchStrategy[bytes]:
    """Whole frames of every type, and frames whose body fits no layout of their type."""
    bad = st.builds(
        lambda t, comm, reply, body: wire.header.pack(12 + len(body), t, comm, reply) + body,
        st.sampled_from(sorted(MESSAGE_CLASSES)),
        st.integers(0, 4),
        st.integers(0, 3),
        st.binary(max_size=80),
    )
    return messages(wire).map(lambda m: encode(m, wire)) | bad


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_one_message_is_feed_messages_of_one_frame(wire: WireFormat) -> None:
    @FAST
    @given(st.lists(_frames(wire) | st.binary(max_size=40), min_size=1, max_size=8))
    def check(reads: list[bytes]) -> None:
        fast, general = FrameDecoder(wire.byte_order), FrameDecoder(wire.byte_order)
        for data in reads:
            one = fast.one_message(data, wire)
            got = fast.feed_messages(data, wire) if one is None else [one]
            want = general.feed_messages(data, wire)
            assert [key(m, wire) for m in got] == [key(m, wire) for m in want]
            assert (fast.frames_decoded, fast.buffered, fast.failed) == (
                general.frames_decoded,
                general.buffered,
                general.failed,
            )

    check()


def _events(link: Link) -> list[object]:
    out: list[object] = []
    while not isinstance(event := link.next_event(), NeedData):
        out.append(event)
    return out


def _event_key(event: object, wire: WireFormat) -> object:
    def field(value: object) -> object:
        if isinstance(value, Message | MalformedMessage):
            return key(value, wire)
        if isinstance(value, Request):
            return ("request", value.msg_type, value.abandoned)
        if isinstance(value, BaseException):  # a FrameError: compared by identity otherwise
            return (type(value), str(value))
        return value

    return (type(event).__name__, {k: field(getattr(event, k)) for k in getattr(event, "__slots__", ())})


@pytest.mark.parametrize("wire", WIRES.values(), ids=WIRES.keys())
def test_receive_one_is_receive_data_and_its_events(wire: WireFormat) -> None:
    """Reads of whole frames, parts and several frames, with requests pending (replies answer
    them): the same events in the same order, the returned message standing for its Received."""

    @FAST
    @given(
        st.lists(_frames(wire) | st.binary(max_size=40), min_size=1, max_size=8),
        st.lists(st.sampled_from([MsgType.PING, MsgType.JOINT_TRAJ_PT]), max_size=3),
        st.booleans(),
    )
    def check(reads: list[bytes], pending: list[int], autodetect: bool) -> None:
        fast, general = Link(wire, autodetect=autodetect), Link(wire, autodetect=autodetect)
        for msg_type in pending:
            request = Ping() if msg_type == MsgType.PING else JointTrajPt(1)
            fast.send_request(request)
            general.send_request(request)
        for data in reads:
            try:
                msg = fast.receive_one(data)
                got = ([] if msg is None else [Received(msg)]) + _events(fast)
            except LocalProtocolError as exc:  # data after the end (b"")
                got = [exc]
            try:
                general.receive_data(data)
                want = _events(general)
            except LocalProtocolError as exc:
                want = [exc]
            assert [_event_key(e, wire) for e in got] == [_event_key(e, wire) for e in want]
            assert (fast.ended, fast.buffered, fast.pending_requests, fast.wire) == (
                general.ended,
                general.buffered,
                general.pending_requests,
                general.wire,
            )

    check()


# -- the standing PING reply of a server's connections -------------------------------------------


class Transport(asyncio.Transport):
    """A transport that records each write; its write buffer and closing state are set by the test."""

    def __init__(self) -> None:
        super().__init__()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.writes: list[bytes] = []
        self.buffered = 0
        self.closing = False
        self.protocol: asyncio.BaseProtocol | None = None

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return {"socket": self.sock, "peername": ("127.0.0.1", 5555), "sockname": ("127.0.0.1", 11000)}.get(
            name, default
        )

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self.protocol = protocol

    def get_protocol(self) -> asyncio.BaseProtocol:
        assert self.protocol is not None
        return self.protocol

    def write(self, data: bytes | bytearray | memoryview) -> None:
        self.writes.append(bytes(data))

    def is_closing(self) -> bool:
        return self.closing

    def get_write_buffer_size(self) -> int:
        return self.buffered

    def pause_reading(self) -> None:
        pass

    def resume_reading(self) -> None:
        pass

    def close(self) -> None:
        if not self.closing and self.protocol is not None:
            asyncio.get_running_loop().call_soon(self.protocol.connection_lost, None)
        self.closing = True

    def abort(self) -> None:
        self.close()


PING = Ping().encode(LE32)
PING_REPLY = Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS).encode(LE32)
STEPS = [
    "ping",  # a whole PING request, one read
    "ping-halves",  # a PING in two reads
    "two-pings",  # two PINGs in one read
    "point",  # a JOINT_TRAJ_PT request answered at once
    "slow-point",  # one whose handler waits until "release"
    "release",
    "part",  # the first 6 bytes of a frame (completed by the next frame read)
    "be-ping",  # a big-endian PING: a bad length prefix for this little-endian server
    "ping-reply",  # a stray SERVICE_REPLY
    "subscribe",
    "buffer",  # the transport's write buffer holds bytes
    "drain",
    "topic-then-ping",  # a broadcast topic queued, not flushed yet, then a PING
    "full-buffer",  # the write buffer over the server's limit
    "log-frames",  # frame logging switched on
    "ping-handler",  # a PING handler registered
]


async def run_steps(steps: list[str], standing: bool, replace_handler: bool = False) -> dict[str, object]:
    """The steps against a server connection whose standing replies are on or off (``replace_handler``:
    its message handler wrapped by the test after the server set it)."""
    calls: list[tuple[str, object]] = []

    class Recording(Server):
        """Records what reaches the server's per-connection pipeline (its on_message)."""

        def _arrived(self, session: Session, msg: Any) -> Any:
            calls.append(("message", type(msg).__name__))
            return super()._arrived(session, msg)

    server = Recording(LE32, name="fast")
    release = asyncio.Event()

    async def slow(msg: JointTrajPt, session: Session) -> None:
        calls.append(("slow", msg.sequence))
        await release.wait()

    def point(msg: JointTrajPt, session: Session) -> None:
        calls.append(("point", msg.sequence))

    server.handle(MsgType.JOINT_TRAJ_PT, lambda m, s: slow(m, s) if m.sequence == 7 else point(m, s))  # type: ignore[arg-type,return-value]
    transport = Transport()
    server._serve_accepted(transport, ("127.0.0.1", 5555))
    connection = next(iter(server.sessions)).connection
    if not standing:
        connection.link.standing.clear()
    if replace_handler:
        original = connection.on_message
        assert original is not None

        def on_message(msg: Any) -> Any:
            calls.append(("replaced", type(msg).__name__))
            return original(msg)

        connection.on_message = on_message
    subscription = None
    logger = logging.getLogger("simple_message.connection.frames")
    level = logger.level
    logger.setLevel(logging.INFO)  # frames not logged until "log-frames"
    records: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record.getMessage())

    handler = Keep()
    logger.addHandler(handler)
    # the PING frame decoded once, so that the standing path may take it (it needs the kept message)
    FrameDecoder().feed_messages(PING, LE32)
    try:
        for step in steps:
            if step == "ping":
                connection.data_received(PING)
            elif step == "ping-halves":
                connection.data_received(PING[:5])
                connection.data_received(PING[5:])
            elif step == "two-pings":
                connection.data_received(PING + PING)
            elif step == "point":
                connection.data_received(JointTrajPt(1, [0.5]).encode(LE32))
            elif step == "slow-point":
                connection.data_received(JointTrajPt(7, [0.5]).encode(LE32))
            elif step == "release":
                release.set()
            elif step == "part":
                connection.data_received(PING[:6])
            elif step == "be-ping":
                connection.data_received(Ping().encode(BE32))
            elif step == "ping-reply":
                connection.data_received(PING_REPLY)
            elif step == "subscribe" and subscription is None:
                subscription = connection.subscribe()
            elif step == "buffer":
                transport.buffered = 100
            elif step == "drain":
                transport.buffered = 0
            elif step == "topic-then-ping":
                server.broadcast(Status())
                connection.data_received(PING)
            elif step == "full-buffer":
                transport.buffered = 10**6
            elif step == "log-frames":
                logger.setLevel(logging.DEBUG)
            elif step == "ping-handler":
                server.handle(MsgType.PING, lambda m, s: calls.append(("ping-handler", None)))  # type: ignore[arg-type,func-returns-value]
            for _ in range(5):  # the server's tasks take their turns (no clock involved)
                await asyncio.sleep(0)
        delivered = []
        while subscription is not None and len(subscription):
            delivered.append(type(subscription.get_nowait()).__name__)
        decoder = connection.link._decoder
        return {
            "writes": transport.writes,
            "calls": calls,
            "delivered": delivered,
            "frames": decoder.frames_decoded,
            "closed": connection.closed,
            "logged": [r for r in records if "->" in r],
        }
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        release.set()
        await server.close()
        transport.sock.close()


def test_the_standing_ping_reply_is_taken_and_answers_as_the_server_would() -> None:
    on = asyncio.run(run_steps(["ping", "ping", "ping"], standing=True))
    off = asyncio.run(run_steps(["ping", "ping", "ping"], standing=False))
    assert on["writes"] == off["writes"] == [PING_REPLY] * 3
    assert on["frames"] == off["frames"] == 3
    # the first frame of a connection goes the general way (it sets the decoder up); the others are
    # neither decoded nor handed to the server: the connection answered them
    assert on["calls"] == [("message", "Ping")]
    assert off["calls"] == [("message", "Ping")] * 3


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.sampled_from(STEPS), min_size=1, max_size=14))
def test_the_standing_reply_changes_nothing_but_the_calls(steps: list[str]) -> None:
    """Whatever happens around the PINGs (requests waiting, partial frames, bad input, subscribers,
    a full write buffer, queued topics, frame logging, a PING handler): the same bytes in the same
    writes, the same handler calls but for the server's own PING answers, the same deliveries."""
    on = asyncio.run(run_steps(steps, standing=True))
    off = asyncio.run(run_steps(steps, standing=False))

    def without_pings(calls: object) -> list[object]:
        assert isinstance(calls, list)
        return [c for c in calls if c != ("message", "Ping")]

    assert on["writes"] == off["writes"]
    assert without_pings(on["calls"]) == without_pings(off["calls"])
    for field in ("delivered", "frames", "closed", "logged"):
        assert on[field] == off[field], field


def test_a_replaced_message_handler_gets_every_ping() -> None:
    """The standing reply is sent on behalf of the server's own handler only."""
    on = asyncio.run(run_steps(["ping", "ping"], standing=True, replace_handler=True))
    assert on["calls"] == [("replaced", "Ping"), ("message", "Ping")] * 2
    assert on["writes"] == [PING_REPLY] * 2


def test_no_standing_reply_when_the_registry_decodes_ping_otherwise() -> None:
    """A PING registered with another class: the frame goes to the server as that class."""

    from dataclasses import dataclass

    @dataclass(frozen=True, slots=True)
    class OtherPing(Message):
        MSG_TYPE = 1

    with scoped_registry():
        register(OtherPing, replace=True)
        on = asyncio.run(run_steps(["ping"], standing=True))
    assert on["calls"] == [("message", "OtherPing")]
