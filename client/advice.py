"""What the client adds to a refused Cartesian move: where it fails and what to do instead.

A controller's refusal of a straight line is a result code (CARTESIAN_LINE's ``LineResult``:
``SINGULAR``, ``UNREACHABLE``...); where on the line and how close to the singularity only its log
says. The client runs the same check on its own model (:class:`robot_server.control.cartesian.
LineMotion`, the emulator's line planner, with its default limits), which says the same where the
model is the controller's (``move --pose`` checks that first, :mod:`.identity`). It also tries what
could work instead: the same line planned on the PC (:class:`.planner.Planner`, joint points
streamed: ``move --pose`` without ``--linear``) and a joint move to the target's inverse
kinematics (``move --joints``), and names the ones that would run.

Which of these applies depends on the controller's reason (:func:`after_refusal`): only a line the
joints cannot run (``SINGULAR``, ``UNREACHABLE``, ``JOINT_LIMIT``) may run another way. A
``TCP_SPEED`` refusal asks for a lower ``--tcp-speed``; a ``WORKSPACE`` refusal is the controller's
workspace supervision (its cell's zones, which the client does not know): another target or path
is the way, not the same path by joints, which the same zones would refuse.
"""

from __future__ import annotations

import numpy as np

from robot_server import Array
from robot_server.control import ControllerConfig
from robot_server.control.cartesian import LineMotion, LineTarget
from robot_server.control.points import Limits, PointRejected
from robot_server.kinematics import IKFailed, ik, rotation_to_quaternion
from robot_server.model import RobotModel
from simple_message.constants import LineResult

from .planner import Planner, PlanningError

__all__ = ["PATH_REFUSALS", "after_refusal", "line_check", "instead"]

#: the controller's refusals of a straight line that the joints cannot run: the same target may be
#: reached another way (the line planned on the PC, a joint move)
PATH_REFUSALS = frozenset({LineResult.SINGULAR, LineResult.UNREACHABLE, LineResult.JOINT_LIMIT})


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


def after_refusal(
    result: int, model: RobotModel, here: Array, target: Array, planner: Planner, *, speed: float
) -> tuple[str | None, list[str]]:
    """What to add to the controller's refusal (a CARTESIAN_LINE reply's ``result``, a
    :class:`LineResult`) of the straight line from joints ``here`` to the 4x4 pose ``target`` at
    ``speed`` (m/s): where the client's check places the fault (or None) and the next steps.

    * ``SINGULAR``, ``UNREACHABLE``, ``JOINT_LIMIT`` (:data:`PATH_REFUSALS`): :func:`line_check`
      and :func:`instead`, the ways that would run;
    * ``TCP_SPEED``: a lower ``--tcp-speed`` (naming the AUTO limit of ``model``'s
      ``[supervision]`` when it has one: the controller's own unless its cell sets another);
    * ``WORKSPACE``: a target or a path outside the controller's zones (the client does not know
      them, so it does not claim that any other way would run);
    * any other reason (the robot not ready, a joint trajectory under way...): nothing."""
    if result in PATH_REFUSALS:
        return line_check(model, here, target, speed), instead(model, here, target, planner, linear=True)
    if result == LineResult.TCP_SPEED:
        limit = model.supervision.auto_speed
        if limit is not None and limit < speed:
            return None, [
                f"a lower --tcp-speed than {speed:g} m/s: at most {limit:g} m/s, the AUTO limit of --model "
                f"{model.name}'s [supervision] (the controller's, unless its cell file sets another)"
            ]
        return None, [f"a lower --tcp-speed than {speed:g} m/s (the controller's TCP speed limit is below it)"]
    if result == LineResult.WORKSPACE:
        return None, [
            "a target, or a path through other poses, outside the cell's zones (the controller's workspace "
            "supervision refused the line: it enters a forbidden zone, leaves the allowed zone or goes below the "
            "floor; the client does not know the controller's zones, so the same target by joints may be refused too)"
        ]
    return None, []
