"""A fleet's log: every line names its controller, and each controller has its own budget under the fleet's.

Many controllers write to one stderr. A line says which one it is about: a context variable holds
the controller's name in every task the controller's start made (its servers' connections, its
state topics, its profile's tasks), in its periods of the shared control loop, and while a command
on stdin is applied to it; :class:`ControllerField` puts it into each record (``%(controller)s``:
``r2: ``, or nothing for the fleet's own lines).

A lone ``robot-server`` bounds what its peers can make it write (:data:`~..emulator.server.PEER_LOGGERS`,
a burst then lines per second, and a lane of its own for safety lines). In a fleet each controller
keeps that budget of its own, so that one controller's flood does not hide another's lines, and
the fleet as a whole has a ceiling over them (:class:`FleetCeiling`), so that two hundred controllers
under attack do not flood the terminal either.
"""

from __future__ import annotations

import contextvars
import logging

from simple_message.lograte import BudgetFilter, LogBudget

from ..emulator.server import PEER_LOG_BURST, PEER_LOG_RATE, PEER_LOGGERS, SAFETY_LOG_BURST, SAFETY_LOG_RATE

__all__ = ["CONTROLLER", "ControllerField", "FleetCeiling", "FORMAT"]

#: the name of the controller the running code is about ("" : the fleet itself)
CONTROLLER: contextvars.ContextVar[str] = contextvars.ContextVar("robot_server_controller", default="")
#: the fleet's log line: the controller's name before the logger's
FORMAT = "%(asctime)s %(levelname)s %(controller)s%(name)s: %(message)s"
#: the fleet's ceiling over every controller's budget: lines per second after a burst
FLEET_LOG_BURST = 4 * PEER_LOG_BURST
FLEET_LOG_RATE = 4 * PEER_LOG_RATE
FLEET_SAFETY_BURST = 4 * SAFETY_LOG_BURST
FLEET_SAFETY_RATE = 4 * SAFETY_LOG_RATE


class ControllerField(logging.Filter):
    """Sets ``record.controller`` to ``"NAME: "`` (or ``""``) for a handler's format."""

    def filter(self, record: logging.LogRecord) -> bool:
        name = CONTROLLER.get()
        record.controller = f"{name}: " if name else ""
        return True


def _budgets(who: str, burst: int, rate: float, safety_burst: int, safety_rate: float) -> BudgetFilter:
    return BudgetFilter(
        LogBudget(who, rate=rate, burst=burst),
        {"safety": LogBudget(f"{who} safety", rate=safety_rate, burst=safety_burst)},
    )


class FleetCeiling(logging.Filter):
    """Each controller's budget over the peer loggers (as a lone ``robot-server``'s), then the
    fleet's over them all. :meth:`install` on the loggers, :meth:`remove` to take it off (writing
    what each budget held back)."""

    def __init__(self, names: list[str]) -> None:
        super().__init__()
        self._own = {
            name: _budgets(f"controller {name}", PEER_LOG_BURST, PEER_LOG_RATE, SAFETY_LOG_BURST, SAFETY_LOG_RATE)
            for name in names
        }
        self._fleet = _budgets("fleet", FLEET_LOG_BURST, FLEET_LOG_RATE, FLEET_SAFETY_BURST, FLEET_SAFETY_RATE)
        self._loggers: list[logging.Logger] = []

    def filter(self, record: logging.LogRecord) -> bool:
        own = self._own.get(CONTROLLER.get())
        if own is not None and not own.filter(record):
            return False
        return self._fleet.filter(record)

    def install(self, *extra: str) -> FleetCeiling:
        for name in (*PEER_LOGGERS, *extra):
            logger = logging.getLogger(name)
            if self not in logger.filters:
                logger.addFilter(self)
                self._loggers.append(logger)
        return self

    def remove(self) -> None:
        for budget in self._own.values():
            budget.remove()
        self._fleet.remove()
        for logger in self._loggers:
            logger.removeFilter(self)
        self._loggers.clear()
