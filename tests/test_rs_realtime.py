"""``--realtime-priority``: the event loop at SCHED_FIFO when the system grants it, a warning and
normal priority when it does not (as ros2_control's controller manager), for a lone server and a
fleet. The servers run as real processes; whether this machine grants a real-time priority is
asked of a throwaway child first, and the refused case is also made for real with ``setpriv``
(the capability taken away) where that is possible."""

from __future__ import annotations

import argparse
import asyncio
import errno
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from robot_server import realtime
from robot_server.realtime import RealtimeUnavailable, normal_priority, priority_argument, use_realtime

linux_only = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="SCHED_FIFO scheduling is Linux's")

#: the priority the processes ask for, and a child's try of it
PRIORITY = 7
PROBE = f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({PRIORITY}))"
#: SCHED_RESET_ON_FORK, which a granted thread's policy carries
RESET = getattr(os, "SCHED_RESET_ON_FORK", 0)

FLEET_FILE = """
[[controller]]
name = "r1"
profile = "generic"
motion_port = 0
state_port = 0

[[controller]]
name = "r2"
profile = "abb"
motion_port = 0
state_port = 0
"""


def _granted_here(prefix: list[str] | None = None) -> bool:
    """Whether a child of this process (under ``prefix``) may take a real-time priority."""
    run = subprocess.run([*(prefix or []), sys.executable, "-c", PROBE], check=False, capture_output=True, timeout=30)
    return run.returncode == 0


def test_the_priority_is_1_to_99() -> None:
    assert [priority_argument(text) for text in ("1", "50", "99")] == [1, 50, 99]
    for text, message in (("0", "1 to 99, not 0"), ("100", "1 to 99, not 100"), ("fast", "not an integer: 'fast'")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            priority_argument(text)


@linux_only
def test_a_refusal_says_what_would_grant_it(monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[tuple[int, int, int]] = []

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        asked.append((pid, policy, param.sched_priority))
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime, "_has_sys_nice", lambda: False)
    with pytest.raises(RealtimeUnavailable, match=r"refused \(Operation not permitted\): .*CAP_SYS_NICE.*ulimit -r"):
        use_realtime(42)
    assert asked == [(0, os.SCHED_FIFO | RESET, 42)]  # this thread, FIFO (children not), the priority asked for
    # a process that has the capability and is refused all the same: its control group's budget
    monkeypatch.setattr(realtime, "_has_sys_nice", lambda: True)
    with pytest.raises(RealtimeUnavailable, match=r"has CAP_SYS_NICE: its control group has no real-time budget"):
        use_realtime(42)
    # a priority beyond this system's range is told with the range, nothing asked
    monkeypatch.setattr(os, "sched_get_priority_max", lambda policy: 31)
    with pytest.raises(RealtimeUnavailable, match=r"SCHED_FIFO priorities are \d+ to 31"):
        use_realtime(42)
    assert len(asked) == 2

    def invalid(pid: int, policy: int, param: os.sched_param) -> None:
        raise OSError(errno.EINVAL, "Invalid argument")

    monkeypatch.setattr(os, "sched_setscheduler", invalid)
    with pytest.raises(RealtimeUnavailable, match=r"refused \(Invalid argument\)$"):
        use_realtime(20)


def test_a_system_without_sched_fifo_is_told(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delattr(os, "sched_setscheduler", raising=False)
    with pytest.raises(RealtimeUnavailable, match=rf"this system \({sys.platform}\) has no SCHED_FIFO scheduling"):
        use_realtime(10)
    normal_priority()  # nothing to undo there: no error


@linux_only
def test_granted_it_is_undone_and_not_inherited(tmp_path: Path) -> None:
    """In a child (this test process keeps its own scheduling): granted, the thread is FIFO, a
    process it starts is not (reset on fork), and normal_priority puts it back."""
    if not _granted_here():
        pytest.skip("this machine grants no real-time priority to this user (the refusal is tested above)")
    script = f"""
import os, subprocess, sys
from robot_server.realtime import normal_priority, use_realtime
use_realtime({PRIORITY})
print(os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
child = subprocess.run([sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"], capture_output=True)
print(child.stdout.decode().strip())
normal_priority()
print(os.sched_getscheduler(0) & ~{RESET}, os.sched_getparam(0).sched_priority)
"""
    out = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, timeout=60).stdout.decode()
    assert out.split("\n")[:3] == [f"{os.SCHED_FIFO | RESET} {PRIORITY}", str(os.SCHED_OTHER), f"{os.SCHED_OTHER} 0"]


async def _serve(args: list[str], lines: int, log: Path, prefix: list[str] | None = None) -> tuple[int, int, str]:
    """Start ``robot-server ARGS`` (under ``prefix``), wait for its ``lines`` ready lines, read its
    main thread's policy and priority and the log written by then (the priority is settled before
    the ready lines), SIGINT it: (policy, priority, log). It must exit 0."""
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            *(prefix or []), sys.executable, "-m", "robot_server", *args, "--no-stdin",
            stdout=asyncio.subprocess.PIPE, stderr=err,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            async with asyncio.timeout(30.0):
                ready = [(await proc.stdout.readline()).decode() for _ in range(lines)]
            text = await asyncio.to_thread(log.read_text)
            assert "ready" in ready[-1], (ready, text)
            policy, priority = os.sched_getscheduler(proc.pid), os.sched_getparam(proc.pid).sched_priority
            proc.send_signal(signal.SIGINT)
            code = await asyncio.wait_for(proc.wait(), 30.0)
            assert code == 0, await asyncio.to_thread(log.read_text)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
    return policy, priority, text


def _check(policy: int, priority: int, text: str, granted: bool) -> None:
    if granted:
        assert (policy, priority) == (os.SCHED_FIFO | RESET, PRIORITY)
        assert f"running at real-time priority {PRIORITY} (SCHED_FIFO)" in text
        assert "normal priority" not in text
    else:
        assert (policy, priority) == (os.SCHED_OTHER, 0)
        assert "WARNING" in text and f"--realtime-priority {PRIORITY}: refused" in text
        assert "running at normal priority" in text and "CAP_SYS_NICE" in text


@linux_only
@pytest.mark.slow
async def test_a_lone_server_runs_at_the_priority_this_machine_grants(tmp_path: Path) -> None:
    granted = await asyncio.to_thread(_granted_here)
    policy, priority, text = await _serve(
        ["--motion-port", "0", "--state-port", "0", "--realtime-priority", str(PRIORITY)], 1, tmp_path / "lone.log"
    )
    _check(policy, priority, text, granted)


@linux_only
@pytest.mark.slow
async def test_a_fleet_takes_the_priority_for_all_its_controllers(tmp_path: Path) -> None:
    """A process's option, not a controller's: accepted beside ``--fleet`` (a controller's option
    there is refused: test_rs_fleet)."""
    granted = await asyncio.to_thread(_granted_here)
    path = tmp_path / "cell.toml"
    path.write_text(FLEET_FILE)
    policy, priority, text = await _serve(
        ["--fleet", str(path), "--realtime-priority", str(PRIORITY)], 3, tmp_path / "fleet.log"
    )
    _check(policy, priority, text, granted)


@linux_only
@pytest.mark.slow
async def test_refused_it_warns_and_serves_at_normal_priority(tmp_path: Path) -> None:
    """The refusal made for real: the child's real-time limit 0 (prlimit) and CAP_SYS_NICE out of
    its bounding set (setpriv), checked to refuse the probe first (setpriv without CAP_SETPCAP
    leaves the capability there). As a normal user the machine refuses it already: the test
    above checks that."""
    prlimit, setpriv = shutil.which("prlimit"), shutil.which("setpriv")
    if prlimit is None or setpriv is None:
        pytest.skip("needs util-linux's prlimit and setpriv to take the privilege away")
    prefix = [prlimit, "--rtprio=0", setpriv, "--bounding-set=-sys_nice"]
    if await asyncio.to_thread(_granted_here, prefix):
        pytest.skip("prlimit and setpriv could not take the real-time privilege away here")
    policy, priority, text = await _serve(
        ["--motion-port", "0", "--state-port", "0", "--realtime-priority", str(PRIORITY)],
        1,
        tmp_path / "lone.log",
        prefix=prefix,
    )
    _check(policy, priority, text, granted=False)
