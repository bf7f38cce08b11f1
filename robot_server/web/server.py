"""The web view's HTTP server: one controller's page, its static files and its WebSocket, on the
emulator's loop.

:class:`ControllerView` is one emulator's page (``index.html``, whose addresses are all relative, so
that it works at ``/`` and under a fleet's ``/c/NAME/``) and its WebSocket (``ws`` beside it). While
at least one of its pages is open, a sampling task calls :meth:`.Feed.sample` ``rate`` times a second
on absolute deadlines, just after a round of state topics; each page's own task sends it the update
made from that sample, so a page that reads slowly delays only itself (its updates are skipped while
a send is under way; aiohttp bounds what it buffers). While none is open, nothing of the view runs:
no task, no hook on the state rounds, no listener on the accepted points (the traffic tap stays on
the servers: it frames the bytes of each connection from its start).

:class:`WebView` serves one controller (``robot-server --web``): ``/`` (the page), ``/static/`` (its
scripts, with three.js and uPlot shipped inside the package: the page needs no internet) and
``/ws``. :class:`~.fleet.FleetView` serves many on one port.

A page sends ``{"type": "command", "command": "estop"}`` (the fault commands of stdin, through
:meth:`~robot_server.emulator.Emulator.command`) and is answered ``{"type": "result", ...}``; a page
without the web view's token, where one is needed (:mod:`.access`), is read-only and its commands are
refused before they reach the robot. Input is bounded: a message longer than :data:`MAX_MESSAGE`
closes that page's socket, more than :data:`COMMAND_BURST` commands within a second are refused,
anything else malformed is answered with an error; none of it reaches the robot or the other pages.
A WebSocket opened by a page of another site (its ``Origin`` names another host than the request's
``Host``, or, on a loopback address, a ``Host`` that is not this machine's) is refused, so that a web
page the user visits cannot press the buttons.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from simple_message.lograte import LogBudget

from ..emulator.cell import FaultError, Wakeup
from .access import Access, is_loopback, token_url, web_token
from .feed import Feed, Page

if TYPE_CHECKING:
    from ..emulator import Emulator

__all__ = ["WebView", "ControllerView", "STATIC", "MAX_MESSAGE", "COMMAND_BURST", "MAX_PAGES", "RunAs"]

log = logging.getLogger(__name__)

#: the page and its scripts
STATIC = Path(__file__).parent / "static"
#: the longest message a page may send (bytes)
MAX_MESSAGE = 4096
#: commands a page may send within one second
COMMAND_BURST = 10
#: how long one send to a page may take before the page is dropped (s)
SEND_TIMEOUT = 10.0
#: pages served at once by one server, all its controllers together (each costs a task and a socket)
MAX_PAGES = 32

#: calls a function as a controller's own code (a fleet's: its log lines then name it)
RunAs = Callable[[Callable[[], str]], str]


def run_here(function: Callable[[], str]) -> str:
    """Call ``function`` (a lone controller's command needs no context of its own)."""
    return function()


class ControllerView:
    """One emulator's page, WebSocket and commands (see the module doc), served by a
    :class:`WebView` or a :class:`~.fleet.FleetView`. Made before the emulator starts (its feed taps
    the traffic then)."""

    def __init__(
        self,
        emulator: Emulator,
        *,
        access: Access,
        bound: str,
        pages: set[web.WebSocketResponse],
        budget: LogBudget,
        rate: float = 30.0,
        window: float = 10.0,
        name: str | None = None,
        run_as: RunAs = run_here,
    ) -> None:
        self.emulator = emulator
        self.name = name
        self.feed = Feed(emulator, rate=rate, window=window)
        #: the host the server binds (the Origin rule differs on loopback)
        self._bound = bound
        self._access = access
        #: this controller's open pages, and every page of the server (the limit counts them all)
        self._pages: set[web.WebSocketResponse] = set()
        self._all_pages = pages
        self._budget = budget
        self._run_as = run_as
        #: sample ``rate`` times a second while a page is open (a test turns it off and samples itself)
        self.autosample = True
        self._sampler: asyncio.Task[None] | None = None
        #: woken by each round of state topics while the sampler runs (it waits for the next one)
        self._rounds = Wakeup()
        #: set while no page of this controller is open
        self.idle = asyncio.Event()
        self.idle.set()

    @property
    def sampling(self) -> bool:
        """The sampler runs (some page is open)."""
        return self._sampler is not None and not self._sampler.done()

    # -- pages come and go -------------------------------------------------------------------------

    def _first_page(self) -> None:
        self.idle.clear()
        self.feed.attach()
        if self.autosample:
            self.emulator.after_state.append(self._rounds.wake)
            self._sampler = asyncio.get_running_loop().create_task(self._sample(), name="web view sampler")

    def _last_page(self) -> None:
        with contextlib.suppress(ValueError):
            self.emulator.after_state.remove(self._rounds.wake)
        if self._sampler is not None:
            self._sampler.cancel()
            self._sampler = None
        self.feed.detach()
        self.idle.set()

    async def close(self) -> None:
        """Close this controller's pages and stop sampling."""
        for ws in list(self._pages):
            with contextlib.suppress(Exception):
                await ws.close(code=1001, message=b"robot-server is shutting down")
        self._last_page()

    async def _sample(self) -> None:
        """``rate`` samples a second on absolute deadlines. Each is taken just after the state topics'
        next round (when they come at least as often): the sample and the sends to the pages then
        run in the gap before the following round instead of delaying it."""
        period = 1.0 / self.feed.rate
        state_period = self.emulator.state_stats.period
        origin = time.monotonic()
        k = 0
        while True:
            k += 1
            delay = origin + k * period - time.monotonic()
            if delay < -period:  # fell behind: skip, never burst
                k += int(-delay // period)
            await asyncio.sleep(max(0.0, delay))
            if state_period <= period:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(2.0 * state_period):
                        await self._rounds.wait()
            self.feed.sample()

    # -- HTTP ------------------------------------------------------------------------------------

    async def page(self, request: web.Request) -> web.StreamResponse:
        """The page (its addresses relative to where it is served)."""
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def socket(self, request: web.Request) -> web.StreamResponse:
        """The page's WebSocket: a hello, then updates; commands answered (when the page may)."""
        if not same_origin(request, self._bound):
            return web.Response(status=403, text="a WebSocket from another site's page is refused\n")
        if len(self._all_pages) >= MAX_PAGES:
            return web.Response(status=503, text=f"at most {MAX_PAGES} pages at once\n")
        why = self._access.why_read_only(request.query.get("token"))
        # no per-message compression: on loopback it would only cost the controller's CPU
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=30.0, compress=False)
        await ws.prepare(request)
        if not self._pages:
            self._first_page()
        self._pages.add(ws)
        self._all_pages.add(ws)
        page = Page()
        sender = asyncio.get_running_loop().create_task(self._send(ws, page, why), name="web view page")
        try:
            await self._receive(ws, why, request.remote or "?")
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
            self._pages.discard(ws)
            self._all_pages.discard(ws)
            if not self._pages:
                self._last_page()
            await ws.close()
        return ws

    async def _send(self, ws: web.WebSocketResponse, page: Page, why: str | None) -> None:
        feed = self.feed
        control = {"commands": why is None, "why": why}
        try:
            async with asyncio.timeout(SEND_TIMEOUT):
                await ws.send_str(feed.hello(page, name=self.name, control=control))
            while not ws.closed:
                await feed.next_sample()
                message = feed.update(page)
                if message is not None:
                    async with asyncio.timeout(SEND_TIMEOUT):
                        await ws.send_str(message)
        except (ConnectionError, TimeoutError) as exc:
            self._budget.log(log, logging.INFO, "web page dropped: %s", exc or type(exc).__name__)
            await ws.close()

    async def _receive(self, ws: web.WebSocketResponse, why: str | None, peer: str) -> None:
        sent: list[float] = []
        async for msg in ws:
            if msg.type is WSMsgType.TEXT:
                reply = self._command(msg.data, sent, why, peer)
                with contextlib.suppress(ConnectionError):
                    await ws.send_str(json.dumps(reply))
            elif msg.type is WSMsgType.BINARY:
                with contextlib.suppress(ConnectionError):
                    await ws.send_str(json.dumps({"type": "result", "ok": False, "error": "binary messages: none"}))
            elif msg.type is WSMsgType.ERROR:  # e.g. a message over MAX_MESSAGE: aiohttp closes
                self._budget.log(log, logging.INFO, "web page closed: %s", ws.exception())

    def _command(self, text: str, sent: list[float], why: str | None, peer: str) -> dict[str, object]:
        try:
            request = json.loads(text)
        except (ValueError, RecursionError):  # nesting deeper than the parser goes: not JSON we read
            return {"type": "result", "ok": False, "error": "not JSON"}
        if not isinstance(request, dict) or request.get("type") != "command":
            return {"type": "result", "ok": False, "error": 'expected {"type": "command", "command": "..."}'}
        command = request.get("command")
        if not isinstance(command, str) or not command.strip():
            return {"type": "result", "ok": False, "error": "command: a fault command, e.g. estop"}
        if why is not None:
            self._run_as(functools.partial(self._refuse, peer))
            return {"type": "result", "ok": False, "refused": True, "error": f"refused, {why}"}
        now = time.monotonic()
        sent[:] = [t for t in sent if now - t < 1.0]
        if len(sent) >= COMMAND_BURST:
            return {"type": "result", "ok": False, "error": f"at most {COMMAND_BURST} commands a second"}
        sent.append(now)
        try:
            applied = self._run_as(functools.partial(self._apply, command))
        except FaultError as exc:
            return {"type": "result", "ok": False, "error": str(exc)}
        return {"type": "result", "ok": True, "text": applied}

    def _refuse(self, peer: str) -> str:
        self._budget.log(log, logging.INFO, "web view: a command from a read-only page (%s) refused", peer)
        return ""

    def _apply(self, command: str) -> str:
        applied = self.emulator.command(command)
        self._budget.log(log, logging.INFO, "applied from the web view: %s", applied)
        return applied


class WebView:
    """The live web view of one emulator (see the module doc). Make it before the emulator
    starts; :meth:`start` after it, :meth:`close` before it closes.

    ``token``: what the page's commands need (``None``: none given); on a host beyond loopback
    without one, a token is made (:func:`~.access.web_token`): :attr:`token`, :attr:`token_generated`,
    and :attr:`token_url` to print once."""

    def __init__(
        self,
        emulator: Emulator,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        rate: float = 30.0,
        window: float = 10.0,
        token: str | None = None,
    ) -> None:
        self.emulator = emulator
        self.host = host
        self.port = port
        self.token, self.token_generated = web_token(host, token)
        self._pages: set[web.WebSocketResponse] = set()
        self.controller = ControllerView(
            emulator,
            access=Access(self.token),
            bound=host,
            pages=self._pages,
            budget=LogBudget("web view", rate=2.0, burst=10),
            rate=rate,
            window=window,
        )
        self._runner: web.AppRunner | None = None

    @property
    def feed(self) -> Feed:
        return self.controller.feed

    @property
    def url(self) -> str:
        """The page's address (no token in it: this one may be logged)."""
        return base_url(self.host, self.port)

    @property
    def token_url(self) -> str:
        """The page's address with the token in it (print it once; never log it)."""
        return token_url(self.url, self.token)

    async def start(self) -> WebView:
        app = web.Application()
        app.router.add_get("/", self.controller.page)
        app.router.add_get("/ws", self.controller.socket)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        self._runner, self.port = await serve(app, self.host, self.port)
        log.info("web view at %s%s", self.url, " (commands need its token)" if self.token else "")
        return self

    async def close(self) -> None:
        await self.controller.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None


async def serve(app: web.Application, host: str, port: int) -> tuple[web.AppRunner, int]:
    """Serve ``app`` on ``host:port``; the runner and the port bound (0 asks for any free one)."""
    runner = web.AppRunner(app, access_log=None, handle_signals=False)
    await runner.setup()
    site = web.TCPSite(runner, host, port, reuse_address=True)
    try:
        await site.start()
    except BaseException:
        await runner.cleanup()
        raise
    return runner, int(runner.addresses[0][1])


def base_url(host: str, port: int) -> str:
    name = f"[{host}]" if ":" in host else host
    return f"http://{name}:{port}/"


def same_origin(request: web.Request, bound: str) -> bool:
    """No ``Origin`` (not a browser), or one whose host and port are the request's ``Host``; and,
    on a loopback address, a ``Host`` that names this machine (so that a site whose name was made
    to point at 127.0.0.1, DNS rebinding, is refused too)."""
    host = (request.host or "").lower()
    if is_loopback(bound):
        name = urlsplit(f"http://{host}").hostname or ""
        if not is_loopback(name):
            return False
    origin = request.headers.get("Origin")
    if origin is None:
        return True
    return urlsplit(origin).netloc.lower() == host
