"""The fleet's web view: many controllers' pages on one port, and an index of them.

:class:`FleetView` serves, with one aiohttp application on one port, every emulator of a fleet
(``robot-server --fleet FILE --web``):

* ``/``: the index, one row per controller (its name, profile, models, ports and, at a glance, its
  drives, e-stop, error, mode, motion and clients), each linking to its page;
* ``/fleet.json``: what the index shows, which the index page reads every :data:`INDEX_PERIOD`
  seconds while it is open. It is made when asked, from the controllers' state at that moment, and
  kept for :attr:`FleetView.index_max_age` seconds for whoever asks meanwhile: nothing is sampled
  for it in between, so the index costs nothing while no index is open, some tens of microseconds
  per controller a second while one is, and no more however many are open or however fast a
  program asks;
* ``/c/NAME/``: controller NAME's own page (:class:`~.server.ControllerView`, the same page as a lone
  ``robot-server --web``'s at ``/``), its WebSocket ``/c/NAME/ws``; its static files are the shared
  ``/static/`` ones (``/c/NAME/static/...`` redirects there, so a browser keeps one copy).

Each controller's page samples its controller only while it is open; a fleet of controllers with no
page open costs nothing here. The commands of every page need the one token of the fleet's view where
a token is needed (:mod:`.access`); ``/fleet.json`` says whether the token a page holds is the right
one, for the index to say so.
"""

from __future__ import annotations

import functools
import json
import logging
import re
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from aiohttp import web

from simple_message.lograte import LogBudget

from .access import Access, token_url, web_token
from .feed import PROTOCOL_VERSION, status_of
from .server import STATIC, ControllerView, RunAs, base_url, run_here, serve

if TYPE_CHECKING:
    from ..emulator import Emulator

__all__ = ["FleetView", "INDEX_PERIOD", "controller_summary"]

log = logging.getLogger(__name__)

#: how often the index page reads ``/fleet.json`` (s)
INDEX_PERIOD = 1.0
#: how long an answer of ``/fleet.json`` is given again to whoever asks (s)
INDEX_MAX_AGE = 0.5
#: a controller's name as the addresses take it (the fleet file's names are all of this kind)
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.~-]{0,62}")


def controller_summary(name: str, emulator: Emulator) -> dict[str, Any]:
    """One controller as the index shows it: where it is and its state at a glance."""
    cfg = emulator.config
    clients = {role: len(server.sessions) for role, server in emulator.servers.items()}
    return {
        "name": name,
        "url": f"c/{name}/",
        "profile": cfg.profile,
        "models": [g.model.name for g in emulator.cell.groups],
        "host": cfg.host,
        "ports": dict(emulator.ports),
        "serial": cfg.serial,
        "policy": cfg.interpolation,
        "status": status_of(emulator),
        "clients": clients,
    }


class FleetView:
    """The web view of many emulators, by name (see the module doc). Make it before the emulators
    start; :meth:`start` after them, :meth:`close` before they close.

    ``token``: what every page's commands need (``None``: none given); on a host beyond loopback
    without one, a token is made (:func:`~.access.web_token`): :attr:`token`,
    :attr:`token_generated`, and :attr:`token_url` to print once. ``run_as(name, function)`` calls
    ``function`` as controller ``name``'s code (a fleet's ``Fleet.run_as``: the log lines of a
    command from its page then name it)."""

    def __init__(
        self,
        emulators: Mapping[str, Emulator],
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        rate: float = 30.0,
        window: float = 10.0,
        token: str | None = None,
        run_as: Callable[[str, Callable[[], str]], str] | None = None,
    ) -> None:
        if not emulators:
            raise ValueError("a fleet's web view needs at least one controller")
        for name in emulators:
            if not NAME.fullmatch(name):
                raise ValueError(
                    f"controller name {name!r}: the web view's addresses take letters, digits, '_', '-', '.', '~' "
                    "(first a letter or digit, at most 63)"
                )
        self.host = host
        self.port = port
        self.token, self.token_generated = web_token(host, token)
        self.access = Access(self.token)
        self._pages: set[web.WebSocketResponse] = set()
        budget = LogBudget("web view", rate=2.0, burst=10)
        self.controllers: dict[str, ControllerView] = {}
        for name, emulator in emulators.items():
            run: RunAs = run_here if run_as is None else functools.partial(run_as, name)
            self.controllers[name] = ControllerView(
                emulator,
                access=self.access,
                bound=host,
                pages=self._pages,
                budget=budget,
                rate=rate,
                window=window,
                name=name,
                run_as=run,
            )
        self._runner: web.AppRunner | None = None
        #: how long the controllers' part of ``/fleet.json`` is given again (s; 0: made anew each time)
        self.index_max_age = INDEX_MAX_AGE
        self._index_made = -float("inf")
        self._index_json = ""

    @property
    def url(self) -> str:
        """The index's address (no token in it: this one may be logged)."""
        return base_url(self.host, self.port)

    @property
    def token_url(self) -> str:
        """The index's address with the token in it (print it once; never log it)."""
        return token_url(self.url, self.token)

    def controller_url(self, name: str) -> str:
        """Controller ``name``'s page (no token in it)."""
        if name not in self.controllers:
            raise KeyError(name)
        return f"{self.url}c/{name}/"

    async def start(self) -> FleetView:
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/fleet.json", self._summary)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        app.router.add_get("/c/{name}", self._slash)
        app.router.add_get("/c/{name}/", self._page)
        app.router.add_get("/c/{name}/ws", self._socket)
        app.router.add_get("/c/{name}/static/{tail:.*}", self._static)
        self._runner, self.port = await serve(app, self.host, self.port)
        log.info(
            "fleet web view of %d controllers at %s%s",
            len(self.controllers),
            self.url,
            " (commands need its token)" if self.token else "",
        )
        return self

    async def close(self) -> None:
        for controller in self.controllers.values():
            await controller.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    def summary(self, offered: str | None = None) -> dict[str, Any]:
        """What ``/fleet.json`` answers: every controller's :func:`controller_summary` (as it is
        now), and whether a page holding ``offered`` may send commands."""
        why = self.access.why_read_only(offered)
        return {
            "type": "fleet",
            "version": PROTOCOL_VERSION,
            "period": INDEX_PERIOD,
            "control": {"commands": why is None, "why": why},
            "controllers": [controller_summary(name, c.emulator) for name, c in self.controllers.items()],
        }

    def summary_json(self, offered: str | None = None) -> str:
        """:meth:`summary` as ``/fleet.json`` sends it: the controllers' part made at most once
        every :attr:`index_max_age` seconds."""
        now = time.monotonic()
        if now - self._index_made >= self.index_max_age:
            controllers = [controller_summary(name, c.emulator) for name, c in self.controllers.items()]
            self._index_json = _dumps(controllers)
            self._index_made = now
        why = self.access.why_read_only(offered)
        head = {"type": "fleet", "version": PROTOCOL_VERSION, "period": INDEX_PERIOD}
        head["control"] = {"commands": why is None, "why": why}
        return f'{_dumps(head)[:-1]},"controllers":{self._index_json}}}'

    # -- HTTP ------------------------------------------------------------------------------------

    def _controller(self, request: web.Request) -> ControllerView:
        controller = self.controllers.get(request.match_info["name"])
        if controller is None:
            raise web.HTTPNotFound(text=f"no controller {request.match_info['name']!r} in this fleet\n")
        return controller

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "fleet.html", headers={"Cache-Control": "no-cache"})

    async def _summary(self, request: web.Request) -> web.StreamResponse:
        return web.Response(
            text=self.summary_json(request.query.get("token")),
            content_type="application/json",
            headers={"Cache-Control": "no-store"},
        )

    async def _slash(self, request: web.Request) -> web.StreamResponse:
        self._controller(request)
        # the page's addresses are relative: it must be served from the folder's own address
        path, sep, query = request.raw_path.partition("?")
        raise web.HTTPMovedPermanently(f"{path}/{sep}{query}")

    async def _page(self, request: web.Request) -> web.StreamResponse:
        return await self._controller(request).page(request)

    async def _socket(self, request: web.Request) -> web.StreamResponse:
        return await self._controller(request).socket(request)

    async def _static(self, request: web.Request) -> web.StreamResponse:
        self._controller(request)
        # /c/NAME/static/... -> /static/... (as sent: still quoted, the query kept)
        raise web.HTTPMovedPermanently("/" + request.raw_path.split("/", 3)[3])


def _dumps(obj: object) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)
