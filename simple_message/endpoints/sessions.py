"""What a server's handlers work with: one connection's session, and what a handler may return.

A :class:`Session` is one connection a :class:`~.server.Server` serves: the connection, the queue
of what arrived and waits its turn (the session's worker handles it, in order), and ``data`` for the
handlers' own per-connection state. A :data:`Handler` gets ``(message, session)`` and returns the
reply, a reply code, ``None`` for SUCCESS or :data:`NO_REPLY`; it may raise :class:`CloseConnection`
(the rules are in :mod:`.server`). What the queue holds besides messages (a handler's awaitable to
finish, a reply computed on arrival, the markers of a close and of the end of input) is here too.
"""

from __future__ import annotations

import asyncio
import enum
import functools
import logging
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from ..connection import Connection
from ..constants import CommType, ReplyCode
from ..errors import MalformedMessage
from ..messages import Message, Ping
from ..wire import BE32, LE32, WireFormat

if TYPE_CHECKING:
    from .server import Server

__all__ = [
    "Session",
    "CloseConnection",
    "NO_REPLY",
    "HandlerResult",
    "Handler",
    "MalformedHandler",
    "ArrivalHook",
]


class _NoReply(enum.Enum):
    NO_REPLY = "no reply"


#: a handler's result: send nothing, though the message is a request
NO_REPLY = _NoReply.NO_REPLY

HandlerResult = Message | ReplyCode | int | _NoReply | None
#: ``handler(message, session)``: returns the reply (see :mod:`.server`); may be async.
Handler = Callable[[Message, "Session"], HandlerResult | Awaitable[HandlerResult]]
#: ``handler(error, session)``: the reply to a request whose body does not decode, or ``None`` for
#: none; may raise :class:`CloseConnection`.
MalformedHandler = Callable[[MalformedMessage, "Session"], Message | None]
#: ``hook(message, session)``: runs synchronously as soon as a request arrives.
ArrivalHook = Callable[[Message, "Session"], None]


class CloseConnection(Exception):
    """Raised by a handler: close this connection at once, without replying."""


class Session:
    """One server-side connection and its request pipeline."""

    def __init__(self, server: Server, connection: Connection, queue_size: int) -> None:
        self.server = server
        self.connection = connection
        self.queue: asyncio.Queue[_Item] = asyncio.Queue(queue_size)
        #: True while the worker handles a message (so new ones must queue behind it).
        self.busy = False
        #: Free for handlers to keep per-connection state in.
        self.data: dict[str, Any] = {}
        self.end_reason: BaseException | None = None
        self._end_task: asyncio.Task[None] | None = None
        self._ping_wire: WireFormat | None = None
        self._ping_frame = b""
        #: the task that handles what is queued, in order
        self.worker: asyncio.Task[None] | None = None

    def arm_standing(self) -> None:
        """Let the connection answer PING itself (its standing reply: the frame of the server's own
        reply, the request neither decoded nor handed over) exactly while the server would answer a
        PING arriving now itself, at once, with that frame (the fast path of :meth:`.Server._arrived`):
        the server answers PING (no handler, no arrival hook, no fixed-size reader) and nothing of
        this session's waits to be handled before it. The connection checks the rest itself (see
        :meth:`.Connection.data_received`); called whenever one of these may have changed."""
        server = self.server
        connection = self.connection
        handler = connection.on_message  # the server's own (see Server._open), unless replaced since
        ours = isinstance(handler, functools.partial) and handler.func == server._arrived and handler.args == (self,)
        ready = (
            ours
            and server._ping_auto
            and server.reader is None
            and server.max_write_buffer >= 0  # the connection sends only with its write buffer empty
            and not self.busy
            and self.queue.empty()
        )
        connection.standing_for = handler if ready else None

    def ping_reply(self) -> bytes:
        """The frame of the server's own PING reply in this session's wire format (cached)."""
        wire = self.connection.link.wire
        if wire is not self._ping_wire:
            self._ping_frame = _PING_REPLY.encode(wire)
            self._ping_wire = wire
        return self._ping_frame

    @property
    def name(self) -> str:
        return self.connection.name

    def log(self, logger: logging.Logger, level: int, msg: str, *args: object, exc_info: bool = False) -> bool:
        """Log ``"<session name>: " + msg % args`` within this peer's log budget (at most a few lines
        per second per connection, the rest counted and summarised: :mod:`.lograte`). Use it for
        every line a peer's input causes; returns whether the line was written."""
        return self.connection.log_budget.log(logger, level, msg, *args, exc_info=exc_info)

    @property
    def wire(self) -> WireFormat:
        return self.connection.wire

    async def send(self, msg: Message) -> None:
        await self.connection.send(msg)

    def end_of_input(self, reason: BaseException | None) -> None:
        """The peer stopped sending (EOF or a frame error): answer what is queued, then close."""
        self.end_reason = reason
        self._end_task = asyncio.get_running_loop().create_task(self.queue.put(_Marker.END))

    def send_nowait(self, msg: Message) -> bool:
        return self.connection.send_nowait(msg)

    def assume_wire(self, wire: WireFormat) -> None:
        """Speak ``wire`` to a peer whose byte order is not known yet (an autodetecting session
        that has not heard a frame); once the peer has spoken, its own order stays."""
        if self.server.autodetect and not self.connection.link.detected:
            self.connection.wire = wire

    @property
    def spoke(self) -> bool:
        """The peer's byte order was detected from a frame it sent (autodetecting servers)."""
        return self.connection.link.detected


#: the server's own answer to a PING (messages are immutable: one instance serves every reply)
_PING_REPLY = Ping(comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
#: the PING request frame in each byte order, the server's reply to it in the same order and the class
#: it decodes to: the standing reply of a server's connections (PING has no reals: one frame serves
#: float32 and float64)
STANDING_PING = {Ping().encode(wire): (_PING_REPLY.encode(wire), Ping) for wire in (LE32, BE32)}


class _Later:
    """A handler's awaitable result, finished by the connection's worker in order."""

    __slots__ = ("awaitable", "msg")

    def __init__(self, msg: Message, awaitable: Awaitable[HandlerResult]) -> None:
        self.msg = msg
        self.awaitable = awaitable


class _Ready:
    """A reply computed on arrival that must wait for the write buffer (sent by the worker)."""

    __slots__ = ("reply",)

    def __init__(self, reply: Message) -> None:
        self.reply = reply


class _Marker(enum.Enum):
    #: what the handler's CloseConnection turns into on the way to the worker
    CLOSE = "close"
    #: queued after the last message of a connection whose input ended
    END = "end"


_Item = Message | MalformedMessage | _Later | _Ready | _Marker
