"""The requests of one connection that wait for their replies.

:meth:`.Connection.request` sends a SERVICE_REQUEST and waits for the reply its link pairs with it.
:class:`Requests` keeps the caller's future per request: the link's :class:`~..link.Answered`
completes it, its :class:`~..link.Unanswerable` (a reply that cannot answer it: another type,
reply_code INVALID, a malformed body) fails it with :class:`~..errors.UnexpectedReply`, and the end
of the connection fails every one left with :class:`~..errors.ConnectionClosed`. A caller that gives
up (a timeout, a cancel) leaves its request in the link's order, so that its late reply is consumed
and never taken for the next request's. Nothing is ever sent again.
"""

from __future__ import annotations

import asyncio

from ..errors import UnexpectedReply
from ..link import Answered, Link, Request, Unanswerable
from ..messages import Message, type_name

__all__ = ["Requests", "expire"]


class Requests:
    """The futures of one connection's requests that wait for a reply (see the module docstring)."""

    __slots__ = ("futures", "link")

    def __init__(self, link: Link) -> None:
        #: the connection's link, told of the requests given up on
        self.link = link
        self.futures: dict[Request, asyncio.Future[Message]] = {}

    def expect(self, request: Request) -> asyncio.Future[Message]:
        """The future that the reply to ``request`` completes."""
        future: asyncio.Future[Message] = asyncio.get_running_loop().create_future()
        self.futures[request] = future
        return future

    def answered(self, event: Answered) -> None:
        future = self.futures.pop(event.request, None)
        if future is not None and not future.done():
            future.set_result(event.reply)

    def unanswerable(self, event: Unanswerable, name: str) -> None:
        """``event``'s request fails (``name``: the connection's, for the error)."""
        future = self.futures.pop(event.request, None)
        if future is not None and not future.done():
            future.set_exception(
                UnexpectedReply(
                    f"{name}: {event.describe()} cannot answer a {_type_name(event.request.msg_type)} request",
                    event.reply,
                )
            )

    def give_up(self, request: Request) -> None:
        """Its caller no longer waits for ``request``'s reply."""
        # keep its place in the FIFO: a late reply must not go to the next request
        if self.futures.pop(request, None) is not None:
            self.link.abandon(request)

    def fail_all(self, error: BaseException) -> None:
        """The connection is over: every request still waiting fails with ``error``."""
        futures, self.futures = self.futures, {}
        for future in futures.values():
            if not future.done():
                future.set_exception(error)


def expire(future: asyncio.Future[Message]) -> None:
    """The request timer fired: mark the future, so request() can tell a timeout from a cancel."""
    if not future.done():
        future.expired = True  # type: ignore[attr-defined]
        future.cancel()


def _type_name(msg_type: int) -> str:
    return type_name(msg_type) or f"type {msg_type}"
