"""The web view's HTTP server: one page, its static files and one WebSocket, on the emulator's loop.

:class:`WebView` serves (aiohttp, the optional ``web`` extra) ``/`` (the page), ``/static/`` (its
scripts, with three.js and uPlot shipped inside the package: the page needs no internet) and
``/ws``. A sampling task calls :meth:`.Feed.sample` ``rate`` times a second on absolute deadlines;
each page's own task sends it the update made from that sample, so a page that reads slowly delays
only itself (its updates are skipped while a send is under way; aiohttp bounds what it buffers).

A page sends ``{"type": "command", "command": "estop"}`` (the fault commands of stdin, through
:meth:`~robot_server.emulator.Emulator.command`) and is answered ``{"type": "result", ...}``.
Input is bounded: a message longer than :data:`MAX_MESSAGE` closes that page's socket, more than
:data:`COMMAND_BURST` commands within a second are refused, anything else malformed is answered
with an error; none of it reaches the robot or the other pages. A WebSocket opened by a page of
another site (its ``Origin`` names another host than the request's ``Host``, or, on a loopback
address, a ``Host`` that is not this machine's) is refused, so that a web page the user visits
cannot press the buttons.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from simple_message.lograte import LogBudget

from ..emulator.cell import FaultError, Wakeup
from .feed import Feed, Page

if TYPE_CHECKING:
    from ..emulator import Emulator

__all__ = ["WebView", "STATIC", "MAX_MESSAGE", "COMMAND_BURST"]

log = logging.getLogger(__name__)

#: the page and its scripts
STATIC = Path(__file__).parent / "static"
#: the longest message a page may send (bytes)
MAX_MESSAGE = 4096
#: commands a page may send within one second
COMMAND_BURST = 10
#: how long one send to a page may take before the page is dropped (s)
SEND_TIMEOUT = 10.0
#: pages served at once (each costs a task and a socket)
MAX_PAGES = 32


class WebView:
    """The live web view of one emulator (see the module doc). Make it before the emulator
    starts; :meth:`start` after it, :meth:`close` before it closes."""

    def __init__(
        self, emulator: Emulator, host: str = "127.0.0.1", port: int = 0, *, rate: float = 30.0, window: float = 10.0
    ) -> None:
        self.emulator = emulator
        self.host = host
        self.port = port
        self.feed = Feed(emulator, rate=rate, window=window)
        self._pages: set[web.WebSocketResponse] = set()
        self._runner: web.AppRunner | None = None
        self._sampler: asyncio.Task[None] | None = None
        #: woken by each round of state topics (the sampler waits for the next one)
        self._rounds = Wakeup()
        self._budget = LogBudget("web view", rate=2.0, burst=10)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    async def start(self) -> WebView:
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._socket)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
        try:
            await site.start()
        except BaseException:
            await runner.cleanup()
            raise
        self._runner = runner
        self.port = int(runner.addresses[0][1])  # the port bound (0 asks for any free one)
        self.emulator.after_state.append(self._rounds.wake)
        self._sampler = asyncio.get_running_loop().create_task(self._sample(), name="web view sampler")
        log.info("web view at %s", self.url)
        return self

    async def close(self) -> None:
        with contextlib.suppress(ValueError):
            self.emulator.after_state.remove(self._rounds.wake)
        self.feed.detach()
        if self._sampler is not None:
            self._sampler.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._sampler
            self._sampler = None
        for ws in list(self._pages):
            with contextlib.suppress(Exception):
                await ws.close(code=1001, message=b"robot-server is shutting down")
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

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

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def _socket(self, request: web.Request) -> web.StreamResponse:
        if not _same_origin(request, self.host):
            return web.Response(status=403, text="a WebSocket from another site's page is refused\n")
        if len(self._pages) >= MAX_PAGES:
            return web.Response(status=503, text=f"at most {MAX_PAGES} pages at once\n")
        # no per-message compression: on loopback it would only cost the controller's CPU
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=30.0, compress=False)
        await ws.prepare(request)
        self._pages.add(ws)
        page = Page()
        sender = asyncio.get_running_loop().create_task(self._send(ws, page), name="web view page")
        try:
            await self._receive(ws)
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
            self._pages.discard(ws)
            await ws.close()
        return ws

    async def _send(self, ws: web.WebSocketResponse, page: Page) -> None:
        feed = self.feed
        try:
            async with asyncio.timeout(SEND_TIMEOUT):
                await ws.send_str(feed.hello(page))
            while not ws.closed:
                await feed.next_sample()
                message = feed.update(page)
                if message is not None:
                    async with asyncio.timeout(SEND_TIMEOUT):
                        await ws.send_str(message)
        except (ConnectionError, TimeoutError) as exc:
            self._budget.log(log, logging.INFO, "web page dropped: %s", exc or type(exc).__name__)
            await ws.close()

    async def _receive(self, ws: web.WebSocketResponse) -> None:
        sent: list[float] = []
        async for msg in ws:
            if msg.type is WSMsgType.TEXT:
                reply = self._command(msg.data, sent)
                with contextlib.suppress(ConnectionError):
                    await ws.send_str(json.dumps(reply))
            elif msg.type is WSMsgType.BINARY:
                with contextlib.suppress(ConnectionError):
                    await ws.send_str(json.dumps({"type": "result", "ok": False, "error": "binary messages: none"}))
            elif msg.type is WSMsgType.ERROR:  # e.g. a message over MAX_MESSAGE: aiohttp closes
                self._budget.log(log, logging.INFO, "web page closed: %s", ws.exception())

    def _command(self, text: str, sent: list[float]) -> dict[str, object]:
        try:
            request = json.loads(text)
        except (ValueError, RecursionError):  # nesting deeper than the parser goes: not JSON we read
            return {"type": "result", "ok": False, "error": "not JSON"}
        if not isinstance(request, dict) or request.get("type") != "command":
            return {"type": "result", "ok": False, "error": 'expected {"type": "command", "command": "..."}'}
        command = request.get("command")
        if not isinstance(command, str) or not command.strip():
            return {"type": "result", "ok": False, "error": "command: a fault command, e.g. estop"}
        now = time.monotonic()
        sent[:] = [t for t in sent if now - t < 1.0]
        if len(sent) >= COMMAND_BURST:
            return {"type": "result", "ok": False, "error": f"at most {COMMAND_BURST} commands a second"}
        sent.append(now)
        try:
            applied = self.emulator.command(command)
        except FaultError as exc:
            return {"type": "result", "ok": False, "error": str(exc)}
        self._budget.log(log, logging.INFO, "applied from the web view: %s", applied)
        return {"type": "result", "ok": True, "text": applied}


def _same_origin(request: web.Request, bound: str) -> bool:
    """No ``Origin`` (not a browser), or one whose host and port are the request's ``Host``; and,
    on a loopback address, a ``Host`` that names this machine (so that a site whose name was made
    to point at 127.0.0.1, DNS rebinding, is refused too)."""
    host = (request.host or "").lower()
    if _loopback(bound):
        name = urlsplit(f"http://{host}").hostname or ""
        if name != "localhost" and not _loopback(name):
            return False
    origin = request.headers.get("Origin")
    if origin is None:
        return True
    return urlsplit(origin).netloc.lower() == host


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False
