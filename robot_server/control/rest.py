"""A controller at rest steps for (almost) nothing: an interpolation period that changed nothing is replayed.

A robot standing still still runs its servo loops: every servo tick the drives compute their loops
on a command that does not change. Once they have settled exactly (the last rounding residues of
the loops gone: about a second after a motion), a whole interpolation period leaves the drives'
state (position, velocity, the velocity loop's integral) as it found it, and the controller's
state around them (alarm, mode, supervision, points, the queue's setpoint) too. The controller is
deterministic, so every following period with the same inputs gives the same ticks: :class:`RestWatch`
keeps the ticks of such a period and hands them out again, with their new times, for as long as
nothing changes. It costs a comparison of a few short lists per interpolation period instead of
the servo loops of every tick: what lets a fleet of controllers at rest (:mod:`robot_server.fleet`)
cost almost nothing.

It is exact, not an approximation: a replayed period is bit for bit what stepping it would have
given (``tests/test_rs_rest.py`` compares them), and anything that could change the outcome (a
point, a stop, an alarm, the drives, the mode, a reset of the loops) ends the replay at the next
interpolation instant, where the controller samples its motion anyway.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .controller import Tick
    from .points import State
    from .servo import ServoDrives

__all__ = ["RestWatch"]

#: what the drives' state is: the lists :meth:`~.servo.ServoDrives.step` reads and writes
_DriveState = tuple[list[float], list[float], list[float]]


def _drives(servo: ServoDrives) -> _DriveState:
    return list(servo.position), list(servo.velocity), list(servo.integral)


def _same_drives(servo: ServoDrives, state: _DriveState) -> bool:
    return servo.position == state[0] and servo.velocity == state[1] and servo.integral == state[2]


class RestWatch:
    """Watches one controller's interpolation periods for one that changed nothing, then replays it.

    The controller calls :meth:`begin` at the start of each period it steps (after sampling its
    motion), :meth:`add` with each tick, :meth:`end` after the last one, and, at the next
    interpolation instant, :meth:`replay` to learn whether the period may be replayed instead of
    stepped."""

    __slots__ = ("_drives", "_key", "_resting", "_setpoint", "_ticks", "periods")

    def __init__(self) -> None:
        self._key: Hashable = None
        self._setpoint: State | None = None
        #: the drives' state when the watched period began (None: no period watched)
        self._drives: _DriveState | None = None
        self._ticks: list[Tick] = []
        #: the ticks of the last period, once it changed nothing (None: step the next one)
        self._resting: list[Tick] | None = None
        #: interpolation periods replayed so far (a diagnostic)
        self.periods = 0

    def begin(self, key: Hashable, setpoint: State, constant: bool, servo: ServoDrives) -> None:
        """A period is about to be stepped: ``key`` is the controller's state around the drives
        (alarm, mode, supervision...), ``setpoint`` the motion's sample it runs towards, and
        ``constant`` whether that sample equals the last one (a standing command)."""
        self._resting = None
        self._ticks = []
        if constant:
            self._key, self._setpoint, self._drives = key, setpoint, _drives(servo)
        else:
            self._drives = None

    @property
    def watching(self) -> bool:
        """A period is being watched (its ticks are needed)."""
        return self._drives is not None

    def add(self, tick: Tick) -> None:
        if self._drives is not None:
            self._ticks.append(tick)

    def end(self, key: Hashable, servo: ServoDrives) -> None:
        """The period's last tick is done: it may be replayed if it left everything as it found it."""
        if self._drives is not None and key == self._key and _same_drives(servo, self._drives):
            self._resting = self._ticks
        else:
            self._drives = None
        self._ticks = []

    def replay(self, key: Hashable, setpoint: State, servo: ServoDrives) -> list[Tick] | None:
        """At an interpolation instant: the ticks of the resting period if the next one would be
        the same (same key, the motion's very same setpoint, the drives untouched), else None."""
        resting, drives = self._resting, self._drives
        if resting is None or drives is None:
            return None
        if key != self._key or setpoint is not self._setpoint or not _same_drives(servo, drives):
            self._resting = self._drives = None
            return None
        self.periods += 1
        return resting

    def forget(self) -> None:
        """Step the next period (the drives were changed outside a period: power, brakes)."""
        self._resting = self._drives = None
        self._ticks = []
