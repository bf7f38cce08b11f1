"""What a connection receives: bytes from its transport, acted on in arrival order.

The connection is its transport's asyncio protocol, and :class:`Inbound` is its reading side. What
arrives is fed to the link (:class:`~..link.Link`) in the transport's own callback and the link's
events are acted on there, with no task and no stream buffer in between: a message that is not a
reply goes to the connection's message handler and to its subscriptions, a reply to the request it
answers (:mod:`.requests`).

* Before the connection starts, what arrives is kept (and reading paused) and acted on by
  :meth:`Inbound.start`.
* A message handler may return an awaitable (back-pressure, e.g. a server whose request queue is
  full): reading pauses until it is done, and the messages after it wait in the link, in order.
* With a ``frame_timeout``, a peer that begins a frame and sends nothing more for that long is
  closed with :class:`~..errors.IncompleteFrame`; the clock does not run while we are the ones who
  stopped reading.
* When reading ends (EOF, a frame error, a lost transport, a failed handler), the connection closes,
  or its ``on_read_end`` is told (a server that still answers what it read, then closes).
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
import time
from collections.abc import Awaitable
from typing import TYPE_CHECKING

from ..errors import IncompleteFrame
from ..link import NEED_DATA, Answered, Ended, LateReply, Malformed, Received, StrayReply, Unanswerable
from ..messages import Message
from .requests import Requests
from .subscriptions import Subscribers
from .taps import TapPoint

if TYPE_CHECKING:
    from . import Connection

__all__ = ["Inbound", "hung_up"]

#: the connection's logger (its name is what the log lines have always shown)
log = logging.getLogger("simple_message.connection")


class Inbound:
    """The reading side of one connection (see the module docstring). Each call is given the
    connection, whose ``link``, handlers (``on_message``, ``on_read_end``) and ``frame_timeout`` it
    reads as they are then, and which it closes with :meth:`.Connection.abort`; it keeps no
    reference to it, so that a finished connection is freed by reference counting, with no cycle
    left for the garbage collector."""

    __slots__ = (
        "autodetect",
        "awaited",
        "blocked",
        "done",
        "early",
        "early_end",
        "input_over",
        "lost_reason",
        "partial_timer",
        "reading",
        "requests",
        "resume_task",
        "subscribers",
        "tap",
    )

    def __init__(
        self,
        requests: Requests,
        subscribers: Subscribers,
        tap: TapPoint,
        *,
        autodetect: bool,
        early: bytes = b"",
        end: tuple[BaseException | None] | None = None,
    ) -> None:
        self.requests = requests
        self.subscribers = subscribers
        self.tap = tap
        #: the byte order is detected from the peer's first frame (logged once detected)
        self.autodetect = autodetect
        #: bytes and the end of input that arrived before start(), acted on by start()
        self.early: list[bytes] | None = [early] if early else []
        self.early_end = end
        #: a handler's awaitable is pending: events wait in the link, reading is paused
        self.blocked = False
        self.resume_task: asyncio.Task[None] | None = None
        self.awaited: Awaitable[None] | None = None
        #: the transport is asked to read (not paused by us)
        self.reading = True
        #: reading is over
        self.done = False
        #: why the transport was lost (the reason of the link's end)
        self.lost_reason: BaseException | None = None
        #: the incomplete-frame clock (``frame_timeout``)
        self.partial_timer: asyncio.TimerHandle | None = None
        #: the peer's input ended (EOF, lost transport) before this end closed (for the tap)
        self.input_over = False

    def start(self, connection: Connection) -> None:
        """Act on what arrived before the connection started (unless it is closed), and read on."""
        early, self.early = self.early, None
        end, self.early_end = self.early_end, None
        if connection.closed:
            return
        for data in early or ():
            self.data_received(connection, data)
        if end is not None:
            self.input_ended(connection, end[0])
        elif not self.reading and not self.blocked and not self.done:
            self.set_reading(connection, True)

    def data_received(self, connection: Connection, data: bytes) -> None:
        link = connection.link
        if self.done or link.ended or connection.closed:
            return  # reading is over (what is still in flight from a thread or a memory pair)
        if self.early is not None:  # not started: keep it, and stop reading until start()
            self.early.append(data)
            self.set_reading(connection, False)
            return
        if self.tap.tap is not None:
            self.tap.data(False, data)
        # One whole frame received, with nothing before it, comes back from the link as its message
        # (the commonest read: a request, a topic); anything else is queued as events. A handler's
        # awaitable pending: everything waits in the link, in order.
        detected = link.detected if self.autodetect else True
        if self.blocked:
            msg = None
            link.receive_data(data)
        else:
            msg = link.receive_one(data)
        if not detected and link.detected:
            log.info("%s: detected %s byte order", connection.name, link.wire.byte_order.value)
        frame_timeout = connection.frame_timeout
        if frame_timeout is not None:
            connection.last_input = time.monotonic()
        if msg is not None:
            # what process() does with the link's one Received event (the link holds nothing more)
            try:
                on_message = connection.on_message
                result = None if on_message is None else on_message(msg)
                if result is not None:
                    self.wait_for(connection, result, msg)
                else:
                    subscribers = self.subscribers
                    if subscribers.subscriptions or subscribers.inbox is not None:
                        subscribers.deliver(msg)
            except Exception as exc:  # a bug in a handler must not leave the peer hanging
                log.exception("%s: reader failed", connection.name)
                self.read_ended(connection, exc)
            if self.partial_timer is not None and connection.frame_timeout is not None:
                self.watch_partial(connection)  # nothing is held: the clock stops
            return
        if not self.blocked:
            self.process(connection)
        if connection.frame_timeout is not None and (link.buffered or self.partial_timer is not None):
            self.watch_partial(connection)  # new bytes: the peer gets a fresh frame_timeout for its frame

    def transport_lost(self, connection: Connection, reason: BaseException | None) -> None:
        """The transport is gone (``reason``: its error, if any): no more bytes will come."""
        self.lost_reason = reason
        self.input_ended(connection, reason)

    def input_ended(self, connection: Connection, reason: BaseException | None) -> None:
        """No more bytes will come (EOF, or the transport is gone): the link ends after what it holds."""
        self.input_over = True
        if self.early is not None:
            if self.early_end is None:
                self.early_end = (reason,)
            return
        link = connection.link
        if link.ended:
            return
        if reason is not None:
            self.lost_reason = reason
        link.receive_data(b"")
        if not self.blocked:
            self.process(connection)

    def set_reading(self, connection: Connection, on: bool) -> None:
        if on == self.reading:
            return
        self.reading = on
        transport = connection.transport
        if transport.is_closing():
            return
        with contextlib.suppress(NotImplementedError, RuntimeError):
            transport.resume_reading() if on else transport.pause_reading()

    def process(self, connection: Connection) -> None:
        """Act on the link's events, in order, until it needs data, the input ended, a handler's
        awaitable must be waited for, or the connection closed."""
        link = connection.link
        try:
            while True:
                event = link.next_event()
                if event is NEED_DATA:
                    return
                if isinstance(event, Received):
                    msg = event.message
                    on_message = connection.on_message
                    if on_message is not None:
                        result = on_message(msg)
                        if result is not None:
                            self.wait_for(connection, result, msg)
                            return
                    self.subscribers.deliver(msg)
                elif isinstance(event, Answered):
                    self.requests.answered(event)
                elif isinstance(event, Unanswerable):
                    self.requests.unanswerable(event, connection.name)
                elif isinstance(event, Malformed):
                    if connection.on_message is not None:
                        result = connection.on_message(event.error)
                        if result is not None:
                            self.wait_for(connection, result, None)
                            return
                    else:
                        log.warning("%s: dropped malformed message: %s", connection.name, event.error)
                elif isinstance(event, LateReply):
                    log.info("%s: late reply to an abandoned request consumed: %s", connection.name, event.reply.name)
                elif isinstance(event, StrayReply):
                    stray = event.reply.name if event.reply else event.error
                    log.debug("%s: stray reply ignored: %s", connection.name, stray)
                else:
                    assert isinstance(event, Ended)
                    self.read_ended(connection, event.error or self.lost_reason)
                    return
                if connection.closed:
                    return
        except Exception as exc:  # a bug in a handler must not leave the peer hanging
            log.exception("%s: reader failed", connection.name)
            self.read_ended(connection, exc)

    def wait_for(self, connection: Connection, awaitable: Awaitable[None], msg: Message | None) -> None:
        """A handler's back-pressure: stop reading until ``awaitable`` is done, then go on."""
        if connection.closed:  # the handler closed the connection: nothing is waited for any more
            if inspect.iscoroutine(awaitable):
                awaitable.close()
            return
        self.blocked = True
        self.set_reading(connection, False)
        self.awaited = awaitable
        self.resume_task = asyncio.get_running_loop().create_task(
            self.resume(connection, awaitable, msg), name=f"sm-wait {connection.name}"
        )

    async def resume(self, connection: Connection, awaitable: Awaitable[None], msg: Message | None) -> None:
        try:
            await awaitable
        except asyncio.CancelledError:
            self.blocked = False
            connection.abort(None)
            return
        except Exception as exc:
            self.blocked = False
            log.exception("%s: reader failed", connection.name)
            self.read_ended(connection, exc)
            return
        self.blocked = False
        self.resume_task = None
        self.awaited = None
        if connection.closed:
            return
        if msg is not None:
            self.subscribers.deliver(msg)
        self.process(connection)
        if connection.frame_timeout is not None and (connection.link.buffered > 0) != (self.partial_timer is not None):
            self.watch_partial(connection)  # the backlog is decoded down to a frame begun: its clock starts now
        if not (self.blocked or self.done or connection.closed):
            self.set_reading(connection, True)

    def read_ended(self, connection: Connection, reason: BaseException | None) -> None:
        """Reading is over (EOF, a frame error, a lost transport, a failed handler)."""
        if self.done:
            return
        self.done = True
        self.set_reading(connection, False)
        if connection.closed:
            return
        on_read_end = connection.on_read_end
        if on_read_end is not None:
            if reason is not None:
                level = logging.INFO if hung_up(reason) else logging.WARNING
                log.log(level, "%s: %s; answering what was read, then closing", connection.name, reason)
            on_read_end(reason)
        else:
            connection.abort(reason)

    def watch_partial(self, connection: Connection) -> None:
        """(Re)start the incomplete-frame timer while a frame is incomplete; stop it between frames."""
        timer = self.partial_timer
        if timer is not None:
            timer.cancel()
            self.partial_timer = None
        if connection.link.buffered and connection.frame_timeout is not None and not connection.closed:
            loop = asyncio.get_running_loop()
            self.partial_timer = loop.call_later(connection.frame_timeout, self.partial_expired, connection)

    def partial_expired(self, connection: Connection) -> None:
        self.partial_timer = None
        if self.blocked or not self.reading:  # we stopped reading it: the peer is not to blame
            self.watch_partial(connection)
            return
        buffered = connection.link.buffered
        if buffered and connection.frame_timeout is not None and not connection.closed:
            connection.abort(IncompleteFrame(buffered, connection.frame_timeout))

    def stop(self) -> None:
        """The connection closed: the clock stops, and a handler's awaitable is no longer waited for."""
        if self.partial_timer is not None:
            self.partial_timer.cancel()
            self.partial_timer = None
        task = self.resume_task
        if task is not None and task is not asyncio.current_task():
            task.cancel()
            awaited = self.awaited
            if inspect.iscoroutine(awaited) and inspect.getcoroutinestate(awaited) == inspect.CORO_CREATED:
                awaited.close()  # the task never started: nobody will await it


def hung_up(reason: BaseException) -> bool:
    """The peer went away (normal life of a connection, not a warning)."""
    return isinstance(reason, BrokenPipeError | ConnectionResetError)
