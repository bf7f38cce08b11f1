"""The pytest plugin's ``robot_controller`` fixture used by this repository's own tests, as any
project's tests use it (the package's ``pytest11`` entry point provides it): in process, sync and
async, on the stepped and the sped-up clock, and as a ``robot-server`` process. The leak guard of
tests/conftest.py checks that each test leaves no task, thread, descriptor or logging filter
behind, after a timeout too. No wall time is measured: "finished" is the controller's time.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import socket
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from robot_server.cli import parser as robot_server_parser
from robot_server.emulator import FaultError
from robot_server.testing import (
    ControllerError,
    ControllerFactory,
    ControllerTimeout,
    RobotController,
    SettingsError,
    assert_reached,
    assert_stopped_within,
    assert_within_limits,
)
from robot_server.testing.settings import OPTION_KEYS, command_line, read_settings
from simple_message import Client
from simple_message.constants import MotoCommand, MsgType, ReplyCode, TriState, ValidFields
from simple_message.messages import JointTrajPt, JointTrajPtFull, MotoMotionCtrl, MotoMotionReply, encode
from simple_message.wire import WireFormat

TARGET = (0.5, -0.3, 0.4, 0.2, 0.3, -0.5)
REQUEST = 2  # comm_type SERVICE_REQUEST


# -- a client that knows only sockets and struct (as one in another language would) -------------------


def frame(msg_type: int, body: bytes = b"") -> bytes:
    return struct.pack("<4i", 12 + len(body), msg_type, REQUEST, 0) + body


def joint_traj_pt(sequence: int, joints: tuple[float, ...], velocity: float, duration: float) -> bytes:
    padded = list(joints) + [0.0] * (10 - len(joints))
    return frame(MsgType.JOINT_TRAJ_PT, struct.pack("<i10f2f", sequence, *padded, velocity, duration))


def read_frame(sock: socket.socket) -> tuple[int, int, int, bytes]:
    """(msg_type, comm_type, reply_code, body) of the next frame."""

    def exactly(count: int) -> bytes:
        data = b""
        while len(data) < count:
            chunk = sock.recv(count - len(data))
            assert chunk, "the controller closed the connection"
            data += chunk
        return data

    (length,) = struct.unpack("<i", exactly(4))
    data = exactly(length)
    msg_type, comm_type, reply_code = struct.unpack_from("<3i", data)
    return msg_type, comm_type, reply_code, data[12:]


@contextlib.contextmanager
def moving(ctrl: RobotController, target: tuple[float, ...], duration: float) -> Iterator[socket.socket]:
    """A JOINT_TRAJ_PT trajectory from where the robot is to ``target`` in ``duration`` s: inside
    the block both points are acknowledged (queued) and the motion connection is open (the
    controller stops the robot when its motion client leaves)."""
    with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=10) as sock:
        for sequence, point, seconds in ((0, ctrl.joints, 0.0), (1, target, duration)):
            sock.sendall(joint_traj_pt(sequence, tuple(point), 0.5, seconds))
            assert read_frame(sock)[:3] == (MsgType.JOINT_TRAJ_PT, 3, ReplyCode.SUCCESS)
        yield sock


# -- settings ------------------------------------------------------------------------------------------


def test_a_misspelt_or_ill_typed_setting_is_refused_naming_the_key(robot_controller) -> None:
    with pytest.raises(
        SettingsError, match=r"robot_controller\(c1\): state_rat: unknown key; did you mean state_rate\?"
    ):
        robot_controller(state_rat=40)
    with pytest.raises(SettingsError, match=r"robot_controller\(c1\): queue_size: must be a whole number, not 'many'"):
        robot_controller(queue_size="many")
    with pytest.raises(SettingsError, match=r"unknown profile 'yaskawa' \(known: abb, fanuc, generic, motoros"):
        robot_controller(profile="yaskawa")
    with pytest.raises(SettingsError, match=r'speedup must be a number > 0, "step" or None'):
        robot_controller(speedup="fast")
    with pytest.raises(SettingsError, match=r"process keeps its own clock"):
        robot_controller(speedup="step", process=True)
    with pytest.raises(SettingsError, match=r"initial_position: robot-server has no such option"):
        robot_controller(process=True, initial_position=[0.0] * 6)
    with pytest.raises(SettingsError, match=r"record: a process's record is read back from .npz, not 'run.csv'"):
        robot_controller(process=True, record="run.csv")
    assert robot_controller.handles == []


def test_a_taken_port_is_refused_before_anything_starts(robot_controller) -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        with pytest.raises(SettingsError, match=rf"robot_controller\(c1\): motion_port: cannot bind 127.0.0.1:{port}"):
            robot_controller(motion_port=port)


def test_every_setting_is_an_option_of_robot_server() -> None:
    known = {action.dest for action in robot_server_parser()._actions}
    assert set(OPTION_KEYS) - {"model", "faults", "profile_options", "queue_size"} <= known
    assert {"model", "fault", "profile_option", "queue_size"} <= known


def test_a_process_s_command_line_is_read_back_to_the_same_settings() -> None:
    settings = read_settings(
        "arm",
        "motoros",
        ["jibot_zxs", "puma560"],
        speedup=20,
        process=True,
        settings={
            "state_rate": 50,
            "interpolation": "quintic",
            "lenient": True,
            "faults": ["1.5:estop", "2:reset"],
            "profile_options": {},
            "record_seconds": 30,
        },
    )
    args = robot_server_parser().parse_args(command_line(settings))
    assert args.model == ["jibot_zxs", "puma560"]
    assert (args.profile, args.state_rate, args.interpolation, args.lenient) == ("motoros", 50.0, "quintic", True)
    assert (args.motion_port, args.state_port, args.io_port, args.speedup) == (0, 0, 0, 20.0)
    assert args.fault == [(1.5, "estop"), (2.0, "reset")]
    assert args.record_seconds == 30.0


# -- in process, sync -----------------------------------------------------------------------------------


def test_a_generic_and_a_motoros_controller_at_once_over_raw_sockets(robot_controller) -> None:
    generic = robot_controller(speedup="step")
    motoros = robot_controller(profile="motoros", speedup="step")
    assert generic.host == motoros.host == "127.0.0.1"
    assert generic.io_port is None and motoros.io_port is not None
    assert len({generic.motion_port, generic.state_port, motoros.motion_port, motoros.state_port}) == 4
    wire = WireFormat()
    for ctrl in (generic, motoros):
        with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=10) as sock:
            sock.sendall(frame(MsgType.PING))
            assert read_frame(sock)[:3] == (MsgType.PING, 3, ReplyCode.SUCCESS)

    with moving(generic, TARGET, 2.0), socket.create_connection((motoros.host, motoros.motion_port), 10) as sock:
        sock.sendall(encode(MotoMotionCtrl(0, 0, MotoCommand.START_TRAJ_MODE, comm_type=REQUEST), wire))
        read_frame(sock)
        start = motoros.joints
        fields = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
        for sequence, (at, point) in enumerate(((0.0, start), (2.0, TARGET))):
            sock.sendall(encode(JointTrajPtFull(0, sequence, fields, at, point, comm_type=REQUEST), wire))
            msg_type, _, _, body = read_frame(sock)
            assert msg_type == MsgType.MOTO_MOTION_REPLY
            assert MotoMotionReply.LAYOUT[3][0] == "result"
            assert struct.unpack_from("<4i", body)[3] == 0, "MotoROS refused the point"
        done = [generic.wait_idle(10.0), motoros.wait_idle(10.0)]
    assert all(2.0 <= t < 3.0 for t in done), done
    for ctrl in (generic, motoros):
        assert ctrl.joints == pytest.approx(TARGET, abs=1e-4)
        assert_reached(ctrl, TARGET, tol=1e-4, settled=True)
        assert ctrl.status.in_motion == TriState.FALSE


@pytest.mark.parametrize("speedup", ["step", 40.0], ids=["stepped", "sped-up"])
def test_a_20_s_move_finishes_by_the_controller_s_clock_where_it_should(robot_controller, speedup: object) -> None:
    ctrl = robot_controller(speedup=speedup)
    begin = ctrl.time
    with moving(ctrl, TARGET, 20.0):
        done = ctrl.wait_idle(60.0)
    # sped up, the wall time before the move starts (the requests) counts 40 times: by the record, the move
    # itself took its 20 s of controller time; stepped, nothing passes between the test's steps
    assert done - begin >= 20.0
    if speedup == "step":
        assert done - begin < 21.0
    assert ctrl.time >= done
    record = ctrl.record
    moved = record.time()[np.any(record.get("command_velocity") != 0.0, axis=1)]
    assert 19.99 <= moved[-1] - moved[0] <= 20.1
    assert_reached(ctrl, TARGET, tol=1e-4, settled=True)
    assert_within_limits(ctrl)


def test_the_stepped_clock_moves_only_when_the_test_says(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    assert ctrl.stepped and ctrl.time == pytest.approx(0.004)
    assert ctrl.advance(0.5) == pytest.approx(0.504)
    assert ctrl.time == pytest.approx(0.504)
    assert ctrl.advance_until(lambda: ctrl.time >= 1.0, 5.0) == pytest.approx(1.0)
    with pytest.raises(ControllerTimeout, match=r"c1: the robot moving: not within 0.5 s of controller time"):
        ctrl.advance_until(lambda: ctrl.in_motion, 0.5, what="the robot moving")
    assert ctrl.time == pytest.approx(1.5)


def test_a_predicate_that_raises_fails_the_wait_not_the_controller(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    calls = 0

    def broken() -> bool:
        nonlocal calls
        calls += 1
        if calls == 10:
            raise KeyError("the test's own defect")
        return False

    before = ctrl.time
    with pytest.raises(KeyError, match="the test's own defect"):
        ctrl.advance_until(broken, 5.0)
    stood = ctrl.time
    assert stood == pytest.approx(before + 8 * 0.004), "checked once, then before every period: eight ran"
    assert ctrl.advance(0.1) == pytest.approx(stood + 0.1), "the control loop runs on"
    with moving(ctrl, TARGET, 1.0):
        assert ctrl.wait_idle(5.0) >= stood + 1.1


def test_a_stop_in_the_middle_of_a_move_is_seen_in_the_record(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    with moving(ctrl, TARGET, 20.0):
        ctrl.advance(5.0)
        since = ctrl.time
        assert ctrl.in_motion
        assert ctrl.fault("stop") == "stop"
        ctrl.wait_idle(5.0)
    took = assert_stopped_within(ctrl, since, ms=1000)
    assert 0.0 < took < 1.0
    assert ctrl.joints != pytest.approx(TARGET, abs=1e-2)


def test_fault_commands_are_robot_server_s(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    assert ctrl.fault("estop") == "estop"
    status = ctrl.status
    assert (status.e_stopped, status.drives_powered) == (TriState.TRUE, TriState.FALSE)
    with pytest.raises(FaultError, match="the drives cannot be powered while the emergency stop is engaged"):
        ctrl.fault("drives on")
    with pytest.raises(FaultError, match=r"unknown fault command 'explode'"):
        ctrl.fault("explode")
    ctrl.fault("reset")
    ctrl.fault("alarm 42 overheated")
    assert (ctrl.status.in_error, ctrl.status.error_code) == (TriState.TRUE, 42)


def test_the_record_a_test_reads_does_not_grow_under_it(robot_controller) -> None:
    ctrl = robot_controller(speedup=10.0)
    record = ctrl.record
    ticks = len(record)
    ctrl.advance(0.5)
    assert len(record) == ticks == record.time().size == record.get("actual_position").shape[0]
    assert len(ctrl.record) > ticks
    assert ctrl.model.name == "jibot_zxs" and [m.name for m in ctrl.models] == ["jibot_zxs"]
    two = robot_controller(speedup="step", model=["jibot_zxs", "puma560"])
    two.advance(0.1)
    assert [len(r) for r in two.records] == [104, 104]


def test_a_wait_that_times_out_says_where_the_robot_was_and_teardown_stops_it(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    with moving(ctrl, TARGET, 20.0):
        with pytest.raises(ControllerTimeout, match=r"c1: the robot at rest: not within 1 s of controller time"):
            ctrl.wait_idle(1.0)
        assert ctrl.in_motion  # moving still: the teardown brings it to rest and stops everything


def test_stop_frees_the_ports_at_once(robot_controller) -> None:
    ctrl = robot_controller()
    ports = ctrl.ports
    ctrl.stop()
    assert ctrl.closed
    for port in ports.values():
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", port))
    ctrl.stop()  # again: nothing
    assert ctrl.time > 0  # the last state stays readable


def test_a_controller_that_cannot_start_is_an_error_and_leaves_nothing(robot_controller) -> None:
    with pytest.raises(ValueError, match="no_such_cell"):
        robot_controller(cell="no_such_cell")


def test_the_controllers_get_names_and_a_name_is_one_controller_s(robot_controller) -> None:
    first = robot_controller(speedup="step")
    left = robot_controller(speedup="step", name="left_arm")
    assert (first.name, left.name) == ("c1", "left_arm")
    assert left.capture_path is not None and left.capture_path.name == "left_arm.pcapng"
    quiet = robot_controller(speedup="step", capture=None, state_rate=None)
    assert quiet.capture_path is None and quiet.emulator.config.rate == 40.0
    with pytest.raises(ValueError, match="this test has a controller 'left_arm' already"):
        robot_controller(name="left_arm")


# -- in process, async ------------------------------------------------------------------------------------


async def test_an_async_test_s_controllers_run_in_its_own_loop(robot_controller) -> None:
    stepped = await robot_controller(speedup="step")
    fast = await robot_controller(speedup=40.0)
    assert stepped.emulator.control is not None
    for ctrl in (stepped, fast):
        begin = ctrl.time
        async with Client.tcp(ctrl.host, ctrl.motion_port) as client:
            for sequence, point, duration in ((0, ctrl.joints, 0.0), (1, TARGET, 20.0)):
                reply = await client.request(JointTrajPt(sequence, point, 0.5, duration, comm_type=REQUEST))
                assert reply.reply_code == ReplyCode.SUCCESS
            done = await ctrl.wait_idle(60.0)
        assert done - begin >= 20.0  # sped up, the wall time before the move counts 40 times
        record = ctrl.record
        moved = record.time()[np.any(record.get("command_velocity") != 0.0, axis=1)]
        assert 19.99 <= moved[-1] - moved[0] <= 20.1
        assert_reached(ctrl, TARGET, tol=1e-4, settled=True)
    assert await stepped.advance(1.0) == pytest.approx(stepped.time)
    assert await stepped.fault("estop") == "estop"
    assert stepped.status.e_stopped == TriState.TRUE


async def test_an_async_controller_not_awaited_says_so_and_is_stopped_anyway(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    with pytest.raises(ControllerError, match=r"c1 has not started: in an async test, ctrl = await robot_controller"):
        _ = ctrl.motion_port
    await asyncio.sleep(0)  # (its start runs meanwhile; the teardown stops it)


async def test_an_async_wait_that_times_out_leaves_nothing_behind(robot_controller) -> None:
    ctrl = await robot_controller(speedup=40.0)
    async with Client.tcp(ctrl.host, ctrl.motion_port) as client:
        for sequence, point, duration in ((0, ctrl.joints, 0.0), (1, TARGET, 20.0)):
            await client.request(JointTrajPt(sequence, point, 0.5, duration, comm_type=REQUEST))
        with pytest.raises(ControllerTimeout, match="the robot at rest"):
            await ctrl.wait_idle(0.5)


def test_a_sync_controller_cannot_be_awaited(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")

    async def wrong() -> None:
        await ctrl

    with pytest.raises(TypeError, match="started outside an event loop"):
        asyncio.run(wrong())


# -- outside pytest -----------------------------------------------------------------------------------------


def test_the_factory_outside_pytest_stops_its_controllers(tmp_path: Path) -> None:
    with ControllerFactory(tmp_path) as start:
        ctrl = start(speedup="step")
        assert ctrl.advance(1.0) == pytest.approx(1.004)
    assert ctrl.closed and (tmp_path / "c1.pcapng").is_file()


async def test_the_factory_outside_pytest_in_an_event_loop(tmp_path: Path) -> None:
    async with ControllerFactory(tmp_path, captures=False) as start:
        ctrl = await start(speedup="step")
        assert ctrl.capture_path is None
        await ctrl.advance(1.0)
    assert ctrl.closed


# -- robot-server processes -------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_robot_server_process_moves_takes_faults_on_stdin_and_leaves_its_record(robot_controller) -> None:
    ctrl = robot_controller(speedup=20.0, process=True)
    assert ctrl.process and ctrl.pid is not None and ctrl.log_path is not None
    with socket.create_connection((ctrl.host, ctrl.motion_port), timeout=10) as sock:
        sock.sendall(frame(MsgType.PING))
        assert read_frame(sock)[:3] == (MsgType.PING, 3, ReplyCode.SUCCESS)
    begin = ctrl.time
    with moving(ctrl, TARGET, 20.0):
        done = ctrl.wait_idle(60.0)
    assert done - begin >= 20.0
    assert ctrl.joints == pytest.approx(TARGET, abs=1e-4)
    with pytest.raises(ControllerError, match="writes its record when it exits"):
        _ = ctrl.record
    assert ctrl.fault("estop") == "estop"
    ctrl.advance_until(lambda: ctrl.status.e_stopped == TriState.TRUE, 5.0)
    with pytest.raises(FaultError, match="unknown fault command 'explode'"):
        ctrl.fault("explode")
    pid = ctrl.pid
    ctrl.stop()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    assert ctrl.record.time()[-1] >= 20.0
    assert_reached(ctrl, TARGET, tol=1e-4)
    assert "applied: estop" in ctrl.log_path.read_text()


@pytest.mark.slow
async def test_an_async_test_s_robot_server_process(robot_controller) -> None:
    ctrl = await robot_controller(profile="motoros", model=["jibot_zxs", "puma560"], process=True)
    assert set(ctrl.ports) == {"motion", "state", "io"}
    assert [m.name for m in ctrl.models] == ["jibot_zxs", "puma560"]
    _, writer = await asyncio.open_connection(ctrl.host, ctrl.io_port)
    writer.close()
    await writer.wait_closed()
    assert ctrl.status.motion_possible == TriState.FALSE  # MotoROS: not in trajectory mode
    assert await ctrl.fault("alarm 7") == "alarm 7"
    await ctrl.advance_until(lambda: ctrl.status.error_code == 7, 5.0)
    await ctrl.stop()
    assert [record.dof for record in ctrl.records] == [6, 6]
    assert ctrl.records[1].time()[-1] == ctrl.records[0].time()[-1] > 0


@pytest.mark.slow
def test_a_robot_server_process_that_cannot_start_says_why(robot_controller) -> None:
    with pytest.raises(ControllerError, match=r"robot-server did not start \(exit status 2\):\n.*no_such_cell"):
        robot_controller(process=True, cell="no_such_cell")


@pytest.mark.parametrize("value", [math.nan, math.inf, -1.0])
def test_a_wait_of_no_finite_length_is_refused_naming_the_argument(robot_controller, value: float) -> None:
    ctrl = robot_controller(speedup="step")
    with pytest.raises(ValueError, match="timeout must be a finite number of seconds >= 0"):
        ctrl.wait_idle(value)
    with pytest.raises(ValueError, match="seconds must be a finite number"):
        ctrl.advance(value)
    with pytest.raises(ValueError, match="limit must be a finite number"):
        ctrl.advance_until(lambda: False, value)
    with pytest.raises(ValueError, match="dt must be a finite number of seconds > 0"):
        ctrl.advance_until(lambda: False, 1.0, dt=0.0)


async def test_an_async_wait_of_no_finite_length_is_refused(robot_controller) -> None:
    ctrl = await robot_controller(speedup="step")
    with pytest.raises(ValueError, match="timeout must be"):
        await ctrl.wait_idle(math.nan)
    with pytest.raises(ValueError, match="limit must be"):
        await ctrl.advance_until(lambda: False, math.inf)


@pytest.mark.slow
async def test_an_async_robot_server_process_that_cannot_start_is_reported_once(robot_controller) -> None:
    # the teardown that follows must not report it again ("did not stop cleanly"): the test would error
    with pytest.raises(ControllerError, match=r"robot-server did not start \(exit status 2\):\n.*no_such_cell"):
        await robot_controller(process=True, cell="no_such_cell")


# -- bad input: a typed error, raised before anything starts or is sent -----------------------------------

#: hosts the fixture refuses (its controllers are reached on loopback), and why
BAD_HOSTS = (
    ("no.such.host.invalid", "is not an IP address"),
    ("127.0.0.300", "is not an IP address"),
    ("8.8.8.8", "is not a loopback address"),
    ("fe80::1", "is not a loopback address"),
)


def _no_lookup(*args: object, **kwargs: object) -> object:
    raise AssertionError(f"a host name was looked up: {args}")


@pytest.mark.parametrize("process", [False, True], ids=["in-process", "process"])
def test_a_host_off_loopback_is_refused_naming_the_key_and_the_value(
    robot_controller, monkeypatch: pytest.MonkeyPatch, process: bool
) -> None:
    with monkeypatch.context() as patch:
        patch.setattr(socket, "getaddrinfo", _no_lookup)  # refused as written, no resolver asked
        for host, why in BAD_HOSTS:
            with pytest.raises(SettingsError) as error:
                robot_controller(host=host, process=process)
            text = str(error.value)
            assert text.startswith(f"robot_controller(c1): host: {host!r} {why}") and "give 127.0.0.1" in text
    assert robot_controller.handles == []
    ctrl = robot_controller(host="localhost", speedup="step")
    assert ctrl.host == "localhost" and ctrl.advance(0.1) > 0.0


async def test_an_async_test_s_host_off_loopback_is_refused_at_the_call(robot_controller) -> None:
    for process in (False, True):
        with pytest.raises(SettingsError, match=r"robot_controller\(c1\): host: 'no.such.host.invalid' is not an IP"):
            robot_controller(host="no.such.host.invalid", process=process)  # (not even awaited)
    assert robot_controller.handles == []


#: fault commands that are not text, and how the TypeError names them
NOT_TEXT = ((1, "1 (int)"), (None, "None (NoneType)"), (b"estop", "b'estop' (bytes)"), (["estop"], "['estop'] (list)"))


def test_a_fault_command_that_is_not_text_is_a_type_error(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    for command, named in NOT_TEXT:
        with pytest.raises(TypeError) as error:
            ctrl.fault(command)
        assert str(error.value).startswith("fault: a fault command is text") and str(error.value).endswith(named)
    assert ctrl.status.e_stopped == TriState.FALSE  # nothing was applied
    assert ctrl.fault("estop") == "estop"


async def test_an_async_fault_command_that_is_not_text_is_a_type_error(robot_controller) -> None:
    ctrl = await robot_controller(speedup="step")
    for command, named in NOT_TEXT:
        with pytest.raises(TypeError) as error:
            await ctrl.fault(command)
        assert str(error.value).endswith(named)
    assert ctrl.status.e_stopped == TriState.FALSE
    assert await ctrl.fault("estop") == "estop"


@pytest.mark.slow
def test_a_robot_server_process_s_fault_command_that_is_not_text_is_a_type_error(robot_controller) -> None:
    ctrl = robot_controller(process=True)
    with pytest.raises(TypeError, match=r"^fault: a fault command is text.*, not 1 \(int\)$"):
        ctrl.fault(1)
    assert ctrl.fault("estop") == "estop"  # nothing was typed before: the process answers the next one
    ctrl.stop()
    assert ctrl.log_path is not None
    applied = [line for line in ctrl.log_path.read_text().splitlines() if "applied:" in line]
    assert len(applied) == 1 and applied[0].endswith("applied: estop"), applied


# -- the pytest and pluggy the plugin needs --------------------------------------------------------------

pytest_plugins = ["pytester"]  # (for the test below: a pytest run of its own)


def test_the_plugin_says_which_pytest_and_pluggy_it_needs() -> None:
    from robot_server.testing import plugin

    assert plugin.UNSUPPORTED is None  # this run's
    assert plugin.unsupported("8.0.0", "1.3.0") is None
    assert plugin.unsupported("9.1.0.dev12+g0123abc", "1.6.0") is None
    assert plugin.unsupported("7.4.4", "1.5.0") == (
        "robot_server's pytest plugin (the robot_controller fixture) needs pytest >= 8.0 (with pluggy >= 1.1); "
        "this is pytest 7.4.4 with pluggy 1.5.0: pip install 'pytest>=8.0' 'pluggy>=1.1', or turn the plugin off "
        "with -p no:robot_server"
    )
    assert plugin.unsupported("8.0.0", "1.0.0") is not None  # (a pluggy installed apart, older than pytest's own)
    assert plugin.unsupported("8.0.0rc1", "1.1.0.dev1") is None


@pytest.mark.slow
def test_with_a_pluggy_too_old_the_fixture_says_so_and_the_run_goes_on(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a plugin given with -p is imported before the entry points': it makes pluggy look like 1.0
    pytester.makepyfile(old_pluggy="import pluggy\n\npluggy.__version__ = '1.0.0'\n")
    pytester.makeini("[pytest]\nasyncio_default_fixture_loop_scope = function\n")
    pytester.makepyfile(
        test_old="""
        def test_asks_for_a_controller(robot_controller):
            robot_controller()

        def test_does_not():
            pass
        """
    )
    monkeypatch.setenv("PYTHONPATH", str(pytester.path))
    options = ("-p", "old_pluggy", "-p", "no:randomly", "-p", "no:cacheprovider", "--robot-captures", "none")
    result = pytester.runpytest_subprocess(*options, timeout=120)
    result.assert_outcomes(passed=1, errors=1)
    out = result.stdout.str()
    needs = "needs pytest >= 8.0 (with pluggy >= 1.1); this is pytest {} with pluggy 1.0.0: pip install"
    assert needs.format(pytest.__version__) in out, out
    assert "def robot_controller" not in out  # the message alone, no traceback of the plugin


# -- a wait cancelled from outside (asyncio.timeout around it) ----------------------------------------------


@contextlib.asynccontextmanager
async def expiring_at(ctrl, at: float):
    """An ``asyncio.timeout`` around a wait of the async handle ``ctrl`` that expires once the
    controller's time reaches ``at``: its clock, not the wall's, so the wait is cancelled at the same
    point on any machine. Raises TimeoutError as any expired timeout; yields the timeout."""
    cell = ctrl.emulator.cell
    loop = asyncio.get_running_loop()
    async with asyncio.timeout(None) as timeout:

        async def expire() -> None:
            await cell.until(lambda: cell.time >= at)
            timeout.reschedule(loop.time())

        trigger = asyncio.create_task(expire(), name="expire the timeout")
        try:
            yield timeout
        finally:
            trigger.cancel()
            await asyncio.gather(trigger, return_exceptions=True)


def advancing_tasks() -> list[str]:
    """The tasks of this loop moving a stepped clock (each wait of a stepped controller makes one)."""
    return [t.get_name() for t in asyncio.all_tasks() if t.get_coro().__qualname__.startswith("SteppedClock.")]


@pytest.mark.parametrize("speedup", ["step", 10.0], ids=["stepped", "sped-up"])
async def test_an_async_wait_cancelled_by_a_timeout_leaves_no_task_and_the_controller_goes_on(
    robot_controller, speedup: object
) -> None:
    ctrl = await robot_controller(speedup=speedup)
    period = ctrl.emulator.cell.config.interpolation_period
    begin = ctrl.time
    async with Client.tcp(ctrl.host, ctrl.motion_port) as client:
        for sequence, point, duration in ((0, ctrl.joints, 0.0), (1, TARGET, 20.0)):
            reply = await client.request(JointTrajPt(sequence, point, 0.5, duration, comm_type=REQUEST))
            assert reply.reply_code == ReplyCode.SUCCESS
        # wait_idle cancelled 5 s into the 20 s move
        with pytest.raises(TimeoutError) as raised:
            async with expiring_at(ctrl, begin + 5.0) as timeout:
                await ctrl.wait_idle(60.0)
        assert timeout.expired() and not isinstance(raised.value, ControllerTimeout)
        assert advancing_tasks() == []
        stopped_at = ctrl.time
        assert ctrl.in_motion and begin + 5.0 <= stopped_at < begin + 20.0
        # the controller goes on: time passes as asked (a stepped clock stood where the wait left it)
        after = await ctrl.advance(0.5)
        assert after >= stopped_at + 0.5 - 1e-6
        if ctrl.stepped:
            assert after <= stopped_at + 0.5 + period + 1e-6
        done = await ctrl.wait_idle(60.0)
        assert done >= begin + 20.0 and not ctrl.in_motion
        assert_reached(ctrl, TARGET, tol=1e-4, settled=True)
        # nothing sent: at rest already, the wait returns at once
        assert await ctrl.wait_idle(5.0) >= done
        # advance_until cancelled the same way (period by period, and in steps of dt), then used again
        for dt in (None, 0.5):
            with pytest.raises(TimeoutError):
                async with expiring_at(ctrl, ctrl.time + 1.0) as timeout:
                    await ctrl.advance_until(lambda: False, 3600.0, dt=dt, what="never")
            assert timeout.expired() and advancing_tasks() == []
            before = ctrl.time
            assert await ctrl.advance(0.2) >= before + 0.2 - 1e-6
            assert await ctrl.wait_idle(5.0) >= before + 0.2 - 1e-6
        # a plain advance the same way: a stepped one runs period by period too, so it ends where it was cut
        before = ctrl.time
        with pytest.raises(TimeoutError):
            async with expiring_at(ctrl, before + 1.0) as timeout:
                await ctrl.advance(3600.0)
        assert timeout.expired() and advancing_tasks() == []
        assert before + 1.0 <= ctrl.time < before + 10.0
        assert await ctrl.advance(0.2) >= before + 1.2 - 1e-6
    assert_reached(ctrl, TARGET, tol=1e-4, settled=True)


def test_a_stepped_clock_keeps_what_is_left_of_a_period(robot_controller) -> None:
    """Advances shorter than an interpolation period add up: the loop runs a period once the clock
    has reached it."""
    ctrl = robot_controller(speedup="step")
    begin = ctrl.time
    for _ in range(100):
        ctrl.advance(0.001)
    assert ctrl.time == pytest.approx(begin + 0.1, abs=0.0041)
    for _ in range(10):
        ctrl.advance(0.006)
    assert ctrl.time == pytest.approx(begin + 0.16, abs=0.0041)


def test_pytest_fail_in_a_predicate_fails_the_test_and_the_controller_runs_on(robot_controller) -> None:
    ctrl = robot_controller(speedup="step")
    calls = 0

    def failing() -> bool:
        nonlocal calls
        calls += 1
        if calls == 4:
            pytest.fail("the predicate's own verdict")
        return False

    with pytest.raises(pytest.fail.Exception, match="the predicate's own verdict"):
        ctrl.advance_until(failing, 5.0)
    stood = ctrl.time
    assert ctrl.advance(0.1) == pytest.approx(stood + 0.1, abs=1e-6)


async def test_two_waits_at_once_on_one_stepped_controller_take_turns(robot_controller) -> None:
    ctrl = await robot_controller(speedup="step")
    begin = ctrl.time
    async with Client.tcp(ctrl.host, ctrl.motion_port) as client:
        for sequence, point, duration in ((0, ctrl.joints, 0.0), (1, TARGET, 2.0)):
            reply = await client.request(JointTrajPt(sequence, point, 0.5, duration, comm_type=REQUEST))
            assert reply.reply_code == ReplyCode.SUCCESS
        idle, later = await asyncio.gather(ctrl.wait_idle(60.0), ctrl.advance(0.1))
    assert begin + 2.0 <= idle < begin + 3.0, "the wait for rest ended at rest, not at its limit"
    assert later == pytest.approx(idle + 0.1, abs=0.0041), "the advance ran after it"
