"""One motion client at a time, and what happens when it goes away.

A real controller takes motion from one client: ABB's and Fanuc's servers serve one connection per
port, MotoROS one motion connection. The emulator does the same on every profile, with MotoROS's
rule for the newcomer (``Ros_MotionServer_StartNewConnection``), which also frees the port of a
client that vanished without closing its socket:

* the first client on the motion port owns the motion;
* a new client while the robot is **busy** (moving, points queued, or a download under way) is
  refused: its connection is closed at once, with a log line naming the owner. It may connect
  again once the robot is at rest;
* a new client while the robot is at rest **takes over**: the previous owner's connection is
  closed (logged), and the newcomer owns the motion.

So a second client can never append points to the owner's trajectory, nor stop it. A serial link
(``robot-server --serial``) cannot be dialled again, so it is never closed by this rule: while it is
open it is the motion client and TCP newcomers are refused; a serial link that opens takes the
motion from a TCP owner (whose departure then counts as below).

When the owner goes away (FIN, reset, a frame error, the server closing it) with the robot busy,
the ``on_disconnect`` setting decides (``robot-server --on-disconnect``):

* ``stop`` (the default, MotoROS's behaviour): a controlled stop, jerk-limited, the queue and any
  unfinished download dropped, logged as a warning;
* ``continue``: the queued motion runs to its end (an unfinished download is dropped all the
  same: a trajectory whose end never came cannot run), logged.

Profiles that must do more when the owner is gone (MotoROS ends trajectory mode) add a listener
with :meth:`MotionOwner.when_gone`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from enum import StrEnum

from simple_message.endpoints import Server, Session

from .cell import SAFETY, RobotCell

__all__ = ["MotionOwner", "OnDisconnect"]

log = logging.getLogger(__name__)


class OnDisconnect(StrEnum):
    """What the robot does when its motion client goes away while it is busy."""

    STOP = "stop"
    CONTINUE = "continue"


class MotionOwner:
    """The motion port's one client (see the module doc)."""

    def __init__(self, cell: RobotCell, on_disconnect: OnDisconnect | str = OnDisconnect.STOP) -> None:
        self.cell = cell
        self.on_disconnect = OnDisconnect(on_disconnect)
        #: the session that owns the motion, if any
        self.owner: Session | None = None
        #: newcomers refused because the robot was busy
        self.refused = 0
        self._listeners: list[Callable[[Session], None]] = []

    def install(self, server: Server) -> None:
        """Watch the motion ``server``'s connections."""
        server.on_connect = self._connected
        server.on_disconnect = self._disconnected

    def when_gone(self, listener: Callable[[Session], None]) -> None:
        """Call ``listener(session)`` after the owner went away (and the robot was stopped, if so)."""
        self._listeners.append(listener)

    @property
    def busy(self) -> bool:
        """The robot is moving, has points queued, or is receiving a download."""
        cell = self.cell
        return cell.in_motion or any(g.downloading for g in cell.groups)

    def _connected(self, session: Session) -> None:
        self.cell.sync()  # (a connection's hooks come before any request: the controllers up to now)
        owner = self.owner
        if owner is not None and owner.connection.closed:
            # gone, but its session has not ended yet: what its departure does happens first
            self._disconnected(owner)
            owner = None
        if owner is None:
            self.owner = session
            return
        if not session.connection.is_socket:
            # a serial link opening: it cannot be refused without being lost, so it takes over
            log.info("%s: replaced by a serial link, %s", owner.name, session.name)
            self._disconnected(owner)  # the departure first: a busy robot stops (or runs on)
            self.owner = session
            owner.connection.abort()
            return
        if self.busy or not owner.connection.is_socket:
            self.refused += 1
            session.log(
                log,
                logging.WARNING,
                "refused: %s (one motion client at a time)",
                f"the robot is moving under motion client {owner.name}"
                if owner.connection.is_socket
                else f"serial link {owner.name} is the motion client while it is open",
            )
            session.connection.abort()
            return
        log.info("%s: replaced by a new motion client, %s (the robot is at rest)", owner.name, session.name)
        self._disconnected(owner)  # what its departure does (MotoROS: trajectory mode ends) happens now
        self.owner = session
        owner.connection.abort()

    def _disconnected(self, session: Session) -> None:
        if session is not self.owner:
            return  # a refused newcomer, or an owner already replaced
        self.owner = None
        cell = self.cell
        cell.sync()
        if self.busy:
            if self.on_disconnect is OnDisconnect.STOP:
                duration = cell.stop()
                log.warning(
                    "%s: the motion client left with the robot busy: controlled stop in %.3f s (--on-disconnect stop)",
                    session.name,
                    duration,
                    extra=SAFETY,
                )
            else:
                for group in cell.groups:
                    group.abandon_download("its motion client left before its end")
                if cell.in_motion:
                    log.info(
                        "%s: the motion client left: the queued motion runs on (--on-disconnect continue)",
                        session.name,
                        extra=SAFETY,
                    )
        for listener in self._listeners:
            listener(session)
