"""Kinematics benchmark: forward kinematics (single and batch), closed-form IK (single, all
solutions, and batch) and numeric IK (median time and success rate), per shipped model.

    python bench/kinematics.py [--quick]

Targets on the CI machine class (2 cores): single FK <= 20 us, batch FK >= 2,000,000 poses/s
(N = 100,000), closed-form IK <= 50 us single and >= 200,000 poses/s batch, numeric IK median
<= 200 us. Single-call times are medians over the calls of each call's best time in three
passes over them (``perf_counter_ns``, after a warm-up): that takes out most of this VM's stolen
time, which otherwise moves a median by up to 1.5x between runs; batch rates are the best of
five runs. Bursts of stolen time can still last seconds: run it more than once. Numeric IK
starts from a random seed inside the limits, like the docs' reference measurements (docs/reference/motion.md
§2); each of its three timings of a pose draws the same restarts.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from codec import machine

from robot_server.kinematics import NumericIKResult, closed_form, fk, fk_batch, ik_numeric
from robot_server.loader import load_model, shipped_models
from robot_server.model import RobotModel


def median_us(calls: Callable[[], list[tuple[Any, ...]]], function: Callable[..., object], passes: int = 3) -> float:
    """The median over the calls of each call's best time in ``passes`` passes (us); ``calls()``
    gives each pass its arguments, made outside the timing."""
    best: list[float] = []
    for _ in range(passes):
        arguments = calls()
        best = best or [float("inf")] * len(arguments)
        for i, args in enumerate(arguments):
            t0 = time.perf_counter_ns()
            function(*args)
            best[i] = min(best[i], time.perf_counter_ns() - t0)
    return statistics.median(best) / 1000.0


def numeric(model: RobotModel, pose: Any, seed: Any, rng: np.random.Generator) -> NumericIKResult:
    return ik_numeric(model, pose, seed, rng=rng)


def best_rate(n: int, function: object, argument: object, repeats: int = 5) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        function(argument)  # type: ignore[operator]
        best = min(best, time.perf_counter() - t0)
    return n / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    args = parser.parse_args()
    samples = 200 if args.quick else 2000
    numeric_poses = 100 if args.quick else 1000
    batch = 10_000 if args.quick else 100_000
    print(f"# kinematics benchmark: {machine()}")
    warm = load_model(shipped_models()[0])  # let the CPU clock settle before the first row
    for _ in range(20_000):
        fk(warm, [0.1] * warm.dof)
    print()
    print(
        "| model | FK single (us) | FK batch (poses/s) | closed-form IK single, all solutions (us) "
        "| closed-form IK batch (poses/s) | numeric IK median (us) | numeric IK solved |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in shipped_models():
        model = load_model(name)
        rng = np.random.default_rng(11)
        qs = rng.uniform(model.lower, model.upper, size=(batch, model.dof))
        fk(model, qs[0])
        fk_calls = [(model, q) for q in qs[:samples]]
        fk_single = median_us(lambda: fk_calls, fk)  # noqa: B023
        fk_rate = best_rate(batch, functools.partial(fk_batch, model), qs)
        poses = fk_batch(model, qs)
        solver = closed_form(model)
        if solver is not None:
            solver.solve_all(poses[0])
            cf_calls = [(p,) for p in poses[:samples]]
            cf_single = f"{median_us(lambda: cf_calls, solver.solve_all):.1f}"  # noqa: B023
            cf_rate = f"{best_rate(batch, solver.solve_batch, poses):,.0f}"
        else:
            cf_single = cf_rate = "n/a (no spherical wrist)"
        seeds = rng.uniform(model.lower, model.upper, size=(numeric_poses, model.dof))

        def numeric_calls() -> list[tuple[Any, ...]]:  # each pass draws the same restarts
            return [(model, poses[i], seeds[i], np.random.default_rng([11, i])) for i in range(numeric_poses)]  # noqa: B023

        numeric_us = median_us(numeric_calls, numeric)
        solved = sum(numeric(*args).success for args in numeric_calls())
        print(
            f"| {name} | {fk_single:.1f} | {fk_rate:,.0f} | {cf_single} | {cf_rate} | "
            f"{numeric_us:.0f} | {solved}/{numeric_poses} |"
        )


if __name__ == "__main__":
    main()
