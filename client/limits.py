"""What the driver checks of a trajectory against the robot model before and while it runs: the
joints' position and speed limits (before anything is sent) and the distance from the planned
joint path (while the robot follows it)."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from robot_server import Array, RobotModel

from .errors import DriverError
from .trajectory import Trajectory

__all__ = [
    "check_limits",
    "within_speeds",
    "within_cubics",
    "central_velocities",
    "cubic_accelerations",
    "path_deviation",
    "MEASURED_OVERSHOOT",
]

log = logging.getLogger("client.driver")


def path_deviation(trajectory: Trajectory, position: Array) -> float:
    """Distance (max over joints) from ``position`` to the piecewise-linear joint path."""
    q = trajectory.positions
    if len(trajectory) == 1:
        return float(np.max(np.abs(position - q[0])))
    a, b = q[:-1], q[1:]
    d = b - a
    length = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", position - a, d) / np.where(length > 0, length, 1.0), 0.0, 1.0)
    nearest = a + s[:, None] * d
    return float(np.min(np.max(np.abs(nearest - position), axis=1)))


def check_limits(trajectory: Trajectory, model: RobotModel, *, speeds: bool = True) -> None:
    """Refuse, before anything is sent, a trajectory the robot cannot follow: a position beyond a
    joint's limits, or (``speeds``) a segment whose mean speed is beyond a joint's maximum speed
    (no controller can run it in its time; one that moves at its own speed takes longer). The
    message names the point, the joint, the value and the limit."""
    names = model.joint_names
    units = ["m" if joint.type.value == "prismatic" else "rad" for joint in model.joints]
    lower, upper, vmax = model.lower, model.upper, model.max_velocity
    q = trajectory.positions
    for bound, beyond, side in ((lower, q < lower - 1e-9, "lower"), (upper, q > upper + 1e-9, "upper")):
        if beyond.any():
            k, j = (int(i) for i in np.argwhere(beyond)[0])
            raise DriverError(
                f"point {k}: joint {j + 1} ({names[j]}) at {q[k, j]:.4g} is beyond its {side} limit "
                f"{bound[j]:.4g} {units[j]}"
            )
    dt = np.diff(trajectory.times)
    if dt.size and speeds:
        speed = np.abs(np.diff(q, axis=0)) / np.maximum(dt, 1e-12)[:, None]
        over = speed > vmax * (1 + 1e-6)
        if over.any():
            k, j = (int(i) for i in np.argwhere(over)[0])
            raise DriverError(
                f"segment {k}->{k + 1}: joint {j + 1} ({names[j]}) would move at {speed[k, j]:.4g} {units[j]}/s on "
                f"average, beyond its maximum {vmax[j]:.4g} {units[j]}/s (give the segment at least "
                f"{abs(q[k + 1, j] - q[k, j]) / vmax[j]:.3g} s)"
            )


#: how far beyond a joint's maximum speed a waypoint's velocity, or a segment's mean speed, is taken
#: for a measurement's overshoot (a recorded state: the drive's actual speed passes the commanded one
#: by a little as it settles) and brought back to the maximum instead of refused
MEASURED_OVERSHOOT = 0.02


def within_speeds(trajectory: Trajectory, model: RobotModel, *, velocities: bool = True) -> Trajectory:
    """``trajectory`` with its speeds within the joints' maximum where they pass it by no more than
    :data:`MEASURED_OVERSHOOT`: a recording carries the speeds the joints were measured at, and a
    joint that cruised at its maximum is measured a fraction of a percent above it (3.1433 rad/s for
    a 3.1416 rad/s joint), and so is its mean speed over the segments its velocities time
    (:func:`.trajectory.recording`). A waypoint velocity beyond the maximum is sent at it (MotoROS
    refuses a point whose velocity is beyond it: INVALID, DATA_SPEED, motoman_driver
    MotoPlus/MotionServer.c:1313); a segment whose mean speed is beyond it takes the time the maximum
    needs (microseconds: 0.05 % of a 24 ms segment is 12 us), and the points after it move later by
    as much. One beyond by more is no measurement's: a velocity is refused here, naming the point and
    the joint, a segment by :func:`check_limits`. ``velocities``: the waypoint velocities are sent
    (MotoROS); the other controllers get none, and the points' velocities are left as they are."""
    vmax = model.max_velocity
    # a hair inside: the wire's float32 rounds the maximum itself up by up to 6e-8 of it
    cap = vmax * (1.0 - 1e-6)
    v = trajectory.velocities
    if v is not None and velocities:
        over = np.abs(v) > vmax * (1.0 + MEASURED_OVERSHOOT)
        if over.any():
            k, j = (int(i) for i in np.argwhere(over)[0])
            unit = "m/s" if model.joints[j].type.value == "prismatic" else "rad/s"
            raise DriverError(
                f"point {k}: joint {j + 1} ({model.joint_names[j]}) has the velocity {v[k, j]:.4g} {unit}, beyond "
                f"its maximum {vmax[j]:.4g} {unit}"
            )
        over_cap = np.abs(v) > cap
        if np.any(over_cap):
            log.info(
                "%d waypoint velocities a hair over a joint's maximum speed (a measurement's overshoot, at most "
                "%.2f %%) are sent at it",
                int(np.count_nonzero(over_cap)),
                float(np.max(np.abs(v) / vmax) - 1.0) * 100,
            )
            trajectory = dataclasses.replace(trajectory, velocities=np.clip(v, -cap, cap))
    dt = np.diff(trajectory.times)
    if dt.size == 0:
        return trajectory
    need = np.max(np.abs(np.diff(trajectory.positions, axis=0)) / cap, axis=1)
    stretch = (need > dt) & (need <= dt * (1.0 + MEASURED_OVERSHOOT))
    if not stretch.any():
        return trajectory
    longer = float(np.sum(np.where(stretch, need - dt, 0.0)))
    log.info(
        "%d segments a hair faster than a joint's maximum speed (a measurement's overshoot) take the time it needs: "
        "%.3f ms longer in all",
        int(np.count_nonzero(stretch)),
        longer * 1000,
    )
    dt = np.where(stretch, need, dt)
    times = np.concatenate([trajectory.times[:1], trajectory.times[0] + np.cumsum(dt)])
    return dataclasses.replace(trajectory, times=times)


def central_velocities(trajectory: Trajectory) -> Array:
    """Waypoint velocities by central differences, zero at both ends: what the MotoROS sender
    gives points that come without velocities."""
    q, t = trajectory.positions, trajectory.times
    v = np.zeros_like(q)
    if len(trajectory) > 2:
        v[1:-1] = (q[2:] - q[:-2]) / (t[2:] - t[:-2])[:, None]
    return v


def cubic_accelerations(times: Array, positions: Array, velocities: Array) -> Array:
    """The largest |acceleration| of each cubic through consecutive points' positions and velocities
    (``(segments, dof)``): at one of its ends, as a cubic's acceleration is linear. MotoROS joins its
    points by these cubics (motoman_driver MotoPlus/MotionServer.c:1414-1468) and runs them as given."""
    h = np.diff(times)[:, None]
    d = np.diff(positions, axis=0)
    v0, v1 = velocities[:-1], velocities[1:]
    start = (6.0 * d / h - 4.0 * v0 - 2.0 * v1) / h
    end = (-6.0 * d / h + 2.0 * v0 + 4.0 * v1) / h
    peaks: Array = np.maximum(np.abs(start), np.abs(end))
    return peaks


#: :func:`within_cubics` aims this far inside the acceleration limit (the millisecond grid the
#: points are then moved onto changes the cubics by a little)
_CUBIC_MARGIN = 0.99


def within_cubics(trajectory: Trajectory, model: RobotModel) -> Trajectory:
    """The client's own plan for a controller that joins points by cubics through their positions
    and velocities and runs them as given (MotoROS): slowed down uniformly (times x k, velocities /
    k, so the cubics' accelerations / k^2) until every cubic is within the joints' acceleration
    limit. A plan at the limits (``--speed 1``) is exactly there, and a cubic through its points,
    which cannot follow its phases, passes it: a rest-to-rest joint move sent as two points would
    ask 1.5x the limit. Without velocities the points' velocities are the central differences the
    MotoROS sender uses. Not for a recording: its time is what a replay keeps."""
    if len(trajectory) < 2:
        return trajectory
    t, q = trajectory.times, trajectory.positions
    v = trajectory.velocities if trajectory.velocities is not None else central_velocities(trajectory)
    ratio = cubic_accelerations(t, q, v) / model.max_acceleration
    worst = float(ratio.max())
    if worst <= _CUBIC_MARGIN:
        return trajectory
    k = math.sqrt(worst / _CUBIC_MARGIN)
    k_, j = (int(i) for i in np.unravel_index(int(np.argmax(ratio)), ratio.shape))
    log.info(
        "slowed down x%.3f: the cubics MotoROS runs through the points would accelerate joint %d up to %.3g x its "
        "limit (segment %d->%d)",
        k,
        j + 1,
        worst,
        k_,
        k_ + 1,
    )
    velocities = None if trajectory.velocities is None else trajectory.velocities / k
    accelerations = None if trajectory.accelerations is None else trajectory.accelerations / (k * k)
    return dataclasses.replace(
        trajectory, times=t[0] + (t - t[0]) * k, velocities=velocities, accelerations=accelerations
    )
