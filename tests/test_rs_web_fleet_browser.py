"""The fleet's web view in a real browser (headless Chromium driven by playwright, as in
test_rs_web_browser.py): the index of a fleet run in this process, its live lights, the way to one
controller's page under /c/NAME/ and back, and a page without the token read-only.

Skipped with the reason where no chromium is found (test_rs_web_browser.py's rule, ``REQUIRE_BROWSER``
included).
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

import pytest
from playwright.async_api import ConsoleMessage, Page, async_playwright

from robot_server.fleet import Fleet, parse_fleet
from robot_server.web import fleet_view, token_url
from robot_server.web.fleet import FleetView
from tests.test_rs_web_browser import CHROMIUM, CHROMIUM_ARGS, CHROMIUM_OWN, WAIT

pytestmark = pytest.mark.slow

TOKEN = "browser-token-0123"
CONTROLLERS = [
    {"name": "r1", "profile": "generic", "motion_port": 0, "state_port": 0},
    {"name": "r2", "profile": "motoros", "motion_port": 0, "state_port": 0, "io_port": 0},
    {"name": "r3", "profile": "abb", "model": ["puma560"], "motion_port": 0, "state_port": 0},
]
#: the controller's page is drawing and connected
PAGE_READY = "window.webview && window.webview.connected && window.webview.renders > 2"


@contextlib.asynccontextmanager
async def fleet_web(token: str | None = None) -> AsyncIterator[tuple[Fleet, FleetView]]:
    """Three controllers in one fleet (real time) and their web view on 127.0.0.1."""
    fleet = Fleet(parse_fleet({"controller": CONTROLLERS}))
    view = fleet_view(fleet.emulators, "127.0.0.1", 0, token=token, run_as=fleet.run_as)
    await fleet.start()
    try:
        await view.start()
        yield fleet, view
    finally:
        await view.close()
        await fleet.close(settle_timeout=5.0)


@contextlib.asynccontextmanager
async def browser() -> AsyncIterator[tuple[Page, list[str]]]:
    """A page (nothing opened yet); the list collects every console error or warning and page error."""
    assert CHROMIUM is not None
    async with async_playwright() as p:
        chromium = await p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = await chromium.new_page(viewport={"width": 1280, "height": 820})
            page.set_default_timeout(WAIT)
            problems: list[str] = []

            def console(m: ConsoleMessage) -> None:
                if m.type in ("error", "warning") and not CHROMIUM_OWN.match(m.text):
                    problems.append(f"{m.type}: {m.text}")

            page.on("console", console)
            page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            yield page, problems
        finally:
            await chromium.close()


def light(name: str, which: str, state: str) -> str:
    return f'#fleet tr[data-name="{name}"] [data-light="{which}"][data-state="{state}"]'


async def test_the_index_follows_the_fleet_and_leads_to_each_controllers_page() -> None:
    async with fleet_web() as (fleet, view), browser() as (page, problems):
        await page.goto(view.url)
        await page.wait_for_function("window.fleetview && window.fleetview.connected")
        await page.wait_for_selector(light("r3", "drives_powered", "on"))
        names = await page.eval_on_selector_all("#fleet tbody tr", "rows => rows.map(r => r.dataset.name)")
        assert names == ["r1", "r2", "r3"]
        row = await page.text_content('#fleet tr[data-name="r2"]') or ""
        assert "motoros" in row and "jibot_zxs" in row and f"motion :{fleet['r2'].ports['motion']}" in row
        assert "puma560" in (await page.text_content('#fleet tr[data-name="r3"]') or "")
        assert "3 controllers" in (await page.text_content("#fleet-summary") or "")

        fleet.command("r2 estop")
        await page.wait_for_selector(light("r2", "e_stopped", "on"))
        await page.wait_for_selector(light("r2", "drives_powered", "off"))
        assert await page.locator(light("r1", "e_stopped", "off")).count() == 1
        assert "1 e-stopped" in (await page.text_content("#fleet-summary") or "")

        # r2's own page, under /c/r2/: its scripts load from there, it draws, it is r2's
        await page.click('#fleet tr[data-name="r2"] td.name a')
        await page.wait_for_function(PAGE_READY)
        assert page.url == view.controller_url("r2")
        assert "r2" in (await page.text_content("#controller-name") or "")
        await page.wait_for_selector('[data-light="e_stopped"][data-state="on"]')
        assert await page.is_enabled('button[data-command="reset"]')
        await page.click('button[data-command="reset"]')
        await page.wait_for_selector('[data-light="e_stopped"][data-state="off"]')
        assert not fleet["r2"].cell.e_stopped

        # and back to the index, which shows it
        await page.click("#fleet-link")
        await page.wait_for_selector(light("r2", "e_stopped", "off"))
        assert page.url == view.url
        assert problems == []


async def test_a_page_without_the_token_is_read_only() -> None:
    async with fleet_web(TOKEN) as (fleet, view), browser() as (page, problems):
        await page.goto(view.controller_url("r1"))
        await page.wait_for_function(PAGE_READY)
        await page.wait_for_selector("#read-only:not([hidden])")
        assert "token" in (await page.text_content("#read-only") or "")
        for command in ("estop", "reset", "drives off"):
            assert await page.is_disabled(f'button[data-command="{command}"]')
        assert not fleet["r1"].cell.e_stopped
        # the index says so too, and its links carry the token it was given
        await page.goto(view.url)
        await page.wait_for_selector("#read-only:not([hidden])")
        await page.goto(view.token_url)
        await page.wait_for_function("window.fleetview && window.fleetview.polls > 0")
        assert await page.is_hidden("#read-only")
        await page.click('#fleet tr[data-name="r1"] td.name a')
        await page.wait_for_function(PAGE_READY)
        assert page.url == token_url(view.controller_url("r1"), TOKEN)
        assert await page.is_hidden("#read-only")
        await page.click('button[data-command="estop"]')
        await page.wait_for_selector('[data-light="e_stopped"][data-state="on"]')
        assert fleet["r1"].cell.e_stopped and not fleet["r2"].cell.e_stopped
        await page.click('button[data-command="reset"]')
        await page.wait_for_selector('[data-light="e_stopped"][data-state="off"]')
        assert problems == []
