"""Which robot the controller drives, as far as it says: a Cartesian command is planned with the
client's model (``robot-client --model``), and a model that is not the controller's robot puts
the tool somewhere else than asked while every joint reaches its goal. So before a Cartesian
command the client compares its model with what the controller says about its own:

* **TOOL_POSE** (this project's extension, docs/protocol.md; the emulator sends it on request,
  asked for and awaited up to the driver's watchdog period, not from a controller family whose
  server takes no unknown message, ABB's, Fanuc's, Staubli's): the controller's actual TCP pose
  beside its joint state. The model's forward kinematics at
  those joints must put the TCP within :data:`POSITION_TOLERANCE` (1 mm) and
  :data:`ORIENTATION_TOLERANCE` of it.
* **GET_DH_PARAMETERS** (MotoROS, asked first, ``Ros_MotionServer_GetDhParameters``, motoman_driver
  MotoPlus/MotionServer.c:2157-2184: one ``DH_LINK {theta, d, a, alpha}`` per axis of each group,
  ParameterTypes.h:116-126): the controller's D-H table, compared with the model's (lengths
  within 1 mm, angles within 1 mrad, modulo a turn: 2 pi apart is the same angle). MotoPlus does
  not document the table's units: a table whose lengths are the model's in millimetres agrees too.
  The table must have as many axes as the model has joints: a reply narrower than the model, or
  one with axes beyond the model's joints (an axis is a row not all zero: a 7-axis arm against a
  6-joint model), is a mismatch naming both counts.
* Otherwise the controller says nothing about its model (ABB, Fanuc, Staubli, the C++ reference
  server, a MotoROS without GET_DH_PARAMETERS): the result rests on ``--model``, and
  :class:`ModelCheck` says so.

A disagreement is :class:`ModelMismatch`, one line naming ``--model``, by how much they differ
and (``skip``: ``robot-client move``'s ``--no-model-check``) how to skip the check; nothing is
sent to move the robot.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from robot_server.kinematics import fk, quaternion_angle, rotation_to_quaternion
from robot_server.model import RobotModel
from simple_message.errors import SimpleMessageError
from simple_message.messages import DhLink, GetDhParameters, GetDhParametersReply, ToolPose

from .errors import DriverError

if TYPE_CHECKING:
    from .driver import RobotDriver

__all__ = ["ModelCheck", "ModelMismatch", "POSITION_TOLERANCE", "ORIENTATION_TOLERANCE", "check_model"]

#: how far (m) the model may put the TCP from the controller's TOOL_POSE at the same joints
POSITION_TOLERANCE = 0.001
#: how far (rad) the model's TCP orientation may be from the controller's
ORIENTATION_TOLERANCE = 0.002
#: D-H angles agree within this (rad)
_DH_ANGLE = 0.001


class ModelMismatch(DriverError):
    """The client's model is not the robot the controller drives (see the module doc)."""


@dataclass(frozen=True)
class ModelCheck:
    """What the controller said about its model: ``agrees`` True (``how`` says what was compared)
    or None (it says nothing: ``how`` says the result rests on the client's model). A
    disagreement raises :class:`ModelMismatch` instead."""

    agrees: bool | None
    how: str


async def check_model(
    driver: RobotDriver, model: RobotModel, *, option: str = "--model", skip: str | None = None
) -> ModelCheck:
    """Compare ``model`` with what the controller of ``driver`` says of its own (module doc);
    ``option`` is how the caller's user gives the model, ``skip`` how they skip this check (e.g.
    ``--no-model-check``; None: they cannot), both named in a :class:`ModelMismatch`."""
    if driver.dialect.motion_control:
        table = await _dh_table(driver)
        if table is not None:
            return _against_dh(model, table, option, skip)
    if driver.dialect.unknown_types:  # a TOPIC it may not know: ABB's, Fanuc's, Staubli's servers take none
        pose = await driver.subscribe_tool_pose(rounds=None)
        state = driver.joint_state
        if pose is not None and state is not None and pose.tool == 0:
            return _against_tool_pose(model, state.positions[: model.dof], pose, option, skip)
    return ModelCheck(
        None,
        f"the controller says nothing about its robot model (no TOOL_POSE, no D-H table): the Cartesian result rests "
        f"on {option} {model.name} being the controller's robot",
    )


def _next_step(option: str, skip: str | None, which: str = "") -> str:
    """The end of a :class:`ModelMismatch`: what to give instead (``which``: a hint where to find
    it), and how to skip the check."""
    text = f"give {option} the model the controller runs{which}"
    return text + (f", or {skip} to skip this check" if skip else "")


def _against_tool_pose(model: RobotModel, q: np.ndarray, pose: ToolPose, option: str, skip: str | None) -> ModelCheck:
    mine = fk(model, q)
    theirs = np.array([pose.x, pose.y, pose.z])
    apart = float(np.linalg.norm(mine[:3, 3] - theirs))
    # the pose and the joints are of the same state round; a moving robot moves a little between
    allowed = POSITION_TOLERANCE + abs(pose.speed) * 0.05
    quaternion = np.array([pose.qw, pose.qx, pose.qy, pose.qz])
    turned = quaternion_angle(_quaternion(mine), quaternion / max(float(np.linalg.norm(quaternion)), 1e-12))
    if apart > allowed or turned > ORIENTATION_TOLERANCE + abs(pose.speed) * 0.05:
        here = ", ".join(f"{v:.4f}" for v in mine[:3, 3])
        there = ", ".join(f"{v:.4f}" for v in theirs)
        raise ModelMismatch(
            f"{option} {model.name} is not the controller's robot: at the robot's joints it puts the tool at ({here}) "
            f"m, the controller reports ({there}) m, {apart * 1000:.1f} mm and {math.degrees(turned):.1f} deg apart; "
            f"{_next_step(option, skip, ' (the one robot-server was started with)')}"
        )
    return ModelCheck(True, f"{option} {model.name} agrees with the controller's TOOL_POSE ({apart * 1000:.3f} mm)")


def _quaternion(pose: np.ndarray) -> np.ndarray:
    return np.asarray(rotation_to_quaternion(pose[:3, :3]), dtype=float)


async def _dh_table(driver: RobotDriver) -> GetDhParametersReply | None:
    """The controller's GET_DH_PARAMETERS reply, or None (refused, unknown, no reply)."""
    with contextlib.suppress(DriverError, SimpleMessageError):
        reply = await driver._request(GetDhParameters())
        if isinstance(reply, GetDhParametersReply):
            return reply
    return None


def _against_dh(model: RobotModel, reply: GetDhParametersReply, option: str, skip: str | None) -> ModelCheck:
    rows = [joint.dh for joint in model.joints]
    theirs = reply.groups[0]
    if not any(v != 0.0 for link in theirs for v in (link.theta, link.d, link.a, link.alpha)):
        return ModelCheck(None, f"the controller's D-H table is empty: the Cartesian result rests on {option}")
    if any(row is None for row in rows):
        return ModelCheck(
            None,
            f"the controller sends its D-H table, but {option} {model.name} has none to compare: the Cartesian "
            f"result rests on {option} {model.name} being the controller's robot",
        )
    known = [row for row in rows if row is not None]
    who = f"{option} {model.name}"
    joints = _plural(len(known), "joint")
    used = _axes(theirs)  # the table's axes: up to its last row that is not all zero
    if reply.axes < len(known):
        differ = f"the controller's D-H table has {_plural(reply.axes, 'axis', 'axes')} per group, {who} has {joints}"
    elif used > len(known):
        k = len(known) + _axes(theirs[len(known) :]) - 1  # the last axis beyond the model's joints
        extra = theirs[k]
        differ = (
            f"the controller's D-H table has {_plural(used, 'axis', 'axes')} in group 0, {who} has {joints} (axis "
            f"{k + 1}: theta {extra.theta:.4g}, d {extra.d:.4g}, a {extra.a:.4g}, alpha {extra.alpha:.4g})"
        )
    else:
        worst = _dh_difference(known, theirs, 1.0, "m", who)
        if not worst or not _dh_difference(known, theirs, 1000.0, "mm", who):  # MotoPlus does not say its units
            return ModelCheck(True, f"{who} agrees with the controller's D-H table")
        # (a table whose last rows are all zero may still have those axes: PUMA 560's last row is)
        differ = f"its D-H table differs from the controller's ({worst})"
    raise ModelMismatch(f"{who} is not the controller's robot: {differ}; {_next_step(option, skip)}")


def _plural(count: int, one: str, many: str | None = None) -> str:
    return f"{count} {one if count == 1 else many or one + 's'}"


def _axes(links: tuple[DhLink, ...]) -> int:
    """How many axes a D-H group describes: up to its last row that is not all zero (MotoROS pads
    a group to 8 axes with zeros)."""
    used = 0
    for k, link in enumerate(links):
        if any(v != 0.0 for v in (link.theta, link.d, link.a, link.alpha)):
            used = k + 1
    return used


def _angle_apart(mine: float, other: float) -> float:
    """How far apart two angles are (rad), modulo a turn: in [0, pi]."""
    return abs(math.remainder(mine - other, 2 * math.pi))


def _dh_difference(
    rows: list[tuple[float, float, float, float]], theirs: tuple[DhLink, ...], scale: float, unit: str, who: str
) -> str:
    """The largest difference of the two D-H tables beyond the tolerances (lengths times
    ``scale``, in ``unit``; angles modulo a turn), in words, or "" when they agree. ``theirs``
    has a row for each of ``rows`` (at least)."""
    worst, text = 1.0, ""
    for j, row in enumerate(rows):
        link = theirs[j]
        for name, mine, other, angle in (
            ("theta", row[0], link.theta, True),
            ("d", row[1], link.d, False),
            ("a", row[2], link.a, False),
            ("alpha", row[3], link.alpha, True),
        ):
            if not math.isfinite(other):
                off = math.inf  # NaN would compare as agreeing
            elif angle:
                off = _angle_apart(mine, other) / _DH_ANGLE
            else:
                off = abs(mine * scale - other) / (POSITION_TOLERANCE * scale)
            if off > worst:
                there = f"{other:.4g} rad" if angle else f"{other:.4g} {unit}"
                here = f"{mine:.4g} rad" if angle else f"{mine * scale:.4g} {unit}"
                worst, text = off, f"joint {j + 1} {name} is {there} there, {here} in {who}"
    return text
