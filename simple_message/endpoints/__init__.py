"""Servers and reconnecting clients over TCP and serial links.

:class:`Server` (:mod:`.server`) is what every emulated controller port is built on: per connection
it reads in arrival order and answers every SERVICE_REQUEST exactly once, in order (docs/reference/protocol.md
§11 item 4), whatever the handler does; :mod:`.server` states its rules. Its handlers work with the
connection's :class:`Session` and return what :mod:`.sessions` describes. :class:`Client`
(:mod:`.client`) keeps one connection to a server and reconnects when it is lost. :func:`run` runs a
program on uvloop when it is installed.
"""

from __future__ import annotations

import asyncio
import importlib
import os
from collections.abc import Coroutine
from typing import Any, TypeVar

# The names imported "as" themselves are importable from here too, though not public (__all__): the
# types of a handler's result and of an arrival hook, and what makes a client's connections.
from ..backlog import MAX_WAITING
from .client import Client, ReconnectPolicy
from .client import Connector as Connector
from .server import DEFAULT_FRAME_TIMEOUT, DEFAULT_IDLE_AFTER, Server
from .sessions import NO_REPLY, CloseConnection, Handler, MalformedHandler, Session
from .sessions import ArrivalHook as ArrivalHook
from .sessions import HandlerResult as HandlerResult

__all__ = [
    "Server",
    "Session",
    "Handler",
    "MalformedHandler",
    "Client",
    "CloseConnection",
    "ReconnectPolicy",
    "run",
    "LOOP_VARIABLE",
    "DEFAULT_FRAME_TIMEOUT",
    "DEFAULT_IDLE_AFTER",
    "MAX_WAITING",
    "NO_REPLY",
]

#: ``$SIMPLE_MESSAGE_LOOP``: ``uvloop`` or ``asyncio`` forces :func:`run`'s event loop
LOOP_VARIABLE = "SIMPLE_MESSAGE_LOOP"

_T = TypeVar("_T")


def run(main: Coroutine[Any, Any, _T], *, debug: bool | None = None) -> _T:
    """:func:`asyncio.run` on uvloop's event loop when uvloop is installed (the ``uvloop`` extra), on
    asyncio's own otherwise. ``$SIMPLE_MESSAGE_LOOP=asyncio`` forces asyncio's, ``uvloop`` uvloop's."""
    choice = os.environ.get(LOOP_VARIABLE, "").strip().lower()
    if choice not in ("", "auto", "asyncio", "uvloop"):
        raise ValueError(f"${LOOP_VARIABLE} must be asyncio or uvloop, not {choice!r}")
    if choice != "asyncio":
        try:
            uvloop = importlib.import_module("uvloop")
        except ImportError:
            if choice == "uvloop":
                raise
        else:
            with asyncio.Runner(debug=debug, loop_factory=uvloop.new_event_loop) as runner:
                return runner.run(main)
    return asyncio.run(main, debug=debug)
