"""The controller layer: segment interpolators, interpolation policies, the motion queue, servo
drives, the control loop.

Independent of sockets and of the wire: points arrive in SI units (:mod:`.points`), and
:mod:`robot_server.emulator` turns messages into the controller's verbs. See the module docs of
:mod:`.points`, :mod:`.policies`, :mod:`.blend`, :mod:`.motion`, :mod:`.segments`, :mod:`.peaks`,
:mod:`.servo`, :mod:`.tool` (where the TCP is), :mod:`.cartesian` (straight lines run by the
controller), :mod:`.controller` (sans-I/O), :mod:`.loop` (asyncio) and :mod:`.clock`.

The names in ``__all__`` are this layer's public API (clients, such as :mod:`client`, import them
from here, never from its modules). Each is imported from its module on first use, so that a client
that plans with the segments and the policies loads no controller, motion queue or control loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from simple_message._lazy import LazyExports

if TYPE_CHECKING:
    from .cartesian import LineLimits, LineTarget
    from .clock import Clock, RealTimeClock, SimulatedClock, SteppedClock
    from .controller import (
        FOLLOWING_ERROR_ALARM,
        SOFT_LIMIT_ALARM,
        Controller,
        ControllerConfig,
        Tick,
        submit_together,
    )
    from .loop import ControlLoop, LoopStats, SharedLoop, run_simulated
    from .motion import MotionQueue
    from .peaks import (
        CUBIC_PEAK_ACCELERATION,
        CUBIC_PEAK_VELOCITY,
        QUINTIC_PEAK_ACCELERATION,
        QUINTIC_PEAK_VELOCITY,
    )
    from .points import Limits, Point, PointRejected, Reason, State, check_point
    from .policies import DEFAULT_POLICY, POLICIES, Policy, policy, register_policy, scoped_policies, unregister_policy
    from .recorder import QUANTITIES, Recorder
    from .segments import (
        Chain,
        PlanningError,
        PolynomialSegment,
        RuckigSegment,
        Samples,
        Segment,
        cubic,
        cubic_hermite,
        hold,
        launch,
        linear,
        quintic,
        quintic_hermite,
    )
    from .servo import ServoDrives
    from .tool import TOOL_FIELDS, ToolState

__all__ = [
    "LineLimits",
    "LineTarget",
    "TOOL_FIELDS",
    "ToolState",
    "Clock",
    "RealTimeClock",
    "SimulatedClock",
    "SteppedClock",
    "FOLLOWING_ERROR_ALARM",
    "SOFT_LIMIT_ALARM",
    "ControlLoop",
    "Controller",
    "ControllerConfig",
    "LoopStats",
    "SharedLoop",
    "Tick",
    "run_simulated",
    "submit_together",
    "MotionQueue",
    "register_policy",
    "scoped_policies",
    "unregister_policy",
    "CUBIC_PEAK_VELOCITY",
    "CUBIC_PEAK_ACCELERATION",
    "QUINTIC_PEAK_VELOCITY",
    "QUINTIC_PEAK_ACCELERATION",
    "Limits",
    "Point",
    "PointRejected",
    "Reason",
    "State",
    "check_point",
    "DEFAULT_POLICY",
    "POLICIES",
    "Policy",
    "policy",
    "QUANTITIES",
    "Recorder",
    "Chain",
    "PlanningError",
    "PolynomialSegment",
    "RuckigSegment",
    "Samples",
    "Segment",
    "cubic",
    "cubic_hermite",
    "hold",
    "launch",
    "linear",
    "quintic",
    "quintic_hermite",
    "ServoDrives",
]

#: where each public name lives; its module is imported when the name is first used
_EXPORTS = LazyExports(
    __name__,
    globals(),
    {
        ".cartesian": ("LineLimits", "LineTarget"),
        ".clock": ("Clock", "RealTimeClock", "SimulatedClock", "SteppedClock"),
        ".controller": (
            "FOLLOWING_ERROR_ALARM",
            "SOFT_LIMIT_ALARM",
            "Controller",
            "ControllerConfig",
            "Tick",
            "submit_together",
        ),
        ".loop": ("ControlLoop", "LoopStats", "SharedLoop", "run_simulated"),
        ".motion": ("MotionQueue",),
        ".peaks": (
            "CUBIC_PEAK_ACCELERATION",
            "CUBIC_PEAK_VELOCITY",
            "QUINTIC_PEAK_ACCELERATION",
            "QUINTIC_PEAK_VELOCITY",
        ),
        ".points": ("Limits", "Point", "PointRejected", "Reason", "State", "check_point"),
        ".policies": (
            "DEFAULT_POLICY",
            "POLICIES",
            "Policy",
            "policy",
            "register_policy",
            "scoped_policies",
            "unregister_policy",
        ),
        ".recorder": ("QUANTITIES", "Recorder"),
        ".segments": (
            "Chain",
            "PlanningError",
            "PolynomialSegment",
            "RuckigSegment",
            "Samples",
            "Segment",
            "cubic",
            "cubic_hermite",
            "hold",
            "launch",
            "linear",
            "quintic",
            "quintic_hermite",
        ),
        ".servo": ("ServoDrives",),
        ".tool": ("TOOL_FIELDS", "ToolState"),
    },
)


def __getattr__(name: str) -> object:
    return _EXPORTS.attribute(name)


def __dir__() -> list[str]:
    return _EXPORTS.names()
