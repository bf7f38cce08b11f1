"""The controller layer of the paper: the robot controller emulator.

Robot models and kinematics (:mod:`.model`, :mod:`.loader`, :mod:`.kinematics`), interpolation,
motor models and the control loop (:mod:`.control`), and the emulator process (:mod:`.emulator`).
It may import :mod:`simple_message`, numpy and ruckig, never :mod:`client`.

The names below are imported from their modules on first use: the robot library (the model, its
loader, URDF, the workspace, the kinematics) loads no emulator, control loop or web view, and
``tests/test_imports.py`` keeps it so.

To embed an emulator in a program (what ``robot-client demo`` does)::

    from robot_server import Emulator, EmulatorConfig

    async with Emulator(EmulatorConfig(motion_port=0, state_port=0, simulated=True)) as emu:
        [record] = emu.record(seconds=60.0)     # every servo tick of group 0 from now on
        ...                                     # drive it at emu.ports["motion"], ["state"]
        await emu.settle(timeout=10.0)          # until the robot is at rest
        emu.stop_recording()
    record.to_csv("run.csv", emu.cell.groups[0].model.joint_names)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from simple_message._lazy import LazyExports

if TYPE_CHECKING:
    from .arrays import Array
    from .control import Recorder
    from .emulator import Emulator, EmulatorConfig
    from .loader import load_model, shipped_models
    from .model import ModelError, RobotModel

__all__ = [
    "Array",
    "Emulator",
    "EmulatorConfig",
    "ModelError",
    "Recorder",
    "RobotModel",
    "load_model",
    "shipped_models",
]

#: where each public name lives; its module is imported when the name is first used
_EXPORTS = LazyExports(
    __name__,
    globals(),
    {
        ".arrays": ("Array",),
        ".control": ("Recorder",),
        ".emulator": ("Emulator", "EmulatorConfig"),
        ".loader": ("load_model", "shipped_models"),
        ".model": ("ModelError", "RobotModel"),
    },
)


def __getattr__(name: str) -> object:
    return _EXPORTS.attribute(name)


def __dir__() -> list[str]:
    return _EXPORTS.names()
