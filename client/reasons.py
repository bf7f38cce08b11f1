"""Why a controller will not move the robot, as its STATUS says: a FAILURE to a point carries no
reason, so the driver reads the reason from the STATUS that came with (or after) it."""

from __future__ import annotations

from simple_message.constants import RobotMode, TriState
from simple_message.messages import Status

__all__ = ["status_faults", "status_why"]


def status_faults(status: Status | None) -> list[str]:
    """The reasons ``status`` gives for the robot not to move (none: nothing wrong, or no STATUS)."""
    if status is None:
        return []
    reasons = []
    if status.e_stopped == TriState.TRUE:
        reasons.append("the controller is e-stopped")
    if status.drives_powered == TriState.FALSE:
        reasons.append("the drives are off")
    if status.in_error == TriState.TRUE:
        reasons.append(f"it is in error (code {status.error_code})")
    if status.mode == RobotMode.MANUAL:
        reasons.append("it is in MANUAL mode (motion from a PC needs AUTO)")
    if not reasons and status.motion_possible == TriState.FALSE:
        reasons.append("STATUS says motion is not possible")
    return reasons


def status_why(status: Status | None) -> str:
    """Why the controller may refuse motion, as ``status`` says (it gives no reason with a FAILURE):
    e-stop, drives, an alarm, the mode; or that STATUS shows nothing wrong."""
    if status is None:
        return "no STATUS received to say why"
    reasons = status_faults(status)
    if reasons:
        return "; ".join(reasons)
    return "STATUS shows nothing wrong, so the point itself was refused (beyond a limit, or not where the robot is)"
