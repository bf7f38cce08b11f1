"""The client suite (simple_message.conformance.client): the project's own driver and robot-client
pass it, with the injected BUSY, FAILURE and dropped connection, and each kind of broken client is
caught by the rule meant for it.

Every controller is on loopback on free ports; every wait is bounded.
"""

from __future__ import annotations

import asyncio
import re
import struct
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from client.driver import ExecutionAborted, RobotDriver
from client.trajectory import Trajectory
from robot_server.loader import load_model
from simple_message.conformance.client import (
    RULES,
    ClientSuite,
    ClientSuiteOptions,
    run_client_suite,
)
from simple_message.conformance.report import Report, RuleResult, Verdict
from simple_message.constants import MotoResult, ReplyCode, ValidFields
from simple_message.messages import JointTrajPt, JointTrajPtFull, Ping
from tests.conformance_clients import (
    TIMEOUT,
    RawClient,
    current_position,
    emulator,
    far_first_point,
    ignores_failure,
    moved,
    options,
    other_byte_order,
    resends_after_reconnect,
    sequence_gap,
    skips_busy,
    two_in_flight,
)

MODEL = load_model("jibot_zxs")
ROOT = Path(__file__).resolve().parents[1]


def rule(report: Report, name: str) -> RuleResult:
    found = [r for r in report.results if r.rule == name]
    assert len(found) == 1, f"{name}: {[r.rule for r in report.results]}"
    return found[0]


def verdicts(report: Report) -> dict[str, Verdict]:
    return {r.rule: r.verdict for r in report.results}


def no_failure(report: Report) -> None:
    failed = [r for r in report.results if r.verdict is Verdict.FAIL]
    assert not failed, report.table()


# -- the driver passes ----------------------------------------------------------------------------------


def line(start: np.ndarray, end: np.ndarray, seconds: float, n: int = 6) -> Trajectory:
    """A quintic-timed joint move sampled at n waypoints, with its velocities."""
    s = np.linspace(0.0, 1.0, n)
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / seconds
    return Trajectory(s * seconds, start + np.outer(blend, end - start), np.outer(rate, end - start))


async def at_rest(driver: RobotDriver) -> np.ndarray:
    """Where the robot stands once STATUS says it is not moving and two samples agree (bounded)."""
    previous = None
    async with asyncio.timeout(TIMEOUT):
        while True:
            state = await driver.wait_state(TIMEOUT)
            still = previous is not None and np.array_equal(previous, state.positions)
            if still and state.status is not None and state.status.in_motion == 0:
                return state.positions
            previous = state.positions


@pytest.mark.parametrize("profile", ["generic", "motoros", "abb", "fanuc", "staubli"])
async def test_the_driver_passes_with_every_injection(profile: str) -> None:
    """Three trajectories and a STOP through the suite: the first runs (on MotoROS after the
    injected BUSY, which the driver retries), the second is refused at point 1 and the third loses
    its connection after point 1. The driver reports both as its ExecutionAborted, stops the robot
    each time (on the new connection after the drop), and breaks no rule."""
    async with emulator(profile) as (_, upstream), ClientSuite(options(profile, upstream)) as suite:
        driver = RobotDriver(
            motion_port=suite.ports["motion"], state_port=suite.ports["state"], profile=profile, model=MODEL
        )
        outcomes: list[BaseException | None] = []
        async with driver:
            for k in range(3):
                here = await at_rest(driver)
                target = moved(here.tolist(), 0.05 if k % 2 == 0 else -0.05)
                try:
                    await asyncio.wait_for(driver.execute(line(here, np.array(target), 0.6)), 30.0)
                    outcomes.append(None)
                except ExecutionAborted as exc:
                    outcomes.append(exc)
            await at_rest(driver)
            await driver.stop()
        report = await suite.finish()

    assert outcomes[0] is None
    if profile == "abb":  # RAPID never answers FAILURE: no failure injection
        assert outcomes[1] is None
    else:
        assert isinstance(outcomes[1], ExecutionAborted)
        assert "refused point 1" in str(outcomes[1])
        assert outcomes[1].confirmed == 0
    assert isinstance(outcomes[2], ExecutionAborted)
    assert "motion connection" in str(outcomes[2]) and outcomes[2].confirmed == 1

    no_failure(report)
    assert [r.rule for r in report.results] == list(RULES)
    exercised = [
        "client.byte-order",
        "client.stop-and-wait",
        "client.sequence",
        "client.point-fields",
        "client.first-point",
        "client.stop",
        "client.failure-reaction",
        "client.reconnect",
    ]
    if profile == "abb":
        exercised.remove("client.failure-reaction")
        assert verdicts(report)["client.failure-reaction"] is Verdict.SKIP, report.table()
    assert all(verdicts(report)[name] is Verdict.PASS for name in exercised), report.table()
    busy = rule(report, "client.busy-reaction")
    assert busy.verdict is (Verdict.PASS if profile == "motoros" else Verdict.SKIP), report.table()
    # the injection log is in the evidence, with the injected replies as they were sent
    if profile == "abb":
        return
    failure = rule(report, "client.failure-reaction")
    assert any(e.kind == "note" and e.text.startswith("failure: trajectory 2, point 1") for e in failure.evidence)
    sent = [e for e in failure.evidence if e.kind == "sent"]
    assert sent and sent[0].decoded is not None
    expected = {"generic": "JOINT_TRAJ_PT", "staubli": "JOINT_TRAJ_PT", "fanuc": "JOINT_POSITION"}
    assert sent[0].decoded["name"] == expected.get(profile, "MOTO_MOTION_REPLY")
    if profile == "motoros":
        assert sent[0].decoded["body"]["result"] == MotoResult.INVALID
        assert sent[0].decoded["body"]["subcode"] == 3010
    else:
        assert sent[0].decoded["reply_code"] == ReplyCode.FAILURE
    reconnect = rule(report, "client.reconnect")
    assert any(e.kind == "note" and e.text.startswith("drop: trajectory 3, point 1") for e in reconnect.evidence)


# -- robot-client passes, against a spawned robot-server --------------------------------------------


async def robot_client(*args: str) -> tuple[int, str]:
    """Run ``robot-client ARGS`` (bounded); its exit status and stderr."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "client",
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        stdin=asyncio.subprocess.DEVNULL,
        cwd=ROOT,
    )
    try:
        _, err = await asyncio.wait_for(proc.communicate(), 60.0)
    except TimeoutError:
        proc.kill()
        await proc.wait()
        raise
    assert proc.returncode is not None
    return proc.returncode, err.decode(errors="replace")


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["generic", "motoros"])
async def test_robot_client_passes_against_a_spawned_controller(profile: str) -> None:
    """robot-client, one process per command: three moves and a stop, through the suite, whose
    upstream controller is a robot-server process it starts (and stops) itself."""
    async with ClientSuite(options(profile, None)) as suite:
        assert set(suite.upstream) == ({"motion", "state", "io"} if profile == "motoros" else {"motion", "state"})
        common = ["--motion-port", str(suite.ports["motion"]), "--state-port", str(suite.ports["state"])]
        common += ["--profile", profile, "--timeout", "5"]
        results = []
        for k in range(3):
            here = await current_position(suite.ports["state"])
            target = moved(here[:6], 0.05 if k % 2 == 0 else -0.05)
            joints = [f"{q:.6f}" for q in target]  # never 1e-05: argparse would take "-1e-05" for an option
            results.append(await robot_client("move", *common, "--joints", *joints, "--speed", "1.0"))
        results.append(await robot_client("stop", *common))
        process = suite._process
        report = await suite.finish()
    assert process is not None and process.returncode is not None  # the spawned controller was stopped

    assert results[0][0] == 0, results[0]
    assert results[1][0] == 1 and "refused point 1" in results[1][1], results[1]
    assert results[2][0] in (0, 1) and "internal error" not in results[2][1], results[2]
    assert results[3][0] == 0, results[3]
    no_failure(report)
    for name in ("client.stop-and-wait", "client.sequence", "client.first-point", "client.failure-reaction"):
        assert verdicts(report)[name] is Verdict.PASS, report.table()
    assert verdicts(report)["client.reconnect"] is Verdict.PASS, report.table()  # each command connects anew
    if profile == "motoros":
        assert verdicts(report)["client.busy-reaction"] is Verdict.PASS, report.table()


# -- broken clients fail ------------------------------------------------------------------------------


BrokenClient = Callable[[dict[str, int]], Awaitable[Any]]


async def run_broken(
    client: BrokenClient, profile: str = "generic", inject: frozenset[str] = frozenset()
) -> tuple[Report, Any]:
    async with emulator(profile) as (_, upstream), ClientSuite(options(profile, upstream, inject=inject)) as suite:
        outcome = await asyncio.wait_for(client(suite.ports), TIMEOUT * 3)
        report = await suite.finish()
    return report, outcome


async def test_two_points_in_flight_fail_stop_and_wait() -> None:
    report, _ = await run_broken(two_in_flight)
    result = rule(report, "client.stop-and-wait")
    assert result.verdict is Verdict.FAIL, report.table()
    assert "point 1 sent" in result.detail and "point 0 still awaited its reply" in result.detail
    frames = [e for e in result.evidence if e.kind == "received"]
    assert [e.decoded["body"]["sequence"] for e in frames[:2] if e.decoded] == [0, 1]
    assert verdicts(report)["client.sequence"] is Verdict.PASS


async def test_a_resend_after_the_reconnect_fails_reconnect() -> None:
    report, reply = await run_broken(resends_after_reconnect, inject=frozenset({"drop"}))
    result = rule(report, "client.reconnect")
    assert result.verdict is Verdict.FAIL, report.table()
    assert "sequence 1" in result.detail and "a repeat" in result.detail
    assert any(e.kind == "note" and e.text.startswith("drop: trajectory 3, point 1") for e in result.evidence)
    assert verdicts(report)["client.failure-reaction"] is Verdict.SKIP  # not injected
    assert reply is None or reply.reply_code == ReplyCode.FAILURE  # the controller had no trajectory


async def test_skipping_the_point_answered_busy_fails_busy_reaction() -> None:
    report, busy = await run_broken(skips_busy, "motoros", frozenset({"busy"}))
    assert busy.result == MotoResult.BUSY and busy.sequence == 2 and busy.command == 14
    result = rule(report, "client.busy-reaction")
    assert result.verdict is Verdict.FAIL, report.table()
    assert "sent point 3 instead: point 2 was skipped" in result.detail


async def test_a_first_point_away_from_the_robot_fails_first_point() -> None:
    report, reply = await run_broken(far_first_point)
    assert reply is not None and reply.reply_code == ReplyCode.FAILURE  # the emulator refuses it too
    result = rule(report, "client.first-point")
    assert result.verdict is Verdict.FAIL, report.table()
    assert "starts 0.05 rad from the robot" in result.detail


async def test_a_frame_in_the_other_byte_order_fails_byte_order() -> None:
    report, closed = await run_broken(other_byte_order)
    assert closed  # the controller could not read it
    result = rule(report, "client.byte-order")
    assert result.verdict is Verdict.FAIL, report.table()
    assert "big-endian frame" in result.detail
    assert result.evidence[0].text == "0000000c000000010000000200000000"  # the frame, as it came
    assert result.evidence[0].decoded is not None and result.evidence[0].decoded["name"] == "PING"


async def test_a_gap_fails_sequence() -> None:
    report, _ = await run_broken(sequence_gap)
    result = rule(report, "client.sequence")
    assert result.verdict is Verdict.FAIL, report.table()
    assert "sequence 3 after 1: a gap" in result.detail
    assert verdicts(report)["client.stop-and-wait"] is Verdict.PASS


@pytest.mark.parametrize(("profile", "verdict"), [("generic", Verdict.WARN), ("motoros", Verdict.FAIL)])
async def test_going_on_after_a_failure_is_judged_by_the_profile(profile: str, verdict: Verdict) -> None:
    """The reference streamer ignores reply codes: a generic controller's client that goes on after a
    refused point is a WARN (the point is lost), a MotoROS client that does so a FAIL."""
    report, replies = await run_broken(
        lambda ports: ignores_failure(ports, motoros=profile == "motoros"), profile, frozenset({"failure"})
    )
    refused = replies[1]
    if profile == "motoros":
        assert refused.result == MotoResult.INVALID and refused.subcode == 3010
    else:
        assert refused.reply_code == ReplyCode.FAILURE
    result = rule(report, "client.failure-reaction")
    assert result.verdict is verdict, report.table()
    assert "went on with point 2" in result.detail
    assert verdicts(report)["client.sequence"] is Verdict.PASS  # 0, 1, 2 are in order: the hole is the refusal's
    assert any(e.kind == "note" and e.text.startswith("failure: trajectory 2, point 1") for e in result.evidence)


async def test_bad_bytes_are_evidence_not_a_crash() -> None:
    """A point whose body fits no layout, then bytes that are no frame in either byte order: both are
    forwarded as they came (the controller refuses the one and hangs up on the other), both are
    evidence, and the suite goes on serving."""
    async with emulator() as (_, upstream), ClientSuite(options("generic", upstream, inject=frozenset())) as suite:
        client = await RawClient.open(suite.ports["motion"])
        try:
            await client.send(struct.pack("<4i", 20, 11, 2, 0) + bytes(8))  # JOINT_TRAJ_PT, 8-byte body
            reply = await client.reply()
            assert reply is not None and reply.reply_code == ReplyCode.FAILURE
            await client.send(b"\xff\xff\xff\x7f" + b"junk" * 10)
            assert await client.closed_by_peer()
        finally:
            await client.close()
        again = await RawClient.open(suite.ports["motion"])
        try:
            assert await again.request(Ping()) is not None
        finally:
            await again.close()
        report = await suite.finish()
    fields = rule(report, "client.point-fields")
    assert fields.verdict is Verdict.FAIL and "fits no layout" in fields.detail, report.table()
    order = rule(report, "client.byte-order")
    assert order.verdict is Verdict.FAIL and "plausible in neither byte order" in order.detail, report.table()
    assert verdicts(report)["client.stop-and-wait"] is Verdict.PASS


async def test_a_special_sequence_at_the_same_time_is_judged_not_a_crash() -> None:
    """A JOINT_TRAJ_PT_FULL with a reserved sequence and the previous point's time (no time step to
    imply a speed from): a sequence FAIL, and the connection goes on being served."""
    async with (
        emulator("motoros") as (_, upstream),
        ClientSuite(options("motoros", upstream, inject=frozenset())) as suite,
    ):
        start = await current_position(suite.ports["state"])
        client = await RawClient.open(suite.ports["motion"])
        try:
            fields = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
            for seq in (0, -5):
                point = JointTrajPtFull(0, seq, fields, 0.0, start, (0.0,) * 10)
                assert await client.request(point) is not None
            assert await client.request(Ping()) is not None  # still served
        finally:
            await client.close()
        report = await suite.finish()
    assert verdicts(report)["client.sequence"] is Verdict.FAIL, report.table()


async def test_a_stop_while_a_point_awaits_its_reply_is_not_two_in_flight() -> None:
    """STOP must be sent even while a point waits for its reply (a controller delays the reply when
    its queue is full): stop-and-wait allows it; a point sent while the STOP waits it does not."""
    async with emulator() as (_, upstream), ClientSuite(options("generic", upstream, inject=frozenset())) as suite:
        start = await current_position(suite.ports["state"])
        client = await RawClient.open(suite.ports["motion"])
        try:
            await client.send(JointTrajPt(0, start, velocity=0.1), JointTrajPt(-4))
            assert await client.reply() is not None and await client.reply() is not None
        finally:
            await client.close()
        report = await suite.finish()
    assert verdicts(report)["client.stop-and-wait"] is Verdict.PASS, report.table()


async def test_a_move_with_neither_duration_nor_velocity_is_warned() -> None:
    async with emulator() as (_, upstream), ClientSuite(options("generic", upstream, inject=frozenset())) as suite:
        start = await current_position(suite.ports["state"])
        client = await RawClient.open(suite.ports["motion"])
        try:
            moved = (start[0] + 0.01, *start[1:])
            for point in (JointTrajPt(0, start, velocity=0.1), JointTrajPt(1, moved)):
                assert await client.request(point) is not None
        finally:
            await client.close()
        report = await suite.finish()
    fields = rule(report, "client.point-fields")
    assert fields.verdict is Verdict.WARN and "neither a duration nor a velocity" in fields.detail, report.table()


async def test_a_controller_that_does_not_start_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    broken = [sys.executable, "-c", "import sys; print('no such model: puma', file=sys.stderr); sys.exit(2)"]
    monkeypatch.setattr(ClientSuite, "command", lambda self: broken)
    suite = ClientSuite(options("generic", None))
    with pytest.raises(RuntimeError, match=r"exited without a ready line.*no such model: puma"):
        await asyncio.wait_for(suite.start(), TIMEOUT)
    assert suite._process is not None and suite._process.returncode == 2
    await suite.finish()


# -- the run, the options -----------------------------------------------------------------------------


async def test_run_ends_after_the_linger_and_says_what_was_not_exercised() -> None:
    """A client that only pings: the run ends by itself once it left, and the rules that saw nothing
    say what the client should have done."""
    ports: dict[str, int] = {}
    ready = asyncio.Event()

    def on_ready(given: dict[str, int]) -> None:
        ports.update(given)
        ready.set()

    async def pinger() -> None:
        await asyncio.wait_for(ready.wait(), TIMEOUT)
        client = await RawClient.open(ports["motion"])
        try:
            assert await client.request(Ping()) is not None
        finally:
            await client.close()

    async with emulator() as (_, upstream):
        task = asyncio.create_task(pinger())
        run = run_client_suite(options("generic", upstream, linger=0.1), on_ready=on_ready)
        report = await asyncio.wait_for(run, TIMEOUT)
        await asyncio.wait_for(task, TIMEOUT)
    assert set(ports) == {"motion", "state"}
    assert report.suite == "client" and report.exit_code == 0
    assert verdicts(report)["client.byte-order"] is Verdict.PASS
    skipped = {r.rule: r.detail for r in report.results if r.verdict is Verdict.SKIP}
    assert "stream or download a trajectory" in skipped["client.sequence"]
    assert "second trajectory" in skipped["client.failure-reaction"]
    assert "third one" in skipped["client.reconnect"]


async def test_run_ends_after_its_duration() -> None:
    async with emulator() as (_, upstream):
        report = await asyncio.wait_for(run_client_suite(options("generic", upstream, duration=0.2)), TIMEOUT)
    assert all(r.verdict is Verdict.SKIP for r in report.results)


async def test_run_ends_when_told_to_stop() -> None:
    stop = asyncio.Event()
    async with emulator() as (_, upstream):
        report = await asyncio.wait_for(
            run_client_suite(options("generic", upstream), on_ready=lambda _: stop.set(), stop=stop), TIMEOUT
        )
    assert all(r.verdict is Verdict.SKIP for r in report.results)
    assert "connect and send something" in rule(report, "client.byte-order").detail


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"profile": "kuka"}, "supported: abb, fanuc, generic, motoros"),
        ({"io_port": 0}, "no IO port"),
        ({"byte_order": "middle"}, "byte_order"),
        ({"inject": frozenset({"busy", "smoke"})}, "unknown injection 'smoke'"),
        ({"start_tolerance": 0.0}, "start_tolerance"),
        ({"motion_port": 70000}, "motion_port"),
        ({"linger": -1.0}, "linger"),
        ({"duration": 0.0}, "duration"),
        ({"upstream": {"motion": ("127.0.0.1", 1)}}, "state"),
        ({"upstream": {"motion": ("127.0.0.1", 1), "state": ("127.0.0.1", 0)}}, "upstream['state']"),
    ],
)
def test_bad_options_are_refused_with_a_clear_message(changes: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        ClientSuite(ClientSuiteOptions(**changes))


def test_the_spawned_controller_plays_the_profile() -> None:
    def command(profile: str, **changes: Any) -> list[str]:
        return ClientSuite(ClientSuiteOptions(profile=profile, **changes)).command()

    generic = command("generic")
    assert generic[:3] == [sys.executable, "-m", "robot_server"]
    assert generic[3:] == [
        "--profile",
        "generic",
        "--motion-port",
        "0",
        "--state-port",
        "0",
        "--byte-order",
        "little",
        "--no-stdin",
    ]
    for vendor in ("abb", "fanuc", "staubli"):  # played by the emulator's profile of the same name
        assert command(vendor)[3:5] == ["--profile", vendor] and "--reply-style" not in command(vendor)
    motoros = command("motoros", float64=True)
    assert "--io-port" in motoros and "--float64" in motoros
    fanuc = command("fanuc")
    assert fanuc[fanuc.index("--byte-order") + 1] == "big"
