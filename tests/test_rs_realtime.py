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
import resource
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from robot_server.realtime import RealtimeUnavailable, priority_argument, use_realtime

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="SCHED_FIFO is Linux's")

PROBE = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))"

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


def _no_rtprio_limit() -> None:
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))


def _granted_here() -> bool:
    """Whether a child of this process may take a real-time priority."""
    return subprocess.run([sys.executable, "-c", PROBE], check=False, capture_output=True, timeout=30).returncode == 0


def test_the_priority_is_1_to_99() -> None:
    assert [priority_argument(text) for text in ("1", "50", "99")] == [1, 50, 99]
    for text, message in (("0", "1 to 99, not 0"), ("100", "1 to 99, not 100"), ("fast", "not an integer: 'fast'")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            priority_argument(text)


def test_a_refusal_says_what_would_grant_it(monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[tuple[int, int, int]] = []

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        asked.append((pid, policy, param.sched_priority))
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with pytest.raises(RealtimeUnavailable, match=r"refused \(Operation not permitted\): .*CAP_SYS_NICE.*ulimit -r"):
        use_realtime(42)
    assert asked == [(0, os.SCHED_FIFO, 42)]  # this thread, FIFO, the priority asked for

    def invalid(pid: int, policy: int, param: os.sched_param) -> None:
        raise OSError(errno.EINVAL, "Invalid argument")

    monkeypatch.setattr(os, "sched_setscheduler", invalid)
    with pytest.raises(RealtimeUnavailable, match=r"refused \(Invalid argument\)$"):
        use_realtime(42)


def test_a_system_without_sched_fifo_is_told(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delattr(os, "sched_setscheduler")
    with pytest.raises(RealtimeUnavailable, match="no SCHED_FIFO scheduling"):
        use_realtime(10)


async def _serve(args: list[str], lines: int, log: Path, prefix: list[str] | None = None) -> tuple[int, int, str]:
    """Start ``robot-server ARGS`` (under ``prefix``), wait for its ``lines`` ready lines, read its
    main thread's policy and priority, SIGINT it: (policy, priority, log). It must exit 0."""
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            *(prefix or []), sys.executable, "-m", "robot_server", *args, "--no-stdin",
            stdout=asyncio.subprocess.PIPE, stderr=err, preexec_fn=_no_rtprio_limit if prefix else None,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            async with asyncio.timeout(30.0):
                ready = [(await proc.stdout.readline()).decode() for _ in range(lines)]
            assert "ready" in ready[-1], (ready, await asyncio.to_thread(log.read_text))
            policy, priority = os.sched_getscheduler(proc.pid), os.sched_getparam(proc.pid).sched_priority
            proc.send_signal(signal.SIGINT)
            code = await asyncio.wait_for(proc.wait(), 30.0)
            assert code == 0, await asyncio.to_thread(log.read_text)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
    return policy, priority, await asyncio.to_thread(log.read_text)


def _check(policy: int, priority: int, text: str, granted: bool) -> None:
    if granted:
        assert (policy, priority) == (os.SCHED_FIFO, 7)
        assert "running at real-time priority 7 (SCHED_FIFO)" in text
        assert "normal priority" not in text
    else:
        assert (policy, priority) == (os.SCHED_OTHER, 0)
        assert "WARNING" in text and "--realtime-priority 7: refused" in text and "running at normal priority" in text
        assert "CAP_SYS_NICE" in text


@pytest.mark.slow
async def test_a_lone_server_runs_at_the_priority_this_machine_grants(tmp_path: Path) -> None:
    granted = await asyncio.to_thread(_granted_here)
    policy, priority, text = await _serve(
        ["--motion-port", "0", "--state-port", "0", "--realtime-priority", "7"], 1, tmp_path / "lone.log"
    )
    _check(policy, priority, text, granted)


@pytest.mark.slow
async def test_a_fleet_takes_the_priority_for_all_its_controllers(tmp_path: Path) -> None:
    """A process's option, not a controller's: accepted beside ``--fleet`` (a controller's option
    there is refused: test_rs_fleet)."""
    granted = await asyncio.to_thread(_granted_here)
    path = tmp_path / "cell.toml"
    path.write_text(FLEET_FILE)
    policy, priority, text = await _serve(["--fleet", str(path), "--realtime-priority", "7"], 3, tmp_path / "fleet.log")
    _check(policy, priority, text, granted)


@pytest.mark.slow
async def test_refused_it_warns_and_serves_at_normal_priority(tmp_path: Path) -> None:
    """The refusal made for real: the capability out of the child's bounding set and its real-time
    priority limit 0 (where the tests run as root; otherwise the machine refuses it already, and
    the test above checks that)."""
    setpriv = shutil.which("setpriv")
    if setpriv is None or os.geteuid() != 0:
        pytest.skip("needs root and util-linux's setpriv to take CAP_SYS_NICE away (a normal user is refused anyway)")
    policy, priority, text = await _serve(
        ["--motion-port", "0", "--state-port", "0", "--realtime-priority", "7"],
        1,
        tmp_path / "lone.log",
        prefix=[setpriv, "--bounding-set=-sys_nice"],
    )
    _check(policy, priority, text, granted=False)
