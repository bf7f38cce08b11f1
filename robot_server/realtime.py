"""Real-time scheduling of the server's event loop (``robot-server --realtime-priority N``).

A controller's interpolation and servo loop runs at a real-time priority on the real thing, and
ros2_control's controller manager asks for the same on Linux: its main loop's thread tries
``SCHED_FIFO`` at priority 50 and, refused, warns and goes on at normal priority
(ros2_control ``controller_manager/src/ros2_control_node.cpp:31-33,120-134``). Here one event loop
runs everything of a server or a fleet (the control loops, the state rounds, the requests, the web
view), so it is asked for, not assumed: at ``SCHED_FIFO`` the loop runs the moment its timer is
due, before any process at normal priority on that CPU (the clients on the same machine, a build,
the kernel's own threads), where at normal priority it waits for its turn. What it cannot beat is
the machine itself (a virtual CPU the hypervisor does not run); and a loop with more work than a
CPU can do keeps that CPU at real-time priority until the kernel's throttling (by default 95 % of
each second) lets others run: size a fleet so it stays well under a core (docs/fleet.md).
"""

from __future__ import annotations

import argparse
import os

__all__ = ["MAX_PRIORITY", "MIN_PRIORITY", "RealtimeUnavailable", "priority_argument", "use_realtime"]

#: the priorities ``SCHED_FIFO`` has on Linux
MIN_PRIORITY = 1
MAX_PRIORITY = 99

#: what to give the process for a real-time priority, said when it was refused
HOW = (
    "the process needs CAP_SYS_NICE (root's) or a real-time priority limit of at least that much "
    "(ulimit -r, rtprio in /etc/security/limits.conf; a container: --ulimit rtprio=N, see docs/deploy.md)"
)


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
    """Put the calling thread (the event loop's: threads it starts later inherit it) on
    ``SCHED_FIFO`` at ``priority``; :class:`RealtimeUnavailable` when the system refuses or has
    no such policy (then nothing changed)."""
    setter = getattr(os, "sched_setscheduler", None)
    policy = getattr(os, "SCHED_FIFO", None)
    if setter is None or policy is None:
        raise RealtimeUnavailable(f"this system has no SCHED_FIFO scheduling ({os.name}: Linux has)")
    try:
        setter(0, policy, os.sched_param(priority))
    except PermissionError as exc:
        raise RealtimeUnavailable(f"refused ({exc.strerror}): {HOW}") from None
    except OSError as exc:  # EINVAL: a priority this kernel does not have
        raise RealtimeUnavailable(f"refused ({exc.strerror})") from None
