"""The client suite's rules: what a client under test sends, judged by what real controllers do with it.

The proxy in :mod:`.client` plays the controller; an :class:`Observer` judges the client. The proxy
feeds it as the bytes pass (each connection opened and closed, every frame the client sends, each
reply once it reached the client, each injection, the robot's joint state) and asks it for the
verdicts at the end; the observer touches no socket and never waits (it runs, synchronous, on the
proxy's event loop). A client is judged by what the controllers it will meet do with its frames,
not by what the protocol would allow (the sections cited are simple-message.md's):

* ``client.byte-order``: every frame in the controller's byte order. Every peer is built for one
  byte order and cannot detect another (§1.3, §10 pitfall 1: Fanuc and the FS100 big-endian, the
  rest little-endian).
* ``client.stop-and-wait``: one point request awaits its reply at a time, as in the reference
  streamer (§4.2): replies carry no request id, and MotoROS and Fanuc keep a one-point buffer (§8.1,
  §8.3). A STOP is the exception: it must be sent even while a point waits for its reply (§12 test
  8; a server that delays a point's reply for flow control must still be stoppable); a point sent
  while the STOP waits is not.
* ``client.sequence``: sequences count 0, 1, 2... per trajectory, the special values used as the
  reference streamer and downloader use them (REP-I0006, §4.1, §4.2, §4.4); MotoROS refuses
  negative sequences (§8.1).
* ``client.point-fields``: fields finite and in range: JOINT_TRAJ_PT's velocity ratio and segment
  duration (§4.3), JOINT_TRAJ_PT_FULL's valid_fields 0x07 and time below 14400 s (§8.1,
  motoman#244), and the point types the controller takes; a WARN for a velocity far above what the
  positions and times around it imply.
* ``client.first-point``: each trajectory starts where the robot is (within ``start_tolerance``):
  MotoROS refuses a start more than 30 pulses away (§8.1, §10 pitfall 10).
* ``client.stop``: a STOP is the controller's (sequence -4 as a request, §4.2, §11 item 8; MotoROS's
  MOTO_MOTION_CTRL STOP_MOTION, §8.1), is answered before the next point, and is followed by a new
  trajectory.
* ``client.busy-reaction``: a point answered BUSY is sent again, unchanged, before any other, as
  motoman_driver does (§8.1: the FS100 trace has 48 BUSY replies out of 58).
* ``client.failure-reaction``: after a refused point, no later point of that trajectory (the
  controller never queued the refused one): a FAIL for MotoROS (motoman_driver aborts, §8.1), a
  WARN elsewhere (the reference streamer ignores reply codes, industrial_core#118, §10 pitfall 6).
* ``client.reconnect``: a motion connection after the first begins with a new trajectory, starting
  where the robot is, or a STOP; nothing of the interrupted trajectory is sent again (industrial_core
  PR #263, §7, §10 pitfall 11, §12 test 7).

Each verdict names the real peer behaviour it comes from and carries the frames that made it (hex
and decoded), at most ten per rule; a rule that saw nothing to judge is SKIPped with what the client
should do to exercise it. Nothing a client sends grows the observer without bound: a point is kept
only while a rule still needs it (the ones waiting for the next joint state, the last few in
flight, the acknowledged ones of the current trajectory), and details and evidence are capped.
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Final

from ..constants import CommType, MotoCommand, MotoResult, MsgType, ReplyCode, SpecialSeq, ValidFields
from ..dialects import Dialect
from ..errors import MalformedMessage
from ..messages import (
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
)
from ..wire import ByteOrder, WireFormat
from .links import other_order
from .report import Evidence, Report, RuleResult, Verdict

__all__ = ["RULES", "SAME", "LinkState", "Observer", "Point", "Positions"]

#: the rules, in report order
RULES: Final = (
    "client.byte-order",
    "client.stop-and-wait",
    "client.sequence",
    "client.point-fields",
    "client.first-point",
    "client.stop",
    "client.busy-reaction",
    "client.failure-reaction",
    "client.reconnect",
)

#: MotoROS refuses a trajectory time from this many seconds (float32 resolution; §8.1, motoman#244)
MAX_TIME = 14400.0
#: evidence items per rule, failure details kept per rule, points waiting for the next joint state
MAX_EVIDENCE = 10
MAX_DETAILS = 20
MAX_WAITING = 64
#: the longest frame shown whole in the evidence (bytes)
MAX_SHOWN = 1024
#: motion groups whose speeds are followed per connection (MotoROS has at most 4)
MAX_GROUPS = 8
#: acknowledged points remembered per connection (to recognise one sent again after a reconnect)
MAX_ACKED = 4096
#: a velocity this far above what the positions and times imply is implausible (rad/s, x)
SPEED_MARGIN = 0.05
SPEED_FACTOR = 2.0
#: values the same within this are the same point (float32 on the wire is far coarser)
SAME = 1e-6

_STOP_SEQ = int(SpecialSeq.STOP_TRAJECTORY)
_START_SEQS = (0, int(SpecialSeq.START_TRAJECTORY_DOWNLOAD), int(SpecialSeq.START_TRAJECTORY_STREAMING))
_POINT_TYPES = frozenset({MsgType.JOINT_TRAJ_PT, MsgType.JOINT_TRAJ_PT_FULL, MsgType.JOINT_TRAJ_PT_FULL_EX})
#: the rule that reports each injection
_INJECTION_RULES = {"busy": "client.busy-reaction", "failure": "client.failure-reaction", "drop": "client.reconnect"}
_REQUIRED_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY

# -- what the rules see -------------------------------------------------------------------------------

#: one value per joint of one group (positions, velocities or speeds)
Positions = tuple[float, ...]


@dataclass(frozen=True)
class _Group:
    """One motion group of a JOINT_TRAJ_PT_FULL(_EX): what the field and speed checks need."""

    group: int
    valid_fields: int
    time: float
    positions: Positions
    velocities: Positions


@dataclass(eq=False)
class Point:
    """A trajectory point or a STOP the client sent on the motion port."""

    link: LinkState
    frame: bytes
    msg: Message | MalformedMessage
    #: "point", "stop" or "malformed" (a point type whose body fits no layout)
    kind: str
    seq: int | None
    #: a SERVICE_REQUEST (awaits a reply)
    request: bool
    #: group 0's positions (None: the point carries none for group 0)
    positions: Positions | None
    groups: tuple[_Group, ...]
    trajectory: int = 0
    #: the first point of a trajectory (sequence 0, -1 or -2)
    start: bool = False
    #: the previous point sent again after BUSY or FAILURE (not a repeat, nor a new trajectory)
    retry: bool = False
    #: the robot's position when it arrived, and at the next joint state after
    here: Positions | None = None
    after: Positions | None = None
    #: the reply's outcome once it reached the client: "success", "busy", "failure"
    outcome: str | None = None
    #: the injection that answered it, if any
    injected: str | None = None
    #: the first point-ish message of a motion connection after another one (the reconnect rule)
    reconnect: bool = False
    resolved: bool = False

    @property
    def what(self) -> str:
        if self.kind == "stop":
            return "STOP"
        if self.seq is None:
            return "a malformed point"
        return f"point {self.seq}"


@dataclass(eq=False)
class _Prev:
    """The last point of a group in the current trajectory, for the time and speed checks."""

    seq: int
    time: float
    positions: Positions
    velocities: Positions
    point: Point
    #: the implied speed (per joint) of the segment that ends at it, if any
    before: Positions | None = None


@dataclass(eq=False)
class LinkState:
    """What the rules know about one of the client's connections."""

    id: int
    role: str
    peer: str
    #: 1 for the first motion connection of the run, 2 for the next...
    motion_index: int = 0
    #: point requests whose reply has not reached the client (the latest few: enough to show one)
    in_flight: deque[Point] = field(default_factory=lambda: deque(maxlen=MAX_WAITING))
    #: None (no trajectory under way), "stream" or "download"
    mode: str | None = None
    last: Point | None = None
    trajectory: int = 0
    acked: dict[int, Positions] = field(default_factory=dict)
    pending_stop: Point | None = None
    after_stop: Point | None = None
    seen_point: bool = False
    prev: dict[int, _Prev] = field(default_factory=dict)
    #: the cutter gave up on this connection's bytes (warned once)
    uncut: bool = False
    #: the last JOINT_TRAJ_PT's positions (a segment's timing is judged against them)
    jtp_positions: Positions | None = None

    @property
    def name(self) -> str:
        return f"{self.role} connection {self.id} ({self.peer})"


class _Rule:
    """One rule's findings: failures and warnings (details capped), evidence (capped), and how many
    things it checked."""

    def __init__(self, rule: str, title: str, source: str) -> None:
        self.rule = rule
        self.title = title
        self.source = source
        self.checked = 0
        self.failures: list[str] = []
        self.fail_count = 0
        self.warnings: list[str] = []
        self.warn_count = 0
        self.evidence: list[Evidence] = []
        self.samples: list[Evidence] = []
        self.notes: list[Evidence] = []

    def fail(self, detail: str, *evidence: Evidence) -> None:
        self.fail_count += 1
        if len(self.failures) < MAX_DETAILS:
            self.failures.append(detail)
        self.keep(*evidence)

    def warn(self, detail: str, *evidence: Evidence) -> None:
        self.warn_count += 1
        if len(self.warnings) < MAX_DETAILS:
            self.warnings.append(detail)
        self.keep(*evidence)

    def sample(self, *evidence: Evidence) -> None:
        """Representative evidence of a pass (shown when nothing failed or warned)."""
        for item in evidence:
            if len(self.samples) < 3:
                self.samples.append(item)

    def note(self, text: str) -> None:
        if len(self.notes) < 4:
            self.notes.append(Evidence.note(text))

    def keep(self, *evidence: Evidence) -> None:
        for item in evidence:
            if len(self.evidence) < MAX_EVIDENCE:
                self.evidence.append(item)

    def result(self, passed: str, skipped: str) -> RuleResult:
        if self.fail_count:
            verdict, detail, shown = Verdict.FAIL, _summary(self.failures, self.fail_count), self.evidence
        elif self.warn_count:
            verdict, detail, shown = Verdict.WARN, _summary(self.warnings, self.warn_count), self.evidence
        elif self.checked:
            verdict, detail, shown = Verdict.PASS, passed, self.samples
        else:
            verdict, detail, shown = Verdict.SKIP, skipped, []
        evidence = (self.notes + list(shown))[:MAX_EVIDENCE]
        return RuleResult(self.rule, self.title, verdict, detail, self.source, evidence)


def _summary(details: list[str], count: int) -> str:
    more = count - 1
    return details[0] + (f" (and {more} more)" if more else "")


def _max_gap(a: Positions, b: Positions) -> float:
    return max((abs(x - y) for x, y in zip(a, b, strict=False)), default=0.0)


def _same(a: Positions | None, b: Positions | None) -> bool:
    return a is not None and b is not None and _max_gap(a, b) <= SAME


def _same_positions(a: Point, b: Point) -> bool:
    """The same positions in every group (a point sent again)."""
    if a.groups or b.groups:
        key_a = sorted((g.group, g.positions) for g in a.groups)
        key_b = sorted((g.group, g.positions) for g in b.groups)
        return len(key_a) == len(key_b) and all(
            ga == gb and _same(pa, pb) for (ga, pa), (gb, pb) in zip(key_a, key_b, strict=True)
        )
    return _same(a.positions, b.positions)


def _finite(values: Iterable[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def _outcome(reply: Message | MalformedMessage) -> str:
    """A reply's meaning for the client: MotoROS's result (0 success, 1 BUSY), else the reply_code."""
    if isinstance(reply, MotoMotionReply):
        if reply.result == MotoResult.SUCCESS:
            return "success"
        return "busy" if reply.result == MotoResult.BUSY else "failure"
    if isinstance(reply, MalformedMessage):
        return "failure"
    return "success" if reply.reply_code == ReplyCode.SUCCESS else "failure"


def _groups_of(msg: Message) -> tuple[_Group, ...]:
    if isinstance(msg, JointTrajPtFull):
        return (_Group(msg.robot_id, int(msg.valid_fields), msg.time, msg.positions, msg.velocities),)
    if isinstance(msg, JointTrajPtFullEx):
        return tuple(
            _Group(g.group_no, int(g.valid_fields), g.time, g.positions, g.velocities) for g in msg.valid_groups
        )
    return ()


def _group0(msg: Message, groups: tuple[_Group, ...]) -> Positions | None:
    if isinstance(msg, JointTrajPt):
        return msg.joint_data
    for group in groups:
        if group.group == 0:
            return group.positions
    return None


class Observer:
    """Every rule's state, fed by the proxy as frames pass (all synchronous, on the event loop).

    ``profile`` names the controller played (abb, fanuc, generic, motoros, staubli), ``dialect`` is its
    dialect (MotoROS's motion control decides several rules), ``wire`` the controller's wire format;
    ``start_tolerance`` (rad) and ``inject`` are the suite's options of the same names, ``clock`` the
    event loop's time.
    """

    def __init__(
        self,
        profile: str,
        dialect: Dialect,
        wire: WireFormat,
        *,
        start_tolerance: float,
        inject: frozenset[str],
        clock: Callable[[], float],
    ) -> None:
        self.profile = profile
        self.moto = dialect.motion_control
        self.wire = wire
        #: the wire format of a frame the client sent in the other byte order
        self.other_wire = wire.with_byte_order(other_order(wire.byte_order))
        self.start_tolerance = start_tolerance
        self.inject = inject
        self.clock = clock
        #: when the run started (set by ClientSuite.start)
        self.t0 = 0.0
        self.links: dict[int, LinkState] = {}
        self.motion_links = 0
        self.trajectories = 0
        #: how the first three trajectories were sent ("stream", "download")
        self.modes: dict[int, str] = {}
        self.points = 0
        self.point_requests = 0
        self.frames = {ByteOrder.LITTLE: 0, ByteOrder.BIG: 0}
        self.state: Positions | None = None
        self.waiting: deque[Point] = deque()
        #: what the previous motion connection had acknowledged, when a new one opened
        self.interrupted: dict[int, Positions] = {}
        self.last_motion: LinkState | None = None
        self.dropped: LinkState | None = None
        #: the injection log, one line per injection, and the injections made (each is made once)
        self.injections: list[str] = []
        self.done: set[str] = set()
        self.busy_watch: Point | None = None
        self.failure_watch: Point | None = None
        self.failure_retry: Point | None = None
        self.stops = 0
        self.rules = self._rules()

    def _rules(self) -> dict[str, _Rule]:
        moto = self.moto
        return {
            "client.byte-order": _Rule(
                "client.byte-order",
                "every frame the client sends is in the controller's byte order",
                "every peer is built for one byte order and cannot detect another (simple-message.md §1.3, "
                "§10 pitfall 1: Fanuc and the FS100 big-endian, the rest little-endian)",
            ),
            "client.stop-and-wait": _Rule(
                "client.stop-and-wait",
                "one point request (STOP included) awaits its reply at a time",
                "industrial_robot_client JointTrajectoryStreamer: one request in flight (simple-message.md §4.2); "
                "replies carry no request id, and MotoROS and Fanuc keep a 1-point buffer (§8.1, §8.3)",
            ),
            "client.sequence": _Rule(
                "client.sequence",
                "sequence numbers count 0, 1, 2... per trajectory; special values used as real peers do",
                "REP-I0006 (out-of-order points abort) and the reference streamer and downloader "
                "(simple-message.md §4.1, §4.2, §4.4)"
                + ("; MotoROS refuses negative sequences with INVALID/3005 (§8.1)" if moto else ""),
            ),
            "client.point-fields": _Rule(
                "client.point-fields",
                "point fields are finite and in range",
                "JOINT_TRAJ_PT: a velocity ratio in [0, 1] and a segment duration (simple-message.md §4.3); "
                "JOINT_TRAJ_PT_FULL: MotoROS requires valid_fields 0x07 and time < 14400 s (§8.1, motoman#244)",
            ),
            "client.first-point": _Rule(
                "client.first-point",
                "each trajectory starts where the robot is",
                "MotoROS refuses a start more than 30 pulses away (INVALID/3011, simple-message.md §8.1, §10 pitfall "
                "10); motoman_driver and the reference action start from the current joint state",
            ),
            "client.stop": _Rule(
                "client.stop",
                "a STOP is well formed, answered before the next point, and followed by a new trajectory",
                (
                    "motoman_driver: stop is MOTO_MOTION_CTRL STOP_MOTION as a request (simple-message.md §8.1)"
                    if moto
                    else "JointTrajectoryInterface::trajectoryStop: JOINT_TRAJ_PT sequence -4 as a SERVICE_REQUEST, "
                    "acknowledged (simple-message.md §4.2, §11 item 8; ros-industrial/abb#42)"
                ),
            ),
            "client.busy-reaction": _Rule(
                "client.busy-reaction",
                "after MotoROS's BUSY, the same point is sent again",
                "motoman_driver retries a point answered BUSY (simple-message.md §8.1; the FS100 trace: 48 BUSY "
                "replies out of 58)",
            ),
            "client.failure-reaction": _Rule(
                "client.failure-reaction",
                "after a refused point, no later point of that trajectory",
                (
                    "motoman_driver aborts on any result but SUCCESS and BUSY (simple-message.md §8.1)"
                    if moto
                    else "a refused point is not queued (REP-I0006: reply_code says whether it was enqueued); "
                    "the reference streamer ignores reply codes (industrial_core#118, simple-message.md §10 pitfall 6)"
                ),
            ),
            "client.reconnect": _Rule(
                "client.reconnect",
                "after a reconnect, nothing of the interrupted trajectory is sent again",
                "industrial_core PR #263: after a reconnect, streamed points may be skipped or repeated "
                "(simple-message.md §7, §10 pitfall 11, §12 test 7)",
            ),
        }

    # -- helpers ------------------------------------------------------------------------------------

    def at(self) -> str:
        return f"{self.clock() - self.t0:.2f} s"

    def evidence(
        self, direction: str, frame: bytes, msg: Message | MalformedMessage | None, other: bool = False
    ) -> Evidence:
        wire = self.other_wire if other else self.wire
        decoded = msg if isinstance(msg, Message) else None
        if len(frame) <= MAX_SHOWN:
            return Evidence.frame(direction, frame, decoded, wire.real_size)
        shown = Evidence.frame(direction, frame[:MAX_SHOWN], None, wire.real_size)
        return Evidence(shown.kind, f"{shown.text}... ({len(frame)} bytes)")

    def ev(self, point: Point) -> Evidence:
        return self.evidence("received", point.frame, point.msg)

    # -- connections --------------------------------------------------------------------------------

    def link_opened(self, link_id: int, role: str, peer: str) -> LinkState:
        link = LinkState(link_id, role, peer)
        if role == "motion":
            self.motion_links += 1
            link.motion_index = self.motion_links
            previous = self.last_motion
            if previous is not None:
                self.interrupted = dict(previous.acked)
            self.last_motion = link
        self.links[link_id] = link
        return link

    def link_closed(self, link: LinkState, by: str) -> None:
        self.links.pop(link.id, None)
        if link.role != "motion":
            return
        self._end_trajectory(link)
        if by == "drop":
            self.dropped = link
        watch = self.busy_watch
        if watch is not None and watch.link is link and watch.outcome is not None:
            self.busy_watch = None
            self.rules["client.busy-reaction"].fail(
                f"the client closed the connection instead of resending {watch.what} after BUSY (it gave up)",
                self.ev(watch),
            )
        if self.failure_watch is not None and self.failure_watch.link is link:
            self._failure_passed("closed the connection")

    # -- the client's frames ------------------------------------------------------------------------

    def client_frame(
        self, link: LinkState, frame: bytes, order: ByteOrder | None, msg: Message | MalformedMessage | None
    ) -> Point | None:
        """Note one frame from the client; a motion port's point or STOP comes back as a :class:`Point`."""
        rule = self.rules["client.byte-order"]
        if order is None:
            if link.uncut:
                return None  # said once per connection: the rest of it is passed on uncut
            link.uncut = True
            rule.fail(
                f"{link.name}: a length prefix plausible in neither byte order "
                f"({frame[:4].hex()}); the rest of that connection was passed on uncut",
                Evidence.note(f"{len(frame)} bytes that could not be cut: {frame[:64].hex()}"),
            )
            return None
        self.frames[order] += 1
        rule.checked += 1
        if order is not self.wire.byte_order:
            rule.fail(
                f"{link.name} sent a {order.value}-endian frame at {self.at()}; the controller speaks "
                f"{self.wire.byte_order.value}-endian",
                self.evidence("received", frame, msg, other=True),
            )
            return None
        if rule.checked == 1 and msg is not None:
            rule.sample(self.evidence("received", frame, msg))
        if link.role != "motion" or msg is None:
            return None
        point = self._point(link, frame, msg)
        if point is None:
            return None
        self._judge_point(point)
        return point

    def _point(self, link: LinkState, frame: bytes, msg: Message | MalformedMessage) -> Point | None:
        request = msg.comm_type == CommType.SERVICE_REQUEST
        if isinstance(msg, MalformedMessage):
            if msg.msg_type not in _POINT_TYPES:
                return None
            return Point(link, frame, msg, "malformed", None, request, None, ())
        if isinstance(msg, MotoMotionCtrl):
            if msg.command != MotoCommand.STOP_MOTION:
                return None
            return Point(link, frame, msg, "stop", msg.sequence, request, None, ())
        if not isinstance(msg, JointTrajPt | JointTrajPtFull | JointTrajPtFullEx):
            return None
        groups = _groups_of(msg)
        kind = "stop" if msg.sequence == _STOP_SEQ else "point"
        return Point(link, frame, msg, kind, msg.sequence, request, _group0(msg, groups), groups)

    def _judge_point(self, point: Point) -> None:
        link = point.link
        first_on_link = not link.seen_point
        link.seen_point = True
        if first_on_link and link.motion_index > 1:
            point.reconnect = True
        self._busy_reaction(point)
        self._stop_and_wait(point)
        self._stop_rule(point)
        self._sequence(point)
        self._failure_reaction(point)
        if point.kind == "point" and point.seq is not None:
            self.points += 1
            self._fields(point)
        elif point.kind == "malformed":
            self.rules["client.point-fields"].fail(
                f"{link.name} sent a {_type_name(point)} whose body fits no layout: {point.msg}", self.ev(point)
            )
        if point.start or point.reconnect:
            point.here = self.state
            self.waiting.append(point)
            while len(self.waiting) > MAX_WAITING:
                self._resolve(self.waiting.popleft())

    # stop-and-wait ------------------------------------------------------------------------------------

    def _stop_and_wait(self, point: Point) -> None:
        if not point.request:
            return
        link = point.link
        rule = self.rules["client.stop-and-wait"]
        rule.checked += 1
        self.point_requests += 1
        if link.in_flight and point.kind != "stop":
            pending = link.in_flight[-1]
            rule.fail(
                f"{link.name}: {point.what} sent at {self.at()} while {pending.what} still awaited its reply",
                self.ev(pending),
                self.ev(point),
            )
        elif rule.checked <= 2:
            rule.sample(self.ev(point))
        link.in_flight.append(point)

    # stop -------------------------------------------------------------------------------------------

    def _stop_rule(self, point: Point) -> None:
        link = point.link
        rule = self.rules["client.stop"]
        if link.pending_stop is not None:
            rule.fail(
                f"{link.name}: {point.what} sent before the STOP's reply", self.ev(link.pending_stop), self.ev(point)
            )
        if link.after_stop is not None and point.kind != "malformed":
            stop = link.after_stop
            link.after_stop = None
            if point.kind == "point" and point.seq not in _START_SEQS:
                rule.fail(
                    f"{link.name}: after the STOP came {point.what}, not a new trajectory starting at 0",
                    self.ev(stop),
                    self.ev(point),
                )
        if point.kind != "stop":
            return
        self.stops += 1
        rule.checked += 1
        msg = point.msg
        problem = None
        if self.moto and not isinstance(msg, MotoMotionCtrl):
            problem = (
                f"a {_type_name(point)} with sequence -4: MotoROS refuses negative sequences (INVALID/3005); "
                "its stop is MOTO_MOTION_CTRL STOP_MOTION"
            )
        elif not self.moto and isinstance(msg, MotoMotionCtrl):
            problem = f"MOTO_MOTION_CTRL STOP_MOTION: the {self.profile} controller's stop is sequence -4"
        elif not point.request:
            problem = f"a STOP sent as comm_type {msg.comm_type}, not a SERVICE_REQUEST: nothing acknowledges it"
        elif isinstance(msg, Message) and msg.reply_code != ReplyCode.INVALID:
            problem = (
                f"a STOP request with reply_code {int(msg.reply_code)} (must be 0): refused by the C++ checks (§1.2)"
            )
        if problem is not None:
            rule.fail(f"{link.name}: {problem}", self.ev(point))
        else:
            rule.sample(self.ev(point))
        if point.request:
            link.pending_stop = point

    # sequence ---------------------------------------------------------------------------------------

    def _sequence(self, point: Point) -> None:
        link = point.link
        rule = self.rules["client.sequence"]
        if point.kind == "stop":
            self._end_trajectory(link)
            return
        if point.kind != "point" or point.seq is None:
            return
        rule.checked += 1
        seq = point.seq
        last = link.last
        problem: str | None = None
        warning: str | None = None
        if self.moto:
            if seq < 0:
                problem = f"sequence {seq}: MotoROS takes no negative sequence (INVALID/3005); stop is STOP_MOTION"
            elif seq == 0:
                if (
                    last is not None
                    and last.seq == 0
                    and last.outcome == "busy"
                    and _same(last.positions, point.positions)
                ):
                    point.retry = True
                else:
                    self._start(point, "stream")
            else:
                problem = self._next_in_order(point, last)
            if seq >= 0:
                link.last = point
        else:
            problem, warning = self._generic_sequence(point, last)
        point.trajectory = link.trajectory
        if problem is not None:
            rule.fail(f"{link.name}: {problem}", *([self.ev(last)] if last is not None else []), self.ev(point))
        elif warning is not None:
            rule.warn(f"{link.name}: {warning}", self.ev(point))
        elif rule.checked <= 2:
            rule.sample(self.ev(point))

    def _next_in_order(self, point: Point, last: Point | None) -> str | None:
        """A streamed point's sequence after ``last`` (None: fine)."""
        seq = point.seq
        assert seq is not None
        link = point.link
        if link.mode is None or last is None or last.seq is None:
            link.mode = "stream"  # judged once: the points after it are judged against it
            return f"sequence {seq} before any point 0 of a trajectory on this connection"
        expected = 1 if last.seq < 0 else last.seq + 1  # after -2 (streaming start) comes 1
        if seq == expected:
            return None
        if seq == last.seq:
            if last.outcome in ("busy", "failure"):
                point.retry = True
                return None
            if last.outcome is None:
                return f"point {seq} sent again while its first copy still awaited a reply"
            return f"point {seq} sent again after it was acknowledged (SUCCESS): a repeat"
        if seq > expected:
            return f"sequence {seq} after {last.seq}: a gap (points {expected}..{seq - 1} never sent)"
        return f"sequence {seq} after {last.seq}: it goes back"

    def _generic_sequence(self, point: Point, last: Point | None) -> tuple[str | None, str | None]:
        link = point.link
        seq = point.seq
        assert seq is not None
        download = SpecialSeq.START_TRAJECTORY_DOWNLOAD
        problem: str | None = None
        warning: str | None = None
        # ABB's RAPID server and Stäubli's VAL3 server answer a request whatever its sequence; the
        # C++ servers' downloads are TOPICs, and Fanuc's relay answers no -1, -2, -3
        answered = self.profile in ("abb", "staubli")
        if seq == download:
            if point.request and not answered:
                problem = (
                    "a download's first point (-1) sent as a SERVICE_REQUEST: the reference downloader sends TOPICs "
                    "and Fanuc does not answer -1 (§4.4, §8.3)"
                )
            elif self.profile == "staubli" and not point.request:
                warning = (
                    "a download of TOPICs to Stäubli: VAL3 takes every point as a move and answers none, so the "
                    "points a full queue refuses are lost unseen (pushMotion.pgx:83-113)"
                )
            self._start(point, "download")
        elif seq == SpecialSeq.END_TRAJECTORY:
            if link.mode != "download":
                problem = "-3 (END_TRAJECTORY) outside a download (-1 ... -3)"
            elif point.request and not answered:
                problem = "a download's last point (-3) sent as a SERVICE_REQUEST: downloads are TOPICs (§4.4)"
            link.mode = None
            link.last = None
            return problem, warning
        elif seq == SpecialSeq.START_TRAJECTORY_STREAMING:
            warning = (
                "sequence -2 (START_TRAJECTORY_STREAMING): the reference streamer never sends it (§0 item 7) and "
                "Fanuc does not answer it (§8.3)"
            )
            self._start(point, "stream")
        elif seq < 0:
            problem = f"sequence {seq}: a reserved negative value (special values are -1 to -4, §4.1)"
        elif link.mode == "download":
            if point.request and not answered:
                problem = f"point {seq} of a download sent as a SERVICE_REQUEST (a download is TOPICs, §4.4)"
            elif last is not None and last.seq is not None:
                expected = 1 if last.seq < 0 else last.seq + 1
                if seq != expected:
                    problem = f"download point {seq} after {last.seq}: expected {expected}"
        elif not point.request:
            problem = f"point {seq} sent as a TOPIC outside a download (-1 ... -3): nothing acknowledges it"
            if seq == 0:
                self._start(point, "stream")
        elif seq == 0:
            self._start(point, "stream")
        else:
            problem = self._next_in_order(point, last)
        if seq >= -2:
            link.last = point
        return problem, warning

    def _start(self, point: Point, mode: str) -> None:
        link = point.link
        self._end_trajectory(link)
        self.trajectories += 1
        link.trajectory = self.trajectories
        if self.trajectories <= 3:  # the injections' trajectories
            self.modes[self.trajectories] = mode
        link.mode = mode
        link.acked.clear()
        point.start = True
        point.trajectory = link.trajectory

    def _end_trajectory(self, link: LinkState) -> None:
        """The trajectory under way on ``link`` ended (a STOP, a new one, the connection closed)."""
        for prev in link.prev.values():
            self._speed_check(prev, None)
        link.prev.clear()
        link.mode = None
        link.last = None

    # point fields -------------------------------------------------------------------------------------

    def _fields(self, point: Point) -> None:
        rule = self.rules["client.point-fields"]
        rule.checked += 1
        msg = point.msg
        link = point.link
        problems: list[str] = []
        if isinstance(msg, JointTrajPt):
            if self.moto:
                problems.append("MotoROS takes no JOINT_TRAJ_PT (INVALID/3003): its points are JOINT_TRAJ_PT_FULL")
            if not _finite(msg.joint_data):
                problems.append("a position is not finite")
            if not (math.isfinite(msg.velocity) and 0.0 <= msg.velocity <= 1.0):
                problems.append(f"velocity {msg.velocity:g} is not a ratio in [0, 1] (§4.3)")
            if not (math.isfinite(msg.duration) and 0.0 <= msg.duration < MAX_TIME):
                problems.append(f"duration {msg.duration:g} s is not a segment time in [0, {MAX_TIME:g}) s")
            before, link.jtp_positions = link.jtp_positions, msg.joint_data
            moves = before is not None and point.seq is not None and point.seq > 0
            if moves and before is not None and not _same(before, msg.joint_data) and msg.duration == msg.velocity == 0:
                rule.warn(
                    f"{link.name}: {point.what} moves with neither a duration nor a velocity: no controller can "
                    "time it (ABB times by duration, the C++ servers and Stäubli by velocity, Fanuc by neither, §4.3)",
                    self.ev(point),
                )
        else:
            if self.profile in ("abb", "fanuc"):
                problems.append(f"the {self.profile} controller takes JOINT_TRAJ_PT only (§8.2, §8.3)")
            elif self.profile == "staubli":
                problems.append(
                    "VAL3 misreads JOINT_TRAJ_PT_FULL: its sequence, valid_fields and time all from the robot_id's "
                    "bytes, the speed from joint 1's velocity (decTrajPtFull.pgx:34-55, pushMotion.pgx:58-61)"
                )
            for group in point.groups:
                problems.extend(self._group_fields(point, group))
        if problems:
            rule.fail(f"{link.name}: {point.what}: {'; '.join(problems)}", self.ev(point))
        elif rule.checked <= 2:
            rule.sample(self.ev(point))

    def _group_fields(self, point: Point, group: _Group) -> list[str]:
        problems = []
        name = f"group {group.group}: " if len(point.groups) > 1 or group.group else ""
        if group.valid_fields & _REQUIRED_FIELDS != _REQUIRED_FIELDS:
            problems.append(
                f"{name}valid_fields 0x{group.valid_fields:02x} lacks TIME|POSITION|VELOCITY (MotoROS requires 0x07: "
                "INVALID/3015, §8.1)"
            )
        if not (math.isfinite(group.time) and 0.0 <= group.time < MAX_TIME):
            problems.append(f"{name}time {group.time:g} s is not in [0, {MAX_TIME:g}) s (INVALID/3016, §8.1)")
        if not _finite(group.positions):
            problems.append(f"{name}a position is not finite")
        if not _finite(group.velocities):
            problems.append(f"{name}a velocity is not finite")
        if problems:
            return problems
        link = point.link
        seq = point.seq
        assert seq is not None
        prev = link.prev.get(group.group)
        if prev is None and len(link.prev) >= MAX_GROUPS:
            return problems  # a client inventing group numbers: the first few are judged
        if point.start or prev is None:
            if prev is not None:
                self._speed_check(prev, None)
            link.prev[group.group] = _Prev(seq, group.time, group.positions, group.velocities, point)
            return problems
        if seq == prev.seq:  # the same point again (after BUSY)
            return problems
        if group.time <= prev.time:
            if seq > 0:
                problems.append(
                    f"{name}time {group.time:g} s is not after point {prev.seq}'s {prev.time:g} s (MotoROS: no motion "
                    "for a segment of 0 s or less, §8.1)"
                )
            # a special or reserved sequence (judged by client.sequence) with no time step: no speeds to imply
            return problems
        dt = group.time - prev.time
        speeds = tuple(abs(b - a) / dt for a, b in zip(prev.positions, group.positions, strict=False))
        self._speed_check(prev, speeds)
        link.prev[group.group] = _Prev(seq, group.time, group.positions, group.velocities, point, speeds)
        return problems

    def _speed_check(self, prev: _Prev, after: Positions | None) -> None:
        """WARN when a point's velocities are far above what its neighbouring segments imply."""
        zeros = (0.0,) * len(prev.velocities)
        implied = [max(a, b) for a, b in zip(prev.before or zeros, after or zeros, strict=False)]
        for joint, (v, speed) in enumerate(zip(prev.velocities, implied, strict=False)):
            limit = SPEED_FACTOR * speed + SPEED_MARGIN
            if abs(v) > limit:
                self.rules["client.point-fields"].warn(
                    f"{prev.point.link.name}: point {prev.seq}: joint {joint + 1}'s velocity {v:.4g} rad/s is more "
                    f"than {SPEED_FACTOR:g}x the {speed:.4g} rad/s its positions and times imply (+{SPEED_MARGIN:g})",
                    self.ev(prev.point),
                )
                return

    # first point ------------------------------------------------------------------------------------

    def state_sample(self, positions: Positions) -> None:
        self.state = positions
        while self.waiting:
            point = self.waiting.popleft()
            point.after = positions
            self._resolve(point)

    def _distance(self, point: Point) -> float | None:
        """How far the point is from the robot: the nearer of the state when it arrived and the next one
        (the suite's state lags the client's by up to one state period)."""
        if point.positions is None:
            return None
        gaps = [_max_gap(point.positions, here) for here in (point.here, point.after) if here is not None]
        return min(gaps) if gaps else None

    def _resolve(self, point: Point) -> None:
        if point.resolved:
            return
        point.resolved = True
        distance = self._distance(point)
        tolerance = self.start_tolerance
        if point.start:
            rule = self.rules["client.first-point"]
            if distance is None:
                why = "no joint state from the controller yet" if point.positions is not None else "no group 0 in it"
                rule.note(f"trajectory {point.trajectory}'s first point not judged: {why}")
            else:
                rule.checked += 1
                if distance > tolerance:
                    rule.fail(
                        f"{point.link.name}: trajectory {point.trajectory} starts {distance:.4g} rad from the robot "
                        f"(tolerance {tolerance:g} rad)",
                        self.ev(point),
                        Evidence.note(f"the robot was at {_fmt(point.here)}"),
                    )
                elif rule.checked <= 2:
                    rule.sample(self.ev(point))
        if point.reconnect:
            self._reconnect(point, distance)

    def _flush_waiting(self) -> None:
        while self.waiting:
            self._resolve(self.waiting.popleft())

    # reconnect ----------------------------------------------------------------------------------------

    def _reconnect(self, point: Point, distance: float | None) -> None:
        rule = self.rules["client.reconnect"]
        if point.kind == "malformed" or point.seq is None:
            return
        rule.checked += 1
        if point.kind == "stop":
            rule.sample(self.ev(point))
            return
        link = point.link
        known = self.interrupted.get(point.seq)
        resent = known is not None and _same(known, point.positions)
        tolerance = self.start_tolerance
        if point.seq not in _START_SEQS:
            again = " (sent and acknowledged before: a repeat)" if resent else ""
            rule.fail(
                f"{link.name}: the first point on the new connection has sequence {point.seq}{again}, not 0",
                self.ev(point),
            )
        elif distance is not None and distance > tolerance:
            again = ", the point 0 acknowledged before the reconnect" if resent else ""
            rule.fail(
                f"{link.name}: the first point on the new connection is {distance:.4g} rad from the robot{again}",
                self.ev(point),
            )
        else:
            rule.sample(self.ev(point))

    # busy and failure -------------------------------------------------------------------------------

    def _busy_reaction(self, point: Point) -> None:
        watch = self.busy_watch
        if watch is None or watch.link is not point.link or watch.outcome is None or point.kind == "malformed":
            return
        self.busy_watch = None
        rule = self.rules["client.busy-reaction"]
        if point.kind == "point" and point.seq == watch.seq and _same_positions(point, watch):
            rule.checked += 1
            rule.sample(self.ev(point))
            return
        if point.kind == "stop":
            why = "sent STOP instead (it gave up)"
        elif point.seq == watch.seq:
            why = f"sent sequence {point.seq} again with other positions"
        elif point.seq is not None and point.seq > (watch.seq or 0):
            why = f"sent point {point.seq} instead: {watch.what} was skipped"
        else:
            why = f"started over with point {point.seq} (it gave up)"
        rule.fail(f"after BUSY to {watch.what}, the client {why}", self.ev(watch), self.ev(point))

    def _failure_reaction(self, point: Point) -> None:
        watch = self.failure_watch
        if watch is None or watch.link is not point.link or watch.outcome is None or point.kind == "malformed":
            return
        if point.kind == "stop" or point.start:
            self._failure_passed("sent STOP" if point.kind == "stop" else f"started trajectory {point.trajectory}")
            return
        if point.seq == watch.seq:
            self.failure_retry = point
            return
        retry = self.failure_retry
        if retry is not None and retry.outcome == "success":
            self._failure_passed(f"sent {watch.what} again (accepted) and went on")
            return
        self.failure_watch = None
        rule = self.rules["client.failure-reaction"]
        detail = (
            f"after FAILURE to {watch.what} of trajectory {watch.trajectory}, the client went on with {point.what}: "
            "the controller never queued the refused point, so the trajectory has a hole"
        )
        if self.moto:
            rule.fail(
                detail + " (motoman_driver aborts on anything but SUCCESS and BUSY)", self.ev(watch), self.ev(point)
            )
        else:
            rule.warn(
                detail
                + " (the reference streamer ignores reply codes, industrial_core#118; the refused point is lost)",
                self.ev(watch),
                self.ev(point),
            )

    def _failure_passed(self, how: str) -> None:
        watch = self.failure_watch
        if watch is None:
            return
        self.failure_watch = None
        rule = self.rules["client.failure-reaction"]
        rule.checked += 1
        rule.note(f"after FAILURE to {watch.what} of trajectory {watch.trajectory}, the client {how}")

    # replies and injections -------------------------------------------------------------------------

    def reply_sent(self, point: Point, reply: Message | MalformedMessage, frame: bytes) -> None:
        """The reply to ``point`` reached the client."""
        link = point.link
        point.outcome = _outcome(reply)
        with contextlib.suppress(ValueError):
            link.in_flight.remove(point)
        if point.kind == "stop" and link.pending_stop is point:
            link.pending_stop = None
            link.after_stop = point
        if point.kind == "point" and point.outcome == "success" and point.seq is not None:
            if point.positions:  # a point without group 0 has nothing to compare a resend by
                link.acked[point.seq] = point.positions
            while len(link.acked) > MAX_ACKED:
                del link.acked[next(iter(link.acked))]
        if point.injected is not None:
            ev = self.evidence("sent", frame, reply)
            rule = self.rules[_INJECTION_RULES[point.injected]]
            rule.sample(ev)
            rule.keep(ev)

    def injected(self, kind: str, point: Point, what: str) -> str:
        """Note an injection, start watching the client's reaction; the line for the injection log."""
        point.injected = kind
        self.done.add(kind)
        line = f"{kind}: trajectory {point.trajectory}, {point.what} on {point.link.name} at {self.at()}: {what}"
        self.injections.append(line)
        self.rules[_INJECTION_RULES[kind]].note(line)
        if kind == "busy":
            self.busy_watch = point
        elif kind == "failure":
            self.failure_watch = point
            self.failure_retry = None
        return line

    # the report -------------------------------------------------------------------------------------

    def judge(self, report: Report) -> None:
        self._flush_waiting()
        for link in list(self.links.values()):
            if link.role == "motion":
                self._end_trajectory(link)
        rules = self.rules
        n = self.trajectories
        order = self.wire.byte_order.value
        frames = _n(self.frames[ByteOrder.LITTLE] + self.frames[ByteOrder.BIG], "frame")
        report.add(
            rules["client.byte-order"].result(
                f"{frames} from the client, all {order}-endian", "the client sent no frame (connect and send something)"
            )
        )
        report.add(
            rules["client.stop-and-wait"].result(
                f"{_n(self.point_requests, 'point request')}, each sent after the previous one's reply",
                "the client sent no point request on the motion port (stream a trajectory as SERVICE_REQUESTs)",
            )
        )
        report.add(
            rules["client.sequence"].result(
                f"{_n(self.points, 'point')} in {_n(n, 'trajectory', 'trajectories')}, every sequence in order",
                "the client sent no trajectory point (stream or download a trajectory)",
            )
        )
        report.add(
            rules["client.point-fields"].result(
                f"{_n(self.points, 'point')}, every field finite and in range",
                "the client sent no trajectory point (stream or download a trajectory)",
            )
        )
        tolerance = self.start_tolerance
        report.add(
            rules["client.first-point"].result(
                f"{_n(rules['client.first-point'].checked, 'trajectory', 'trajectories')}, each starting within "
                f"{tolerance:g} rad of the robot",
                "no trajectory's first point could be judged (send a trajectory that starts where the robot is)",
            )
        )
        report.add(
            rules["client.stop"].result(
                f"{_n(self.stops, 'STOP')}, well formed and answered before the next point",
                "the client sent no STOP (stop the robot once, e.g. robot-client stop)",
            )
        )
        report.add(self._busy_result(n))
        report.add(self._failure_result(n))
        report.add(self._reconnect_result())

    def _busy_result(self, n: int) -> RuleResult:
        rule = self.rules["client.busy-reaction"]
        watch = self.busy_watch
        if watch is not None and watch.outcome is not None:
            self.busy_watch = None
            rule.fail(f"the client never sent {watch.what} again after BUSY (it gave up)", self.ev(watch))
        if not self.moto:
            skipped = f"BUSY is MotoROS's; the {self.profile} controller never answers it"
        elif "busy" not in self.inject:
            skipped = "the busy injection was not asked for"
        else:
            skipped = (
                f"no BUSY was injected: the client's first trajectory had no point 2 (it sent {n} trajectories; "
                "stream a first trajectory of at least three points)"
            )
        return rule.result("the client sent the point answered BUSY again, unchanged, before any other", skipped)

    def _failure_result(self, n: int) -> RuleResult:
        rule = self.rules["client.failure-reaction"]
        if self.failure_watch is not None:
            self._failure_passed("sent nothing more of that trajectory")
        if "failure" not in self.inject:
            skipped = "the failure injection was not asked for"
        elif self.modes.get(2) == "download":
            skipped = (
                "no FAILURE was injected: the second trajectory was a download, whose TOPIC points have no reply "
                "to refuse (stream a second trajectory of at least two points)"
            )
        else:
            skipped = (
                f"no FAILURE was injected: the client sent {n} trajectories, and it is point 1 of the second one that "
                "is refused (send a second trajectory of at least two points)"
            )
        return rule.result("after the refused point the client sent no later point of that trajectory", skipped)

    def _reconnect_result(self) -> RuleResult:
        rule = self.rules["client.reconnect"]
        if self.dropped is not None and self.dropped is self.last_motion:
            rule.note("the client did not open a motion connection again after the drop")
        if self.motion_links > 1 and not rule.checked:
            skipped = (
                f"the client opened {self.motion_links} motion connections but sent no point or STOP on the later ones"
            )
        elif "drop" not in self.inject:
            skipped = "no reconnect happened (the drop injection was not asked for)"
        elif self.modes.get(3) == "download":
            skipped = (
                "no reconnect happened: the third trajectory, whose connection is dropped after point 1's reply, "
                "was a download (TOPICs have no reply); stream a third trajectory of at least two points"
            )
        else:
            skipped = (
                "no reconnect happened: the client sent "
                f"{self.trajectories} trajectories, and it is the third one (of at least two points) that is dropped "
                "after point 1; the client should then reconnect"
            )
        count = _n(rule.checked, "motion connection")
        return rule.result(f"{count} after the first began with a new trajectory or a STOP", skipped)


def _n(count: int, word: str, plural: str | None = None) -> str:
    return f"{count} {word if count == 1 else plural or word + 's'}"


def _type_name(point: Point) -> str:
    msg_type = point.msg.msg_type or 0
    try:
        return MsgType(msg_type).name
    except ValueError:
        return str(msg_type)


def _fmt(positions: Positions | None) -> str:
    if positions is None:
        return "(unknown)"
    return "[" + ", ".join(f"{v:.4g}" for v in positions) + "]"
