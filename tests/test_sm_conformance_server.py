"""The conformance server suite: it passes against the emulator in every profile, byte order and
float size, with and without motion, and each deliberately broken server is caught by the rule
named for its defect."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import pytest

from robot_server.emulator import Emulator, EmulatorConfig
from simple_message.conformance import Report, Verdict
from simple_message.conformance.malformed import FANUC_MIN_READ, malformed_cases
from simple_message.conformance.server import ServerSuite, ServerSuiteOptions, run_server_suite
from simple_message.constants import MotoCommand
from simple_message.framing import FrameDecoder
from simple_message.messages import JointTrajPt, JointTrajPtFull, Message, MotoMotionCtrl, decode
from simple_message.wire import BE32, LE32
from tests.brokenservers import BrokenServer

# quick but real: the state topics watched for 1 s, moves of 0.5 s
QUICK: dict[str, Any] = {"observe": 1.0, "move_time": 0.5, "reply_timeout": 1.0, "motion_timeout": 5.0}


def verdicts(report: Report) -> dict[str, Verdict]:
    return {r.rule: r.verdict for r in report.results}


def failed(report: Report) -> str:
    return report.table()


async def against_emulator(profile: str, allow_motion: bool, **config: Any) -> Report:
    """The suite of ``profile`` against the emulator's profile of the same name (the controller it plays)."""
    cfg = EmulatorConfig(profile=profile, motion_port=0, state_port=0, io_port=0, **config)
    async with Emulator(cfg) as emu:
        options = ServerSuiteOptions(
            profile=profile,
            motion_port=emu.ports["motion"],
            state_port=emu.ports["state"],
            io_port=emu.ports.get("io"),
            allow_motion=allow_motion,
            **QUICK,
        )
        return await run_server_suite(options)


EMULATOR_CASES = [
    ("generic", {}),
    ("generic", {"byte_order": "big"}),
    ("generic", {"float64": True}),
    ("abb", {}),
    ("fanuc", {}),
    ("staubli", {}),
    ("motoros", {}),
    ("motoros", {"byte_order": "big"}),
    ("motoros", {"float64": True}),
]


@pytest.mark.slow
@pytest.mark.parametrize(("profile", "config"), EMULATOR_CASES, ids=str)
async def test_passes_against_the_emulator_without_motion(profile: str, config: dict[str, Any]) -> None:
    report = await against_emulator(profile, False, **config)
    seen = verdicts(report)
    assert report.exit_code == 0, failed(report)
    assert Verdict.FAIL not in seen.values()
    # nothing moved: every motion rule skipped for want of --allow-motion
    for rule in ("motion.small-move", "motion.stop", "motion.out-of-limit"):
        assert seen[rule] is Verdict.SKIP
        assert "--allow-motion" in next(r.detail for r in report.results if r.rule == rule)
    for rule in ("framing.byte-order", "framing.body", "state.status"):
        assert seen[rule] is Verdict.PASS, failed(report)
    # RAPID's motion server would stop on a malformed frame: not sent to ABB
    assert seen["malformed.survival"] is (Verdict.SKIP if profile == "abb" else Verdict.PASS), failed(report)
    # the rate is measured on this machine's clock: its jitter may WARN on a loaded one, never FAIL
    assert seen["state.rate"] in (Verdict.PASS, Verdict.WARN)
    order = next(r for r in report.results if r.rule == "framing.byte-order").detail
    assert order.startswith(config.get("byte_order", "big" if profile == "fanuc" else "little"))
    size = next(r for r in report.results if r.rule == "framing.float-size").detail
    assert size.startswith("float64" if config.get("float64") else "float32")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("profile", "config"),
    [
        ("generic", {}),
        ("generic", {"byte_order": "big", "float64": True}),
        ("abb", {}),
        ("fanuc", {}),
        ("staubli", {}),
        ("motoros", {}),
    ],
    ids=str,
)
async def test_passes_against_the_emulator_with_motion(profile: str, config: dict[str, Any]) -> None:
    report = await against_emulator(profile, True, **config)
    seen = verdicts(report)
    assert report.exit_code == 0, failed(report)
    # what the real controllers do, each WARNed with its source: ABB acknowledges the point beyond
    # its limits (its motion task refuses it later); Fanuc's STOP stops nothing, and a short move
    # may be over between two of its STATUS
    known = {"abb": {"motion.out-of-limit"}, "fanuc": {"motion.stop", "motion.in-motion"}}.get(profile, set())
    for rule in ("motion.preconditions", "motion.small-move", "motion.in-motion", "motion.stop", "motion.out-of-limit"):
        expected = (Verdict.PASS, Verdict.WARN) if rule in known else (Verdict.PASS,)
        assert seen[rule] in expected, failed(report)
    if profile == "motoros":
        for rule in ("motoros.traj-mode", "motoros.busy", "motoros.start-position", "motoros.check-motion-ready"):
            assert seen[rule] is Verdict.PASS, failed(report)


async def test_no_motion_is_sent_without_allow_motion() -> None:
    """Every frame the suite sends without --allow-motion: no trajectory point but STOP, no
    MotoROS command but CHECK_MOTION_READY and STOP_MOTION (bursts cut into their frames; the
    malformed cases are checked below)."""
    cfg = EmulatorConfig(profile="motoros", motion_port=0, state_port=0, io_port=0)
    async with Emulator(cfg) as emu:
        options = ServerSuiteOptions(
            profile="motoros",
            motion_port=emu.ports["motion"],
            state_port=emu.ports["state"],
            io_port=emu.ports["io"],
            **QUICK,
        )
        suite = ServerSuite(options)
        report = await suite.run()
    assert report.exit_code == 0, failed(report)
    sent = [f.raw for link in suite.links for f in link.sent]
    messages = [m for raw in sent for m in cut(raw)]
    assert len(messages) > 10
    for msg in messages:
        assert not isinstance(msg, JointTrajPtFull)
        if isinstance(msg, JointTrajPt):
            assert msg.sequence == -4
        if isinstance(msg, MotoMotionCtrl):
            assert msg.command in (MotoCommand.CHECK_MOTION_READY, MotoCommand.STOP_MOTION)


def cut(data: bytes) -> list[Message]:
    """The messages in what the suite sent at once (a burst is several frames)."""
    decoder = FrameDecoder()
    decoder.feed(data)
    out: list[Message] = []
    while (frame := decoder.next_frame()) is not None:
        out.append(decode(frame, LE32))
    return out


def test_the_malformed_cases_carry_no_motion_type() -> None:
    """No case is a motion message, and none is long enough for Fanuc's parser to read as a point
    (it takes any 56 bytes as one, whatever their type, §8.3)."""
    for wire, fmt in ((LE32, "<"), (BE32, ">")):
        for case in malformed_cases(wire):
            if len(case.data) >= 8:
                msg_type = struct.unpack_from(f"{fmt}i", case.data, 4)[0]
                assert msg_type not in (11, 12, 14, 2001, 2016, 65001), case.name
            assert len(case.data) < FANUC_MIN_READ, case.name
    assert len(set(malformed_cases(LE32)[-1].data)) > 10  # the noise is noise


# -- the negative tests: each broken server caught by its rule ------------------------------------------

BROKEN: list[tuple[str, str, bool]] = [
    ("wrong-order-reply", "framing.byte-order", False),
    ("missing-reply", "reply.order", False),
    ("out-of-order", "reply.order", False),
    ("header-only-status", "framing.body", False),
    ("slow-state", "state.rate", False),
    ("moves-beyond-limits", "motion.out-of-limit", True),
]


async def against_broken(defects: frozenset[str], allow_motion: bool, **options: Any) -> Report:
    async with BrokenServer(defects) as server:
        return await run_server_suite(
            ServerSuiteOptions(
                motion_port=server.ports["motion"],
                state_port=server.ports["state"],
                allow_motion=allow_motion,
                **{**QUICK, "reply_timeout": 0.5, **options},
            )
        )


async def test_the_sound_fake_server_passes() -> None:
    """The broken servers' base, with no defect, passes: each negative test's FAIL is its defect's."""
    report = await against_broken(frozenset(), True)
    assert report.exit_code == 0, failed(report)
    assert verdicts(report)["motion.out-of-limit"] is Verdict.PASS


@pytest.mark.parametrize(("defect", "rule", "allow_motion"), BROKEN, ids=[b[0] for b in BROKEN])
async def test_each_broken_server_is_caught_by_its_rule(defect: str, rule: str, allow_motion: bool) -> None:
    report = await against_broken(frozenset({defect}), allow_motion)
    seen = verdicts(report)
    assert seen[rule] is Verdict.FAIL, failed(report)
    assert report.exit_code == 1
    result = next(r for r in report.results if r.rule == rule)
    assert result.evidence, "a FAIL carries its evidence"


async def test_the_wrong_order_reply_is_shown_as_evidence() -> None:
    report = await against_broken(frozenset({"wrong-order-reply"}), False)
    result = next(r for r in report.results if r.rule == "framing.byte-order")
    swapped = [e for e in result.evidence if "big-endian" in e.kind]
    assert swapped and swapped[0].decoded is not None and swapped[0].decoded["name"] == "PING"


async def test_a_server_that_is_not_there_fails_to_connect_and_skips_the_rest() -> None:
    async with BrokenServer() as server:
        port = server.ports["motion"]
    report = await run_server_suite(ServerSuiteOptions(motion_port=port, state_port=port, **QUICK))
    seen = verdicts(report)
    assert seen["connect.state"] is Verdict.FAIL and seen["connect.motion"] is Verdict.FAIL
    assert seen["reply.ping"] is Verdict.SKIP
    assert report.exit_code == 1


def test_options_are_checked() -> None:
    with pytest.raises(ValueError, match="unknown profile"):
        ServerSuiteOptions(profile="kuka")
    with pytest.raises(ValueError, match="matches no rule"):
        ServerSuiteOptions(only=("nothing.*",))
    with pytest.raises(ValueError, match="amplitude"):
        ServerSuiteOptions(amplitude=1.0)
    with pytest.raises(ValueError, match="known message type"):
        ServerSuiteOptions(unknown_type=11)  # JOINT_TRAJ_PT: it could move the robot
    assert ServerSuiteOptions(profile="motoros").ports == {"motion": 50240, "state": 50241, "io": 50242}
    assert ServerSuiteOptions().ports == {"motion": 11000, "state": 11002}


async def test_a_server_of_one_client_at_a_time_survives_the_malformed_frames() -> None:
    """The C++ TcpServer, ABB's and Fanuc's serve one motion connection at a time (§6): the suite
    frees its own before each case's connection and opens it again after."""
    async with BrokenServer(single_client=True) as server:
        report = await run_server_suite(
            ServerSuiteOptions(motion_port=server.ports["motion"], state_port=server.ports["state"], **QUICK)
        )
    seen = verdicts(report)
    assert seen["malformed.survival"] is Verdict.PASS, failed(report)
    assert report.exit_code == 0, failed(report)


async def test_float64_is_read_from_the_joint_state_not_the_first_frame() -> None:
    async with BrokenServer(status_first=True, real="d") as server:
        report = await run_server_suite(
            ServerSuiteOptions(
                motion_port=server.ports["motion"], state_port=server.ports["state"], float_size=8, **QUICK
            )
        )
    assert report.exit_code == 0, failed(report)
    assert next(r for r in report.results if r.rule == "framing.float-size").detail.startswith("float64")


async def test_a_state_port_gone_silent_stops_the_motion_rules() -> None:
    """No motion is sent on what the suite knew of the robot before its state port went silent, and
    the silence is a gap the rate rule FAILs."""
    async with BrokenServer(frozenset({"state-dies"})) as server:
        report = await run_server_suite(
            ServerSuiteOptions(
                motion_port=server.ports["motion"], state_port=server.ports["state"], allow_motion=True, **QUICK
            )
        )
        moved = server.target is not None or any(server.joints)
    seen = verdicts(report)
    assert seen["state.rate"] is Verdict.FAIL, failed(report)
    assert seen["motion.preconditions"] is Verdict.WARN, failed(report)
    assert seen["motion.small-move"] is Verdict.SKIP and seen["motion.out-of-limit"] is Verdict.SKIP
    assert not moved


async def test_a_server_in_another_byte_order_than_demanded_fails_once() -> None:
    """The suite speaks the order the server speaks: the demanded one FAILs framing.byte-order, and
    the other rules still judge the server."""
    async with BrokenServer(order=">") as server:
        report = await run_server_suite(
            ServerSuiteOptions(
                motion_port=server.ports["motion"], state_port=server.ports["state"], byte_order="little", **QUICK
            )
        )
    failed_rules = [r.rule for r in report.results if r.verdict is Verdict.FAIL]
    assert failed_rules == ["framing.byte-order"], failed(report)


async def test_only_and_skip_choose_the_rules() -> None:
    async with BrokenServer() as server:
        report = await run_server_suite(
            ServerSuiteOptions(
                motion_port=server.ports["motion"],
                state_port=server.ports["state"],
                only=("reply.*",),
                skip=("reply.unknown-topic",),
                **QUICK,
            )
        )
    rules = [r.rule for r in report.results]
    assert len(rules) == len(set(rules)), rules  # each once
    assert set(rules) == {"reply.ping", "reply.order", "reply.unknown-type", "reply.comm-type"}, failed(report)
    # the connections the rules need are made though their own rules were not chosen
    assert all(r.verdict is Verdict.PASS for r in report.results), failed(report)


# -- the command -------------------------------------------------------------------------------------------


def run_command(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run(
        [sys.executable, "-m", "simple_message", "conformance", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        check=False,
    )


def against(ports: dict[str, int], *args: str) -> subprocess.CompletedProcess[str]:
    """``conformance server`` against the emulator's ports."""
    where = ["--motion-port", str(ports["motion"]), "--state-port", str(ports["state"])]
    return run_command("server", "127.0.0.1", *where, *args)


def start_robot_server(*args: str) -> tuple[subprocess.Popen[str], dict[str, int]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "robot_server", "--motion-port", "0", "--state-port", "0", "--no-stdin", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    ports = {}
    for role in ("motion", "state", "io"):
        marker = f"{role} 127.0.0.1:"
        if marker in line:
            ports[role] = int(line.split(marker)[1].split(",")[0].split()[0])
    return proc, ports


def stopped(proc: subprocess.Popen[str]) -> Callable[[], None]:
    def stop() -> None:
        proc.terminate()
        proc.wait(timeout=30)

    return stop


@pytest.mark.slow
def test_the_command_writes_json_and_junit_and_exits_0(tmp_path: Path) -> None:
    proc, ports = start_robot_server("--byte-order", "big")
    try:
        result = against(
            ports,
            "--byte-order",
            "big",
            "--observe",
            "1",
            "--json",
            str(tmp_path / "r.json"),
            "--junit",
            str(tmp_path / "r.xml"),
        )
    finally:
        stopped(proc)()
    assert result.returncode == 0, result.stdout + result.stderr
    assert "PASS  malformed.survival" in result.stdout
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["suite"] == "server" and data["counts"]["FAIL"] == 0
    root = ElementTree.parse(tmp_path / "r.xml").getroot()
    suite = root.find("testsuite")
    assert root.tag == "testsuites" and suite is not None
    assert int(suite.get("tests", "0")) == len(data["results"]) == len(suite.findall("testcase"))


@pytest.mark.slow
def test_the_command_exits_1_on_a_fail_and_names_the_rule() -> None:
    proc, ports = start_robot_server()
    try:
        # the emulator speaks little-endian: demanding big makes framing.byte-order FAIL
        result = against(
            ports,
            "--byte-order",
            "big",
            "--only",
            "framing.*",
            "--only",
            "connect.*",
            "--observe",
            "0.5",
        )
    finally:
        stopped(proc)()
    assert result.returncode == 1, result.stdout + result.stderr
    assert "FAIL  framing.byte-order" in result.stdout


def test_the_command_refuses_bad_options() -> None:
    result = run_command("server", "127.0.0.1", "--only", "nonsense")
    assert result.returncode == 2 and "matches no rule" in result.stderr
    help_text = run_command("server", "--help").stdout
    assert "THE ROBOT WILL MOVE" in help_text.replace("\n", " ").replace("  ", " ")
