"""The server suite's catalogue: what each family of real servers does, and every rule it judges.

What a profile's real servers do differently where the protocol leaves it open (which port answers
a PING, how an unknown type is answered, which topics the state port sends at what rate) is in
:data:`EXPECTATIONS`, from the project's protocol notes (docs/reference/protocol.md §3, §5, §8).
:data:`SERVER_RULES` lists every rule of the suite, in report order, with what it checks and the
real peer behaviour it comes from; the rules and their sources are listed in docs/conformance.md
too. The groups the suite runs (or skips) together are named here as well: the requests that cannot
move anything (:data:`REQUEST_RULES`), the state port's rules (:data:`STATE_RULES`) and the motion
rules (:data:`MOTION_RULES`, MotoROS's among them :data:`MOTOROS_MOTION_RULES`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..constants import MsgType
from ..dialects import ABB, FANUC, GENERIC, MOTOROS, STAUBLI, Dialect

__all__ = [
    "Expectations",
    "EXPECTATIONS",
    "SERVER_RULES",
    "REQUEST_RULES",
    "STATE_RULES",
    "MOTION_RULES",
    "MOTOROS_MOTION_RULES",
]


@dataclass(frozen=True)
class Expectations:
    """What one family of real servers does, where the protocol leaves it open."""

    dialect: Dialect
    #: its motion port answers a PING (ABB's RAPID server takes only JOINT_TRAJ_PT and stops on
    #: anything else; Fanuc's relay waits for 56 bytes and would misframe one; Stäubli's answers only
    #: trajectory points, §8.2, §8.3, docs/vendors.md)
    ping: bool
    #: it can be sent a request of an unknown type (the same servers cannot)
    unknown_types: bool
    #: the state port's joint-state topic
    joint_state: int
    #: documented rates of its state topics (Hz), for a WARN when far off
    rates: dict[int, float] = field(default_factory=dict)
    #: where its behaviour is documented
    source: str = ""
    #: why malformed frames must not be sent to it (None: they may, each on its own connection)
    no_malformed: str | None = None
    #: its STOP is known to stop nothing (why; a WARN, not a FAIL, when the robot goes on)
    stop_stops_nothing: str | None = None
    #: it acknowledges a point before checking it, then answers FAILURE and hangs up (Fanuc's relay)
    acks_before_checking: bool = False
    #: its motion port serves one client; a second waits in the listen backlog, and ABB's server
    #: resets its backlog when its client goes (docs/vendors.md): the suite closes its link before
    #: it connects anew, and connects once more if the new link is reset
    one_client: bool = False


EXPECTATIONS: dict[str, Expectations] = {
    "generic": Expectations(
        GENERIC, True, True, MsgType.JOINT_POSITION, {}, "the reference C++ library (docs/reference/protocol.md §3, §6)"
    ),
    "abb": Expectations(
        ABB,
        False,
        False,
        MsgType.JOINT_POSITION,
        {MsgType.JOINT_POSITION: 10.0, MsgType.STATUS: 10.0},
        "abb_driver's RAPID servers (docs/reference/protocol.md §8.2)",
        no_malformed="RAPID's motion server stops on a message it cannot read, unanswered, until its program is "
        "restarted (ROS_messages.sys:111-124, ROS_motionServer.mod:51): not sent",
        one_client=True,
    ),
    "fanuc": Expectations(
        FANUC,
        False,
        False,
        MsgType.JOINT_POSITION,
        {MsgType.JOINT_POSITION: 1000.0 / 24.0, MsgType.STATUS: 1000.0 / 24.0 / 11.0},
        "fanuc_driver's KAREL servers (docs/reference/protocol.md §8.3)",
        stop_stops_nothing="Fanuc's relay answers STOP SUCCESS, but its CANCEL stops nothing: the TP program runs "
        "the points it has taken (ros_relay.kl:309-318, ros-industrial/fanuc#93)",
        acks_before_checking=True,
        one_client=True,
    ),
    "staubli": Expectations(
        STAUBLI,
        False,
        False,
        MsgType.JOINT_POSITION,
        {MsgType.JOINT_POSITION: 50.0, MsgType.STATUS: 10.0},
        "staubli_val3_driver's VAL3 server (docs/vendors.md)",
        one_client=True,
    ),
    "motoros": Expectations(
        MOTOROS,
        True,
        True,
        MsgType.JOINT_FEEDBACK,
        {MsgType.JOINT_FEEDBACK: 40.0, MsgType.STATUS: 40.0},
        "MotoROS (docs/reference/protocol.md §8.1)",
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

#: the requests on the motion port that cannot move anything: they need the motion link and the byte
#: order the server speaks
REQUEST_RULES: tuple[str, ...] = (
    "reply.ping",
    "reply.order",
    "reply.unknown-type",
    "reply.unknown-topic",
    "malformed.survival",
    "motoros.check-motion-ready",
)
#: the state port's rules, judged over what it sent before any motion
STATE_RULES: tuple[str, ...] = (
    "state.topics",
    "state.rate",
    "state.joint-state",
    "state.status",
    "state.status-consistency",
)
#: the rules that move the robot (only with ``allow_motion``)
MOTION_RULES: tuple[str, ...] = (
    "motion.preconditions",
    "motion.small-move",
    "motion.in-motion",
    "motion.stop",
    "motion.out-of-limit",
    "motoros.traj-mode",
    "motoros.busy",
    "motoros.start-position",
)
#: the motion rules of a MotoROS server only
MOTOROS_MOTION_RULES: tuple[str, ...] = ("motoros.traj-mode", "motoros.busy", "motoros.start-position")
