"""The client suite's rules of the stream of requests itself, judged as each point passes.

* ``client.stop-and-wait``: one point request awaits its reply at a time (a STOP may be sent while
  a point waits; a point while the STOP waits may not);
* ``client.stop``: a STOP as the controller takes it, answered before the next point, followed by a
  new trajectory;
* ``client.sequence``: sequences counting 0, 1, 2... per trajectory, the special values used as the
  reference streamer and downloader use them (and none on MotoROS);
* ``client.point-fields``: fields finite and in range, the point types the controller takes, and a
  WARN for a velocity far above what the positions and times around it imply.

:class:`RequestOrder` judges the first three and keeps count of the trajectories (a trajectory
starts with a point of sequence 0, -1 or -2: it is what the injections are planned by);
:class:`PointFields` judges the last. Both write the findings of the observer's
catalogue (:mod:`.client_catalogue`) and keep their state in the points and connections
(:mod:`.client_seen`); the observer (:mod:`.client_rules`) calls them in its order.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from ..constants import ReplyCode, SpecialSeq, ValidFields
from ..messages import JointTrajPt, Message, MotoMotionCtrl
from .client_catalogue import Findings
from .client_seen import START_SEQS, Group, LinkState, Point, Positions, Prev, finite, same, type_name
from .report import Evidence

__all__ = ["PointFields", "RequestOrder"]

#: MotoROS refuses a trajectory time from this many seconds (float32 resolution; §8.1, motoman#244)
MAX_TIME = 14400.0
#: motion groups whose speeds are followed per connection (MotoROS has at most 4)
MAX_GROUPS = 8
#: a velocity this far above what the positions and times imply is implausible (rad/s, x)
SPEED_MARGIN = 0.05
SPEED_FACTOR = 2.0

_REQUIRED_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY


class RequestOrder:
    """The stop-and-wait, stop and sequence rules, and the trajectories counted.

    ``rules`` are the observer's findings, ``moto`` and ``profile`` the controller played, ``ev``
    a point as evidence, ``at`` the time into the run as text; ``trajectory_ended(link)`` is called
    when a trajectory on ``link`` ends (the point-fields rule then judges its last points' speeds).
    """

    def __init__(
        self,
        rules: dict[str, Findings],
        *,
        moto: bool,
        profile: str,
        ev: Callable[[Point], Evidence],
        at: Callable[[], str],
        trajectory_ended: Callable[[LinkState], None],
    ) -> None:
        self.rules = rules
        self.moto = moto
        self.profile = profile
        self.ev = ev
        self.at = at
        self.trajectory_ended = trajectory_ended
        self.point_requests = 0
        self.stops = 0
        self.trajectories = 0
        #: how the first three trajectories were sent ("stream", "download")
        self.modes: dict[int, str] = {}

    # stop-and-wait --------------------------------------------------------------------------------

    def stop_and_wait(self, point: Point) -> None:
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

    # stop -----------------------------------------------------------------------------------------

    def stop(self, point: Point) -> None:
        link = point.link
        rule = self.rules["client.stop"]
        if link.pending_stop is not None:
            rule.fail(
                f"{link.name}: {point.what} sent before the STOP's reply", self.ev(link.pending_stop), self.ev(point)
            )
        if link.after_stop is not None and point.kind != "malformed":
            stop = link.after_stop
            link.after_stop = None
            if point.kind == "point" and point.seq not in START_SEQS:
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
                f"a {type_name(point)} with sequence -4: MotoROS refuses negative sequences (INVALID/3005); "
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

    # sequence -------------------------------------------------------------------------------------

    def sequence(self, point: Point) -> None:
        link = point.link
        rule = self.rules["client.sequence"]
        if point.kind == "stop":
            self.end_trajectory(link)
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
                    and same(last.positions, point.positions)
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
        self.end_trajectory(link)
        self.trajectories += 1
        link.trajectory = self.trajectories
        if self.trajectories <= 3:  # the injections' trajectories
            self.modes[self.trajectories] = mode
        link.mode = mode
        link.acked.clear()
        point.start = True
        point.trajectory = link.trajectory

    def end_trajectory(self, link: LinkState) -> None:
        """The trajectory under way on ``link`` ended (a STOP, a new one, the connection closed)."""
        self.trajectory_ended(link)
        link.mode = None
        link.last = None


class PointFields:
    """The point-fields rule: ``rules`` are the observer's findings, ``moto`` and ``profile`` the
    controller played, ``ev`` a point as evidence."""

    def __init__(
        self, rules: dict[str, Findings], *, moto: bool, profile: str, ev: Callable[[Point], Evidence]
    ) -> None:
        self.rules = rules
        self.moto = moto
        self.profile = profile
        self.ev = ev
        #: trajectory points judged
        self.points = 0

    def judge(self, point: Point) -> None:
        """A point (or a point type that fits no layout); a STOP has no fields to judge."""
        if point.kind == "point" and point.seq is not None:
            self.points += 1
            self._fields(point)
        elif point.kind == "malformed":
            self.rules["client.point-fields"].fail(
                f"{point.link.name} sent a {type_name(point)} whose body fits no layout: {point.msg}", self.ev(point)
            )

    def close(self, link: LinkState) -> None:
        """The trajectory on ``link`` ended: the speeds of its last points are judged without a next segment."""
        for prev in link.prev.values():
            self._speed_check(prev, None)
        link.prev.clear()

    def _fields(self, point: Point) -> None:
        rule = self.rules["client.point-fields"]
        rule.checked += 1
        msg = point.msg
        link = point.link
        problems: list[str] = []
        if isinstance(msg, JointTrajPt):
            if self.moto:
                problems.append("MotoROS takes no JOINT_TRAJ_PT (INVALID/3003): its points are JOINT_TRAJ_PT_FULL")
            if not finite(msg.joint_data):
                problems.append("a position is not finite")
            if not (math.isfinite(msg.velocity) and 0.0 <= msg.velocity <= 1.0):
                problems.append(f"velocity {msg.velocity:g} is not a ratio in [0, 1] (§4.3)")
            if not (math.isfinite(msg.duration) and 0.0 <= msg.duration < MAX_TIME):
                problems.append(f"duration {msg.duration:g} s is not a segment time in [0, {MAX_TIME:g}) s")
            before, link.jtp_positions = link.jtp_positions, msg.joint_data
            moves = before is not None and point.seq is not None and point.seq > 0
            if moves and before is not None and not same(before, msg.joint_data) and msg.duration == msg.velocity == 0:
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

    def _group_fields(self, point: Point, group: Group) -> list[str]:
        problems = []
        name = f"group {group.group}: " if len(point.groups) > 1 or group.group else ""
        if group.valid_fields & _REQUIRED_FIELDS != _REQUIRED_FIELDS:
            problems.append(
                f"{name}valid_fields 0x{group.valid_fields:02x} lacks TIME|POSITION|VELOCITY (MotoROS requires 0x07: "
                "INVALID/3015, §8.1)"
            )
        if not (math.isfinite(group.time) and 0.0 <= group.time < MAX_TIME):
            problems.append(f"{name}time {group.time:g} s is not in [0, {MAX_TIME:g}) s (INVALID/3016, §8.1)")
        if not finite(group.positions):
            problems.append(f"{name}a position is not finite")
        if not finite(group.velocities):
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
            link.prev[group.group] = Prev(seq, group.time, group.positions, group.velocities, point)
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
        link.prev[group.group] = Prev(seq, group.time, group.positions, group.velocities, point, speeds)
        return problems

    def _speed_check(self, prev: Prev, after: Positions | None) -> None:
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
