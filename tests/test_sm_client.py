"""Request/reply matching, the reconnecting client, and the in-process transport pair."""

from __future__ import annotations

import asyncio
import random
import types

import pytest

from simple_message import (
    LE32,
    CommType,
    FrameDecoder,
    HeaderOnly,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    MotoMotionReply,
    MsgType,
    Ping,
    ReplyCode,
    Status,
    decode,
    endpoints,
)
from simple_message.connection import Connection, ConnectionState
from simple_message.endpoints import LOOP_VARIABLE, Client, ReconnectPolicy, Server, run
from simple_message.errors import (
    ConnectionClosed,
    LocalProtocolError,
    NotConnected,
    RequestFailed,
    RequestTimeout,
    UnexpectedReply,
)
from simple_message.transport import FaultSpec, StreamPair, memory_pair, open_serial

T = 10.0


class FakePeer:
    """The far end of a memory pair, driven by the test frame by frame."""

    def __init__(self, streams: StreamPair) -> None:
        self.reader, self.writer = streams
        self.decoder = FrameDecoder()

    async def next(self) -> bytes:
        async with asyncio.timeout(T):
            while True:
                frame = self.decoder.next_frame()
                if frame is not None:
                    return frame
                data = await self.reader.read(65536)
                assert data, "connection closed"
                self.decoder.feed(data)

    def reply(self, msg: object) -> None:
        self.writer.write(msg.encode(LE32))  # type: ignore[attr-defined]


async def pair(a_to_b: FaultSpec | None = None, b_to_a: FaultSpec | None = None) -> tuple[Connection, FakePeer]:
    ours, theirs = memory_pair(a_to_b, b_to_a)
    return Connection(ours, LE32, name="ours").start(), FakePeer(theirs)


# -- request/reply matching -----------------------------------------------------------------------


async def test_vendor_reply_shapes_are_accepted() -> None:
    conn, peer = await pair()
    point = JointTrajPt(1, [0.5], 0.5, 1.0)
    shapes = [
        HeaderOnly(11, reply_code=ReplyCode.SUCCESS),  # ABB
        point.to_reply(ReplyCode.SUCCESS),  # C++ reference library
        JointPosition(1, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS),  # Fanuc
    ]
    for shape in shapes:
        task = asyncio.create_task(conn.request(point, timeout=T))
        await peer.next()
        peer.reply(shape)
        assert await task == shape
    # MotoROS answers JOINT_TRAJ_PT_FULL with MOTO_MOTION_REPLY; its outcome is in the body.
    full = JointTrajPtFull(0, 5, 0x07, 0.5)
    task = asyncio.create_task(conn.request(full, timeout=T))
    await peer.next()
    busy = MotoMotionReply(0, 5, 14, 1, 0)
    peer.reply(busy)
    assert await task == busy
    await conn.close()


async def test_failure_wrong_type_and_invalid_reply_code_are_typed_errors() -> None:
    conn, peer = await pair()
    task = asyncio.create_task(conn.request(JointTrajPt(0), timeout=T))
    await peer.next()
    peer.reply(HeaderOnly(11, reply_code=ReplyCode.FAILURE))
    with pytest.raises(RequestFailed):
        await task
    task = asyncio.create_task(conn.request(JointTrajPt(0), timeout=T))
    await peer.next()
    peer.reply(Status(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS))
    with pytest.raises(UnexpectedReply) as info:
        await task
    assert isinstance(info.value.reply, Status)
    task = asyncio.create_task(conn.request(Ping(), timeout=T))
    await peer.next()
    peer.reply(Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.INVALID))
    with pytest.raises(UnexpectedReply):
        await task
    with pytest.raises(LocalProtocolError):
        await conn.request(Status(), timeout=T)  # a TOPIC is not a request
    await conn.close()


async def test_timeout_leaves_a_tombstone_that_eats_the_late_reply() -> None:
    conn, peer = await pair()
    with pytest.raises(RequestTimeout):
        await conn.request(JointTrajPt(0), timeout=0.05)
    assert decode(await peer.next(), LE32).sequence == 0  # type: ignore[attr-defined]
    task = asyncio.create_task(conn.request(JointTrajPt(1), timeout=T))
    assert decode(await peer.next(), LE32).sequence == 1  # type: ignore[attr-defined]
    peer.reply(JointTrajPt(0).to_reply())  # the late reply to the abandoned request
    peer.reply(JointTrajPt(1).to_reply())
    assert (await task).sequence == 1  # type: ignore[attr-defined]
    assert conn.pending_requests == 0
    await conn.close()


async def test_a_reply_that_never_came_does_not_shift_later_replies() -> None:
    conn, peer = await pair()
    with pytest.raises(RequestTimeout):
        await conn.request(Ping(), timeout=0.05)
    task = asyncio.create_task(conn.request(JointTrajPt(7), timeout=T))
    await peer.next()
    await peer.next()
    peer.reply(JointTrajPt(7).to_reply())  # the PING's reply never comes
    assert (await task).sequence == 7  # type: ignore[attr-defined]
    await conn.close()


async def test_lost_connection_fails_every_pending_request_at_once() -> None:
    conn, peer = await pair()
    tasks = [asyncio.create_task(conn.request(JointTrajPt(i), timeout=T)) for i in range(3)]
    for _ in range(3):
        await peer.next()
    peer.writer.close()
    for task in tasks:
        with pytest.raises(ConnectionClosed):
            await asyncio.wait_for(task, 2.0)
    assert conn.closed


async def test_stray_replies_and_topics() -> None:
    conn, peer = await pair()
    sub = conn.subscribe(maxsize=10, msg_types=[MsgType.STATUS])
    inbox = aiter(conn)  # everything that is not a reply, from now on
    peer.reply(Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS))  # stray: ignored
    peer.reply(JointPosition(0, [0.5]))
    peer.reply(Status(1, 0, 0, 0, 0, 2, 1))
    assert await sub.get(timeout=T) == Status(1, 0, 0, 0, 0, 2, 1)
    assert await asyncio.wait_for(anext(inbox), T) == JointPosition(0, [0.5])
    assert await asyncio.wait_for(anext(inbox), T) == Status(1, 0, 0, 0, 0, 2, 1)
    peer.reply(JointPosition(1))
    assert await asyncio.wait_for(anext(inbox), T) == JointPosition(1)
    await conn.close()


# -- the hand-over from a stream pair, and reading before start() ----------------------------------


async def test_what_the_stream_reader_had_buffered_is_not_lost() -> None:
    """A connection takes a stream pair's transport over with the bytes its reader already holds."""
    ours, theirs = memory_pair()
    first, second = JointPosition(1).encode(LE32), JointPosition(2).encode(LE32)
    theirs[1].write(first)
    theirs[1].write(second)
    reader = ours[0]
    assert await asyncio.wait_for(reader.readexactly(len(first)), T) == first  # someone read the first
    conn = Connection(ours, LE32, name="ours")
    inbox = aiter(conn)
    conn.start()
    assert await asyncio.wait_for(anext(inbox), T) == JointPosition(2)  # the second was in the reader
    theirs[1].write(JointPosition(3).encode(LE32))
    assert await asyncio.wait_for(anext(inbox), T) == JointPosition(3)
    await conn.close()


async def test_what_arrives_before_start_is_acted_on_at_start_in_order() -> None:
    ours, theirs = memory_pair()
    conn = Connection(ours, LE32, name="ours")
    inbox = aiter(conn)
    peer = FakePeer(theirs)
    for i in range(3):
        peer.reply(JointPosition(i))
    peer.writer.close()  # and the end of the input, before start() too
    await asyncio.wait_for(theirs[1].wait_closed(), T)
    assert len(inbox) == 0 and not conn.closed  # nothing acted on yet
    conn.start()
    assert [await inbox.get(timeout=T) for _ in range(3)] == [JointPosition(0), JointPosition(1), JointPosition(2)]
    await asyncio.wait_for(conn.wait_closed(), T)
    assert conn.close_reason is None


async def test_the_memory_pair_pauses_and_resumes_reading_in_order() -> None:
    ours, theirs = memory_pair()
    transport = ours[1].transport
    transport.pause_reading()
    assert not transport.is_reading()
    theirs[1].write(b"abc")
    await asyncio.sleep(0)  # one turn of the loop: delivered, and held
    transport.resume_reading()
    transport.pause_reading()  # paused again before the release: it stays held
    theirs[1].write(b"def")
    await asyncio.sleep(0)
    await asyncio.sleep(0)
    assert len(ours[0]._buffer) == 0  # nothing delivered while paused
    transport.resume_reading()
    theirs[1].write(b"ghi")  # arrives before the held pieces are released: queued behind them
    theirs[1].close()  # and the hang-up after everything
    async with asyncio.timeout(T):
        assert await ours[0].read() == b"abcdefghi"
    ours[1].close()


async def test_a_connection_over_the_thread_backed_serial_transport() -> None:
    """pyserial's loop:// (no file descriptor): the connection takes over the thread transport and
    reads what it sent itself, with reading paused and resumed on the way."""
    conn = Connection(await open_serial("loop://"), LE32, name="loop").start()
    inbox = aiter(conn)
    transport = conn.transport
    transport.pause_reading()
    assert not transport.is_reading()
    transport.resume_reading()
    for i in range(3):
        await conn.send(JointPosition(i))
    assert [await asyncio.wait_for(anext(inbox), T) for _ in range(3)] == [JointPosition(i) for i in range(3)]
    await conn.close()


class _MarkedLoop(asyncio.SelectorEventLoop):
    """The loop a stand-in uvloop module makes (the real one keeps process-wide descriptors)."""


def test_run_uses_uvloop_when_it_is_installed(monkeypatch: pytest.MonkeyPatch) -> None:
    async def loop_type() -> type:
        return type(asyncio.get_running_loop())

    modules: dict[str, object] = {}

    def import_module(name: str) -> object:
        if name not in modules:
            raise ImportError(name)
        return modules[name]

    monkeypatch.setattr(endpoints.importlib, "import_module", import_module)
    monkeypatch.delenv(LOOP_VARIABLE, raising=False)
    assert run(loop_type()) is not _MarkedLoop  # not installed: asyncio.run's loop
    modules["uvloop"] = types.SimpleNamespace(new_event_loop=_MarkedLoop)
    assert run(loop_type()) is _MarkedLoop  # installed: used
    monkeypatch.setenv(LOOP_VARIABLE, "asyncio")
    assert run(loop_type()) is not _MarkedLoop  # unless told otherwise
    monkeypatch.setenv(LOOP_VARIABLE, "uvloop")
    assert run(loop_type()) is _MarkedLoop
    del modules["uvloop"]
    coro = loop_type()
    with pytest.raises(ImportError):
        run(coro)  # asked for, not installed
    coro.close()
    monkeypatch.setenv(LOOP_VARIABLE, "tokio")
    coro = loop_type()
    with pytest.raises(ValueError, match="asyncio or uvloop"):
        run(coro)
    coro.close()


# -- the in-process pair's fault injection ------------------------------------------------------


@pytest.mark.parametrize(
    "faults",
    [FaultSpec(split=1), FaultSpec(split=7), FaultSpec(coalesce=True), FaultSpec(delay=0.02)],
    ids=["split-1", "split-7", "coalesce", "delay"],
)
async def test_memory_pair_faults_keep_the_protocol_working(faults: FaultSpec) -> None:
    conn, peer = await pair(a_to_b=faults, b_to_a=faults)
    tasks = [asyncio.create_task(conn.request(JointTrajPt(i, [0.5]), timeout=T)) for i in range(4)]
    for i in range(4):
        assert decode(await peer.next(), LE32).sequence == i  # type: ignore[attr-defined]
        peer.reply(JointTrajPt(i, [0.5]).to_reply())
    assert [(await t).sequence for t in tasks] == [0, 1, 2, 3]  # type: ignore[attr-defined]
    await conn.close()


async def test_memory_pair_delay_is_real() -> None:
    conn, peer = await pair(b_to_a=FaultSpec(delay=0.2))
    loop = asyncio.get_running_loop()
    task = asyncio.create_task(conn.request(Ping(), timeout=T))
    await peer.next()
    start = loop.time()
    peer.reply(Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS))
    await task
    assert loop.time() - start >= 0.19
    await conn.close()


async def test_corruption_of_a_length_prefix_closes_the_connection() -> None:
    def corrupt(data: bytes) -> bytes:
        return b"\xff\xff\xff\xff" + data[4:]

    conn, peer = await pair(b_to_a=FaultSpec(corrupt=corrupt))
    task = asyncio.create_task(conn.request(Ping(), timeout=T))
    await peer.next()
    peer.reply(Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS))
    with pytest.raises(ConnectionClosed):
        await task
    assert conn.closed and "length prefix" in str(conn.close_reason)


async def test_loop_url_without_a_file_descriptor() -> None:
    """pyserial's loop:// has no fileno: the thread-backed transport carries it."""
    reader, writer = await open_serial("loop://")
    frame = Ping().encode(LE32)
    writer.write(frame)
    async with asyncio.timeout(T):
        assert await reader.readexactly(len(frame)) == frame
    writer.close()


# -- the reconnecting client ------------------------------------------------------------------------


def test_backoff_is_bounded_exponential_with_jitter() -> None:
    policy = ReconnectPolicy(initial_delay=0.1, max_delay=2.0, factor=2.0, jitter=0.25)
    rng = random.Random(3)
    for attempt, base in [(1, 0.1), (2, 0.2), (3, 0.4), (5, 1.6), (6, 2.0), (50, 2.0)]:
        delays = [policy.delay(attempt, rng) for _ in range(200)]
        assert min(delays) >= base * 0.75 - 1e-12 and max(delays) <= base * 1.25 + 1e-12
        assert len(set(delays)) > 100  # jittered


async def test_client_reconnects_after_the_server_restarts_on_the_same_port() -> None:
    server = Server(LE32)
    port = await server.serve_tcp("127.0.0.1", 0)
    client = Client.tcp("127.0.0.1", port, LE32, reconnect=ReconnectPolicy(initial_delay=0.05, max_delay=0.2))
    states: list[ConnectionState] = []

    async def watch() -> None:
        async for state in client.states():
            states.append(state)

    watcher = asyncio.create_task(watch())
    await client.start(timeout=T)
    sub = client.subscribe(msg_types=[MsgType.STATUS])
    assert (await client.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
    await server.close()
    await client.wait_for(ConnectionState.RECONNECTING, timeout=T)
    with pytest.raises(NotConnected):
        await client.request(Ping(), timeout=T)  # fails at once; nothing is queued for later
    server = Server(LE32)
    await server.serve_tcp("127.0.0.1", port)
    await client.wait_for(ConnectionState.CONNECTED, timeout=T)
    assert (await client.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
    server.broadcast(Status(1, 0, 0, 0, 0, 2, 1))
    assert (await sub.get(timeout=T)).msg_type == MsgType.STATUS  # subscriptions survive reconnection
    assert client.connects == 2
    await client.close()
    await server.close()
    await asyncio.wait_for(watcher, T)
    assert states[0] in (ConnectionState.CONNECTING, ConnectionState.CONNECTED)
    assert ConnectionState.RECONNECTING in states and states[-1] is ConnectionState.CLOSED


async def test_client_close_cancels_a_pending_backoff() -> None:
    client = Client.tcp("127.0.0.1", _free_port(), LE32, reconnect=ReconnectPolicy(initial_delay=30.0, max_delay=30.0))
    task = asyncio.create_task(client.start(timeout=None))
    await client.wait_for(ConnectionState.RECONNECTING, timeout=T)
    await asyncio.wait_for(client.close(), 2.0)  # does not sit out the 30 s backoff
    assert client.state is ConnectionState.CLOSED
    with pytest.raises(ConnectionClosed):
        await asyncio.wait_for(task, T)


async def test_client_without_reconnect_gives_up() -> None:
    client = Client.tcp("127.0.0.1", _free_port(), LE32, reconnect=None)
    with pytest.raises(ConnectionClosed):
        await client.start(timeout=T)
    assert client.state is ConnectionState.CLOSED
    assert isinstance(client.last_error, OSError)


async def test_client_max_attempts() -> None:
    client = Client.tcp("127.0.0.1", _free_port(), LE32, reconnect=ReconnectPolicy(initial_delay=0.01, max_attempts=3))
    with pytest.raises(ConnectionClosed):
        await client.start(timeout=T)
    assert client.attempts == 4  # the first try and three retries


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
