"""The robot controller emulator: what a simple_message client meets on the robot's side.

* :mod:`.cell`: the motion groups' controllers, e-stop, drives, mode, alarms, STATUS and the fault
  injector (sans-I/O);
* :mod:`.generic` and :mod:`.motoros`: the two profiles (the generic nodes / ABB / the reference
  library, and Yaskawa MotoROS), as handlers on :class:`simple_message.endpoints.Server`;
* :mod:`.io_table`: MotoROS's IO addresses;
* :mod:`.server`: :class:`Emulator`, which runs it all (and ``robot-server``, :mod:`robot_server.cli`).
"""

from .cell import FAULT_COMMANDS, FaultError, RobotCell, apply_fault_command
from .generic import GenericMotion, GenericState
from .io_table import IoTable
from .motoros import MotorosIo, MotorosMotion, MotorosState
from .server import Emulator, EmulatorConfig, PeriodStats, Profile

__all__ = [
    "FAULT_COMMANDS",
    "FaultError",
    "RobotCell",
    "apply_fault_command",
    "GenericMotion",
    "GenericState",
    "IoTable",
    "MotorosIo",
    "MotorosMotion",
    "MotorosState",
    "Emulator",
    "EmulatorConfig",
    "PeriodStats",
    "Profile",
]
