"""Adding a controller family is one module: tests/acme_dialect.py, registered on import.

What CONTRIBUTING.md's "Adding a dialect" promises, shown end to end: the emulator serves the new
family on its ports, in its byte order, with its reply style and its connection limits; the
endpoints match replies by its rule; the driver and ``robot-server --import`` pick it up by name.
The built-in profiles are checked against their dialects the same way.
"""

from __future__ import annotations

import asyncio
import dataclasses
import importlib
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from client.driver import RobotDriver
from client.trajectory import Trajectory
from robot_server import Emulator, EmulatorConfig, ModelError, load_model
from robot_server.emulator import PROFILES, profile_named, unregister_profile
from simple_message import (
    BE32,
    BE64,
    DIALECTS,
    FANUC,
    GENERIC,
    LE32,
    MOTOROS,
    Client,
    HeaderOnly,
    JointPosition,
    JointTrajPt,
    Message,
    MsgType,
    Port,
    ReplyCode,
    ReplyStyle,
    SpecialSeq,
)
from simple_message import dialects as dialects_module
from tests.test_rs_server_process import robot_server

MODULE = "tests.acme_dialect"
MODEL = load_model("jibot_zxs")


@pytest.fixture
def acme() -> Iterator[ModuleType]:
    module = importlib.import_module(MODULE)
    try:
        yield module
    finally:  # leave the registries as they were
        unregister_profile("acme")
        dialects_module.unregister("acme")
        sys.modules.pop(MODULE, None)


def test_the_module_registers_a_dialect_and_a_profile(acme: ModuleType) -> None:
    assert DIALECTS["acme"] is acme.ACME and PROFILES["acme"] is acme.ACME_PROFILE
    config = EmulatorConfig(profile="acme")
    assert config.wire == BE64 and config.byte_order == "big" and config.float64
    assert config.reply_style is ReplyStyle.HEADER_ONLY
    assert (config.port("motion"), config.port("state"), config.port("io")) == (12000, 12002, None)
    # the user's choices still win over the dialect's defaults
    chosen = EmulatorConfig(profile="acme", byte_order="little", float64=False, reply_style="echo", motion_port=0)
    assert chosen.wire == LE32 and chosen.reply_style is ReplyStyle.ECHO and chosen.port("motion") == 0
    with pytest.raises(ValueError, match="cannot reply moto-motion-reply"):
        EmulatorConfig(profile="acme", reply_style=ReplyStyle.MOTO_MOTION_REPLY)


def test_unknown_profiles_name_the_known_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown profile 'acme' \(known: abb, fanuc, generic, motoros, staubli\)"):
        EmulatorConfig(profile="acme")
    with pytest.raises(ValueError, match="unknown reply style 'loud'"):
        EmulatorConfig(reply_style="loud")


async def test_the_emulator_serves_it_and_the_endpoints_speak_it(acme: ModuleType) -> None:
    config = EmulatorConfig(profile="acme", motion_port=0, state_port=0, simulated=True, state_rate=100.0)
    async with Emulator(config) as emu:
        assert set(emu.ports) == {"motion", "state"}
        assert emu.motion_server.max_connections == 1 and emu.state_server.max_connections == 2
        here = tuple(emu.cell.groups[0].command.actual_position)
        client = Client.tcp("127.0.0.1", emu.ports["motion"], BE64, dialect=acme.ACME, reconnect=None)
        state = Client.tcp("127.0.0.1", emu.ports["state"], BE64, reconnect=None)
        topics = state.subscribe(8, (MsgType.JOINT_POSITION,))
        await client.start(5.0)
        await state.start(5.0)
        try:
            reply = await client.request(JointTrajPt(0, here, 0.5, 0.0), timeout=5.0)
            assert isinstance(reply, HeaderOnly)  # ACME answers header-only
            assert (reply.msg_type, reply.reply_code) == (MsgType.JOINT_TRAJ_PT, ReplyCode.SUCCESS)
            position = await topics.get(5.0)  # decoded as big-endian float64: the real position
            assert isinstance(position, JointPosition)
            assert np.allclose(position.joint_data[: len(here)], here)
        finally:
            await client.close()
            await state.close()


async def test_the_driver_takes_it_by_name(acme: ModuleType) -> None:
    config = EmulatorConfig(profile="acme", motion_port=0, state_port=0, simulated=True, state_rate=100.0)
    async with Emulator(config) as emu:
        driver = RobotDriver(
            motion_port=emu.ports["motion"], state_port=emu.ports["state"], profile="acme", model=MODEL
        )
        assert driver.dialect is acme.ACME and driver.wire == BE64
        async with driver:
            start = (await driver.wait_state()).positions
            goal = start + np.array([0.2, -0.1, 0.1, 0.0, 0.0, 0.1])
            times = np.array([0.0, 1.0, 2.0])
            final = await driver.execute(Trajectory(times, np.stack([start, (start + goal) / 2, goal])), "download")
            assert np.max(np.abs(final.positions - goal)) <= driver.goal_tolerance
            assert emu.cell.groups[0].trajectories == 1


def test_the_driver_takes_its_defaults_from_the_dialect() -> None:
    fanuc = RobotDriver(profile="fanuc")
    assert (fanuc.motion_port, fanuc.state_port, fanuc.wire) == (Port.MOTION, Port.STATE, BE32)
    motoros = RobotDriver(profile=MOTOROS)
    assert (motoros.motion_port, motoros.state_port, motoros.wire) == (50240, 50241, LE32)
    assert motoros.dialect.motion_control and not fanuc.dialect.motion_control
    with pytest.raises(KeyError, match="unknown dialect 'nosuch'"):
        RobotDriver(profile="nosuch")


@pytest.mark.parametrize("name", ["generic", "motoros"])
def test_built_in_profiles_follow_their_dialects(name: str) -> None:
    profile = profile_named(name)
    dialect = DIALECTS[name]
    assert profile.dialect is dialect
    config = EmulatorConfig(profile=name)
    assert config.wire == dialect.wire and config.reply_style is dialect.reply_style
    for role in ("motion", "state", "io"):
        expected = dialect.ports.get(role) if role in profile.ports else None
        assert config.port(role) == expected
    assert GENERIC.reply_style is ReplyStyle.ECHO and FANUC.replies[MsgType.JOINT_TRAJ_PT] == {MsgType.JOINT_POSITION}
    with pytest.raises(TypeError):  # a dialect's rules are read-only, and a dialect is hashable
        FANUC.replies[MsgType.PING] = frozenset()  # type: ignore[index]
    assert len({GENERIC, FANUC, GENERIC}) == 2


class _Recorded:
    """A stand-in state server that notes the type of every topic broadcast."""

    def __init__(self) -> None:
        self.types: list[int] = []

    def broadcast(self, msg: Message, sessions: object = None) -> int:
        self.types.append(msg.msg_type)
        return 1


@pytest.mark.parametrize("name", ["generic", "motoros"])
def test_built_in_profiles_publish_their_dialects_state_topics(name: str) -> None:
    emulator = Emulator(EmulatorConfig(profile=name, motion_port=0, state_port=0, io_port=0))
    recorded = _Recorded()
    emulator.behaviour.publish(recorded, [])  # type: ignore[arg-type]
    assert tuple(recorded.types) == DIALECTS[name].state_topics


@pytest.mark.slow
async def test_robot_server_imports_a_family_by_module(tmp_path: Path) -> None:
    async with robot_server(tmp_path, "--import", MODULE, "--profile", "acme", "--no-stdin") as server:
        assert set(server.ports) == {"motion", "state"}
        client = Client.tcp("127.0.0.1", server.ports["motion"], BE64, reconnect=None)
        await client.start(10.0)
        try:  # a header-only reply in big-endian: what only the ACME profile sends
            reply = await client.request(JointTrajPt(SpecialSeq.STOP_TRAJECTORY), timeout=10.0)
        finally:
            await client.close()
        assert isinstance(reply, HeaderOnly)
        assert (reply.msg_type, reply.reply_code) == (MsgType.JOINT_TRAJ_PT, ReplyCode.SUCCESS)
        assert await server.terminate() == 0


def test_the_commands_import_before_they_list_and_say_what_is_unknown(capsys: pytest.CaptureFixture[str]) -> None:
    from client.cli import main as robot_client
    from robot_server.cli import main as robot_server_main

    assert robot_server_main(["--import", "no_such_module_here"]) == 2
    assert "cannot import no_such_module_here: ModuleNotFoundError" in capsys.readouterr().err
    assert robot_server_main(["--profile", "nosuch", "--no-stdin"]) == 2
    assert "unknown profile 'nosuch' (known: abb, fanuc, generic, motoros, staubli)" in capsys.readouterr().err
    assert robot_client(["demo", "--embedded", "--policies", "nosuch"]) == 2
    assert "unknown interpolation policy 'nosuch'" in capsys.readouterr().err
    try:  # an imported family is listed by --help and accepted by --profile
        with pytest.raises(SystemExit):
            robot_server_main(["--import", MODULE, "--help"])
        assert "acme: ACME RC-1" in capsys.readouterr().out
        with pytest.raises(SystemExit):
            robot_client(["status", "--import", MODULE, "--help"])
        assert "acme" in capsys.readouterr().out
    finally:
        unregister_profile("acme")
        dialects_module.unregister("acme")
        sys.modules.pop(MODULE, None)


def test_a_model_the_wire_cannot_carry_is_refused() -> None:
    twelve = dataclasses.replace(MODEL, name="twelve", joints=MODEL.joints * 2, motors=())
    with pytest.raises(ModelError, match="twelve has 12 joints; simple_message carries at most 10"):
        Emulator(EmulatorConfig(), [twelve])


async def test_a_port_that_cannot_be_bound_leaves_nothing_bound() -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        emulator = Emulator(EmulatorConfig(motion_port=0, state_port=port, simulated=True))
        with pytest.raises(OSError):
            await emulator.start()
    bound = emulator.ports["motion"]  # bound before the state port failed, and closed again
    with pytest.raises(ConnectionRefusedError):
        _, writer = await asyncio.wait_for(asyncio.open_connection("127.0.0.1", bound), 5.0)
        writer.close()
