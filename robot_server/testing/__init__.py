"""Testing robot software against emulated controllers: the pytest plugin and what it gives.

Installing the package installs the plugin (the ``pytest11`` entry point ``robot_server``, module
:mod:`.plugin`): a test asks for the ``robot_controller`` fixture, with no conftest and no import::

    def test_ping(robot_controller):
        ctrl = robot_controller(profile="motoros")      # free loopback ports, its own thread
        ...                                             # connect to ctrl.host, ctrl.motion_port
        ctrl.wait_idle(timeout=30)

In an async test, ``ctrl = await robot_controller(...)`` runs the controller in the test's own
event loop. ``speedup=10`` runs its clock ten times faster, ``speedup="step"`` lets the test move
it (``ctrl.advance(20.0)``), ``process=True`` starts a ``robot-server`` process for clients in
other languages. Each controller records its traffic; a failed test's report names the pcapng file
and the controller's last state. The motion assertions (:mod:`.assertions`: ``assert_reached``,
``assert_within_joints``, ``assert_within_box``, ``assert_within_limits``, ``assert_stopped_within``)
read a handle's record and model. docs/testing.md is the guide.

The names below are imported from their modules on first use: the plugin, which pytest loads in
every run, costs nothing until a test asks for a controller.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from simple_message._lazy import LazyExports

if TYPE_CHECKING:
    from .assertions import (
        LimitReport,
        MotionAssertionError,
        MotionSource,
        Recorded,
        Side,
        assert_reached,
        assert_stopped_within,
        assert_within_box,
        assert_within_joints,
        assert_within_limits,
    )
    from .core import ControllerError, ControllerTimeout
    from .handle import AsyncRobotController, ControllerFactory, RobotController
    from .settings import SettingsError

__all__ = [
    "AsyncRobotController",
    "ControllerError",
    "ControllerFactory",
    "ControllerTimeout",
    "LimitReport",
    "MotionAssertionError",
    "MotionSource",
    "Recorded",
    "RobotController",
    "SettingsError",
    "Side",
    "assert_reached",
    "assert_stopped_within",
    "assert_within_box",
    "assert_within_joints",
    "assert_within_limits",
]

_EXPORTS = LazyExports(
    __name__,
    globals(),
    {
        ".assertions": (
            "LimitReport",
            "MotionAssertionError",
            "MotionSource",
            "Recorded",
            "Side",
            "assert_reached",
            "assert_stopped_within",
            "assert_within_box",
            "assert_within_joints",
            "assert_within_limits",
        ),
        ".core": ("ControllerError", "ControllerTimeout"),
        ".handle": ("AsyncRobotController", "ControllerFactory", "RobotController"),
        ".settings": ("SettingsError",),
    },
)


def __getattr__(name: str) -> object:
    return _EXPORTS.attribute(name)


def __dir__() -> list[str]:
    return _EXPORTS.names()
