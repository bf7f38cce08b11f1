"""A fleet of emulated controllers in one process: ``robot-server --fleet FILE.toml``.

:mod:`.config` reads the fleet file strictly, :mod:`.runner` runs its controllers on one event loop
with shared wake-ups (:mod:`robot_server.emulator.shared`), :mod:`.logs` names each line's
controller and bounds what each may write, :mod:`.command` is the command. See docs/fleet.md.
"""

from __future__ import annotations

from .config import CONTROLLER_KEYS, ControllerSpec, FleetError, FleetSpec, load_fleet, parse_fleet
from .runner import Fleet

__all__ = ["CONTROLLER_KEYS", "ControllerSpec", "Fleet", "FleetError", "FleetSpec", "load_fleet", "parse_fleet"]
