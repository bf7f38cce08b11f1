"""A fleet of controllers in one process (robot_server.fleet): the file read strictly, each
controller its own robot, faults by name, log lines by name, and the command.

The in-process fleets run on a clock the test advances (tests/stepped.py's rules): what a test
asserts at a controller time holds however loaded the machine is.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import importlib.util
import logging
import os
import re
import signal
import socket
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from robot_server.control import SteppedClock
from robot_server.control import loop as loop_module
from robot_server.emulator import FaultError
from robot_server.fleet import Fleet, FleetError, load_fleet, parse_fleet
from robot_server.fleet.logs import CONTROLLER, ControllerField
from robot_server.fleet.runner import FleetCommandError
from tests.rawpeer import RawPeer, joint_position, joint_traj_pt, vectors
from tests.stepped import STEP_TIMEOUT, advance_until

V = vectors("<")
JTP = V["JOINT_TRAJ_PT_REQUEST_SEQ3"]
PING = V["PING_REQUEST"]
JOINT_POSITION = 10
FREE = {"motion_port": 0, "state_port": 0}


def _fleet(*controllers: dict[str, Any], defaults: dict[str, Any] | None = None) -> dict[str, Any]:
    data: dict[str, Any] = {"controller": [{**FREE, **c} for c in controllers]}
    if defaults is not None:
        data["defaults"] = defaults
    return data


def _refused(data: dict[str, Any], *parts: str) -> str:
    with pytest.raises(FleetError) as caught:
        parse_fleet(data, "cell.toml")
    message = str(caught.value)
    assert message.startswith("cell.toml: "), message
    for part in parts:
        assert part in message, message
    return message


# -- the file ------------------------------------------------------------------------------------


def test_a_fleet_file_gives_each_controller_its_settings_over_the_defaults(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(
        """
[defaults]
state_rate = 20
interpolation = "quintic"

[[controller]]
name = "r1"
motion_port = 0
state_port = 0

[[controller]]
name = "arm-2"
profile = "motoros"
model = ["jibot_zxs", "puma560"]
motion_port = 0
state_port = 0
io_port = 0
state_rate = 40
faults = ["1.5:estop", "3:reset"]
profile_options = { }
"""
    )
    spec = load_fleet(path)
    r1, r2 = spec.controllers
    assert (r1.name, r1.config.profile, r1.config.rate, r1.config.interpolation) == ("r1", "generic", 20.0, "quintic")
    assert (r2.name, r2.config.profile, r2.config.models, r2.config.rate) == (
        "arm-2",
        "motoros",
        ("jibot_zxs", "puma560"),
        40.0,
    )
    assert r2.faults == ((1.5, "estop"), (3.0, "reset"))
    assert r1.config.port("motion") == 0 and r2.config.port("io") == 0


def test_unknown_tables_and_keys_are_refused_with_the_name_meant() -> None:
    _refused({"controllers": []}, "[controllers]: unknown table; did you mean [controller]?")
    _refused(
        _fleet({"name": "r1", "motoin_port": 1}), "controller r1: motoin_port: unknown key; did you mean motion_port?"
    )
    _refused(
        _fleet({"name": "r1"}, defaults={"prfile": "abb"}), "[defaults]: prfile: unknown key; did you mean profile?"
    )


def test_wrong_values_are_refused_naming_the_controller_and_the_key() -> None:
    _refused(_fleet({"name": "r1", "motion_port": "11000"}), "controller r1: motion_port: must be a whole number")
    _refused(_fleet({"name": "r1", "state_port": 70000}), "controller r1: state_port: must be 0..65535")
    _refused(_fleet({"name": "r1", "state_rate": 5000}), "controller r1: state_rate: must be > 0 and at most 1000")
    _refused(_fleet({"name": "r1", "profile": "kuka"}), "controller r1: unknown profile 'kuka'")
    _refused(_fleet({"name": "r1", "interpolation": "spline"}), "controller r1:", "spline")
    _refused(
        _fleet({"name": "r1", "profile": "abb", "io_port": 0}), "controller r1: io_port: the abb profile serves no io"
    )
    _refused(_fleet({"name": "r1", "profile": "fanuc", "byte_order": "little"}), "controller r1:", "big-endian only")
    _refused(_fleet({"name": "r1", "faults": ["2:explode"]}), "controller r1: faults: unknown fault command 'explode'")
    _refused(_fleet({"name": "r1", "faults": ["soon:estop"]}), 'controller r1: faults: expected "SECONDS:COMMAND"')
    _refused(_fleet({"name": "r1", "model": []}), "controller r1: model: must be a model")


def test_names_are_required_unique_and_plain() -> None:
    _refused(_fleet({"profile": "abb"}), "[[controller]] 1st: name: missing")
    _refused(
        _fleet({"name": "r1"}, {"name": "r1"}), "[[controller]] 2nd: name: 'r1' is the name of the 1st controller too"
    )
    _refused(_fleet({"name": "r 1"}), "[[controller]] 1st: name: 'r 1' is not a name")
    _refused(_fleet({"name": "all"}), "name: 'all' is not a name")
    _refused(_fleet({"name": "r1"}, defaults={"name": "x"}), "[defaults] name: every controller has a name of its own")
    _refused({"defaults": {}}, "no [[controller]] table")


def test_two_controllers_on_one_port_are_refused_before_anything_is_bound() -> None:
    _refused(
        _fleet({"name": "r1", "motion_port": 12000}, {"name": "r2", "state_port": 12000}),
        "controller r2: state_port: 12000 is controller r1's motion_port too",
    )
    _refused(
        _fleet({"name": "r1", "motion_port": 12000, "state_port": 12000}),
        "controller r1: state_port: 12000 is this controller's motion_port too",
    )
    wildcard = _fleet({"name": "r1", "motion_port": 12000, "host": "0.0.0.0"}, {"name": "r2", "motion_port": 12000})
    _refused(wildcard, "controller r2: motion_port: 12000 is controller r1's motion_port too")
    # the same port on two addresses of the machine is two ports
    two = _fleet(
        {"name": "r1", "motion_port": 12000, "host": "127.0.0.1"},
        {"name": "r2", "motion_port": 12000, "host": "127.0.0.2"},
    )
    assert len(parse_fleet(two, check_ports=False).controllers) == 2


def test_a_port_another_program_holds_is_refused_naming_the_controller() -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        _refused(
            _fleet({"name": "r1"}, {"name": "r2", "state_port": port}),
            f"controller r2: state_port: cannot bind 127.0.0.1:{port}",
        )


# -- the fleet in process ------------------------------------------------------------------------


@contextlib.asynccontextmanager
async def stepped_fleet(*controllers: dict[str, Any]) -> AsyncIterator[tuple[Fleet, SteppedClock]]:
    clock = SteppedClock()
    fleet = Fleet(parse_fleet(_fleet(*controllers)), clock=clock)
    await fleet.start()
    try:
        async with asyncio.timeout(STEP_TIMEOUT):
            await clock.advance(0.0)
        yield fleet, clock
        await advance_until(clock, lambda: not any(e.in_motion for e in fleet.emulators.values()), what="rest")
    finally:
        await fleet.close(settle_timeout=1.0)


CELL = (
    {"name": "r1"},
    {"name": "r2", "profile": "motoros", "io_port": 0},
    {"name": "r3", "profile": "abb", "model": "puma560"},
)


async def test_a_motion_on_one_controller_moves_that_one_only() -> None:
    async with stepped_fleet(*CELL) as (fleet, clock):
        r1 = fleet["r1"]
        motion = await RawPeer.connect(r1.ports["motion"])
        target = [0.2, -0.1, 0.05, 0.0, 0.1, 0.0]
        assert (await motion.request(joint_traj_pt(JTP, 0, [0.0] * 6))).reply_code == 1
        assert (await motion.request(joint_traj_pt(JTP, 1, target, 0.0, 1.0))).reply_code == 1
        await advance_until(clock, lambda: r1.in_motion, what="r1 moving")
        await advance_until(clock, lambda: not r1.in_motion, what="r1 settling")
        assert r1.cell.groups[0].command.command_position == pytest.approx(target, abs=1e-6)  # float32
        for other in ("r2", "r3"):
            group = fleet[other].cell.groups[0]
            assert group.trajectories == 0 and group.points_accepted == 0
            assert group.command.command_position == [0.0] * group.dof
        state = await RawPeer.connect(r1.ports["state"])  # r1's state port publishes r1's joints
        published = joint_position(await state.next_of(JOINT_POSITION))[:6]  # the measured joints, settled
        assert published == pytest.approx(target, abs=1e-3)
        await motion.close()
        await state.close()


async def test_a_fault_on_one_controller_touches_no_other_and_all_reaches_every_one() -> None:
    async with stepped_fleet(*CELL) as (fleet, _clock):
        assert fleet.command("r2 estop") == ["r2: estop"]
        assert fleet["r2"].cell.e_stopped
        assert not fleet["r1"].cell.e_stopped and not fleet["r3"].cell.e_stopped
        assert fleet["r1"].cell.drives_powered and fleet["r3"].cell.drives_powered
        fleet.command("all alarm 42 a test alarm")
        assert all(fleet[n].cell.error_code == 42 for n in fleet)
        fleet.command("all reset")
        assert all(not fleet[n].cell.in_error and not fleet[n].cell.e_stopped for n in fleet)
        with pytest.raises(FleetCommandError, match=r"no controller 'r9' in the fleet \(controllers: r1, r2, r3"):
            fleet.command("r9 estop")
        with pytest.raises(FleetCommandError, match="expected NAME COMMAND"):
            fleet.command("estop")
        with pytest.raises(FaultError, match="unknown"):
            fleet.command("r1 explode")


async def test_scheduled_faults_run_at_their_controllers_time() -> None:
    async with stepped_fleet({"name": "r1", "faults": ["0.5:estop"]}, {"name": "r2"}) as (fleet, clock):
        async with asyncio.timeout(STEP_TIMEOUT):
            await clock.advance(0.4)
        assert not fleet["r1"].cell.e_stopped
        await advance_until(clock, lambda: fleet["r1"].cell.e_stopped, limit=1.0, what="the scheduled e-stop")
        assert not fleet["r2"].cell.e_stopped
        fleet.command("r1 reset")


async def test_log_lines_name_their_controller() -> None:
    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record)

    handler = Keep()
    handler.addFilter(ControllerField())
    root = logging.getLogger()
    root.addHandler(handler)
    level = root.level
    root.setLevel(logging.INFO)  # setLevel: the loggers' cached levels are cleared too
    try:
        async with stepped_fleet(*CELL) as (fleet, _clock):  # the fleet's log ceiling installed meanwhile
            assert fleet.ceiling in logging.getLogger("robot_server.emulator.cell").filters
            peer = await RawPeer.connect(fleet["r3"].ports["state"])  # a connection's lines: r3's
            await peer.frame()
            await peer.close()
            fleet.command("r2 estop")
            fleet.command("r2 reset")
    finally:
        root.removeHandler(handler)
        root.setLevel(level)
    named = {(r.controller, r.getMessage()) for r in records}  # type: ignore[attr-defined]
    assert any(who == "r2: " and "emergency stop" in text for who, text in named), named
    assert any(who == "r3: " and "state" in text.lower() for who, text in named), named
    assert any(who == "" for who, _ in named)  # the fleet's own
    assert CONTROLLER.get() == ""
    assert fleet.ceiling not in logging.getLogger("robot_server.emulator.cell").filters


async def test_fifty_controllers_of_every_profile_each_answer_and_publish() -> None:
    profiles = ("generic", "motoros", "abb", "fanuc", "staubli")
    controllers = [
        {"name": f"c{k}", "profile": profiles[k % 5], **({"io_port": 0} if profiles[k % 5] == "motoros" else {})}
        for k in range(50)
    ]
    fleet = Fleet(parse_fleet(_fleet(*controllers)))
    async with fleet:
        async with asyncio.timeout(30.0):
            for name in fleet:
                emu = fleet[name]
                peer = await RawPeer.connect(emu.ports["state"], "<" if emu.config.byte_order == "little" else ">")
                frame = await peer.frame()  # the state topics of its profile
                assert frame.comm_type == 1, (name, frame.raw.hex())
                await peer.close()
    assert len(fleet.ready_lines()) == 51
    assert fleet.ready_lines()[-1].startswith(
        "robot-server fleet ready: 50 controllers (generic 10, motoros 10, abb 10, fanuc 10, staubli 10)"
    )


# -- the command ---------------------------------------------------------------------------------


FLEET_FILE = """
[[controller]]
name = "r1"
motion_port = 0
state_port = 0

[[controller]]
name = "r2"
profile = "motoros"
motion_port = 0
state_port = 0
io_port = 0
"""


@pytest.mark.slow
async def test_the_command_prints_a_ready_line_per_controller_and_exits_0_on_sigint(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(FLEET_FILE)
    log = tmp_path / "fleet.log"
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "robot_server", "--fleet", str(path), stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE, stderr=err,
        )  # fmt: skip
        try:
            assert proc.stdout is not None and proc.stdin is not None
            async with asyncio.timeout(30.0):
                lines = [(await proc.stdout.readline()).decode() for _ in range(3)]
            assert lines[0].startswith("r1: robot-server ready: generic profile"), lines
            assert lines[1].startswith("r2: robot-server ready: motoros profile"), lines
            assert lines[2].startswith("robot-server fleet ready: 2 controllers (generic 1, motoros 1)"), lines
            port = int(re.search(r"motion 127\.0\.0\.1:(\d+)", lines[0]).group(1))  # type: ignore[union-attr]
            peer = await RawPeer.connect(port)
            assert (await peer.request(PING)).reply_code == 1
            await peer.close()
            proc.stdin.write(b"r2 estop\n")
            await proc.stdin.drain()
            async with asyncio.timeout(10.0):
                while b"r2: robot_server.emulator.cell: fault: emergency stop" not in log.read_bytes():  # noqa: ASYNC110
                    await asyncio.sleep(0.05)  # the log file has no event to wait on: a bounded poll
            proc.send_signal(signal.SIGINT)
            assert await asyncio.wait_for(proc.wait(), 30.0) == 0, log.read_text()
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
    text = log.read_text()
    assert "Traceback" not in text, text
    assert "shutting down: bringing 2 controllers to rest" in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--profile", "abb"], "--profile: a controller's setting; with --fleet it goes in the fleet file"),
        (["--motion-port", "0", "--state-rate", "10"], "--motion-port, --state-rate: a controller's setting"),
    ],
)
async def test_the_command_refuses_a_controller_option_beside_fleet(
    tmp_path: Path, args: list[str], message: str
) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(FLEET_FILE)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "robot_server", "--fleet", str(path), *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 30.0)
    assert proc.returncode == 2 and message in err.decode() and not out


async def test_the_command_refuses_a_bad_file_before_binding(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(FLEET_FILE.replace('profile = "motoros"', 'profile = "motoros"\nqueue_sise = 8'))
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "robot_server", "--fleet", str(path),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 30.0)
    assert proc.returncode == 2 and not out
    assert f"{path}: controller r2: queue_sise: unknown key; did you mean queue_size?" in err.decode()


@pytest.mark.slow
async def test_the_command_serves_the_fleets_web_view_with_a_token_beyond_loopback(tmp_path: Path) -> None:
    pytest.importorskip("aiohttp")
    path = tmp_path / "cell.toml"
    path.write_text(FLEET_FILE)
    log = tmp_path / "fleet.log"
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "robot_server", "--fleet", str(path), "--web", "0.0.0.0:0", "--no-stdin",
            stdout=asyncio.subprocess.PIPE, stderr=err, env={**os.environ, "ROBOT_SERVER_WEB_TOKEN": ""},
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            async with asyncio.timeout(30.0):
                lines = [(await proc.stdout.readline()).decode() for _ in range(3)]
            match = re.search(r", web view http://0\.0\.0\.0:(\d+)/\?token=([\w-]{16,})$", lines[2].strip())
            assert match, lines[2]
            reader, writer = await asyncio.open_connection("127.0.0.1", int(match[1]))
            writer.write(b"GET /fleet.json HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
            async with asyncio.timeout(10.0):
                answer = (await reader.read()).decode()
            writer.close()
            assert " 200 " in answer.splitlines()[0]
            assert '"name":"r1"' in answer.replace(" ", "") and '"name":"r2"' in answer.replace(" ", "")
            assert match[2] not in log.read_text(), "the token is printed once, never logged"
            proc.send_signal(signal.SIGINT)
            assert await asyncio.wait_for(proc.wait(), 30.0) == 0, log.read_text()
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()


@pytest.mark.fixed_ports_allowed(
    "the fleet check binds MotoROS's well-known ports for a moment; either outcome is asserted"
)
def test_a_controller_may_leave_its_ports_to_its_profile() -> None:
    data = {"controller": [{"name": "r1", "profile": "motoros"}]}
    try:  # the well-known ports are probed as plain numbers (a profile's are an IntEnum)
        spec = parse_fleet(data, "cell.toml")
    except FleetError as exc:  # another program on this machine holds one: said so, by controller and key
        assert "controller r1:" in str(exc) and "cannot bind" in str(exc), exc
    else:
        assert [spec.controllers[0].config.port(r) for r in ("motion", "state", "io")] == [50240, 50241, 50242]


def test_two_controllers_writing_one_file_are_refused() -> None:
    _refused(
        _fleet({"name": "r1"}, {"name": "r2"}, defaults={"record": "/tmp/same.csv"}),
        "controller r2: record: /tmp/same.csv is controller r1's record too",
    )
    _refused(
        _fleet({"name": "r1", "capture": "/tmp/a.pcapng"}, {"name": "r2", "capture": "/tmp/../tmp/a.pcapng"}),
        "controller r2: capture:",
    )
    tiny = _fleet({"name": "r1", "servo_period": 1e-9})
    _refused(tiny, "controller r1: servo_period: 1e-09 s is more than 1000 ticks")
    _refused(_fleet({"name": "r1", "interpolation_period": 1e300}), "controller r1: interpolation_period: must be > 0")


async def test_each_state_round_runs_as_its_controller() -> None:
    from robot_server.emulator.shared import StateRounds

    rounds = StateRounds(0.004, None)
    seen: list[tuple[str, str]] = []
    done = asyncio.Event()

    def member(name: str) -> None:
        def publish(_deadline: float) -> None:
            seen.append((name, CONTROLLER.get()))
            if len(seen) >= 4:
                done.set()

        CONTROLLER.set(name)  # joined from the controller's own context, as Emulator.start does
        rounds.add(publish, lambda _count: None)

    for name in ("r1", "r2"):
        contextvars.copy_context().run(member, name)
    task = asyncio.get_running_loop().create_task(rounds.run(), context=contextvars.Context())
    try:
        async with asyncio.timeout(10.0):
            await done.wait()
    finally:
        task.cancel()
    assert all(name == who for name, who in seen), seen


async def test_the_exit_report_gives_the_overruns_and_their_times_as_the_bench_reads_them(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The lines bench/fleet.py parses (its OVERRUNS pattern), and the overruns' times after them.
    The overruns are put in the shared loop's stats as late wake-ups would (no wall clock waited for)."""
    bench = _bench_module()
    fleet = Fleet(parse_fleet(_fleet({"name": "r1"}, {"name": "r2"})))
    caplog.set_level(logging.INFO, logger="robot_server.fleet.runner")
    async with fleet:
        [shared] = fleet.shared.loops.values()
        shared.stats.wakes = max(shared.stats.wakes, 10)
        loop_module._late(shared.stats, 0.0061, 0.004)
        loop_module._late(shared.stats, 0.0042, 0.004)
    report = "\n".join(r.getMessage() for r in caplog.records if r.name == "robot_server.fleet.runner")
    match = bench.OVERRUNS.search(report)
    assert match is not None, report
    assert match[2] == "2" and float(match[3]) == pytest.approx(6.1, abs=1e-3)
    times = re.search(r"control loop \(4 ms\) overruns, the last 2 \(.*?\): (.*)$", report, re.M)
    assert times is not None, report
    found = re.findall(r"([\d.]+) \+([\d.]+) ms", times[1])
    assert [late for _, late in found] == ["6.100", "4.200"]
    assert [float(at) for at, _ in found] == [pytest.approx(at, abs=1e-5) for at, _ in shared.stats.late_wakes]


def _bench_module() -> Any:
    """bench/fleet.py as a module (a script, not a package's)."""
    path = Path(__file__).resolve().parent.parent / "bench" / "fleet.py"
    spec = importlib.util.spec_from_file_location("bench_fleet", path)
    assert spec is not None and spec.loader is not None
    module = sys.modules.get(spec.name)
    if module is None:
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # its dataclasses look their module up there
        spec.loader.exec_module(module)
    return module
