"""Connections that wait for their turn, as in the listen backlog of a one-client controller.

A controller-side server that serves one client at a time (RAPID's, KAREL's, VAL3's) calls accept
only when its last client has gone. A second client's connect still succeeds (the kernel completes
it in the listen backlog) and then nothing reads or answers it until its turn comes. A
:class:`~.endpoints.Server` with ``excess="wait"`` plays that: a connection beyond
its limit is accepted, handed to a :class:`Backlog`, kept unread (what the peer sends meanwhile is
kept, up to ``WAITING_BYTES``, then reading pauses), and served when a connection ends, oldest
first. At most ``MAX_WAITING`` wait; more are closed, as a full backlog refuses;
:meth:`~.endpoints.Server.reset_backlog` closes them all (a server that reopens its socket).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from typing import cast

from .lograte import LogBudget

__all__ = ["MAX_WAITING", "WAITING_BYTES", "Backlog", "Waiting"]

log = logging.getLogger("simple_message.endpoints")

#: connections that may wait for their turn at once
MAX_WAITING = 8
#: what a waiting connection may send before it is read no more (a few messages' worth)
WAITING_BYTES = 64 * 1024


class Waiting(asyncio.Protocol):
    """The protocol of a connection waiting for its turn: what the peer sends is kept (at most
    ``WAITING_BYTES``; then reading pauses), and its end noted, for the connection it becomes."""

    def __init__(self, transport: asyncio.Transport) -> None:
        self.transport = transport
        self.data: list[bytes] = []
        self.size = 0
        self.ended = False
        self.lost = False
        self.paused = False

    def data_received(self, data: bytes) -> None:
        self.data.append(data)
        self.size += len(data)
        if self.size >= WAITING_BYTES and not self.paused:
            self.paused = True
            with contextlib.suppress(NotImplementedError, RuntimeError):
                self.transport.pause_reading()

    def eof_received(self) -> bool:
        self.ended = True
        return True  # kept open: its turn may still come, and what it sent is answered then

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = True

    def resume(self) -> None:
        """Reading resumes (the connection it became reads now)."""
        if self.paused:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                self.transport.resume_reading()


class Backlog:
    """The connections waiting for their turn on one server, oldest first (see the module doc)."""

    def __init__(self, name: str, log_budget: LogBudget) -> None:
        self.name = name
        self._log_budget = log_budget
        self._waiting: deque[Waiting] = deque()

    def __bool__(self) -> bool:
        return bool(self._waiting)

    def __len__(self) -> int:
        return len(self._waiting)

    def add(self, transport: asyncio.BaseTransport, peer: object, limit: int) -> bool:
        """Keep ``transport`` waiting, unread and unanswered (``limit``: the connections its server
        serves at once); False (nothing done) when ``MAX_WAITING`` wait already."""
        self._waiting = deque(w for w in self._waiting if not w.lost)  # gone while they waited
        if len(self._waiting) >= MAX_WAITING:
            return False
        # a socket's (uvloop's is no asyncio.Transport subclass)
        waiting = Waiting(cast(asyncio.Transport, transport))
        transport.set_protocol(waiting)
        self._waiting.append(waiting)
        self._log_budget.log(
            log, logging.INFO, "%s waits: %d connection(s) is the limit, it is served when one ends", peer, limit
        )
        return True

    def next_open(self) -> Waiting | None:
        """The oldest waiting connection still open, taken off (those gone meanwhile are dropped),
        or None."""
        while self._waiting:
            waiting = self._waiting.popleft()
            if not (waiting.lost or waiting.transport.is_closing()):
                return waiting
        return None

    def drop(self) -> int:
        """Close every waiting connection (a server that closes its listening socket resets its
        backlog); returns how many were open."""
        dropped = 0
        while self._waiting:
            waiting = self._waiting.popleft()
            if not (waiting.lost or waiting.transport.is_closing()):
                dropped += 1
            waiting.transport.close()
        return dropped
