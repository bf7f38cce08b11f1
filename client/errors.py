"""The driver's errors, and how a MotoROS refusal reads (shared by :mod:`.driver` and :mod:`.sending`)."""

from __future__ import annotations

from simple_message.constants import MotoResult, moto_subcode_name

__all__ = ["DriverError", "ExecutionAborted", "moto_reason"]


class DriverError(Exception):
    """The driver cannot do what was asked (not connected, bad trajectory, robot not ready...)."""


class ExecutionAborted(DriverError):
    """A trajectory execution (or a series of straight lines) stopped before the goal;
    ``confirmed`` is the index of the last point (line) the controller acknowledged (-1: none)."""

    def __init__(self, message: str, confirmed: int, *, what: str = "point") -> None:
        super().__init__(f"{message} (last {what} confirmed by the controller: {confirmed})")
        self.confirmed = confirmed


class _NotSent(DriverError):
    """The motion connection was down before the request was written: the controller never saw it."""


class _InFlight(DriverError):
    """The motion connection dropped while a request awaited its reply: the controller may have it."""


def moto_reason(result: int, subcode: int) -> str:
    """A MOTO_MOTION_REPLY's result and subcode, named."""
    try:
        name = MotoResult(result).name
    except ValueError:
        name = f"result {result}"
    sub = moto_subcode_name(result, subcode)
    if sub is not None:
        return f"{name} ({sub}, subcode {subcode})"
    return f"{name} (subcode {subcode})" if subcode else name
