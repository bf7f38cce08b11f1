"""The server suite: probe a running simple_message server (a controller, real or emulated) and
judge it by the rules the real peers follow.

It connects to the server's state port first and listens (the server speaks first there: byte
order and float size are detected from its frames), then asks the motion port what can be asked
without moving anything (PING, requests of a type nobody assigns, a burst of requests, the
reference library's list of malformed frames), and watches the state topics throughout. Only with
``allow_motion`` does it send trajectory points, and only after STATUS says the robot is idle, in
AUTO and not in error: a small move of one joint (``amplitude``, default 0.01 rad), a move stopped
half way, a point beyond any joint's range (refused, nothing moved), and on MotoROS its trajectory
mode, BUSY and start-position rules. Every move is followed by one back to where the robot was.

What a profile's real servers do differently (which port answers a PING, how an unknown type is
answered, which topics the state port sends at what rate) is in :data:`EXPECTATIONS`, from the
project's protocol notes (simple-message.md §3, §5, §8); the rules and their sources are listed in
docs/conformance.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import fnmatch
import itertools
import logging
import math
import statistics
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field

from ..constants import (
    CommType,
    InvalidSubcode,
    MotoCommand,
    MotoResult,
    MsgType,
    ReplyCode,
    RobotMode,
    SpecialSeq,
    TriState,
    ValidFields,
)
from ..dialects import ABB, FANUC, GENERIC, MOTOROS, Dialect, ReplyStyle
from ..framing import decode_or_error
from ..messages import (
    HeaderOnly,
    JointFeedback,
    JointFeedbackEx,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Ping,
    RawMessage,
    Status,
    message_class,
    type_name,
)
from ..wire import ByteOrder, WireFormat
from .links import Link, Seen
from .malformed import malformed_cases
from .report import Evidence, Report, RuleResult, Verdict

__all__ = ["ServerSuiteOptions", "ServerSuite", "Expectations", "EXPECTATIONS", "SERVER_RULES", "run_server_suite"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Expectations:
    """What one family of real servers does, where the protocol leaves it open."""

    dialect: Dialect
    #: its motion port answers a PING (ABB's RAPID server takes only JOINT_TRAJ_PT; Fanuc's parser
    #: waits for 56 bytes and would misframe one, §8.2, §8.3)
    ping: bool
    #: it can be sent a request of an unknown type (the same servers cannot)
    unknown_types: bool
    #: the state port's joint-state topic
    joint_state: int
    #: documented rates of its state topics (Hz), for a WARN when far off
    rates: dict[int, float] = field(default_factory=dict)
    #: where its behaviour is documented
    source: str = ""


EXPECTATIONS: dict[str, Expectations] = {
    "generic": Expectations(
        GENERIC, True, True, MsgType.JOINT_POSITION, {}, "the reference C++ library (simple-message.md §3, §6)"
    ),
    "abb": Expectations(
        ABB,
        False,
        False,
        MsgType.JOINT_POSITION,
        {MsgType.JOINT_POSITION: 10.0, MsgType.STATUS: 10.0},
        "abb_driver's RAPID servers (simple-message.md §8.2)",
    ),
    "fanuc": Expectations(
        FANUC,
        False,
        False,
        MsgType.JOINT_POSITION,
        {MsgType.JOINT_POSITION: 42.0, MsgType.STATUS: 4.2},
        "fanuc_driver's KAREL servers (simple-message.md §8.3)",
    ),
    "motoros": Expectations(
        MOTOROS,
        True,
        True,
        MsgType.JOINT_FEEDBACK,
        {MsgType.JOINT_FEEDBACK: 40.0, MsgType.STATUS: 40.0},
        "MotoROS (simple-message.md §8.1)",
    ),
}

#: rule id → (what it checks, the real peer behaviour it comes from)
SERVER_RULES: dict[str, tuple[str, str]] = {
    "connect.state": ("the state port accepts a connection", "REP-I0006: the controller is the TCP server (§6)"),
    "connect.motion": ("the motion port accepts a connection", "REP-I0006: the controller is the TCP server (§6)"),
    "connect.io": ("the IO port accepts a connection", "MotoROS IO server, port 50242 (§6)"),
    "framing.byte-order": (
        "every frame in one byte order, the one expected",
        "§1.3: no negotiation; Fanuc and the FS100 big-endian, the others little-endian",
    ),
    "framing.float-size": (
        "reals of one size, the one expected",
        "§1.3: float32 by default, float64 in the FLOAT64 build; no negotiation",
    ),
    "framing.length": (
        "length prefixes count header and body, within what C++ peers can take",
        "§1.1, §1.5: length excludes itself; a C++ peer's buffer holds 1024 bytes",
    ),
    "framing.body": (
        "every body has its type's layout; header-only only where a reply may be",
        "§2.2 layouts; §3: only replies may be short (ABB, the C++ FAILURE reply)",
    ),
    "reply.ping": ("a PING is answered by a PING reply, SUCCESS", "C++ PING handler; MotoROS (§2, §8.1)"),
    "reply.order": (
        "one reply per request, in order, none extra",
        "§3: servers answer every request once; the generic client takes the next message as the reply",
    ),
    "reply.comm-type": (
        "replies are SERVICE_REPLY with SUCCESS or FAILURE",
        "§1.2 validateMessage: a reply with reply_code INVALID is dropped by C++ peers",
    ),
    "reply.unknown-type": (
        "a request of an unknown type is answered FAILURE (MotoROS: INVALID 3003)",
        "§3 MessageManager::spinOnce; MotoROS Ros_SimpleMsg_MotionReply (§8.1)",
    ),
    "reply.unknown-topic": (
        "a TOPIC of an unknown type is ignored (MotoROS: answered INVALID 3003)",
        "§3: receivers ignore unsupported TOPICs; MotoROS answers all but replies (§8.1)",
    ),
    "malformed.survival": (
        "each malformed frame of the reference peer's list, on its own connection, leaves the server serving",
        "§1.2, §1.5: what the C++ library rejects; §11: a server must not depend on well-formed peers",
    ),
    "state.topics": ("the state port sends its profile's topics as TOPICs", "§6; §8.1 MotoROS state server"),
    "state.rate": (
        "joint state above 1 Hz with no gap over 1 s; the rate steady",
        "§5: the PC's 1.0 s watchdog on joint state; vendor rates §8",
    ),
    "state.joint-state": ("joint state finite, valid_fields honest", "§2.2, §8.1"),
    "state.status": ("STATUS fields within their enums and consistent with each other", "§5 (REP-I0006 STATUS)"),
    "state.status-consistency": (
        "STATUS agrees with the joints over time (no motion while in_motion FALSE)",
        "§5: a goal succeeds only when in_motion is FALSE",
    ),
    "motion.preconditions": (
        "STATUS says idle, AUTO, not in error before any motion is sent",
        "this suite's safety rule (issue text: check before moving)",
    ),
    "motion.small-move": (
        "a small move of one joint is accepted and its target reached within tolerance",
        "§4.2 streaming; §5 goal_threshold",
    ),
    "motion.in-motion": ("in_motion TRUE while moving, FALSE after", "§5: joint_trajectory_action waits for FALSE"),
    "motion.stop": (
        "STOP acknowledged at once and obeyed: the robot stops short of the target",
        "§4.2 trajectoryStop, §10 pitfall 5 (ABB did not reply to STOP); MotoROS STOP_MOTION",
    ),
    "motion.out-of-limit": (
        "a point beyond any joint's range is refused and nothing moves",
        "§3: reply_code says whether the point was enqueued; MotoROS INVALID 3012",
    ),
    "motoros.check-motion-ready": (
        "CHECK_MOTION_READY answered with TRUE, or FALSE with a NOT_READY subcode",
        "MotoROS MotionServer.c; motoman_driver checks it before every trajectory (§8.1)",
    ),
    "motoros.traj-mode": (
        "START_TRAJ_MODE makes it ready, STOP_TRAJ_MODE not ready",
        "MotoROS robot_enable / robot_disable (§8.1)",
    ),
    "motoros.busy": (
        "points sent back to back: BUSY means not taken; every point taken on resend, the last reached",
        "MotoROS one staging slot per group; the FS100 capture's BUSY replies (§8.1)",
    ),
    "motoros.start-position": (
        "a trajectory not starting at the current position is refused INVALID 3011, nothing moved",
        "MotoROS START_MAX_PULSE_DEVIATION, motoman#134 (§8.1, §10 pitfall 10)",
    ),
}

#: how far beyond the current position the out-of-limit point puts the joint (rad): beyond the
#: range of any revolute joint of an industrial arm
BEYOND_LIMITS = 100.0
#: the time the out-of-limit point is given (s): accepted by mistake, it would creep
BEYOND_SECONDS = 1000.0
#: a joint that moved less than this (rad) did not move (feedback noise on a real arm is ~1e-5)
STILL = 1e-4
#: longest frame a C++ peer can take (§1.5)
CPP_MAX_FRAME = 1023


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


class _Skip(Exception):
    """A rule cannot be judged: SKIP with this reason."""


class _Abort(Exception):
    """The motion phase cannot go on (the server stopped answering, or a move failed): this rule
    FAILs with the reason and the evidence so far, the rules after it SKIP."""

    def __init__(self, reason: str, evidence: list[Evidence] | None = None) -> None:
        super().__init__(reason)
        self.evidence = evidence or []


@dataclass
class _Verdict:
    verdict: Verdict
    detail: str
    evidence: list[Evidence] = field(default_factory=list)


class ServerSuite:
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
        malformed-frame rule replaced (or was refused beside) the suite's own (§6 connection limits)."""
        if self.motion is None or self.wire is None:
            return
        link = Link("motion", self.wire)
        try:
            await link.open(self.options.host, self.options.ports["motion"], self.options.reply_timeout)
        except (OSError, TimeoutError):
            return
        await self.motion.close()
        self.motion = link
        self.links.append(link)

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

    async def _state_rules(self) -> None:
        names = ["state.topics", "state.rate", "state.joint-state", "state.status", "state.status-consistency"]
        if self.state is None:
            self._skip_all(names, "the state port did not accept a connection")
            return
        frames = self._state_seen(self.motion_started)
        if not frames:
            self._skip_all(names[1:], "the state port sent nothing")
        await self._rule("state.topics", lambda: self._topics(frames))
        if frames:
            await self._rule("state.rate", lambda: self._rate(frames))
            await self._rule("state.joint-state", lambda: self._joint_state(frames))
            await self._rule("state.status", lambda: self._status(frames))
            await self._rule("state.status-consistency", lambda: self._consistency(frames))

    async def _topics(self, frames: list[Seen]) -> _Verdict:
        wanted = (self.expect.joint_state, MsgType.STATUS)
        seen_types = {f.message.msg_type for f in frames if f.message is not None}
        ev = [f.evidence(self._real) for f in _first_of_each(frames)]
        if not frames:
            return _Verdict(Verdict.FAIL, f"nothing in {self.options.observe:g} s", ev)
        missing = [_type_name(t) for t in wanted if t not in seen_types]
        if missing:
            return _Verdict(Verdict.FAIL, "never sent: " + ", ".join(missing), ev)
        not_topics = [f for f in frames if f.message is not None and f.message.comm_type != CommType.TOPIC]
        if not_topics:
            return _Verdict(
                Verdict.FAIL, "state messages that are not TOPICs", [f.evidence(self._real) for f in not_topics[:3]]
            )
        names = ", ".join(_type_name(t) for t in sorted(seen_types))
        return _Verdict(Verdict.PASS, f"{len(frames)} TOPICs: {names}", ev)

    @property
    def _real(self) -> int:
        return self.wire.real_size if self.wire else 4

    async def _rate(self, frames: list[Seen]) -> _Verdict:
        ev: list[Evidence] = []
        verdict = Verdict.PASS
        details = []
        for msg_type in sorted({f.message.msg_type for f in frames if f.message is not None}):
            times = [f.time for f in frames if f.message is not None and f.message.msg_type == msg_type]
            if len(times) < 3:
                continue
            intervals = [b - a for a, b in itertools.pairwise(times)]
            span = times[-1] - times[0]
            rate = (len(times) - 1) / span if span > 0 else math.inf
            median = statistics.median(intervals)
            jitter = _p99([abs(i - median) for i in intervals])
            # a stream that stopped: the silence up to the end of the window is a gap too
            gap = max(*intervals, (self.motion_started or time.monotonic()) - times[-1])
            name = _type_name(msg_type)
            ev.append(
                Evidence.note(
                    f"{name}: {rate:.1f} Hz, median interval {median * 1000:.1f} ms, p99 jitter "
                    f"{jitter * 1000:.1f} ms, longest gap {gap * 1000:.0f} ms ({len(times)} frames)"
                )
            )
            details.append(f"{name} {rate:.1f} Hz")
            joint_state = msg_type == self.expect.joint_state
            if joint_state and (rate < 1.0 or gap > 1.0):
                verdict = Verdict.FAIL
                details[-1] += f" with a gap of {gap * 1000:.0f} ms (the PC's 1 s watchdog would abort goals)"
            expected = self.options.state_rate if joint_state else None
            if expected and abs(rate - expected) > 0.25 * expected:
                verdict = Verdict.FAIL
                details[-1] += f" (expected {expected:g} Hz)"
            documented = self.expect.rates.get(msg_type)
            if verdict is Verdict.PASS and documented and rate < 0.5 * documented:
                verdict = Verdict.WARN
                details[-1] += f" ({self.options.profile} sends {documented:g} Hz)"
            if verdict is Verdict.PASS and jitter > 0.5 * median:
                verdict = Verdict.WARN
                details[-1] += f" (jitter {jitter * 1000:.1f} ms)"
        state = self.state
        if state is not None and state.closed_at is not None and state.closed_at <= (self.motion_started or math.inf):
            ev.append(Evidence.note(f"the state port closed the connection: {state.close_reason or 'end of stream'}"))
            return _Verdict(Verdict.FAIL, "the state port closed the connection while watched", ev)
        joint_count = sum(1 for f in frames if f.message is not None and f.message.msg_type == self.expect.joint_state)
        if joint_count < 3:
            window = (self.motion_started or time.monotonic()) - frames[0].time
            ev.append(Evidence.note(f"{joint_count} joint-state frames in the {window:.1f} s watched"))
            ev.extend(f.evidence(self._real) for f in frames[:2])
            return _Verdict(Verdict.FAIL, f"{joint_count} joint-state frames in {window:.1f} s", ev)
        return _Verdict(verdict, ", ".join(details), ev)

    async def _joint_state(self, frames: list[Seen]) -> _Verdict:
        problems: list[Seen] = []
        why: list[str] = []
        for f in frames:
            msg = f.message
            if isinstance(msg, JointPosition):
                values = msg.joint_data
            elif isinstance(msg, JointFeedback):
                values = msg.positions
                valid = ValidFields(msg.valid_fields)
                if ValidFields.POSITION not in valid:
                    problems.append(f)
                    why.append("JOINT_FEEDBACK without POSITION in valid_fields")
                    continue
                if ValidFields.TIME not in valid and msg.time != 0.0:
                    problems.append(f)
                    why.append("a time without the TIME bit")
                    continue
                for flag, arr in (
                    (ValidFields.VELOCITY, msg.velocities),
                    (ValidFields.ACCELERATION, msg.accelerations),
                ):
                    if flag not in valid and any(v != 0.0 for v in arr):
                        problems.append(f)
                        why.append(f"{str(flag.name).lower()} values without their valid_fields bit")
            else:
                continue
            if not all(math.isfinite(v) for v in values):
                problems.append(f)
                why.append("a position that is not finite")
        if problems:
            ev = [p.evidence(self._real) for p in problems[:5]]
            return _Verdict(Verdict.FAIL, f"{len(problems)} joint-state frames wrong: {why[0]}", ev)
        count = sum(1 for f in frames if _joints_of(f.message) is not None)
        if not count:
            raise _Skip("no joint state was sent")
        return _Verdict(Verdict.PASS, f"{count} joint states: finite, valid_fields honest", [])

    async def _status(self, frames: list[Seen]) -> _Verdict:
        tristates = {int(t) for t in TriState}
        modes = {int(m) for m in RobotMode}
        problems: list[tuple[Seen, str]] = []
        for f in frames:
            s = f.message
            if not isinstance(s, Status):
                continue
            for name in ("drives_powered", "e_stopped", "in_error", "in_motion", "motion_possible"):
                if getattr(s, name) not in tristates:
                    problems.append((f, f"{name} {getattr(s, name)} is no tristate"))
            if s.mode not in modes:
                problems.append((f, f"mode {s.mode} is no RobotMode"))
            if s.motion_possible == TriState.TRUE and TriState.TRUE in (s.e_stopped, s.in_error):
                problems.append((f, "motion_possible TRUE while e-stopped or in error"))
            if (
                s.motion_possible == TriState.TRUE
                and s.drives_powered == TriState.FALSE
                and not self.dialect.motion_control
            ):
                problems.append((f, "motion_possible TRUE with the drives off"))
            if s.in_motion == TriState.TRUE and s.drives_powered == TriState.FALSE:
                problems.append((f, "in_motion TRUE with the drives off"))
        statuses = [f for f in frames if isinstance(f.message, Status)]
        if not statuses:
            raise _Skip("no STATUS was sent")
        if problems:
            ev = [Evidence.note(problems[0][1])] + [p.evidence(self._real) for p, _ in problems[:4]]
            return _Verdict(Verdict.FAIL, f"{len(problems)} STATUS problems: {problems[0][1]}", ev)
        codes = [
            f.message.error_code
            for f in statuses
            if isinstance(f.message, Status) and f.message.in_error != TriState.TRUE
        ]
        if any(codes):
            return _Verdict(Verdict.WARN, "an error_code with in_error not TRUE", [statuses[-1].evidence(self._real)])
        return _Verdict(Verdict.PASS, f"{len(statuses)} STATUS frames valid", [statuses[-1].evidence(self._real)])

    async def _consistency(self, frames: list[Seen]) -> _Verdict:
        """No motion while every STATUS said in_motion FALSE; no mode or e-stop flicker."""
        statuses = [(f.time, f.message) for f in frames if isinstance(f.message, Status)]
        if not statuses:
            raise _Skip("no STATUS was sent")
        joints = [(f.time, j) for f in frames if (j := _joints_of(f.message)) is not None]
        ev: list[Evidence] = []
        still = all(s.in_motion == TriState.FALSE for _, s in statuses)
        if still and len(joints) >= 2:
            first, last = joints[0][1], joints[-1][1]
            drift = max((abs(a - b) for a, b in zip(first, last, strict=True)), default=0.0)
            if drift > 10 * STILL:
                ev.append(Evidence.note(f"joints moved {drift:.4f} rad while in_motion was FALSE"))
                return _Verdict(Verdict.FAIL, "the joints moved while STATUS said in_motion FALSE", ev)
        changes = sum(
            1 for (_, a), (_, b) in itertools.pairwise(statuses) if (a.mode, a.e_stopped) != (b.mode, b.e_stopped)
        )
        if changes > 2:
            return _Verdict(Verdict.WARN, f"mode or e_stopped changed {changes} times while watched", ev)
        latest = statuses[-1][1]
        return _Verdict(
            Verdict.PASS,
            f"consistent over {len(statuses)} STATUS (in_motion {_tri(latest.in_motion)}, mode {_mode(latest.mode)})",
            ev,
        )

    # -- framing, judged over everything received ----------------------------------------------------------

    async def _framing_rules(self) -> None:
        received = [f for link in self.links for f in link.frames if not f.outgoing]
        await self._rule("framing.byte-order", lambda: self._byte_order(received))
        await self._rule("framing.float-size", lambda: self._float_size(received))
        await self._rule("framing.length", lambda: self._length(received))
        await self._rule("framing.body", lambda: self._body(received))
        await self._rule("reply.comm-type", lambda: self._comm_types(received))

    async def _byte_order(self, frames: list[Seen]) -> _Verdict:
        if self.wire is None or not frames:
            raise _Skip("no frame was received")
        order = self.wire.byte_order.value
        swapped = [f for f in frames if f.swapped]
        if swapped:
            ev = [f.evidence(self._real) for f in swapped[:5]]
            return _Verdict(
                Verdict.FAIL, f"{len(swapped)} frame(s) in the other byte order (the rest {order}-endian)", ev
            )
        expected = self.options.byte_order
        if expected and self.detected is not None and self.detected.byte_order.value != expected:
            return _Verdict(
                Verdict.FAIL, f"the server speaks {self.detected.byte_order.value}-endian, not {expected}", []
            )
        note = f"{order}-endian, all {len(frames)} frames"
        default = self.dialect.wire.byte_order.value
        if order != default:
            note += f" (the {self.options.profile} default is {default}; a bswap build, like Fanuc's and the FS100's)"
        return _Verdict(Verdict.PASS, note, [])

    async def _float_size(self, frames: list[Seen]) -> _Verdict:
        if self.detected is None:
            raise _Skip("no state frame to measure reals by")
        size = self.detected.real_size
        sized = [f for f in frames if f.message is not None and _has_reals(f.message)]
        wrong = [f for f in frames if f.problem and "fits no layout" in f.problem]
        expected = self.options.float_size
        if expected and expected != size:
            return _Verdict(
                Verdict.FAIL, f"float{size * 8} reals, not float{expected * 8}", [f.evidence(size) for f in sized[:1]]
            )
        if wrong:
            return _Verdict(
                Verdict.FAIL,
                f"{len(wrong)} frames fit no layout in float{size * 8}",
                [f.evidence(size) for f in wrong[:5]],
            )
        return _Verdict(Verdict.PASS, f"float{size * 8} ({len(sized)} frames with reals)", [])

    async def _length(self, frames: list[Seen]) -> _Verdict:
        if not frames:
            raise _Skip("no frame was received")
        bad = [f for f in frames if f.problem and f.problem.startswith("length prefix")]
        cut = [link for link in self.links if link.close_reason and "middle of a frame" in link.close_reason]
        if bad or cut:
            ev = [f.evidence(self._real) for f in bad[:5]] + [
                Evidence.note(f"{lk.role}: {lk.close_reason}") for lk in cut
            ]
            return _Verdict(Verdict.FAIL, "a length prefix that does not frame the stream", ev)
        large = [f for f in frames if len(f.raw) > CPP_MAX_FRAME]
        if large:
            return _Verdict(
                Verdict.WARN,
                f"{len(large)} frames over {CPP_MAX_FRAME} bytes: C++ peers cannot read them",
                [large[0].evidence(self._real)],
            )
        return _Verdict(Verdict.PASS, f"{len(frames)} frames, every prefix its frame's size", [])

    async def _body(self, frames: list[Seen]) -> _Verdict:
        if not frames:
            raise _Skip("no frame was received")
        problems: list[tuple[Seen, str]] = []
        for f in frames:
            msg = f.message
            if f.problem and "fits no layout" in f.problem:
                problems.append((f, f.problem))
            elif isinstance(msg, HeaderOnly) and not self._may_be_header_only(msg):
                problems.append((f, f"{_type_name(msg.msg_type)} with no body, where its layout is required"))
        if problems:
            ev = [Evidence.note(problems[0][1])] + [p.evidence(self._real) for p, _ in problems[:5]]
            return _Verdict(Verdict.FAIL, f"{len(problems)} frame(s): {problems[0][1]}", ev)
        return _Verdict(Verdict.PASS, f"{len(frames)} bodies match their layouts", [])

    def _may_be_header_only(self, msg: HeaderOnly) -> bool:
        cls = message_class(msg.msg_type, msg.comm_type)
        if cls is None or (not cls.LAYOUT and msg.msg_type != MsgType.MOTO_MOTION_REPLY):
            return True  # a type with no body, or unknown here
        if msg.comm_type != CommType.SERVICE_REPLY:
            return False
        # a reply: short replies are the C++ FAILURE reply and ABB's ack (§3), never MotoROS's or Fanuc's
        if msg.msg_type == MsgType.MOTO_MOTION_REPLY:
            return False
        return (
            self.dialect.reply_style in (ReplyStyle.ECHO, ReplyStyle.HEADER_ONLY) or msg.reply_code == ReplyCode.FAILURE
        )

    async def _comm_types(self, frames: list[Seen]) -> _Verdict:
        replies = [f for f in frames if f.role in ("motion", "io") and f.message is not None]
        if not replies:
            raise _Skip("no reply was received")
        bad = [
            f
            for f in replies
            if f.message is not None
            and (
                f.message.comm_type != CommType.SERVICE_REPLY
                or f.message.reply_code not in (ReplyCode.SUCCESS, ReplyCode.FAILURE)
            )
        ]
        if bad:
            ev = [f.evidence(self._real) for f in bad[:5]]
            return _Verdict(Verdict.FAIL, f"{len(bad)} replies with a wrong comm_type or reply_code", ev)
        return _Verdict(Verdict.PASS, f"{len(replies)} replies, all SERVICE_REPLY with SUCCESS or FAILURE", [])

    # -- motion ------------------------------------------------------------------------------------------------

    async def _motion(self) -> None:
        names = [
            r
            for r in SERVER_RULES
            if r.startswith("motion.") or r in ("motoros.traj-mode", "motoros.busy", "motoros.start-position")
        ]
        moroso = self.dialect.motion_control
        if not moroso:
            self._skip_all(
                ["motoros.traj-mode", "motoros.busy", "motoros.start-position"],
                f"not a MotoROS server (profile {self.options.profile})",
            )
        if not self.options.allow_motion:
            self._skip_all(names, "needs --allow-motion (it moves the robot)")
            return
        pre = await self._rule("motion.preconditions", self._preconditions)
        if pre is None or pre.verdict is not Verdict.PASS:
            self._skip_all(names, "motion.preconditions " + ("not run" if pre is None else "not met: " + pre.detail))
            return
        steps: list[tuple[str, Callable[[], Awaitable[_Verdict]]]] = [
            ("motion.small-move", self._small_move),
            ("motion.stop", self._stop),
        ]
        if moroso:
            steps += [("motoros.busy", self._busy), ("motoros.start-position", self._start_position)]
        steps.append(("motion.out-of-limit", self._out_of_limit))
        try:
            if moroso:
                ready = await self._rule("motoros.traj-mode", self._start_traj_mode)
                if ready is not None and ready.verdict is Verdict.FAIL:
                    raise _Abort("trajectory mode could not be started")
            for rule, check in steps:
                await self._rule(rule, check)
                if self._aborted:
                    # the robot may not be where the next rule needs it: no more motion
                    raise _Abort(self._aborted)
        except _Abort as abort:
            self._skip_all(names, f"an earlier motion rule failed: {abort}")
        finally:
            if self.motion is not None:
                with contextlib.suppress(Exception):
                    await self._exchange(self.motion, self._stop_message())
                if moroso:
                    with contextlib.suppress(Exception):
                        await self._stop_traj_mode_end()

    async def _preconditions(self) -> _Verdict:
        status = self._current_status()
        joints = self._current_joints()
        if status is None or joints is None:
            return _Verdict(Verdict.WARN, "no STATUS or joint state to check the robot by")
        if not self._state_fresh():
            return _Verdict(Verdict.WARN, "the state port went silent: no motion sent without knowing the robot")
        ev = [Evidence.note(f"STATUS {_status_text(status)}")]
        problems = []
        if status.in_motion != TriState.FALSE:
            problems.append(f"in_motion {_tri(status.in_motion)}")
        if status.mode != RobotMode.AUTO:
            problems.append(f"mode {_mode(status.mode)}")
        if status.in_error != TriState.FALSE:
            problems.append(f"in_error {_tri(status.in_error)}")
        if status.e_stopped == TriState.TRUE:
            problems.append("e-stopped")
        if problems:
            return _Verdict(Verdict.WARN, ", ".join(problems) + ": no motion sent", ev)
        return _Verdict(Verdict.PASS, "idle, AUTO, not in error", ev)

    def _point(
        self, sequence: int, positions: Sequence[float], seconds: float, since_start: float, ratio: float = 0.1
    ) -> Message:
        if self.dialect.point_type == MsgType.JOINT_TRAJ_PT_FULL:
            return JointTrajPtFull(
                0,
                sequence,
                ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY,
                since_start,
                tuple(positions),
                (0.0,) * len(positions),
            )
        return JointTrajPt(sequence, tuple(positions), velocity=ratio if seconds > 0 else 0.0, duration=seconds)

    def _sequences(self) -> tuple[int, int]:
        """A two-point trajectory's sequence numbers: streamed (0, 1), or for ABB a download (-1,
        -3): its RAPID server only adds streamed points to its buffer and runs them at -3 (§8.2)."""
        if self.options.profile == "abb":
            return SpecialSeq.START_TRAJECTORY_DOWNLOAD, SpecialSeq.END_TRAJECTORY
        return 0, 1

    def _accepted(self, reply: Seen | None) -> bool:
        msg = reply.message if reply else None
        if msg is None:
            return False
        if isinstance(msg, MotoMotionReply):
            return msg.result == MotoResult.SUCCESS
        return msg.comm_type == CommType.SERVICE_REPLY and msg.reply_code == ReplyCode.SUCCESS

    def _target(self, start: tuple[float, ...], offset: float) -> list[float]:
        target = list(start)
        target[self.options.joint - 1] += offset
        return target

    async def _send_move(
        self, start: tuple[float, ...], target: Sequence[float], seconds: float, ev: list[Evidence], what: str
    ) -> None:
        """A two-point trajectory from where the robot is to ``target`` in ``seconds``, both points
        accepted (BUSY is resent: MotoROS's flow control); else :class:`_Abort` saying why, with
        the frames."""
        assert self.motion is not None
        first, second = self._sequences()
        for seq, pos, dt in ((first, start, 0.0), (second, target, seconds)):
            reply = await self._send_point(self._point(seq, pos, dt, dt), ev)
            if reply is None:
                why = "the connection was closed" if not self.motion.alive else "no reply"
                raise _Abort(f"{what}: {why} (point {seq})", ev)
            if not self._accepted(reply):
                raise _Abort(f"{what}: point {seq} was refused", ev)

    async def _send_point(self, point: Message, ev: list[Evidence]) -> Seen | None:
        assert self.motion is not None
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.options.motion_timeout
        while True:
            sent, reply = await self._exchange(self.motion, point)
            busy = (
                reply is not None
                and isinstance(reply.message, MotoMotionReply)
                and reply.message.result == MotoResult.BUSY
            )
            if not busy or loop.time() > deadline:
                ev.append(sent.evidence(self._real))
                if reply is not None:
                    ev.append(reply.evidence(self._real))
                return reply
            await asyncio.sleep(0.01)  # MotoROS's client resends a BUSY point every few ms

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

    async def _settle(self, timeout: float) -> tuple[float, ...] | None:
        """Wait for in_motion FALSE (or the joints still, when STATUS says UNKNOWN) and return the
        joints then."""
        last: list[tuple[float, ...]] = []

        def done(joints: tuple[float, ...], status: Status | None) -> bool:
            last.append(joints)
            if status is not None and status.in_motion == TriState.FALSE:
                return len(last) > 1 and _distance(last[-2], joints) <= STILL
            if status is not None and status.in_motion == TriState.TRUE:
                return False
            # in_motion UNKNOWN (the C++ default, §5): still over ten joint states
            return len(last) > 10 and _distance(last[-11], joints) <= STILL

        if not await self._wait_state(done, timeout):
            return None
        return self._current_joints()

    async def _return_to(self, start: tuple[float, ...]) -> None:
        """Move back to where a rule began (a rule leaves the robot where it found it)."""
        now = self._current_joints()
        if now is None or _distance(now, start) <= self.options.tolerance:
            return
        ev: list[Evidence] = []
        await self._send_move(now, start, self.options.move_time, ev, "the move back to the start position")
        if await self._settle(self.options.move_time + self.options.motion_timeout) is None:
            raise _Abort("the move back to the start position did not end", ev)

    async def _small_move(self) -> _Verdict:
        o = self.options
        start = self._current_joints()
        assert start is not None
        target = self._target(start, o.amplitude)
        ev = [
            Evidence.note(
                f"joint {o.joint}: {start[o.joint - 1]:.5f} -> {target[o.joint - 1]:.5f} rad in {o.move_time:g} s"
            )
        ]
        sent_at = time.monotonic()
        self._saw_in_motion = False
        await self._send_move(start, target, o.move_time, ev, "a small move near the current position")
        final = await self._settle_after_motion(o.move_time + o.motion_timeout)
        took = time.monotonic() - sent_at
        await self._rule("motion.in-motion", lambda: self._in_motion_verdict(final, ev))
        if final is None:
            raise _Abort(f"the move did not end within {o.move_time + o.motion_timeout:g} s", ev)
        error = _distance(final, target)
        ev.append(Evidence.note(f"reached {final[o.joint - 1]:.5f}, error {error:.5f} rad after {took:.2f} s"))
        await self._return_to(start)
        if error > o.tolerance:
            return _Verdict(Verdict.FAIL, f"stopped {error:.4f} rad from the target (tolerance {o.tolerance:g})", ev)
        return _Verdict(Verdict.PASS, f"target reached within {error:.5f} rad in {took:.2f} s", ev)

    async def _settle_after_motion(self, timeout: float) -> tuple[float, ...] | None:
        """Wait for the move to begin (in_motion TRUE or the joints leaving the start) and then end."""
        start = self._current_joints()
        assert start is not None
        began = await self._wait_state(
            lambda j, s: self._saw_in_motion or _distance(j, start) > STILL,
            min(timeout, 2.0 + self.options.move_time / 2),
        )
        if not began:
            return self._current_joints()
        return await self._settle(timeout)

    async def _in_motion_verdict(self, final: tuple[float, ...] | None, ev: list[Evidence]) -> _Verdict:
        status = self._current_status()
        if status is None:
            raise _Skip("no STATUS")
        if not self._saw_in_motion:
            return _Verdict(Verdict.FAIL, "in_motion never TRUE during the move", ev[:1])
        if final is None or status.in_motion != TriState.FALSE:
            return _Verdict(
                Verdict.FAIL,
                f"in_motion {_tri(status.in_motion)} after the move (a ROS goal would never succeed)",
                ev[:1],
            )
        return _Verdict(Verdict.PASS, "TRUE while moving, FALSE after", [])

    async def _stop(self) -> _Verdict:
        o = self.options
        start = self._current_joints()
        assert start is not None and self.motion is not None
        seconds = 2 * o.move_time
        target = self._target(start, o.amplitude)
        ev: list[Evidence] = [Evidence.note(f"a {seconds:g} s move of joint {o.joint}, stopped once it moves")]
        await self._send_move(start, target, seconds, ev, "the move to stop")
        # STOP once a tenth of the way is done (the move is then surely under way)
        moving = await self._wait_state(lambda j, s: _distance(j, start) > o.amplitude / 10, seconds + o.motion_timeout)
        at_stop = self._current_joints()
        if not moving or at_stop is None:
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            raise _Skip("the move did not begin; STOP not tried")
        stop = self._stop_message()
        sent, reply = await self._exchange(self.motion, stop)
        ev += [sent.evidence(self._real)] + ([reply.evidence(self._real)] if reply else [])
        if reply is None or not self._answers(stop, reply):
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            return _Verdict(
                Verdict.FAIL, f"STOP not answered within {o.reply_timeout:g} s (the client hangs, §10 pitfall 5)", ev
            )
        latency = (reply.time - sent.time) * 1000
        left = _distance(at_stop, target)
        if left <= o.tolerance:
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            raise _Skip(
                f"the move was over when STOP was sent (answered in {latency:.1f} ms): the server does not "
                "take the move's time (Fanuc runs at a fixed speed, §8.3); try a larger --move-time"
            )
        rest = max(2.0, o.move_time)
        final = await self._settle(rest)
        if final is None:
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            return _Verdict(Verdict.FAIL, f"still moving {rest:g} s after STOP", ev)
        short = _distance(final, target)
        ev.append(
            Evidence.note(
                f"STOP sent {left:.5f} rad short of the target, answered in {latency:.1f} ms; came to rest "
                f"{short:.5f} rad short"
            )
        )
        await self._return_to(start)
        if short <= o.tolerance:
            return _Verdict(Verdict.FAIL, "the robot went on to the target after STOP", ev)
        return _Verdict(Verdict.PASS, f"answered in {latency:.1f} ms, stopped {short:.4f} rad short", ev)

    async def _out_of_limit(self) -> _Verdict:
        """A point far beyond any joint's range, timed to take 1000 s at 1 % of the speed limit, so
        that a server that wrongly accepts it would creep towards it, and a STOP at once on its
        reply: whatever the server does, the robot cannot go far."""
        o = self.options
        start = self._current_joints()
        assert start is not None and self.motion is not None
        target = self._target(start, BEYOND_LIMITS)
        seconds = BEYOND_SECONDS
        ev: list[Evidence] = [
            Evidence.note(
                f"joint {o.joint} to {target[o.joint - 1]:.2f} rad ({BEYOND_LIMITS:g} rad beyond), in {seconds:g} s"
            )
        ]
        first_seq, second_seq = self._sequences()
        first = await self._send_point(self._point(first_seq, start, 0.0, 0.0), ev)
        if not self._accepted(first):
            raise _Skip("the trajectory's first point, at the current position, was refused")
        reply = await self._send_point(self._point(second_seq, target, seconds, seconds, ratio=0.01), ev)
        accepted = self._accepted(reply)
        if accepted or reply is None:
            with contextlib.suppress(Exception):
                await self._exchange(self.motion, self._stop_message())
        moved = await self._wait_state(lambda j, s: _distance(j, start) > 10 * STILL, 0.5)
        fresh = self._state_fresh()
        if not accepted and reply is not None:
            with contextlib.suppress(Exception):
                await self._exchange(self.motion, self._stop_message())  # close the trajectory begun
        if moved:
            ev.append(Evidence.note(f"moved: {self._moved_since(start)}"))
            await self._settle(o.motion_timeout)
            await self._return_to(start)
            return _Verdict(Verdict.FAIL, "the robot moved towards a point beyond its limits", ev)
        if not fresh:
            raise _Abort("the state port went silent: whether the robot moved cannot be told", ev)
        if reply is None:
            return _Verdict(Verdict.FAIL, "no reply to the point (nothing moved)", ev)
        if accepted:
            if self.options.profile == "abb":
                # RAPID acknowledges every point; the motion task refuses it later (§8.2)
                return _Verdict(
                    Verdict.WARN, "acknowledged, as ABB's server acknowledges every point; nothing moved", ev
                )
            return _Verdict(
                Verdict.FAIL,
                "accepted a point beyond its limits (stopped at once; nothing moved): a client cannot "
                "know it will not run",
                ev,
            )
        return _Verdict(Verdict.PASS, "refused, nothing moved", ev)

    # -- MotoROS ---------------------------------------------------------------------------------------------

    async def _ctrl(
        self, command: MotoCommand, ev: list[Evidence], timeout: float | None = None
    ) -> MotoMotionReply | None:
        assert self.motion is not None
        sent, reply = await self._exchange(self.motion, MotoMotionCtrl(0, 0, command), timeout)
        ev.append(sent.evidence(self._real))
        if reply is not None:
            ev.append(reply.evidence(self._real))
        msg = reply.message if reply else None
        return msg if isinstance(msg, MotoMotionReply) else None

    async def _start_traj_mode(self) -> _Verdict:
        ev: list[Evidence] = []
        start = await self._ctrl(MotoCommand.START_TRAJ_MODE, ev, self.options.motion_timeout)
        if start is None or start.result != MotoResult.SUCCESS:
            return _Verdict(Verdict.FAIL, "START_TRAJ_MODE not answered SUCCESS", ev)
        ready = await self._ctrl(MotoCommand.CHECK_MOTION_READY, ev)
        if ready is None or ready.result != MotoResult.TRUE:
            return _Verdict(Verdict.FAIL, "not ready after START_TRAJ_MODE", ev)
        # the end of trajectory mode is judged when the suite stops it (_stop_traj_mode_end)
        return _Verdict(Verdict.PASS, "START_TRAJ_MODE SUCCESS, then ready", ev)

    async def _stop_traj_mode_end(self) -> None:
        ev: list[Evidence] = []
        stop = await self._ctrl(MotoCommand.STOP_TRAJ_MODE, ev)
        ready = await self._ctrl(MotoCommand.CHECK_MOTION_READY, ev)
        result = next((r for r in self.report.results if r.rule == "motoros.traj-mode"), None)
        if result is None or result.verdict is not Verdict.PASS:
            return
        result.evidence.extend(ev[:4])
        if stop is None or stop.result != MotoResult.SUCCESS:
            result.verdict, result.detail = Verdict.FAIL, "STOP_TRAJ_MODE not answered SUCCESS"
        elif ready is None or ready.result == MotoResult.TRUE:
            result.verdict, result.detail = Verdict.FAIL, "still ready after STOP_TRAJ_MODE"
        else:
            result.detail = "START_TRAJ_MODE made it ready, STOP_TRAJ_MODE not ready"

    async def _busy(self) -> _Verdict:
        o = self.options
        start = self._current_joints()
        assert start is not None and self.motion is not None
        count = 8
        step = o.move_time / 4
        ev: list[Evidence] = [
            Evidence.note(f"{count} points {step:g} s apart, each sent as soon as the last was taken")
        ]
        busy = 0
        points = [self._point(0, start, 0.0, 0.0)]
        for k in range(1, count):
            offset = o.amplitude * (k / (count - 1))
            points.append(self._point(k, self._target(start, offset), step, k * step))
        loop = asyncio.get_running_loop()
        deadline = loop.time() + o.motion_timeout + count * step
        for point in points:
            while True:
                sent, reply = await self._exchange(self.motion, point)
                msg = reply.message if reply else None
                if isinstance(msg, MotoMotionReply) and msg.result == MotoResult.BUSY:
                    busy += 1
                    if busy <= 3:
                        ev += [sent.evidence(self._real), reply.evidence(self._real)] if reply else []
                    if msg.sequence != getattr(point, "sequence", None):
                        return _Verdict(Verdict.FAIL, f"a BUSY reply names sequence {msg.sequence}", ev)
                    if loop.time() > deadline:
                        return _Verdict(Verdict.FAIL, "BUSY for longer than the trajectory lasts", ev)
                    await asyncio.sleep(0.01)
                    continue
                if not self._accepted(reply):
                    ev += [sent.evidence(self._real)] + ([reply.evidence(self._real)] if reply else [])
                    raise _Abort(f"point {getattr(point, 'sequence', '?')} refused", ev)
                break
        target = self._target(start, o.amplitude)
        final = await self._settle(count * step + o.motion_timeout)
        if final is None:
            raise _Abort("the trajectory did not end", ev)
        error = _distance(final, target)
        await self._return_to(start)
        ev.append(Evidence.note(f"{busy} BUSY replies; the last point reached within {error:.5f} rad"))
        if error > o.tolerance:
            return _Verdict(Verdict.FAIL, f"ended {error:.4f} rad from the last point: a BUSY point was lost", ev)
        return _Verdict(Verdict.PASS, f"{busy} BUSY replies, every point taken, the last reached", ev)

    async def _start_position(self) -> _Verdict:
        o = self.options
        start = self._current_joints()
        assert start is not None
        off = self._target(start, o.amplitude)
        ev: list[Evidence] = [Evidence.note(f"sequence 0 at joint {o.joint} + {o.amplitude:g} rad")]
        reply = await self._send_point(self._point(0, off, 0.0, 0.0), ev)
        moved = await self._wait_state(lambda j, s: _distance(j, start) > 10 * STILL, 0.5)
        msg = reply.message if reply else None
        if not moved and not self._state_fresh():
            raise _Abort("the state port went silent: whether the robot moved cannot be told", ev)
        if moved:
            await self._settle(o.motion_timeout)
            await self._return_to(start)
            return _Verdict(Verdict.FAIL, "the robot moved (jumped to a start point away from it)", ev)
        if not isinstance(msg, MotoMotionReply):
            return _Verdict(Verdict.FAIL, "no MOTO_MOTION_REPLY", ev)
        if msg.result != MotoResult.INVALID or msg.subcode != InvalidSubcode.DATA_START_POS:
            verdict = Verdict.FAIL if msg.result == MotoResult.SUCCESS else Verdict.WARN
            return _Verdict(verdict, f"result {msg.result} subcode {msg.subcode}, not INVALID 3011", ev)
        return _Verdict(Verdict.PASS, "INVALID 3011 (DATA_START_POS), nothing moved", ev)


async def run_server_suite(options: ServerSuiteOptions) -> Report:
    """Run the server suite with ``options`` and return its report."""
    return await ServerSuite(options).run()


# -- helpers -----------------------------------------------------------------------------------------


def _real_size(seen: Seen) -> int | None:
    """The float size a joint-state frame decodes in (its layout fits one real size only); ``None``
    for a frame that tells nothing (STATUS has no reals)."""
    for size in (4, 8):
        decoded = decode_or_error(seen.raw, WireFormat(seen.order, size))
        if isinstance(decoded, JointPosition | JointFeedback | JointFeedbackEx):
            return size
    return None


def _joints_of(msg: Message | None) -> tuple[float, ...] | None:
    if isinstance(msg, JointPosition):
        return tuple(msg.joint_data)
    if isinstance(msg, JointFeedback) and msg.robot_id == 0:
        return tuple(msg.positions)
    return None


def _distance(a: Sequence[float], b: Sequence[float]) -> float:
    return max((abs(x - y) for x, y in zip(a, b, strict=False)), default=0.0)


def _p99(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))] if ordered else 0.0


def _first_of_each(frames: list[Seen]) -> list[Seen]:
    seen: dict[int, Seen] = {}
    for f in frames:
        if f.message is not None:
            seen.setdefault(f.message.msg_type, f)
    return list(seen.values())[:4]


def _has_reals(msg: Message) -> bool:
    return any("r" in code for _, code in type(msg).LAYOUT) if type(msg).LAYOUT else False


def _type_name(msg_type: int) -> str:
    return type_name(msg_type) or str(msg_type)


def _name(msg: Message) -> str:
    if isinstance(msg, RawMessage):
        return f"type {msg.msg_type}"
    return msg.name


def _tri(value: int) -> str:
    try:
        return TriState(value).name
    except ValueError:
        return str(value)


def _mode(value: int) -> str:
    try:
        return RobotMode(value).name
    except ValueError:
        return str(value)


def _status_text(s: Status) -> str:
    return (
        f"drives {_tri(s.drives_powered)}, e_stopped {_tri(s.e_stopped)}, in_error {_tri(s.in_error)} "
        f"(code {s.error_code}), in_motion {_tri(s.in_motion)}, motion_possible {_tri(s.motion_possible)}, "
        f"mode {_mode(s.mode)}"
    )
