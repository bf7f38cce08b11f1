"""Why a controller will not move the robot, as its STATUS says: a FAILURE to a point carries no
reason, so the driver reads the reason from the STATUS that came with (or after) it. And who
moves it when this client does not: a controller takes motion from one client at a time (MotoROS,
ABB's and Fanuc's servers, the emulator) and closes a newcomer's motion connection while the robot
is busy, without a word on the wire; STATUS in_motion TRUE with that connection closed says so."""

from __future__ import annotations

from simple_message.constants import RobotMode, TriState
from simple_message.messages import Status

__all__ = ["moving_elsewhere", "status_faults", "status_why"]


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


def moving_elsewhere(status: Status | None, link_closed: bool) -> str | None:
    """Why this client cannot start a motion while ``status`` says the robot moves (in_motion
    TRUE) and nothing of this client's runs: another motion client's motion if the controller
    closed this client's motion connection (``link_closed``), else a motion still under way. None
    when STATUS does not say the robot moves."""
    if status is None or status.in_motion != TriState.TRUE:
        return None
    if link_closed:
        return (
            "another motion client is moving the robot: the controller closed this client's motion connection "
            "(it takes motion from one client at a time; STATUS says in_motion TRUE); try again once the robot is "
            "at rest, or stop it from that client"
        )
    return "the robot is still moving (STATUS says in_motion TRUE): a motion starts from rest; wait until it stops"
