"""What each family of real peers makes of simple_message, as data: one :class:`Dialect` each.

The protocol leaves open which ports a controller listens on, its byte order, how it answers a
request and which topics its state port sends. Each controller family settled these differently
(the project's protocol notes, §1.3, §3, §6, §8): the reference C++ library echoes a request's body
in its reply, ABB's RAPID server replies header-only, Fanuc's KAREL server acknowledges a
JOINT_TRAJ_PT with a JOINT_POSITION reply and speaks big-endian, Stäubli's VAL3 server answers with
a message of the request's type whose fields are zero but the sequence, MotoROS answers every
request but PING with a MOTO_MOTION_REPLY (type 2002) on its own ports. A link that knows its peer's dialect
matches replies by that dialect's rule (:meth:`Dialect.answers`); one that does not accepts what
any registered dialect would send (:func:`any_dialect_answers`), so registering a dialect widens
that rule for every such link in the process. (Before the dialects, a link took a
MOTO_MOTION_REPLY as the answer to any request, PING included; no dialect answers a PING so, and
neither does a link that does not know its peer.)

Adding a dialect is one :class:`Dialect` value passed to :func:`register` (in its own module or
here, with its tests); ``robot_server.emulator.profiles`` says how the emulator plays it.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from .constants import MsgType, Port
from .messages import Message
from .registry import Registry
from .wire import BE32, LE32, WireFormat

__all__ = [
    "ABB",
    "DIALECTS",
    "FANUC",
    "GENERIC",
    "MOTOROS",
    "STAUBLI",
    "Dialect",
    "ReplyStyle",
    "any_dialect_answers",
    "dialect",
    "register",
    "reply_style_of",
    "unregister",
]


class ReplyStyle(enum.Enum):
    """How a server answers a request it accepts."""

    #: the request's message with its body, comm_type SERVICE_REPLY (the C++ library)
    ECHO = "echo"
    #: the request's type with no body (ABB)
    HEADER_ONLY = "header-only"
    #: a JOINT_TRAJ_PT answered by a JOINT_POSITION carrying its sequence (Fanuc)
    JOINT_POSITION_ACK = "joint-position-ack"
    #: a MOTO_MOTION_REPLY whose body says the outcome (MotoROS; PING is echoed)
    MOTO_MOTION_REPLY = "moto-motion-reply"
    #: the request's type at its full length, the sequence echoed and every other field zero (Stäubli)
    ZEROED = "zeroed"


def reply_style_of(value: ReplyStyle | str) -> ReplyStyle:
    """``value`` as a :class:`ReplyStyle` (also its value, and ``"header"`` for header-only);
    :class:`ValueError` names the known ones."""
    if isinstance(value, ReplyStyle):
        return value
    try:
        return ReplyStyle("header-only" if value == "header" else value)
    except ValueError:
        known = ", ".join(style.value for style in ReplyStyle)
        raise ValueError(f"unknown reply style {value!r} (known: {known})") from None


@dataclass(frozen=True)
class Dialect:
    """One family of peers: where it listens, what it speaks, how it answers."""

    name: str
    description: str
    motion_port: int
    state_port: int
    #: the I/O port, if the family has one
    io_port: int | None
    #: byte order and float size it speaks by default
    wire: WireFormat
    reply_style: ReplyStyle
    #: reply types that answer a request of any type, besides the request's own
    replies_to_any: frozenset[int] = frozenset()
    #: per request type, reply types that answer it besides its own (replaces replies_to_any)
    replies: Mapping[int, frozenset[int]] = field(default_factory=dict)
    #: topics its state port publishes, in the order of one round
    state_topics: tuple[int, ...] = (MsgType.JOINT_POSITION, MsgType.STATUS)
    #: the trajectory point message its motion port takes
    point_type: int = MsgType.JOINT_TRAJ_PT
    #: motion is checked, started and stopped with MOTO_MOTION_CTRL commands (MotoROS's
    #: trajectory mode) rather than by the points themselves and a STOP point
    motion_control: bool = False
    #: it runs the points on the times they carry; False: each at a speed of its own (Fanuc's
    #: R[1] %, Stäubli's velocity share), their times ignored
    timed: bool = True
    #: how a trajectory may be sent to it, the first the usual: "stream" (sequence 0, 1, ...; one
    #: request in flight) and "download" (-1, 1 ... n-2, -3); ABB runs downloads only
    modes: tuple[str, ...] = ("stream", "download")
    #: the most points of one trajectory it keeps (ABB's 100-point buffer: beyond it points are dropped)
    max_points: int | None = None
    #: its motion port answers a PING (ABB's, Fanuc's and Stäubli's servers do not: the first dies
    #: on it, the second stalls, the third leaves it unanswered)
    ping: bool = True
    #: a point it cannot queue yet is answered FAILURE (Stäubli's full queue), not held or BUSY
    fails_when_full: bool = False
    #: it answers a request of a type it does not know (the C++ library: FAILURE; MotoROS: INVALID);
    #: ABB's, Fanuc's and Stäubli's servers do not (nor a PING: ``ping``)
    unknown_types: bool = True
    #: its J3 is measured from the horizontal, not from J2's link: J3 - J23_factor x J2 of the
    #: model's (Fanuc; fanuc_driver's ``J23_factor`` converts both ways, 1 by default here)
    j23_coupled: bool = False
    #: a trajectory's first point closer than this (rad, every joint) is skipped; farther, the
    #: controller moves there first, in that point's duration (ABB's ``is_near``: 0.1 degree)
    skips_first_within: float | None = None

    def __post_init__(self) -> None:
        # read-only: a built-in dialect's rules cannot be changed behind every link's back
        frozen = {int(k): frozenset(v) for k, v in self.replies.items()}
        object.__setattr__(self, "replies", MappingProxyType(frozen))

    def __hash__(self) -> int:
        return hash(self.name)

    def answers(self, request_type: int, reply: Message) -> bool:
        """Whether ``reply`` can be this dialect's answer to a request of ``request_type``."""
        reply_type = reply.msg_type
        if reply_type == request_type:
            return True
        return reply_type in self.replies.get(request_type, self.replies_to_any)

    @property
    def ports(self) -> dict[str, int]:
        """Its default ports by role (``motion``, ``state`` and, if it has one, ``io``)."""
        ports = {"motion": self.motion_port, "state": self.state_port}
        if self.io_port is not None:
            ports["io"] = self.io_port
        return ports


GENERIC = Dialect(
    name="generic",
    description="the ROS-Industrial C++ reference library (industrial_robot_client's peers)",
    motion_port=Port.MOTION,
    state_port=Port.STATE,
    io_port=Port.IO,
    wire=LE32,
    reply_style=ReplyStyle.ECHO,
)
ABB = Dialect(
    name="abb",
    description="ABB IRC5, abb_driver's RAPID servers",
    motion_port=Port.MOTION,
    state_port=Port.STATE,
    io_port=None,
    wire=LE32,
    reply_style=ReplyStyle.HEADER_ONLY,
    modes=("download",),
    max_points=100,
    ping=False,
    unknown_types=False,
    skips_first_within=math.radians(0.1),
)
FANUC = Dialect(
    name="fanuc",
    description="Fanuc, the fanuc_driver KAREL servers (ros_relay, ros_state)",
    motion_port=Port.MOTION,
    state_port=Port.STATE,
    io_port=None,
    wire=BE32,
    reply_style=ReplyStyle.JOINT_POSITION_ACK,
    replies={MsgType.JOINT_TRAJ_PT: frozenset({MsgType.JOINT_POSITION})},
    timed=False,
    modes=("stream",),
    ping=False,
    unknown_types=False,
    j23_coupled=True,
)
STAUBLI = Dialect(
    name="staubli",
    description="Staubli CS8/CS9, staubli_val3_driver's VAL3 server",
    motion_port=Port.MOTION,
    state_port=Port.STATE,
    io_port=None,
    wire=LE32,
    reply_style=ReplyStyle.ZEROED,
    timed=False,
    modes=("stream",),
    ping=False,
    fails_when_full=True,
    unknown_types=False,
)
MOTOROS = Dialect(
    name="motoros",
    description="Yaskawa Motoman, MotoROS (DX100, DX200, YRC1000; the FS100 speaks big-endian)",
    motion_port=Port.MOTOROS_MOTION,
    state_port=Port.MOTOROS_STATE,
    io_port=Port.MOTOROS_IO,
    wire=LE32,
    reply_style=ReplyStyle.MOTO_MOTION_REPLY,
    replies_to_any=frozenset({MsgType.MOTO_MOTION_REPLY}),
    replies={MsgType.PING: frozenset()},
    state_topics=(MsgType.JOINT_FEEDBACK, MsgType.STATUS),
    point_type=MsgType.JOINT_TRAJ_PT_FULL,
    motion_control=True,
    modes=("stream",),
)

#: Every registered dialect by name.
DIALECTS: Registry[Dialect] = Registry("dialect", KeyError)


def register(value: Dialect, *, replace: bool = False) -> Dialect:
    """Make ``value`` known by its name (``replace``: over one of the same name)."""
    return DIALECTS.add(value.name, value, replace=replace)


def unregister(name: str) -> None:
    """Forget the dialect called ``name`` (tests that register their own)."""
    DIALECTS.remove(name)


def dialect(name: str) -> Dialect:
    """The registered dialect called ``name``; :class:`KeyError` names the known ones."""
    return DIALECTS.named(name)


def any_dialect_answers(request_type: int, reply: Message) -> bool:
    """Whether any registered dialect would answer a request of ``request_type`` with ``reply``
    (the rule of a link that does not know its peer)."""
    return any(d.answers(request_type, reply) for d in DIALECTS.values())


for _dialect in (GENERIC, ABB, FANUC, MOTOROS, STAUBLI):
    register(_dialect)
