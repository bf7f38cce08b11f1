"""The reconnecting client: one connection to a server, kept alive.

:class:`Client` keeps one connection to a server and reconnects with bounded exponential backoff
and jitter (:class:`ReconnectPolicy`) when it is lost. Its state is observable
(:class:`~..connection.ConnectionState`); while it is not connected, requests fail at once with
:class:`~..errors.NotConnected` (nothing is queued, so nothing is sent late); pending requests fail
with :class:`~..errors.ConnectionClosed` the moment the link drops. Subscriptions survive
reconnection.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable
from dataclasses import dataclass
from typing import Any

from ..connection import Connection, ConnectionState, Subscription, Tap
from ..dialects import Dialect, any_dialect_answers
from ..errors import ConnectionClosed, NotConnected
from ..framing import DEFAULT_MAX_LENGTH
from ..messages import Message
from ..transport import StreamPair, open_serial, open_tcp
from ..wire import DEFAULT_FORMAT, WireFormat

__all__ = ["Client", "ReconnectPolicy", "Connector"]

#: the endpoints' logger (its name is what the log lines have always shown)
log = logging.getLogger("simple_message.endpoints")


@dataclass(frozen=True)
class ReconnectPolicy:
    """Bounded exponential backoff with jitter. ``max_attempts=None`` retries for ever."""

    initial_delay: float = 0.1
    max_delay: float = 5.0
    factor: float = 2.0
    jitter: float = 0.2
    max_attempts: int | None = None

    def delay(self, attempt: int, rng: random.Random | None = None) -> float:
        """The wait before reconnection attempt ``attempt`` (1-based), jitter included."""
        base = min(self.max_delay, self.initial_delay * self.factor ** max(0, attempt - 1))
        spread = base * self.jitter
        return max(0.0, base + (rng or random).uniform(-spread, spread))


Connector = Callable[[], Awaitable[StreamPair]]


class Client:
    """A client that keeps one connection alive and reconnects (see the module docstring)."""

    def __init__(
        self,
        connector: Connector,
        wire: WireFormat = DEFAULT_FORMAT,
        *,
        name: str = "client",
        reconnect: ReconnectPolicy | None = ReconnectPolicy(),
        max_length: int = DEFAULT_MAX_LENGTH,
        drain_timeout: float = 5.0,
        dialect: Dialect | None = None,
        tap: Tap | None = None,
    ) -> None:
        self._connector = connector
        #: sees the traffic of every connection the client makes (:class:`~.connection.Tap`)
        self.tap = tap
        #: the server's dialect (which replies answer which requests); None: any dialect's
        self.dialect = dialect
        self.wire = wire
        self.name = name
        self.reconnect = reconnect
        self.max_length = max_length
        self.drain_timeout = drain_timeout
        self.connection: Connection | None = None
        self.subscriptions: list[Subscription] = []
        self._state = ConnectionState.CONNECTING
        self._changed = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._closing = False
        self.attempts = 0
        self.connects = 0
        #: Why the last connection attempt or connection failed.
        self.last_error: BaseException | None = None
        self._refused_ends = False

    @classmethod
    def tcp(cls, host: str, port: int, wire: WireFormat = DEFAULT_FORMAT, **kwargs: Any) -> Client:
        return cls(lambda: open_tcp(host, port), wire, name=kwargs.pop("name", f"{host}:{port}"), **kwargs)

    @classmethod
    def serial(cls, url: str, wire: WireFormat = DEFAULT_FORMAT, **kwargs: Any) -> Client:
        options = kwargs.pop("serial_options", {})
        return cls(lambda: open_serial(url, **options), wire, name=kwargs.pop("name", url), **kwargs)

    # -- state -------------------------------------------------------------------------------------

    @property
    def state(self) -> ConnectionState:
        return self._state

    def _set_state(self, state: ConnectionState) -> None:
        if state is not self._state:
            log.info("%s: %s", self.name, state.value)
            self._state = state
            self._changed.set()
            self._changed = asyncio.Event()

    async def wait_for(self, state: ConnectionState, timeout: float | None = None) -> None:
        """Wait until the client is in ``state``; raises TimeoutError after ``timeout`` s."""
        async with asyncio.timeout(timeout):
            while self._state is not state:
                if self._state is ConnectionState.CLOSED:
                    raise ConnectionClosed(f"{self.name}: closed ({self.last_error})")
                await self._changed.wait()

    async def states(self) -> AsyncIterator[ConnectionState]:
        """Yields the current state, then every change, until CLOSED."""
        state = self._state
        yield state
        while state is not ConnectionState.CLOSED:
            await self._changed.wait()
            state = self._state
            yield state

    @property
    def closing(self) -> bool:
        """True once :meth:`close` was called (checked after every await of the supervisor)."""
        return self._closing

    # -- lifecycle ---------------------------------------------------------------------------------

    async def start(self, timeout: float | None = 10.0, *, refused_ends: bool = False) -> Client:
        """Connect, and keep reconnecting in the background. Waits for the first connection.
        ``refused_ends``: if the very first attempt is refused (nothing listens there), give up at
        once with :class:`ConnectionClosed` (its ``last_error`` the refusal) instead of retrying
        until ``timeout``: what a command a user just typed wants."""
        self._refused_ends = refused_ends
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run(), name=f"sm-client {self.name}")
        await self.wait_for(ConnectionState.CONNECTED, timeout)
        return self

    async def __aenter__(self) -> Client:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        """Close the connection and stop reconnecting (cancels a pending backoff wait)."""
        self._closing = True
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self.connection is not None:
            await self.connection.close()
        for sub in self.subscriptions:
            sub.close()
        self._set_state(ConnectionState.CLOSED)

    async def _run(self) -> None:
        failures = 0
        try:
            while not self._closing:
                try:
                    self.attempts += 1
                    streams = await self._connector()
                except (OSError, TimeoutError) as exc:
                    self.last_error = exc
                    failures += 1
                    log.info("%s: connection attempt %d failed: %s", self.name, failures, exc)
                    if self._refused_ends and self.connects == 0 and isinstance(exc, ConnectionRefusedError):
                        break
                else:
                    failures = 0
                    self.connects += 1
                    conn = Connection(
                        streams,
                        self.wire,
                        max_length=self.max_length,
                        name=self.name,
                        subscriptions=self.subscriptions,
                        drain_timeout=self.drain_timeout,
                        answers=self.dialect.answers if self.dialect is not None else any_dialect_answers,
                        tap=self.tap,
                    )
                    self.connection = conn.start()
                    self._set_state(ConnectionState.CONNECTED)
                    await conn.wait_closed()
                    self.last_error = conn.close_reason
                    failures = 1
                if self.closing:
                    break
                if self.reconnect is None or (
                    self.reconnect.max_attempts is not None and failures > self.reconnect.max_attempts
                ):
                    break
                self._set_state(ConnectionState.RECONNECTING)
                await asyncio.sleep(self.reconnect.delay(failures))
        finally:
            if not self._closing:
                self._set_state(ConnectionState.CLOSED)

    # -- traffic -----------------------------------------------------------------------------------

    def _live(self) -> Connection:
        conn = self.connection
        if conn is None or conn.closed or self._state is not ConnectionState.CONNECTED:
            raise NotConnected(f"{self.name}: not connected ({self._state.value})")
        return conn

    async def request(self, msg: Message, timeout: float | None = 5.0) -> Message:
        """See :meth:`Connection.request`; raises NotConnected at once while disconnected."""
        return await self._live().request(msg, timeout)

    async def send(self, msg: Message) -> None:
        await self._live().send(msg)

    def subscribe(self, maxsize: int = 256, msg_types: Iterable[int] | None = None) -> Subscription:
        """A bounded subscription to received topics that lasts across reconnections."""
        sub = Subscription(maxsize, msg_types)
        self.subscriptions.append(sub)
        return sub
