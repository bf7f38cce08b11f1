"""The fleet's web view (robot_server.web.fleet) and the token of the web view's commands
(robot_server.web.access): the index of the controllers and their state, each controller's page
under /c/NAME/ reaching that controller only, sampling only while a page is open, and the token
rules (read-only without it, commands refused, accepted with it, loopback as before).

The fleets run in process on a clock the test advances (tests/stepped.py), on 127.0.0.1. The pages'
own samplers are off where a test reads updates (it samples itself), so nothing depends on timing.
A token "beyond loopback" is tested by giving one on loopback (the same rule: then it is needed) and
by making views for other hosts without starting them (tests bind 127.0.0.1 only).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
import pytest

from robot_server.control import SteppedClock
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.fleet import Fleet, parse_fleet
from robot_server.fleet.logs import ControllerField
from robot_server.web import TOKEN_ENV, fleet_view, is_loopback, token_url, web_token, web_view
from robot_server.web.access import MIN_TOKEN, Access
from robot_server.web.fleet import FleetView
from robot_server.web.server import WebView
from tests.rawpeer import RawPeer
from tests.stepped import STEP_TIMEOUT, advance_until
from tests.test_rs_web import receive

TOKEN = "s3cret-Token_0123"
CONTROLLERS = (
    {"name": "r1", "profile": "generic", "motion_port": 0, "state_port": 0},
    {"name": "r2", "profile": "motoros", "motion_port": 0, "state_port": 0, "io_port": 0},
    {"name": "r3", "profile": "abb", "model": ["puma560"], "motion_port": 0, "state_port": 0},
)


@contextlib.asynccontextmanager
async def fleet_web(token: str | None = None, *, autosample: bool = False) -> AsyncIterator[tuple[Fleet, FleetView]]:
    """Three controllers of three profiles in one fleet on a stepped clock, and their web view on a
    free port of 127.0.0.1 (the pages' samplers off unless ``autosample``)."""
    clock = SteppedClock()
    fleet = Fleet(parse_fleet({"controller": [dict(c) for c in CONTROLLERS]}), clock=clock)
    view = fleet_view(fleet.emulators, "127.0.0.1", 0, token=token, run_as=fleet.run_as)
    for controller in view.controllers.values():
        controller.autosample = autosample
    view.index_max_age = 0.0  # each /fleet.json made anew (its reuse is tested on its own)
    await fleet.start()
    try:
        await view.start()
        async with asyncio.timeout(STEP_TIMEOUT):
            await clock.advance(0.0)
        yield fleet, view
        await advance_until(clock, lambda: not any(e.in_motion for e in fleet.emulators.values()), what="rest")
    finally:
        await view.close()
        await fleet.close(settle_timeout=1.0)


async def index(http: aiohttp.ClientSession, view: FleetView, token: str | None = None) -> dict[str, Any]:
    async with http.get(token_url(view.url + "fleet.json", token)) as response:
        assert response.status == 200
        assert response.headers["Cache-Control"] == "no-store"
        data: dict[str, Any] = await response.json()
        return data


# -- the index -------------------------------------------------------------------------------------


async def test_the_index_lists_every_controller_and_follows_an_estop() -> None:
    async with fleet_web() as (fleet, view), aiohttp.ClientSession() as http:
        data = await index(http, view)
        assert data["type"] == "fleet" and data["version"] == 1 and data["period"] > 0
        assert data["control"] == {"commands": True, "why": None}  # loopback, no token: as before
        rows = {c["name"]: c for c in data["controllers"]}
        assert list(rows) == ["r1", "r2", "r3"]  # the fleet's order
        for name, row in rows.items():
            emulator = fleet[name]
            assert row["url"] == f"c/{name}/"
            assert row["profile"] == emulator.config.profile
            assert row["models"] == [g.model.name for g in emulator.cell.groups]
            assert row["ports"] == emulator.ports and row["host"] == "127.0.0.1"
            assert row["status"]["e_stopped"] is False and row["status"]["in_error"] is False
            assert row["clients"] == dict.fromkeys(emulator.servers, 0)
        assert set(rows["r2"]["ports"]) == {"motion", "state", "io"}
        assert rows["r3"]["models"] == ["puma560"]
        assert rows["r1"]["status"]["drives_powered"] is True and rows["r1"]["status"]["mode"] == "AUTO"

        fleet["r2"].cell.estop()
        state = await RawPeer.connect(fleet["r3"].ports["state"])
        try:
            rows = {c["name"]: c for c in (await index(http, view))["controllers"]}
        finally:
            await state.close()
        assert rows["r2"]["status"]["e_stopped"] is True and rows["r2"]["status"]["drives_powered"] is False
        assert not rows["r1"]["status"]["e_stopped"] and not rows["r3"]["status"]["e_stopped"]
        assert rows["r3"]["clients"]["state"] == 1 and rows["r1"]["clients"]["state"] == 0
        fleet.command("r2 alarm 4711 door open")
        rows = {c["name"]: c for c in (await index(http, view))["controllers"]}
        assert rows["r2"]["status"]["in_error"] and rows["r2"]["status"]["error_code"] == 4711


async def test_one_index_answer_serves_whoever_asks_within_its_max_age() -> None:
    """However many index pages are open, or however fast a program asks, the controllers are read
    at most once every ``index_max_age`` seconds; the token's part is each request's own."""
    async with fleet_web(TOKEN) as (fleet, view), aiohttp.ClientSession() as http:
        view.index_max_age = 3600.0
        first = await index(http, view)
        fleet["r1"].cell.estop()
        again = await index(http, view, TOKEN)
        assert again["controllers"] == first["controllers"]  # the same answer, r1 not yet e-stopped
        assert first["control"]["commands"] is False and again["control"]["commands"] is True
        assert view.summary()["controllers"][0]["status"]["e_stopped"] is True  # summary() reads now
        view.index_max_age = 0.0
        assert (await index(http, view))["controllers"][0]["status"]["e_stopped"] is True


async def test_the_index_page_and_each_controllers_page_are_served() -> None:
    async with fleet_web() as (_, view), aiohttp.ClientSession() as http:
        async with http.get(view.url) as response:
            assert response.status == 200
            html = await response.text()
        assert "fleet.js" in html and not re.findall(r'(?:src|href)="/', html)
        for path in re.findall(r'(?:src|href)="(static/[^"]+)"', html):
            async with http.get(view.url + path) as response:
                assert response.status == 200, path
        # a controller's page, the same as a lone robot-server's; its static files are the shared ones
        async with http.get(view.controller_url("r2")) as response:
            assert response.status == 200 and 'src="static/app.js"' in await response.text()
        async with http.get(view.url + "c/r2/static/app.js", allow_redirects=False) as response:
            assert response.status == 301 and response.headers["Location"] == "/static/app.js"
        async with http.get(view.url + "c/r2/static/vendor/three/three.module.js") as response:
            assert response.status == 200 and response.url.path == "/static/vendor/three/three.module.js"
        # the folder's address without its slash: redirected, the token kept
        async with http.get(view.url + "c/r2?token=abc", allow_redirects=False) as response:
            assert response.status == 301 and response.headers["Location"] == "/c/r2/?token=abc"
        for missing in ("c/nope/", "c/nope/ws", "c/nope", "c/nope/static/app.js", "c/r2/other"):
            async with http.get(view.url + missing, allow_redirects=False) as response:
                assert response.status == 404, missing
        async with http.get(view.url + "c/r2/static/../../fleet.py") as response:
            assert response.status in (403, 404)


async def test_a_command_on_one_controllers_page_reaches_that_controller_only(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    caplog.handler.addFilter(ControllerField())  # the fleet's handler's: the record names its controller
    async with (
        fleet_web() as (fleet, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.controller_url("r2") + "ws") as ws,
    ):
        hello = await receive(ws, "hello")
        assert hello["emulator"]["name"] == "r2" and hello["emulator"]["profile"] == "motoros"
        assert hello["emulator"]["ports"] == fleet["r2"].ports
        assert hello["control"] == {"commands": True, "why": None}
        await ws.send_json({"type": "command", "command": "estop"})
        assert await receive(ws, "result") == {"type": "result", "ok": True, "text": "estop"}
        assert fleet["r2"].cell.e_stopped
        assert not fleet["r1"].cell.e_stopped and not fleet["r3"].cell.e_stopped
        # the update of r2's page is r2's
        view.controllers["r2"].feed.sample()
        assert (await receive(ws, "update"))["status"]["e_stopped"] is True
        await ws.send_json({"type": "command", "command": "reset"})
        assert (await receive(ws, "result"))["ok"]
    # the log line of the command names its controller (run as the fleet's r2)
    applied = [r for r in caplog.records if "applied from the web view" in r.getMessage()]
    assert applied and all(getattr(r, "controller", None) == "r2: " for r in applied), applied


async def test_a_controllers_page_samples_only_while_it_is_open() -> None:
    """No page: no sampler, no hook on the state rounds, no listener on the accepted points; a page
    of r1 starts r1's sampling only, and its close ends it."""
    async with fleet_web(autosample=True) as (fleet, view), aiohttp.ClientSession() as http:
        hooks = {name: list(fleet[name].after_state) for name in fleet}
        listeners = {name: list(fleet[name].cell.point_listeners) for name in fleet}
        assert not any(c.sampling for c in view.controllers.values())
        r1 = view.controllers["r1"]
        async with http.ws_connect(view.controller_url("r1") + "ws") as ws:
            await receive(ws, "hello")
            await receive(ws, "update")  # sampled on its own, after a state round
            assert r1.sampling and not r1.idle.is_set()
            assert len(fleet["r1"].after_state) == len(hooks["r1"]) + 1
            assert len(fleet["r1"].cell.point_listeners) == len(listeners["r1"]) + 1
            assert not view.controllers["r2"].sampling and not view.controllers["r3"].sampling
        async with asyncio.timeout(10.0):
            await r1.idle.wait()
        assert not r1.sampling
        assert {name: list(fleet[name].after_state) for name in fleet} == hooks
        assert {name: list(fleet[name].cell.point_listeners) for name in fleet} == listeners


async def test_a_lone_web_view_samples_only_while_a_page_is_open() -> None:
    emulator = Emulator(EmulatorConfig(motion_port=0, state_port=0))
    view = web_view(emulator, "127.0.0.1", 0)
    await emulator.start()
    try:
        await view.start()
        assert view.token is None and not view.token_generated and view.token_url == view.url
        assert emulator.after_state == [] and not view.controller.sampling
        async with aiohttp.ClientSession() as http, http.ws_connect(view.url + "ws") as ws:
            assert (await receive(ws, "hello"))["control"]["commands"] is True
            await receive(ws, "update")
            assert view.controller.sampling and len(emulator.after_state) == 1
        async with asyncio.timeout(10.0):
            await view.controller.idle.wait()
        assert emulator.after_state == [] and not view.controller.sampling
    finally:
        await view.close()
        await emulator.close(settle_timeout=1.0)


async def test_a_page_of_another_site_is_refused_under_c_name() -> None:
    async with fleet_web() as (fleet, view), aiohttp.ClientSession() as http:
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(view.controller_url("r1") + "ws", origin="http://evil.example")
        assert refused.value.status == 403
        assert not fleet["r1"].cell.e_stopped


def test_fleet_view_refuses_names_its_addresses_cannot_carry() -> None:
    emulator = Emulator(EmulatorConfig(motion_port=0, state_port=0))
    for bad in ("", "a/b", "..", "r 1", "ü"):
        with pytest.raises(ValueError, match="controller name"):
            FleetView({bad: emulator})
    with pytest.raises(ValueError, match="at least one"):
        FleetView({})


# -- the token -------------------------------------------------------------------------------------


def test_web_token_rules() -> None:
    assert TOKEN_ENV == "ROBOT_SERVER_WEB_TOKEN"
    for host in ("127.0.0.1", "127.1.2.3", "::1", "[::1]", "localhost", "LOCALHOST"):
        assert is_loopback(host), host
        assert web_token(host, None) == (None, False)
        assert web_token(host, "") == (None, False)  # an empty variable is none given
        assert web_token(host, TOKEN) == (TOKEN, False)  # given: needed on loopback too
    made = set()
    for host in ("0.0.0.0", "::", "192.168.1.20", "fe80::1", "robot-cell-0.robot-cell", ""):
        assert not is_loopback(host), host
        token, generated = web_token(host, None)
        assert generated and token is not None and len(token) >= 22
        assert re.fullmatch(r"[A-Za-z0-9_-]+", token)
        made.add(token)
        assert web_token(host, TOKEN) == (TOKEN, False)
    assert len(made) == 6  # a new one each time
    for bad, message in [("short", "8 to 256"), ("x" * 257, "8 to 256"), ("has space in it", "printable ASCII")]:
        with pytest.raises(ValueError, match=message) as refused:
            web_token("0.0.0.0", bad)
        assert bad not in str(refused.value)  # never repeated
    assert token_url("http://h:1/", "a b&c/d") == "http://h:1/?token=a%20b%26c%2Fd"
    assert token_url("http://h:1/", None) == "http://h:1/"


def test_views_beyond_loopback_make_a_token() -> None:
    """Made, not started: the tests bind 127.0.0.1 only."""
    emulator = Emulator(EmulatorConfig(motion_port=0, state_port=0))
    view = WebView(emulator, "0.0.0.0", 8080)
    assert view.token is not None and view.token_generated
    assert view.url == "http://0.0.0.0:8080/" and view.token_url == f"http://0.0.0.0:8080/?token={view.token}"
    fleet = FleetView({"r1": emulator}, "::", 8080, token=TOKEN)
    assert (fleet.token, fleet.token_generated) == (TOKEN, False)
    assert fleet.token_url == f"http://[::]:8080/?token={TOKEN}"
    assert fleet.controller_url("r1") == "http://[::]:8080/c/r1/"


def test_access_compares_the_token() -> None:
    assert Access(None).why_read_only(None) is None and not Access(None).required
    access = Access(TOKEN)
    assert access.required and access.why_read_only(TOKEN) is None
    assert "?token=" in (access.why_read_only(None) or "") and TOKEN not in (access.why_read_only(None) or "")
    assert "not this web view's" in (access.why_read_only(TOKEN + "x") or "")
    assert "not this web view's" in (access.why_read_only("ü" * MIN_TOKEN) or "")


async def test_without_the_token_a_page_is_read_only_and_its_commands_are_refused(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG)
    async with fleet_web(TOKEN) as (fleet, view), aiohttp.ClientSession() as http:
        assert view.token == TOKEN and not view.token_generated
        page = view.controller_url("r2") + "ws"
        for offered, why in [(None, "?token="), ("wrong-token-1234", "not this web view's")]:
            async with http.ws_connect(token_url(page, offered)) as ws:
                hello = await receive(ws, "hello")
                assert hello["control"]["commands"] is False and why in hello["control"]["why"]
                assert hello["groups"] and hello["emulator"]["ports"] == fleet["r2"].ports  # it still sees all
                view.controllers["r2"].feed.sample()
                assert "status" in await receive(ws, "update")
                for command in ("estop", "drives off", "reset", "mode manual"):
                    await ws.send_json({"type": "command", "command": command})
                    result = await receive(ws, "result")
                    assert result["ok"] is False and result["refused"] is True, result
                    assert result["error"].startswith("refused, read-only") and why in result["error"]
                # bad input is still answered as bad input
                await ws.send_str("not json")
                assert (await receive(ws, "result"))["error"] == "not JSON"
        assert not fleet["r2"].cell.e_stopped and fleet["r2"].cell.drives_powered
        # the index says whether the token a page holds is the right one
        assert (await index(http, view))["control"]["commands"] is False
        assert (await index(http, view, "wrong-token-1234"))["control"]["commands"] is False
        assert (await index(http, view, TOKEN))["control"] == {"commands": True, "why": None}
        # with it: commands reach the robot
        async with http.ws_connect(token_url(page, TOKEN)) as ws:
            assert (await receive(ws, "hello"))["control"] == {"commands": True, "why": None}
            await ws.send_json({"type": "command", "command": "estop"})
            assert await receive(ws, "result") == {"type": "result", "ok": True, "text": "estop"}
            assert fleet["r2"].cell.e_stopped
            await ws.send_json({"type": "command", "command": "reset"})
            assert (await receive(ws, "result"))["ok"]
    logged = "\n".join(f"{r.getMessage()} {r.args}" for r in caplog.records)
    assert "refused" in logged and TOKEN not in logged and "wrong-token-1234" not in logged


async def test_a_lone_web_view_on_loopback_needs_a_token_once_given_one() -> None:
    emulator = Emulator(EmulatorConfig(motion_port=0, state_port=0))
    view = web_view(emulator, "127.0.0.1", 0, token=TOKEN)
    await emulator.start()
    try:
        await view.start()
        assert view.token_url == f"{view.url}?token={TOKEN}"
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(view.url + "ws") as ws:
                assert (await receive(ws, "hello"))["control"]["commands"] is False
                await ws.send_json({"type": "command", "command": "estop"})
                assert (await receive(ws, "result"))["refused"] is True
            assert not emulator.cell.e_stopped
            async with http.ws_connect(view.token_url.replace("/?", "/ws?")) as ws:
                await receive(ws, "hello")
                await ws.send_json({"type": "command", "command": "estop"})
                assert (await receive(ws, "result"))["ok"] is True
            assert emulator.cell.e_stopped
    finally:
        await view.close()
        await emulator.close(settle_timeout=1.0)
