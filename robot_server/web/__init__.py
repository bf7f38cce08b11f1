"""A live web view of the emulated controller: ``robot-server --web [HOST:]PORT``.

One page shows the robot in 3D (three.js), per-joint plots of the last seconds (uPlot), STATUS as
lights, the policy, the queues and the clients, the last frames on the wire, and the fault
injector's buttons; its data comes over one WebSocket (docs/web.md). A fleet's view
(:func:`fleet_view`) serves an index of its controllers and each one's page on one port. Beyond
loopback the buttons need a token (:mod:`.access`). It needs aiohttp, the optional ``web`` extra:
``pip install 'simple-message-stack[web]'``.

:mod:`.feed` (what pages are sent), :mod:`.traffic` (the frames) and :mod:`.access` (the token) need
no web server; the servers themselves are imported on first use (:func:`web_view`,
:func:`fleet_view`), so that a missing aiohttp is one clear error.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from .access import TOKEN_ENV, is_loopback, token_url, web_token
from .feed import MAX_RATE, Feed, Page
from .traffic import TrafficTap

if TYPE_CHECKING:
    from ..emulator import Emulator
    from .fleet import FleetView
    from .server import WebView

__all__ = [
    "Feed",
    "Page",
    "TrafficTap",
    "MAX_RATE",
    "TOKEN_ENV",
    "web_view",
    "fleet_view",
    "web_address",
    "web_token",
    "token_url",
    "is_loopback",
    "WebUnavailable",
]


class WebUnavailable(RuntimeError):
    """The web view's web server (aiohttp) is not installed."""


def _unavailable(exc: ImportError) -> WebUnavailable:
    return WebUnavailable(f"the web view needs aiohttp ({exc}): pip install 'simple-message-stack[web]'")


def web_view(
    emulator: Emulator, host: str = "127.0.0.1", port: int = 0, *, rate: float = 30.0, token: str | None = None
) -> WebView:
    """A :class:`~.server.WebView` of ``emulator`` (before it starts); ``token``: what its commands
    need (``None``: none given; beyond loopback one is then made, see :func:`web_token`). Raises
    :class:`WebUnavailable` without aiohttp, ValueError for a token that cannot be one."""
    try:
        from .server import WebView
    except ImportError as exc:
        raise _unavailable(exc) from None
    return WebView(emulator, host, port, rate=rate, token=token)


def fleet_view(
    emulators: Mapping[str, Emulator],
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    rate: float = 30.0,
    token: str | None = None,
    run_as: Callable[[str, Callable[[], str]], str] | None = None,
) -> FleetView:
    """A :class:`~.fleet.FleetView` of ``emulators`` by name (before they start): the index at ``/``,
    each one's page at ``/c/NAME/``. ``token`` as for :func:`web_view`; ``run_as(name, function)``
    runs a page's command as that controller's code. Raises :class:`WebUnavailable` without aiohttp,
    ValueError for a token or a name that cannot be one."""
    try:
        from .fleet import FleetView
    except ImportError as exc:
        raise _unavailable(exc) from None
    return FleetView(emulators, host, port, rate=rate, token=token, run_as=run_as)


def web_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` (an IPv6 host in brackets: ``[::1]:8080``) as ``(host, port)``; the host is
    127.0.0.1 when not given, the port 0..65535 (0: any free one). Raises ValueError."""
    if text.count(":") > 1 and not text.startswith("["):
        raise ValueError(f"an IPv6 host goes in brackets: [{text}]:PORT (e.g. [::1]:8080), not {text!r}")
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host.strip()
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host:
        host = "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"expected [HOST:]PORT (e.g. 8080 or 127.0.0.1:8080), not {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"a port is 0..65535 (0: any free port), not {number}")
    return host, number
