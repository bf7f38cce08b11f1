"""The STOP a driver sends after an aborted motion, whatever aborted it.

An abort is often a cancellation (the caller's timeout, Ctrl-C, a task cancelled): the STOP must
still go out, so it runs as its own task, shielded from the cancellation, and bounded by the
driver's own timeouts. :func:`stop_after_abort` waits for it; a stop that could not be sent (a lost
link, no reply in time, a refusal) is logged as a warning, since the robot may still be moving, and
not raised: the abort is what the caller hears about. (A defect in the stop itself is raised.) When
the caller is cancelled while the stop is still under way, the stop goes on as long as the event
loop runs and its outcome is logged when it ends (never an asyncio "exception was never
retrieved"); a loop that ends first cancels it, which is logged too.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Coroutine
from typing import Any

from simple_message.errors import SimpleMessageError

from .errors import DriverError

__all__ = ["stop_after_abort"]

log = logging.getLogger("client.driver")

#: what a stop that could not be sent raises (a lost link, no reply in time, a refusal)
NOT_SENT = (DriverError, SimpleMessageError, TimeoutError)


#: stops whose callers left: held until they end (the event loop keeps only weak references to tasks)
_RUNNING: set[asyncio.Future[None]] = set()


async def stop_after_abort(stop: Coroutine[Any, Any, None], what: str = "STOP") -> None:
    """Run ``stop`` to its end even if the caller is cancelled meanwhile (see the module doc)."""
    task = asyncio.ensure_future(stop)
    try:
        await asyncio.shield(task)
    except asyncio.CancelledError:
        if task.done() and not task.cancelled():
            _outcome(task, what)
        else:  # the caller leaves; the stop goes on, its outcome logged when it ends
            _RUNNING.add(task)
            task.add_done_callback(_RUNNING.discard)
            task.add_done_callback(lambda t: _outcome(t, what))
        raise
    except NOT_SENT as exc:
        _not_sent(exc, what)


def _outcome(task: asyncio.Future[None], what: str) -> None:
    if task.cancelled():
        log.warning("the %s after the abort was cancelled: the robot may still be moving", what)
        return
    exc = task.exception()
    if exc is None:
        return
    if isinstance(exc, NOT_SENT):
        _not_sent(exc, what)
    else:
        log.error("the %s after the abort failed: the robot may still be moving", what, exc_info=exc)


def _not_sent(exc: BaseException, what: str) -> None:
    log.warning("the %s after the abort was not sent (%s): the robot may still be moving", what, exc)
