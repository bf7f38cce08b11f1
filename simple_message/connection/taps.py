"""Taps: what sees a connection's traffic, byte for byte (captures, the live traffic view).

A :class:`Tap` is given to a connection (``Connection(tap=...)``, ``Server.tap``,
``Client(tap=...)``) and is told about each of its connections, one :class:`TapLink` each: that it
opened, every chunk of bytes written to the transport or received from it (before the connection
acts on it: a request comes before the reply it causes), and that it closed. :class:`TapTee` joins
several taps. :class:`TapPoint` is where one connection calls its tap: a tap that raises is logged
once and dropped for that connection, never raised into the I/O; unset, it costs the connection one
``is not None`` per read and write.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

__all__ = ["TapLink", "Tap", "TapTee", "TapPoint", "socket_addresses"]

#: the connection's logger (its name is what the log lines have always shown)
log = logging.getLogger("simple_message.connection")


@dataclass(frozen=True, eq=False)
class TapLink:
    """What a :class:`Tap` is told about one connection (each connection has its own: compared by
    identity). ``local`` and ``peer`` are the socket addresses ``(host, port)`` of a TCP connection
    (IPv4 or IPv6), ``None`` for a serial port, a pty or a memory pair. ``accepted``: the peer
    opened the connection (a server's); else this end did (a client's)."""

    name: str
    local: tuple[str, int] | None
    peer: tuple[str, int] | None
    accepted: bool


class Tap(Protocol):
    """Sees a connection's traffic (``Connection(tap=...)``, ``Server.tap``, ``Client(tap=...)``).
    Called on the event loop; ``time_ns`` is ``time.time_ns()``. Must not block."""

    def opened(self, link: TapLink, time_ns: int) -> None:
        """The connection exists (called once, first)."""

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        """Bytes written to the transport (``outgoing``) or received from it, in order."""

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        """The connection is over (called once, last); ``by_peer``: the peer's input had ended
        (EOF, reset) before this end closed."""


class TapTee:
    """Several taps seen as one: each is told everything, in the order given (e.g. a capture file
    and a live traffic display on the same server)."""

    def __init__(self, taps: Sequence[Tap]) -> None:
        self.taps = tuple(taps)

    def opened(self, link: TapLink, time_ns: int) -> None:
        for tap in self.taps:
            tap.opened(link, time_ns)

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        for tap in self.taps:
            tap.data(link, outgoing, data, time_ns)

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        for tap in self.taps:
            tap.closed(link, by_peer, time_ns)


class TapPoint:
    """Where one connection tells its tap (if any) what happens, in the order it happens.

    ``tap`` is ``None`` until :meth:`open`, once the tap failed, and once :meth:`close` told it the
    connection is over: nothing is told after that.
    """

    __slots__ = ("link", "tap")

    def __init__(self, link: TapLink) -> None:
        #: what the tap is told about this connection
        self.link = link
        self.tap: Tap | None = None

    def open(self, tap: Tap) -> None:
        """Tap the connection from now on (its tap is told it opened)."""
        self.tap = tap
        self._call(tap.opened, self.link, time.time_ns())

    def data(self, outgoing: bool, data: bytes | bytearray | memoryview) -> None:
        """Bytes handed to the transport (``outgoing``) or received from it."""
        tap = self.tap
        if tap is not None:
            self._call(tap.data, self.link, outgoing, bytes(data), time.time_ns())

    def close(self, by_peer: bool) -> None:
        """The connection is over (``by_peer``: the peer's input had ended first); nothing more."""
        tap = self.tap
        if tap is not None:
            self.tap = None  # nothing more: the tap's record of the connection ends here
            self._call(tap.closed, self.link, by_peer, time.time_ns())

    def _call(self, method: Callable[..., None], *args: object) -> None:
        """Call the tap; one that raises is logged once and dropped (never raised into the I/O)."""
        try:
            method(*args)
        except Exception:
            self.tap = None
            log.error("%s: the tap failed and is dropped for this connection", self.link.name, exc_info=True)


def socket_addresses(
    transport: asyncio.BaseTransport,
) -> tuple[tuple[str, int] | None, tuple[str, int] | None]:
    """A TCP transport's local and peer ``(host, port)``; ``(None, None)`` for anything else."""
    sock = transport.get_extra_info("socket")
    if sock is None or sock.family not in (socket.AF_INET, socket.AF_INET6):
        return None, None
    local, peer = transport.get_extra_info("sockname"), transport.get_extra_info("peername")
    if not isinstance(local, tuple) or not isinstance(peer, tuple):
        return None, None
    return (str(local[0]), int(local[1])), (str(peer[0]), int(peer[1]))
