"""The server suite's passive checks: what a server sends on its own, judged once it was received.

The state rules judge the state port's frames from the connection up to the first motion (the suite
watches them for at least ``observe`` seconds before it sends any): the profile's topics sent as
TOPICs, their rate and longest gap (the PC's 1 s watchdog on joint state, §5; the vendors' rates,
§8), joint state finite with valid_fields honest, STATUS within its enums and consistent, and the
joints agreeing with STATUS over time. The framing rules judge every frame received on every link
over the whole run: one byte order and one real size, the ones expected (there is no negotiation,
§1.3), length prefixes that frame the stream within what C++ peers can take (§1.1, §1.5), bodies
of their type's layout (§2.2, §3), and replies of the right comm_type and reply_code (§1.2).

Each check is a function of the frames and of the little it needs of the suite (its options, the
profile's :class:`~.expectations.Expectations`, the wire format); the suite (:mod:`.server`) runs
them as rules through its :class:`~.server_runner.RuleRunner`, which reports what they return or
the SKIP they raise. A frame's fault is told by its :class:`~.links.Fault`, never by the words of
its problem. The small helpers the suite's modules share (reading a frame's real size, the joints
of a joint state, STATUS as text) are here too.
"""

from __future__ import annotations

import itertools
import math
import statistics
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..constants import CommType, MsgType, ReplyCode, RobotMode, TriState, ValidFields
from ..dialects import Dialect, ReplyStyle
from ..framing import decode_or_error
from ..messages import (
    HeaderOnly,
    JointFeedback,
    JointFeedbackEx,
    JointPosition,
    Message,
    Status,
    message_class,
    type_name,
)
from ..wire import WireFormat
from .expectations import Expectations
from .links import Fault, ProbeLink, Seen
from .report import Evidence, Verdict

if TYPE_CHECKING:
    from .server import ServerSuiteOptions

__all__ = [
    "STILL",
    "CPP_MAX_FRAME",
    "state_topics",
    "state_rate",
    "state_joint_state",
    "state_status",
    "state_consistency",
    "framing_byte_order",
    "framing_float_size",
    "framing_length",
    "framing_body",
    "reply_comm_types",
]

#: a joint that moved less than this (rad) did not move (feedback noise on a real arm is ~1e-5)
STILL = 1e-4
#: longest frame a C++ peer can take (§1.5)
CPP_MAX_FRAME = 1023


class _Skip(Exception):
    """A rule cannot be judged: SKIP with this reason."""


@dataclass
class _Verdict:
    verdict: Verdict
    detail: str
    evidence: list[Evidence] = field(default_factory=list)


# -- the state port --------------------------------------------------------------------------------


async def state_topics(frames: list[Seen], options: ServerSuiteOptions, expect: Expectations, real: int) -> _Verdict:
    wanted = (expect.joint_state, MsgType.STATUS)
    seen_types = {f.message.msg_type for f in frames if f.message is not None}
    ev = [f.evidence(real) for f in _first_of_each(frames)]
    if not frames:
        return _Verdict(Verdict.FAIL, f"nothing in {options.observe:g} s", ev)
    missing = [_type_name(t) for t in wanted if t not in seen_types]
    if missing:
        return _Verdict(Verdict.FAIL, "never sent: " + ", ".join(missing), ev)
    not_topics = [f for f in frames if f.message is not None and f.message.comm_type != CommType.TOPIC]
    if not_topics:
        return _Verdict(Verdict.FAIL, "state messages that are not TOPICs", [f.evidence(real) for f in not_topics[:3]])
    names = ", ".join(_type_name(t) for t in sorted(seen_types))
    return _Verdict(Verdict.PASS, f"{len(frames)} TOPICs: {names}", ev)


async def state_rate(
    frames: list[Seen],
    options: ServerSuiteOptions,
    expect: Expectations,
    *,
    state: ProbeLink | None,
    motion_started: float | None,
    real: int,
) -> _Verdict:
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
        gap = max(*intervals, (motion_started or time.monotonic()) - times[-1])
        name = _type_name(msg_type)
        ev.append(
            Evidence.note(
                f"{name}: {rate:.1f} Hz, median interval {median * 1000:.1f} ms, p99 jitter "
                f"{jitter * 1000:.1f} ms, longest gap {gap * 1000:.0f} ms ({len(times)} frames)"
            )
        )
        details.append(f"{name} {rate:.1f} Hz")
        joint_state = msg_type == expect.joint_state
        if joint_state and (rate < 1.0 or gap > 1.0):
            verdict = Verdict.FAIL
            details[-1] += f" with a gap of {gap * 1000:.0f} ms (the PC's 1 s watchdog would abort goals)"
        expected = options.state_rate if joint_state else None
        if expected and abs(rate - expected) > 0.25 * expected:
            verdict = Verdict.FAIL
            details[-1] += f" (expected {expected:g} Hz)"
        documented = expect.rates.get(msg_type)
        if verdict is Verdict.PASS and documented and rate < 0.5 * documented:
            verdict = Verdict.WARN
            details[-1] += f" ({options.profile} sends {documented:g} Hz)"
        if verdict is Verdict.PASS and jitter > 0.5 * median:
            verdict = Verdict.WARN
            details[-1] += f" (jitter {jitter * 1000:.1f} ms)"
    if state is not None and state.closed_at is not None and state.closed_at <= (motion_started or math.inf):
        ev.append(Evidence.note(f"the state port closed the connection: {state.close_reason or 'end of stream'}"))
        return _Verdict(Verdict.FAIL, "the state port closed the connection while watched", ev)
    joint_count = sum(1 for f in frames if f.message is not None and f.message.msg_type == expect.joint_state)
    if joint_count < 3:
        window = (motion_started or time.monotonic()) - frames[0].time
        ev.append(Evidence.note(f"{joint_count} joint-state frames in the {window:.1f} s watched"))
        ev.extend(f.evidence(real) for f in frames[:2])
        return _Verdict(Verdict.FAIL, f"{joint_count} joint-state frames in {window:.1f} s", ev)
    return _Verdict(verdict, ", ".join(details), ev)


async def state_joint_state(frames: list[Seen], real: int) -> _Verdict:
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
        ev = [p.evidence(real) for p in problems[:5]]
        return _Verdict(Verdict.FAIL, f"{len(problems)} joint-state frames wrong: {why[0]}", ev)
    count = sum(1 for f in frames if _joints_of(f.message) is not None)
    if not count:
        raise _Skip("no joint state was sent")
    return _Verdict(Verdict.PASS, f"{count} joint states: finite, valid_fields honest", [])


async def state_status(frames: list[Seen], dialect: Dialect, real: int) -> _Verdict:
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
        if s.motion_possible == TriState.TRUE and s.drives_powered == TriState.FALSE and not dialect.motion_control:
            problems.append((f, "motion_possible TRUE with the drives off"))
        if s.in_motion == TriState.TRUE and s.drives_powered == TriState.FALSE:
            problems.append((f, "in_motion TRUE with the drives off"))
    statuses = [f for f in frames if isinstance(f.message, Status)]
    if not statuses:
        raise _Skip("no STATUS was sent")
    if problems:
        ev = [Evidence.note(problems[0][1])] + [p.evidence(real) for p, _ in problems[:4]]
        return _Verdict(Verdict.FAIL, f"{len(problems)} STATUS problems: {problems[0][1]}", ev)
    codes = [
        f.message.error_code for f in statuses if isinstance(f.message, Status) and f.message.in_error != TriState.TRUE
    ]
    if any(codes):
        return _Verdict(Verdict.WARN, "an error_code with in_error not TRUE", [statuses[-1].evidence(real)])
    return _Verdict(Verdict.PASS, f"{len(statuses)} STATUS frames valid", [statuses[-1].evidence(real)])


async def state_consistency(frames: list[Seen]) -> _Verdict:
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


# -- framing, judged over everything received ------------------------------------------------------


async def framing_byte_order(
    frames: list[Seen],
    options: ServerSuiteOptions,
    dialect: Dialect,
    *,
    wire: WireFormat | None,
    detected: WireFormat | None,
    real: int,
) -> _Verdict:
    if wire is None or not frames:
        raise _Skip("no frame was received")
    order = wire.byte_order.value
    swapped = [f for f in frames if f.swapped]
    if swapped:
        ev = [f.evidence(real) for f in swapped[:5]]
        return _Verdict(Verdict.FAIL, f"{len(swapped)} frame(s) in the other byte order (the rest {order}-endian)", ev)
    expected = options.byte_order
    if expected and detected is not None and detected.byte_order.value != expected:
        return _Verdict(Verdict.FAIL, f"the server speaks {detected.byte_order.value}-endian, not {expected}", [])
    note = f"{order}-endian, all {len(frames)} frames"
    default = dialect.wire.byte_order.value
    if order != default:
        note += f" (the {options.profile} default is {default}; a bswap build, like Fanuc's and the FS100's)"
    return _Verdict(Verdict.PASS, note, [])


async def framing_float_size(frames: list[Seen], options: ServerSuiteOptions, detected: WireFormat | None) -> _Verdict:
    if detected is None:
        raise _Skip("no state frame to measure reals by")
    size = detected.real_size
    sized = [f for f in frames if f.message is not None and _has_reals(f.message)]
    wrong = [f for f in frames if f.fault is Fault.LAYOUT]
    expected = options.float_size
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


async def framing_length(frames: list[Seen], links: list[ProbeLink], real: int) -> _Verdict:
    if not frames:
        raise _Skip("no frame was received")
    bad = [f for f in frames if f.fault is Fault.PREFIX]
    cut = [link for link in links if link.fault is Fault.CUT_SHORT]
    if bad or cut:
        ev = [f.evidence(real) for f in bad[:5]] + [Evidence.note(f"{lk.role}: {lk.close_reason}") for lk in cut]
        return _Verdict(Verdict.FAIL, "a length prefix that does not frame the stream", ev)
    large = [f for f in frames if len(f.raw) > CPP_MAX_FRAME]
    if large:
        return _Verdict(
            Verdict.WARN,
            f"{len(large)} frames over {CPP_MAX_FRAME} bytes: C++ peers cannot read them",
            [large[0].evidence(real)],
        )
    return _Verdict(Verdict.PASS, f"{len(frames)} frames, every prefix its frame's size", [])


async def framing_body(frames: list[Seen], dialect: Dialect, real: int) -> _Verdict:
    if not frames:
        raise _Skip("no frame was received")
    problems: list[tuple[Seen, str]] = []
    for f in frames:
        msg = f.message
        if f.fault is Fault.LAYOUT and f.problem:
            problems.append((f, f.problem))
        elif isinstance(msg, HeaderOnly) and not _may_be_header_only(msg, dialect):
            problems.append((f, f"{_type_name(msg.msg_type)} with no body, where its layout is required"))
    if problems:
        ev = [Evidence.note(problems[0][1])] + [p.evidence(real) for p, _ in problems[:5]]
        return _Verdict(Verdict.FAIL, f"{len(problems)} frame(s): {problems[0][1]}", ev)
    return _Verdict(Verdict.PASS, f"{len(frames)} bodies match their layouts", [])


def _may_be_header_only(msg: HeaderOnly, dialect: Dialect) -> bool:
    cls = message_class(msg.msg_type, msg.comm_type)
    if cls is None or (not cls.LAYOUT and msg.msg_type != MsgType.MOTO_MOTION_REPLY):
        return True  # a type with no body, or unknown here
    if msg.comm_type != CommType.SERVICE_REPLY:
        return False
    # a reply: short replies are the C++ FAILURE reply and ABB's ack (§3), never MotoROS's or Fanuc's
    if msg.msg_type == MsgType.MOTO_MOTION_REPLY:
        return False
    return dialect.reply_style in (ReplyStyle.ECHO, ReplyStyle.HEADER_ONLY) or msg.reply_code == ReplyCode.FAILURE


async def reply_comm_types(frames: list[Seen], real: int) -> _Verdict:
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
        ev = [f.evidence(real) for f in bad[:5]]
        return _Verdict(Verdict.FAIL, f"{len(bad)} replies with a wrong comm_type or reply_code", ev)
    return _Verdict(Verdict.PASS, f"{len(replies)} replies, all SERVICE_REPLY with SUCCESS or FAILURE", [])


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
