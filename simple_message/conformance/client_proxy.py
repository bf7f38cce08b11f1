"""The client suite's proxy: one connection of the client under test and its upstream twin.

For each connection the client opens on a port of the suite, :class:`ProxyLink` forwards the bytes
to the same port of the controller and back, unchanged and frame by frame (cut with the suites'
tolerant :class:`~.cutter.FrameCutter`: a frame in the other byte order is passed on as a frame,
bytes that are no frame in either order are passed on uncut). On the motion port it also plays the
controller's awkward answers: a request the suite injects a reply to (BUSY, FAILURE) is not
forwarded and is answered in the controller's place, and after the reply the drop injection names
both connections are closed. Replies keep their order (a reply answers the oldest request still
waiting, §3): an injected reply waits behind the upstream replies owed before it, and a client owed
:data:`MAX_PENDING` replies is read no further until one is sent. Every frame the client sends and
every reply that reached it is told to the suite's observer (:mod:`.client_rules`).

A client connection of a shared state port (a controller that takes one state client) has no
upstream of its own: its twin is :func:`nowhere`, and what it gets is written by the suite.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

from ..constants import CommType, MotoCommand, MotoResult, MsgType, ReplyCode
from ..errors import MalformedMessage
from ..framing import decode_or_error
from ..messages import HeaderOnly, Message, MotoMotionCtrl, MotoMotionReply
from .client_rules import LinkState, Point
from .cutter import FrameCutter

if TYPE_CHECKING:
    from .client import ClientSuite

__all__ = ["MAX_PENDING", "ProxyLink", "nowhere"]

#: the suite's logger: what the proxy logs (each injection, a forwarding that failed) is the suite's
log = logging.getLogger("simple_message.conformance.client")

#: replies owed to the client on one connection before the suite reads no more from it (a real
#: controller, too, stops reading a client that does not wait for its replies)
MAX_PENDING = 256
#: bytes read at a time
READ = 65536
#: MotoROS closes the motion connection on these, without a reply (§8.1)
_MOTO_CLOSERS = frozenset(
    {MsgType.STATUS, MsgType.JOINT_FEEDBACK, MsgType.MOTO_MOTION_REPLY, MsgType.JOINT_FEEDBACK_EX}
)


@dataclass(eq=False)
class _Slot:
    """A reply the client is owed, in order: from upstream, or injected (``reply`` already set)."""

    point: Point | None
    request: Message | MalformedMessage
    upstream: bool
    reply: Message | MalformedMessage | None = None
    frame: bytes | None = None
    drop_after: bool = False


class ProxyLink:
    """One client connection and its upstream twin, forwarded frame by frame."""

    def __init__(
        self,
        suite: ClientSuite,
        state: LinkState,
        client: tuple[asyncio.StreamReader, asyncio.StreamWriter],
        upstream: tuple[asyncio.StreamReader, asyncio.StreamWriter],
    ) -> None:
        self.suite = suite
        self.state = state
        self.client_reader, self.client_writer = client
        self.up_reader, self.up_writer = upstream
        self.slots: deque[_Slot] = deque()
        #: set when a reply owed was sent (the client side waits for it when MAX_PENDING are owed)
        self.room = asyncio.Event()
        self.dropped = False

    async def run(self) -> str:
        """Forward until one side closes; who closed it: ``client``, ``upstream`` or ``drop``."""
        loop = asyncio.get_running_loop()
        pumps = {
            loop.create_task(self._from_client(), name=f"client suite {self.state.name} client"): "client",
            loop.create_task(self._from_upstream(), name=f"client suite {self.state.name} upstream"): "upstream",
        }
        try:
            done, _ = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in pumps:
                task.cancel()
            outcomes = await asyncio.gather(*pumps, return_exceptions=True)
        for task, outcome in zip(pumps, outcomes, strict=True):
            if isinstance(outcome, Exception):
                log.error("%s: forwarding (%s) failed", self.state.name, pumps[task], exc_info=outcome)
        if self.dropped:
            return "drop"
        first = next(iter(done))
        return pumps[first]

    # client -> upstream ----------------------------------------------------------------------------

    async def _from_client(self) -> None:
        observer = self.suite.observer
        cutter = FrameCutter(self.suite.wire.byte_order)
        motion = self.state.role == "motion"
        with contextlib.suppress(OSError):
            while not self.dropped:
                data = await self.client_reader.read(READ)
                if not data:
                    return
                for frame, order in cutter.feed(data):
                    if self.closed():
                        return
                    if order is None:
                        observer.client_frame(self.state, frame, None, None)
                        self.up_writer.write(frame)
                        continue
                    wire = self.suite.wire if order is self.suite.wire.byte_order else observer.other_wire
                    msg = decode_or_error(frame, wire)
                    point = observer.client_frame(self.state, frame, order, msg)
                    if motion and order is self.suite.wire.byte_order:
                        self._request(frame, msg, point)
                    else:
                        self.up_writer.write(frame)
                await self.up_writer.drain()
                await self.client_writer.drain()
                while len(self.slots) >= MAX_PENDING and not self.closed():
                    self.room.clear()
                    await self.room.wait()

    def _answered(self, frame: bytes, msg: Message | MalformedMessage) -> bool:
        """Whether the controller owes a reply: a SERVICE_REQUEST, or for MotoROS anything but a reply and
        the types that close its motion connection (docs/reference/protocol.md §3, §8.1)."""
        _, msg_type, comm, _ = self.suite.wire.header.unpack_from(frame, 0)
        if not self.suite.profile.dialect.motion_control:
            return bool(comm == CommType.SERVICE_REQUEST)
        if comm == CommType.SERVICE_REPLY or msg_type in _MOTO_CLOSERS:
            return False
        return not (isinstance(msg, MotoMotionCtrl) and msg.command == MotoCommand.DISCONNECT)

    def _request(self, frame: bytes, msg: Message | MalformedMessage, point: Point | None) -> None:
        answered = self._answered(frame, msg)
        injection = self.suite.injection_for(point) if point is not None and answered else None
        if injection in ("busy", "failure") and isinstance(msg, Message) and point is not None:
            reply = self.suite.injected_reply(injection, msg)
            reply_frame = reply.encode(self.suite.wire)
            self._injected(injection, point, f"not forwarded, answered {_describe(reply)}")
            self.slots.append(_Slot(point, msg, upstream=False, reply=reply, frame=reply_frame))
            self._flush()
            return
        self.up_writer.write(frame)
        if answered:
            slot = _Slot(point, msg, upstream=True)
            if injection == "drop" and point is not None:
                slot.drop_after = True
                self._injected("drop", point, "forwarded; the connection is closed once its reply reached the client")
            self.slots.append(slot)

    def _injected(self, kind: str, point: Point, what: str) -> None:
        """Tell the observer (it watches the client's reaction from now on), and log the injection."""
        log.info("injected %s", self.suite.observer.injected(kind, point, what))

    # upstream -> client ----------------------------------------------------------------------------

    async def _from_upstream(self) -> None:
        cutter = FrameCutter(self.suite.wire.byte_order)
        motion = self.state.role == "motion"
        with contextlib.suppress(OSError):
            while not self.dropped:
                data = await self.up_reader.read(READ)
                if not data:
                    return
                if not motion:
                    self.client_writer.write(data)
                else:
                    for frame, order in cutter.feed(data):
                        if self.closed():
                            return
                        if order is not self.suite.wire.byte_order:
                            self.client_writer.write(frame)
                            continue
                        self._reply(frame)
                await self.client_writer.drain()

    def _reply(self, frame: bytes) -> None:
        _, _, comm, _ = self.suite.wire.header.unpack_from(frame, 0)
        slot = next((s for s in self.slots if s.upstream and s.reply is None), None)
        if comm != CommType.SERVICE_REPLY or slot is None:
            self.client_writer.write(frame)  # a topic, or a reply nothing here waits for
            return
        reply = decode_or_error(frame, self.suite.wire)
        slot.reply = reply
        slot.frame = frame
        self._flush()

    def _flush(self) -> None:
        """Send the replies owed, in order, as far as they are known."""
        while self.slots and self.slots[0].reply is not None:
            slot = self.slots.popleft()
            self.room.set()
            assert slot.frame is not None and slot.reply is not None
            self.client_writer.write(slot.frame)
            if slot.point is not None:
                self.suite.observer.reply_sent(slot.point, slot.reply, slot.frame)
            if slot.drop_after:
                self._drop()
                return

    def closed(self) -> bool:
        """The drop injection closed both connections (checked between frames of one chunk)."""
        return self.dropped

    def _drop(self) -> None:
        """The drop injection: the reply just written goes out, then both connections close."""
        self.dropped = True
        self.client_writer.close()
        self.up_writer.close()


def _describe(reply: Message) -> str:
    if isinstance(reply, MotoMotionReply):
        result = MotoResult(reply.result).name if reply.result in MotoResult._value2member_map_ else reply.result
        sub = f"/{reply.subcode}" if reply.subcode else ""
        return f"MOTO_MOTION_REPLY {result}{sub}"
    code = ReplyCode(reply.reply_code).name if reply.reply_code in ReplyCode._value2member_map_ else reply.reply_code
    body = "header-only " if isinstance(reply, HeaderOnly) else ""
    return f"{body}{reply.name} {code}"


class _Nowhere:
    """The upstream of a client connection that has none of its own (a shared state port): it
    takes what is written and never sends anything."""

    def write(self, data: bytes) -> None:
        pass

    async def drain(self) -> None:
        pass

    def close(self) -> None:
        pass

    async def wait_closed(self) -> None:
        pass

    def is_closing(self) -> bool:
        return False


def nowhere() -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return asyncio.StreamReader(), cast(asyncio.StreamWriter, _Nowhere())
