"""The asyncio layer over loopback TCP and a real pseudo-terminal pair (the same suite for both)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import struct
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass

import pytest

from simple_message import (
    BE32,
    LE32,
    CommType,
    FrameDecoder,
    HeaderOnly,
    JointFeedback,
    JointTrajPt,
    MsgType,
    Ping,
    ReplyCode,
    Status,
    decode,
    encode,
)
from simple_message.connection import Connection
from simple_message.endpoints import Client, Server, Session
from simple_message.errors import ConnectionClosed, RequestFailed
from simple_message.transport import StreamPair, open_fd, open_serial, open_tcp, unread_by_peers

T = 10.0  # every wait in these tests is bounded by this many seconds


@dataclass
class Served:
    """A running server and a way to open raw client streams to it."""

    kind: str
    server: Server
    open: Callable[[], Awaitable[StreamPair]]

    async def connection(self) -> Connection:
        return Connection(await self.open(), LE32, name=f"test-{self.kind}").start()


def server_port(server: Server) -> int:
    return int(server._servers[0].sockets[0].getsockname()[1])


def echo_server(**kwargs: object) -> Server:
    server = Server(LE32, name="test", **kwargs)  # type: ignore[arg-type]
    server.handle(MsgType.JOINT_TRAJ_PT, lambda msg, session: None)  # SUCCESS, echoed body
    return server


@contextlib.asynccontextmanager
async def tcp_link(server: Server) -> AsyncIterator[Served]:
    port = await server.serve_tcp("127.0.0.1", 0)
    try:
        yield Served("tcp", server, lambda: open_tcp("127.0.0.1", port))
    finally:
        await server.close()


@contextlib.asynccontextmanager
async def pty_link(server: Server) -> AsyncIterator[Served]:
    """The server on the pty master, the client through pyserial on the slave device."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    server.start_serving(server.serve_fd(master, name="pty-master"))
    opened = False

    async def opener() -> StreamPair:
        nonlocal opened
        if opened:
            raise AssertionError("a serial link has one client")
        opened = True
        streams = await open_serial(path, baudrate=115200)
        os.close(slave)  # pyserial holds its own descriptor now
        return streams

    try:
        yield Served("pty", server, opener)
    finally:
        await server.close()
        if not opened:
            os.close(slave)


LINKS = {"tcp": tcp_link, "pty": pty_link}


@pytest.fixture(params=list(LINKS))
def link_kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


async def read_frames(reader: asyncio.StreamReader, count: int, decoder: FrameDecoder | None = None) -> list[bytes]:
    decoder = decoder or FrameDecoder()
    frames: list[bytes] = []
    async with asyncio.timeout(T):
        while len(frames) < count:
            frames.extend(decoder)
            if len(frames) >= count:
                break
            data = await reader.read(65536)
            if not data:
                break
            decoder.feed(data)
    return frames


async def test_ping_and_request_reply(link_kind: str) -> None:
    async with LINKS[link_kind](echo_server()) as link:
        conn = await link.connection()
        reply = await conn.request(Ping(), timeout=T)
        assert reply == Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
        point = JointTrajPt(3, [0.5, -0.25], 0.5, 1.25)
        reply = await conn.request(point, timeout=T)
        assert reply == point.to_reply(ReplyCode.SUCCESS)
        await conn.close()


async def test_one_byte_writes_and_coalesced_writes(link_kind: str) -> None:
    async with LINKS[link_kind](echo_server()) as link:
        reader, writer = await link.open()
        request = JointTrajPt(1, [0.5], 0.5, 1.0).encode(LE32)
        for byte in request:
            writer.write(bytes([byte]))
            await writer.drain()
        (frame,) = await read_frames(reader, 1)
        assert decode(frame, LE32) == decode(request, LE32).to_reply(ReplyCode.SUCCESS)
        # Five requests coalesced into one write: five replies, in order.
        writer.write(b"".join(JointTrajPt(seq).encode(LE32) for seq in range(5)) + Ping().encode(LE32))
        frames = await read_frames(reader, 6)
        assert [decode(f, LE32).sequence for f in frames[:5]] == [0, 1, 2, 3, 4]  # type: ignore[attr-defined]
        assert decode(frames[5], LE32).msg_type == MsgType.PING
        writer.close()


async def test_pipelined_requests_are_answered_in_order(link_kind: str) -> None:
    """The first request finishes last of all (only once the other four have arrived behind it):
    the replies still go out in the order of the requests."""
    server = echo_server()
    arrived: list[int] = []
    handled: list[int] = []
    all_arrived = asyncio.Event()

    def on_arrival(msg: JointTrajPt, session: Session) -> None:
        arrived.append(msg.sequence)
        if len(arrived) == 5:
            all_arrived.set()

    async def first_finishes_last(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence == 0:
            await asyncio.wait_for(all_arrived.wait(), T)
        handled.append(msg.sequence)

    server.handle(MsgType.JOINT_TRAJ_PT, first_finishes_last, on_arrival=on_arrival)  # type: ignore[arg-type]
    async with LINKS[link_kind](server) as link:
        conn = await link.connection()
        replies = await asyncio.gather(*(conn.request(JointTrajPt(seq), timeout=T) for seq in range(5)))
        assert [r.sequence for r in replies] == [0, 1, 2, 3, 4]  # type: ignore[attr-defined]
        assert arrived == [0, 1, 2, 3, 4] and handled == [0, 1, 2, 3, 4]
        await conn.close()


async def test_a_ping_queued_behind_a_slow_request_is_answered_after_it(link_kind: str) -> None:
    """PING has a fast path (a cached reply, no handler): it still keeps its place in the order."""
    server = echo_server()
    later_arrived = asyncio.Event()

    def on_arrival(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence == 1:  # read after the PING: the server has seen the PING by now
            later_arrived.set()

    async def first_waits(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence == 0:
            await asyncio.wait_for(later_arrived.wait(), T)

    server.handle(MsgType.JOINT_TRAJ_PT, first_waits, on_arrival=on_arrival)  # type: ignore[arg-type]
    async with LINKS[link_kind](server) as link:
        reader, writer = await link.open()
        writer.write(JointTrajPt(0).encode(LE32) + Ping().encode(LE32) + JointTrajPt(1).encode(LE32))
        replies = [decode(f, LE32) for f in await read_frames(reader, 3)]
        assert [(r.msg_type, r.reply_code) for r in replies] == [
            (MsgType.JOINT_TRAJ_PT, ReplyCode.SUCCESS),
            (MsgType.PING, ReplyCode.SUCCESS),
            (MsgType.JOINT_TRAJ_PT, ReplyCode.SUCCESS),
        ]
        assert replies[1] == Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
        assert [r.sequence for r in (replies[0], replies[2])] == [0, 1]  # type: ignore[attr-defined]
        writer.close()


async def test_a_full_request_queue_stops_reading_until_there_is_room(link_kind: str) -> None:
    """Back-pressure: with a queue of one, a request handled, one queued and one waiting for room,
    the server reads nothing more (not even for the arrival hooks) until the first is done."""
    server = echo_server(request_queue=1)
    arrived: list[int] = []
    three = asyncio.Event()
    release = asyncio.Event()

    def on_arrival(msg: JointTrajPt, session: Session) -> None:
        arrived.append(msg.sequence)
        if len(arrived) == 3:
            three.set()

    async def first_waits(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence == 0:
            await asyncio.wait_for(release.wait(), T)

    server.handle(MsgType.JOINT_TRAJ_PT, first_waits, on_arrival=on_arrival)  # type: ignore[arg-type]
    async with LINKS[link_kind](server) as link:
        reader, writer = await link.open()
        writer.write(b"".join(JointTrajPt(seq).encode(LE32) for seq in range(5)))  # all five at once
        await asyncio.wait_for(three.wait(), T)
        assert arrived == [0, 1, 2]  # 0 is handled, 1 is queued, 2 waits for room: reading stopped
        release.set()
        replies = [decode(f, LE32) for f in await read_frames(reader, 5)]
        assert [r.sequence for r in replies] == [0, 1, 2, 3, 4]  # type: ignore[attr-defined]
        assert arrived == [0, 1, 2, 3, 4]
        writer.close()


async def test_a_server_closed_while_its_queue_is_full_leaves_nothing_behind(link_kind: str) -> None:
    """The handler never finishes and the reading waits for room: closing the server ends the
    session anyway (the guard in conftest.py fails the test on a leaked task or descriptor)."""
    server = echo_server(request_queue=1)
    three = asyncio.Event()
    ended = asyncio.Event()
    arrived: list[int] = []

    def on_arrival(msg: JointTrajPt, session: Session) -> None:
        arrived.append(msg.sequence)
        if len(arrived) == 3:
            three.set()

    async def never(msg: JointTrajPt, session: Session) -> None:
        await asyncio.Event().wait()

    server.handle(MsgType.JOINT_TRAJ_PT, never, on_arrival=on_arrival)  # type: ignore[arg-type]
    server.on_disconnect = lambda session: ended.set()
    async with LINKS[link_kind](server) as link:
        reader, writer = await link.open()
        writer.write(b"".join(JointTrajPt(seq).encode(LE32) for seq in range(5)))
        await asyncio.wait_for(three.wait(), T)
        await asyncio.wait_for(server.close(), T)
        assert ended.is_set() and not server.sessions and arrived == [0, 1, 2]
        async with asyncio.timeout(T):
            assert await reader.read() == b""  # nothing answered, then closed
        writer.close()


async def test_a_connection_closed_by_the_request_that_finds_the_queue_full(link_kind: str) -> None:
    """An arrival hook closes the connection on the very request that must wait for room: nothing
    is left waiting for that room (no task, no coroutine never awaited)."""
    server = echo_server(request_queue=1)
    ended = asyncio.Event()

    def on_arrival(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence == 2:
            session.connection.abort()

    async def never(msg: JointTrajPt, session: Session) -> None:
        await asyncio.Event().wait()

    server.handle(MsgType.JOINT_TRAJ_PT, never, on_arrival=on_arrival)  # type: ignore[arg-type]
    server.on_disconnect = lambda session: ended.set()
    async with LINKS[link_kind](server) as link:
        reader, writer = await link.open()
        writer.write(b"".join(JointTrajPt(seq).encode(LE32) for seq in range(3)))
        await asyncio.wait_for(ended.wait(), T)
        async with asyncio.timeout(T):
            assert await reader.read() == b""
        writer.close()


async def test_broadcast_topics_go_out_in_order_and_before_a_later_reply(link_kind: str) -> None:
    """Topics broadcast in one loop iteration are written together at its end; a reply sent
    meanwhile on the same connection goes out after them, not before."""
    server = echo_server()

    def publish_then_reply(msg: JointTrajPt, session: Session) -> None:
        server.broadcast(JointFeedback(0, 0x0E, 1.0, [0.1]))
        server.broadcast(Status(1, 0, 0, 0, 0, 2, 1))

    server.handle(MsgType.JOINT_TRAJ_PT, publish_then_reply)  # type: ignore[arg-type]
    async with LINKS[link_kind](server) as link:
        reader, writer = await link.open()
        writer.write(JointTrajPt(7).encode(LE32))
        frames = [decode(f, LE32) for f in await read_frames(reader, 3)]
        assert [f.msg_type for f in frames] == [MsgType.JOINT_FEEDBACK, MsgType.STATUS, MsgType.JOINT_TRAJ_PT]
        assert frames[2].sequence == 7  # type: ignore[attr-defined]
        assert server.broadcast(Status(1, 0, 0, 0, 0, 2, 1)) == 1
        (topic,) = await read_frames(reader, 1)
        assert decode(topic, LE32).msg_type == MsgType.STATUS
        writer.close()


async def test_handler_that_raises_gets_failure_and_the_server_lives(
    link_kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    server = echo_server()

    def broken(msg: object, session: Session) -> None:
        raise RuntimeError("handler bug")

    server.handle(MsgType.STATUS, broken)
    async with LINKS[link_kind](server) as link:
        conn = await link.connection()
        with pytest.raises(RequestFailed) as info:
            await conn.request(Status(comm_type=CommType.SERVICE_REQUEST), timeout=T)
        assert info.value.reply == HeaderOnly(13, reply_code=ReplyCode.FAILURE)  # type: ignore[comparison-overlap]
        assert "handler bug" in caplog.text
        assert (await conn.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
        await conn.close()


async def test_unknown_request_type_gets_header_only_failure(link_kind: str) -> None:
    async with LINKS[link_kind](echo_server()) as link:
        reader, writer = await link.open()
        writer.write(struct.pack("<iiii", 12, 9999, 2, 0))
        writer.write(struct.pack("<iiii", 12, 9998, 1, 0))  # unknown TOPIC: ignored
        writer.write(struct.pack("<iiii", 12, 1, 3, 1))  # stray reply: ignored
        writer.write(Ping().encode(LE32))
        frames = await read_frames(reader, 2)
        assert frames[0].hex() == "0c0000000f27000003000000" + "02000000"  # the C++ MessageManager reply
        assert decode(frames[1], LE32).msg_type == MsgType.PING
        writer.close()


async def test_peer_that_disconnects_mid_request_fails_the_request_fast(link_kind: str) -> None:
    server = echo_server()
    arrived = asyncio.Event()

    async def hang_up(msg: object, session: Session) -> None:
        arrived.set()
        session.connection.abort()
        await asyncio.sleep(3600)

    server.handle(MsgType.JOINT_TRAJ_PT, hang_up)
    async with LINKS[link_kind](server) as link:
        conn = await link.connection()
        with pytest.raises(ConnectionClosed):  # not RequestTimeout: it fails on the hang-up
            await conn.request(JointTrajPt(0), timeout=T)
        assert arrived.is_set()
        assert conn.closed
        with pytest.raises(ConnectionClosed):
            await conn.request(Ping(), timeout=T)


async def test_malformed_body_gets_failure_and_the_connection_stays(link_kind: str) -> None:
    async with LINKS[link_kind](echo_server()) as link:
        reader, writer = await link.open()
        writer.write(struct.pack("<iiii", 12 + 7, 11, 2, 0) + bytes(7))  # JOINT_TRAJ_PT with 7-byte body
        writer.write(struct.pack("<iiii", 12, 11, 2, 1))  # invalid header: request with reply_code 1
        writer.write(Ping().encode(LE32))
        frames = await read_frames(reader, 3)
        assert [decode(f, LE32) for f in frames[:2]] == [HeaderOnly(11, reply_code=ReplyCode.FAILURE)] * 2
        assert decode(frames[2], LE32).msg_type == MsgType.PING
        writer.close()


async def test_on_arrival_hook_runs_before_queued_requests_finish(link_kind: str) -> None:
    """A STOP must act while an earlier request still waits (docs/reference/protocol.md §10 pitfall 5)."""
    server = echo_server()
    released = asyncio.Event()
    waiting = asyncio.Event()
    order: list[str] = []

    async def point(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence >= 0:
            order.append(f"point {msg.sequence} waits")
            waiting.set()
            await asyncio.wait_for(released.wait(), T)
            order.append(f"point {msg.sequence} done")
        else:
            order.append("stop replied")

    def on_arrival(msg: JointTrajPt, session: Session) -> None:
        if msg.sequence == -4:
            order.append("stop arrived")
            released.set()

    server.handle(MsgType.JOINT_TRAJ_PT, point, on_arrival=on_arrival)  # type: ignore[arg-type]
    async with LINKS[link_kind](server) as link:
        conn = await link.connection()
        first = asyncio.create_task(conn.request(JointTrajPt(0), timeout=T))
        await asyncio.wait_for(waiting.wait(), T)  # point 0 is being handled and waits for room
        stop = await conn.request(JointTrajPt(-4), timeout=T)
        assert (await first).sequence == 0  # type: ignore[attr-defined]
        assert stop.sequence == -4  # type: ignore[attr-defined]
        assert order == ["point 0 waits", "stop arrived", "point 0 done", "stop replied"]
        await conn.close()


async def test_frames_are_logged(link_kind: str, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="simple_message")
    async with LINKS[link_kind](echo_server()) as link:
        conn = await link.connection()
        await conn.request(Ping(), timeout=T)
        await conn.close()
    text = caplog.text
    assert "connected" in text and "disconnected" in text
    assert Ping().encode(LE32).hex() in text


# -- TCP only: several clients, restarts, bad frames from raw sockets ----------------------------


@pytest.mark.parametrize(
    "bad_prefix", [0, -1, 11, 65 * 1024, 2**31 - 1], ids=["zero", "negative", "below-12", "above-max", "huge"]
)
async def test_malformed_frames_close_only_that_connection(bad_prefix: int) -> None:
    server = echo_server()
    async with tcp_link(server) as link:
        healthy = await link.connection()
        await healthy.request(Ping(), timeout=T)
        reader, writer = await link.open()
        writer.write(Ping().encode(LE32) + struct.pack("<i", bad_prefix) + bytes(32))
        frames = await read_frames(reader, 2)
        assert len(frames) == 1  # the PING before the bad prefix is answered, then EOF
        async with asyncio.timeout(T):
            assert await reader.read() == b""
        for _ in range(3):
            assert (await healthy.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
        assert len(server.sessions) == 1
        await healthy.close()


async def test_truncated_frame_then_disconnect_leaves_the_server_serving() -> None:
    """A peer that sends part of a frame and hangs up gets no reply; its session ends (and only
    it), and the other client is served throughout."""
    server = echo_server()
    ended: asyncio.Queue[Session] = asyncio.Queue()
    server.on_disconnect = ended.put_nowait
    async with tcp_link(server) as link:
        healthy = await link.connection()
        await healthy.request(Ping(), timeout=T)
        (healthy_session,) = server.sessions
        for cut in (2, 10, 30):
            reader, writer = await link.open()
            writer.write(JointTrajPt(0).encode(LE32)[:cut])
            writer.write_eof()  # the hang-up, while still reading what the server sends back
            async with asyncio.timeout(T):
                assert await reader.read() == b""  # no reply to the truncated request, then EOF
            session = await asyncio.wait_for(ended.get(), T)
            assert session is not healthy_session and session.end_reason is None
            assert server.sessions == {healthy_session}
            assert (await healthy.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
            writer.close()
        await healthy.close()


async def test_connection_limit_refuses_cleanly() -> None:
    server = echo_server(max_connections=2)
    async with tcp_link(server) as link:
        a = await link.connection()
        b = await link.connection()
        await a.request(Ping(), timeout=T)
        await b.request(Ping(), timeout=T)
        reader, _ = await link.open()
        async with asyncio.timeout(T):
            assert await reader.read() == b""  # closed at once, a clean EOF
        assert server.refused == 1
        await b.request(Ping(), timeout=T)
        await a.close()
        await b.close()


async def test_connection_limit_holds_for_clients_that_connect_at_once() -> None:
    """Connections accepted in one loop iteration count against the limit one by one."""
    server = echo_server(max_connections=2)
    async with tcp_link(server) as link:
        opened = await asyncio.gather(*(link.open() for _ in range(5)))
        ping = Ping().encode(LE32)
        answers = []
        for reader, writer in opened:
            writer.write(ping)
            async with asyncio.timeout(T):
                try:
                    answers.append(await reader.read(len(ping)))  # a PING reply, or the EOF of a refusal
                except ConnectionResetError:  # refused: the PING reached a closed socket
                    answers.append(b"")
        assert sorted(len(a) for a in answers) == [0, 0, 0, len(ping), len(ping)]
        assert server.refused == 3 and len(server.sessions) == 2
        for _, writer in opened:
            writer.close()


async def test_ipv6_loopback() -> None:
    server = echo_server()
    try:
        port = await server.serve_tcp("::1", 0)
    except OSError:
        pytest.skip("IPv6 loopback is not configured on this machine")
    try:
        conn = Connection(await open_tcp("::1", port), LE32).start()
        assert (await conn.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
        await conn.close()
    finally:
        await server.close()


@pytest.mark.slow
async def test_100_clients_each_doing_100_pings() -> None:
    server = echo_server(max_connections=128)
    async with tcp_link(server) as link:
        conns = [await link.connection() for _ in range(100)]

        async def pings(conn: Connection, n: int) -> int:
            ok = 0
            for _ in range(n):
                reply = await conn.request(Ping(), timeout=T)
                ok += reply == Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
            return ok

        async with asyncio.timeout(60):
            results = await asyncio.gather(*(pings(c, 100) for c in conns))
        assert results == [100] * 100
        for c in conns:
            await c.close()


async def test_stalled_peer_never_delays_the_others() -> None:
    """10,000 topics: a peer that never reads is cut off at the write-buffer bound; a subscriber
    that never reads loses only its oldest topics; everyone else gets everything."""
    server = echo_server(max_write_buffer=64 * 1024, socket_send_buffer=16 * 1024)
    async with tcp_link(server) as link:
        healthy = await link.connection()
        everything = healthy.subscribe(maxsize=20_000)
        never_read = healthy.subscribe(maxsize=100)
        both_connected = asyncio.Event()  # (set up first: the server may accept during the connect)
        server.on_connect = lambda session: both_connected.set() if len(server.sessions) == 2 else None
        # A peer that never reads: a small receive window, so the kernel buffers fill quickly.
        raw = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        raw.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        raw.setblocking(False)
        await asyncio.get_running_loop().sock_connect(raw, ("127.0.0.1", server_port(server)))
        _, stalled_writer = await asyncio.open_connection(sock=raw)
        await asyncio.wait_for(both_connected.wait(), T)
        sent_to_stalled = 0
        for i in range(10_000):
            topic = JointFeedback(0, 0x0E, float(i), [0.1] * 6, [0.2] * 6)
            delivered = server.broadcast(topic)
            sent_to_stalled += delivered == 2
            for session in server.sessions:
                # Bounded: at most the limit plus the one frame that crossed it.
                assert session.connection.write_buffer_size() <= server.max_write_buffer + len(topic.encode())
            await asyncio.sleep(0)
        got = [await everything.get(timeout=T) for _ in range(10_000)]
        assert [m.time for m in got] == list(range(10_000))  # type: ignore[attr-defined]
        assert everything.dropped == 0
        assert len(never_read) == 100 and never_read.dropped == 9_900
        assert [m.time for m in list(never_read._items)] == list(range(9_900, 10_000))  # type: ignore[attr-defined]
        assert sent_to_stalled < 10_000  # the stalled peer was cut off...
        assert len(server.sessions) == 1  # ...and only it
        stalled_writer.close()
        await healthy.close()


async def test_server_binds_loopback_by_default() -> None:
    server = echo_server()
    await server.serve_tcp(port=0)
    try:
        (listener,) = server._servers
        assert {s.getsockname()[0] for s in listener.sockets} == {"127.0.0.1"}
    finally:
        await server.close()


async def test_encode_frames_are_what_the_server_sends() -> None:
    """Header-only reply style (ABB) on a server configured for it."""
    server = echo_server(reply_style="header")
    async with tcp_link(server) as link:
        reader, writer = await link.open()
        writer.write(JointTrajPt(1).encode(LE32))
        (frame,) = await read_frames(reader, 1)
        assert frame == encode(HeaderOnly(11, reply_code=ReplyCode.SUCCESS), LE32)
        writer.close()


async def test_fd_transport_reports_hang_up() -> None:
    master, slave = os.openpty()
    reader, writer = await open_fd(master, name="m")
    os.close(slave)
    async with asyncio.timeout(T):
        assert await reader.read(10) == b""  # EIO on the master is the peer hanging up
    writer.close()


async def test_server_autodetects_each_connections_byte_order() -> None:
    server = Server(LE32, autodetect=True)
    server.handle(MsgType.JOINT_TRAJ_PT, lambda msg, session: None)
    async with tcp_link(server) as link:
        big = Connection(await link.open(), BE32, name="big-endian peer").start()
        little = Connection(await link.open(), LE32, name="little-endian peer").start()
        for conn in (big, little, big):
            reply = await conn.request(JointTrajPt(5, [0.5]), timeout=T)
            assert reply.sequence == 5  # type: ignore[attr-defined]
        assert sorted(s.wire.byte_order.value for s in server.sessions) == ["big", "little"]
        await big.close()
        await little.close()


async def test_pyserial_socket_url_reaches_a_tcp_server() -> None:
    """serial_for_url("socket://...") has a file descriptor: it runs on the non-blocking fd transport."""
    async with tcp_link(echo_server()) as link:
        port = server_port(link.server)
        client = Client.serial(f"socket://127.0.0.1:{port}", LE32, reconnect=None)
        async with client:
            assert (await client.request(Ping(), timeout=T)).reply_code == ReplyCode.SUCCESS
            assert (await client.request(JointTrajPt(2), timeout=T)).sequence == 2  # type: ignore[attr-defined]


@pytest.mark.skipif(not os.path.exists("/proc/net/tcp"), reason="the kernel's socket table is Linux's")
@pytest.mark.parametrize("family, host", [(socket.AF_INET, "127.0.0.1"), (socket.AF_INET6, "::1")])
def test_unread_by_peers_counts_what_a_local_peer_left_in_its_receive_queue(family: int, host: str) -> None:
    if family == socket.AF_INET6 and not socket.has_ipv6:
        pytest.skip("no IPv6")
    listener = socket.create_server((host, 0), family=family)
    with listener, socket.create_connection((host, listener.getsockname()[1]), timeout=10) as peer:
        ours, _ = listener.accept()
        with ours, socket.socket() as unconnected:
            ours.sendall(b"x" * 5000)
            assert peer.recv(3000, socket.MSG_PEEK | socket.MSG_WAITALL) == b"x" * 3000  # it arrived
            assert unread_by_peers([ours, unconnected]) == [5000, 0]
            assert len(peer.recv(3000)) == 3000
            assert unread_by_peers([ours]) == [2000]
            assert unread_by_peers([peer]) == [0]  # nothing sent the other way
