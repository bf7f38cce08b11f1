"""The server suite: probe a running simple_message server (a controller, real or emulated) and
judge it by the rules the real peers follow.

It connects to the server's state port first and listens (the server speaks first there: byte
order and float size are detected from its frames), then asks the motion port what can be asked
without moving anything (PING, requests of a type nobody assigns, a burst of requests, the
reference library's list of malformed frames), and watches the state topics throughout. Only with
``allow_motion`` does it send trajectory points, and only after STATUS says the robot is idle, in
AUTO and not in error.

This module holds the options and the runner: the connections, the byte order and float size
detected, the order the rules run in, and the requests that cannot move anything. The rest is
composed from:

* :mod:`.expectations`: what a profile's real servers do differently (which port answers a
  PING, how an unknown type is answered, which topics the state port sends at what rate),
  :data:`EXPECTATIONS`, from the project's protocol notes (simple-message.md §3, §5, §8), and
  every rule with its source, :data:`SERVER_RULES` (the rules and their sources are listed in
  docs/conformance.md);
* :mod:`.server_checks`: the passive checks of what the server sends on its own, the state topics
  and the framing;
* :mod:`.server_motion`: the motion rules (a mixin of :class:`ServerSuite`): a small move, a move
  stopped, a point beyond the joints' range, MotoROS's trajectory mode, BUSY and start position;
  every move followed by one back to where the robot was.

The names in ``__all__`` are importable from here.
"""

from __future__ import annotations

import asyncio
import contextlib
import fnmatch
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass

from ..constants import (
    CommType,
    InvalidSubcode,
    MotoCommand,
    MotoResult,
    MsgType,
    ReplyCode,
    SpecialSeq,
    TriState,
)
from ..dialects import ReplyStyle
from ..messages import (
    JointTrajPt,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Ping,
    RawMessage,
    Status,
    message_class,
)
from ..wire import ByteOrder, WireFormat
from .expectations import EXPECTATIONS, SERVER_RULES, Expectations
from .links import Link, Seen
from .malformed import malformed_cases
from .report import Evidence, Report, RuleResult, Verdict
from .server_checks import (
    STILL,
    _joints_of,
    _real_size,
    _Skip,
    _Verdict,
    framing_body,
    framing_byte_order,
    framing_float_size,
    framing_length,
    reply_comm_types,
    state_consistency,
    state_joint_state,
    state_rate,
    state_status,
    state_topics,
)
from .server_motion import _Abort, _MotionRules

__all__ = ["ServerSuiteOptions", "ServerSuite", "Expectations", "EXPECTATIONS", "SERVER_RULES", "run_server_suite"]

log = logging.getLogger(__name__)

#: a one-client server that resets a new motion link does so this soon after it connects (s)
_RESET_WINDOW = 0.3
#: how often the suite connects anew when its new motion link is reset
_REOPENS = 3


@dataclass(frozen=True)
class ServerSuiteOptions:
    """Where the server is and what may be done to it."""

    host: str = "127.0.0.1"
    profile: str = "generic"
    #: None: the profile's port
    motion_port: int | None = None
    state_port: int | None = None
    io_port: int | None = None
    #: "little" | "big" | None: detected from the server's first frame
    byte_order: str | None = None
    #: 4 | 8 | None: detected
    float_size: int | None = None
    #: send trajectory points (it moves the robot)
    allow_motion: bool = False
    #: the small move, on joint ``joint`` (1-based)
    amplitude: float = 0.01
    joint: int = 1
    #: target reached within this (rad)
    tolerance: float = 0.001
    #: how long the state topics are watched before any motion (s)
    observe: float = 3.0
    #: the small move's duration (s); the stopped move takes twice as long
    move_time: float = 2.0
    reply_timeout: float = 2.0
    #: how long a move may take beyond its duration (s)
    motion_timeout: float = 10.0
    #: the joint-state rate expected (Hz); None: any above 1 Hz
    state_rate: float | None = None
    #: the msg_type used as an unknown type
    unknown_type: int = 65535
    #: rule patterns (fnmatch) to run only / to leave out
    only: tuple[str, ...] = ()
    skip: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.profile not in EXPECTATIONS:
            raise ValueError(f"unknown profile {self.profile!r} (known: {', '.join(EXPECTATIONS)})")
        if self.byte_order not in (None, "little", "big"):
            raise ValueError(f"byte order must be little or big, not {self.byte_order!r}")
        if self.float_size not in (None, 4, 8):
            raise ValueError(f"float size must be 4 or 8, not {self.float_size!r}")
        if not 1 <= self.joint <= 10:
            raise ValueError(f"joint must be 1..10, not {self.joint}")
        if not 0 < self.amplitude <= 0.2:
            raise ValueError(f"amplitude must be in (0, 0.2] rad, not {self.amplitude}")
        if not 0 < self.tolerance < self.amplitude:
            raise ValueError(f"tolerance must be in (0, amplitude), not {self.tolerance}")
        for name in ("observe", "move_time", "reply_timeout", "motion_timeout"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name.replace('_', ' ')} must be positive")
        if message_class(self.unknown_type) is not None or not 0 < self.unknown_type < 2**31:
            raise ValueError(
                f"unknown type {self.unknown_type} is a known message type (or out of range): choose one nobody "
                "assigns, e.g. 65535"
            )
        for pattern in self.only + self.skip:
            if not any(fnmatch.fnmatchcase(rule, pattern) for rule in SERVER_RULES):
                raise ValueError(f"{pattern!r} matches no rule (rules: {', '.join(SERVER_RULES)})")

    @property
    def ports(self) -> dict[str, int]:
        dialect = EXPECTATIONS[self.profile].dialect
        ports = {
            "motion": dialect.motion_port if self.motion_port is None else self.motion_port,
            "state": dialect.state_port if self.state_port is None else self.state_port,
        }
        # the generic nodes define an IO port but none of the real servers serves it (§6)
        if self.io_port is not None:
            ports["io"] = self.io_port
        elif dialect.io_port is not None and dialect.motion_control:
            ports["io"] = dialect.io_port
        return ports


class ServerSuite(_MotionRules):
    """One run of the server suite against ``options.host``."""

    def __init__(self, options: ServerSuiteOptions) -> None:
        self.options = options
        self.expect = EXPECTATIONS[options.profile]
        self.dialect = self.expect.dialect
        self.report = Report("server", f"{options.host} ({options.profile})")
        self.wire: WireFormat | None = None
        self.detected: WireFormat | None = None
        self.state: Link | None = None
        self.motion: Link | None = None
        self.links: list[Link] = []  # links whose frames the framing rules judge
        self.motion_started: float | None = None  # when the first motion was sent (state rules stop there)
        self._state_event = asyncio.Event()
        self._results: dict[str, _Verdict] = {}
        self._aborted: str | None = None
        self._saw_in_motion = False  # a STATUS said in_motion TRUE (reset before each move)

    # -- running -----------------------------------------------------------------------------------

    def _wanted(self, rule: str) -> bool:
        o = self.options
        if o.only and not any(fnmatch.fnmatchcase(rule, p) for p in o.only):
            return False
        return not any(fnmatch.fnmatchcase(rule, p) for p in o.skip)

    async def _rule(
        self, rule: str, check: Callable[[], Awaitable[_Verdict]], *, always: bool = False
    ) -> _Verdict | None:
        """Judge ``rule`` by ``check`` and report it, if it is wanted (``always``: run the check
        anyway, unreported: a connection the other rules need)."""
        if rule in self._results:
            return self._results[rule]
        wanted = self._wanted(rule)
        if not wanted and not always:
            return None
        title, source = SERVER_RULES[rule]
        started = time.monotonic()
        try:
            result = await check()
        except _Skip as skip:
            result = _Verdict(Verdict.SKIP, str(skip))
        except _Abort as abort:
            self._aborted = self._aborted or str(abort)
            result = _Verdict(Verdict.FAIL, str(abort), abort.evidence)
        if not wanted:
            return result
        self._results[rule] = result
        evidence = result.evidence[:12]
        if len(result.evidence) > 12:
            evidence.append(Evidence.note(f"... and {len(result.evidence) - 12} more"))
        self.report.add(
            RuleResult(rule, title, result.verdict, result.detail, source, evidence, time.monotonic() - started)
        )
        return result

    def _skip_all(self, rules: Sequence[str], reason: str) -> None:
        for rule in rules:
            if self._wanted(rule) and rule not in self._results:
                title, source = SERVER_RULES[rule]
                self._results[rule] = _Verdict(Verdict.SKIP, reason)
                self.report.add(RuleResult(rule, title, Verdict.SKIP, reason, source))

    async def run(self) -> Report:
        """Run every rule (those not wanted are left out of the report) and return the report. If
        cancelled, the motion under way is stopped first and :attr:`report` holds the rules run."""
        try:
            await self._run()
        except asyncio.CancelledError:
            await self._framing_rules()  # what was received so far is judged too
            raise
        finally:
            for link in self.links + [lk for lk in (self.state, self.motion) if lk is not None]:
                await link.close()
            order = list(SERVER_RULES)
            self.report.results.sort(key=lambda r: order.index(r.rule))
        return self.report

    async def _run(self) -> None:
        o = self.options
        ports = o.ports
        state_ok = await self._rule("connect.state", lambda: self._connect("state", ports["state"]), always=True)
        await self._rule("connect.motion", lambda: self._connect("motion", ports["motion"]), always=True)
        if "io" in ports:
            await self._rule("connect.io", lambda: self._connect("io", ports["io"]))
        else:
            self._skip_all(["connect.io"], f"the {o.profile} profile has no IO port")
        observe_from = time.monotonic()
        await self._decide_wire()
        motion_rules = [
            r
            for r in SERVER_RULES
            if r.startswith(("motion.", "motoros.", "reply.", "malformed.")) and r != "reply.comm-type"
        ]
        if self.motion is None:
            self._skip_all(motion_rules, "the motion port did not accept a connection")
        elif self.wire is None:
            self._skip_all(motion_rules, "the byte order is unknown: no state frame arrived; pass --byte-order")
        else:
            await self._requests()
        # the state rules judge what came before any motion, over at least `observe` seconds
        if self.state is not None and state_ok is not None:
            wait = observe_from + o.observe - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
        self.motion_started = time.monotonic()
        await self._state_rules()
        if self.motion is not None and self.wire is not None:
            await self._motion()
        await self._framing_rules()

    async def _connect(self, role: str, port: int) -> _Verdict:
        o = self.options
        link = Link(role, None, self._state_frame if role == "state" else None)
        try:
            await link.open(o.host, port, o.reply_timeout)
        except (OSError, TimeoutError) as exc:
            return _Verdict(Verdict.FAIL, f"{o.host}:{port}: {exc or 'timed out'}")
        if role == "state":
            self.state = link
        elif role == "motion":
            self.motion = link
        self.links.append(link)
        return _Verdict(Verdict.PASS, f"{o.host}:{port} accepted")

    def _state_frame(self, seen: Seen) -> None:
        if isinstance(seen.message, Status) and seen.message.in_motion == TriState.TRUE:
            self._saw_in_motion = True
        self._state_event.set()

    async def _decide_wire(self) -> None:
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

    # -- requests that cannot move anything ---------------------------------------------------------

    def _liveness(self) -> Message:
        """A request every profile's motion port answers and that cannot move the robot."""
        return Ping() if self.expect.ping else self._stop_message()

    def _stop_message(self) -> Message:
        if self.dialect.motion_control:
            return MotoMotionCtrl(0, 0, MotoCommand.STOP_MOTION)
        return JointTrajPt(SpecialSeq.STOP_TRAJECTORY)

    async def _exchange(
        self, link: Link, message: Message, timeout: float | None = None, *, keep: bool = False
    ) -> tuple[Seen, Seen | None]:
        """Send ``message`` and take the next frame as its reply, within ``timeout`` (default the
        reply timeout). Frames received before it are forgotten first, unless ``keep``: an extra
        reply already waiting is then what comes back."""
        if not keep:
            link.skip_pending()
        sent = link.send_message(message)
        reply = await link.next_frame(self.options.reply_timeout if timeout is None else timeout)
        return sent, reply

    def _answers(self, request: Message, reply: Seen | None) -> bool:
        return reply is not None and reply.message is not None and self.dialect.answers(request.msg_type, reply.message)

    async def _requests(self) -> None:
        await self._rule("reply.ping", self._ping)
        await self._rule("reply.order", self._order)
        await self._rule("reply.unknown-type", self._unknown_type)
        await self._rule("reply.unknown-topic", self._unknown_topic)
        if self.dialect.motion_control:
            await self._rule("motoros.check-motion-ready", self._check_motion_ready)
        else:
            self._skip_all(["motoros.check-motion-ready"], f"not a MotoROS server (profile {self.options.profile})")
        await self._rule("malformed.survival", self._malformed)
        await self._reopen_motion()

    async def _reopen_motion(self) -> None:
        """A fresh motion link: a controller takes one motion client, and each new connection of the
        malformed-frame rule replaced (or was refused beside) the suite's own (§6 connection limits).
        Against a one-client server the old link is closed first: it leaves a second connect waiting
        in its backlog, and ABB's resets that backlog when its client goes; a new link reset within
        ``_RESET_WINDOW`` is opened again (at most ``_REOPENS`` times)."""
        if self.motion is None or self.wire is None:
            return
        if not self.expect.one_client:  # the new link first: a server that takes over keeps serving
            link = Link("motion", self.wire)
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
            link = Link("motion", self.wire)
            try:
                await link.open(self.options.host, self.options.ports["motion"], self.options.reply_timeout)
            except (OSError, TimeoutError):
                return
            self.links.append(link)
            self.motion = link
            if not await link.wait_closed(_RESET_WINDOW):
                return
            await link.close()

    async def _ping(self) -> _Verdict:
        if not self.expect.ping:
            raise _Skip(
                f"the {self.options.profile} profile's motion port takes only JOINT_TRAJ_PT ({self.expect.source})"
            )
        assert self.motion is not None
        sent, reply = await self._exchange(self.motion, Ping())
        ev = [sent.evidence()] + ([reply.evidence()] if reply else [])
        if reply is None:
            return _Verdict(Verdict.FAIL, f"no reply within {self.options.reply_timeout:g} s", ev)
        msg = reply.message
        if msg is None or msg.msg_type != MsgType.PING:
            return _Verdict(Verdict.FAIL, "the reply is not a PING", ev)
        if msg.comm_type != CommType.SERVICE_REPLY or msg.reply_code != ReplyCode.SUCCESS:
            return _Verdict(Verdict.FAIL, "the PING reply is not a SERVICE_REPLY with SUCCESS", ev)
        latency = (reply.time - sent.time) * 1000
        return _Verdict(Verdict.PASS, f"PING answered in {latency:.1f} ms", ev)

    async def _order(self) -> _Verdict:
        assert self.motion is not None and self.wire is not None
        if self.expect.unknown_types:
            unknown = RawMessage(self.options.unknown_type)
            burst: list[Message] = [Ping(), unknown, Ping(), unknown, Ping()]
        else:
            burst = [self._stop_message()] * 3
        sentinel = self._liveness()
        link = self.motion
        link.skip_pending()
        sent = link.send(b"".join(m.encode(self.wire) for m in burst), None)
        ev = [Evidence.note(f"{len(burst)} requests in one segment: " + ", ".join(_name(m) for m in burst))]
        ev.append(sent.evidence())
        replies: list[Seen] = []
        for _ in burst:
            reply = await link.next_frame(self.options.reply_timeout)
            if reply is None:
                break
            replies.append(reply)
        ev.extend(r.evidence() for r in replies)
        if len(replies) < len(burst):
            return _Verdict(Verdict.FAIL, f"{len(replies)} replies to {len(burst)} requests", ev)
        for k, (request, reply) in enumerate(zip(burst, replies, strict=True)):
            if not self._answers(request, reply):
                return _Verdict(Verdict.FAIL, f"reply {k + 1} does not answer request {k + 1} ({_name(request)})", ev)
        # one per request, none extra: the sentinel's reply must be the very next frame
        s_sent, s_reply = await self._exchange(link, sentinel, keep=True)
        ev += [s_sent.evidence()] + ([s_reply.evidence()] if s_reply else [])
        if s_reply is None:
            return _Verdict(Verdict.FAIL, "no reply to the request sent after the burst", ev)
        if not self._answers(sentinel, s_reply) or s_reply.time < s_sent.time:
            return _Verdict(Verdict.FAIL, "an extra frame came before the next request's reply", ev)
        return _Verdict(Verdict.PASS, f"{len(burst)} replies in order, then the next request's reply", ev)

    async def _unknown_type(self) -> _Verdict:
        if not self.expect.unknown_types:
            raise _Skip(f"the {self.options.profile} profile's servers take no other type ({self.expect.source})")
        assert self.motion is not None
        request = RawMessage(self.options.unknown_type)
        sent, reply = await self._exchange(self.motion, request)
        ev = [sent.evidence()] + ([reply.evidence()] if reply else [])
        if reply is None or reply.message is None:
            return _Verdict(Verdict.FAIL, f"no reply to type {self.options.unknown_type} (the client would hang)", ev)
        msg = reply.message
        if self.dialect.reply_style is ReplyStyle.MOTO_MOTION_REPLY:
            if not isinstance(msg, MotoMotionReply):
                return _Verdict(Verdict.FAIL, "MotoROS answers an unknown type with MOTO_MOTION_REPLY", ev)
            if msg.result != MotoResult.INVALID or msg.subcode != InvalidSubcode.MSGTYPE:
                return _Verdict(Verdict.FAIL, f"result {msg.result} subcode {msg.subcode}, not INVALID 3003", ev)
            if msg.command != self.options.unknown_type:
                return _Verdict(Verdict.WARN, f"INVALID 3003, but command {msg.command} is not the type sent", ev)
            return _Verdict(Verdict.PASS, "MOTO_MOTION_REPLY INVALID 3003 (MSGTYPE)", ev)
        if msg.msg_type != self.options.unknown_type or msg.comm_type != CommType.SERVICE_REPLY:
            return _Verdict(Verdict.FAIL, "the reply is not a SERVICE_REPLY of the type sent", ev)
        if msg.reply_code != ReplyCode.FAILURE:
            return _Verdict(Verdict.FAIL, f"reply_code {msg.reply_code}, not FAILURE", ev)
        return _Verdict(Verdict.PASS, "FAILURE, as the C++ MessageManager answers", ev)

    async def _unknown_topic(self) -> _Verdict:
        if not self.expect.unknown_types:
            raise _Skip(f"the {self.options.profile} profile's servers take no other type ({self.expect.source})")
        assert self.motion is not None and self.wire is not None
        topic = RawMessage(self.options.unknown_type, comm_type=CommType.TOPIC)
        sentinel = Ping()
        link = self.motion
        link.skip_pending()
        sent = link.send(topic.encode(self.wire) + sentinel.encode(self.wire), None)
        first = await link.next_frame(self.options.reply_timeout)
        ev = [sent.evidence()] + ([first.evidence()] if first else [])
        motoros = self.dialect.reply_style is ReplyStyle.MOTO_MOTION_REPLY
        if first is None:
            return _Verdict(Verdict.FAIL, "no reply at all (not even to the PING after the TOPIC)", ev)
        if motoros:
            msg = first.message
            if not (isinstance(msg, MotoMotionReply) and msg.result == MotoResult.INVALID):
                return _Verdict(Verdict.FAIL, "MotoROS answers every message but replies: INVALID 3003 expected", ev)
            second = await link.next_frame(self.options.reply_timeout)
            if second is not None:
                ev.append(second.evidence())
            if not self._answers(sentinel, second):
                return _Verdict(Verdict.FAIL, "the PING after the TOPIC was not answered next", ev)
            return _Verdict(Verdict.PASS, "answered INVALID 3003, as MotoROS does, then the PING", ev)
        if not self._answers(sentinel, first):
            return _Verdict(Verdict.FAIL, "the TOPIC was answered; a TOPIC gets no reply (§3)", ev)
        return _Verdict(Verdict.PASS, "ignored; the PING after it answered next", ev)

    async def _check_motion_ready(self) -> _Verdict:
        assert self.motion is not None
        request = MotoMotionCtrl(0, 0, MotoCommand.CHECK_MOTION_READY)
        sent, reply = await self._exchange(self.motion, request)
        ev = [sent.evidence()] + ([reply.evidence()] if reply else [])
        msg = reply.message if reply else None
        if not isinstance(msg, MotoMotionReply):
            return _Verdict(Verdict.FAIL, "no MOTO_MOTION_REPLY", ev)
        if msg.command != MotoCommand.CHECK_MOTION_READY:
            return _Verdict(Verdict.FAIL, f"the reply's command is {msg.command}, not 200101 (echoed)", ev)
        if msg.result == MotoResult.TRUE:
            return _Verdict(Verdict.PASS, "TRUE: ready", ev)
        if msg.result in {MotoResult.FALSE, MotoResult.NOT_READY}:
            if not 5000 <= msg.subcode < 6000:
                return _Verdict(Verdict.WARN, f"not ready, but subcode {msg.subcode} is no NOT_READY reason (5xxx)", ev)
            return _Verdict(Verdict.PASS, f"not ready, subcode {msg.subcode}", ev)
        return _Verdict(Verdict.FAIL, f"result {msg.result}: neither TRUE nor FALSE", ev)

    async def _malformed(self) -> _Verdict:
        if self.expect.no_malformed is not None:
            raise _Skip(self.expect.no_malformed)
        assert self.wire is not None
        o = self.options
        port = o.ports["motion"]
        ev: list[Evidence] = []
        failures: list[str] = []
        still = self._current_joints()
        if self.motion is not None:
            # a server that takes one client at a time (the C++ TcpServer, ABB's and Fanuc's, §6)
            # must be free for the cases' connections; the suite's own link is opened again after
            await self.motion.close()
        for case in malformed_cases(self.wire):
            witness_before = len(self.state.frames) if self.state else 0
            # the state port is the witness only while it is sending (its silence is state.rate's)
            witnessing = self._state_fresh()
            link = Link("malformed", self.wire)
            try:
                await link.open(o.host, port, o.reply_timeout)
            except (OSError, TimeoutError) as exc:
                failures.append(case.name)
                ev.append(Evidence.note(f"{case.name}: the motion port refused a connection: {exc}"))
                break
            link.send(case.data)
            closed = await link.wait_closed(0.3 if case.hold else 0.15)
            answered = [f.evidence() for f in link.frames[:2]]
            await link.close()
            fate = "closed by the server" if closed else "left open"
            if answered:
                fate += f", {len(link.frames)} frame(s) back"
            # another connection stays served: the state port kept sending, and a new motion
            # connection is answered
            witness_ok = not witnessing or await self._witness(witness_before)
            probe = Link("motion", self.wire)
            alive = False
            try:
                await probe.open(o.host, port, o.reply_timeout)
                request = self._liveness()
                _, reply = await self._exchange(probe, request)
                alive = self._answers(request, reply)
            except (OSError, TimeoutError):
                alive = False
            finally:
                await probe.close()
            ok = alive and witness_ok
            ev.append(Evidence.note(f"{case.name} ({case.what}): {fate}" + ("; served after it" if ok else "")))
            ev.extend(answered[:1])
            if not alive:
                failures.append(case.name)
                ev.append(Evidence.note(f"{case.name}: a new motion connection was not answered afterwards"))
                break
            if not witness_ok:
                failures.append(case.name)
                ev.append(Evidence.note(f"{case.name}: the state port sent nothing while it was handled"))
        moved = self._moved_since(still)
        if moved:
            failures.append("motion")
            ev.append(Evidence.note(f"the robot moved while malformed frames were sent: {moved}"))
        elif still is not None and not self._state_fresh():
            failures.append("state")
            ev.append(Evidence.note("the state port went silent: whether the robot moved cannot be told"))
        if failures:
            return _Verdict(Verdict.FAIL, "not served after: " + ", ".join(failures), ev)
        return _Verdict(
            Verdict.PASS, f"{len(malformed_cases(self.wire))} malformed frames survived, served throughout", ev
        )

    def _state_fresh(self, within: float = 1.0) -> bool:
        """Whether the state port is connected and sent a frame in the last ``within`` seconds (the
        PC's watchdog, §5): what the suite knows of the robot is then current."""
        state = self.state
        if state is None or not state.alive or not state.frames:
            return False
        return time.monotonic() - state.frames[-1].time <= within

    async def _witness(self, count_before: int) -> bool:
        """Whether the state port sent a frame after ``count_before`` of them (waiting up to the 1 s
        the PC's watchdog allows, §5)."""
        state = self.state
        if state is None:
            return True
        return await self._wait_state(lambda j, s: len(state.frames) > count_before, 1.0)

    # -- the state port ----------------------------------------------------------------------------------

    def _state_seen(self, until: float | None = None) -> list[Seen]:
        if self.state is None:
            return []
        return [f for f in self.state.frames if until is None or f.time <= until]

    def _current_joints(self) -> tuple[float, ...] | None:
        for seen in reversed(self._state_seen()):
            joints = _joints_of(seen.message)
            if joints is not None:
                return joints
        return None

    def _status_since(self, since: float) -> Status | None:
        """The latest STATUS received at ``time.monotonic()`` ``since`` or later, if any."""
        for seen in reversed(self._state_seen()):
            if seen.time < since:
                return None
            if isinstance(seen.message, Status):
                return seen.message
        return None

    def _current_status(self) -> Status | None:
        for seen in reversed(self._state_seen()):
            if isinstance(seen.message, Status):
                return seen.message
        return None

    def _moved_since(self, before: tuple[float, ...] | None) -> str:
        now = self._current_joints()
        if before is None or now is None:
            return ""
        moved = [(k, b, n) for k, (b, n) in enumerate(zip(before, now, strict=True)) if abs(n - b) > STILL]
        return ", ".join(f"joint {k + 1} {b:.5f} -> {n:.5f}" for k, b, n in moved)

    async def _wait_state(self, check: Callable[[tuple[float, ...], Status | None], bool], timeout: float) -> bool:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            joints = self._current_joints()
            if joints is not None and check(joints, self._current_status()):
                return True
            remaining = deadline - loop.time()
            if remaining <= 0 or self.state is None or not self.state.alive:
                return False
            self._state_event.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._state_event.wait(), remaining)

    async def _state_rules(self) -> None:
        names = ["state.topics", "state.rate", "state.joint-state", "state.status", "state.status-consistency"]
        if self.state is None:
            self._skip_all(names, "the state port did not accept a connection")
            return
        frames = self._state_seen(self.motion_started)
        if not frames:
            self._skip_all(names[1:], "the state port sent nothing")
        await self._rule("state.topics", lambda: state_topics(frames, self.options, self.expect, self._real))
        if frames:
            await self._rule(
                "state.rate",
                lambda: state_rate(
                    frames,
                    self.options,
                    self.expect,
                    state=self.state,
                    motion_started=self.motion_started,
                    real=self._real,
                ),
            )
            await self._rule("state.joint-state", lambda: state_joint_state(frames, self._real))
            await self._rule("state.status", lambda: state_status(frames, self.dialect, self._real))
            await self._rule("state.status-consistency", lambda: state_consistency(frames))

    @property
    def _real(self) -> int:
        return self.wire.real_size if self.wire else 4

    # -- framing, judged over everything received ----------------------------------------------------------

    async def _framing_rules(self) -> None:
        received = [f for link in self.links for f in link.frames if not f.outgoing]
        await self._rule(
            "framing.byte-order",
            lambda: framing_byte_order(
                received, self.options, self.dialect, wire=self.wire, detected=self.detected, real=self._real
            ),
        )
        await self._rule("framing.float-size", lambda: framing_float_size(received, self.options, self.detected))
        await self._rule("framing.length", lambda: framing_length(received, self.links, self._real))
        await self._rule("framing.body", lambda: framing_body(received, self.dialect, self._real))
        await self._rule("reply.comm-type", lambda: reply_comm_types(received, self._real))


async def run_server_suite(options: ServerSuiteOptions) -> Report:
    """Run the server suite with ``options`` and return its report."""
    return await ServerSuite(options).run()


# -- helpers -----------------------------------------------------------------------------------------


def _name(msg: Message) -> str:
    if isinstance(msg, RawMessage):
        return f"type {msg.msg_type}"
    return msg.name
