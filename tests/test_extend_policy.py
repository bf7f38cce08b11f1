"""Extending the controller with an interpolation policy, end to end: the worked example of
CONTRIBUTING.md, "Adding an interpolation policy".

``Dwell`` is a made-up policy built from existing pieces: every point is reached at rest by the
paper's quintic, then held for a settling time (a "fine" stop with a wait, as some controllers do
before the next motion). It is registered with ``register_policy`` inside ``scoped_policies()``, so
other test modules see only the built-in policies, then run by a controller (sans-I/O, servo tick by
servo tick) and by the emulator over TCP (on a clock the test advances), selected by its name; and
by a ``robot-server`` process that imports a module registering it (``--import``).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import textwrap
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from robot_server import Array
from robot_server.control import (
    DEFAULT_POLICY,
    POLICIES,
    QUINTIC_PEAK_ACCELERATION,
    QUINTIC_PEAK_VELOCITY,
    Chain,
    Controller,
    ControllerConfig,
    Limits,
    Point,
    PointRejected,
    Policy,
    Reason,
    Recorder,
    Segment,
    State,
    SteppedClock,
    hold,
    policy,
    quintic,
    register_policy,
    scoped_policies,
    unregister_policy,
)
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.loader import load_model
from simple_message import LE32, Client, CommType, JointPosition, JointTrajPt, MsgType, ReplyCode
from tests.test_rs_server_process import robot_server

# -- the new policy: what a contributor writes (one module) -----------------------------------------


class Dwell(Policy):
    """Each point reached at rest by the paper's quintic, then held for ``dwell`` seconds."""

    name = "dwell"
    summary = "the quintic to rest at each point, then a settling wait there (0.1 s)"
    # rest-to-rest: a segment beyond the velocity or acceleration limit is refused
    passes_through: ClassVar[bool] = False
    checked_orders: ClassVar[tuple[int, ...]] = (1, 2)

    def __init__(self, dwell: float = 0.1) -> None:
        self.dwell = dwell
        self.planned = 0  # segments planned (the tests check that the controller used this policy)

    def segment_time(self, delta: Array, ratio: float, limits: Limits) -> float:
        # the quintic's peak speed and acceleration over D/T and D/T^2
        speed = QUINTIC_PEAK_VELOCITY * np.abs(delta) / (ratio * limits.max_velocity)
        accel = np.sqrt(QUINTIC_PEAK_ACCELERATION * np.abs(delta) / limits.max_acceleration)
        return float(np.maximum(speed, accel).max())

    def to_rest(
        self, start: State, target: Array, duration: float | None, ratio: float, limits: Limits
    ) -> Segment | None:
        delta = target - start.position
        if duration is None:  # no duration given: the velocity ratio sets the time
            if not np.any(delta):
                return None
            if not 0.0 < ratio <= 1.0:
                raise PointRejected(Reason.TIMING, f"the point has no duration and its velocity ratio is {ratio:g}")
            duration = self.segment_time(delta, ratio, limits)
        self.planned += 1
        return Chain((quintic(start.position, target, duration), hold(target, self.dwell)), kind="dwell")


# -- the tests ------------------------------------------------------------------------------------------

MODEL = load_model("jibot_zxs")
N = MODEL.dof
VMAX, AMAX = MODEL.max_velocity, MODEL.max_acceleration
RATIO = 0.8
TARGETS = [np.zeros(N), np.full(N, 0.4), np.array([-0.3, 0.2, 0.6, -0.5, 0.4, 1.0]), np.zeros(N)]
LIMITS = Limits.from_model(MODEL)
#: wall-clock bound of one step of the stepped clock (the loop answers within milliseconds)
STEP_TIMEOUT = 10.0


@pytest.fixture
def dwell() -> Iterator[Dwell]:
    """A fresh ``Dwell`` registered for the test only."""
    with scoped_policies():
        yield register_policy(Dwell())


def expected_durations(policy_: Dwell) -> list[float]:
    """Each point's motion time (by the policy's own rule) plus its wait."""
    return [policy_.segment_time(b - a, RATIO, LIMITS) + policy_.dwell for a, b in itertools.pairwise(TARGETS)]


def check_run(policy_: Dwell, record: Recorder) -> None:
    """The robot reached every point at rest and waited there, within the limits."""
    times, command = record.time(), record.get("command_position")
    velocity, acceleration = record.get("command_velocity"), record.get("command_acceleration")
    t0 = times[np.flatnonzero(np.any(command != command[0], axis=1))[0]]  # the motion's first tick
    starts = t0 + np.cumsum([0.0, *expected_durations(policy_)])
    for target, arrival in zip(TARGETS[1:], starts[1:] - policy_.dwell, strict=True):
        # the servo ticks well inside the wait (the 4 ms interpolation period blurs its edges)
        waiting = (times > arrival + 0.01) & (times < arrival + policy_.dwell - 0.01)
        assert np.count_nonzero(waiting) >= 60
        assert np.allclose(command[waiting], target, atol=1e-6)
        assert np.all(velocity[waiting] == 0.0)
    assert np.allclose(command[-1], TARGETS[-1], atol=1e-6)
    assert np.all(np.abs(velocity) <= RATIO * VMAX * (1 + 1e-9))  # the ratio caps the quintic's peak speed
    assert np.all(np.abs(acceleration) <= AMAX * (1 + 1e-9))


def test_a_registered_policy_is_known_by_its_name_and_gone_after_the_scope() -> None:
    builtin = dict(POLICIES)
    with scoped_policies():
        new = Dwell()
        assert register_policy(new) is new
        assert policy("dwell") is new and POLICIES["dwell"] is new
        assert list(POLICIES)[: len(builtin)] == list(builtin)  # the built-in ones stay first, the default first
        assert ControllerConfig(policy="dwell").policy == "dwell"
        assert EmulatorConfig(interpolation="dwell").interpolation == "dwell"
    assert builtin == POLICIES and all(POLICIES[name] is entry for name, entry in builtin.items())
    with pytest.raises(ValueError, match="unknown interpolation policy 'dwell'"):
        ControllerConfig(policy="dwell")


def test_the_controller_runs_the_new_policy_and_reaches_every_point(dwell: Dwell) -> None:
    ctl = Controller(MODEL, ControllerConfig(policy="dwell"))
    assert ctl.policy is dwell
    ctl.start(Point(TARGETS[0], velocity_ratio=RATIO))
    for target in TARGETS[1:]:
        ctl.add(Point(target, velocity_ratio=RATIO))
    segments = ctl.queue.segments()
    assert [s.kind for s in segments] == ["dwell"] * 3  # one segment per point, all this policy's
    assert [s.duration for s in segments] == pytest.approx(expected_durations(dwell), abs=1e-12)
    assert dwell.planned == 3
    seconds = sum(expected_durations(dwell)) + 0.5
    recorder = Recorder(N, capacity=round(seconds / ctl.config.servo_period) + 1)
    ctl.run_for(seconds, recorder)
    assert not ctl.in_motion and ctl.queue_fill == 0 and not ctl.in_error
    assert np.allclose(ctl.command.actual_position, TARGETS[-1], atol=1e-3)  # the drives followed
    check_run(dwell, recorder)


def test_the_new_policy_refuses_what_rest_to_rest_policies_refuse(dwell: Dwell) -> None:
    ctl = Controller(MODEL, ControllerConfig(policy="dwell"))
    ctl.start(Point(np.zeros(N)))
    with pytest.raises(PointRejected) as err:  # 1.2 rad in 0.2 s: beyond the speed limit
        ctl.add(Point(np.full(N, 1.2), duration=0.2))
    assert err.value.reason is Reason.VELOCITY_LIMIT
    assert ctl.queue_fill == 0


async def step(clock: SteppedClock, seconds: float) -> None:
    """Advance the controller by ``seconds``, bounded: a loop that died fails the test, never hangs it."""
    async with asyncio.timeout(STEP_TIMEOUT):
        await clock.advance(seconds)


@contextlib.asynccontextmanager
async def emulator(interpolation: str) -> AsyncIterator[tuple[Emulator, SteppedClock, Recorder]]:
    clock = SteppedClock()
    config = EmulatorConfig(models=("jibot_zxs",), motion_port=0, state_port=0, interpolation=interpolation)
    async with Emulator(config, clock=clock) as emu:
        record = emu.record(30.0)[0]
        await step(clock, 0.0)  # the loop has run its first period and waits
        yield emu, clock, record


async def test_the_emulator_runs_the_new_policy_selected_by_name_over_tcp(dwell: Dwell) -> None:
    async with emulator("dwell") as (emu, clock, record):
        ctl = emu.cell.groups[0]
        assert ctl.policy is dwell
        async with Client.tcp("127.0.0.1", emu.ports["motion"], LE32, reconnect=None) as client:
            for sequence, target in enumerate(TARGETS):  # the first point is where the robot is
                point = JointTrajPt(sequence, tuple(target.tolist()), velocity=RATIO)
                reply = await client.request(point, timeout=10.0)
                assert (reply.comm_type, reply.reply_code) == (CommType.SERVICE_REPLY, ReplyCode.SUCCESS)
            assert ctl.queue_fill == 3 and dwell.planned == 3  # all queued before the clock moved
            while ctl.in_motion:
                assert ctl.time < 20.0, "the robot never settled"
                await step(clock, 0.004)
    check_run(dwell, record)


def test_the_command_line_offers_a_policy_registered_before_it_parses(dwell: Dwell) -> None:
    """What ``robot-server`` sees of the policy when the module that registers it is imported first
    (by a wrapper script that then calls ``robot_server.cli.main``, or ``--import`` where the
    command has it)."""
    from robot_server.cli import parser

    command = parser()
    assert command.parse_args(["--interpolation", "dwell"]).interpolation == "dwell"
    assert "dwell:" in command.format_help()


#: a user's module that registers the policy when imported (it logs each segment it plans, so
#: that the test sees from outside the process that the policy ran)
USER_MODULE = textwrap.dedent(
    """\
    import logging

    from robot_server.control.policies import register_policy
    from tests.test_extend_policy import Dwell

    log = logging.getLogger("acme_dwell")


    class LoggedDwell(Dwell):
        def to_rest(self, start, target, duration, ratio, limits):
            segment = super().to_rest(start, target, duration, ratio, limits)
            if segment is not None:
                log.info("dwell planned a %s segment of %.3f s", segment.kind, segment.duration)
            return segment


    register_policy(LoggedDwell())
    """
)


@pytest.mark.slow
async def test_robot_server_imports_the_policy_and_runs_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``robot-server --import MODULE --interpolation NAME``: the command, as a process."""
    (tmp_path / "acme_dwell.py").write_text(USER_MODULE)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, (str(tmp_path), os.environ.get("PYTHONPATH")))))
    options = ("--import", "acme_dwell", "--interpolation", "dwell", "--speedup", "4", "--no-stdin")
    async with robot_server(tmp_path, *options) as server:
        motion = Client.tcp("127.0.0.1", server.ports["motion"], LE32, reconnect=None)
        state = Client.tcp("127.0.0.1", server.ports["state"], LE32, reconnect=None)
        topics = state.subscribe(msg_types=[MsgType.JOINT_POSITION])
        async with motion, state:
            for sequence, target in enumerate(TARGETS[:2]):
                reply = await motion.request(JointTrajPt(sequence, tuple(target.tolist()), velocity=RATIO), 10.0)
                assert reply.reply_code == ReplyCode.SUCCESS
            async with asyncio.timeout(20.0):  # state topics until the robot is at the point
                while True:
                    message = await topics.get()
                    assert isinstance(message, JointPosition)
                    if np.allclose(message.joint_data[:N], TARGETS[1], atol=1e-6):
                        break
        assert await server.terminate() == 0
    assert "dwell planned a dwell segment" in server.log.read_text()


def test_registration_refuses_clashes_and_malformed_policies() -> None:
    with scoped_policies():
        first = register_policy(Dwell())
        assert register_policy(first) is first  # the same policy again: nothing changes
        with pytest.raises(ValueError, match="already registered"):
            register_policy(Dwell(0.2))
        with pytest.raises(ValueError, match="already registered"):
            register_policy(Dwell(), replace=False)
        assert POLICIES["dwell"] is first
        longer = register_policy(Dwell(0.2), replace=True)
        assert POLICIES["dwell"] is longer

        class NoName(Dwell):
            name = "no name"

        class NoSummary(Dwell):
            name = "no_summary"
            summary = ""

        class Jounce(Dwell):
            name = "jounce"
            checked_orders = (1, 4)

        class Timer(Policy):  # rest to rest, but it cannot plan a segment
            name = "timer"
            summary = "a time rule only"

            def segment_time(self, delta: Array, ratio: float, limits: Limits) -> float:
                return 1.0

        before = dict(POLICIES)
        for bad, message in (
            (NoName(), "letters, digits"),
            (NoSummary(), "summary"),
            (Jounce(), "checked_orders"),
            (Timer(), "must implement to_rest"),
            ("quintic", "a Policy instance"),
        ):
            with pytest.raises(ValueError, match=message):
                register_policy(bad)  # type: ignore[type-var]
        assert before == POLICIES

        class Through(Timer):  # passes through: the blend machinery plans it, by its segment_time
            name = "through"
            passes_through = True

        register_policy(Through())
        assert unregister_policy("through").name == "through" and "through" not in POLICIES
        with pytest.raises(ValueError, match="unknown interpolation policy"):
            unregister_policy("through")
        with pytest.raises(ValueError, match="the default"):
            unregister_policy(DEFAULT_POLICY)
        unregister_policy("ruckig")  # a built-in one may go, for the scope
        assert "ruckig" not in POLICIES
    assert "ruckig" in POLICIES and "dwell" not in POLICIES


def test_the_scope_restores_the_table_when_the_block_fails() -> None:
    builtin = dict(POLICIES)
    with pytest.raises(RuntimeError), scoped_policies():
        register_policy(Dwell())
        unregister_policy("linear")
        raise RuntimeError
    assert builtin == POLICIES and list(POLICIES) == list(builtin)
