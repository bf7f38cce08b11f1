"""Controller benchmark: real-time factor of the 6-joint controller (paper's robot) at a 1 ms servo
period and a 4 ms interpolation period, per interpolation policy, and the cost of one servo tick.

    python bench/controller.py [--quick]

Each run streams random waypoints inside the limits (velocity ratio 0.8) so the robot moves all
the time, and runs the control loop on the simulated clock (as fast as possible, the asyncio event
loop included). Planning a point (validation and the segment) is timed separately: it happens
when a point arrives, not per tick. Target on the CI machine class: at least 20x real time on one
core.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from codec import machine

from robot_server.control import POLICIES, Controller, ControllerConfig, ControlLoop, Point, SimulatedClock
from robot_server.loader import load_model


def waypoints(model_lower: np.ndarray, model_upper: np.ndarray, count: int) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    inner_lo, inner_hi = 0.8 * model_lower, 0.8 * model_upper
    return [np.zeros(model_lower.size)] + [rng.uniform(inner_lo, inner_hi) for _ in range(count)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a shorter run (a smoke test)")
    args = parser.parse_args()
    seconds = 10.0 if args.quick else 60.0
    model = load_model("jibot_zxs")
    print(
        f"# controller benchmark: {machine()}; model {model.name}, {model.dof} joints, "
        f"servo 1 ms, interpolation 4 ms, {seconds:.0f} s simulated per policy"
    )
    print()
    print("| policy | real-time factor | per servo tick (us) | planning per point (us) | points run |")
    print("|---|---|---|---|---|")
    for policy in POLICIES:
        ctl = Controller(model, ControllerConfig(policy=policy, queue_capacity=100_000))
        points = waypoints(model.lower, model.upper, 400)
        t0 = time.perf_counter()
        ctl.start(Point(points[0], velocity_ratio=0.8, duration=0.0))
        for q in points[1:]:
            ctl.add(Point(q, velocity_ratio=0.8, duration=0.0))
        planning = (time.perf_counter() - t0) / len(points)
        queued = ctl.queue_fill
        stats = asyncio.run(ControlLoop(ctl, SimulatedClock()).run(seconds))
        assert ctl.moving and not ctl.in_error, "the benchmark must keep the robot moving"
        print(
            f"| {policy} | {stats.realtime_factor:.1f}x | {stats.wall / stats.ticks * 1e6:.1f} | "
            f"{planning * 1e6:.0f} | {queued - ctl.queue_fill} |"
        )


if __name__ == "__main__":
    main()
