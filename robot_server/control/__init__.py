"""The controller layer: segment interpolators, trajectory semantics, servo drives, the control loop.

Independent of sockets: :mod:`robot_server` wires it to the protocol. See the module docs of
:mod:`.segments`, :mod:`.trajectory`, :mod:`.servo`, :mod:`.controller` and :mod:`.clock`.
"""

from .clock import Clock, RealTimeClock, SimulatedClock
from .controller import (
    FOLLOWING_ERROR_ALARM,
    Controller,
    ControllerConfig,
    ControlLoop,
    LoopStats,
    Tick,
    run_simulated,
    submit_together,
)
from .recorder import QUANTITIES, Recorder
from .segments import (
    PlanningError,
    PolynomialSegment,
    RuckigSegment,
    Samples,
    Segment,
    cubic,
    cubic_hermite,
    hold,
    linear,
    quintic,
    quintic_hermite,
)
from .servo import ServoDrives
from .trajectory import Limits, Point, PointRejected, Policy, Reason, State, TrajectoryPlanner, point_from_message

__all__ = [
    "Clock",
    "RealTimeClock",
    "SimulatedClock",
    "FOLLOWING_ERROR_ALARM",
    "ControlLoop",
    "Controller",
    "ControllerConfig",
    "LoopStats",
    "Tick",
    "run_simulated",
    "submit_together",
    "QUANTITIES",
    "Recorder",
    "PlanningError",
    "PolynomialSegment",
    "RuckigSegment",
    "Samples",
    "Segment",
    "cubic",
    "cubic_hermite",
    "hold",
    "linear",
    "quintic",
    "quintic_hermite",
    "ServoDrives",
    "Limits",
    "Point",
    "PointRejected",
    "Policy",
    "Reason",
    "State",
    "TrajectoryPlanner",
    "point_from_message",
]
