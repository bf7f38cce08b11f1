"""Replay the client side of a captured session against a controller, and compare the replies.

A capture (:mod:`.capture`) holds both sides of each TCP connection. :func:`exchanges` takes what
the *client* sent, in capture order over every connection (the motion, state and IO ports), each
request with the reply the controller gave then; :func:`replay` sends the same frames to another
controller (or the emulator) and :func:`compare` checks each reply against the captured one **by
kind**: message type, comm type and reply code, and for a MotoROS MOTO_MOTION_REPLY its result and
subcode. Values (positions, times) are not compared: two controllers do not move identically.

**Which side is the client.** The side that sent the SYN when the capture has it; else the side
whose peer's port is a controller's well-known one (a registered dialect's: 11000, 11002, 50240...),
else the side with the higher port number (a client's port is ephemeral).

**BUSY.** A MotoROS client repeats a point the controller answered BUSY (result 1) until it is
taken; when the controller takes it depends on how fast the robot moves, which differs between
two controllers. Consecutive identical requests answered BUSY are one exchange here: it is sent
again while the target answers BUSY (every 2 ms, at most ``busy_timeout``), and the exchange
matches when the final replies match; the BUSY replies are counted, not compared.

**Joint values.** A captured trajectory starts where the captured robot stood. ``remap`` moves
every JOINT_TRAJ_PT, JOINT_TRAJ_PT_FULL and JOINT_TRAJ_PT_FULL_EX point by the difference between
the target robot's position (its first joint state on the state port) and the capture's first
point, and clears the slots beyond the target's joints (the FS100 capture is of a 7-axis arm).

**Versions.** MotoROS before 1.9 answered CHECK_MOTION_READY FALSE with subcode 0; 1.9 (and the
emulator) gives the reason as the subcode. A captured 0 there matches any reason (the table says so).

**Timing.** As fast as the protocol allows (each request once the previous one is answered), or,
with ``keep_timing``, each request no earlier than its capture time after the first one.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import time
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

from .capture import CaptureEvent, captured_messages
from .constants import CommType, MotoCommand, MotoResult, ReplyCode
from .dialects import DIALECTS, any_dialect_answers
from .errors import SimpleMessageError
from .framing import FrameDecoder, detect_byte_order
from .messages import (
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotoMotionReply,
    decode,
    encode,
    type_name,
)
from .wire import WireFormat

__all__ = [
    "Captured",
    "Exchange",
    "Outcome",
    "ReplayError",
    "exchanges",
    "from_capture",
    "server_ports",
    "replay",
    "kind",
    "format_table",
]

log = logging.getLogger(__name__)

Address = tuple[str, int]
#: how often a request answered BUSY is sent again (s)
BUSY_RETRY = 0.002


class ReplayError(SimpleMessageError):
    """A capture that cannot be replayed, or a target that cannot be reached."""


@dataclass(frozen=True)
class Captured:
    """One frame of a capture: when, from where, to where, its bytes and what it decodes to."""

    time: float
    src: Address
    dst: Address
    frame: bytes
    message: Message
    #: the side that opened the connection, when the capture shows its SYN
    client: Address | None = None


@dataclass(frozen=True)
class Exchange:
    """What the client sent once (a request, or a topic), and the captured reply to it."""

    index: int
    time: float
    #: the controller's port it went to (in the capture)
    port: int
    frame: bytes
    message: Message
    #: the controller's reply in the capture (None: a topic, or a request the capture shows unanswered)
    expected: Message | None
    #: how many times the client repeated it after a BUSY reply, in the capture
    busy: int = 0


@dataclass
class Outcome:
    """An exchange replayed: the target's reply (None: none in time) and whether it matches."""

    exchange: Exchange
    reply: Message | None
    busy: int = 0
    match: bool = False
    note: str = ""


def kind(msg: Message | None) -> tuple[int, ...] | None:
    """What replies are compared by: type, comm type, reply code, and a MOTO_MOTION_REPLY's result and subcode."""
    if msg is None:
        return None
    base = (int(msg.msg_type), int(msg.comm_type), int(msg.reply_code))
    if isinstance(msg, MotoMotionReply):
        return (*base, int(msg.result), int(msg.subcode))
    return base


def _busy(msg: Message | None) -> bool:
    return isinstance(msg, MotoMotionReply) and msg.result == MotoResult.BUSY


def exchanges(frames: Iterable[Captured]) -> list[Exchange]:
    """The client's side of a capture as exchanges (see the module doc), in capture order."""
    items = sorted(frames, key=lambda c: c.time)
    out: list[Exchange] = []
    waiting: dict[tuple[Address, Address], int] = {}  # (client, server) -> index in out awaiting a reply
    known = _well_known()
    for item in items:
        client, server = _sides(item, known)
        from_client = item.src == client
        key = (client, server)
        if from_client:
            if item.message.comm_type == CommType.SERVICE_REPLY:
                continue  # a client answering the controller (never seen in practice): not replayed
            last = next((e for e in reversed(out) if e.port == server[1]), None)
            if last is not None and last.frame == item.frame and _busy(last.expected):
                out[last.index] = dataclasses.replace(last, busy=last.busy + 1, expected=None)
                waiting[key] = last.index
                continue
            exchange = Exchange(len(out), item.time, server[1], item.frame, item.message, None)
            out.append(exchange)
            if item.message.comm_type == CommType.SERVICE_REQUEST:
                waiting[key] = exchange.index
            else:
                waiting.pop(key, None)
        elif item.message.comm_type == CommType.SERVICE_REPLY and key in waiting:
            k = waiting.pop(key)
            out[k] = dataclasses.replace(out[k], expected=item.message)
    return out


def from_capture(
    path: str, wire: WireFormat, auto: bool, *, ports: Collection[int] | None = None
) -> tuple[list[Captured], WireFormat, list[str]]:
    """The frames of a pcap/pcapng capture (:mod:`.capture`) as :class:`Captured`, the wire format
    they were spoken in (the byte order detected from the first frame when ``auto``) and what the
    capture could not give (gaps, undecodable frames), as lines for the user."""
    items: list[Captured] = []
    problems: list[str] = []
    for item in captured_messages(path, wire, auto, ports=ports):
        if isinstance(item, CaptureEvent):
            problems.append(f"{item.kind.value}: {item.message}")
        elif item.message is None:
            problems.append(f"{type(item.error).__name__}: {item.error}")
        else:
            items.append(Captured(item.time, item.src, item.dst, item.frame, item.message, item.client))
    if auto and items:
        wire = WireFormat(detect_byte_order(items[0].frame[:4]), wire.real_size)
    return items, wire, problems


def server_ports(items: Iterable[Captured]) -> list[int]:
    """The controller's ports in the capture (the server side of each connection), ascending."""
    known = _well_known()
    return sorted({_sides(item, known)[1][1] for item in items})


def _well_known() -> set[int]:
    """The ports the registered dialects' controllers listen on."""
    return {port for d in DIALECTS.values() for port in d.ports.values()}


def _sides(item: Captured, known: set[int]) -> tuple[Address, Address]:
    """(client, server) of the connection ``item`` was on."""
    if item.client is not None:
        return (item.src, item.dst) if item.client == item.src else (item.dst, item.src)
    if (item.dst[1] in known) != (item.src[1] in known):
        return (item.src, item.dst) if item.dst[1] in known else (item.dst, item.src)
    return (item.src, item.dst) if item.src[1] > item.dst[1] else (item.dst, item.src)


@dataclass
class _TargetConnection:
    """One connection to the target: its reader feeds replies to a queue, keeps the joint state."""

    reader: asyncio.StreamReader
    writer: asyncio.StreamWriter
    wire: WireFormat
    replies: asyncio.Queue[Message] = field(default_factory=asyncio.Queue)
    position: tuple[float, ...] | None = None
    state_seen: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    #: why the connection is over (None: it is not): the target closed it, or sent what cannot be framed
    ended: str | None = None
    #: wakes a wait for a reply when the connection ends
    changed: asyncio.Event = field(default_factory=asyncio.Event)

    async def read(self) -> None:
        decoder = FrameDecoder(self.wire.byte_order)
        try:
            while data := await self.reader.read(65536):
                decoder.feed(data)
                while (frame := decoder.next_frame()) is not None:
                    self._received(frame)
            self.ended = "the target closed the connection"
        except SimpleMessageError as exc:  # a length prefix no frame has: wrong byte order?
            self.ended = f"the target's bytes cannot be framed ({exc}): is the byte order right?"
        except (OSError, ConnectionError) as exc:
            self.ended = f"the connection failed: {exc}"
        self.changed.set()

    def _received(self, frame: bytes) -> None:
        try:
            msg = decode(frame, self.wire)
        except SimpleMessageError as exc:
            log.warning("the target sent a frame that does not decode: %s", exc)
            return
        if msg.comm_type == CommType.SERVICE_REPLY:
            self.replies.put_nowait(msg)
            self.changed.set()
        elif isinstance(msg, JointFeedback | JointPosition) and self.position is None:
            values = msg.positions if isinstance(msg, JointFeedback) else msg.joint_data
            self.position = tuple(values)
            self.state_seen.set()

    async def reply_to(self, request: Message, timeout: float) -> Message | None:
        """The next reply that answers ``request`` (its type by any dialect's rule, and its sequence
        where both have one); replies that do not (late ones, replies to topics) are dropped.
        None: none in time, or the connection ended (:attr:`ended` says why)."""
        deadline = time.monotonic() + timeout
        while True:
            while not self.replies.empty():
                reply = self.replies.get_nowait()
                if _answers(request, reply):
                    return reply
                log.info("a reply that answers nothing asked now dropped: %s", reply.name)
            if self.ended is not None or time.monotonic() >= deadline:
                return None
            self.changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.changed.wait(), max(deadline - time.monotonic(), 0.0))


async def replay(
    items: Sequence[Exchange],
    host: str,
    ports: dict[int, int],
    wire: WireFormat,
    *,
    keep_timing: bool = False,
    remap: int | None = None,
    reply_timeout: float = 5.0,
    busy_timeout: float = 30.0,
) -> list[Outcome]:
    """Send ``items`` to the controller at ``host`` (capture port -> target port: ``ports``) and
    return one :class:`Outcome` each (see the module doc; ``remap``: the target's joint count,
    to move the trajectory to where the target stands)."""
    connections: dict[int, _TargetConnection] = {}
    try:
        for captured_port in sorted(ports):
            try:
                reader, writer = await asyncio.wait_for(asyncio.open_connection(host, ports[captured_port]), 5.0)
            except (OSError, TimeoutError) as exc:
                raise ReplayError(f"cannot connect to {host}:{ports[captured_port]}: {exc}") from None
            connection = _TargetConnection(reader, writer, wire)
            connection.task = asyncio.get_running_loop().create_task(connection.read())
            connections[captured_port] = connection
        shift = await _shift(items, connections, remap) if remap is not None else None
        outcomes: list[Outcome] = []
        started = time.monotonic()
        first = items[0].time if items else 0.0
        for exchange in items:
            if keep_timing:
                delay = exchange.time - first - (time.monotonic() - started)
                if delay > 0:
                    await asyncio.sleep(delay)
            connection = connections[exchange.port]
            outcomes.append(
                await _one(exchange, connection, shift, remap, reply_timeout=reply_timeout, busy_timeout=busy_timeout)
            )
        return outcomes
    finally:
        for connection in connections.values():
            connection.writer.close()
            if connection.task is not None:
                connection.task.cancel()
                with contextlib.suppress(asyncio.CancelledError, OSError, ConnectionError):
                    await connection.task
            with contextlib.suppress(OSError, ConnectionError, TimeoutError):
                await asyncio.wait_for(connection.writer.wait_closed(), 2.0)


async def _shift(items: Sequence[Exchange], connections: dict[int, _TargetConnection], joints: int) -> list[float]:
    """How far to move the captured points: the target's position minus the capture's first point."""
    first = next((_positions(e.message) for e in items if _positions(e.message) is not None), None)
    if first is None:
        return [0.0] * joints
    waits = [asyncio.ensure_future(connection.state_seen.wait()) for connection in connections.values()]
    try:
        await asyncio.wait(waits, timeout=5.0, return_when=asyncio.FIRST_COMPLETED)  # any connection's first state
    finally:
        for wait in waits:
            wait.cancel()
    for connection in connections.values():
        if connection.position is not None:
            here = connection.position
            return [here[j] - first[j] for j in range(min(joints, len(here), len(first)))] + [0.0] * max(
                0, joints - min(len(here), len(first))
            )
    raise ReplayError("no joint state from the target to remap the trajectory to (is a state port in the capture?)")


def _answers(request: Message, reply: Message) -> bool:
    """Whether ``reply`` answers ``request``: its type by any registered dialect's rule (the echo,
    MotoROS's MOTO_MOTION_REPLY, Fanuc's JOINT_POSITION), and the same sequence where both have one."""
    if not any_dialect_answers(request.msg_type, reply):
        return False
    asked, answered = getattr(request, "sequence", None), getattr(reply, "sequence", None)
    return asked is None or answered is None or asked == answered


def _positions(msg: Message) -> tuple[float, ...] | None:
    if isinstance(msg, JointTrajPt):
        return tuple(msg.joint_data)
    if isinstance(msg, JointTrajPtFull):
        return tuple(msg.positions)
    if isinstance(msg, JointTrajPtFullEx) and msg.groups:
        return tuple(msg.groups[0].positions)
    return None


def _moved(msg: Message, shift: list[float], joints: int) -> Message:
    """``msg`` with its positions moved by ``shift`` and the slots beyond ``joints`` cleared."""

    def move(values: Sequence[float]) -> tuple[float, ...]:
        return tuple(v + shift[j] if j < joints else 0.0 for j, v in enumerate(values))

    def clear(values: Sequence[float]) -> tuple[float, ...]:
        return tuple(v if j < joints else 0.0 for j, v in enumerate(values))

    if isinstance(msg, JointTrajPt):
        return dataclasses.replace(msg, joint_data=move(msg.joint_data))
    if isinstance(msg, JointTrajPtFull):
        return dataclasses.replace(
            msg, positions=move(msg.positions), velocities=clear(msg.velocities), accelerations=clear(msg.accelerations)
        )
    if isinstance(msg, JointTrajPtFullEx):
        groups = tuple(
            dataclasses.replace(
                g, positions=move(g.positions), velocities=clear(g.velocities), accelerations=clear(g.accelerations)
            )
            for g in msg.groups
        )
        return dataclasses.replace(msg, groups=groups)
    return msg


async def _one(
    exchange: Exchange,
    connection: _TargetConnection,
    shift: list[float] | None,
    joints: int | None,
    *,
    reply_timeout: float,
    busy_timeout: float,
) -> Outcome:
    frame = exchange.frame
    if shift is not None and joints is not None and _positions(exchange.message) is not None:
        frame = encode(_moved(exchange.message, shift, joints), connection.wire)
    outcome = Outcome(exchange, None)
    is_request = exchange.message.comm_type == CommType.SERVICE_REQUEST
    deadline = time.monotonic() + busy_timeout
    while True:
        if connection.ended is not None:
            outcome.note = connection.ended
            return outcome
        try:
            connection.writer.write(frame)
            await connection.writer.drain()
        except (OSError, ConnectionError) as exc:
            outcome.note = f"cannot send: {exc}"
            return outcome
        if not is_request:
            outcome.match = True
            outcome.note = "topic: no reply expected"
            return outcome
        reply = await connection.reply_to(exchange.message, reply_timeout)
        if reply is None:
            outcome.note = connection.ended or f"no reply within {reply_timeout:g} s"
            return outcome
        if _busy(reply) and not _busy(exchange.expected) and time.monotonic() < deadline:
            outcome.busy += 1
            await asyncio.sleep(BUSY_RETRY)
            continue
        outcome.reply = reply
        break
    expected = exchange.expected
    if expected is None:
        outcome.match = True
        outcome.note = "the capture shows no reply"
    else:
        outcome.match = kind(reply) == kind(expected)
        if not outcome.match and _older_not_ready(expected, reply):
            outcome.match = True
            outcome.note = "MotoROS before 1.9 sent no subcode with CHECK_MOTION_READY FALSE"
        if not outcome.match:
            outcome.note = f"expected {_describe(expected)}"
    return outcome


def _older_not_ready(expected: Message, reply: Message) -> bool:
    """A CHECK_MOTION_READY answered FALSE with subcode 0 (MotoROS before 1.9, which did not say
    why: the FS100 capture) against the same FALSE with the reason (MotoROS 1.9 and the emulator)."""
    return (
        isinstance(expected, MotoMotionReply)
        and isinstance(reply, MotoMotionReply)
        and expected.command == reply.command == MotoCommand.CHECK_MOTION_READY
        and expected.result == reply.result == MotoResult.FALSE
        and expected.subcode == 0
        and kind(expected)[:3] == kind(reply)[:3]  # type: ignore[index]
    )


def _describe(msg: Message | None) -> str:
    if msg is None:
        return "nothing"
    text = f"{_name(msg.msg_type)} comm {msg.comm_type} reply {msg.reply_code}"
    if isinstance(msg, MotoMotionReply):
        text += f" result {msg.result}/{msg.subcode}"
    return text


def format_table(outcomes: Sequence[Outcome]) -> str:
    """One line per exchange, then the summary."""
    header = f"{'#':<5} {'time (s)':>9}  {'port':<5}  {'request':<40} {'captured reply':<40} "
    header += f"{'replayed reply':<40} busy  match"
    lines = [header]
    first = outcomes[0].exchange.time if outcomes else 0.0
    for o in outcomes:
        e = o.exchange
        request = _name(e.message.msg_type)
        sequence = getattr(e.message, "sequence", None)
        if sequence is not None:
            request += f" seq {sequence}"
        command = getattr(e.message, "command", None)
        if command is not None:
            request += f" {_enum_name(MotoCommand, command)}"
        verdict = ("yes" + (f" ({o.note})" if o.note else "")) if o.match else "NO: " + o.note
        lines.append(
            f"{e.index:<5} {e.time - first:9.3f}  {e.port:<5}  {request:<40} {_short(e.expected):<40} "
            f"{_short(o.reply):<40} {o.busy:>4}  {verdict}"
        )
    matched = sum(o.match for o in outcomes)
    tail = "" if matched == len(outcomes) else " (mismatches above)"
    lines.append(f"{matched} of {len(outcomes)} exchanges match{tail}")
    return "\n".join(lines)


def _name(msg_type: int) -> str:
    return type_name(msg_type) or str(msg_type)


def _short(msg: Message | None) -> str:
    k = kind(msg)
    if msg is None or k is None:
        return "-"
    text = f"{_name(msg.msg_type)} {_enum_name(ReplyCode, msg.reply_code)}"
    if isinstance(msg, MotoMotionReply):
        text += f" {_enum_name(MotoResult, msg.result)}/{msg.subcode}"
    return text


def _enum_name(enum: type[IntEnum], value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return str(value)
