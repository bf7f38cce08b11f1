"""Cartesian supervision of planned motion: the tool's path against the zones and the TCP speed
limit, before the robot moves (:class:`.controller.Controller` checks every planned joint path with
it; its live supervision of the tool, every interpolation instant, stays in the controller).

:func:`tcp_path` turns a joint path into TCP positions and their peak speed; :func:`check_zones`
refuses a path that breaks a zone rule (WORKSPACE); :func:`path_slowing` says by how much a
trajectory must slow down for the TCP speed limit in force (MANUAL) or refuses it (AUTO:
TCP_SPEED). :class:`Slowing` is how a trajectory is slowed down round by round until it fits.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..arrays import Array
from ..kinematics import fk_batch
from ..model import RobotModel
from ..workspace import Supervision, densify, first_violation, point_violation
from .points import Point, PointRejected, Reason

#: how many times a trajectory is slowed down further for the TCP speed limit before it is refused
SLOWING_ROUNDS = 10


def tcp_path(model: RobotModel, tolerance: float, times: Array, q: Array) -> tuple[Array, float]:
    """TCP positions along a joint path (times ``(m,)``, positions ``(m, dof)``, a few ms
    apart) and its peak speed. Where two positions are more than ``tolerance`` apart, the joint
    path is subdivided (linearly: over a few ms the joints move on a straight line to well within
    the tolerance) until they are not."""
    positions = fk_batch(model, q)[:, :3, 3]
    gaps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    if gaps.size and float(gaps.max()) > tolerance:
        n = np.maximum(np.ceil(gaps / tolerance).astype(np.int64), 1)
        interval = np.repeat(np.arange(gaps.size), n)
        f = (np.arange(interval.size) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
        q = np.concatenate([q[interval] + (q[interval + 1] - q[interval]) * f[:, None], q[-1:]])
        times = np.concatenate([times[interval] + (times[interval + 1] - times[interval]) * f, times[-1:]])
        positions = fk_batch(model, q)[:, :3, 3]
    dt = np.diff(times)
    moved = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    speeds = np.divide(moved, dt, out=np.zeros_like(moved), where=dt > 1e-9)
    return positions, float(speeds.max()) if speeds.size else 0.0


def check_zones(supervision: Supervision, positions: Array) -> None:
    """Refuse (WORKSPACE) a TCP path that breaks a zone rule. A path that starts in a
    violation (after an alarm) is checked from where it first gets clear: it may lead out."""
    if not supervision.has_zones:
        return
    positions = densify(positions, supervision.tolerance)
    violation = first_violation(supervision, positions)
    if violation is not None and violation.sample == 0:
        clear = next(
            (i for i, p in enumerate(positions.tolist()) if point_violation(supervision, *p) is None),
            positions.shape[0],
        )
        violation = first_violation(supervision, positions[clear:])
    if violation is not None:
        raise PointRejected(Reason.WORKSPACE, f"the motion would violate a zone: {violation.message}")


def path_slowing(
    model: RobotModel, supervision: Supervision, *, manual: bool, margin: float, times: Array, q: Array
) -> float | None:
    """Check a planned joint path: the zones (refused: WORKSPACE) and the TCP speed limit in
    force, planned to at most ``margin`` of it (AUTO: refused, TCP_SPEED; MANUAL: returns by how
    much to slow it down). None: fine."""
    limit = supervision.speed_limit(manual)
    if limit is None and not supervision.has_zones:
        return None
    positions, peak = tcp_path(model, supervision.tolerance, times, q)
    check_zones(supervision, positions)
    if limit is None or peak <= limit * margin:
        return None
    if not manual:
        raise PointRejected(
            Reason.TCP_SPEED, f"the trajectory moves the TCP at {peak:.4g} m/s, over the AUTO limit {limit:.4g} m/s"
        )
    return peak / (limit * margin) * 1.01


class Slowing:
    """How a trajectory is slowed down for the TCP speed limit, round by round. First by the
    queue's time scale, which reaches every segment decided from the points' times and ratios;
    once a round gains nothing, also by the velocity ratio of the ratio-timed points (a last
    segment to rest is planned from its ratio when it starts, out of the time scale's reach, and
    an acceleration-bound one hardly slows down with its ratio); a round that still gains nothing
    doubles its step."""

    def __init__(self) -> None:
        self.scale = 1.0  # the time scale asked of the queue
        self.ratio = 1.0  # the division of the velocity ratios
        self._last = math.inf
        self._by_ratio = False

    def step(self, factor: float) -> None:
        """One more round, for the TCP's ``factor`` = peak / limit (with margin)."""
        stuck = factor >= self._last * 0.99
        self._last = factor
        if stuck:
            if self._by_ratio:
                factor = max(factor, 2.0)
            self._by_ratio = True
        self.scale *= factor
        if self._by_ratio:
            self.ratio *= factor


def slowed(point: Point, factor: float) -> Point:
    """``point`` with its velocity ratio divided by ``factor`` where it is timed by one (a
    JOINT_TRAJ_PT with duration 0); any other point as it is."""
    timed = point.duration is not None and point.duration > 0.0
    if factor == 1.0 or point.velocity_ratio is None or timed:
        return point
    return dataclasses.replace(point, velocity_ratio=point.velocity_ratio / factor)


class SlowDown(Exception):
    """A downloaded trajectory must be slowed down by ``factor`` for the TCP speed limit."""

    def __init__(self, factor: float) -> None:
        super().__init__(f"slow down x{factor:.3g}")
        self.factor = factor
