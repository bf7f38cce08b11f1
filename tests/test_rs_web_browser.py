"""The web view in a real browser: headless Chromium (Debian's ``chromium``) driven by playwright,
against a ``robot-server --web`` process, moved by ``robot-client`` processes and watched on its
state port with raw frames.

Without a chromium these tests are skipped with the reason, except where ``REQUIRE_BROWSER`` is set
(``.ci/run`` sets it, after installing chromium with apt-get): there a missing browser fails.
``UPDATE_SCREENSHOT=1`` also writes the screenshot taken during the demo to
``docs/figures/web-view.png`` (the README's).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import shutil
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest
from playwright.async_api import ConsoleMessage, Page, async_playwright

from robot_server.kinematics import fk
from robot_server.loader import load_model
from tests.rawpeer import RawPeer, joint_position, status, vectors
from tests.test_rs_server_process import ServerProcess, robot_server

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
SCREENSHOT = ROOT / "docs" / "figures" / "web-view.png"
PING = vectors("<")["PING_REQUEST"]
MODEL = load_model("jibot_zxs")
JOINT_POSITION, STATUS = 10, 13
#: Chromium's own console warning with --disable-gpu (WebGL frames read back in software): not the page's
CHROMIUM_OWN = re.compile(
    r"^\[\.WebGL-0x[0-9a-fA-F]+\]GL Driver Message \(OpenGL, Performance, GL_CLOSE_PATH_NV, High\)"
)
#: every wait in the browser, ms
WAIT = 30_000
CHROMIUM = os.environ.get("CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
#: what the probe of this machine found Chromium needs headless, as root, offline
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]

if CHROMIUM is None:
    if os.environ.get("REQUIRE_BROWSER"):
        raise RuntimeError("REQUIRE_BROWSER is set but no chromium was found (apt-get install chromium)")
    pytest.skip(
        "no chromium on this machine (apt-get install chromium): browser tests not run", allow_module_level=True
    )


class Server:
    def __init__(self, process: ServerProcess) -> None:
        self.process, self.ports = process, process.ports
        url = re.search(r"web view (http://\S+/)$", process.ready)
        assert url, process.ready
        self.url = url.group(1)

    def client(self, *args: str) -> list[str]:
        """A robot-client command line against this server."""
        ports = ["--motion-port", str(self.ports["motion"]), "--state-port", str(self.ports["state"])]
        return [sys.executable, "-m", "client", args[0], *ports, *args[1:]]


@contextlib.asynccontextmanager
async def web_server(tmp_path: Path) -> AsyncIterator[Server]:
    """``robot-server --web 0`` on free ports; SIGTERM at the end (it stops the robot first)."""
    async with robot_server(tmp_path, "--web", "0") as process:
        try:
            yield Server(process)
        finally:
            await process.terminate()


@contextlib.asynccontextmanager
async def browser_page(url: str) -> AsyncIterator[tuple[Page, list[str]]]:
    """The page open and drawing; the list collects every console error or warning and page error."""
    assert CHROMIUM is not None
    async with async_playwright() as p:
        browser = await p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = await browser.new_page(viewport={"width": 1280, "height": 820})
            page.set_default_timeout(WAIT)
            problems: list[str] = []

            def console(m: ConsoleMessage) -> None:
                if m.type in ("error", "warning") and not CHROMIUM_OWN.match(m.text):
                    problems.append(f"{m.type}: {m.text}")

            page.on("console", console)
            page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            await page.goto(url)
            await page.wait_for_function("window.webview && window.webview.connected && window.webview.renders > 2")
            yield page, problems
        finally:
            await browser.close()


@contextlib.asynccontextmanager
async def running(*command: str) -> AsyncIterator[asyncio.subprocess.Process]:
    proc = await asyncio.create_subprocess_exec(
        *command, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE
    )
    try:
        yield proc
    finally:
        if proc.returncode is None:
            proc.send_signal(signal.SIGTERM)  # robot-client stops the robot, then exits
            try:
                await asyncio.wait_for(proc.wait(), 20.0)
            except TimeoutError:
                proc.kill()
                await proc.wait()


# what the 3D view drew: pixels unlike the background, and how many colours
_CANVAS_PIXELS = """() => {
    const gl = document.querySelector('#robot3d canvas');
    const copy = document.createElement('canvas');
    copy.width = gl.width; copy.height = gl.height;
    const ctx = copy.getContext('2d');
    ctx.drawImage(gl, 0, 0);
    const d = ctx.getImageData(0, 0, copy.width, copy.height).data;
    const bg = [d[0], d[1], d[2]];
    let differ = 0; const colours = new Set();
    for (let i = 0; i < d.length; i += 4) {
        if (Math.abs(d[i] - bg[0]) + Math.abs(d[i + 1] - bg[1]) + Math.abs(d[i + 2] - bg[2]) > 24) differ++;
        colours.add((d[i] >> 3) << 10 | (d[i + 1] >> 3) << 5 | (d[i + 2] >> 3));
    }
    return {pixels: d.length / 4, differ, colours: colours.size};
}"""

# the x range of the position plot and how far its series have moved within it
_POSITION_PLOT = """() => {
    const u = window.webview.plots[0];
    const [xs, ...series] = u.data;
    let lo = Infinity, hi = -Infinity;
    for (const s of series) for (const v of s) {
        if (v !== null && v !== undefined) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    return {xmax: xs.length ? xs[xs.length - 1] : null, spread: hi - lo, points: xs.length};
}"""


async def test_page_loads_and_draws_the_robot_without_console_errors(tmp_path: Path) -> None:
    async with web_server(tmp_path) as server, browser_page(server.url) as (page, problems):
        drawn = await page.evaluate(_CANVAS_PIXELS)
        assert drawn["differ"] > 0.01 * drawn["pixels"], drawn  # the robot, grid and axes, not a blank canvas
        assert drawn["colours"] >= 8, drawn
        await page.wait_for_selector('[data-light="drives_powered"][data-state="on"]')
        await page.wait_for_selector('[data-light="e_stopped"][data-state="off"]')
        assert (await page.text_content("#mode") or "").strip() == "AUTO"
        assert "blend" in (await page.text_content("#policy") or "")
        assert re.search(r"0 / 64", await page.text_content("#queue") or ""), await page.text_content("#queue")
        assert await page.locator("#plots canvas").count() >= 4  # position, velocity, acceleration, error
        assert problems == []


async def test_plots_advance_while_a_trajectory_runs(tmp_path: Path) -> None:
    async with web_server(tmp_path) as server, browser_page(server.url) as (page, problems):
        before = await page.evaluate(_POSITION_PLOT)
        move = server.client("move", "--joints", "0.6", "-0.3", "0.3", "0", "0", "0", "--speed", "0.5")
        async with running(*move) as proc:
            await page.wait_for_selector('[data-light="in_motion"][data-state="on"]')
            await page.wait_for_function(
                f"() => ({_POSITION_PLOT})().spread > 0.2 && ({_POSITION_PLOT})().xmax > {before['xmax'] or 0} + 0.5"
            )
            assert await asyncio.wait_for(proc.wait(), 60.0) == 0
        after = await page.evaluate(_POSITION_PLOT)
        assert after["xmax"] > before["xmax"] and after["points"] > 10
        # the waypoints of the move were received and are kept for the marks on the plot
        assert await page.evaluate("() => window.webview.waypoints") > 0
        # the 3D robot is the controller's kinematics: the page's tool frame is the controller's FK
        drawn = await page.evaluate("() => window.webview.toolPose(0)")
        assert abs(drawn["q"][0] - 0.6) < 0.01
        np.testing.assert_allclose(np.reshape(drawn["pose"], (4, 4)), fk(MODEL, drawn["q"]), atol=1e-9)
        await page.wait_for_selector('[data-light="in_motion"][data-state="off"]')
        # the clients table showed the move's connections; the plot keeps scrolling with the clock
        await page.wait_for_function(f"() => ({_POSITION_PLOT})().xmax > {after['xmax']} + 0.2")
        assert problems == []


async def test_estop_on_the_page_stops_the_robot(tmp_path: Path) -> None:
    async with web_server(tmp_path) as server, browser_page(server.url) as (page, problems):
        state = await RawPeer.connect(server.ports["state"])
        try:
            move = server.client("move", "--joints", "2.0", "-0.8", "0.8", "0", "0", "0", "--speed", "0.2")
            async with running(*move) as proc:
                await page.wait_for_selector('[data-light="in_motion"][data-state="on"]')
                await page.click('button[data-command="estop"]')
                await page.wait_for_selector('[data-light="e_stopped"][data-state="on"]')
                await page.wait_for_selector('[data-light="drives_powered"][data-state="off"]')
                await page.wait_for_selector('[data-light="motion_possible"][data-state="off"]')
                await page.wait_for_selector('[data-light="in_motion"][data-state="off"]')
                # the state port says so too, and the robot stands where it stopped, short of its goal
                async with asyncio.timeout(20.0):
                    while status(await state.next_of(STATUS))["e_stopped"] != 1:
                        pass
                    held = joint_position(await state.next_of(JOINT_POSITION))
                    for _ in range(5):
                        assert joint_position(await state.next_of(JOINT_POSITION)) == held
                assert 0.0 < held[0] < 1.9
                assert await asyncio.wait_for(proc.wait(), 30.0) == 1  # the client saw its motion fail
        finally:
            await state.close()
        assert "estop" in (await page.text_content("#command-result") or "")
        await page.click('button[data-command="reset"]')
        await page.wait_for_selector('[data-light="e_stopped"][data-state="off"]')
        await page.wait_for_selector('[data-light="drives_powered"][data-state="on"]')
        assert problems == []


async def test_traffic_list_shows_the_pings_a_test_sends_and_pauses(tmp_path: Path) -> None:
    async with web_server(tmp_path) as server, browser_page(server.url) as (page, problems):
        peer = await RawPeer.connect(server.ports["motion"])
        try:
            for _ in range(3):
                await peer.request(PING)
            rows = page.locator('#traffic tbody tr[data-name="PING"]')
            await page.wait_for_function(
                """() => document.querySelectorAll('#traffic tbody tr[data-name="PING"]').length >= 6"""
            )
            assert "127.0.0.1:" in (await rows.first.text_content() or "")
            await page.click("#traffic-pause")
            seen = await page.evaluate("() => window.webview.traffic")
            for _ in range(2):
                await peer.request(PING)
            await page.wait_for_function(f"() => window.webview.traffic >= {seen} + 4")  # received, not shown
            assert await rows.count() == 6
            await page.click("#traffic-pause")
            await page.wait_for_function(
                """() => document.querySelectorAll('#traffic tbody tr[data-name="PING"]').length >= 10"""
            )
            # the client list names the test's connection
            await page.wait_for_function(
                "() => document.querySelector('#clients tbody').textContent.includes('motion')"
            )
        finally:
            await peer.close()
        assert problems == []


async def test_screenshot_during_the_demo(tmp_path: Path) -> None:
    """The README's picture: the page while the paper's experiment runs on the emulator."""
    async with web_server(tmp_path) as server, browser_page(server.url) as (page, problems):
        demo = server.client("demo", "--no-plot", "--no-movl", "--output", str(tmp_path / "demo"))
        async with running(*demo):
            await page.wait_for_selector('[data-light="in_motion"][data-state="on"]', timeout=60_000)
            await page.wait_for_function(f"() => ({_POSITION_PLOT})().spread > 0.05", timeout=60_000)
            # the rectangle itself (its waypoints stream after the approach move), a few seconds into it
            await page.wait_for_function("() => window.webview.waypoints > 15", timeout=60_000)
            then = await page.evaluate("() => window.webview.lastTime")
            await page.wait_for_function(f"() => window.webview.lastTime > {then} + 4", timeout=60_000)
            shot = tmp_path / "web-view.png"
            await page.screenshot(path=str(shot))
        assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000
        if os.environ.get("UPDATE_SCREENSHOT"):
            SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(shot, SCREENSHOT)
        assert problems == []
