"""The pytest plugin as a user meets it: their own test files in a folder outside the checkout, run by
pytest in a process of its own (``pytester``), with only the installed package to provide
``robot_controller``. Their tests pass, fail and time out; the failed ones' reports name the pcapng
files, which exist; and afterwards no controller thread, ``robot-server`` process or port is left.
The examples of docs/testing.md run the same way, each block a test file.
"""

from __future__ import annotations

import json
import os
import re
import socket
import sys
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parent.parent
#: a user's project settings: pytest-asyncio's strict mode (its default), its loop scope said
INI = "[pytest]\nasyncio_default_fixture_loop_scope = function\n"
#: the inner runs: in file order, no cache
OPTIONS = ("-p", "no:randomly", "-p", "no:cacheprovider", "-rA")
#: wall-clock bound of one inner run (s)
RUN_TIMEOUT = 300

USER_TESTS = '''
import asyncio
import json
import os
import socket
import struct
import threading
from pathlib import Path

import pytest

from robot_server.testing import ControllerTimeout, assert_reached
from simple_message import Client
from simple_message.messages import JointTrajPt

TARGET = [0.5, -0.3, 0.4, 0.2, 0.3, -0.5]
SEEN = Path(os.environ["SEEN"])


def seen(*controllers):
    """Note each controller's ports and process for the checks after the run."""
    with SEEN.open("a") as out:
        for ctrl in controllers:
            out.write(json.dumps({"ports": list(ctrl.ports.values()), "pid": ctrl.pid}) + "\\n")


def request(sock, msg_type, body=b""):
    sock.sendall(struct.pack("<4i", 12 + len(body), msg_type, 2, 0) + body)
    (length,) = struct.unpack("<i", sock.recv(4, socket.MSG_WAITALL))
    return struct.unpack("<3i", sock.recv(length, socket.MSG_WAITALL)[:12])


def point(sequence, joints, duration):
    return struct.pack("<i10f2f", sequence, *joints, *[0.0] * (10 - len(joints)), 0.5, duration)


def start_move(sock, ctrl, duration):
    assert request(sock, 11, point(0, list(ctrl.joints), 0.0)) == (11, 3, 1)
    assert request(sock, 11, point(1, TARGET, duration)) == (11, 3, 1)


def test_generic_and_motoros_at_once(robot_controller):
    generic = robot_controller(speedup="step")
    motoros = robot_controller(profile="motoros", speedup="step")
    seen(generic, motoros)
    for ctrl in (generic, motoros):
        with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=5) as sock:
            assert request(sock, 1) == (1, 3, 1)  # PING: SERVICE_REPLY, SUCCESS
    with socket.create_connection((generic.host, generic.motion_port), timeout=5) as sock:
        start_move(sock, generic, 2.0)
        generic.wait_idle(10)
    assert_reached(generic, TARGET, tol=1e-4)


@pytest.mark.parametrize("speedup", ["step", 40])
def test_a_20_s_move(robot_controller, speedup):
    ctrl = robot_controller(speedup=speedup)
    seen(ctrl)
    begin = ctrl.time
    with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=5) as sock:
        start_move(sock, ctrl, 20.0)
        done = ctrl.wait_idle(60)
    assert done - begin >= 20.0  # sped up, the wall time before the move counts 40 times
    assert_reached(ctrl, TARGET, tol=1e-4, settled=True)


@pytest.mark.asyncio
async def test_async_stepped(robot_controller):
    ctrl = await robot_controller(speedup="step")
    seen(ctrl)
    async with Client.tcp(ctrl.host, ctrl.motion_port) as client:
        for sequence, joints, duration in ((0, ctrl.joints, 0.0), (1, TARGET, 20.0)):
            await client.request(JointTrajPt(sequence, joints, 0.5, duration, comm_type=2))
        await ctrl.wait_idle(60)
    assert_reached(ctrl, TARGET, tol=1e-4)


def test_fails_with_two_controllers(robot_controller):
    generic = robot_controller(speedup="step")
    motoros = robot_controller(profile="motoros")
    seen(generic, motoros)
    with socket.create_connection((motoros.host, motoros.motion_port), timeout=5) as sock:
        assert request(sock, 1) == (1, 3, 1)
    assert generic.joints == TARGET, "deliberately"


def test_times_out_in_the_middle_of_a_move(robot_controller):
    ctrl = robot_controller(speedup=5)
    seen(ctrl)
    with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=5) as sock:
        start_move(sock, ctrl, 20.0)
        ctrl.wait_idle(0.5)


@pytest.mark.asyncio
async def test_async_times_out(robot_controller):
    ctrl = await robot_controller(speedup=5)
    seen(ctrl)
    async with Client.tcp(ctrl.host, ctrl.motion_port) as client:
        for sequence, joints, duration in ((0, ctrl.joints, 0.0), (1, TARGET, 20.0)):
            await client.request(JointTrajPt(sequence, joints, 0.5, duration, comm_type=2))
        async with asyncio.timeout(0.2):
            await ctrl.wait_idle(60)


def test_a_process_fails(robot_controller):
    ctrl = robot_controller(process=True, speedup=5)
    seen(ctrl)
    with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=5) as sock:
        start_move(sock, ctrl, 20.0)
        ctrl.fault("estop")
        assert not ctrl.joints, "deliberately"


def test_zz_nothing_is_left():
    threads = [t.name for t in threading.enumerate() if t.name.startswith("robot_controller")]
    assert threads == []
    tasks = Path(f"/proc/{os.getpid()}/task").iterdir()
    children = [child for task in tasks for child in (task / "children").read_text().split()]
    assert children == [], children
    for line in SEEN.read_text().splitlines():
        for port in json.loads(line)["ports"]:
            with socket.socket() as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                probe.bind(("127.0.0.1", port))
'''


def _free(port: int) -> bool:
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as robot-server binds
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.fixture
def project(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch) -> pytest.Pytester:
    """A user's project folder (outside the checkout) with the package installed, nothing else."""
    assert ROOT not in pytester.path.parents
    pytester.makeini(INI)
    bindir = str(Path(sys.executable).parent)  # the commands (robot-client) of this environment
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    return pytester


@pytest.mark.slow
def test_pytest_fixtures_lists_robot_controller(project: pytest.Pytester) -> None:
    result = project.runpytest_subprocess("--fixtures", *OPTIONS, timeout=RUN_TIMEOUT)
    assert result.ret == 0, result.stdout.str()
    result.stdout.fnmatch_lines(["robot_controller -- *robot_server*testing*plugin.py*", "*Start emulated robot*"])


@pytest.mark.slow
@pytest.mark.fixed_ports_allowed(
    "probes whether the ports of the controllers, robot-server processes' too, are free again"
)
def test_a_user_s_tests_pass_fail_time_out_and_leave_nothing_behind(
    project: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = project.path / "seen.jsonl"
    monkeypatch.setenv("SEEN", str(seen))
    project.makepyfile(test_cell=USER_TESTS)
    result = project.runpytest_subprocess(*OPTIONS, timeout=RUN_TIMEOUT)
    out = result.stdout.str()
    result.assert_outcomes(passed=5, failed=4)
    failed = set(re.findall(r"^FAILED test_cell.py::(\w+)", out, re.MULTILINE))
    assert failed == {
        "test_fails_with_two_controllers",
        "test_times_out_in_the_middle_of_a_move",
        "test_async_times_out",
        "test_a_process_fails",
    }, out
    assert "ControllerTimeout: c1: the robot at rest: not within 0.5 s of controller time" in out
    # each failed test's report: a section per controller, naming its capture, which exists
    captures = [Path(p) for p in re.findall(r"^traffic \(pcapng.*?\): (\S+\.pcapng) ", out, re.MULTILINE)]
    assert len(captures) == 5, out
    for capture in captures:
        assert capture.is_file() and capture.stat().st_size > 0, capture
    assert re.search(r"-+ robot_controller c2 -+\nc2: motoros profile, jibot_zxs, in this process", out), out
    assert "robot-server process" in out and "the log's last lines:" in out
    # the passed tests kept nothing
    kept = {p.parent.name for p in project.path.glob("runpytest-*/*/robot_controller") if not p.parent.is_symlink()}
    assert {name[:-1] for name in kept} == {name[:30] for name in failed}, kept  # (pytest's tmp_path names)
    # nothing left: the inner run's last test checked its threads and children; here, the ports and processes
    seen_controllers = [json.loads(line) for line in seen.read_text().splitlines()]
    assert len(seen_controllers) == 10
    for controller in seen_controllers:
        assert all(_free(port) for port in controller["ports"]), controller
        if controller["pid"] is not None:
            assert _gone(controller["pid"]), controller


@pytest.mark.slow
def test_robot_captures_all_keeps_a_passed_test_s_files_and_none_records_no_traffic(project: pytest.Pytester) -> None:
    project.makepyfile(
        test_kept="""
        def test_passes(robot_controller):
            ctrl = robot_controller(speedup="step")
            print("CAPTURE", ctrl.capture_path)
        """
    )
    result = project.runpytest_subprocess("-s", "--robot-captures", "all", *OPTIONS, timeout=RUN_TIMEOUT)
    result.assert_outcomes(passed=1)
    [path] = re.findall(r"CAPTURE (\S+)", result.stdout.str())
    assert Path(path).is_file()
    result = project.runpytest_subprocess("-s", "--robot-captures", "none", *OPTIONS, timeout=RUN_TIMEOUT)
    result.assert_outcomes(passed=1)
    assert "CAPTURE None" in result.stdout.str()


# -- docs/testing.md --------------------------------------------------------------------------------------

#: a ```python block of the page, with the outcome the comment before it announces (else: all pass)
DOC_BLOCK = re.compile(r"(?:<!-- outcome: (?P<outcome>[^>]*) -->\n)?^```python\n(?P<code>.*?)^```\s*$", re.M | re.S)


def doc_blocks() -> list[tuple[str, dict[str, int]]]:
    text = (ROOT / "docs" / "testing.md").read_text(encoding="utf-8")
    blocks = []
    for match in DOC_BLOCK.finditer(text):
        outcome = {}
        if match["outcome"]:
            for item in match["outcome"].split(","):
                key, _, value = item.strip().partition("=")
                outcome[key] = int(value)
        blocks.append((match["code"], outcome))
    return blocks


def test_the_page_has_examples() -> None:
    assert len(doc_blocks()) >= 6


@pytest.mark.slow
@pytest.mark.parametrize("number", range(len(doc_blocks())), ids=lambda n: f"block{n + 1}")
def test_the_examples_of_docs_testing_md_run_as_test_files(project: pytest.Pytester, number: int) -> None:
    code, expected = doc_blocks()[number]
    project.makepyfile(**{f"test_example_{number + 1}": code})
    result = project.runpytest_subprocess(*OPTIONS, timeout=RUN_TIMEOUT)
    outcomes = result.parseoutcomes()
    counted = {key: outcomes.get(key, 0) for key in ("passed", "failed", "errors")}
    wanted = {"passed": 0, "failed": 0, "errors": 0, **expected}
    if not expected:
        wanted["passed"] = counted["passed"] or 1
    assert counted == wanted, result.stdout.str()
    assert counted["passed"] + counted["failed"] >= 1
    if expected.get("failed"):
        [capture] = re.findall(r"^traffic \(pcapng.*?\): (\S+\.pcapng) ", result.stdout.str(), re.MULTILINE)
        assert Path(capture).is_file()
