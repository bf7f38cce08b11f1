"""Segment interpolators: boundary conditions, continuity, the paper's cubic, ruckig limits."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import ruckig

from robot_server.control import (
    Chain,
    PlanningError,
    PolynomialSegment,
    RuckigSegment,
    cubic,
    cubic_hermite,
    hold,
    launch,
    linear,
    quintic,
    quintic_hermite,
)
from robot_server.control.segments import run_up, stop_travel

N = 6


def states(count: int, seed: int = 5) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``count`` random joint states, the same for every test that asks (whatever ran before it)."""
    rng = np.random.default_rng(seed)
    return [(rng.uniform(-2, 2, N), rng.uniform(-1, 1, N), rng.uniform(-3, 3, N)) for _ in range(count)]


def close(a: np.ndarray, b: np.ndarray, tol: float = 1e-12) -> None:
    assert np.max(np.abs(np.asarray(a) - np.asarray(b))) <= tol


@pytest.mark.parametrize("duration", [0.004, 0.37, 2.5])
def test_boundary_conditions(duration: float) -> None:
    (p0, v0, a0), (p1, v1, a1) = states(2)
    zero = np.zeros(N)
    cases = [
        (linear(p0, p1, duration), (p0, None, None), (p1, None, None)),
        (cubic(p0, p1, duration), (p0, zero, None), (p1, zero, None)),
        (cubic_hermite(p0, v0, p1, v1, duration), (p0, v0, None), (p1, v1, None)),
        (quintic(p0, p1, duration), (p0, zero, zero), (p1, zero, zero)),
        (quintic_hermite((p0, v0, a0), (p1, v1, a1), duration), (p0, v0, a0), (p1, v1, a1)),
    ]
    for segment, start, end in cases:
        for t, expected in ((0.0, start), (duration, end)):
            got = segment.sample(t)
            for order, value in enumerate(expected):
                if value is not None:
                    # position exact to 1e-12; derivatives scale with 1/T^order
                    close(got[order], value, 1e-12 * max(1.0, duration**-order))
    close(linear(p0, p1, duration).sample(duration / 2).velocity, (p1 - p0) / duration, 1e-9)


def test_rest_to_rest_shapes_match_the_closed_forms() -> None:
    """docs/reference/motion.md §4: the correct cubic (h2 = 3D/T^2, h3 = -2D/T^3) and the paper's quintic."""
    p0, p1 = np.full(N, 0.3), np.full(N, 1.3)
    tf, delta = 2.0, 1.0
    c = cubic(p0, p1, tf).coefficients
    close(c[:4, 0], [0.3, 0.0, 3 * delta / tf**2, -2 * delta / tf**3])
    q = quintic(p0, p1, tf).coefficients
    close(q[:, 0], [0.3, 0.0, 0.0, 10 * delta / tf**3, -15 * delta / tf**4, 6 * delta / tf**5])
    # the paper's eq. 5 (h0 = 0, h2 = -3D/T^2) fails both boundary conditions: p(T) = -5D, v(T) = -12D/T
    paper = PolynomialSegment([[0.0], [0.0], [-3 * delta / tf**2], [-2 * delta / tf**3]], tf)
    close(paper.end().position, [-5 * delta])
    close(paper.end().velocity, [-12 * delta / tf])
    # peaks (docs/reference/motion.md §4): cubic 1.5 D/T and 6 D/T^2 at the ends; quintic 1.875 D/T, 5.774 D/T^2
    assert math.isclose(cubic(p0, p1, tf).peak(1)[0], 1.5 * delta / tf, rel_tol=1e-12)
    assert math.isclose(cubic(p0, p1, tf).peak(2)[0], 6 * delta / tf**2, rel_tol=1e-12)
    assert math.isclose(quintic(p0, p1, tf).peak(1)[0], 1.875 * delta / tf, rel_tol=1e-12)
    assert math.isclose(quintic(p0, p1, tf).peak(2)[0], 10 / math.sqrt(3) * delta / tf**2, rel_tol=1e-12)


def test_cubic_vs_quintic_acceleration_at_segment_ends() -> None:
    """The paper's point: the cubic's acceleration jumps from 0 to 6D/T^2 when a segment starts
    (and from -6D/T^2 to 0 when it ends); the quintic's is 0 at both ends, so chained quintics
    have no acceleration step."""
    p0, p1, tf = np.zeros(N), np.ones(N), 1.0
    c, q = cubic(p0, p1, tf), quintic(p0, p1, tf)
    close(c.sample(0.0).acceleration, np.full(N, 6.0))
    close(c.sample(tf).acceleration, np.full(N, -6.0))
    close(q.sample(0.0).acceleration, np.zeros(N))
    close(q.sample(tf).acceleration, np.zeros(N))
    # jerk: constant -12 D/T^3 for the cubic, 60 D/T^3 at the start of the quintic
    close(c.sample(0.3).jerk, np.full(N, -12.0), 1e-11)
    close(q.sample(0.0).jerk, np.full(N, 60.0), 1e-11)


def chain(kind: str, points: list[tuple[np.ndarray, np.ndarray, np.ndarray]], durations: list[float]) -> list:
    out = []
    for s, e, tf in zip(points, points[1:], durations, strict=False):
        if kind == "linear":
            out.append(linear(s[0], e[0], tf))
        elif kind == "cubic":
            out.append(cubic_hermite(s[0], s[1], e[0], e[1], tf))
        else:
            out.append(quintic_hermite(s, e, tf))
    return out


@pytest.mark.parametrize(("kind", "continuous_orders"), [("linear", 1), ("cubic", 2), ("quintic", 3)])
def test_continuity_across_chained_segments(kind: str, continuous_orders: int) -> None:
    """C0 for linear, C1 for cubic Hermite, C2 for quintic; and the next order does jump."""
    points = states(6)
    durations = list(np.random.default_rng(6).uniform(0.2, 1.5, 5))
    segments = chain(kind, points, durations)
    for left, right in itertools.pairwise(segments):
        a, b = left.end(), right.sample(0.0)
        for order in range(continuous_orders):
            close(a[order], b[order], 1e-9)
        assert np.max(np.abs(a[continuous_orders] - b[continuous_orders])) > 1e-6  # not smoother than claimed


def test_sampling_is_vectorised_and_consistent() -> None:
    (p0, v0, a0), (p1, v1, a1) = states(2)
    segment = quintic_hermite((p0, v0, a0), (p1, v1, a1), 1.2)
    times = np.linspace(0, 1.2, 1201)
    s = segment.sample(times)
    assert s.position.shape == (1201, N) and s.jerk.shape == (1201, N)
    close(s.position[600], segment.sample(0.6).position)
    # each quantity is the derivative of the one before (central differences)
    h = times[1] - times[0]
    for order in range(3):
        numeric = (s[order][2:] - s[order][:-2]) / (2 * h)
        assert np.max(np.abs(numeric - s[order + 1][1:-1])) < 1e-3
    # outside [0, T] the segment holds its end states
    close(segment.sample(-1.0).position, p0)
    close(segment.sample(9.0).position, p1)
    close(hold(p0, 1.0).sample(times).position, np.broadcast_to(p0, (1201, N)))


@pytest.mark.parametrize("seed", range(5))
def test_extremes_are_exact(seed: int) -> None:
    (p0, v0, a0), (p1, v1, a1) = states(2, seed)
    for segment in (
        cubic_hermite(p0, v0, p1, v1, 0.8),
        quintic_hermite((p0, v0, a0), (p1, v1, a1), 0.8),
        RuckigSegment.plan((p0, v0, np.zeros(N)), (p1, np.zeros(N), np.zeros(N)), *LIMITS),
    ):
        samples = 200_001
        dense = segment.sample(np.linspace(0, segment.duration, samples))
        step = segment.duration / (samples - 1)
        for order in range(4):
            lo, hi = segment.extremes(order)
            scale = max(1.0, float(np.max(np.abs(dense[order]))))
            tol = 1e-9 * scale if order < 3 else 1e-12 * scale
            assert np.all(lo <= dense[order].min(axis=0) + tol), (segment, order)
            assert np.all(hi >= dense[order].max(axis=0) - tol), (segment, order)
            if order < 3 or segment.kind != "ruckig":  # ruckig's jerk is exact at phase starts, sampled inside
                # the samples come within a step's change of an extreme at a kink (ruckig's
                # acceleration is piecewise linear), within far less of a smooth one
                resolution = np.max(np.abs(dense[order + 1]), axis=0) * step if order < 3 else 0.0
                assert np.all(dense[order].min(axis=0) - lo < 1e-6 * scale + resolution), (segment, order)
                assert np.all(hi - dense[order].max(axis=0) < 1e-6 * scale + resolution), (segment, order)
            bound_lo, bound_hi = segment.bounds(order)
            assert np.all(bound_lo <= lo + tol) and np.all(bound_hi >= hi - tol)


def test_bounded_order_says_which_derivatives_stay_finite_at_joins() -> None:
    (p0, v0, a0), (p1, v1, a1) = states(2)
    assert linear(p0, p1, 1.0).bounded_order == 1
    assert cubic(p0, p1, 1.0).bounded_order == cubic_hermite(p0, v0, p1, v1, 1.0).bounded_order == 2
    assert quintic(p0, p1, 1.0).bounded_order == quintic_hermite((p0, v0, a0), (p1, v1, a1), 1.0).bounded_order == 3
    assert hold(p0, 1.0).bounded_order == 3
    assert RuckigSegment.plan((p0, v0, a0), (p1, v1, np.zeros(N)), *LIMITS).bounded_order == 3


def test_bad_segments_are_refused() -> None:
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(PlanningError):
            quintic(np.zeros(N), np.ones(N), bad)
    with pytest.raises(PlanningError):
        linear(np.zeros(N), np.ones(N - 1), 1.0)


LIMITS = (np.full(N, math.pi), np.full(N, 10.0), np.full(N, 500.0))


def assert_within_limits(segment: RuckigSegment, step: float = 1e-3) -> None:
    times = np.arange(0.0, segment.duration + step, step)
    s = segment.sample(times)
    for values, limit in zip((s.velocity, s.acceleration, s.jerk), LIMITS, strict=True):
        assert np.all(np.abs(values) <= limit * (1 + 1e-9))


@pytest.mark.parametrize("seed", range(20))
def test_ruckig_segments_respect_limits_and_end_at_target(seed: int) -> None:
    rng = np.random.default_rng(seed)
    start = (rng.uniform(-2, 2, N), rng.uniform(-3, 3, N), rng.uniform(-9, 9, N))
    target = (rng.uniform(-2, 2, N), rng.uniform(-2, 2, N) * (seed % 2), np.zeros(N))
    segment = RuckigSegment.plan(start, target, *LIMITS)
    assert_within_limits(segment)
    end = segment.end()
    close(end.position, target[0], 1e-8)
    close(end.velocity, target[1], 1e-8)
    close(segment.sample(0.0).position, start[0], 1e-12)
    # our vectorised evaluation is ruckig's own
    for t in np.linspace(0, segment.duration, 37):
        p, v, a = segment.trajectory.at_time(float(t))
        s = segment.sample(t)
        close(s.position, p, 1e-9)
        close(s.velocity, v, 1e-9)
        close(s.acceleration, a, 1e-9)


def test_ruckig_minimum_duration_and_stop() -> None:
    rest = np.zeros(N)
    slow = RuckigSegment.plan((rest, rest, rest), (np.ones(N), rest, rest), *LIMITS, minimum_duration=3.0)
    assert math.isclose(slow.duration, 3.0)
    moving = (np.zeros(N), np.full(N, math.pi), np.zeros(N))
    stop = RuckigSegment.plan(moving, (np.zeros(N), rest, rest), *LIMITS, velocity_interface=True)
    assert_within_limits(stop)
    close(stop.end().velocity, rest, 1e-9)
    lo, hi = stop.extremes(1)
    assert np.all(hi <= math.pi * (1 + 1e-12)) and np.all(lo >= -1e-9)


def test_ruckig_ignores_position_limits_so_we_check_extremes() -> None:
    """docs/reference/motion.md §3.2: the PyPI build accepts max_position and ignores it; extremes(0) is what
    the planner checks instead."""
    inp = ruckig.InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [1.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [0.1], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [3.0], [2.0], [10.0]
    inp.max_position = [0.2]
    trajectory = ruckig.Trajectory(1)
    assert ruckig.Ruckig(1).calculate(inp, trajectory) == ruckig.Result.Working
    assert trajectory.position_extrema[0].max > 0.2  # the limit was ignored
    segment = RuckigSegment.plan(([0.0], [1.0], [0.0]), ([0.1], [0.0], [0.0]), [3.0], [2.0], [10.0])
    _, hi = segment.extremes(0)
    # ruckig's own position_extrema says 0.3186 here, but its at_time reaches 0.3467 (at t = 0.6 s):
    # extremes(0) finds the true maximum (where the velocity crosses zero), not ruckig's figure
    sampled = max(segment.trajectory.at_time(float(t))[0][0] for t in np.linspace(0, segment.duration, 20_001))
    assert math.isclose(hi[0], sampled, rel_tol=1e-6) and hi[0] >= sampled
    assert trajectory.position_extrema[0].max < sampled - 0.02
    assert hi[0] > 0.2


def test_ruckig_brake_phase_from_beyond_the_limits() -> None:
    """A start faster than the limit makes ruckig prepend a brake; our evaluation includes it."""
    n = 2
    limits = (np.full(n, math.pi), np.full(n, 10.0), np.full(n, 500.0))
    start = (np.zeros(n), np.array([4.0, -1.0]), np.array([9.5, 0.0]))
    segment = RuckigSegment.plan(start, (np.ones(n), np.zeros(n), np.zeros(n)), *limits)
    assert segment.trajectory.profiles[0][0].brake.duration > 0.0
    for t in np.linspace(0, segment.duration, 101):
        p, v, a = segment.trajectory.at_time(float(t))
        s = segment.sample(t)
        close(s.position, p, 1e-9)
        close(s.velocity, v, 1e-9)
        close(s.acceleration, a, 1e-9)


# -- launch: from rest as a plan starts ----------------------------------------------------------

JERK = np.full(N, 500.0)


def test_a_launch_starts_at_rest_ramps_at_the_jerk_limit_and_ends_in_the_given_state() -> None:
    (p0, _, _), (p1, v1, a1) = states(2)
    p1 = p0 + 0.05 * (p1 - p0)  # a short move: the start acceleration stays a few rad/s^2
    segment = launch(p0, (p1, v1, a1), 1.5, JERK)
    assert isinstance(segment, Chain) and segment.kind == "launch" and segment.bounded_order == 3
    start, end = segment.sample(0.0), segment.sample(1.5)
    close(start.position, p0), close(start.velocity, np.zeros(N)), close(start.acceleration, np.zeros(N))
    close(end.position, p1, 1e-12), close(end.velocity, v1, 1e-11), close(end.acceleration, a1, 1e-10)
    ramp = segment.parts[0].duration
    assert 0.0 < ramp <= 0.25 * 1.5
    # the jerk is at the limit on the slowest joint of the ramp, and never beyond it
    lo, hi = segment.parts[0].extremes(3)
    ramp_jerk = np.maximum(-lo, hi) / JERK
    assert np.all(ramp_jerk <= 1.0 + 1e-9) and np.max(ramp_jerk) >= 1.0 - 1e-9
    # C2 where the ramp hands over to the quintic
    before, after = segment.sample(ramp - 1e-9), segment.sample(ramp + 1e-9)
    for order in range(3):
        close(before[order], after[order], 1e-6)


def test_a_launch_follows_a_plan_that_starts_with_a_constant_acceleration() -> None:
    """End state of p = a t^2 / 2 at T: the launch is that parabola but for the ramp's lag (a
    step vs a ramp of tau: a velocity short by a tau / 2), where the quintic from rest at zero
    acceleration trails it by far more."""
    a, tf = np.linspace(0.1, 0.6, N), 1.5
    p0 = np.zeros(N)
    end = (a * tf**2 / 2, a * tf, a)
    segment = launch(p0, end, tf, JERK)
    assert segment is not None
    times = np.linspace(0.0, tf, 1501)
    plan = a * times[:, None] ** 2 / 2
    tau = float(np.max(a / JERK))
    lag = np.max(np.abs(segment.sample(times).position - plan))
    assert lag <= np.max(a) * tau * tf  # a velocity short by a tau / 2, made up over the segment
    from_rest = quintic_hermite((p0, p0, p0), end, tf)
    assert np.max(np.abs(from_rest.sample(times).position - plan)) > 100 * lag
    # the start acceleration is the plan's
    close(segment.sample(tau).acceleration, a, 1e-9)


def test_a_launch_whose_ramp_would_be_long_is_not_made() -> None:
    """A start acceleration the jerk limit needs more than a quarter of the segment to reach: no
    launch (the caller keeps the quintic from rest and its own jerk handling)."""
    p0 = np.zeros(N)
    assert launch(p0, (np.full(N, 0.016), np.full(N, 3.2), np.full(N, 3.2)), 0.01, JERK) is None
    still = launch(p0, (p0, p0, p0), 0.5, JERK)  # nothing to accelerate for: the quintic from rest
    assert still is not None and still.kind == "quintic"


def test_a_chain_samples_vectorised_and_bounds_its_parts() -> None:
    (p0, _, _), (p1, v1, a1) = states(2)
    segment = launch(p0, (p0 + 0.05 * (p1 - p0), v1, a1), 0.9, JERK)
    assert segment is not None
    times = np.linspace(-0.1, 1.0, 1101)
    s = segment.sample(times)
    assert s.position.shape == (1101, N) and s.jerk.shape == (1101, N)
    for i in (0, 1, 50, 600, 1100):
        close(s.position[i], segment.sample(times[i]).position)
        close(s.jerk[i], segment.sample(times[i]).jerk)
    assert segment.sample(times[:1100].reshape(11, 100)).velocity.shape == (11, 100, N)
    dense = segment.sample(np.linspace(0, segment.duration, 200_001))
    for order in range(4):
        lo, hi = segment.extremes(order)
        scale = max(1.0, float(np.max(np.abs(dense[order]))))
        assert np.all(lo <= dense[order].min(axis=0) + 1e-9 * scale)
        assert np.all(hi >= dense[order].max(axis=0) - 1e-9 * scale)
        bound_lo, bound_hi = segment.bounds(order)
        assert np.all(bound_lo <= lo + 1e-9 * scale) and np.all(bound_hi >= hi - 1e-9 * scale)
    with pytest.raises(PlanningError):
        Chain(())
    with pytest.raises(PlanningError):
        Chain((hold(p0, 1.0), hold(p0[:2], 1.0)))


def test_run_up_is_the_shortest_way_to_a_speed() -> None:
    """From rest to v at the jerk limit only (v <= A^2 / J): v sqrt(v / J); reaching the
    acceleration limit: v^2 / 2A + v A / 2J; arriving decelerating needs more than arriving at
    constant speed; from a speed already reached, nothing is added but the way at it."""
    v_max, a_max, j_max = np.full(3, 3.0), np.full(3, 10.0), np.full(3, 500.0)
    target = np.array([0.1, 1.0, 1.0])
    d = run_up(np.zeros(3), np.zeros(3), target, np.zeros(3), limits=(v_max, a_max, j_max))
    close(d[:2], [0.1 * math.sqrt(0.1 / 500.0), 1.0 / 20.0 + 10.0 / 1000.0], 1e-9)
    slowing = run_up(np.zeros(3), np.zeros(3), target, np.array([0.0, 0.0, -5.0]), limits=(v_max, a_max, j_max))
    assert slowing[2] > d[2] + 1e-3
    assert run_up([0.5], [0.0], [0.5], [0.0], limits=([3.0], [10.0], [500.0]))[0] == 0.0


def test_stop_travel_is_ruckigs_fastest_stop_in_closed_form() -> None:
    rng = np.random.default_rng(11)
    limits = (np.full(N, 3.0), np.full(N, 10.0), np.full(N, 500.0))
    zero = np.zeros(N)
    for _ in range(300):
        # at rest, slow, fast; not accelerating, accelerating, braking (harder than a stop starts with too)
        v = rng.uniform(-2.5, 2.5, N) * rng.choice([0.0, 0.01, 1.0], N)
        a = rng.uniform(-10.0, 10.0, N) * rng.choice([0.0, 0.1, 1.0], N)
        close(stop_travel(v, a, limits=limits), run_up(v, a, zero, zero, limits=limits), 1e-9)
