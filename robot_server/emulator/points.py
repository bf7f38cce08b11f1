"""From trajectory-point messages to the controller's verbs.

The controller takes points in SI units and knows no sequence numbers (:mod:`..control.points`).
This module reads JOINT_TRAJ_PT, the points of a JOINT_TRAJ and JOINT_TRAJ_PT_FULL into
:class:`~..control.Point` values, and :func:`dispatch` says what a sequence number asks for
(docs/reference/protocol.md §4.1):

========  ======================================================================================
  -4      STOP_TRAJECTORY: stop (decelerate to rest, drop the queue)
  -1      START_TRAJECTORY_DOWNLOAD: open a download with this first point
  -3      END_TRAJECTORY: the download's last point; it runs now
  -2, 0   a streamed trajectory starts with this point (inside a download: a point of it)
  > 0     the next point (of the download, or of the streamed trajectory)
  other   refused (reserved)
========  ======================================================================================
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from simple_message.constants import SpecialSeq, ValidFields
from simple_message.messages import JointTrajPt, JointTrajPtFull, TrajPoint

from ..control import Controller, Point, PointRejected, Reason

__all__ = ["point_from_message", "dispatch", "STREAM_STARTS", "ExtraSlots"]

#: sequence numbers that start a streamed trajectory
STREAM_STARTS = (0, SpecialSeq.START_TRAJECTORY_STREAMING)

#: what to do with values in the slots beyond a group's joints: refuse the point (the reference
#: library's generic servers expect zeros there) or ignore them (MotoROS reads only its axes)
ExtraSlots = Literal["refuse", "ignore"]


def point_from_message(message: Any, dof: int, extra_slots: ExtraSlots = "refuse") -> tuple[int, Point]:
    """The sequence number and :class:`~..control.Point` of a JOINT_TRAJ_PT, a JOINT_TRAJ point or
    a JOINT_TRAJ_PT_FULL. A STOP (sequence -4) needs no valid data. A JOINT_TRAJ_PT_FULL must have
    a time (valid_fields TIME); its other fields count only where ``valid_fields`` says so."""
    sequence = int(message.sequence)
    if sequence == SpecialSeq.STOP_TRAJECTORY:
        return sequence, Point(None)
    if isinstance(message, JointTrajPt | TrajPoint):
        positions = _slots(message.joint_data, dof, "positions", extra_slots)
        return sequence, Point(positions, duration=float(message.duration), velocity_ratio=float(message.velocity))
    if isinstance(message, JointTrajPtFull):
        valid = ValidFields(message.valid_fields)
        if ValidFields.TIME not in valid:
            raise PointRejected(Reason.MISSING_FIELDS, "a JOINT_TRAJ_PT_FULL point needs a time (valid_fields TIME)")

        def field(flag: ValidFields, values: Any, what: str) -> NDArray[np.float64] | None:
            return _slots(values, dof, what, extra_slots) if flag in valid else None

        return sequence, Point(
            field(ValidFields.POSITION, message.positions, "positions"),
            field(ValidFields.VELOCITY, message.velocities, "velocities"),
            field(ValidFields.ACCELERATION, message.accelerations, "accelerations"),
            time=float(message.time),
        )
    raise TypeError(f"not a trajectory point message: {type(message).__name__}")


def _slots(values: Any, dof: int, what: str, extra_slots: ExtraSlots) -> NDArray[np.float64]:
    array = np.array(values, dtype=float)
    extra = array[dof:]
    if extra_slots == "refuse" and np.any(extra != 0.0):
        used = dof + int(np.flatnonzero(extra)[-1]) + 1
        raise PointRejected(Reason.JOINT_COUNT, f"{what} has values for {used} joints; this robot has {dof}")
    return array[:dof].copy()


def dispatch(controller: Controller, sequence: int, point: Point) -> None:
    """Act on one point as its sequence number says (module doc); raises PointRejected."""
    if sequence == SpecialSeq.STOP_TRAJECTORY:
        controller.stop()
    elif sequence == SpecialSeq.START_TRAJECTORY_DOWNLOAD:
        controller.start_download(point)
    elif sequence == SpecialSeq.END_TRAJECTORY:
        if not controller.downloading:
            raise PointRejected(Reason.SEQUENCE, "END_TRAJECTORY (-3) without a download started by -1")
        controller.finish_download(point)
    elif sequence in STREAM_STARTS and not controller.downloading:
        controller.start(point)
    elif sequence >= 0 or sequence in STREAM_STARTS:
        controller.add(point)
    else:
        raise PointRejected(Reason.SEQUENCE, f"sequence {sequence} is reserved")
