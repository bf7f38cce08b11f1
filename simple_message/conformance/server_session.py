"""The server suite's connections to the server under test, and what they tell of the robot.

A :class:`Session` holds the suite's links to the server: the state link (opened first: the server
speaks first there, and its first frames tell the byte order and float size the suite then speaks
too), the motion link (opened anew after the malformed frames' connections: a controller takes one
motion client, §6) and the IO link. Every request goes through :meth:`Session.exchange`: send it,
take the next frame as its reply (replies carry no request id, §3).

Its :class:`RobotView` is what the state link says of the robot now: where the joints are, the
latest STATUS, whether the state port is still sending (the PC's 1 s watchdog, §5), whether a
STATUS said in_motion, and a wait for a condition on them. The probes (:mod:`.server_probes`) and
the motion rules (:mod:`.server_motion`) know the server through these two.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..constants import MotoCommand, SpecialSeq, TriState
from ..messages import JointTrajPt, Message, MotoMotionCtrl, Ping, Status
from ..wire import ByteOrder, WireFormat
from .expectations import EXPECTATIONS
from .links import ProbeLink, Seen
from .report import Verdict
from .server_checks import STILL, _joints_of, _real_size, _Verdict

if TYPE_CHECKING:
    from .server import ServerSuiteOptions

__all__ = ["RobotView", "Session"]

#: a one-client server that resets a new motion link does so this soon after it connects (s)
_RESET_WINDOW = 0.3
#: how often the suite connects anew when its new motion link is reset
_REOPENS = 3


class RobotView:
    """What the state link says of the robot (nothing while there is no state link)."""

    def __init__(self) -> None:
        self.link: ProbeLink | None = None
        #: a STATUS said in_motion TRUE (reset before each move)
        self.saw_in_motion = False
        self._event = asyncio.Event()

    def on_frame(self, seen: Seen) -> None:
        """Each frame the state link receives."""
        if isinstance(seen.message, Status) and seen.message.in_motion == TriState.TRUE:
            self.saw_in_motion = True
        self._event.set()

    def seen(self, until: float | None = None) -> list[Seen]:
        """The state frames received (up to ``time.monotonic()`` ``until``)."""
        if self.link is None:
            return []
        return [f for f in self.link.frames if until is None or f.time <= until]

    def joints(self) -> tuple[float, ...] | None:
        for seen in reversed(self.seen()):
            joints = _joints_of(seen.message)
            if joints is not None:
                return joints
        return None

    def status(self) -> Status | None:
        for seen in reversed(self.seen()):
            if isinstance(seen.message, Status):
                return seen.message
        return None

    def status_since(self, since: float) -> Status | None:
        """The latest STATUS received at ``time.monotonic()`` ``since`` or later, if any."""
        for seen in reversed(self.seen()):
            if seen.time < since:
                return None
            if isinstance(seen.message, Status):
                return seen.message
        return None

    def moved_since(self, before: tuple[float, ...] | None) -> str:
        """The joints that moved since ``before`` (empty when none did, or it cannot be told)."""
        now = self.joints()
        if before is None or now is None:
            return ""
        moved = [(k, b, n) for k, (b, n) in enumerate(zip(before, now, strict=True)) if abs(n - b) > STILL]
        return ", ".join(f"joint {k + 1} {b:.5f} -> {n:.5f}" for k, b, n in moved)

    def fresh(self, within: float = 1.0) -> bool:
        """Whether the state port is connected and sent a frame in the last ``within`` seconds (the
        PC's watchdog, §5): what the suite knows of the robot is then current."""
        state = self.link
        if state is None or not state.alive or not state.frames:
            return False
        return time.monotonic() - state.frames[-1].time <= within

    async def witness(self, count_before: int) -> bool:
        """Whether the state port sent a frame after ``count_before`` of them (waiting up to the 1 s
        the PC's watchdog allows, §5)."""
        state = self.link
        if state is None:
            return True
        return await self.wait(lambda j, s: len(state.frames) > count_before, 1.0)

    async def wait(self, check: Callable[[tuple[float, ...], Status | None], bool], timeout: float) -> bool:
        """Whether ``check(joints, status)`` came true within ``timeout`` (checked at each state frame)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            joints = self.joints()
            if joints is not None and check(joints, self.status()):
                return True
            remaining = deadline - loop.time()
            if remaining <= 0 or self.link is None or not self.link.alive:
                return False
            self._event.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._event.wait(), remaining)


class Session:
    """The suite's links to the server at ``options.host``, and the wire format it speaks."""

    def __init__(self, options: ServerSuiteOptions) -> None:
        self.options = options
        self.expect = EXPECTATIONS[options.profile]
        self.dialect = self.expect.dialect
        #: the wire format the suite speaks (decided from the server's first frames), and the one
        #: the server was found speaking (None: it sent nothing to tell)
        self.wire: WireFormat | None = None
        self.detected: WireFormat | None = None
        self.state: ProbeLink | None = None
        self.motion: ProbeLink | None = None
        self.links: list[ProbeLink] = []  # links whose frames the framing rules judge
        self.robot = RobotView()

    @property
    def real(self) -> int:
        """The real size frames are shown in."""
        return self.wire.real_size if self.wire else 4

    async def connect(self, role: str, port: int) -> _Verdict:
        """Open the ``role`` link (the verdict of its ``connect.*`` rule)."""
        o = self.options
        link = ProbeLink(role, None, self.robot.on_frame if role == "state" else None)
        try:
            await link.open(o.host, port, o.reply_timeout)
        except (OSError, TimeoutError) as exc:
            return _Verdict(Verdict.FAIL, f"{o.host}:{port}: {exc or 'timed out'}")
        if role == "state":
            self.state = link
            self.robot.link = link
        elif role == "motion":
            self.motion = link
        self.links.append(link)
        return _Verdict(Verdict.PASS, f"{o.host}:{port} accepted")

    async def decide_wire(self) -> None:
        """Byte order and float size as the server speaks them: the order from the state port's
        first frame (the server speaks first there), the float size from its first joint state
        (a STATUS has no reals); else the options', else the profile's. What the server speaks is
        what the suite speaks to it: a server in another order than ``--byte-order`` FAILs
        ``framing.byte-order`` once, and every other rule still judges it."""
        o = self.options
        order: ByteOrder | None = None
        size: int | None = None
        if self.state is not None:
            loop = asyncio.get_running_loop()
            deadline = loop.time() + max(o.reply_timeout, 1.5)
            while size is None:
                seen = await self.state.next_frame(max(0.0, deadline - loop.time()))
                if seen is None:
                    break
                order = order or seen.order
                size = _real_size(seen)
        if order is not None:
            self.detected = WireFormat(order, size or (o.float_size or self.dialect.wire.real_size))
        else:
            order = ByteOrder(o.byte_order) if o.byte_order else self.dialect.wire.byte_order
        size = size or o.float_size or self.dialect.wire.real_size
        self.wire = WireFormat(order, size)
        for link in self.links:
            link.set_wire(self.wire)

    def liveness(self) -> Message:
        """A request every profile's motion port answers and that cannot move the robot."""
        return Ping() if self.expect.ping else self.stop_message()

    def stop_message(self) -> Message:
        if self.dialect.motion_control:
            return MotoMotionCtrl(0, 0, MotoCommand.STOP_MOTION)
        return JointTrajPt(SpecialSeq.STOP_TRAJECTORY)

    async def exchange(
        self, link: ProbeLink, message: Message, timeout: float | None = None, *, keep: bool = False
    ) -> tuple[Seen, Seen | None]:
        """Send ``message`` and take the next frame as its reply, within ``timeout`` (default the
        reply timeout). Frames received before it are forgotten first, unless ``keep``: an extra
        reply already waiting is then what comes back."""
        if not keep:
            link.skip_pending()
        sent = link.send_message(message)
        reply = await link.next_frame(self.options.reply_timeout if timeout is None else timeout)
        return sent, reply

    def answers(self, request: Message, reply: Seen | None) -> bool:
        """Whether ``reply`` is the server's answer to ``request`` (in its profile's reply style)."""
        return reply is not None and reply.message is not None and self.dialect.answers(request.msg_type, reply.message)

    async def reopen_motion(self) -> None:
        """A fresh motion link: a controller takes one motion client, and each new connection of the
        malformed-frame rule replaced (or was refused beside) the suite's own (§6 connection limits).
        Against a one-client server the old link is closed first: it leaves a second connect waiting
        in its backlog, and ABB's resets that backlog when its client goes; a new link reset within
        ``_RESET_WINDOW`` is opened again (at most ``_REOPENS`` times)."""
        if self.motion is None or self.wire is None:
            return
        if not self.expect.one_client:  # the new link first: a server that takes over keeps serving
            link = ProbeLink("motion", self.wire)
            try:
                await link.open(self.options.host, self.options.ports["motion"], self.options.reply_timeout)
            except (OSError, TimeoutError):
                return
            await self.motion.close()
            self.motion = link
            self.links.append(link)
            return
        await self.motion.close()
        for _ in range(_REOPENS):
            link = ProbeLink("motion", self.wire)
            try:
                await link.open(self.options.host, self.options.ports["motion"], self.options.reply_timeout)
            except (OSError, TimeoutError):
                return
            self.links.append(link)
            self.motion = link
            if not await link.wait_closed(_RESET_WINDOW):
                return
            await link.close()

    async def close(self) -> None:
        """Close every link."""
        for link in self.links + [lk for lk in (self.state, self.motion) if lk is not None]:
            await link.close()
