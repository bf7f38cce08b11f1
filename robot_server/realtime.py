"""Real-time scheduling of the server's event loop (``robot-server --realtime-priority N``).

A controller's interpolation and servo loop runs at a real-time priority on the real thing, and
ros2_control's controller manager asks for one on Linux: its update loop's own thread tries
``SCHED_FIFO`` at priority 50 and, refused, warns and goes on at normal priority
(ros2_control 53b9999, ``controller_manager/src/ros2_control_node.cpp:31-33,120-134``; it also
locks memory on a real-time kernel, and serves requests from other threads at normal priority).
Here one event loop runs everything of a server or a fleet: the control loops, the state rounds,
every request and the web view. So it is asked for, never assumed, and what it costs is said:

* at ``SCHED_FIFO`` the loop runs the moment its timer is due, before any process at normal
  priority on that CPU (the clients on the same machine, a build, the kernel's own threads), where
  at normal priority it waits for its turn;
* while it is busy it keeps that CPU from all of them, whatever keeps it busy: more controllers
  than a CPU can run, a large ``--speedup``, or a flood of requests from whoever reaches its
  ports (simple_message has no authentication). The kernel's throttling (by default 95 % of each
  second, ``/proc/sys/kernel/sched_rt_runtime_us``; none when it is -1) is then all that lets
  the others run: keep a fleet well under a core;
* only the calling thread (the event loop's) and the threads it starts later are real-time:
  those started before (numpy's BLAS pool, uvloop's resolver threads) stay at normal priority,
  and a child process starts at normal priority (``SCHED_RESET_ON_FORK``);
* it cannot beat the machine: a virtual CPU the hypervisor does not run stalls it all the same.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys

__all__ = [
    "MAX_PRIORITY",
    "MIN_PRIORITY",
    "RealtimeUnavailable",
    "normal_priority",
    "priority_argument",
    "use_realtime",
]

#: the priorities ``SCHED_FIFO`` has on Linux (other systems are checked when asked)
MIN_PRIORITY = 1
MAX_PRIORITY = 99

#: what to give the process for a real-time priority, said when it was refused
HOW = (
    "the process needs CAP_SYS_NICE (root's) or a real-time priority limit of at least that much "
    "(ulimit -r, rtprio in /etc/security/limits.conf; a container: --ulimit rtprio=N, see docs/deploy.md)"
)
#: said instead when the process has CAP_SYS_NICE and is refused all the same
BUDGET = (
    "the process has CAP_SYS_NICE: its control group has no real-time budget (cgroup v1's "
    "cpu.rt_runtime_us is 0 there; a container: --cpu-rt-runtime, see docs/deploy.md)"
)
#: CAP_SYS_NICE's bit in /proc/self/status's CapEff
_CAP_SYS_NICE = 23


class RealtimeUnavailable(Exception):
    """The real-time priority asked for was not given; the message says why and what would give it."""


def priority_argument(text: str) -> int:
    """``argparse`` type of ``--realtime-priority``: an integer from 1 to 99."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not MIN_PRIORITY <= value <= MAX_PRIORITY:
        raise argparse.ArgumentTypeError(f"a SCHED_FIFO priority is {MIN_PRIORITY} to {MAX_PRIORITY}, not {value}")
    return value


def use_realtime(priority: int) -> None:
    """Put the calling thread (the event loop's: threads it starts later inherit it, child
    processes do not) on ``SCHED_FIFO`` at ``priority``; :class:`RealtimeUnavailable` when the
    system refuses or has no such policy (then nothing changed)."""
    setter = getattr(os, "sched_setscheduler", None)
    policy = getattr(os, "SCHED_FIFO", None)
    if setter is None or policy is None:
        raise RealtimeUnavailable(f"this system ({sys.platform}) has no SCHED_FIFO scheduling")
    low, high = os.sched_get_priority_min(policy), os.sched_get_priority_max(policy)
    if not low <= priority <= high:
        raise RealtimeUnavailable(f"this system's SCHED_FIFO priorities are {low} to {high}")
    try:
        setter(0, policy | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
    except PermissionError as exc:
        raise RealtimeUnavailable(f"refused ({exc.strerror}): {BUDGET if _has_sys_nice() else HOW}") from None
    except OSError as exc:
        raise RealtimeUnavailable(f"refused ({exc.strerror})") from None


def normal_priority() -> None:
    """Put the calling thread back on normal scheduling (``SCHED_OTHER``), as :func:`use_realtime`
    found it: what follows the event loop (records written, the interpreter's exit) needs no
    real-time priority. Does nothing where there is no such call."""
    setter = getattr(os, "sched_setscheduler", None)
    if setter is not None:  # keeping the reset-on-fork flag: only a privileged thread may clear it
        with contextlib.suppress(OSError):
            setter(0, os.SCHED_OTHER | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(0))


def _has_sys_nice() -> bool:
    """Whether this process has CAP_SYS_NICE in effect (Linux's /proc; ``False`` if unknown)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> _CAP_SYS_NICE & 1)
    except (OSError, ValueError):
        pass
    return False
