"""The client suite's rules: what a client under test sends, judged by what real controllers do with it.

The proxy in :mod:`.client` plays the controller; an :class:`Observer` judges the client. The proxy
feeds it as the bytes pass (each connection opened and closed, every frame the client sends, each
reply once it reached the client, each injection, the robot's joint state) and asks it for the
verdicts at the end; the observer touches no socket and never waits (it runs, synchronous, on the
proxy's event loop). A client is judged by what the controllers it will meet do with its frames,
not by what the protocol would allow (the sections cited are docs/reference/protocol.md's):

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

The :class:`Observer` here is the proxy's one interface: it keeps the connections, judges the byte
order, hands each point to the rules in their order and writes the report. The rules themselves
are composed from :mod:`.client_catalogue` (the rules' titles, sources and findings),
:mod:`.client_seen` (the points and connections they judge), :mod:`.client_stream` (stop-and-wait,
stop, sequence, point fields) and :mod:`.client_reactions` (first point, reconnect, the reactions
to BUSY and FAILURE). The names in ``__all__`` are importable from here.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

from ..dialects import Dialect
from ..errors import MalformedMessage
from ..messages import Message
from ..wire import ByteOrder, WireFormat
from .client_catalogue import INJECTION_RULES, RULES, rule_findings
from .client_reactions import Reactions, StartPositions
from .client_seen import SAME, LinkState, Point, Positions, frame_evidence, outcome, point_of
from .client_stream import PointFields, RequestOrder
from .cutter import other_order
from .report import Evidence, Report, RuleResult

__all__ = ["RULES", "SAME", "LinkState", "Observer", "Point", "Positions"]

#: acknowledged points remembered per connection (to recognise one sent again after a reconnect)
MAX_ACKED = 4096


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
        self.frames = {ByteOrder.LITTLE: 0, ByteOrder.BIG: 0}
        self.last_motion: LinkState | None = None
        self.dropped: LinkState | None = None
        #: the injection log, one line per injection, and the injections made (each is made once)
        self.injections: list[str] = []
        self.done: set[str] = set()
        self.rules = rule_findings(self.moto)
        self.fields = PointFields(self.rules, moto=self.moto, profile=profile, ev=self.ev)
        self.order = RequestOrder(
            self.rules, moto=self.moto, profile=profile, ev=self.ev, at=self.at, trajectory_ended=self.fields.close
        )
        self.positions = StartPositions(self.rules, start_tolerance=start_tolerance, ev=self.ev)
        self.reactions = Reactions(self.rules, moto=self.moto, ev=self.ev)

    # -- helpers ------------------------------------------------------------------------------------

    def at(self) -> str:
        return f"{self.clock() - self.t0:.2f} s"

    def evidence(
        self, direction: str, frame: bytes, msg: Message | MalformedMessage | None, other: bool = False
    ) -> Evidence:
        return frame_evidence(direction, frame, msg, self.other_wire if other else self.wire)

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
                self.positions.interrupted = dict(previous.acked)
            self.last_motion = link
        self.links[link_id] = link
        return link

    def link_closed(self, link: LinkState, by: str) -> None:
        self.links.pop(link.id, None)
        if link.role != "motion":
            return
        self.order.end_trajectory(link)
        if by == "drop":
            self.dropped = link
        self.reactions.link_closed(link)

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
        point = point_of(link, frame, msg)
        if point is None:
            return None
        self._judge_point(point)
        return point

    def _judge_point(self, point: Point) -> None:
        """Each rule in its order: a rule may read what an earlier one noted on the point (its
        trajectory, whether it starts one)."""
        link = point.link
        first_on_link = not link.seen_point
        link.seen_point = True
        if first_on_link and link.motion_index > 1:
            point.reconnect = True
        self.reactions.busy(point)
        self.order.stop_and_wait(point)
        self.order.stop(point)
        self.order.sequence(point)
        self.reactions.failure(point)
        self.fields.judge(point)
        self.positions.arrived(point)

    def state_sample(self, positions: Positions) -> None:
        """A joint state of the robot (group 0), as the suite's own state connection read it."""
        self.positions.sample(positions)

    # -- replies and injections ----------------------------------------------------------------------

    def reply_sent(self, point: Point, reply: Message | MalformedMessage, frame: bytes) -> None:
        """The reply to ``point`` reached the client."""
        link = point.link
        point.outcome = outcome(reply)
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
            rule = self.rules[INJECTION_RULES[point.injected]]
            rule.sample(ev)
            rule.keep(ev)

    def injected(self, kind: str, point: Point, what: str) -> str:
        """Note an injection, start watching the client's reaction; the line for the injection log."""
        point.injected = kind
        self.done.add(kind)
        line = f"{kind}: trajectory {point.trajectory}, {point.what} on {point.link.name} at {self.at()}: {what}"
        self.injections.append(line)
        self.rules[INJECTION_RULES[kind]].note(line)
        self.reactions.watch(kind, point)
        return line

    # -- the report ----------------------------------------------------------------------------------

    def judge(self, report: Report) -> None:
        self.positions.flush()
        for link in list(self.links.values()):
            if link.role == "motion":
                self.order.end_trajectory(link)
        rules = self.rules
        n = self.order.trajectories
        order = self.wire.byte_order.value
        frames = _n(self.frames[ByteOrder.LITTLE] + self.frames[ByteOrder.BIG], "frame")
        report.add(
            rules["client.byte-order"].result(
                f"{frames} from the client, all {order}-endian", "the client sent no frame (connect and send something)"
            )
        )
        report.add(
            rules["client.stop-and-wait"].result(
                f"{_n(self.order.point_requests, 'point request')}, each sent after the previous one's reply",
                "the client sent no point request on the motion port (stream a trajectory as SERVICE_REQUESTs)",
            )
        )
        report.add(
            rules["client.sequence"].result(
                f"{_n(self.fields.points, 'point')} in {_n(n, 'trajectory', 'trajectories')}, every sequence in order",
                "the client sent no trajectory point (stream or download a trajectory)",
            )
        )
        report.add(
            rules["client.point-fields"].result(
                f"{_n(self.fields.points, 'point')}, every field finite and in range",
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
                f"{_n(self.order.stops, 'STOP')}, well formed and answered before the next point",
                "the client sent no STOP (stop the robot once, e.g. robot-client stop)",
            )
        )
        self.reactions.finish()  # what the client never did after BUSY or FAILURE
        report.add(self._busy_result(n))
        report.add(self._failure_result(n))
        report.add(self._reconnect_result())

    def _busy_result(self, n: int) -> RuleResult:
        rule = self.rules["client.busy-reaction"]
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
        if "failure" not in self.inject:
            skipped = "the failure injection was not asked for"
        elif self.order.modes.get(2) == "download":
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
        elif self.order.modes.get(3) == "download":
            skipped = (
                "no reconnect happened: the third trajectory, whose connection is dropped after point 1's reply, "
                "was a download (TOPICs have no reply); stream a third trajectory of at least two points"
            )
        else:
            skipped = (
                f"no reconnect happened: the client sent {self.order.trajectories} trajectories, and it is the "
                "third one (of at least two points) that is dropped after point 1; the client should then reconnect"
            )
        count = _n(rule.checked, "motion connection")
        return rule.result(f"{count} after the first began with a new trajectory or a STOP", skipped)


def _n(count: int, word: str, plural: str | None = None) -> str:
    return f"{count} {word if count == 1 else plural or word + 's'}"
