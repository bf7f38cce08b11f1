"""Trajectories as MoveIt plans them and as ROS clients stream them, and what to measure of the
motion a controller makes of them (shared by the blend and streaming tests).

The plan is the shape of ``../shared/ros/goal.py``: a trapezoidal path parameter (a quarter of the
time accelerating, a quarter decelerating: the acceleration steps, as MoveIt's time-optimal
parameterisation makes it) along a straight joint-space move plus a sine bump on three joints
(joint 2 reverses before the end).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from client.demo import distance_to_path
from robot_server import Array
from robot_server.control import Controller, Point, PointRejected, Reason, Recorder
from robot_server.kinematics import fk_batch
from robot_server.model import RobotModel

DELTA = np.array([1.2, 0.4, -0.5, 0.6, -0.4, 0.8]) * 0.5
BUMP = np.array([0.0, 0.15, 0.10, 0.0, 0.10, 0.0]) * 0.5
#: joints whose planned motion is monotone (joint 2 turns back before the end)
MONOTONE_JOINTS = [0, 2, 3, 4, 5]


@dataclass(frozen=True)
class Plan:
    """``count`` points over ``duration`` seconds from ``start`` (time, position, velocity, acceleration)."""

    duration: float
    count: int
    start: Array
    time: Array
    position: Array
    velocity: Array
    acceleration: Array

    @classmethod
    def make(cls, duration: float, count: int, start: Array | None = None) -> Plan:
        t = np.linspace(0.0, duration, count)
        q, v, a = shape(duration, t)
        q0 = np.zeros(6) if start is None else start
        return cls(duration, count, q0, t, q0 + q, v, a)

    def dense(self, step: float = 1e-3) -> Array:
        """Positions every ``step`` seconds of plan time."""
        t = np.arange(0.0, self.duration + step / 2, step)
        return self.start + shape(self.duration, t)[0]

    @property
    def peak_acceleration(self) -> float:
        return float(np.abs(shape(self.duration, np.linspace(0.0, self.duration, 20001))[2]).max())

    @classmethod
    def with_peak_acceleration(cls, peak: float, count: int) -> Plan:
        """The plan whose peak joint acceleration is ``peak`` (it scales as 1 / duration^2)."""
        reference = cls.make(1.0, count).peak_acceleration
        return cls.make(float(np.sqrt(reference / peak)), count)


def shape(duration: float, t: Array) -> tuple[Array, Array, Array]:
    """Position (from 0), velocity and acceleration of the plan at times ``t``."""
    ta = 0.25 * duration
    vs = 1.0 / (duration - ta)
    a = vs / ta
    cruise = 0.5 * a * ta**2 + vs * (t - ta)
    s = np.where(t < ta, 0.5 * a * t**2, np.where(t <= duration - ta, cruise, 1 - 0.5 * a * (duration - t) ** 2))
    sd = np.where(t < ta, a * t, np.where(t <= duration - ta, vs, a * (duration - t)))
    sdd = np.where(t < ta, a, np.where(t <= duration - ta, 0.0, -a))
    s, sd, sdd = s[:, None], sd[:, None], sdd[:, None]
    q = s * DELTA + np.sin(np.pi * s) * BUMP
    dq = DELTA + np.pi * np.cos(np.pi * s) * BUMP
    ddq = -(np.pi**2) * np.sin(np.pi * s) * BUMP
    return q, dq * sd, ddq * sd**2 + dq * sdd


def ros_points(plan: Plan, max_velocity: Array) -> list[Point]:
    """JOINT_TRAJ_PT points as industrial_robot_client fills them: the velocity ratio of the
    critical joint, the duration since the previous point, 10 s for the first one."""
    points = []
    for i in range(plan.count):
        ratio = float(np.clip(np.max(np.abs(plan.velocity[i]) / max_velocity), 0.0, 1.0))
        duration = 10.0 if i == 0 else float(plan.time[i] - plan.time[i - 1])
        points.append(Point(plan.position[i].copy(), duration=duration, velocity_ratio=ratio))
    return points


def full_points(plan: Plan, accelerations: bool = True) -> list[Point]:
    """JOINT_TRAJ_PT_FULL points as motoman_driver fills them: time, positions, velocities,
    accelerations."""
    p, v, a, t = plan.position, plan.velocity, plan.acceleration, plan.time
    return [Point(p[i], v[i], a[i] if accelerations else None, time=float(t[i])) for i in range(plan.count)]


def stream(controller: Controller, points: list[Point], cadence: float, extra: float = 3.0) -> Recorder:
    """Hand ``points`` to ``controller`` one per ``cadence`` seconds of controller time (0: as
    many as it takes at once), waiting while its queue is full, and run until it has settled
    (``extra`` seconds at most after the motion queued with the last point). Every point must be
    accepted."""
    sub = controller.servo_ticks_per_interpolation
    recorder = Recorder(controller.dof, capacity=round(120.0 / controller.config.servo_period))
    sent, next_time, deadline = 0, 0.0, None
    while True:
        while sent < len(points) and controller.time >= next_time - 1e-12:
            try:
                (controller.start if sent == 0 else controller.add)(points[sent])
            except PointRejected as exc:
                assert exc.reason is Reason.QUEUE_FULL, exc
                break
            sent += 1
            next_time = controller.time + cadence
            if cadence > 0.0:
                break
        for _ in range(sub):
            recorder.add(controller.step())
        if sent == len(points):
            # the time the queued motion still takes (slowed down or not), and some to settle
            deadline = deadline if deadline is not None else controller.time + controller.remaining + extra
            if not controller.in_motion or controller.time > deadline:
                return recorder
        assert controller.time < 600.0, "the stream never finished"


@dataclass(frozen=True)
class Motion:
    """What a record shows of one streamed trajectory."""

    start: float  # s from the first point's arrival to the first commanded motion
    executed: float  # s from the first commanded motion to the last change of the command
    stops: int  # times the command stood still and then moved on
    deviation_command: float  # m, largest distance of the commanded flange from the planned path
    deviation_actual: float  # m, the same for the actual flange
    peak_acceleration: float  # rad/s^2, of the command (exact samples at the interpolation instants)
    peak_jerk: float  # rad/s^3, differences of those accelerations
    final_error: float  # rad, the command's last position against the last point


def measure(record: Recorder, model: RobotModel, plan: Plan, ticks_per_interpolation: int) -> Motion:
    t = record.time()
    command, actual = record.get("command_position"), record.get("actual_position")
    step = np.max(np.abs(np.diff(command, axis=0)), axis=1)
    moving = np.flatnonzero(step > 1e-9)  # tick i + 1 differs from tick i
    first, last = int(moving[0]) + 1, int(moving[-1]) + 1  # the first and the last tick that moved
    arrived = int(np.flatnonzero(record.points() >= 1)[0])
    # stops: the command stands still (every joint slower than 1e-4 rad/s) and then moves on by
    # more than a micro-radian; the final approach to rest is not a stop
    speed = np.max(np.abs(record.get("command_velocity")), axis=1)
    still = speed < 1e-4
    stops = 0
    i = first + int(np.argmax(~still[first:last]))  # from the first time it moves at speed
    while i < last:
        if still[i]:
            j = i
            while j < last and still[j]:
                j += 1
            if j < last and np.max(np.abs(command[last] - command[j])) > 1e-6:
                stops += 1
            i = j
        else:
            i += 1
    path = fk_batch(model, plan.dense())[:, :3, 3]
    window = slice(first, None)
    deviation_command = float(distance_to_path(fk_batch(model, command[window])[:, :3, 3], path).max())
    deviation_actual = float(distance_to_path(fk_batch(model, actual[window])[:, :3, 3], path).max())
    instants = slice(ticks_per_interpolation - 1, None, ticks_per_interpolation)
    acceleration = record.get("command_acceleration")[instants]
    period = float(t[ticks_per_interpolation] - t[0])
    return Motion(
        start=float(t[first] - t[arrived]),
        executed=float(t[last] - t[first]),
        stops=stops,
        deviation_command=deviation_command,
        deviation_actual=deviation_actual,
        peak_acceleration=float(np.abs(acceleration).max()),
        peak_jerk=float(np.abs(np.diff(acceleration, axis=0)).max() / period),
        final_error=float(np.abs(command[-1] - plan.position[-1]).max()),
    )
