"""The simple_message server: handlers per message type, over any number of links.

:class:`Server` is what every emulated controller port is built on. Per connection it reads in
arrival order and answers every SERVICE_REQUEST exactly once, in order (docs/reference/protocol.md §11 item
4), whatever the handler does:

* handlers are registered per message type: ``server.handle(MsgType.JOINT_TRAJ_PT, fn)``. A handler
  gets ``(message, session)`` and may be sync or async; for a request it returns the reply message,
  a :class:`~..constants.ReplyCode` (replied in the server's ``reply_style``, a
  :class:`~..dialects.ReplyStyle`: ``ECHO`` like the C++ library, header-only like ABB, §3; the
  dialects whose replies are messages of their own, Fanuc's and MotoROS's, have their handlers
  return those and get header-only otherwise), or ``None`` for SUCCESS;
* ``on_arrival`` hooks run synchronously the moment a request is read, before queued requests are
  handled: a STOP must act at once even while an earlier point waits for queue space (§10 pitfall 5);
* PING is answered SUCCESS with an empty body unless a handler (or an arrival hook) is registered
  (or the server has a ``reader``: every read goes to the handlers);
  with nothing queued ahead of it, that reply is a cached frame written in the same callback that
  read the request (a PING behind a slow request still waits its turn);
* an unknown SERVICE_REQUEST gets a header-only FAILURE (or what ``unknown_request`` returns, e.g.
  the MotoROS 2002 INVALID/3003 reply); unknown TOPICs and stray SERVICE_REPLYs are ignored (debug);
* a request with a malformed body (or none where its type has one) or an invalid header (§1.2) is
  answered FAILURE, or what ``malformed_request`` returns (MotoROS's INVALID/3001); with
  ``answer_topics``, malformed TOPICs go to ``malformed_request`` too;
* a handler that raises is answered FAILURE and logged; the server goes on;
* a handler may raise :class:`CloseConnection` to close the connection without a reply (MotoROS
  does so for DISCONNECT and for message types its motion port refuses, §8.1), or return
  :data:`NO_REPLY` to leave a request unanswered (a controller that answers only some requests);
* ``answer_topics``: TOPICs of unknown type go to ``unknown_request`` too (MotoROS answers every
  message that is not a SERVICE_REPLY, §3);
* a frame error (bad length prefix) closes only that connection;
* at most ``max_connections`` connections per server: excess ones are accepted and closed at once,
  with a log line, so the peer sees a clean EOF rather than a hang; or, with ``excess="wait"``, they
  wait unserved (not read, not written) until a connection ends, as in the listen backlog of a
  controller that accepts its next client only when the last one has gone (:mod:`..backlog`; at
  most ``MAX_WAITING`` of them; more are closed); :meth:`Server.reset_backlog` closes those
  waiting (a controller that closes its listening socket and opens a new one);
* writes are bounded per connection (:class:`~..connection.Connection`), so a stalled peer is closed
  and never delays the others. :meth:`Server.broadcast` publishes a topic to every connection: encoded
  once per wire format, and what one loop iteration broadcasts is written in one go per connection
  (``batch_topics``; without it each message is written the moment it is broadcast, in its own
  write, as a controller that sends each message with its own call does);
* ``reader``: connections cut their input as a controller that reads fixed byte counts does
  (:class:`~..fixed_reads.FixedReads`, one per connection), every read going to the handlers
  (``validate_headers`` False skips the C++ header rules: such controllers check nothing);
  ``write_split``: each frame is written in these pieces, one write each.

An accepted TCP socket gets its :class:`~..connection.Connection` as its asyncio protocol before it
reads a byte (no streams); serial, pty and other links come as stream pairs (:meth:`Server.serve_link`)
whose transport the connection takes over. Each connection is a :class:`~.sessions.Session`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import inspect
import logging
import socket
import time
from collections.abc import Awaitable, Callable, Iterable, Sequence
from typing import Any, Literal

from ..backlog import MAX_WAITING, Backlog, Waiting
from ..connection import Connection, Tap
from ..constants import CommType, MsgType, ReplyCode
from ..dialects import ReplyStyle, reply_style_of
from ..errors import ConnectionClosed, HeaderError, MalformedMessage
from ..fixed_reads import FixedReads
from ..framing import DEFAULT_MAX_LENGTH
from ..header import header_error
from ..lograte import LogBudget
from ..messages import HeaderOnly, Message, Ping
from ..transport import StreamPair, open_fd, open_serial, unread_by_peers
from ..wire import DEFAULT_FORMAT, WireFormat
from .sessions import (
    _PING_REPLY,
    NO_REPLY,
    STANDING_PING,
    ArrivalHook,
    CloseConnection,
    Handler,
    HandlerResult,
    MalformedHandler,
    Session,
    _Item,
    _Later,
    _Marker,
    _Ready,
)

__all__ = ["Server", "DEFAULT_FRAME_TIMEOUT", "DEFAULT_IDLE_AFTER"]

#: the endpoints' logger (its name is what the log lines have always shown)
log = logging.getLogger("simple_message.endpoints")

#: a server closes a connection that began a frame and sent nothing more for this long (s)
DEFAULT_FRAME_TIMEOUT = 5.0
#: a full server may close a connection silent this long (s) to serve a newcomer
DEFAULT_IDLE_AFTER = 10.0
#: unread bytes that mark a peer that does not read (far above a state round in flight: 4 s of the
#: emulator's default state stream)
_DEAF_BYTES = 16 * 1024
#: how long a full port trusts its last look at what its peers left unread (s)
_UNREAD_SCAN_AGE = 1.0


class Server:
    """A simple_message server: handlers per message type over any number of links."""

    def __init__(
        self,
        wire: WireFormat = DEFAULT_FORMAT,
        *,
        name: str = "server",
        autodetect: bool = False,
        reply_style: ReplyStyle | str = ReplyStyle.ECHO,
        max_connections: int = 16,
        max_length: int = DEFAULT_MAX_LENGTH,
        request_queue: int = 64,
        drain_timeout: float = 2.0,
        max_write_buffer: int = 256 * 1024,
        unknown_request: Handler | None = None,
        malformed_request: MalformedHandler | None = None,
        answer_topics: bool = False,
        socket_send_buffer: int | None = None,
        frame_timeout: float | None = DEFAULT_FRAME_TIMEOUT,
        idle_after: float | None = DEFAULT_IDLE_AFTER,
        tap: Tap | None = None,
        batch_topics: bool = True,
        reader: Callable[[WireFormat], FixedReads] | None = None,
        write_split: Callable[[bytes], Sequence[bytes]] | None = None,
        validate_headers: bool = True,
        excess: Literal["close", "wait"] = "close",
    ) -> None:
        self.wire = wire
        #: topics broadcast in one loop iteration go out in one write per connection (else one
        #: write per message, at once)
        self.batch_topics = batch_topics
        #: makes each connection's frame cutter (None: the length prefix)
        self.reader = reader
        #: cuts each frame into the pieces written one by one (None: one write)
        self.write_split = write_split
        #: refuse requests whose header breaks the C++ rules (header.header_error)
        self.validate_headers = validate_headers
        if excess not in ("close", "wait"):
            raise ValueError(f"excess must be 'close' or 'wait', not {excess!r}")
        #: what a connection beyond ``max_connections`` gets: closed at once, or a wait for its turn
        self.excess = excess
        #: sees the traffic of every connection accepted from now on (:class:`~.connection.Tap`,
        #: e.g. a :class:`~.capture.CaptureWriter`)
        self.tap = tap
        #: a connection that begins a frame and sends nothing more for this long (s) is closed
        #: (sockets only: a serial link, which cannot be dialled again, is never closed for that)
        self.frame_timeout = frame_timeout
        #: a full server may close a connection silent this long (s) to serve a newcomer (``None``:
        #: never for silence: a state port, whose clients only listen)
        self.idle_after = idle_after
        #: SO_SNDBUF for accepted sockets (``None``: the kernel's autotuning, up to megabytes).
        #: A small value makes a stalled peer show up in our own bounded buffer sooner.
        self.socket_send_buffer = socket_send_buffer
        self.name = name
        self.autodetect = autodetect
        self.reply_style = reply_style_of(reply_style)
        self.max_connections = max_connections
        self.max_length = max_length
        self.request_queue = request_queue
        self.drain_timeout = drain_timeout
        self.max_write_buffer = max_write_buffer
        self.unknown_request = unknown_request
        self.malformed_request = malformed_request
        self.answer_topics = answer_topics
        self.sessions: set[Session] = set()
        self._handlers: dict[int, Handler] = {}
        self._arrival: dict[int, ArrivalHook] = {}
        self._servers: list[asyncio.base_events.Server] = []
        self._tasks: set[asyncio.Task[None]] = set()
        #: one task per accepted TCP connection, serving it until it closes
        self._accepted: set[asyncio.Task[None]] = set()
        #: connections with broadcast frames queued, written at the end of the loop iteration
        self._queued: set[Connection] = set()
        self._flush_scheduled = False
        self._closing = False
        #: Called with each new and each ended session (e.g. to start publishing state).
        self.on_connect: Callable[[Session], None] | None = None
        self.on_disconnect: Callable[[Session], None] | None = None
        self.refused = 0
        #: connections closed to make room for newcomers
        self.evicted = 0
        #: the lines refused and evicted connections cause (one budget for the port)
        self._log_budget = LogBudget(name)
        #: connections waiting for their turn (``excess="wait"``), oldest first
        self._waiting = Backlog(name, self._log_budget)
        #: (when, unread bytes by session) of the last look a full port took (``_make_room``)
        self._unread_scan: tuple[float, dict[Session, int]] = (-_UNREAD_SCAN_AGE, {})
        #: PING is answered by the server itself (no handler, no arrival hook): the fast path
        self._ping_auto = True
        #: called once before a message's arrival hook and handler run (before the hook, or before the
        #: handler of a message without one, or of one queued behind others: again when it is
        #: handled), e.g. an application's periodic work that must not wait behind a burst of
        #: requests handled one after another
        self.before_handler: Callable[[], None] | None = None

    # -- configuration -----------------------------------------------------------------------------

    def handle(self, msg_type: int, handler: Handler, *, on_arrival: ArrivalHook | None = None) -> None:
        """Register ``handler`` for ``msg_type`` (requests and topics alike)."""
        self._handlers[msg_type] = handler
        if on_arrival is not None:
            self._arrival[msg_type] = on_arrival
        self._ping_auto = _PING not in self._handlers and _PING not in self._arrival
        for session in self.sessions:
            session.arm_standing()

    # -- serving -----------------------------------------------------------------------------------

    async def serve_tcp(self, host: str | None = "127.0.0.1", port: int = 0, *, reuse_address: bool = True) -> int:
        """Listen on ``host:port`` (127.0.0.1 unless told otherwise; ``::1`` for IPv6; port 0 picks
        a free port) and return the bound port."""
        loop = asyncio.get_running_loop()
        server = await loop.create_server(lambda: _Accepted(self), host, port, reuse_address=reuse_address)
        self._servers.append(server)
        bound = server.sockets[0].getsockname()[1]
        for sock in server.sockets:
            log.info("%s: listening on %s", self.name, _addr(sock))
        return int(bound)

    def _accept(self, transport: asyncio.BaseTransport) -> None:
        """A TCP connection was accepted: serve it (its connection becomes the transport's protocol
        before any byte is read), or close it at once if the server is full or closing."""
        sock = transport.get_extra_info("socket")
        if self.socket_send_buffer is not None and sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.socket_send_buffer)
        peer = transport.get_extra_info("peername")
        live = sum(1 for s in self.sessions if not s.connection.closed)  # not those closing meanwhile
        if not self._closing and live >= self.max_connections and self.excess == "wait":
            self._wait_turn(transport, peer)
            return
        if self._closing or (live >= self.max_connections and not self._make_room(peer)):
            self.refused += 1
            self._log_budget.log(
                log, logging.WARNING, "refused %s: %d connections is the limit", peer, self.max_connections
            )
            transport.close()
            return
        self._serve_accepted(transport, peer)

    def _serve_accepted(self, transport: asyncio.BaseTransport, peer: object, waited: Waiting | None = None) -> None:
        # The session is counted at once: connections accepted in the same loop iteration see it.
        connection = self._connection(transport, f"{self.name} {peer}")
        if waited is not None:  # what the peer sent while it waited comes first
            for data in waited.data:
                connection.data_received(data)
            if waited.ended:
                connection.eof_received()
        session = self._open(connection, None)
        if waited is not None:
            waited.resume()
        task = asyncio.get_running_loop().create_task(self._until_closed(session), name=f"sm-serve {session.name}")
        self._accepted.add(task)
        task.add_done_callback(self._accepted.discard)

    def _wait_turn(self, transport: asyncio.BaseTransport, peer: object) -> None:
        """A connection beyond the limit of a server whose excess waits: not read, not answered,
        until a connection ends (:meth:`_next_turn`); beyond ``MAX_WAITING`` it is closed."""
        if not self._waiting.add(transport, peer, self.max_connections):
            self.refused += 1
            self._log_budget.log(log, logging.WARNING, "refused %s: %d connections wait already", peer, MAX_WAITING)
            transport.close()

    def _next_turn(self) -> None:
        """A connection ended: serve the oldest waiting one still open, if there is room."""
        while self._waiting and not self._closing:
            if sum(1 for s in self.sessions if not s.connection.closed) >= self.max_connections:
                return
            waiting = self._waiting.next_open()
            if waiting is None:
                return
            transport = waiting.transport
            peer = transport.get_extra_info("peername")
            log.info("%s: serving %s, which waited for its turn", self.name, peer)
            self._serve_accepted(transport, peer, waiting)

    def reset_backlog(self, why: str) -> int:
        """Close every connection waiting for its turn (``excess="wait"``), as a controller that
        closes its listening socket and opens a new one resets the old one's backlog: only a
        connect made after that is served. Logged with ``why``; returns how many were closed."""
        dropped = self._waiting.drop()
        if dropped:
            self._log_budget.log(log, logging.WARNING, "%d waiting connection(s) closed: %s", dropped, why)
        return dropped

    def _make_room(self, newcomer: object) -> bool:
        """The server is full and ``newcomer`` knocks: close the connection least likely to be a
        live client, if there is one, so idle sockets can never lock real clients out. In order:
        one holding an incomplete frame; one whose peer does not read what it is sent; unless
        ``idle_after`` is ``None`` (a port whose clients only listen, such as a state port), the
        one silent longest, if for at least ``idle_after`` s. Returns whether room was made."""
        now = time.monotonic()
        candidates = [s for s in self.sessions if not s.connection.closed and s.connection.is_socket]
        victim: Session | None = None
        reason = ""
        partial = [s for s in candidates if s.connection.link.buffered]
        if partial:
            victim = min(partial, key=lambda s: s.connection.last_input)
            reason = "held an incomplete frame"
        if victim is None:
            in_socket = self._unread_in_sockets(candidates, now)
            unread = [s.connection.write_buffer_size() + n for s, n in zip(candidates, in_socket, strict=True)]
            deaf = [(n, s) for n, s in zip(unread, candidates, strict=True) if n >= _DEAF_BYTES]
            if deaf:
                most, victim = max(deaf, key=lambda pair: pair[0])
                reason = f"did not read ({most} bytes unread)"
        idle_after = self.idle_after
        if victim is None and idle_after is not None:
            silent = [s for s in candidates if now - s.connection.last_input >= idle_after]
            if silent:
                victim = min(silent, key=lambda s: s.connection.last_input)
                reason = f"was silent for {now - victim.connection.last_input:.0f} s"
        if victim is None:
            return False
        self.evicted += 1
        self._log_budget.log(
            log,
            logging.WARNING,
            "full (%d connections): closed %s (%s) for %s",
            len(self.sessions),
            victim.name,
            reason,
            newcomer,
        )
        victim.connection.abort(ConnectionClosed(f"closed to make room for a new connection: it {reason}"))
        return True

    def _unread_in_sockets(self, sessions: list[Session], now: float) -> list[int]:
        """What each session's sockets hold unread by its peer (:func:`.transport.unread_by_peers`:
        one read of the kernel's socket table for all of them), looked up at most once per
        ``_UNREAD_SCAN_AGE`` s: the table grows with every socket on the machine, and a flood of
        newcomers to a full port must not make the event loop read it for each one."""
        taken, scan = self._unread_scan
        if now - taken >= _UNREAD_SCAN_AGE:
            socks = [s.connection.transport.get_extra_info("socket") for s in sessions]
            scan = dict(zip(sessions, unread_by_peers(socks), strict=True))
            self._unread_scan = (now, scan)
        return [scan.get(s, 0) for s in sessions]  # a session newer than the look: nothing unread yet

    async def serve_link(
        self, streams: StreamPair, name: str | None = None, data: dict[str, Any] | None = None
    ) -> None:
        """Serve one link (an accepted socket, a serial port) until it closes. ``data`` starts the
        session's :attr:`Session.data` (e.g. to mark a serial link that also carries state)."""
        connection = self._connection(streams, name or f"{self.name} {streams[1].get_extra_info('peername')}")
        if self._closing:
            await connection.close()
            return
        await self._until_closed(self._open(connection, data))

    def _connection(self, streams: StreamPair | asyncio.BaseTransport, name: str) -> Connection:
        connection = Connection(
            streams,
            self.wire,
            autodetect=self.autodetect,
            max_length=self.max_length,
            name=name,
            drain_timeout=self.drain_timeout,
            max_write_buffer=self.max_write_buffer,
            frame_timeout=self.frame_timeout,
            tap=self.tap,
            accepted=True,
            reader=None if self.reader is None else self.reader(self.wire),
            write_split=self.write_split,
        )
        if not connection.is_socket:
            # a serial line cannot be dialled again: a byte of line noise must not end it
            connection.frame_timeout = None
        return connection

    def _open(self, connection: Connection, data: dict[str, Any] | None) -> Session:
        """A new session on ``connection``, counted, with its worker, and reading."""
        session = Session(self, connection, self.request_queue)
        if data:
            session.data.update(data)
        connection.on_message = functools.partial(self._arrived, session)
        connection.on_read_end = session.end_of_input
        # A PING the server answers itself (see _arrived) is answered by the connection, the frame
        # neither decoded nor handed over, while nothing of the session's is queued before it.
        connection.link.standing.update(STANDING_PING)
        self.sessions.add(session)
        session.worker = asyncio.get_running_loop().create_task(self._work(session), name=f"sm-work {connection.name}")
        if self.on_connect is not None:
            self.on_connect(session)
        connection.start()
        session.arm_standing()
        return session

    async def _until_closed(self, session: Session) -> None:
        """Serve ``session`` until its connection closes, then end it."""
        connection = session.connection
        worker = session.worker
        assert worker is not None
        try:
            await connection.wait_closed()
        finally:
            worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await worker
            self.sessions.discard(session)
            await connection.close()
            if self.on_disconnect is not None:
                self.on_disconnect(session)
            if self._waiting:
                self._next_turn()
            # The session and its connection refer to each other through these: unlinked, they are
            # freed as soon as the last reference goes, not by a later garbage collection (which,
            # with connections coming and going, let memory pile up between collections).
            connection.on_message = None
            connection.on_read_end = None
            connection.standing_for = None
            session.worker = None

    async def serve_serial(self, url: str, *, data: dict[str, Any] | None = None, **serial_options: Any) -> None:
        """Serve one serial link (pyserial URL) until it closes."""
        await self.serve_link(await open_serial(url, **serial_options), name=f"{self.name} {url}", data=data)

    async def serve_fd(self, fd: int, *, name: str = "fd", data: dict[str, Any] | None = None) -> None:
        """Serve one link over an open file descriptor (e.g. a pty master)."""
        await self.serve_link(await open_fd(fd, name=name), name=f"{self.name} {name}", data=data)

    def start_serving(self, coro: Awaitable[None]) -> asyncio.Task[None]:
        """Run a ``serve_*`` coroutine in the background, owned (and closed) by this server."""
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    def broadcast(self, msg: Message, sessions: Iterable[Session] | None = None) -> int:
        """Send a topic to every connection (or to ``sessions``) without waiting, encoded once per
        wire format; returns how many open connections it was queued for.

        The frames are written at the end of this loop iteration, one write per connection for
        all the topics broadcast meanwhile (a state round of two or three topics costs one system
        call per client, not one per topic); anything sent on a connection before then goes out
        after what was queued for it. A peer found more than ``max_write_buffer`` bytes behind at
        that write is closed (:meth:`.Connection.flush`).
        """
        frames: dict[WireFormat, bytes] = {}
        last_wire: WireFormat | None = None
        frame = b""
        sent = 0
        queued = self._queued
        batch = self.batch_topics
        for session in list(self.sessions if sessions is None else sessions):
            connection = session.connection
            wire = connection.link.wire
            if wire is not last_wire:  # sessions mostly share one WireFormat instance
                last_wire = wire
                got = frames.get(wire)
                frame = frames[wire] = msg.encode(wire) if got is None else got
            if not batch:
                sent += connection.send_frame_nowait(frame)
            elif connection.queue_frame(frame):
                sent += 1
                queued.add(connection)
        if queued and not self._flush_scheduled:
            self._flush_scheduled = True
            asyncio.get_running_loop().call_soon(self._flush_queued)
        return sent

    def _flush_queued(self) -> None:
        self._flush_scheduled = False
        queued, self._queued = self._queued, set()
        for connection in queued:
            connection.flush()

    async def close(self) -> None:
        """Stop listening and close every connection."""
        self._closing = True
        for server in self._servers:
            server.close()
        self._waiting.drop()
        for session in list(self.sessions):
            await session.connection.close()
        if self._accepted:  # each finishes its session (on_disconnect) once its connection is closed
            _, late = await asyncio.wait(list(self._accepted), timeout=2.0)
            for task in late:
                task.cancel()
        for server in self._servers:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 2.0)
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        self._servers.clear()
        self._log_budget.flush()  # what refused and evicted connections left unsaid
        self._unread_scan = (-_UNREAD_SCAN_AGE, {})

    async def __aenter__(self) -> Server:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # -- per-connection pipeline ---------------------------------------------------------------

    def _arrived(self, session: Session, msg: Message | MalformedMessage) -> Awaitable[None] | None:
        if (
            msg.__class__ is Ping
            and self._ping_auto
            and msg.comm_type == _SERVICE_REQUEST
            and msg.reply_code == _INVALID
            and not session.busy
            and session.queue.empty()
        ):
            # The fast path of the commonest request: a PING the server answers itself, with nothing
            # ahead of it (so the reply keeps its place in the order); its reply frame is cached.
            connection = session.connection
            if connection.transport.get_write_buffer_size() <= self.max_write_buffer:
                connection.send_frame_nowait(session.ping_reply())
                return None
        caught_up = False  # before_handler ran for this message (its arrival hook's)
        if isinstance(msg, Message) and msg.comm_type == _SERVICE_REQUEST:
            hook = self._arrival.get(msg.msg_type)
            if hook is not None and (
                not self.validate_headers or _header_error(msg.msg_type, msg.comm_type, msg.reply_code) is None
            ):
                self._before_handler()
                caught_up = True
                try:
                    hook(msg, session)
                except Exception:
                    session.log(log, logging.ERROR, "on_arrival hook for %s failed", msg.name, exc_info=True)
        item: _Item = msg
        if not session.busy and session.queue.empty():
            # Nothing is ahead of this message: handle it now, without a hop through the worker.
            # Order holds, and a synchronous handler's reply goes out in this very loop iteration.
            out = self._dispatch_now(session, msg, caught_up=caught_up)
            if out is None:
                return None
            if out is _Marker.CLOSE:
                log.info("%s: closed by the server", session.name)
                session.connection.abort()
                return None
            if isinstance(out, Message) and session.connection.write_buffer_size() <= self.max_write_buffer:
                with contextlib.suppress(ConnectionClosed):
                    session.connection.send_nowait(out)
                return None
            item = out if isinstance(out, _Later) else _Ready(out)
        session.connection.standing_for = None  # something waits now: PINGs take their turn behind it
        try:
            session.queue.put_nowait(item)
        except asyncio.QueueFull:
            return session.queue.put(item)  # back-pressure: stop reading until there is room
        return None

    async def _work(self, session: Session) -> None:
        while True:
            item = await session.queue.get()
            if item is _Marker.END:
                session.connection.abort(session.end_reason)
                return
            session.busy = True
            try:
                reply = await self._dispatch(session, item)
                if reply is not None:
                    await session.connection.send(reply)
            except ConnectionClosed:
                return
            except CloseConnection:
                log.info("%s: closed by the server", session.name)
                session.connection.abort()
                return
            finally:
                session.busy = False
                session.arm_standing()

    async def _dispatch(self, session: Session, item: _Item) -> Message | None:
        if isinstance(item, _Ready):
            return item.reply
        if isinstance(item, _Marker):
            raise CloseConnection if item is _Marker.CLOSE else AssertionError(item)
        out = item if isinstance(item, _Later) else self._dispatch_now(session, item)
        if out is _Marker.CLOSE:
            raise CloseConnection
        if not isinstance(out, _Later):
            return out
        try:
            result = await out.awaitable
        except CloseConnection:
            raise
        except Exception:
            return self._handler_failed(session, out.msg)
        return self._finish(out.msg, result)

    def _dispatch_now(
        self, session: Session, msg: Message | MalformedMessage, *, caught_up: bool = False
    ) -> Message | _Later | Literal[_Marker.CLOSE] | None:
        """Everything up to the handler's result: the reply, nothing, or an awaitable to finish
        (``caught_up``: :attr:`before_handler` ran for this message a moment ago, before its arrival
        hook, and is not called again)."""
        is_request = msg.comm_type == _SERVICE_REQUEST
        if isinstance(msg, MalformedMessage):
            session.log(log, logging.WARNING, "malformed message: %s", msg)
            if self.malformed_request is not None and (is_request or self.answer_topics):
                try:
                    return self.malformed_request(msg, session)
                except CloseConnection:
                    return _Marker.CLOSE
                except Exception:
                    session.log(log, logging.ERROR, "the malformed-request handler failed; FAILURE", exc_info=True)
            return HeaderOnly(msg.msg_type or 0, reply_code=ReplyCode.FAILURE) if is_request else None
        msg_type = msg.msg_type
        problem = _header_error(msg_type, msg.comm_type, msg.reply_code) if self.validate_headers else None
        if problem is not None:
            session.log(log, logging.WARNING, "%s", problem)
            return HeaderOnly(msg_type, reply_code=ReplyCode.FAILURE) if is_request else None
        handler = self._handlers.get(msg_type)
        if handler is None:
            if msg_type == _PING and self.reader is None:  # a fixed-size reader's reads are the handlers' alone
                return _PING_REPLY if is_request else None
            if not is_request and not (self.answer_topics and self.unknown_request is not None):
                session.log(log, logging.DEBUG, "ignored %s comm_type %s", msg.name, msg.comm_type)
                return None
            if self.unknown_request is None:
                session.log(log, logging.INFO, "no handler for request type %s; FAILURE", msg.msg_type)
                return HeaderOnly(msg.msg_type, reply_code=ReplyCode.FAILURE)
            handler = self.unknown_request
        if not caught_up:
            self._before_handler()
        try:
            result = handler(msg, session)
        except CloseConnection:
            return _Marker.CLOSE
        except Exception:
            return self._handler_failed(session, msg)
        if result is not None and not isinstance(result, Message | int) and inspect.isawaitable(result):
            return _Later(msg, result)
        return self._finish(msg, result)

    def _before_handler(self) -> None:
        before = self.before_handler
        if before is not None:
            try:
                before()
            except Exception:  # the application's defect: logged once, dropped; the request is handled
                self.before_handler = None
                log.exception("%s: the before_handler hook failed (no longer called)", self.name)

    def _handler_failed(self, session: Session, msg: Message) -> Message | None:
        session.log(log, logging.ERROR, "handler for %s failed; answering FAILURE", msg.name, exc_info=True)
        if msg.comm_type == CommType.SERVICE_REQUEST:
            return HeaderOnly(msg.msg_type, reply_code=ReplyCode.FAILURE)
        return None

    def _finish(self, msg: Message, result: HandlerResult) -> Message | None:
        """Turn a handler's result into the reply (see the module docstring)."""
        if isinstance(result, Message):
            return result
        if msg.comm_type != _SERVICE_REQUEST or result is NO_REPLY:
            return None
        code = _SUCCESS if result is None else ReplyCode(result)
        if self.reply_style is _ECHO:
            return msg.to_reply(code)
        return HeaderOnly(msg.msg_type, reply_code=code)


_PING = int(MsgType.PING)
_SERVICE_REQUEST = int(CommType.SERVICE_REQUEST)
_INVALID = int(ReplyCode.INVALID)
_SUCCESS = ReplyCode.SUCCESS
_ECHO = ReplyStyle.ECHO
#: headers known to pass the C++ validation rules (the few a peer sends), looked up, not recomputed
_VALID_HEADERS: set[tuple[int, int, int]] = set()
_VALID_HEADERS_MAX = 1024


def _header_error(msg_type: int, comm_type: int, reply_code: int) -> HeaderError | None:
    """:func:`~.header.header_error`, remembered for valid headers only: a peer's invalid ones are
    garbage, computed again each time rather than kept (kept, a flood of random headers would pin
    a thousand exceptions in memory for the life of the server)."""
    key = (msg_type, comm_type, reply_code)
    if key in _VALID_HEADERS:
        return None
    problem = header_error(msg_type, comm_type, reply_code)
    if problem is None and len(_VALID_HEADERS) < _VALID_HEADERS_MAX:
        _VALID_HEADERS.add(key)
    return problem


class _Accepted(asyncio.Protocol):
    """The protocol an accepted TCP socket starts with: it hands the transport to the server, whose
    :class:`~.connection.Connection` becomes its protocol at once (or closes it)."""

    def __init__(self, server: Server) -> None:
        self.server = server

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.server._accept(transport)


def _addr(sock: socket.socket) -> str:
    name = sock.getsockname()
    return f"[{name[0]}]:{name[1]}" if sock.family == socket.AF_INET6 else f"{name[0]}:{name[1]}"
