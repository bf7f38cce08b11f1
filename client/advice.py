"""What the client adds to a refused Cartesian move: where it fails and what to do instead.

A controller's refusal of a straight line is a result code (CARTESIAN_LINE's ``LineResult``:
``SINGULAR``, ``UNREACHABLE``...); where on the line and how close to the singularity only its log
says. The client runs the same check on its own model (:class:`robot_server.control.cartesian.
LineMotion`, the emulator's line planner, with its default limits), which says the same where the
model is the controller's (``move --pose`` checks that first, :mod:`.identity`). It also tries what
could work instead: the same line planned on the PC (:class:`.planner.Planner`, joint points
streamed: ``move --pose`` without ``--linear``) and a joint move to the target's inverse
kinematics (``move --joints``), and names the ones that would run.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from robot_server.control import ControllerConfig
from robot_server.control.cartesian import LineMotion, LineTarget
from robot_server.control.points import Limits, PointRejected
from robot_server.kinematics import IKFailed, ik, rotation_to_quaternion
from robot_server.model import RobotModel

from .planner import Planner, PlanningError

__all__ = ["line_check", "instead"]

Array = NDArray[np.float64]


def line_check(model: RobotModel, here: Array, target: Array, speed: float) -> str | None:
    """Why the controller's line check refuses the straight line from joints ``here`` to the 4x4
    pose ``target`` at ``speed`` (m/s), run on ``model``: the controller's words (where on the line,
    how close to the singularity), or None when the line passes (or the model has no closed-form
    inverse kinematics, which the check needs)."""
    defaults = ControllerConfig()  # the emulator's own line limits and interpolation period
    motion = LineMotion(model, Limits.from_model(model), defaults.line, defaults.interpolation_period)
    if not motion.available:
        return None
    w, x, y, z = (float(v) for v in rotation_to_quaternion(target[:3, :3]))
    position = target[:3, 3]
    line = LineTarget((float(position[0]), float(position[1]), float(position[2])), (w, x, y, z), speed)
    try:
        motion.plan(line, now=0.0, rest=np.asarray(here, dtype=float), speed_cap=None)
    except PointRejected as exc:
        return str(exc).split(": ", 1)[-1]
    return None


def instead(model: RobotModel, here: Array, target: Array, planner: Planner, *, linear: bool) -> list[str]:
    """What would reach ``target`` from ``here`` where the straight line did not: the line planned
    on the PC (when ``linear``, the controller's line was refused) and a joint move, as commands."""
    ways = []
    if linear:
        try:
            planner.linear_moves(here, [target])
        except PlanningError:
            pass
        else:
            ways.append("without --linear (the same straight line planned on the PC) it runs")
    try:
        solutions = ik(model, target, seed=here)
    except IKFailed:
        return ways
    q = np.asarray(solutions[0].q, dtype=float)
    if np.all(q >= model.lower - 1e-9) and np.all(q <= model.upper + 1e-9):
        joints = " ".join(f"{round(float(v), 4) + 0.0:.4f}" for v in q)  # + 0.0: no -0.0000
        ways.append(f"by joints it reaches the pose: robot-client move --joints {joints}")
    return ways
