"""The client suite's rules of how a client meets the robot and the controller's awkward answers.

* ``client.first-point``: each trajectory starts where the robot is, within ``start_tolerance`` (the
  nearer of the joint state when the point arrived and the next one: the suite's own view of the
  robot lags the client's by up to one state period);
* ``client.reconnect``: a motion connection after the first begins with a new trajectory starting
  where the robot is, or a STOP, and sends nothing of the interrupted trajectory again;
* ``client.busy-reaction``: a point answered BUSY is sent again, unchanged, before any other;
* ``client.failure-reaction``: after a refused point, no later point of that trajectory (a FAIL for
  MotoROS, whose driver aborts; a WARN elsewhere, the reference streamer ignoring reply codes).

:class:`StartPositions` judges the first two: a trajectory's first point, and the first point or
STOP of a connection after another, wait for the next joint state before they are judged.
:class:`Reactions` judges the last two, watching the client from the moment the injected reply
reached it. Both write the findings of the observer's catalogue (:mod:`.client_catalogue`); the
observer (:mod:`.client_rules`) feeds them.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from .client_catalogue import Findings
from .client_seen import MAX_WAITING, START_SEQS, LinkState, Point, Positions, fmt, max_gap, same, same_positions
from .report import Evidence

__all__ = ["Reactions", "StartPositions"]


class StartPositions:
    """The first-point and reconnect rules: ``rules`` are the observer's findings,
    ``start_tolerance`` (rad) the suite's option, ``ev`` a point as evidence."""

    def __init__(self, rules: dict[str, Findings], *, start_tolerance: float, ev: Callable[[Point], Evidence]) -> None:
        self.rules = rules
        self.start_tolerance = start_tolerance
        self.ev = ev
        #: the robot's latest joint positions (group 0)
        self.state: Positions | None = None
        #: the points waiting for the next joint state
        self.waiting: deque[Point] = deque()
        #: what the previous motion connection had acknowledged, when a new one opened
        self.interrupted: dict[int, Positions] = {}

    def arrived(self, point: Point) -> None:
        """A point that starts a trajectory or a connection: judged at the next joint state."""
        if point.start or point.reconnect:
            point.here = self.state
            self.waiting.append(point)
            while len(self.waiting) > MAX_WAITING:
                self._resolve(self.waiting.popleft())

    # first point ----------------------------------------------------------------------------------

    def sample(self, positions: Positions) -> None:
        """A joint state of the robot: the points waiting for it are judged."""
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
        gaps = [max_gap(point.positions, here) for here in (point.here, point.after) if here is not None]
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
                        Evidence.note(f"the robot was at {fmt(point.here)}"),
                    )
                elif rule.checked <= 2:
                    rule.sample(self.ev(point))
        if point.reconnect:
            self._reconnect(point, distance)

    def flush(self) -> None:
        """Judge the points still waiting for a joint state (at the end of the run)."""
        while self.waiting:
            self._resolve(self.waiting.popleft())

    # reconnect ------------------------------------------------------------------------------------

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
        resent = known is not None and same(known, point.positions)
        tolerance = self.start_tolerance
        if point.seq not in START_SEQS:
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


class Reactions:
    """The busy-reaction and failure-reaction rules: ``rules`` are the observer's findings, ``moto``
    whether the controller played is MotoROS, ``ev`` a point as evidence."""

    def __init__(self, rules: dict[str, Findings], *, moto: bool, ev: Callable[[Point], Evidence]) -> None:
        self.rules = rules
        self.moto = moto
        self.ev = ev
        #: the point answered BUSY, the point refused, and the refused point sent again
        self.busy_watch: Point | None = None
        self.failure_watch: Point | None = None
        self.failure_retry: Point | None = None

    def watch(self, kind: str, point: Point) -> None:
        """``point`` was answered by the ``kind`` injection: watch what the client does next."""
        if kind == "busy":
            self.busy_watch = point
        elif kind == "failure":
            self.failure_watch = point
            self.failure_retry = None

    def link_closed(self, link: LinkState) -> None:
        """The client closed ``link``: giving up after BUSY, and no more of a refused trajectory."""
        watch = self.busy_watch
        if watch is not None and watch.link is link and watch.outcome is not None:
            self.busy_watch = None
            self.rules["client.busy-reaction"].fail(
                f"the client closed the connection instead of resending {watch.what} after BUSY (it gave up)",
                self.ev(watch),
            )
        if self.failure_watch is not None and self.failure_watch.link is link:
            self.failure_passed("closed the connection")

    def finish(self) -> None:
        """The run is over: a point answered BUSY and never sent again, a refused trajectory never gone on with."""
        watch = self.busy_watch
        if watch is not None and watch.outcome is not None:
            self.busy_watch = None
            self.rules["client.busy-reaction"].fail(
                f"the client never sent {watch.what} again after BUSY (it gave up)", self.ev(watch)
            )
        if self.failure_watch is not None:
            self.failure_passed("sent nothing more of that trajectory")

    def busy(self, point: Point) -> None:
        """The point after the one answered BUSY: the same one again, unchanged?"""
        watch = self.busy_watch
        if watch is None or watch.link is not point.link or watch.outcome is None or point.kind == "malformed":
            return
        self.busy_watch = None
        rule = self.rules["client.busy-reaction"]
        if point.kind == "point" and point.seq == watch.seq and same_positions(point, watch):
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

    def failure(self, point: Point) -> None:
        """A point after the one refused: none of that trajectory but the refused one again?"""
        watch = self.failure_watch
        if watch is None or watch.link is not point.link or watch.outcome is None or point.kind == "malformed":
            return
        if point.kind == "stop" or point.start:
            self.failure_passed("sent STOP" if point.kind == "stop" else f"started trajectory {point.trajectory}")
            return
        if point.seq == watch.seq:
            self.failure_retry = point
            return
        retry = self.failure_retry
        if retry is not None and retry.outcome == "success":
            self.failure_passed(f"sent {watch.what} again (accepted) and went on")
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

    def failure_passed(self, how: str) -> None:
        """The client reacted to the refusal as it should (``how``)."""
        watch = self.failure_watch
        if watch is None:
            return
        self.failure_watch = None
        rule = self.rules["client.failure-reaction"]
        rule.checked += 1
        rule.note(f"after FAILURE to {watch.what} of trajectory {watch.trajectory}, the client {how}")
