"""The web view's server side (robot_server.web): the model and samples a page is sent, the traffic
list, the buttons' commands, bad input, and the command line. The page itself runs in a real
browser in test_rs_web_browser.py.

The emulator runs on a clock the test advances; the web view's own sampler is not started here
(``Feed.sample`` is called by the test), so what a page gets does not depend on timing. The fleet's
view and the token are tested in test_rs_web_fleet.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import re
import struct
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import pytest

import robot_server
from robot_server.control import SteppedClock
from robot_server.emulator import Emulator, EmulatorConfig
from robot_server.kinematics import link_frames
from robot_server.web import Feed, Page, TrafficTap, web_address
from robot_server.web.feed import MAX_FRAMES_PER_UPDATE
from robot_server.web.server import COMMAND_BURST, MAX_MESSAGE, WebView
from robot_server.web.traffic import summary
from simple_message.connection import TapLink
from tests.rawpeer import RawPeer, joint_traj_pt, vectors
from tests.stepped import settle, step
from tests.test_rs_server_process import robot_server as server_process

V = vectors("<")
PING = V["PING_REQUEST"]
JTP = V["JOINT_TRAJ_PT_REQUEST_SEQ3"]


@contextlib.asynccontextmanager
async def web_emulator(**options: Any) -> AsyncIterator[tuple[Emulator, SteppedClock, WebView]]:
    """An emulator on a stepped clock with its web view on a free port (sampler stopped)."""
    options.setdefault("motion_port", 0)
    options.setdefault("state_port", 0)
    clock = SteppedClock()
    emu = Emulator(EmulatorConfig(**options), clock=clock)
    view = WebView(emu, "127.0.0.1", 0)
    await emu.start()
    try:
        view.controller.autosample = False  # the test takes the samples
        await view.start()
        await step(clock, 0.0)
        yield emu, clock, view
        await settle(emu, clock)
    finally:
        await view.close()
        await emu.close(settle_timeout=1.0)


async def receive(ws: aiohttp.ClientWebSocketResponse, kind: str, timeout: float = 10.0) -> dict[str, Any]:
    """The next message of ``kind`` (others skipped), bounded."""
    async with asyncio.timeout(timeout):
        while True:
            msg = await ws.receive()
            assert msg.type is aiohttp.WSMsgType.TEXT, msg
            data: dict[str, Any] = json.loads(msg.data)
            if data["type"] == kind:
                return data


async def sample_and_receive(view: WebView, ws: aiohttp.ClientWebSocketResponse) -> dict[str, Any]:
    view.feed.sample()
    return await receive(ws, "update")


def chain_frames(group: dict[str, Any], q: list[float]) -> list[np.ndarray]:
    """What the page computes: base, then per joint pre, motion about the axis, post; then the tool."""

    def matrix(values: list[float]) -> np.ndarray:
        return np.array(values, dtype=float).reshape(4, 4)

    t = matrix(group["base"])
    frames = []
    for joint, value in zip(group["joints"], q, strict=True):
        theta = value + joint["offset"]
        x, y, z = joint["axis"]
        motion = np.eye(4)
        if joint["type"] == "prismatic":
            motion[:3, 3] = np.array(joint["axis"]) * theta
        else:
            k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
            motion[:3, :3] = np.eye(3) + math.sin(theta) * k + (1 - math.cos(theta)) * k @ k
        t = t @ matrix(joint["pre"]) @ motion @ matrix(joint["post"])
        frames.append(t)
    frames.append(t @ matrix(group["tool"]))
    return frames


# -- the hello: the model as the page builds it ----------------------------------------------------


GANTRY = """<?xml version="1.0"?>
<robot name="gantry">
  <link name="world"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="tool"/>
  <joint name="x" type="prismatic"><parent link="world"/><child link="l1"/><origin xyz="0 0 0.5" rpy="0 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-0.5" upper="0.5" velocity="1" effort="1"/></joint>
  <joint name="z" type="prismatic"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.2" rpy="0 0.3 0"/>
    <axis xyz="0 0 1"/><limit lower="-0.3" upper="0.3" velocity="1" effort="1"/></joint>
  <joint name="r" type="continuous"><parent link="l2"/><child link="l3"/><origin xyz="0.1 0 0" rpy="0.2 0 0"/>
    <axis xyz="0 0 1"/></joint>
  <joint name="f" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.2 0 0" rpy="0 0 0"/></joint>
</robot>
"""


@pytest.mark.parametrize("model", ["jibot_zxs", "puma560", "ur5", "kuka_kr6_r900_sixx.urdf", "gantry"])
async def test_hello_chain_is_the_controllers_kinematics(model: str, tmp_path: Path) -> None:
    """The page's chain (base, pre, axis, post, offset, tool) put together as the page does gives the
    controller's own link frames, for D-H (standard and modified) and URDF models, revolute and
    prismatic joints. (The browser test checks the page's own tool frame against the controller's.)"""
    name = model if not model.endswith(".urdf") else str(Path(robot_server.__file__).parent / "models" / model)
    if model == "gantry":
        (tmp_path / "gantry.urdf").write_text(GANTRY)
        name = str(tmp_path / "gantry.urdf")
    async with (
        web_emulator(models=(name,)) as (emu, _, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as ws,
    ):
        hello = await receive(ws, "hello")
        assert hello["version"] == 1
        (group,) = hello["groups"]
        m = emu.cell.groups[0].model
        assert [j["name"] for j in group["joints"]] == list(m.joint_names)
        if model == "gantry":
            assert [j["type"] for j in group["joints"]] == ["prismatic", "prismatic", "revolute"]
        rng = np.random.default_rng(7)
        for _ in range(5):
            q = rng.uniform(m.lower, m.upper)
            for mine, theirs in zip(chain_frames(group, list(q)), link_frames(m, q), strict=True):
                np.testing.assert_allclose(mine, theirs, atol=1e-12)
        assert hello["emulator"]["profile"] == "generic"
        assert hello["emulator"]["ports"] == emu.ports
        assert hello["emulator"]["window"] == 10.0


async def test_hello_carries_the_cells_workspace_zones() -> None:
    async with (
        web_emulator(cell="cell_example") as (emu, _, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as ws,
    ):
        zones = (await receive(ws, "hello"))["groups"][0]["zones"]
        sup = emu.cell.groups[0].supervision
        assert sup.has_zones
        if sup.allowed is not None:
            assert zones["allowed"]["lower"] == list(sup.allowed.lower)
        assert [z["name"] for z in zones["forbidden"]] == [b.name for b in sup.forbidden]
        assert zones["floor"] == sup.floor


# -- samples, waypoints, status ---------------------------------------------------------------------


async def test_updates_follow_a_streamed_trajectory_with_its_waypoints() -> None:
    async with (
        web_emulator() as (emu, clock, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as ws,
    ):
        await receive(ws, "hello")
        motion = await RawPeer.connect(emu.ports["motion"])
        try:
            targets = [[0.0] * 6, [0.2, -0.1, 0.1, 0.0, 0.0, 0.0], [0.4, -0.2, 0.2, 0.0, 0.0, 0.0]]
            for seq, q in enumerate(targets):
                reply = await motion.reply_to(joint_traj_pt(JTP, seq, q, velocity=0.5, duration=1.0))
                assert reply.reply_code == 1
            first = await sample_and_receive(view, ws)
            np.testing.assert_allclose([w["p"] for w in first["waypoints"]], targets, atol=1e-6)
            assert all(w["g"] == 0 for w in first["waypoints"])
            assert first["status"]["in_motion"] is True
            assert first["queue"][0]["capacity"] == 64
            assert {c["port"] for c in first["clients"]} == {"motion"}
            assert first["clients"][0]["byte_order"] == "little"
            await step(clock, 1.0)
            mid = await sample_and_receive(view, ws)
            assert mid["waypoints"] == []  # each waypoint is sent once
            assert mid["sample"]["t"] > first["sample"]["t"]
            g = mid["sample"]["groups"][0]
            assert 0.0 < g["ap"][0] < 0.4 and g["cv"][0] > 0.0
            assert g["fe"][0] == pytest.approx(g["cp"][0] - g["ap"][0], abs=1e-12)
            await settle(emu, clock)
            end = await sample_and_receive(view, ws)
            assert end["sample"]["groups"][0]["ap"][0] == pytest.approx(0.4, abs=1e-3)
            assert end["status"]["in_motion"] is False
        finally:
            await motion.close()
        # a page opened now gets the window's samples and waypoints in its hello
        async with http.ws_connect(view.url + "ws") as late:
            hello = await receive(late, "hello")
            assert len(hello["history"]) == 3
            assert len(hello["waypoints"]) == 3
            assert [s["t"] for s in hello["history"]] == sorted(s["t"] for s in hello["history"])


async def test_one_update_per_sample_at_most() -> None:
    """Decimation: a page is sent nothing between samples, one update per sample (at most 60 a second)."""
    async with web_emulator() as (emu, _, view):
        page = Page()
        view.feed.hello(page)
        assert view.feed.update(page) is None
        view.feed.sample()
        assert view.feed.update(page) is not None
        assert view.feed.update(page) is None
        with pytest.raises(ValueError, match=r"\(0, 60\]"):
            Feed(emu, rate=61.0)


async def test_status_lights_follow_faults_and_the_buttons_commands() -> None:
    async with (
        web_emulator() as (emu, _, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as ws,
    ):
        await receive(ws, "hello")
        await ws.send_json({"type": "command", "command": "estop"})
        assert await receive(ws, "result") == {"type": "result", "ok": True, "text": "estop"}
        assert emu.cell.e_stopped
        status = (await sample_and_receive(view, ws))["status"]
        assert status["e_stopped"] and not status["drives_powered"] and not status["motion_possible"]
        await ws.send_json({"type": "command", "command": "reset"})
        assert (await receive(ws, "result"))["ok"]
        await ws.send_json({"type": "command", "command": "alarm 4711 overheated"})
        assert (await receive(ws, "result"))["ok"]
        status = (await sample_and_receive(view, ws))["status"]
        assert status["in_error"] and status["error_code"] == 4711
        for command in ("reset", "mode manual"):
            await ws.send_json({"type": "command", "command": command})
            assert (await receive(ws, "result"))["ok"]
        assert (await sample_and_receive(view, ws))["status"]["mode"] == "MANUAL"
        await ws.send_json({"type": "command", "command": "mode auto"})
        assert (await receive(ws, "result"))["ok"]


async def test_motoros_status_is_the_state_ports() -> None:
    """MotoROS reports motion possible only in trajectory mode: the lights show what the state port says."""
    async with (
        web_emulator(profile="motoros", io_port=0) as (_, _, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as ws,
    ):
        await receive(ws, "hello")
        status = (await sample_and_receive(view, ws))["status"]
        assert status["motion_possible"] is False and status["drives_powered"] is True


# -- traffic ---------------------------------------------------------------------------------------


async def test_traffic_lists_the_frames_decoded() -> None:
    async with (
        web_emulator() as (emu, _, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as ws,
    ):
        await receive(ws, "hello")
        peer = await RawPeer.connect(emu.ports["motion"])
        try:
            for _ in range(3):
                await peer.request(PING)
            frames = (await sample_and_receive(view, ws))["traffic"]
        finally:
            await peer.close()
        pings = [f for f in frames if f["name"] == "PING"]
        assert [(f["dir"], f["comm"], f["reply"]) for f in pings] == [
            ("in", "SERVICE_REQUEST", "INVALID"),
            ("out", "SERVICE_REPLY", "SUCCESS"),
        ] * 3
        assert [f["n"] for f in frames] == list(range(frames[0]["n"], frames[0]["n"] + len(frames)))
        assert all(f["port"] == "motion" and re.fullmatch(r"127\.0\.0\.1:\d+", f["peer"]) for f in pings)


def test_traffic_tap_keeps_the_newest_and_counts_what_a_slow_page_missed() -> None:
    tap = TrafficTap(capacity=4)
    link = TapLink("motion 127.0.0.1:5", ("127.0.0.1", 11000), ("127.0.0.1", 5), accepted=True)
    tap.opened(link, 0)
    tap.data(link, False, PING * 3 + PING[:7], 1)  # three frames and the start of a fourth
    tap.data(link, False, PING[7:] + PING * 2, 2)
    assert tap.count == 6 and tap.first == 3
    assert [json.loads(f)["n"] for f in tap.since(1)] == [3, 4, 5, 6]
    assert [json.loads(f)["n"] for f in tap.since(5)] == [5, 6]


async def test_a_page_behind_is_told_how_many_frames_it_missed() -> None:
    """Frames that left the list before a page could be sent them, and frames beyond the newest
    MAX_FRAMES_PER_UPDATE of one update, are counted in ``skipped``, not sent."""
    emu = Emulator(EmulatorConfig(motion_port=0, state_port=0))
    link = TapLink("motion 127.0.0.1:5", ("127.0.0.1", 11000), ("127.0.0.1", 5), accepted=True)
    small = Feed(emu, frames=4)
    small.traffic.opened(link, 0)
    page = Page()
    small.hello(page)
    small.traffic.data(link, False, PING * 6, 1)
    small.sample()
    update = json.loads(small.update(page) or "")
    assert [f["n"] for f in update["traffic"]] == [3, 4, 5, 6] and update["skipped"] == 2
    big = Feed(emu)
    big.traffic.opened(link, 0)
    page = Page()
    big.hello(page)
    big.traffic.data(link, False, PING * (MAX_FRAMES_PER_UPDATE + 25), 1)
    big.sample()
    update = json.loads(big.update(page) or "")
    assert len(update["traffic"]) == MAX_FRAMES_PER_UPDATE and update["skipped"] == 25
    assert update["traffic"][-1]["n"] == MAX_FRAMES_PER_UPDATE + 25


def test_traffic_tap_survives_garbage_and_malformed_bodies() -> None:
    tap = TrafficTap()
    link = TapLink("motion 127.0.0.1:5", None, ("127.0.0.1", 5), accepted=True)
    tap.opened(link, 0)
    short_ping = struct.pack("<iiiii", 16, 10, 1, 0, 7)  # PING with a 4-byte body: not PING's layout
    tap.data(link, False, short_ping, 1)
    tap.data(link, False, struct.pack("<i", -5) + b"\x00" * 40, 2)  # a length no frame has
    tap.data(link, False, PING, 3)  # that direction is no longer read
    entries = [json.loads(f) for f in tap.since(1)]
    assert entries[0]["msg_type"] == 10 and entries[0]["summary"].startswith("malformed")
    assert entries[1]["name"] == "UNFRAMEABLE"
    assert len(entries) == 2
    tap.closed(link, True, 4)


def test_summary_is_short_and_drops_the_unused_joint_slots() -> None:
    body = {"sequence": 3, "joint_data": [0.1, 0.25, 0.0] + [0.0] * 7, "velocity": 0.5, "duration": 1.0}
    assert summary(body) == "sequence=3 joint_data=[0.1, 0.25, …] velocity=0.5 duration=1"
    assert len(summary({"raw": "ab" * 500})) == 160


# -- bad input -------------------------------------------------------------------------------------


async def test_bad_messages_are_answered_and_hurt_no_one() -> None:
    async with (
        web_emulator() as (emu, _, view),
        aiohttp.ClientSession() as http,
        http.ws_connect(view.url + "ws") as bystander,
        http.ws_connect(view.url + "ws") as ws,
    ):
        await receive(bystander, "hello")
        await receive(ws, "hello")
        for bad, error in [
            ("not json", "not JSON"),
            ("[1, 2]", "expected"),
            ('{"type": "command", "command": 5}', "fault command"),
            ('{"type": "command", "command": "explode"}', "unknown fault command"),
            ('{"type": "command", "command": "alarm x"}', "numeric code"),
            ('{"type": "command", "command": "alarm 99999999999 x"}', "1 to 2147483647"),
            ("[" * 3000, "not JSON"),  # deeper than the parser recurses
        ]:
            await ws.send_str(bad)
            result = await receive(ws, "result")
            assert result["ok"] is False and error in result["error"], (bad, result)
        await ws.send_bytes(b"\x00\x01")
        assert not (await receive(ws, "result"))["ok"]
        # a burst of commands: the excess refused
        results = []
        for _ in range(COMMAND_BURST + 5):
            await ws.send_json({"type": "command", "command": "stop"})
            results.append(await receive(ws, "result"))
        refused = [r for r in results if not r["ok"]]
        assert len(refused) >= 5 and "commands a second" in refused[0]["error"]
        # too long a message closes that page only
        await ws.send_str("x" * (MAX_MESSAGE + 1))
        async with asyncio.timeout(10.0):
            while (await ws.receive()).type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                pass
        assert (await sample_and_receive(view, bystander))["status"]["e_stopped"] is False
        assert not emu.cell.in_motion and not emu.cell.e_stopped


async def test_a_page_of_another_site_is_refused() -> None:
    async with web_emulator() as (emu, _, view), aiohttp.ClientSession() as http:
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(view.url + "ws", origin="http://evil.example")
        assert refused.value.status == 403
        # DNS rebinding: another site's name made to point at 127.0.0.1, Host and Origin agreeing
        rebound = {"Host": f"evil.example:{view.port}"}
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(view.url + "ws", origin=f"http://evil.example:{view.port}", headers=rebound)
        assert refused.value.status == 403
        async with http.ws_connect(view.url + "ws", origin=f"http://127.0.0.1:{view.port}") as ws:
            await receive(ws, "hello")
            await ws.send_json({"type": "command", "command": "estop"})
            assert (await receive(ws, "result"))["ok"]
        assert emu.cell.e_stopped


async def test_page_and_static_files_are_served() -> None:
    async with web_emulator() as (_, _, view), aiohttp.ClientSession() as http:
        async with http.get(view.url) as page:
            assert page.status == 200
            html = await page.text()
        also = ["/static/vendor/three/three.core.js", "/static/vendor/three/LICENSE", "/static/vendor/uplot/LICENSE"]
        # every address in the page is relative (it is served at / and at a fleet's /c/NAME/ alike)
        assert not re.findall(r'(?:src|href)="/', html) and '"/static' not in html
        linked = re.findall(r'(?:src|href)="(static/[^"]+)"', html) + re.findall(r'"\./(static/[^"]+)"', html)
        assert len(linked) >= 5, linked
        for path in [*linked, *also]:
            async with http.get(view.url + path.lstrip("/")) as response:
                assert response.status == 200, path
        assert "//cdn" not in html and "https://" not in html  # everything comes from the package
        async with http.get(view.url + "static/../feed.py") as escape:
            assert escape.status in (403, 404)


# -- the command line ------------------------------------------------------------------------------


def test_web_address() -> None:
    assert web_address("8080") == ("127.0.0.1", 8080)
    assert web_address("0.0.0.0:80") == ("0.0.0.0", 80)
    assert web_address("[::1]:0") == ("::1", 0)
    for bad in ("http", "1:2:x", "70000", ":-1", "::1"):
        with pytest.raises(ValueError):
            web_address(bad)


@pytest.mark.slow
async def test_ready_line_prints_the_url_and_the_page_answers(tmp_path: Path) -> None:
    async with server_process(tmp_path, "--web", "0") as server:
        url = re.search(r"web view (http://127\.0\.0\.1:\d+/)$", server.ready)
        assert url, server.ready
        async with aiohttp.ClientSession() as http, http.ws_connect(url.group(1) + "ws") as ws:
            assert (await receive(ws, "hello"))["emulator"]["ready"] in server.ready
            await receive(ws, "update")  # the process samples on its own
        assert await server.terminate() == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--web", "x:y"], "[HOST:]PORT"), (["--web", "80", "--web-rate", "100"], "at most 60")],
)
def test_bad_web_options(args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    from robot_server.cli import main

    with pytest.raises(SystemExit) if args[0] == "--web" and args[1] == "x:y" else contextlib.nullcontext():
        code = main(["--no-stdin", *args])
        assert code == 2
    assert message in capsys.readouterr().err
