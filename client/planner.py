"""Motion planning, the MoveIt stand-in: joint moves and Cartesian straight lines, time-parameterized.

A :class:`Planner` turns a task into a :class:`Motion`, a time-parameterized joint path that can be
sampled at any time and handed to the driver as a :class:`~.trajectory.Trajectory`, either
*sparse* (its knots, as a planner hands them over: the Cartesian waypoints of a line, a few points
of a joint move) or *dense* (every ``dt`` seconds).

* :meth:`Planner.joint_move`: a straight line in joint space.
* :meth:`Planner.linear_moves`: straight lines of the flange through a list of poses, stopping at
  each (position interpolated linearly, orientation by quaternion slerp). Every ``step`` metres the
  pose is solved with the model's closed-form inverse kinematics, taking the solution nearest the
  previous one; the path keeps one solution branch throughout and is refused
  (:class:`PlanningError`) if a step would jump (a joint moving more than ``max_joint_step``), if
  another branch comes as close (a singularity), or if a solution is flagged singular.

**Time parameterization.** Each straight piece (in joint or Cartesian space) is a path ``q(s)``
with ``s`` its length (radians of the fastest joint for a joint move, metres for a Cartesian line).
Along it a jerk-limited rest-to-rest profile ``s(t)`` is computed with ruckig, with the speed,
acceleration and jerk of ``s`` bounded so that every joint stays within ``scale`` times its
velocity, acceleration and jerk limits (using the path's first and second derivatives), and within
the optional Cartesian ``max_speed`` and ``max_acceleration``. The result is then sampled densely
and checked against the limits; if the curvature of ``q(s)`` made a joint exceed one, the profile is
slowed down and planned again.

All units are SI (m, rad, s); poses are 4x4 homogeneous matrices of the flange in the base frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from robot_server import Array, RobotModel
from robot_server.control import (
    CUBIC_PEAK_ACCELERATION,
    CUBIC_PEAK_VELOCITY,
    QUINTIC_PEAK_ACCELERATION,
    QUINTIC_PEAK_VELOCITY,
    PlanningError,
    RuckigSegment,
)
from robot_server.kinematics import (
    ClosedFormIK,
    Singularity,
    closed_form,
    fk_batch,
    quaternion_angle,
    quaternion_to_rotation,
    rotation_to_quaternion,
    slerp,
)

from .trajectory import Trajectory

__all__ = ["Planner", "Motion", "PlanningError", "pose", "rotation_to_quaternion", "quaternion_to_rotation", "slerp"]

#: how often a piece's limits are checked after planning (s)
_CHECK_DT = 0.002
#: a rest-to-rest segment's peak speed and acceleration over D/T and D/T^2 (the worse of the cubic's
#: and the quintic's: the quintic's 1.875 and the cubic's 6)
_REST_SPEED = max(CUBIC_PEAK_VELOCITY, QUINTIC_PEAK_VELOCITY)
_REST_ACCELERATION = max(CUBIC_PEAK_ACCELERATION, QUINTIC_PEAK_ACCELERATION)
#: how many times a piece is slowed down before giving up
_RETRIES = 12


#: what to try when a straight line cannot be followed (the planner's errors end with it)
_TRY_JUMP = (
    "try a smaller change of orientation, or move in two steps (the position with the orientation kept, "
    "then the orientation), or go by joints (move --joints)"
)
_TRY_SINGULAR = (
    "a straight line cannot start at or cross a singular configuration (a wrist singularity: joints 4 and 6 "
    "aligned, joint 5 near 0, as at the home pose); move the robot out of it by joints first, e.g. "
    "move --joints 0 0.3 -0.2 0 0.9 0"
)


# -- rotations -------------------------------------------------------------------------------------


def pose(position: ArrayLike, rotation: ArrayLike | None = None) -> Array:
    """A 4x4 pose from a position (m) and a 3x3 rotation (identity if None)."""
    t = np.eye(4)
    t[:3, 3] = np.asarray(position, dtype=float).reshape(3)
    if rotation is not None:
        t[:3, :3] = np.asarray(rotation, dtype=float).reshape(3, 3)
    return t


# -- planned motion --------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Piece:
    """A path ``q(s)`` sampled on a uniform grid of ``s`` (``h`` apart), with its timing profile."""

    s: Array  # (m,) grid, 0 .. length
    q: Array  # (m, dof)
    dq: Array  # dq/ds
    ddq: Array  # d2q/ds2
    knots: NDArray[np.int64]  # indices into the grid of the sparse waypoints
    profile: RuckigSegment | None  # None: zero length (a pause of no time)
    start: float  # time at which the piece starts

    @classmethod
    def still(cls, q: Array, start: float) -> _Piece:
        """A zero-length piece at configuration ``q`` (no time, one knot)."""
        zeros = np.zeros((1, q.size))
        return cls(np.zeros(1), q[None, :], zeros, zeros, np.zeros(1, int), None, start)

    @property
    def duration(self) -> float:
        return self.profile.duration if self.profile is not None else 0.0

    def at_s(self, s: Array) -> tuple[Array, Array, Array]:
        """q, dq/ds, d2q/ds2 at path parameters ``s`` (piecewise-linear between grid samples)."""
        if self.s.size == 1:
            n = s.size
            return np.repeat(self.q, n, 0), np.zeros((n, self.q.shape[1])), np.zeros((n, self.q.shape[1]))
        cols = range(self.q.shape[1])
        q = np.stack([np.interp(s, self.s, self.q[:, j]) for j in cols], axis=1)
        dq = np.stack([np.interp(s, self.s, self.dq[:, j]) for j in cols], axis=1)
        ddq = np.stack([np.interp(s, self.s, self.ddq[:, j]) for j in cols], axis=1)
        return q, dq, ddq

    def sample(self, t: Array) -> tuple[Array, Array, Array]:
        """Joint position, velocity and acceleration at times ``t`` (relative to the piece start)."""
        if self.profile is None:
            q, dq, _ = self.at_s(np.zeros(t.size))
            return q, dq, dq.copy()
        p = self.profile.sample(np.clip(t, 0.0, self.duration))
        s, sd, sdd = p.position[:, 0], p.velocity[:, 0], p.acceleration[:, 0]
        q, dq, ddq = self.at_s(np.clip(s, 0.0, self.s[-1]))
        v = dq * sd[:, None]
        a = ddq * (sd * sd)[:, None] + dq * sdd[:, None]
        return q, v, a

    def knot_times(self) -> Array:
        """Times (relative to the piece start) at which the profile passes the sparse knots."""
        if self.profile is None:
            return np.zeros(self.knots.size)
        grid = np.linspace(0.0, self.duration, max(2, math.ceil(self.duration / 0.0005) + 1))
        s = self.profile.sample(grid).position[:, 0]
        s = np.maximum.accumulate(s)  # monotone (rounding) so it can be inverted
        t: Array = np.interp(self.s[self.knots], s, grid)
        t[0], t[-1] = 0.0, self.duration
        return t


class Motion:
    """A planned, time-parameterized joint motion: pieces one after the other, at rest between."""

    def __init__(
        self, pieces: Sequence[_Piece], joint_names: Sequence[str], velocity: Array, acceleration: Array
    ) -> None:
        if not pieces:
            raise PlanningError("a motion needs at least one piece")
        self._pieces = list(pieces)
        self.joint_names = tuple(joint_names)
        #: the joint limits it was planned within
        self.velocity = velocity
        self.acceleration = acceleration

    @property
    def duration(self) -> float:
        last = self._pieces[-1]
        return last.start + last.duration

    @property
    def start(self) -> Array:
        return np.array(self._pieces[0].q[0], dtype=float)

    @property
    def end(self) -> Array:
        return np.array(self._pieces[-1].q[-1], dtype=float)

    def sample(self, t: ArrayLike) -> tuple[Array, Array, Array]:
        """Joint positions, velocities and accelerations ``(len(t), dof)`` at times ``t``."""
        times = np.atleast_1d(np.asarray(t, dtype=float))
        dof = self._pieces[0].q.shape[1]
        out = [np.empty((times.size, dof)) for _ in range(3)]
        starts = np.array([p.start for p in self._pieces])
        which = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(self._pieces) - 1)
        for i, piece in enumerate(self._pieces):
            mask = which == i
            if np.any(mask):
                for k, values in enumerate(piece.sample(times[mask] - piece.start)):
                    out[k][mask] = values
        return out[0], out[1], out[2]

    def sparse(self, rest_to_rest: bool = False) -> Trajectory:
        """The knots (Cartesian waypoints, or a joint move's few points) with times, velocities and
        accelerations: what a planner hands to a controller.

        With ``rest_to_rest`` the knots are retimed for a controller that joins points at rest
        (JOINT_TRAJ_PT, docs/reference/protocol.md §4.3): each segment lasts at least as long as a
        rest-to-rest cubic or quintic needs to stay within the planner's velocity and acceleration
        limits, and the points carry no velocities (the controller would not use them)."""
        times = [0.0]
        for piece in self._pieces:
            times.extend((piece.start + piece.knot_times()[1:]).tolist())
        trajectory = self._trajectory(np.array(times))
        if not rest_to_rest or len(trajectory) < 2:
            return trajectory
        distance = np.abs(np.diff(trajectory.positions, axis=0))
        needed = np.maximum(
            _REST_SPEED * distance / self.velocity, np.sqrt(_REST_ACCELERATION * distance / self.acceleration)
        ).max(axis=1)
        durations = np.maximum(np.diff(trajectory.times), needed)
        retimed = np.concatenate([[0.0], np.cumsum(durations)])
        return Trajectory(retimed, trajectory.positions, None, None, self.joint_names)

    def dense(self, dt: float = 0.01) -> Trajectory:
        """Samples every ``dt`` seconds (and at the end)."""
        if not dt > 0:
            raise PlanningError(f"the sampling period must be > 0, not {dt}")
        n = math.floor(self.duration / dt + 1e-9)
        times: Array = np.arange(n + 1, dtype=float) * dt
        if self.duration - times[-1] > 1e-9:
            times = np.append(times, self.duration)
        return self._trajectory(times)

    def _trajectory(self, times: Array) -> Trajectory:
        keep = np.concatenate([[True], np.diff(times) > 1e-9])  # a zero-length piece adds no point
        times = times[keep]
        q, v, a = self.sample(times)
        return Trajectory(times, q, v, a, self.joint_names)


# -- the planner -----------------------------------------------------------------------------------


class Planner:
    """Plans joint and Cartesian moves for one model (see the module doc).

    ``velocity_scale``, ``acceleration_scale`` and ``jerk_scale`` (0 < x <= 1) scale the model's
    joint limits; ``max_speed`` (m/s) and ``max_acceleration`` (m/s^2) bound the flange along
    Cartesian lines; ``step`` (m) is how finely lines are solved; ``waypoint_spacing`` (m) is the
    distance between the sparse waypoints of a line, ``joint_spacing`` (rad) that of a joint move.
    """

    def __init__(
        self,
        model: RobotModel,
        *,
        velocity_scale: float = 0.5,
        acceleration_scale: float = 0.5,
        jerk_scale: float = 0.5,
        max_speed: float = 0.25,
        max_acceleration: float = 1.0,
        step: float = 0.001,
        waypoint_spacing: float = 0.02,
        joint_spacing: float = 0.2,
        max_joint_step: float = 0.05,
    ) -> None:
        for name, value in (
            ("velocity_scale", velocity_scale),
            ("acceleration_scale", acceleration_scale),
            ("jerk_scale", jerk_scale),
        ):
            if not 0.0 < value <= 1.0:
                raise PlanningError(f"{name} must be in (0, 1], not {value}")
        for name, value in (
            ("max_speed", max_speed),
            ("max_acceleration", max_acceleration),
            ("step", step),
            ("waypoint_spacing", waypoint_spacing),
            ("joint_spacing", joint_spacing),
            ("max_joint_step", max_joint_step),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise PlanningError(f"{name} must be > 0, not {value}")
        self.model = model
        self.velocity = model.max_velocity * velocity_scale
        self.acceleration = model.max_acceleration * acceleration_scale
        self.jerk = model.max_jerk * jerk_scale
        self.max_speed = max_speed
        self.max_acceleration = max_acceleration
        self.step = step
        self.waypoint_spacing = waypoint_spacing
        self.joint_spacing = joint_spacing
        self.max_joint_step = max_joint_step
        self._ik: ClosedFormIK | None = closed_form(model)

    # -- tasks -------------------------------------------------------------------------------------

    def joint_move(self, start: ArrayLike, goal: ArrayLike) -> Motion:
        """A straight line in joint space from ``start`` to ``goal``, at rest at both ends."""
        q0, q1 = self._configuration(start, "start"), self._configuration(goal, "goal")
        return self._motion([self._joint_piece(q0, q1, 0.0)])

    def linear_moves(self, start: ArrayLike, poses: Sequence[ArrayLike]) -> Motion:
        """Straight flange lines from the pose at ``start`` through each of ``poses`` in turn,
        stopping at each one, on the IK branch of ``start``."""
        if self._ik is None:
            raise PlanningError(
                f"{self.model.name} has no closed-form inverse kinematics (not a 6R arm with a spherical wrist)"
            )
        q = self._configuration(start, "start")
        current = fk_batch(self.model, q[None, :])[0]
        pieces: list[_Piece] = []
        time = 0.0
        for i, target in enumerate(poses):
            goal = np.asarray(target, dtype=float)
            if goal.shape != (4, 4) or not np.all(np.isfinite(goal)):
                raise PlanningError(f"pose {i} is not a finite 4x4 matrix")
            if not self._ik.solve_all(goal):
                where = "the target pose" if len(poses) == 1 else f"pose {i + 1} of {len(poses)}"
                raise PlanningError(
                    f"{where} (flange at {np.round(goal[:3, 3], 4).tolist()} m) is out of reach within the joint "
                    "limits: try a point nearer the robot's base, or another orientation"
                )
            piece = self._line_piece(current, goal, q, time, i)
            pieces.append(piece)
            time += piece.duration
            q, current = piece.q[-1], goal
        if not pieces:
            raise PlanningError("linear_moves needs at least one pose")
        return self._motion(pieces)

    def then(self, first: Motion, second: Motion) -> Motion:
        """``second`` after ``first`` (it must start where ``first`` ends)."""
        gap = float(np.max(np.abs(second.start - first.end)))
        if gap > 1e-9:
            raise PlanningError(f"the second motion starts {gap:.3g} rad away from where the first ends")
        shifted = [_shift(p, first.duration) for p in second._pieces]
        return self._motion([*first._pieces, *shifted])

    # -- pieces ------------------------------------------------------------------------------------

    def _motion(self, pieces: Sequence[_Piece]) -> Motion:
        return Motion(pieces, self.model.joint_names, self.velocity, self.acceleration)

    def _configuration(self, q: ArrayLike, what: str) -> Array:
        values = np.asarray(q, dtype=float).reshape(-1)
        if values.size != self.model.dof or not np.all(np.isfinite(values)):
            raise PlanningError(f"the {what} configuration must be {self.model.dof} finite values, not {q!r}")
        if not self.model.within_limits(values, 1e-9):
            model = self.model
            j = int(np.argmax(np.maximum(model.lower - values, values - model.upper)))
            side, bound = ("lower", model.lower[j]) if values[j] < model.lower[j] else ("upper", model.upper[j])
            raise PlanningError(
                f"the {what} configuration is outside the joint limits: joint {j + 1} ({model.joint_names[j]}) at "
                f"{values[j]:.4g} is beyond its {side} limit {bound:.4g}"
            )
        return values

    def _joint_piece(self, q0: Array, q1: Array, start: float) -> _Piece:
        span = float(np.max(np.abs(q1 - q0)))
        if span == 0.0:
            return _Piece.still(q0, start)
        m = max(2, math.ceil(span / self.step) + 1)
        s = np.linspace(0.0, span, m)
        q = q0 + np.outer(s / span, q1 - q0)
        knots = _knots(m, span, self.joint_spacing)
        dq = np.repeat(((q1 - q0) / span)[None, :], m, 0)
        return self._timed(s, q, dq, np.zeros_like(q), knots, start, cartesian=False)

    def _line_piece(self, t0: Array, t1: Array, seed: Array, start: float, index: int) -> _Piece:
        assert self._ik is not None
        p0, p1 = t0[:3, 3], t1[:3, 3]
        r0, r1 = rotation_to_quaternion(t0), rotation_to_quaternion(t1)
        # the path parameter is the flange's travel; a rotation counts as travel of a point 0.1 m away
        length = max(float(np.linalg.norm(p1 - p0)), 0.1 * quaternion_angle(r0, r1))
        if length < 1e-9:
            return _Piece.still(seed, start)
        m = max(2, math.ceil(length / self.step) + 1)
        u = np.linspace(0.0, 1.0, m)
        poses = np.empty((m, 4, 4))
        poses[:] = np.eye(4)
        poses[:, :3, :3] = quaternion_to_rotation(slerp(r0, r1, u))
        poses[:, :3, 3] = p0 + np.outer(u, p1 - p0)
        q = self._track_branch(poses, seed, index)
        s = u * length
        h = s[1] - s[0]
        dq = np.gradient(q, h, axis=0)
        ddq = np.gradient(dq, h, axis=0)
        knots = _knots(m, length, self.waypoint_spacing)
        return self._timed(s, q, dq, ddq, knots, start, cartesian=True)

    def _track_branch(self, poses: Array, seed: Array, index: int) -> Array:
        """IK along ``poses`` keeping the branch of ``seed`` (refusing jumps and singularities)."""
        assert self._ik is not None
        solutions, valid, flags = self._ik.solve_batch(poses, seed)
        lower, upper = self.model.lower, self.model.upper
        out = np.empty((poses.shape[0], seed.size))
        previous = seed
        for k in range(poses.shape[0]):
            ok = valid[k]
            if not np.any(ok):
                raise PlanningError(
                    f"line {index}: the pose {k} steps along it is out of reach within the joint limits"
                )
            candidates = solutions[k][ok]
            # the same configuration modulo 2 pi, as near the previous one as possible
            candidates = previous + (candidates - previous + math.pi) % (2.0 * math.pi) - math.pi
            distance = np.max(np.abs(candidates - previous), axis=1)
            order = np.argsort(distance)
            best = candidates[order[0]]
            jump = float(distance[order[0]])
            if jump > self.max_joint_step:
                raise PlanningError(
                    f"line {index}: a joint would jump {jump:.3g} rad between two poses {self.step * 1000:g} mm apart "
                    f"(at step {k}; limit {self.max_joint_step} rad): {_TRY_JUMP}"
                )
            if order.size > 1 and distance[order[1]] <= self.max_joint_step:
                raise PlanningError(
                    f"line {index}: passes too near a singularity at step {k} (two IK branches meet): {_TRY_SINGULAR}"
                )
            flag = Singularity(int(flags[k][ok][order[0]]))
            if flag != Singularity.NONE:
                where = "starts at" if k == 0 else f"passes through, at step {k},"
                raise PlanningError(f"line {index}: {where} a {flag.name} singularity: {_TRY_SINGULAR}")
            if np.any(best < lower - 1e-9) or np.any(best > upper + 1e-9):
                raise PlanningError(f"line {index}: leaves the joint limits at step {k}")
            out[k] = previous = best
        return out

    def _timed(  # noqa: PLR0917 - the parts of one piece
        self, s: Array, q: Array, dq: Array, ddq: Array, knots: NDArray[np.int64], start: float, cartesian: bool
    ) -> _Piece:
        """Plan the jerk-limited profile ``s(t)`` keeping every joint within the scaled limits."""
        slope = np.max(np.abs(dq), axis=0)  # per joint, max |dq/ds|
        bend = np.max(np.abs(ddq), axis=0)
        tiny = 1e-12
        speed = float(np.min(self.velocity / np.maximum(slope, tiny)))
        if cartesian:
            speed = min(speed, self.max_speed)
        # leave half of each joint's acceleration for the path's curvature at full speed
        while True:
            room = self.acceleration - bend * speed * speed
            if np.all(room > 0.5 * self.acceleration):
                break
            speed *= 0.8
        acceleration = float(np.min(room / np.maximum(slope, tiny)))
        if cartesian:
            acceleration = min(acceleration, self.max_acceleration)
        jerk = float(np.min(self.jerk / np.maximum(slope, tiny)))
        length = float(s[-1])
        piece: _Piece | None = None
        for _ in range(_RETRIES):
            try:
                profile = RuckigSegment.plan(
                    ([0.0], [0.0], [0.0]), ([length], [0.0], [0.0]), [speed], [acceleration], [jerk]
                )
            except PlanningError as exc:
                raise PlanningError(f"no timing profile: {exc}") from None
            piece = _Piece(s, q, dq, ddq, knots, profile, start)
            worst = self._excess(piece)
            if worst <= 1.0 + 1e-9:
                return piece
            factor = 0.95 / worst
            speed *= factor
            acceleration *= factor
            jerk *= factor
        raise PlanningError("cannot keep this path within the joint limits (it passes too near a singularity)")

    def _excess(self, piece: _Piece) -> float:
        """The worst ratio of joint velocity or acceleration to its (scaled) limit."""
        t = np.linspace(0.0, piece.duration, max(3, math.ceil(piece.duration / _CHECK_DT) + 1))
        _, v, a = piece.sample(t)
        ratio_v = np.max(np.abs(v) / self.velocity)
        ratio_a = np.max(np.abs(a) / self.acceleration)
        return float(max(ratio_v, ratio_a))


def _knots(m: int, length: float, spacing: float) -> NDArray[np.int64]:
    """Indices into an ``m``-sample grid of a path ``length`` long: waypoints at most ``spacing`` apart."""
    count = max(2, math.ceil(length / spacing) + 1)
    return np.linspace(0, m - 1, count).round().astype(np.int64)


def _shift(piece: _Piece, offset: float) -> _Piece:
    return _Piece(piece.s, piece.q, piece.dq, piece.ddq, piece.knots, piece.profile, piece.start + offset)
