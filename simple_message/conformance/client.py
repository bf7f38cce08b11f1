"""The client suite (``simple-message conformance client``): play a controller, judge the client.

A PC-side client is only as good as what it does when the controller is *not* a happy path: the
reference streamer blocks forever without a reply (simple-message.md §10 pitfall 5), ignores reply
codes (§3, industrial_core#118), may skip or repeat points across a reconnect (§7, PR #263), and a
client that gives up on MotoROS's BUSY cannot drive MotoROS at all (§8.1: the FS100 trace has 48
BUSY replies out of 58). So the suite does not just listen: it sits between the client and a real
controller and makes the controller's awkward answers happen.

**A proxy with an observer.** The suite listens on the profile's ports (motion, state, and io when
the profile has one). For each connection the client opens it opens one to the same port of an
upstream controller and forwards the bytes both ways unchanged, frame by frame, except for the
replies it injects (below). The client's frames, on every port, and the controller's on the motion
port are cut and fed to the rules (the controller's state and IO traffic passes as it comes: no rule
judges the controller). The cutter is tolerant: a frame in the other byte order is evidence, not the
end of the stream (§10 pitfall 1's rule: a length above 0xFFFF read one way is a frame of the other
order), and bytes that are no frame in either order are passed on uncut. Replies keep their order
(a reply answers the oldest request still waiting, §3): an injected reply waits behind the upstream
replies owed before it. The suite also keeps its own connection to the controller's state port,
so it always knows where the robot is (JOINT_POSITION, or JOINT_FEEDBACK of group 0 for MotoROS)
even when the client never subscribes: that is what a first point is compared with.

**The controller upstream** is given (``upstream={"motion": (host, port), "state": ...}``) or,
by default, started for the run: ``python -m robot_server`` (the project's emulator) on free ports,
its one ready line read from stdout (bounded), stopped with SIGINT at the end (then killed). It is
a *process* dependency, never an import: :mod:`simple_message` is the protocol package and imports
only the standard library and itself (the emulator needs numpy and ruckig; a user of the protocol
package needs neither), and a process is also exactly what a real controller is to the suite, so
any controller can take the emulator's place. The ``abb`` profile is the generic emulator with
header-only replies; ``fanuc`` is the generic emulator in big-endian whose echo replies to
JOINT_TRAJ_PT are rewritten as Fanuc's JOINT_POSITION acknowledgement carrying the sequence (§3,
§8.3): the one other change the proxy makes to the bytes.

**Injections** (each once, by trajectory count: a trajectory starts with a point of sequence 0, -1
or -2 streamed or downloaded by the client on the motion port):

* ``busy`` (MotoROS only), first trajectory: the point with sequence 2 (or sequence 1 if it comes to
  rest, i.e. is the last point of a two-point trajectory) is not forwarded; the suite answers it
  MOTO_MOTION_REPLY BUSY as MotoROS builds it (§8.1: groupNo, sequence, command = the request's type,
  subcode 0). The client must send the same point again.
* ``failure``, second trajectory: point 1 is not forwarded and is answered FAILURE in the profile's
  style (echo with reply_code FAILURE; ABB: header-only FAILURE; Fanuc: JOINT_POSITION FAILURE;
  MotoROS: INVALID/3010 DATA). The controller never got it, so any later point of that trajectory
  would leave a hole.
* ``drop``, third trajectory: right after the reply to point 1 reached the client, the suite closes
  the client's motion connection (and its own upstream one). The client may reconnect.

**Rules** (``RULES``): ``client.byte-order``, ``client.stop-and-wait``, ``client.sequence``,
``client.point-fields``, ``client.first-point``, ``client.stop``, ``client.busy-reaction``,
``client.failure-reaction``, ``client.reconnect``. Each verdict names the real peer behaviour it
comes from and carries the frames that made it (hex and decoded), at most ten per rule; a rule that
saw nothing to judge is SKIPped with what the client should do to exercise it. Nothing a
client sends can crash the suite (bad bytes are evidence), and nothing it sends grows the suite's
memory without bound: frames are kept only while a rule still needs them, evidence is capped.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import re
import signal
import struct
import sys
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Final

from ..constants import (
    HEADER_SIZE,
    LENGTH_SIZE,
    CommType,
    InvalidSubcode,
    MotoCommand,
    MotoResult,
    MsgType,
    ReplyCode,
    SpecialSeq,
    ValidFields,
)
from ..dialects import ABB, FANUC, GENERIC, MOTOROS, Dialect, ReplyStyle
from ..errors import MalformedMessage
from ..framing import decode_or_error
from ..messages import (
    HeaderOnly,
    JointFeedback,
    JointPosition,
    JointTrajPt,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
)
from ..wire import ByteOrder, WireFormat
from .report import Evidence, Report, RuleResult, Verdict

__all__ = [
    "INJECTIONS",
    "PROFILES",
    "RULES",
    "ClientSuite",
    "ClientSuiteOptions",
    "run_client_suite",
]

log = logging.getLogger(__name__)

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
#: what the suite can make the controller do, each once
INJECTIONS: Final = frozenset({"busy", "failure", "drop"})

#: bounds on a spawned robot-server: its ready line, and its exit after SIGINT
SPAWN_TIMEOUT = 30.0
STOP_TIMEOUT = 10.0
#: connecting to the upstream controller (per accepted client connection, and the suite's state watch)
CONNECT_TIMEOUT = 5.0
#: start() waits at most this long for the first joint state from the controller
FIRST_STATE_TIMEOUT = 5.0
#: MotoROS refuses a trajectory time from this many seconds (float32 resolution; §8.1, motoman#244)
MAX_TIME = 14400.0
#: the tolerant cutter's largest plausible length prefix (§10 pitfall 1: above it, the other order)
MAX_FRAME = 0xFFFF
#: evidence items per rule, failure details kept per rule, points waiting for the next joint state
MAX_EVIDENCE = 10
MAX_DETAILS = 20
MAX_WAITING = 64
#: the longest frame shown whole in the evidence (bytes)
MAX_SHOWN = 1024
#: motion groups whose speeds are followed per connection (MotoROS has at most 4)
MAX_GROUPS = 8
#: replies owed to the client on one connection before the suite reads no more from it (a real
#: controller, too, stops reading a client that does not wait for its replies)
MAX_PENDING = 256
#: acknowledged points remembered per connection (to recognise one sent again after a reconnect)
MAX_ACKED = 4096
#: a velocity this far above what the positions and times imply is implausible (rad/s, x)
SPEED_MARGIN = 0.05
SPEED_FACTOR = 2.0
#: values the same within this are the same point (float32 on the wire is far coarser)
SAME = 1e-6

_READ = 65536
_STOP_SEQ = int(SpecialSeq.STOP_TRAJECTORY)
_START_SEQS = (0, int(SpecialSeq.START_TRAJECTORY_DOWNLOAD), int(SpecialSeq.START_TRAJECTORY_STREAMING))
_POINT_TYPES = frozenset({MsgType.JOINT_TRAJ_PT, MsgType.JOINT_TRAJ_PT_FULL, MsgType.JOINT_TRAJ_PT_FULL_EX})
#: MotoROS closes the motion connection on these, without a reply (§8.1)
_MOTO_CLOSERS = frozenset(
    {MsgType.STATUS, MsgType.JOINT_FEEDBACK, MsgType.MOTO_MOTION_REPLY, MsgType.JOINT_FEEDBACK_EX}
)
#: the rule that reports each injection
_INJECTION_RULES = {"busy": "client.busy-reaction", "failure": "client.failure-reaction", "drop": "client.reconnect"}
_POSITION = ValidFields.POSITION
_REQUIRED_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
_READY = re.compile(r"\b(motion|state|io) (\S+):(\d+)")


# -- profiles and options -----------------------------------------------------------------------------


@dataclass(frozen=True)
class _Profile:
    """A controller family the suite plays: its dialect, and how robot-server is asked to play it."""

    name: str
    dialect: Dialect
    #: robot-server --profile
    emulator: str
    #: robot-server --reply-style (None: the emulator profile's own)
    reply_style: str | None = None
    #: it has an IO port (MotoROS)
    io: bool = False
    #: replies to JOINT_TRAJ_PT are rewritten as Fanuc's JOINT_POSITION ack (§8.3)
    fanuc_ack: bool = False


PROFILES: Final[Mapping[str, _Profile]] = {
    p.name: p
    for p in (
        _Profile("abb", ABB, "generic", reply_style="header"),
        _Profile("fanuc", FANUC, "generic", fanuc_ack=True),
        _Profile("generic", GENERIC, "generic"),
        _Profile("motoros", MOTOROS, "motoros", io=True),
    )
}


@dataclass(frozen=True)
class ClientSuiteOptions:
    """How the suite plays the controller (see the module doc)."""

    profile: str = "generic"
    host: str = "127.0.0.1"
    #: None: the profile's; 0: any free port
    motion_port: int | None = None
    state_port: int | None = None
    io_port: int | None = None
    #: "little" | "big" | None: the profile's
    byte_order: str | None = None
    float64: bool = False
    #: None: spawn robot-server
    upstream: Mapping[str, tuple[str, int]] | None = None
    inject: frozenset[str] = INJECTIONS
    start_tolerance: float = 0.001
    #: end after this many seconds
    duration: float | None = None
    #: end this long after the client's last connection closed (if it was closed by the client, not by
    #: the drop injection) with none open
    linger: float = 5.0

    def __post_init__(self) -> None:
        _check_options(self)  # ValueError at once, naming the option


def _check_options(options: ClientSuiteOptions) -> _Profile:
    """The profile, once every option is known to be usable; :class:`ValueError` says which is not."""
    profile = PROFILES.get(options.profile)
    if profile is None:
        raise ValueError(f"unknown profile {options.profile!r} (supported: {', '.join(sorted(PROFILES))})")
    if not isinstance(options.host, str) or not options.host:
        raise ValueError("host must be an address to listen on, e.g. 127.0.0.1")
    for role, port in (("motion", options.motion_port), ("state", options.state_port), ("io", options.io_port)):
        if port is not None and (isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535):
            raise ValueError(f"{role}_port must be 0..65535 (0: any free port) or None (the profile's), not {port!r}")
    if options.io_port is not None and not profile.io:
        raise ValueError(f"the {profile.name} profile has no IO port (only motoros has one)")
    if options.byte_order not in (None, "little", "big"):
        raise ValueError(f"byte_order must be 'little', 'big' or None (the profile's), not {options.byte_order!r}")
    unknown = set(options.inject) - INJECTIONS
    if unknown:
        raise ValueError(
            f"unknown injection {', '.join(sorted(map(repr, unknown)))} (known: {', '.join(sorted(INJECTIONS))})"
        )
    if not (isinstance(options.start_tolerance, int | float) and math.isfinite(options.start_tolerance)):
        raise ValueError(f"start_tolerance must be a finite number of radians, not {options.start_tolerance!r}")
    if options.start_tolerance <= 0:
        raise ValueError(f"start_tolerance must be > 0 rad, not {options.start_tolerance}")
    if options.duration is not None and not (math.isfinite(options.duration) and options.duration > 0):
        raise ValueError(f"duration must be > 0 s or None, not {options.duration!r}")
    if not (math.isfinite(options.linger) and options.linger >= 0):
        raise ValueError(f"linger must be >= 0 s, not {options.linger!r}")
    if options.upstream is not None:
        roles = set(options.upstream)
        missing = {"motion", "state"} - roles
        if missing:
            raise ValueError(f"upstream needs the {' and '.join(sorted(missing))} port(s) of the controller")
        extra = roles - {"motion", "state", "io"}
        if extra:
            raise ValueError(f"upstream roles are motion, state and io, not {', '.join(sorted(extra))}")
        if "io" in roles and not profile.io:
            raise ValueError(f"the {profile.name} profile has no IO port: give upstream motion and state only")
        for role, address in options.upstream.items():
            ok = (
                isinstance(address, tuple | list)
                and len(address) == 2
                and isinstance(address[0], str)
                and isinstance(address[1], int)
                and 0 < address[1] <= 65535
            )
            if not ok:
                raise ValueError(f"upstream[{role!r}] must be (host, port 1..65535), not {address!r}")
    return profile


# -- the tolerant cutter ------------------------------------------------------------------------------


def _other(order: ByteOrder) -> ByteOrder:
    return ByteOrder.BIG if order is ByteOrder.LITTLE else ByteOrder.LITTLE


def _plausible(length: int) -> bool:
    return HEADER_SIZE <= length <= MAX_FRAME


class _Cutter:
    """Cuts a byte stream into frames, each in the byte order its length prefix is plausible in.

    A peer's frame in the other byte order is a frame to show, not the end of the stream: every
    length a frame can have (12..0xFFFF) reads as at least 0x10000 the other way round, so the
    order of each prefix is never in doubt (§10 pitfall 1). A prefix plausible in neither order ends
    the cutting: the rest of the stream is handed on as it is (``order`` None). At most one frame
    (4 + 0xFFFF bytes) is held.
    """

    def __init__(self, order: ByteOrder) -> None:
        self.order = order
        self.other = _other(order)
        self._buf = bytearray()
        #: the stream could not be cut any further
        self.lost = False

    def feed(self, data: bytes) -> list[tuple[bytes, ByteOrder | None]]:
        if self.lost:
            return [(data, None)] if data else []
        self._buf += data
        out: list[tuple[bytes, ByteOrder | None]] = []
        buf = self._buf
        while len(buf) >= LENGTH_SIZE:
            order: ByteOrder | None = None
            for candidate in (self.order, self.other):
                (length,) = struct.unpack_from(candidate.struct_char + "i", buf, 0)
                if _plausible(length):
                    order = candidate
                    break
            if order is None:
                out.append((bytes(buf), None))
                buf.clear()
                self.lost = True
                break
            end = LENGTH_SIZE + length
            if len(buf) < end:
                break
            out.append((bytes(buf[:end]), order))
            del buf[:end]
        return out


# -- what the rules see -------------------------------------------------------------------------------


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
class _Point:
    """A trajectory point or a STOP the client sent on the motion port."""

    link: _LinkState
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
    arrived: float
    trajectory: int = 0
    #: the first point of a trajectory (sequence 0, -1 or -2)
    start: bool = False
    #: a resend of the previous point after BUSY (not a new trajectory)
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
    point: _Point
    #: the implied speed (per joint) of the segment that ends at it, if any
    before: Positions | None = None


@dataclass(eq=False)
class _LinkState:
    """What the rules know about one of the client's connections."""

    id: int
    role: str
    peer: str
    opened: float
    #: 1 for the first motion connection of the run, 2 for the next...
    motion_index: int = 0
    #: point requests whose reply has not reached the client (the latest few: enough to show one)
    in_flight: deque[_Point] = field(default_factory=lambda: deque(maxlen=MAX_WAITING))
    #: None (no trajectory under way), "stream" or "download"
    mode: str | None = None
    last: _Point | None = None
    trajectory: int = 0
    acked: dict[int, Positions] = field(default_factory=dict)
    pending_stop: _Point | None = None
    after_stop: _Point | None = None
    seen_point: bool = False
    prev: dict[int, _Prev] = field(default_factory=dict)
    closed_by: str | None = None

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


def _same_positions(a: _Point, b: _Point) -> bool:
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


class _Observer:
    """Every rule's state, fed by the proxy as frames pass (all synchronous, on the event loop)."""

    def __init__(
        self, profile: _Profile, wire: WireFormat, options: ClientSuiteOptions, clock: Callable[[], float]
    ) -> None:
        self.profile = profile
        self.moto = profile.dialect.motion_control
        self.wire = wire
        self.other_wire = wire.with_byte_order(_other(wire.byte_order))
        self.options = options
        self.clock = clock
        #: when the run started (set by ClientSuite.start)
        self.t0 = 0.0
        self.links: dict[int, _LinkState] = {}
        self.motion_links = 0
        self.trajectories = 0
        #: how the first three trajectories were sent ("stream", "download")
        self.modes: dict[int, str] = {}
        self.points = 0
        self.point_requests = 0
        self.frames = {ByteOrder.LITTLE: 0, ByteOrder.BIG: 0}
        self.state: Positions | None = None
        self.waiting: deque[_Point] = deque()
        #: what the previous motion connection had acknowledged, when a new one opened
        self.interrupted: dict[int, Positions] = {}
        self.last_motion: _LinkState | None = None
        self.dropped: _LinkState | None = None
        self.injections: list[str] = []
        self.done: set[str] = set()
        self.busy_watch: _Point | None = None
        self.failure_watch: _Point | None = None
        self.failure_retry: _Point | None = None
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

    def ev(self, point: _Point) -> Evidence:
        return self.evidence("received", point.frame, point.msg)

    # -- connections --------------------------------------------------------------------------------

    def link_opened(self, link_id: int, role: str, peer: str) -> _LinkState:
        link = _LinkState(link_id, role, peer, self.clock())
        if role == "motion":
            self.motion_links += 1
            link.motion_index = self.motion_links
            previous = self.last_motion
            if previous is not None:
                self.interrupted = dict(previous.acked)
            self.last_motion = link
        self.links[link_id] = link
        return link

    def link_closed(self, link: _LinkState, by: str) -> None:
        link.closed_by = by
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
        self, link: _LinkState, frame: bytes, order: ByteOrder | None, msg: Message | MalformedMessage | None
    ) -> _Point | None:
        """Note one frame from the client; a motion port's point or STOP comes back as a :class:`_Point`."""
        rule = self.rules["client.byte-order"]
        if order is None:
            rule.warn(
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

    def _point(self, link: _LinkState, frame: bytes, msg: Message | MalformedMessage) -> _Point | None:
        request = msg.comm_type == CommType.SERVICE_REQUEST
        now = self.clock()
        if isinstance(msg, MalformedMessage):
            if msg.msg_type not in _POINT_TYPES:
                return None
            return _Point(link, frame, msg, "malformed", None, request, None, (), now)
        if isinstance(msg, MotoMotionCtrl):
            if msg.command != MotoCommand.STOP_MOTION:
                return None
            return _Point(link, frame, msg, "stop", msg.sequence, request, None, (), now)
        if not isinstance(msg, JointTrajPt | JointTrajPtFull | JointTrajPtFullEx):
            return None
        groups = _groups_of(msg)
        kind = "stop" if msg.sequence == _STOP_SEQ else "point"
        return _Point(link, frame, msg, kind, msg.sequence, request, _group0(msg, groups), groups, now)

    def _judge_point(self, point: _Point) -> None:
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

    def _stop_and_wait(self, point: _Point) -> None:
        if not point.request:
            return
        link = point.link
        rule = self.rules["client.stop-and-wait"]
        rule.checked += 1
        self.point_requests += 1
        if link.in_flight:
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

    def _stop_rule(self, point: _Point) -> None:
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
            problem = f"MOTO_MOTION_CTRL STOP_MOTION: the {self.profile.name} controller's stop is sequence -4"
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

    def _sequence(self, point: _Point) -> None:
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

    def _next_in_order(self, point: _Point, last: _Point | None) -> str | None:
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

    def _generic_sequence(self, point: _Point, last: _Point | None) -> tuple[str | None, str | None]:
        link = point.link
        seq = point.seq
        assert seq is not None
        download = SpecialSeq.START_TRAJECTORY_DOWNLOAD
        problem: str | None = None
        warning: str | None = None
        if seq == download:
            if point.request:
                problem = (
                    "a download's first point (-1) sent as a SERVICE_REQUEST: the reference downloader sends TOPICs "
                    "and Fanuc does not answer -1 (§4.4, §8.3)"
                )
            self._start(point, "download")
        elif seq == SpecialSeq.END_TRAJECTORY:
            if link.mode != "download":
                problem = "-3 (END_TRAJECTORY) outside a download (-1 ... -3)"
            elif point.request:
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
            if point.request:
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

    def _start(self, point: _Point, mode: str) -> None:
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

    def _end_trajectory(self, link: _LinkState) -> None:
        """The trajectory under way on ``link`` ended (a STOP, a new one, the connection closed)."""
        for prev in link.prev.values():
            self._speed_check(prev, None)
        link.prev.clear()
        link.mode = None
        link.last = None

    # point fields -------------------------------------------------------------------------------------

    def _fields(self, point: _Point) -> None:
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
        else:
            if self.profile.name in ("abb", "fanuc"):
                problems.append(f"the {self.profile.name} controller takes JOINT_TRAJ_PT only (§8.2, §8.3)")
            for group in point.groups:
                problems.extend(self._group_fields(point, group))
        if problems:
            rule.fail(f"{link.name}: {point.what}: {'; '.join(problems)}", self.ev(point))
        elif rule.checked <= 2:
            rule.sample(self.ev(point))

    def _group_fields(self, point: _Point, group: _Group) -> list[str]:
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
        if seq > 0 and group.time <= prev.time:
            problems.append(
                f"{name}time {group.time:g} s is not after point {prev.seq}'s {prev.time:g} s (MotoROS: no motion for "
                "a segment of 0 s or less, §8.1)"
            )
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

    def _distance(self, point: _Point) -> float | None:
        """How far the point is from the robot: the nearer of the state when it arrived and the next one
        (the suite's state lags the client's by up to one state period)."""
        if point.positions is None:
            return None
        gaps = [_max_gap(point.positions, here) for here in (point.here, point.after) if here is not None]
        return min(gaps) if gaps else None

    def _resolve(self, point: _Point) -> None:
        if point.resolved:
            return
        point.resolved = True
        distance = self._distance(point)
        tolerance = self.options.start_tolerance
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

    def flush_waiting(self) -> None:
        while self.waiting:
            self._resolve(self.waiting.popleft())

    # reconnect ----------------------------------------------------------------------------------------

    def _reconnect(self, point: _Point, distance: float | None) -> None:
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
        tolerance = self.options.start_tolerance
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

    def _busy_reaction(self, point: _Point) -> None:
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

    def _failure_reaction(self, point: _Point) -> None:
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

    def reply_sent(self, point: _Point, reply: Message | MalformedMessage, frame: bytes) -> None:
        """The reply to ``point`` reached the client."""
        link = point.link
        point.outcome = _outcome(reply)
        with contextlib.suppress(ValueError):
            link.in_flight.remove(point)
        if point.kind == "stop" and link.pending_stop is point:
            link.pending_stop = None
            link.after_stop = point
        if point.kind == "point" and point.outcome == "success" and point.seq is not None:
            link.acked[point.seq] = point.positions or ()
            while len(link.acked) > MAX_ACKED:
                del link.acked[next(iter(link.acked))]
        if point.injected is not None:
            ev = self.evidence("sent", frame, reply)
            rule = self.rules[_INJECTION_RULES[point.injected]]
            rule.sample(ev)
            rule.keep(ev)

    def injected(self, kind: str, point: _Point, what: str) -> None:
        """Log an injection (and start watching the client's reaction)."""
        point.injected = kind
        self.done.add(kind)
        line = f"{kind}: trajectory {point.trajectory}, {point.what} on {point.link.name} at {self.at()}: {what}"
        self.injections.append(line)
        log.info("injected %s", line)
        self.rules[_INJECTION_RULES[kind]].note(line)
        if kind == "busy":
            self.busy_watch = point
        elif kind == "failure":
            self.failure_watch = point
            self.failure_retry = None

    # the report -------------------------------------------------------------------------------------

    def judge(self, report: Report) -> None:
        self.flush_waiting()
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
        tolerance = self.options.start_tolerance
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
            skipped = f"BUSY is MotoROS's; the {self.profile.name} controller never answers it"
        elif "busy" not in self.options.inject:
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
        if "failure" not in self.options.inject:
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
        elif "drop" not in self.options.inject:
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


def _type_name(point: _Point) -> str:
    msg_type = point.msg.msg_type or 0
    try:
        return MsgType(msg_type).name
    except ValueError:
        return str(msg_type)


def _fmt(positions: Positions | None) -> str:
    if positions is None:
        return "(unknown)"
    return "[" + ", ".join(f"{v:.4g}" for v in positions) + "]"


# -- the proxy ----------------------------------------------------------------------------------------


@dataclass(eq=False)
class _Slot:
    """A reply the client is owed, in order: from upstream, or injected (``reply`` already set)."""

    point: _Point | None
    request: Message | MalformedMessage
    upstream: bool
    reply: Message | MalformedMessage | None = None
    frame: bytes | None = None
    drop_after: bool = False


class _Link:
    """One client connection and its upstream twin, forwarded frame by frame."""

    def __init__(
        self,
        suite: ClientSuite,
        state: _LinkState,
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
        cutter = _Cutter(self.suite.wire.byte_order)
        motion = self.state.role == "motion"
        with contextlib.suppress(OSError):
            while not self.dropped:
                data = await self.client_reader.read(_READ)
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
        the types that close its motion connection (simple-message.md §3, §8.1)."""
        _, msg_type, comm, _ = self.suite.wire.header.unpack_from(frame, 0)
        if not self.suite.profile.dialect.motion_control:
            return bool(comm == CommType.SERVICE_REQUEST)
        if comm == CommType.SERVICE_REPLY or msg_type in _MOTO_CLOSERS:
            return False
        return not (isinstance(msg, MotoMotionCtrl) and msg.command == MotoCommand.DISCONNECT)

    def _request(self, frame: bytes, msg: Message | MalformedMessage, point: _Point | None) -> None:
        answered = self._answered(frame, msg)
        injection = self.suite.injection_for(point) if point is not None and answered else None
        if injection in ("busy", "failure") and isinstance(msg, Message) and point is not None:
            reply = self.suite.injected_reply(injection, msg)
            reply_frame = reply.encode(self.suite.wire)
            self.suite.observer.injected(injection, point, f"not forwarded, answered {_describe(reply)}")
            self.slots.append(_Slot(point, msg, upstream=False, reply=reply, frame=reply_frame))
            self._flush()
            return
        self.up_writer.write(frame)
        if answered:
            slot = _Slot(point, msg, upstream=True)
            if injection == "drop" and point is not None:
                slot.drop_after = True
                self.suite.observer.injected(
                    "drop", point, "forwarded; the connection is closed once its reply reached the client"
                )
            self.slots.append(slot)

    # upstream -> client ----------------------------------------------------------------------------

    async def _from_upstream(self) -> None:
        cutter = _Cutter(self.suite.wire.byte_order)
        motion = self.state.role == "motion"
        with contextlib.suppress(OSError):
            while not self.dropped:
                data = await self.up_reader.read(_READ)
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
        if self.suite.profile.fanuc_ack and isinstance(slot.request, JointTrajPt):
            reply = _fanuc_ack(slot.request, reply)
            frame = reply.encode(self.suite.wire)
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


def _fanuc_ack(request: JointTrajPt, reply: Message | MalformedMessage) -> Message:
    """Fanuc's acknowledgement of a JOINT_TRAJ_PT: JOINT_POSITION carrying its sequence (§3, §8.3)."""
    code = reply.reply_code if isinstance(reply, Message) else ReplyCode.FAILURE
    return JointPosition(request.sequence, comm_type=CommType.SERVICE_REPLY, reply_code=code)


def _describe(reply: Message) -> str:
    if isinstance(reply, MotoMotionReply):
        result = MotoResult(reply.result).name if reply.result in MotoResult._value2member_map_ else reply.result
        sub = f"/{reply.subcode}" if reply.subcode else ""
        return f"MOTO_MOTION_REPLY {result}{sub}"
    code = ReplyCode(reply.reply_code).name if reply.reply_code in ReplyCode._value2member_map_ else reply.reply_code
    body = "header-only " if isinstance(reply, HeaderOnly) else ""
    return f"{body}{reply.name} {code}"


# -- the suite ----------------------------------------------------------------------------------------


class ClientSuite:
    """The client suite (see the module doc): :meth:`start`, :meth:`wait`, :meth:`finish`.

    ``async with ClientSuite(options) as suite`` starts it and finishes it on the way out;
    :attr:`ports` are the listening ports by role once started, :attr:`report` the report once
    finished. Bad options raise :class:`ValueError` at once; :meth:`start` raises :class:`OSError`
    when a port cannot be bound and :class:`RuntimeError` when robot-server cannot be started.
    """

    def __init__(self, options: ClientSuiteOptions) -> None:
        self.profile = _check_options(options)
        self.options = options
        order = ByteOrder(options.byte_order) if options.byte_order else self.profile.dialect.wire.byte_order
        self.wire = WireFormat(order, 8 if options.float64 else 4)
        self.observer = _Observer(self.profile, self.wire, options, self._now)
        #: listening ports by role, once started
        self.ports: dict[str, int] = {}
        #: the controller's ports by role, once started
        self.upstream: dict[str, tuple[str, int]] = dict(options.upstream) if options.upstream else {}
        self.report: Report | None = None
        self._servers: list[asyncio.Server] = []
        self._process: asyncio.subprocess.Process | None = None
        self._readers: list[asyncio.Task[None]] = []
        self._stderr: deque[str] = deque(maxlen=20)
        self._handlers: set[asyncio.Task[None]] = set()
        self._state_task: asyncio.Task[None] | None = None
        self._first_state = asyncio.Event()
        self._activity = asyncio.Event()
        self._open = 0
        self._last_close: float | None = None
        self._linger_armed = False
        self._started: float | None = None
        self._finishing = False
        self._next_link = 0
        self._injection_plan: dict[str, tuple[int, Callable[[_Point], bool]]] = {
            "busy": (1, _busy_point),
            "failure": (2, lambda p: p.seq == 1),
            "drop": (3, lambda p: p.seq == 1),
        }

    @staticmethod
    def _now() -> float:
        return asyncio.get_running_loop().time()

    # -- lifecycle ----------------------------------------------------------------------------------

    async def start(self) -> dict[str, int]:
        """Start (or reach) the controller, bind the ports; the listening ports by role."""
        if self._started is not None:
            raise RuntimeError("the client suite is already started")
        self._started = self._now()
        self.observer.t0 = self._started
        try:
            if not self.upstream:
                self.upstream = await self._spawn()
            defaults = self.profile.dialect.ports
            wanted = {"motion": self.options.motion_port, "state": self.options.state_port}
            if self.profile.io and "io" in self.upstream:
                wanted["io"] = self.options.io_port
            for role, port in wanted.items():
                chosen = defaults[role] if port is None else port
                server = await asyncio.start_server(
                    functools.partial(self._accept, role), self.options.host, chosen, reuse_address=True
                )
                self._servers.append(server)
                self.ports[role] = int(server.sockets[0].getsockname()[1])
            self._state_task = asyncio.get_running_loop().create_task(self._watch_state(), name="client suite state")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._first_state.wait(), FIRST_STATE_TIMEOUT)
            if not self._first_state.is_set():
                log.warning("no joint state from the controller at %s yet", self._address("state"))
        except BaseException:
            await self._shutdown()
            raise
        log.info("client suite ready: %s", self.target)
        return dict(self.ports)

    @property
    def target(self) -> str:
        ports = ", ".join(f"{role} {self.options.host}:{port}" for role, port in self.ports.items())
        upstream = "robot-server (spawned)" if self._process is not None else "the controller"
        return (
            f"the client of {ports} ({self.profile.name} profile, {self.wire}; upstream {upstream} at "
            f"{self._address('motion')})"
        )

    def _address(self, role: str) -> str:
        host, port = self.upstream.get(role, ("?", 0))
        return f"{host}:{port}"

    async def wait(self) -> None:
        """Until ``duration`` has passed, or ``linger`` has after the client's last connection closed."""
        if self._started is None:
            raise RuntimeError("start the client suite first")
        duration, linger = self.options.duration, self.options.linger
        end = None if duration is None else self._started + duration
        while True:
            ends = [] if end is None else [end]
            if self._open == 0 and self._last_close is not None and self._linger_armed:
                ends.append(self._last_close + linger)
            now = self._now()
            stop = min(ends) if ends else None
            if stop is not None and now >= stop:
                return
            self._activity.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._activity.wait(), None if stop is None else stop - now)

    async def finish(self) -> Report:
        """Stop everything (connections, the spawned controller), judge, and return the report."""
        if self.report is not None:
            return self.report
        await self._shutdown()
        report = Report(suite="client", target=self.target)
        self.observer.judge(report)
        for line in self.observer.injections:
            log.debug("injection log: %s", line)
        self.report = report
        return report

    async def __aenter__(self) -> ClientSuite:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.finish()

    async def _shutdown(self) -> None:
        self._finishing = True
        for server in self._servers:
            server.close()
        tasks = [*self._handlers, *([self._state_task] if self._state_task is not None else [])]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for server in self._servers:
            with contextlib.suppress(TimeoutError, OSError):
                await asyncio.wait_for(server.wait_closed(), 2.0)
        self._servers.clear()
        await self._stop_process()

    # -- the spawned controller -----------------------------------------------------------------------

    def command(self) -> list[str]:
        """The robot-server command the suite starts when no upstream is given."""
        profile = self.profile
        args = [sys.executable, "-m", "robot_server", "--profile", profile.emulator, "--motion-port", "0"]
        args += ["--state-port", "0"]
        if profile.io:
            args += ["--io-port", "0"]
        args += ["--byte-order", self.wire.byte_order.value]
        if self.wire.real_size == 8:
            args.append("--float64")
        if profile.reply_style is not None:
            args += ["--reply-style", profile.reply_style]
        args.append("--no-stdin")
        return args

    async def _spawn(self) -> dict[str, tuple[str, int]]:
        args = self.command()
        log.info("starting %s", " ".join(args[1:]))
        # its own session: a Ctrl-C at the terminal reaches the suite only, which closes the client's
        # connections first and then stops the controller (so no connection ends "by the controller")
        process = await asyncio.create_subprocess_exec(
            *args,
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            start_new_session=True,
        )
        self._process = process
        assert process.stdout is not None and process.stderr is not None
        loop = asyncio.get_running_loop()
        self._readers.append(loop.create_task(self._drain(process.stderr, keep=True), name="robot-server stderr"))
        try:
            line = await asyncio.wait_for(process.stdout.readline(), SPAWN_TIMEOUT)
        except (TimeoutError, ValueError):  # ValueError: a "line" longer than the stream's limit
            await self._stop_process()
            raise RuntimeError(
                f"robot-server did not say it was ready within {SPAWN_TIMEOUT:g} s{self._last_words()}"
            ) from None
        self._readers.append(loop.create_task(self._drain(process.stdout, keep=False), name="robot-server stdout"))
        text = line.decode(errors="replace").strip()
        ports = {m.group(1): (m.group(2), int(m.group(3))) for m in _READY.finditer(text)}
        if "motion" not in ports or "state" not in ports:
            await self._stop_process(exiting=not line)
            why = f"it printed {text!r}" if text else "it exited without a ready line"
            raise RuntimeError(f"robot-server could not be started: {why}{self._last_words()}")
        log.info("upstream controller: %s", text)
        return ports

    def _last_words(self) -> str:
        if not self._stderr:
            return ""
        return "; its last lines: " + " | ".join(self._stderr)

    async def _drain(self, stream: asyncio.StreamReader, *, keep: bool) -> None:
        """Read a pipe of the spawned controller to its end (so it never blocks on a full pipe)."""
        with contextlib.suppress(OSError, ValueError):
            while True:
                line = await stream.readline()
                if not line:
                    return
                text = line.decode(errors="replace").rstrip()
                if keep:
                    self._stderr.append(text[:300])
                log.debug("robot-server: %s", text)

    async def _stop_process(self, *, exiting: bool = False) -> None:
        """Stop the spawned controller: SIGINT (it brings the robot to rest and exits), a bounded wait,
        then SIGKILL. ``exiting``: it closed its stdout, so it is on its way out: no signal (Popen's
        send_signal reaps an exited child before asyncio's child watcher sees its exit status)."""
        process = self._process
        if process is not None and process.returncode is None:
            if not exiting:
                with contextlib.suppress(ProcessLookupError):
                    process.send_signal(signal.SIGINT)
            try:
                await asyncio.wait_for(process.wait(), STOP_TIMEOUT)
            except TimeoutError:
                log.warning("robot-server did not exit within %g s: killed", STOP_TIMEOUT)
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        if self._readers:
            _, pending = await asyncio.wait(self._readers, timeout=STOP_TIMEOUT)
            for task in pending:
                task.cancel()
            await asyncio.gather(*self._readers, return_exceptions=True)
            self._readers.clear()

    # -- connections ----------------------------------------------------------------------------------

    async def _accept(self, role: str, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        if self._finishing:
            writer.close()
            return
        self._handlers.add(task)
        self._next_link += 1
        peer = writer.get_extra_info("peername")
        name = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        state = self.observer.link_opened(self._next_link, role, name)
        self._open += 1
        self._activity.set()
        by = "upstream"
        upstream: asyncio.StreamWriter | None = None
        try:
            host, port = self.upstream[role]
            try:
                up = await asyncio.wait_for(asyncio.open_connection(host, port), CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                log.warning("%s: cannot reach the controller's %s port %s:%s: %s", state.name, role, host, port, exc)
                return
            upstream = up[1]
            by = await _Link(self, state, (reader, writer), up).run()
        except asyncio.CancelledError:
            # the suite is finishing (it cancels its handlers). Not raised on: this is the stream
            # server's callback task, and asyncio logs a callback task that ends cancelled as an error
            by = "suite"
        finally:
            for w in (writer, upstream):
                if w is not None:
                    w.close()
            for w in (writer, upstream):
                if w is not None:
                    with contextlib.suppress(OSError, TimeoutError, asyncio.CancelledError):
                        await asyncio.wait_for(w.wait_closed(), 1.0)
            self.observer.link_closed(state, by)
            self._open -= 1
            self._last_close = self._now()
            self._linger_armed = by != "drop"
            self._activity.set()
            self._handlers.discard(task)
            log.debug("%s closed by the %s", state.name, by)

    # -- injections -----------------------------------------------------------------------------------

    def injection_for(self, point: _Point) -> str | None:
        """Which injection, if any, this point request gets (each once, by trajectory count)."""
        if point.kind != "point" or point.seq is None or point.retry or not point.request:
            return None
        for kind in ("busy", "failure", "drop"):
            if kind not in self.options.inject or kind in self.observer.done:
                continue
            if kind == "busy" and not self.profile.dialect.motion_control:
                continue
            trajectory, match = self._injection_plan[kind]
            if point.trajectory == trajectory and match(point):
                return kind
        return None

    def injected_reply(self, kind: str, request: Message) -> Message:
        """The reply the suite sends in the controller's place: BUSY, or FAILURE in the profile's style."""
        style = self.profile.dialect.reply_style
        if style is ReplyStyle.MOTO_MOTION_REPLY:
            group = request.robot_id if isinstance(request, JointTrajPtFull) else 0
            if isinstance(request, JointTrajPtFullEx) and request.valid_groups:
                group = request.valid_groups[0].group_no
            sequence = getattr(request, "sequence", -1)
            if kind == "busy":
                return MotoMotionReply(group, sequence, request.msg_type, MotoResult.BUSY, 0)
            return MotoMotionReply(group, sequence, request.msg_type, MotoResult.INVALID, InvalidSubcode.DATA)
        if style is ReplyStyle.HEADER_ONLY:
            return HeaderOnly(request.msg_type, reply_code=ReplyCode.FAILURE)
        if style is ReplyStyle.JOINT_POSITION_ACK and isinstance(request, JointTrajPt):
            return JointPosition(request.sequence, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.FAILURE)
        return request.to_reply(ReplyCode.FAILURE)

    # -- the suite's own view of the robot ------------------------------------------------------------

    async def _watch_state(self) -> None:
        """Keep a state connection to the controller: where the robot is, whatever the client reads."""
        host, port = self.upstream["state"]
        delay = 0.1
        while True:
            try:
                reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                log.debug("state connection to %s:%s: %s", host, port, exc)
            else:
                delay = 0.1
                try:
                    await self._read_state(reader)
                finally:
                    writer.close()
                    with contextlib.suppress(OSError, TimeoutError):
                        await asyncio.wait_for(writer.wait_closed(), 1.0)
            await asyncio.sleep(delay)  # back-off before connecting again
            delay = min(delay * 2, 2.0)

    async def _read_state(self, reader: asyncio.StreamReader) -> None:
        cutter = _Cutter(self.wire.byte_order)
        with contextlib.suppress(OSError):
            while True:
                data = await reader.read(_READ)
                if not data:
                    return
                for frame, order in cutter.feed(data):
                    if order is not self.wire.byte_order:
                        return
                    msg = decode_or_error(frame, self.wire)
                    if isinstance(msg, JointPosition) and msg.comm_type == CommType.TOPIC:
                        positions: Positions = msg.joint_data
                    elif (
                        isinstance(msg, JointFeedback) and msg.robot_id == 0 and msg.valid_fields & ValidFields.POSITION
                    ):
                        positions = msg.positions
                    else:
                        continue
                    self.observer.state_sample(positions)
                    self._first_state.set()


async def _until(event: asyncio.Event) -> None:
    await event.wait()


def _busy_point(point: _Point) -> bool:
    """Point 2, or point 1 when it comes to rest (the last point of a two-point trajectory)."""
    if point.seq == 2:
        return True
    return point.seq == 1 and bool(point.groups) and all(abs(v) <= SAME for g in point.groups for v in g.velocities)


async def run_client_suite(
    options: ClientSuiteOptions,
    *,
    on_ready: Callable[[dict[str, int]], None] | None = None,
    stop: asyncio.Event | None = None,
) -> Report:
    """Start the suite, call ``on_ready(ports)``, wait until :meth:`ClientSuite.wait` ends or ``stop`` is
    set, finish and return the report."""
    suite = ClientSuite(options)
    await suite.start()
    try:
        if on_ready is not None:
            on_ready(dict(suite.ports))
        loop = asyncio.get_running_loop()
        waiting = [loop.create_task(suite.wait(), name="client suite wait")]
        if stop is not None:
            waiting.append(loop.create_task(_until(stop), name="client suite stop"))
        try:
            await asyncio.wait(waiting, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in waiting:
                task.cancel()
            await asyncio.gather(*waiting, return_exceptions=True)
    finally:
        report = await suite.finish()
    return report
