"""Where a connection's received messages go: bounded subscriptions, and its inbox.

A :class:`Subscription` is a bounded stream of received messages (topics, and requests on a server).
A subscriber that does not keep up loses its *oldest* messages, and the loss is counted
(:attr:`Subscription.dropped`): it never blocks the reader or grows memory. :class:`Subscribers` is
one connection's fan-out: every subscription that wants a message gets it, and so does the inbox
that iterating the connection opens. A reconnecting client hands its own list of subscriptions to
each connection it makes, so they outlive one connection.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from collections.abc import AsyncIterator, Iterable

from ..errors import ConnectionClosed
from ..messages import Message

__all__ = ["Subscription", "Subscribers"]


class Subscription:
    """A bounded stream of received messages (topics, and requests on a server).

    Iterate with ``async for``, or call :meth:`get` with a timeout. When full, the oldest message is
    dropped and :attr:`dropped` counts it.
    """

    def __init__(self, maxsize: int = 256, msg_types: Iterable[int] | None = None) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self.maxsize = maxsize
        self.msg_types = frozenset(msg_types) if msg_types is not None else None
        self.dropped = 0
        self.received = 0
        self._items: deque[Message] = deque(maxlen=maxsize)
        self._event = asyncio.Event()
        self._closed = False

    def wants(self, msg: Message) -> bool:
        return self.msg_types is None or msg.msg_type in self.msg_types

    def put(self, msg: Message) -> None:
        if self._closed:
            return
        if len(self._items) == self.maxsize:
            self.dropped += 1
        self._items.append(msg)
        self.received += 1
        self._event.set()

    def __len__(self) -> int:
        return len(self._items)

    def get_nowait(self) -> Message | None:
        return self._items.popleft() if self._items else None

    async def get(self, timeout: float | None = None) -> Message:
        """The next message; raises :class:`TimeoutError` after ``timeout`` s, or
        :class:`~.errors.ConnectionClosed` once the subscription is closed and drained."""
        async with asyncio.timeout(timeout):
            while not self._items:
                if self._closed:
                    raise ConnectionClosed("subscription closed")
                self._event.clear()
                await self._event.wait()
        return self._items.popleft()

    def close(self) -> None:
        self._closed = True
        self._event.set()

    @property
    def closed(self) -> bool:
        return self._closed

    def __aiter__(self) -> AsyncIterator[Message]:
        return self

    async def __anext__(self) -> Message:
        try:
            return await self.get()
        except ConnectionClosed:
            raise StopAsyncIteration from None


class Subscribers:
    """The subscriptions of one connection and its inbox (see the module docstring)."""

    __slots__ = ("inbox", "subscriptions")

    def __init__(self, subscriptions: list[Subscription] | None = None) -> None:
        #: shared with a reconnecting client, so subscriptions outlive one connection
        self.subscriptions: list[Subscription] = subscriptions if subscriptions is not None else []
        #: every message that is not a reply, from the first iteration of the connection on
        self.inbox: Subscription | None = None

    def deliver(self, msg: Message) -> None:
        """Give ``msg`` to every subscription that wants it, and to the inbox."""
        for sub in self.subscriptions:
            if sub.wants(msg):
                sub.put(msg)
        if self.inbox is not None:
            self.inbox.put(msg)

    def add(self, maxsize: int = 256, msg_types: Iterable[int] | None = None) -> Subscription:
        """A new subscription (``msg_types``: only these types)."""
        sub = Subscription(maxsize, msg_types)
        self.subscriptions.append(sub)
        return sub

    def remove(self, sub: Subscription) -> None:
        """End ``sub`` (it is closed, whether it was one of these or not)."""
        with contextlib.suppress(ValueError):
            self.subscriptions.remove(sub)
        sub.close()

    def open_inbox(self, closed: bool) -> Subscription:
        """The inbox, made on first use: bounded to 1024, closed at once if the connection is."""
        if self.inbox is None:
            self.inbox = Subscription(1024)
            if closed:
                self.inbox.close()
        return self.inbox

    def close(self) -> None:
        """The connection is over: the inbox ends (subscriptions are the subscribers' own)."""
        if self.inbox is not None:
            self.inbox.close()
