"""Straight lines executed by the controller (MOVL, MoveL, L): the tool moves on a line in the
cell, its orientation turns by slerp, and the inverse kinematics is solved every interpolation
period.

**A line** goes from where the previous one ends (or from the robot's pose at rest) to a target
tool pose at a TCP speed. The tool position moves along the segment ``p0 -> p1`` and the
orientation along the slerp ``r0 -> r1``, both driven by one path fraction ``u(t)`` from 0 to 1.
``u`` follows a jerk-limited rest-to-rest profile (ruckig, one degree of freedom) over a path
length ``S = max(L, theta v/w, theta a/alpha, theta j/zeta)`` (L the distance, theta the turn): the
TCP stays within its speed, acceleration and jerk, and the turn within the rotation limits of
:class:`LineLimits`.

**Before it moves**, the whole line is sampled (no two samples more than ``step`` = 1 mm or
``angle_step`` = 1 mrad apart) and solved in one batch of inverse kinematics on the branch that
continues the current configuration. It is refused, and nothing moves, when a sample is out of
reach (:attr:`~.Reason.UNREACHABLE`), passes a singularity (:attr:`~.Reason.SINGULAR`: the
Jacobian's inverse condition number falls below ``singularity``, the solver flags a singular
configuration, or a joint jumps more than ``max_joint_step`` between neighbouring samples: the
branch cannot be continued), needs a joint beyond its position limits
(:attr:`~.Reason.POSITION_LIMIT`) or takes the TCP out of the allowed space
(:attr:`~.Reason.WORKSPACE`, :mod:`robot_server.workspace`). Where the joints could not follow the
profile (their velocity or acceleration limits, measured on the same samples by finite
differences), the profile is slowed down until they can, and the log says so.

**Corners**: a line stops exactly at its end unless it carries a blend radius and the next line
arrives before the robot reaches the blend zone. Then the next line starts while this one is
still decelerating, within the last ``blend_radius`` of its path, and the two motions add up (the
second line's displacement, and its turn relative to the corner, superposed on the first): the
path rounds the corner within about the radius, and position, velocity and acceleration stay
continuous. The blended stretch is checked like a line; if it fails any check, or would make the
TCP faster than either line, the corner is not blended (the lines stop exactly at it).

**Running**: :meth:`LineMotion.sample` evaluates the path at the next interpolation instant and
solves the inverse kinematics seeded with the last solution (the nearest of the closed-form
solutions: the same branch), one period ahead, so that the joint velocity and acceleration fed to
the drives are central differences of three solutions. :meth:`LineMotion.stop` brakes every
running line along its own path (a category-2 stop that stays on the line).
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ..arrays import Array
from ..kinematics import (
    ClosedFormIK,
    Singularity,
    chain_functions,
    closed_form,
    quaternion_angle,
    quaternion_of,
    quaternion_to_rotation,
    singularity_measure_batch,
    slerp,
)
from ..kinematics._ops import SCALAR_OPS
from ..model import JointType, RobotModel
from .points import Limits, PointRejected, Reason, State
from .segments import PlanningError, RuckigSegment

__all__ = ["LineLimits", "LineTarget", "LineMotion", "PathCheck"]

log = logging.getLogger(__name__)

Quaternion = tuple[float, float, float, float]

#: a check of TCP positions (N, 3) along a path: raises PointRejected(WORKSPACE) on a violation
PathCheck = Callable[[Array], None]

_MAX_SLOWING_ROUNDS = 6
#: a stretch of a line this long (m) without any inverse-kinematics solution is out of reach; a
#: shorter one is where a singularity loses the solutions (numerically, at a point)
_OUT_OF_REACH = 0.005
#: the most samples a line is checked on every interpolation period: a slower one is sampled more
#: coarsely in time, never more than ``step`` apart (about 40 ms of planning for 5,000 samples)
_SAMPLES = 5_000
#: the share of the TCP acceleration and jerk a line that blends at a corner plans with: the
#: decelerating and the accelerating line add up there (at a right angle, to 1/sqrt(2) of the sum)
_BLEND_SHARE = 0.7


@dataclass(frozen=True)
class LineLimits:
    """What bounds a controller straight line besides the requested TCP speed and the joints."""

    #: TCP acceleration (m/s^2) and jerk (m/s^3)
    acceleration: float = 2.0
    jerk: float = 20.0
    #: turn of the tool: speed (rad/s), acceleration (rad/s^2), jerk (rad/s^3)
    rotation_speed: float = 1.5
    rotation_acceleration: float = 6.0
    rotation_jerk: float = 60.0
    #: the Jacobian's inverse condition number below which a configuration counts as singular
    singularity: float = 1e-3
    #: the largest distance (m) and turn (rad) between two samples of a checked line
    step: float = 0.001
    angle_step: float = 0.001
    #: a joint moving more than this (rad) between two neighbouring samples has left its branch
    max_joint_step: float = 0.1

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"line limit {name} must be a finite number > 0, not {value!r}")


class LineTarget(NamedTuple):
    """A straight line's end: TCP position (m, cell frame), orientation (unit quaternion
    ``(w, x, y, z)``), TCP speed (m/s) and blend radius (m, 0: stop exactly at the end)."""

    position: tuple[float, float, float]
    orientation: Quaternion
    speed: float
    blend_radius: float = 0.0
    sequence: int = 0


@dataclass
class _Line:
    """One line of the timeline: the geometry and its fraction over controller time."""

    target: LineTarget
    p0: Array
    p1: Array
    r0: Array
    r1: Array
    span: float
    #: the path length profile (one joint: s from ``offset``), starting at controller time ``start``
    profile: RuckigSegment | None
    start: float
    offset: float = 0.0
    #: the joint position at its end (the seed of the next line)
    q_end: Array | None = None
    #: controller time from which a following line may be blended in (None: no blending)
    blend_from: float | None = None
    #: the samples it was checked on: times and joint positions (seeds for blended lines)
    checked: tuple[Array, Array] | None = None
    #: the path's speed, acceleration and jerk limits its profile was planned with (a stop brakes within them)
    rates: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the TCP speed it runs at (the target's, capped by the limit in force)
    speed: float = 0.0

    @property
    def duration(self) -> float:
        return self.profile.duration if self.profile is not None else 0.0

    @functools.cached_property
    def floats(self) -> tuple[tuple[float, float, float], Quaternion, Quaternion]:
        """Its displacement and its two orientations as floats (for the control loop)."""
        (dx, dy, dz), r0, r1 = (self.p1 - self.p0).tolist(), self.r0.tolist(), self.r1.tolist()
        return (dx, dy, dz), (r0[0], r0[1], r0[2], r0[3]), (r1[0], r1[1], r1[2], r1[3])

    @property
    def end(self) -> float:
        return self.start + self.duration

    def fraction(self, t: Array) -> Array:
        """Path fraction u at controller times ``t`` (0 before the start, 1 after the end)."""
        if self.profile is None or self.span <= 0.0:
            return np.where(t >= self.start, 1.0, 0.0)
        s = self.profile.sample(np.asarray(t, dtype=float) - self.start).position[..., 0]
        u: Array = np.clip((self.offset + s) / self.span, 0.0, 1.0)
        return np.where(t >= self.start, u, self.offset / self.span)

    def fraction_at(self, t: float) -> float:
        """:meth:`fraction` at one time, in floats (ruckig's own evaluation: half a microsecond)."""
        if self.profile is None or self.span <= 0.0:
            return 1.0 if t >= self.start else 0.0
        local = min(max(t - self.start, 0.0), self.profile.duration)
        s = float(self.profile.trajectory.at_time(local)[0][0])
        return min(max((self.offset + s) / self.span, 0.0), 1.0)

    def relative(self) -> Array:
        """The turn of the whole line relative to its start, as a quaternion."""
        return _multiply(_conjugate(self.r0), self.r1)


class LineMotion:
    """The controller's queue of straight lines (see the module doc)."""

    def __init__(
        self,
        model: RobotModel,
        limits: Limits,
        line_limits: LineLimits,
        period: float,
        *,
        capacity: int = 64,
        path_check: PathCheck | None = None,
    ) -> None:
        solver = closed_form(model)
        self.model = model
        self.available = solver is not None and all(j.type is JointType.REVOLUTE for j in model.joints)
        self._solver: ClosedFormIK | None = solver
        self.limits = limits
        self.line_limits = line_limits
        self.period = period
        self.capacity = capacity
        self.path_check = path_check
        self._pose = chain_functions(model).pose
        self._lines: list[_Line] = []
        #: where the finished lines ended: position, orientation, joints
        self._base: tuple[Array, Array, Array] | None = None
        self._cache: dict[float, tuple[float, ...]] = {}
        #: where braking lines come to rest (position, orientation, joints): the next line's start
        self._stopped_at: tuple[Array, Array, Array] | None = None
        self._last: tuple[float, tuple[float, ...]] | None = None
        self.lines_run = 0

    # -- state -------------------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        """Lines are queued or running (a braking line included)."""
        return bool(self._lines)

    @property
    def fill(self) -> int:
        return len(self._lines)

    def remaining(self, now: float) -> float:
        """Seconds of line motion still to run."""
        return max(0.0, self._lines[-1].end - now) if self._lines else 0.0

    def end_position(self) -> Array | None:
        """The joint position where the queued lines end (None: no line queued)."""
        return self._lines[-1].q_end if self._lines else None

    # -- planning ----------------------------------------------------------------------------------

    def plan(self, target: LineTarget, *, now: float, rest: Array, speed_cap: float | None) -> _Line:
        """Check and time one more line from the end of the queued ones (from ``rest``, the joint
        position at rest, when none is queued), starting no earlier than ``now``; raises
        :class:`PointRejected`. ``speed_cap``: the TCP speed it may not exceed (the line is slowed
        down to it). Nothing changes until :meth:`commit`."""
        solver = self._solver
        if solver is None or not self.available:
            raise PointRejected(
                Reason.UNREACHABLE, f"{self.model.name} has no closed-form inverse kinematics: no controller lines"
            )
        if len(self._lines) >= self.capacity:
            raise PointRejected(Reason.QUEUE_FULL, f"the line queue is full ({self.capacity} lines)")
        p1 = np.array(target.position, dtype=float)
        r1 = np.array(target.orientation, dtype=float)
        r1 = r1 / np.linalg.norm(r1)
        previous = self._lines[-1] if self._lines else None
        if previous is not None and self._stopped_at is not None:  # after a stop: from where it brakes to
            p0, r0, q0 = self._stopped_at
            earliest = max(previous.end, now)
            previous = None  # nothing blends into a stop
        elif previous is not None:
            assert previous.q_end is not None
            p0, r0, q0 = previous.p1, previous.r1, previous.q_end
            earliest = max(previous.end, now)
        else:
            if self._base is not None and np.allclose(self._base[2], rest, atol=1e-12, rtol=0.0):
                p0, r0 = self._base[0], self._base[1]
            else:
                p0, r0 = self._flange(rest)
            q0 = np.asarray(rest, dtype=float)
            earliest = now
        if float(np.dot(r0, r1)) < 0.0:
            r1 = -r1
        speed = target.speed if speed_cap is None else min(target.speed, speed_cap)
        if speed < target.speed:
            log.info(
                "line %d slowed down from %.4g to %.4g m/s (the TCP speed limit)", target.sequence, target.speed, speed
            )
        length = float(np.linalg.norm(p1 - p0))
        angle = quaternion_angle(r0, r1)
        lim = self.line_limits
        span = max(length, angle * speed / lim.rotation_speed, angle * lim.acceleration / lim.rotation_acceleration)
        span = max(span, angle * lim.jerk / lim.rotation_jerk)
        line = _Line(target, p0, p1, r0, r1, span, None, earliest, speed=speed)
        velocity = speed
        if span < 1e-9:  # already there
            line.q_end = q0.copy()
            line.checked = (np.array([earliest]), q0[None, :].copy())
            return line
        blend = previous is not None and previous.blend_from is not None and previous.blend_from >= now + self.period
        slowed = 1.0  # how much the joints' limits slowed the line down (acceleration and jerk)
        for _ in range(_MAX_SLOWING_ROUNDS):
            # at a blended corner two lines' accelerations add up: each plans with a share
            share = _BLEND_SHARE if target.blend_radius > 0.0 else 1.0
            if blend and previous is not None:
                share = min(share, _corner_share(previous, line, lim.acceleration))
            acceleration, jerk = lim.acceleration * share / slowed, lim.jerk * share / slowed
            line.profile = _profile(span, velocity, acceleration, jerk)
            line.rates = (velocity, acceleration, jerk)
            line.start = earliest
            try:
                q, times = self._check_line(line, previous, q0, blend=blend, speed=speed)
            except _Blend:
                blend = False
                continue
            ratio_v, ratio_a = self._joint_rates(q, times)
            if ratio_v <= 1.0 and ratio_a <= 1.0:
                break
            if blend:  # is the corner the cause? then stop at it instead; else slow the line down
                line.start = earliest
                alone = self._joint_rates(*self._check_line(line, previous, q0, blend=False, speed=speed))
                if alone[0] <= 1.0 and alone[1] <= 1.0:
                    blend = False
                    continue
            velocity /= max(ratio_v, 1.0) * 1.02
            slowed *= max(ratio_a, 1.0) * 1.02
            log.info(
                "line %d slowed down for the joints' limits (velocity x%.3g, acceleration x%.3g)",
                target.sequence,
                ratio_v,
                ratio_a,
            )
        else:
            raise PointRejected(Reason.VELOCITY_LIMIT, "the joints cannot follow the line even slowed down")
        line.q_end = q[-1].copy()
        line.checked = (times, q)
        if target.blend_radius > 0.0 and length > 0.0:
            line.blend_from = self._blend_start(line, min(target.blend_radius, 0.5 * length))
        return line

    def commit(self, line: _Line) -> None:
        """Queue a line of :meth:`plan` (before the next :meth:`sample`)."""
        if self._lines:
            self._lines[-1].blend_from = None  # a next line is queued: nothing else can blend in
            self._stopped_at = None  # the next one starts where this one ends
        else:  # a new series of lines, from where the robot rests
            assert line.checked is not None
            self._base = (line.p0, line.r0, line.checked[1][0].copy())
            self._last = None
        self._lines.append(line)
        self._cache.clear()

    # -- running -----------------------------------------------------------------------------------

    def sample(self, t: float) -> State:
        """The joint setpoint at controller time ``t`` (increasing from call to call)."""
        self._retire(t)
        period = self.period
        last = self._last
        q_prev = last[1] if last is not None and abs(last[0] - (t - period)) < 1e-9 else None
        q_t = self._solution(t, last[1] if last is not None else None)
        q_next = self._solution(t + period, q_t)
        self._cache = {key: value for key, value in self._cache.items() if key >= t - 1e-9}
        self._last = (t, q_t)
        if not self._lines:  # finished: rest there
            return State.rest(np.array(q_t))
        b = q_prev if q_prev is not None else tuple(2.0 * x - y for x, y in zip(q_t, q_next, strict=True))
        k1, k2 = 0.5 / period, 1.0 / (period * period)
        velocity = [(y - z) * k1 for y, z in zip(q_next, b, strict=True)]
        acceleration = [(y - 2.0 * x + z) * k2 for x, y, z in zip(q_t, q_next, b, strict=True)]
        return State(np.array(q_t), np.array(velocity), np.array(acceleration))

    def stop(self, now: float) -> float:
        """Brake every running line along its path and drop the others; returns the braking time."""
        keep: list[_Line] = []
        longest = 0.0
        for line in self._lines:
            if line.start > now or line.profile is None or line.end <= now:
                if line.end <= now and line.start <= now:
                    keep.append(line)
                continue
            sample = line.profile.sample(now - line.start)
            s, v, a = (float(x[0]) for x in sample[:3])
            if s == 0.0 and v == 0.0 and a == 0.0:  # it has not set off: dropped like the later ones
                continue
            top, acceleration, jerk = line.rates
            brake = RuckigSegment.plan(
                ([0.0], [v], [a]),
                ([0.0], [0.0], [0.0]),
                [max(top, abs(v))],
                [max(acceleration, abs(a))],
                [jerk],
                velocity_interface=True,
            )
            line.profile, line.offset, line.start = brake, line.offset + s, now
            line.blend_from = None
            longest = max(longest, brake.duration)
            keep.append(line)
        self._lines = keep
        self._cache.clear()
        self._stopped_at = None
        if keep and self._base is not None:  # where the braking ends: a line queued now starts there
            position, rotation = (np.array(v) for v in self._tool_at(now + longest))
            seed = self._last[1] if self._last is not None else self._base[2]
            self._stopped_at = (position, rotation, self._solve_one(position, rotation, seed))
        return longest

    def abandon(self) -> None:
        """Drop every line at once (alarm, e-stop)."""
        self._lines = []
        self._stopped_at = None
        self._base = None
        self._cache.clear()
        self._last = None

    # -- internals ---------------------------------------------------------------------------------

    def _retire(self, t: float) -> None:
        """Fold the lines that have ended into the base pose (a finished line's contribution is
        constant: its whole displacement and turn)."""
        while self._lines and t >= self._lines[0].end:
            done = self._lines.pop(0)
            assert done.q_end is not None and self._base is not None
            u = done.fraction_at(t)
            if u >= 1.0 - 1e-12:
                q_end = done.q_end
                position, rotation = done.p1, done.r1
            else:  # braked short of its end: where the braking left it
                position, rotation = _point(done, u)
                q_end = self._solve_one(position, rotation, self._last[1] if self._last is not None else done.q_end)
            if self._lines:  # a blended successor: the base moves by this line's share
                self._base = (
                    self._base[0] + (position - done.p0),
                    _multiply(self._base[1], _multiply(_conjugate(done.r0), rotation)),
                    q_end,
                )
            else:
                self._base = (position, rotation, q_end)
                self._stopped_at = None
            self.lines_run += 1

    def _solve_one(self, position: Array, rotation: Array, seed: Sequence[float] | Array) -> Array:
        solver = self._solver
        assert solver is not None
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_rotation(rotation)
        pose[:3, 3] = position
        solution = solver.solve(pose, np.asarray(seed, dtype=float))
        if solution is None:
            raise RuntimeError("a braked line's pose has no solution (it was on the checked line)")
        return np.array(solution.q)

    def _solution(self, t: float, seed: tuple[float, ...] | None) -> tuple[float, ...]:
        key = round(t, 9)
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        solver = self._solver
        assert solver is not None and self._base is not None
        if seed is None:
            seed = tuple(self._base[2].tolist())
        if not self._lines:
            assert self._base is not None
            value = tuple(self._base[2].tolist())
        else:
            (px, py, pz), (w, x, y, z) = self._tool_at(t)
            rotation = (
                *(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
                *(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
                *(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
            )
            solution = solver.nearest(rotation, (px, py, pz), seed)
            if solution is None:
                raise RuntimeError(f"the line's pose at t = {t:.4f} s has no solution (it was checked)")
            value = solution.q
        self._cache[key] = value
        return value

    def _tool_at(self, t: float) -> tuple[tuple[float, float, float], Quaternion]:
        """The tool position and orientation quaternion of the running lines at time ``t``, in
        floats (what the control loop asks every period; :meth:`_poses` is the batch form)."""
        assert self._base is not None
        px, py, pz = self._base[0].tolist()
        rotation: Quaternion = tuple(self._base[1].tolist())
        for line in self._lines:
            if line.start > t:
                break  # the lines start in order; one not started yet adds nothing
            u = line.fraction_at(t)
            (dx, dy, dz), r0, r1 = line.floats
            px, py, pz = px + dx * u, py + dy * u, pz + dz * u
            rotation = _product(rotation, _product(_conjugated(r0), _slerp(r0, r1, u)))
        return (px, py, pz), rotation

    def _poses(self, times: Array, lines: Sequence[_Line] | None = None) -> NDArray[np.float64]:
        """Tool poses (m, 4, 4) of the queued lines (or ``lines``) at controller ``times``."""
        running = lines is None
        lines = self._lines if lines is None else lines
        first = lines[0]
        base_p, base_r = (self._base[0], self._base[1]) if running and self._base is not None else (first.p0, first.r0)
        m = times.size
        position = np.broadcast_to(base_p, (m, 3)).copy()
        rotation = np.broadcast_to(base_r, (m, 4)).copy()
        for line in lines:
            u = line.fraction(times)
            position += (line.p1 - line.p0)[None, :] * u[:, None]
            turn = _multiply(_conjugate(line.r0), slerp(line.r0, line.r1, u))
            rotation = _multiply(rotation, turn)
        out = np.zeros((m, 4, 4))
        out[:, :3, :3] = quaternion_to_rotation(rotation)
        out[:, :3, 3] = position
        out[:, 3, 3] = 1.0
        return out

    def _check_line(
        self, line: _Line, previous: _Line | None, q0: Array, *, blend: bool, speed: float
    ) -> tuple[Array, Array]:
        """Sample and solve the line (with the blended stretch of ``previous``); raise
        PointRejected for a line that cannot run, _Blend for a blend that cannot."""
        lim = self.line_limits
        lines: list[_Line] = [line]
        seed = q0
        if blend and previous is not None:
            assert previous.blend_from is not None and previous.checked is not None
            line.start = previous.blend_from
            lines = [previous, line]  # the blended stretch: both lines add up
            times_before, q_before = previous.checked  # the joints where the blend starts
            seed = np.array([np.interp(line.start, times_before, q_before[:, j]) for j in range(q_before.shape[1])])
        assert line.profile is not None
        duration = line.end - line.start
        peak = float(np.abs(line.profile.extremes(1)[1]).max()) if line.profile.duration > 0 else 0.0
        length = float(np.linalg.norm(line.p1 - line.p0))
        angle = quaternion_angle(line.r0, line.r1)
        # never more than a step (or an angle step) apart, and every interpolation period (what
        # the drives get) up to _SAMPLES in all: a very slow line is sampled more coarsely in time
        # (its joints are far from their limits), never more coarsely in space
        space = math.inf
        if peak > 0.0:
            moving = max(peak * length / line.span, 1e-12), max(peak * angle / line.span, 1e-12)
            space = min(lim.step / moving[0], lim.angle_step / moving[1])
        if blend and previous is not None:
            space = min(space, lim.step / max(previous.speed, 1e-9))
        count = max(min(math.ceil(duration / self.period), _SAMPLES), math.ceil(duration / space)) + 1
        times = line.start + np.linspace(0.0, duration, max(count, 2))
        poses = self._poses(times, lines)
        try:
            q = self._solve(poses, seed, line)
        except PointRejected:
            if blend:
                raise _Blend() from None
            raise
        if blend:
            positions = poses[:, :3, 3]
            step = float(times[1] - times[0])
            tcp = np.linalg.norm(np.diff(positions, axis=0), axis=1) / step
            if tcp.size and float(tcp.max()) > max(speed, previous.speed if previous else 0.0) * 1.001:
                raise _Blend()  # faster than either line
            tcp_acceleration = np.linalg.norm(np.diff(positions, 2, axis=0), axis=1) / step**2
            if tcp_acceleration.size and float(tcp_acceleration.max()) > lim.acceleration * 1.01:
                raise _Blend()  # the two lines' accelerations add up beyond the TCP's
        return q, times

    def _solve(self, poses: NDArray[np.float64], seed: Array, line: _Line) -> Array:
        solver = self._solver
        assert solver is not None
        batch = solver.solve_batch(poses, seed, limits=False)
        start = batch.q[0]
        gaps = np.abs(np.nan_to_num(start - seed[None, :], nan=np.inf))  # invalid slots are NaN
        distance = np.where(batch.valid[0], gaps.max(axis=1), np.inf)
        branch = int(np.argmin(distance))
        where = poses[:, :3, 3]
        if not math.isfinite(float(distance[branch])) or distance[branch] > 1e-3:
            raise PointRejected(Reason.UNREACHABLE, "the line's start is not the robot's pose (no continuing solution)")
        # out of reach: no solution at all over a stretch (a singularity loses them at a point)
        reachable = batch.valid.any(axis=1)
        if not reachable.all():
            edges = np.flatnonzero(np.diff(np.concatenate([[0], (~reachable).astype(np.int8), [0]])))
            for begin, end in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
                if float(np.linalg.norm(where[end - 1] - where[begin])) >= _OUT_OF_REACH:
                    raise PointRejected(
                        Reason.UNREACHABLE,
                        f"line {line.target.sequence} leaves the reachable space at {_at(where[begin])} "
                        f"({100.0 * begin / max(where.shape[0] - 1, 1):.0f}% along)",
                    )
        valid = batch.valid[:, branch]
        lost = int(np.argmin(valid)) if not valid.all() else valid.size
        # a singularity on the way to where the branch is lost is the reason it is lost
        self._check_singular(batch.q[:lost, branch, :], batch.flags[:lost, branch], seed, where, line)
        if lost < valid.size:
            i = lost
            along = f"({100.0 * i / max(valid.size - 1, 1):.0f}% along)"
            raise PointRejected(  # lost at a point: where branches meet, a singularity
                Reason.SINGULAR,
                f"line {line.target.sequence} passes a singularity at {_at(where[i])} {along}: "
                "the configuration cannot be continued",
            )
        q = self._unwrapped(batch.q[:, branch, :], seed)
        lower, upper = self.limits.lower, self.limits.upper
        beyond = (q < lower[None, :] - 1e-9) | (q > upper[None, :] + 1e-9)
        if beyond.any():
            i, j = (int(x) for x in np.argwhere(beyond)[0])
            raise PointRejected(
                Reason.POSITION_LIMIT,
                f"line {line.target.sequence} needs joint {j + 1} ({self.model.joints[j].name}) at "
                f"{q[i, j]:.4g}, beyond its limits {lower[j]:.4g}..{upper[j]:.4g}, at {_at(where[i])}",
                j,
            )
        if self.path_check is not None:
            self.path_check(where)
        return q

    @staticmethod
    def _unwrapped(q: Array, seed: Array) -> Array:
        """A branch's joint path made continuous (no 2 pi jumps), starting at the seed's turn."""
        out: Array = np.unwrap(q, axis=0)
        out += 2.0 * np.pi * np.round((seed - out[0]) / (2.0 * np.pi))[None, :]
        return out

    def _check_singular(self, q: Array, flags: NDArray[np.int64], seed: Array, where: Array, line: _Line) -> None:
        """Refuse (SINGULAR) a branch path that passes a singularity: a flagged or near-singular
        sample (the Jacobian's inverse condition), or a joint jumping between two samples."""
        if q.shape[0] < 2:
            return
        lim = self.line_limits
        q = self._unwrapped(q, seed)
        jumps = np.abs(np.diff(q, axis=0)).max(axis=1)
        measure = singularity_measure_batch(self.model, q)
        singular = np.flatnonzero((flags[1:] != 0) | (measure[1:] < lim.singularity) | (jumps > lim.max_joint_step))
        if not singular.size:
            return
        i = int(singular[0]) + 1
        what = f"{Singularity(int(flags[i])).name or 'a'} singularity".lower() if flags[i] else "a near-singular pose"
        raise PointRejected(
            Reason.SINGULAR,
            f"line {line.target.sequence} passes a singularity at {_at(where[i])} "
            f"({100.0 * i / max(where.shape[0] - 1, 1):.0f}% along: {what}, inverse condition {measure[i]:.2g})",
        )

    def _joint_rates(self, q: Array, times: Array) -> tuple[float, float]:
        """How far the joints exceed their velocity and acceleration limits (ratios; <= 1: within)."""
        if q.shape[0] < 3:
            return 0.0, 0.0
        # resample at the interpolation period, the rate the drives get setpoints at (a very slow
        # line, sampled more coarsely, at its samples' spacing)
        dt = max(self.period, (times[-1] - times[0]) / _SAMPLES)
        grid = np.arange(times[0], times[-1] + 0.5 * dt, dt)
        if grid.size < 3:
            return 0.0, 0.0
        qs = np.stack([np.interp(grid, times, q[:, j]) for j in range(q.shape[1])], axis=1)
        velocity = np.gradient(qs, dt, axis=0)
        acceleration = np.diff(qs, 2, axis=0) / (dt * dt)
        ratio_v = float((np.abs(velocity) / self.limits.max_velocity[None, :]).max())
        ratio_a = float((np.abs(acceleration) / self.limits.max_acceleration[None, :]).max())
        return ratio_v, ratio_a

    def _blend_start(self, line: _Line, radius: float) -> float | None:
        """The controller time from which the next line may start: where this line has
        ``radius`` of its path left, and not before it starts to slow down."""
        assert line.profile is not None
        length = float(np.linalg.norm(line.p1 - line.p0))
        if length <= 0.0 or line.profile.duration <= 0.0:
            return None
        times = np.linspace(0.0, line.profile.duration, 512)
        s = line.profile.sample(times)
        remaining = (line.span - s.position[:, 0]) * length / line.span
        velocity = s.velocity[:, 0]
        # where it starts to slow down: the last sample at its top speed (a next line starting
        # before that would add its speed to the full speed of this one)
        top = float(velocity.max()) if velocity.size else 0.0
        slowing = int(np.flatnonzero(velocity >= top * (1.0 - 1e-9))[-1]) if velocity.size else 0
        inside = np.flatnonzero((remaining <= radius) & (np.arange(times.size) >= slowing))
        if not inside.size:
            return None
        return line.start + float(times[inside[0]])

    def _flange(self, q: Array) -> tuple[Array, Array]:
        pose = self._pose(*q.tolist(), SCALAR_OPS)
        rotation = (pose.r00, pose.r01, pose.r02, pose.r10, pose.r11, pose.r12, pose.r20, pose.r21, pose.r22)
        return np.array([pose.px, pose.py, pose.pz], dtype=float), np.array(quaternion_of(rotation))


class _Blend(Exception):
    """The blended corner cannot run: plan the line to start from rest at the corner instead."""


def _corner_share(previous: _Line, line: _Line, acceleration: float) -> float:
    """The share of the TCP acceleration ``line`` may plan with when it blends in while
    ``previous`` slows down with its own: their sum stays within the TCP acceleration whatever the
    corner's angle (a reversal: they add up), and the sum of their speeds within the faster one's."""
    d1, d2 = previous.p1 - previous.p0, line.p1 - line.p0
    n1, n2 = float(np.linalg.norm(d1)), float(np.linalg.norm(d2))
    if n1 <= 0.0 or n2 <= 0.0:
        return _BLEND_SHARE
    a1 = min(previous.rates[1] / acceleration, 1.0)  # what slowing down the first line asks
    c = -float(np.dot(d1, d2)) / (n1 * n2)  # the cosine between its deceleration and our acceleration
    within = -a1 * c + math.sqrt(max(a1 * a1 * c * c - a1 * a1 + 1.0, 0.0))
    # and no faster a speed-up than its slow-down: near straight on, their speeds add up
    return max(0.05, min(within, a1))


def _profile(span: float, velocity: float, acceleration: float, jerk: float) -> RuckigSegment:
    try:
        return RuckigSegment.plan(([0.0], [0.0], [0.0]), ([span], [0.0], [0.0]), [velocity], [acceleration], [jerk])
    except PlanningError as exc:
        log.debug("no speed profile for a line of %g at %g: %s", span, velocity, exc)
        raise PointRejected(
            Reason.TIMING, f"no speed profile for a line of {span:.4g} m at {velocity:.4g} m/s (out of range)"
        ) from None


def _point(line: _Line, u: float) -> tuple[Array, Array]:
    return line.p0 + (line.p1 - line.p0) * u, slerp(line.r0, line.r1, u)


def _at(position: Array) -> str:
    return "({:.4f}, {:.4f}, {:.4f}) m".format(*(float(x) for x in position))


def _conjugated(q: Quaternion) -> Quaternion:
    return (q[0], -q[1], -q[2], -q[3])


def _product(a: Quaternion, b: Quaternion) -> Quaternion:
    """The Hamilton product of two quaternions (w first), in floats."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _slerp(a: Quaternion, b: Quaternion, u: float) -> Quaternion:
    """:func:`~..kinematics.slerp` of two unit quaternions at one fraction, in floats."""
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    if dot < 0.0:
        b, dot = (-b[0], -b[1], -b[2], -b[3]), -dot
    if dot > 1.0 - 1e-12:
        out = tuple(x + u * (y - x) for x, y in zip(a, b, strict=True))
    else:
        theta = math.acos(dot)
        k0, k1 = math.sin((1.0 - u) * theta) / math.sin(theta), math.sin(u * theta) / math.sin(theta)
        out = tuple(k0 * x + k1 * y for x, y in zip(a, b, strict=True))
    n = math.sqrt(sum(x * x for x in out))
    return (out[0] / n, out[1] / n, out[2] / n, out[3] / n)


def _conjugate(q: Array) -> Array:
    out: Array = q * np.array([1.0, -1.0, -1.0, -1.0])
    return out


def _multiply(a: Array, b: Array) -> Array:
    """Hamilton products of quaternions ``(..., 4)`` (w first), broadcast."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )
