"""The robot controller emulator: what a simple_message client meets on the robot's side.

* :mod:`.cell`: the motion groups' controllers, e-stop, drives, mode, alarms, STATUS and the fault
  injector (sans-I/O);
* :mod:`.profiles`: what a profile is (a dialect, the ports served and their rules, a behaviour)
  and the registry ``robot-server --profile`` chooses from;
* :mod:`.generic` and :mod:`.motoros`: the two built-in profiles (the generic nodes / ABB / the
  reference library, and Yaskawa MotoROS), as handlers on :class:`simple_message.endpoints.Server`;
* :mod:`.io_table`: MotoROS's IO addresses;
* :mod:`.server`: :class:`Emulator`, which runs it all (and ``robot-server``, :mod:`robot_server.cli`).
"""

from .cell import FAULT_COMMANDS, FaultError, RobotCell, apply_fault_command
from .generic import GENERIC_PROFILE, GenericBehaviour, GenericMotion, GenericState
from .io_table import IoTable
from .motoros import MOTOROS_PROFILE, MotorosBehaviour, MotorosIo, MotorosMotion, MotorosState
from .profiles import (
    PROFILES,
    Behaviour,
    EmulatorProfile,
    PortRules,
    ProfileContext,
    profile_named,
    register_profile,
    unregister_profile,
)
from .server import Emulator, EmulatorConfig, PeriodStats

__all__ = [
    "FAULT_COMMANDS",
    "FaultError",
    "RobotCell",
    "apply_fault_command",
    "GENERIC_PROFILE",
    "MOTOROS_PROFILE",
    "PROFILES",
    "Behaviour",
    "EmulatorProfile",
    "GenericBehaviour",
    "MotorosBehaviour",
    "PortRules",
    "ProfileContext",
    "profile_named",
    "register_profile",
    "unregister_profile",
    "GenericMotion",
    "GenericState",
    "IoTable",
    "MotorosIo",
    "MotorosMotion",
    "MotorosState",
    "Emulator",
    "EmulatorConfig",
    "PeriodStats",
]
