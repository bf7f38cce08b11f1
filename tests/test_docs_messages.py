"""The messages the docs quote are the programs' own. Each one is produced here by running the code
(``robot-client``'s ``main()`` in process against an emulator on free loopback ports, the planner,
the trajectory reader), and the text the page shows, read from the page, must appear in what the
program printed or logged.

In a quoted message ``...`` stands for text the page leaves out (numbers, advice); log lines are
compared without their time stamp, and addresses as ``127.0.0.1:PORT`` and ``('127.0.0.1', PORT)``
(the pages show the default ports, the tests use free ones). A line of a page's transcript is
``exit status N``, a ``robot-client: ...`` line on its standard error, a ``LEVEL logger: ...`` log
line, or ``... (a note)``, skipped.

Also: the JSON and CSV examples of docs/trajectories.md load as the same points, survive a save in
either format, and its commands run; the cell file cartesian.md shows has the shipped file's settings.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import logging
import re
import shlex
import socket
import sys
import tomllib
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest

from client import cli
from client.driver import DriverError, RobotDriver
from client.planner import Planner, PlanningError, pose
from client.trajectory import Trajectory
from robot_server.kinematics import fk
from robot_server.loader import load_model
from simple_message import cli as sm_cli
from simple_message.endpoints import Client, ReconnectPolicy
from simple_message.errors import RequestFailed
from simple_message.messages import JointTrajPt
from tests.stepped import poll
from tests.test_client_cli_inprocess import client, controller, positions
from tests.test_rs_server_process import robot_server

ROOT = Path(__file__).resolve().parent.parent
#: bound of a wait for something the server does on its own (s)
WAIT = 10.0
#: the configuration the pages move to before a Cartesian move (off the wrist singularity of q = 0)
CENTRE = (0.0, 0.3, -0.2, 0.0, 0.9, 0.0)

# -- reading the pages -------------------------------------------------------------------------------


def page(name: str) -> str:
    return (ROOT / "docs" / name).read_text(encoding="utf-8")


def section(name: str, heading: str) -> str:
    """The part of docs/``name`` under the ``## heading`` line, up to the next ``## ``."""
    text = page(name)
    start = text.index(f"\n## {heading}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else len(text)]


def fenced(text: str, language: str) -> list[str]:
    """The contents of the ``language`` fenced blocks of ``text``, in order."""
    return re.findall(rf"^```{language}\n(.*?)^```\s*$", text, re.MULTILINE | re.DOTALL)


def spans(text: str) -> list[str]:
    """The inline code spans of ``text`` outside fenced blocks (one line each)."""
    prose = re.sub(r"^```.*?^```\s*$", "", text, flags=re.MULTILINE | re.DOTALL)
    return re.findall(r"`([^`\n]+)`", prose)


def span(text: str, start: str) -> str:
    """The one inline code span of ``text`` that starts with ``start``."""
    found = [s for s in spans(text) if s.startswith(start)]
    assert len(found) == 1, f"the page should quote one message starting {start!r}, not {found}"
    return found[0]


def command(line: str) -> list[str]:
    """A documented ``robot-client ...`` line as ``main()``'s arguments (without ``|| ...`` and a
    comment)."""
    words = shlex.split(line.split(" || ", maxsplit=1)[0], comments=True)
    assert words[0] == "robot-client", line
    return words[1:]


# -- comparing ---------------------------------------------------------------------------------------

_ADDRESS = re.compile(r"127\.0\.0\.1:\d+")
_PEER = re.compile(r"\('127\.0\.0\.1', \d+\)")


def normal(text: str) -> str:
    return _PEER.sub("('127.0.0.1', PORT)", _ADDRESS.sub("127.0.0.1:PORT", text))


def says(documented: str, actual: str) -> bool:
    """Whether ``actual`` contains ``documented``, each ``...`` of which stands for any text."""
    at = 0
    text = normal(actual)
    for piece in normal(documented).split("..."):
        found = text.find(piece, at)
        if found < 0:
            return False
        at = found + len(piece)
    return True


def assert_says(documented: str, lines: Sequence[str], where: str = "output") -> None:
    assert any(says(documented, line) for line in lines), (
        f"the docs quote\n  {documented}\nwhich is not in the program's {where}:\n  " + "\n  ".join(lines)
    )


class Logs:
    """What the code logged during a test, as the commands print it without the time stamp."""

    def __init__(self, caplog: pytest.LogCaptureFixture) -> None:
        self._caplog = caplog

    def lines(self) -> list[str]:
        return [f"{r.levelname} {r.name}: {r.getMessage()}" for r in self._caplog.records]


@pytest.fixture
def logs(caplog: pytest.LogCaptureFixture) -> Logs:
    caplog.set_level(logging.INFO)
    return Logs(caplog)


def check_transcript(transcript: str, code: int, err: str, logs: Logs | None = None) -> None:
    """Every line of a page's transcript block against the exit status, stderr and log lines."""
    errors = err.splitlines()
    for line in transcript.splitlines():
        if not line or line.startswith("..."):
            continue
        status = re.fullmatch(r"exit status (\d+)", line)
        if status:
            assert code == int(status.group(1)), (line, code, err)
        elif line.startswith("robot-client: "):
            assert_says(line, errors, "standard error")
        elif re.match(r"(DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.]+: ", line):
            assert logs is not None, line
            assert_says(line, logs.lines(), "log")
        else:
            pytest.fail(f"a transcript line of an unknown kind: {line!r}")


def keep_disconnected(monkeypatch: pytest.MonkeyPatch) -> None:
    """From now on, once a client has connected, a connection of it that ends stays ended (the next
    attempt an hour away, cancelled when the client closes): what a command says when its time runs
    out then does not depend on whether a reconnection happens to be under way. Until a client has
    connected it tries as usual (a controller that closes a newcomer at once is still seen
    connected: a client waits for that first)."""
    start = Client.start

    async def started(self: Client, timeout: float | None = 10.0, *, refused_ends: bool = False) -> Client:
        await start(self, timeout, refused_ends=refused_ends)
        # in the same step as the connection was seen up: before its end asks for the next delay
        self.reconnect = ReconnectPolicy(initial_delay=3600.0, max_delay=3600.0, jitter=0.0)
        return self

    monkeypatch.setattr(Client, "start", started)


@pytest.fixture
def no_reconnection(monkeypatch: pytest.MonkeyPatch) -> None:
    keep_disconnected(monkeypatch)


@contextlib.contextmanager
def refused_port() -> Iterator[int]:
    """A loopback port nothing listens on (bound, so nobody else takes it meanwhile)."""
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        yield int(closed.getsockname()[1])


@contextlib.asynccontextmanager
async def silent_server() -> AsyncIterator[int]:
    """A loopback port that accepts connections and never sends anything."""
    held: list[asyncio.StreamWriter] = []

    async def hold(_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        held.append(writer)

    server = await asyncio.start_server(hold, "127.0.0.1", 0)
    try:
        yield int(server.sockets[0].getsockname()[1])
    finally:
        server.close()
        for writer in held:
            writer.close()
        await server.wait_closed()


def trajectory_file(path: Path, *rows: Sequence[float]) -> Path:
    path.write_text(
        "time,q1,q2,q3,q4,q5,q6\n" + "".join(",".join(map(str, row)) + "\n" for row in rows), encoding="utf-8"
    )
    return path


# -- troubleshooting.md ------------------------------------------------------------------------------


def test_the_exit_status_example(capsys: pytest.CaptureFixture[str]) -> None:
    text = section("troubleshooting.md", "Exit status of `robot-client`")
    (bash,), (transcript,) = fenced(text, "bash"), fenced(text, "text")
    code = cli.main(command(bash), io.StringIO())  # refused before connecting
    check_transcript(transcript, code, capsys.readouterr().err)


def test_the_connection_refused_example(capsys: pytest.CaptureFixture[str]) -> None:
    text = section("troubleshooting.md", "Connection refused: no server, or the wrong port")
    (bash,), (transcript,) = fenced(text, "bash"), fenced(text, "text")
    argv = command(bash)
    with refused_port() as port:
        argv[argv.index("--state-port") + 1] = str(port)
        code = cli.main(argv, io.StringIO())
    check_transcript(transcript, code, capsys.readouterr().err)


@pytest.mark.slow
async def test_the_ready_line_and_a_port_in_use(tmp_path: Path) -> None:
    text = section("troubleshooting.md", "Connection refused: no server, or the wrong port")
    async with robot_server(tmp_path, "--no-stdin") as server:
        assert says(span(text, "robot-server ready: "), server.ready), server.ready
        # a second server on the first one's motion port
        second = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "robot_server",
            "--motion-port",
            str(server.ports["motion"]),
            "--state-port",
            "0",
            "--no-stdin",
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.PIPE,
        )
        async with asyncio.timeout(WAIT * 3):
            _, err = await second.communicate()
        assert second.returncode == 1
        assert_says(span(text, "[Errno 98]"), err.decode().splitlines(), "standard error")
        assert await server.terminate() == 0


@pytest.mark.slow
@pytest.mark.usefixtures("no_reconnection")
async def test_the_wrong_byte_order_examples(tmp_path: Path, capsys: pytest.CaptureFixture[str], logs: Logs) -> None:
    text = section("troubleshooting.md", "Wrong byte order")
    status, decode = fenced(text, "bash")
    client_side, server_side = fenced(text, "text")
    argv = command(status)
    async with controller() as (emu, ports):  # little-endian, the generic profile's
        code, _ = await client(*argv, *ports)
        check_transcript(client_side, code, capsys.readouterr().err, logs)

        # a big-endian PING: the server answers what it read (nothing) and closes
        reader, writer = await asyncio.open_connection("127.0.0.1", emu.ports["motion"])
        try:
            writer.write(bytes.fromhex("0000000c000000010000000200000000"))
            async with asyncio.timeout(WAIT):
                assert await reader.read() == b""
        finally:
            writer.close()
        check_transcript(server_side, 0, "", logs)

    # the time running out while connected: nothing came on this connection yet
    async with silent_server() as port:
        code, _ = await client(*argv, "--motion-port", str(port), "--state-port", str(port))
    assert code == 1
    assert_says(span(text, "robot-client: no joint state and STATUS"), capsys.readouterr().err.splitlines())

    # simple-message decode of a big-endian PING as little-endian
    capture = tmp_path / "ping.hex"
    capture.write_text(decode.splitlines()[1].split()[1] + "\n", encoding="utf-8")
    assert sm_cli.main(["decode", str(capture)]) == 1
    assert_says(span(text, '{"error": '), capsys.readouterr().err.splitlines())


async def test_the_start_mismatch_messages(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], logs: Logs
) -> None:
    text = section("troubleshooting.md", '"... starts ... rad away from the robot\'s position"')
    client_says, server_logs = fenced(text, "text")
    gap = re.search(r"robot-client: (\S+) starts ([\d.]+) rad away", client_says)
    away = re.search(r"the first point is ([\d.]+) from the current position of joint (\d)", server_logs)
    assert gap and away
    monkeypatch.chdir(tmp_path)
    start = float(gap.group(2))
    path = trajectory_file(Path(gap.group(1)), (0, start, 0, 0, 0, 0, 0), (1, start + 0.1, 0, 0, 0, 0, 0))
    async with controller() as (emu, ports):
        code, _ = await client("run", str(path), *ports)
        check_transcript(client_says + "\nexit status 1", code, capsys.readouterr().err)

        # the driver's own words, in Python
        raised = span(text, "DriverError: ").removeprefix("DriverError: ")
        model = load_model("jibot_zxs")
        async with RobotDriver(motion_port=emu.ports["motion"], state_port=emu.ports["state"], model=model) as driver:
            with pytest.raises(DriverError) as refused:
                await driver.execute(Trajectory.load(path))
        assert says(raised, str(refused.value)), (raised, str(refused.value))

        # another client's first point elsewhere: the emulator refuses it and logs why
        first = [0.0] * 6
        first[int(away.group(2)) - 1] = float(away.group(1))
        async with Client.tcp("127.0.0.1", emu.ports["motion"], name="motion") as motion:
            with pytest.raises(RequestFailed):
                await motion.request(JointTrajPt(0, tuple(first), velocity=0.2), timeout=WAIT)
        check_transcript(server_logs, 0, "", logs)
        assert positions(emu)[0] == 0.0


#: the fault command (robot-server's standard input) for each row of the table of refused points
FAULTS = {"e-stop": "estop", "drives off": "drives off", "alarm": "alarm 1234 overheated", "MANUAL mode": "mode manual"}


def refusal_rows() -> dict[str, list[str]]:
    """The table of refused points: its first column's start -> the row's cells."""
    rows = {}
    for line in section("troubleshooting.md", "Refused points").splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if line.startswith("| ") and cells[0] not in ("cause",):
            key = next((k for k in FAULTS if cells[0].startswith(k)), cells[0])
            rows[key] = cells
    return rows


def test_every_row_of_the_refusal_table_is_checked() -> None:
    assert set(refusal_rows()) == set(FAULTS)


@pytest.mark.parametrize("cause", list(FAULTS))
async def test_the_refused_points_table(
    cause: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], logs: Logs
) -> None:
    cells = refusal_rows()[cause]
    (client_says,), (server_logs,) = spans(cells[1]), spans(cells[2])
    async with controller() as (emu, ports):
        emu.command(FAULTS[cause])
        path = trajectory_file(tmp_path / "p.csv", (0, 0, 0, 0, 0, 0, 0), (1, 0.1, 0, 0, 0, 0, 0))
        code, _ = await client("run", str(path), *ports)
        assert code == 1
        assert_says(client_says, capsys.readouterr().err.splitlines(), "standard error")
        assert_says(server_logs, logs.lines(), "log")
        assert positions(emu)[0] == 0.0


async def test_motoros_refuses_start_traj_mode_under_an_estop(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    says_ = span(section("troubleshooting.md", "Refused points"), "START_TRAJ_MODE refused")
    async with controller(profile="motoros") as (emu, ports):
        emu.command("estop")
        path = trajectory_file(tmp_path / "p.csv", (0, 0, 0, 0, 0, 0, 0), (1, 0.1, 0, 0, 0, 0, 0))
        code, _ = await client("run", str(path), *ports)
    assert code == 1
    assert_says(says_, capsys.readouterr().err.splitlines(), "standard error")


async def test_the_limit_and_speed_messages(tmp_path: Path, capsys: pytest.CaptureFixture[str], logs: Logs) -> None:
    text = section("troubleshooting.md", "Refused points")
    beyond, too_fast = fenced(text, "text")[0].splitlines()
    at = re.search(r"point 1: joint 1 \(joint_1\) at ([\d.]+) ", beyond)
    rate = re.search(r"segment 0->1: joint 1 \(joint_1\) would move at ([\d.]+) rad/s", too_fast)
    assert at and rate
    async with controller() as (_, ports):
        path = trajectory_file(tmp_path / "beyond.csv", (0, 0, 0, 0, 0, 0, 0), (1, float(at.group(1)), 0, 0, 0, 0, 0))
        code, _ = await client("run", str(path), *ports)
        check_transcript(beyond + "\nexit status 1", code, capsys.readouterr().err)
        fast = (1 / float(rate.group(1)), 1, 0, 0, 0, 0, 0)  # 1 rad at that rate
        path = trajectory_file(tmp_path / "fast.csv", (0, 0, 0, 0, 0, 0, 0), fast)
        code, _ = await client("run", str(path), *ports)
        check_transcript(too_fast + "\nexit status 1", code, capsys.readouterr().err)

        # within the speed limit, too fast for the acceleration limit: under blend, slowed down
        # (downloaded: queued whole, the controller's time cannot outrun the client's points)
        path = trajectory_file(
            tmp_path / "sharp.csv",
            (0, 0, 0, 0, 0, 0, 0),
            (0.15, 0.3, 0, 0, 0, 0, 0),
            (0.45, 0, 0, 0, 0, 0, 0),
            (1.45, 0, 0, 0, 0, 0, 0),
        )
        code, _ = await client("run", str(path), "--mode", "download", *ports)
        assert code == 0, capsys.readouterr().err
        assert_says(span(text, "... is too fast for the joints' limits"), logs.lines(), "log")
    async with controller(interpolation="cubic") as (_, ports):  # refused by the others
        code, _ = await client("run", str(path), *ports)
        assert code == 1
        assert_says(span(text, "acceleration_limit: "), logs.lines(), "log")


@pytest.mark.slow
async def test_one_motion_client_at_a_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], logs: Logs, monkeypatch: pytest.MonkeyPatch
) -> None:
    text = section("troubleshooting.md", "One motion client at a time")
    (others_say,) = fenced(text, "text")
    async with controller(speedup=1.0) as (emu, ports):
        slowly = ["--joints", "2.5", "0", "0", "0", "0", "0", "--speed", "0.05"]  # about 16 s
        moving = asyncio.create_task(client("move", *slowly, *ports))
        try:
            await poll(lambda: positions(emu)[0] > 0.05, WAIT)
            code, _ = await client("move", "--joints", "0.1", "0", "0", "0", "0", "0", *ports)
            check_transcript(others_say + "\nexit status 1", code, capsys.readouterr().err)
            path = trajectory_file(tmp_path / "p.csv", (0, 0, 0, 0, 0, 0, 0), (1, 0.1, 0, 0, 0, 0, 0))
            code, _ = await client("run", str(path), *ports)
            check_transcript(others_say + "\nexit status 1", code, capsys.readouterr().err)
            # stop: its request finds the motion connection closed (and kept closed)
            keep_disconnected(monkeypatch)
            code, _ = await client("stop", *ports)
            assert code == 1
            assert_says(span(text, "robot-client: motion connection down: "), capsys.readouterr().err.splitlines())
            assert_says(span(text, "refused: the robot is moving under motion client"), logs.lines(), "log")
            assert emu.cell.in_motion  # the others stopped nothing

            emu.command("stop")  # robot-server's stop: the moving client sees the robot stand still
            code, _ = await moving
        finally:
            moving.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await moving
    assert code == 1
    # how far from the goal depends on when the stop came: the page's number is an example
    stands_still = re.sub(r"still [\d.]+ from", "still ... from", span(text, "the robot stands still "))
    assert_says(stands_still, capsys.readouterr().err.splitlines(), "standard error")


@pytest.mark.usefixtures("no_reconnection")
async def test_a_full_state_port(capsys: pytest.CaptureFixture[str], logs: Logs) -> None:
    text = section("troubleshooting.md", "A full state port")
    (transcript,) = fenced(text, "text")
    argv = command(span(text, "robot-client --profile motoros status"))
    async with controller(profile="motoros") as (emu, ports):
        limit = emu.state_server.max_connections
        streams = [await asyncio.open_connection("127.0.0.1", emu.ports["state"]) for _ in range(limit)]
        readers = [asyncio.create_task(reader.read()) for reader, _ in streams]  # they read: not idle
        try:
            await poll(lambda: len(emu.state_server.sessions) == limit, WAIT)
            code, _ = await client(*argv, *ports)
        finally:
            for _, writer in streams:
                writer.close()
            async with asyncio.timeout(WAIT):
                await asyncio.gather(*readers, return_exceptions=True)
    assert f"{limit} connections is the limit" in transcript
    check_transcript(transcript + "\nexit status 1", code, capsys.readouterr().err, logs)


# -- kinematics.md -----------------------------------------------------------------------------------


def _jibot_line(start: Sequence[float], goal: Sequence[float]) -> Callable[[], object]:
    model = load_model("jibot_zxs")
    return lambda: Planner(model).linear_moves(start, [fk(model, goal)])


def _out_of_reach() -> object:
    model = load_model("jibot_zxs")
    keep = fk(model, CENTRE)[:3, :3]
    return Planner(model).linear_moves(CENTRE, [pose((0.9, 0.0, 0.12), keep)])


def _no_closed_form() -> object:
    return Planner(load_model("ur5")).linear_moves([0.0, -1.0, 1.0, 0.0, 1.0, 0.0], [np.eye(4)])


#: a distinctive part of each refusal kinematics.md quotes -> a plan that is refused so; the
#: configurations were found by trying random lines of jibot_zxs
PLANNER_REFUSALS: dict[str, Callable[[], object]] = {
    "is out of reach within the joint limits: try": _out_of_reach,
    "steps along it is out of reach": _jibot_line((-0.8, -0.8, 2.1, -0.3, 1.6, 0.2), (0.1, 1.3, 1.2, 0.5, -0.2, 3.8)),
    "starts at a WRIST singularity": _jibot_line((0.0,) * 6, CENTRE),
    "passes too near a singularity": _jibot_line((0.6, 1.3, 1.3, -1.5, -0.7, 3.8), (-2.3, 1.1, 1.4, -0.2, -0.7, -2.2)),
    "a joint would jump": _jibot_line((-1.2, -0.2, 0.0, 0.3, 1.7, 2.9), (0.6, 1.6, -1.4, -1.9, 0.4, -4.6)),
    "leaves the joint limits": _jibot_line((-2.2, 0.0, -0.2, 2.3, 0.4, 0.1), (0.0, -0.8, -2.3, -1.7, 0.6, -3.0)),
    "has no closed-form inverse kinematics": _no_closed_form,
}


def _planner_quotes() -> list[str]:
    """The messages quoted in kinematics.md's list of what ``move --pose`` refuses."""
    text = section("kinematics.md", "What `robot-client move --pose` does")
    listed = text[text.index("\n* ") : text.index("`robot-client` prints the message")]
    return [s for s in spans(listed) if " " in s]


def test_every_planner_refusal_quoted_is_checked() -> None:
    quotes = _planner_quotes()
    assert all(sum(key in q for key in PLANNER_REFUSALS) == 1 for q in quotes), quotes
    assert all(any(key in q for q in quotes) for key in PLANNER_REFUSALS)


@pytest.mark.parametrize("key", list(PLANNER_REFUSALS))
def test_the_planner_refusals(key: str) -> None:
    (quoted,) = [q for q in _planner_quotes() if key in q]
    with pytest.raises(PlanningError) as refused:
        PLANNER_REFUSALS[key]()
    assert says(quoted, str(refused.value)), f"the docs quote\n  {quoted}\nthe planner says\n  {refused.value}"


async def test_robot_client_says_what_would_run_instead(capsys: pytest.CaptureFixture[str]) -> None:
    text = section("kinematics.md", "What `robot-client move --pose` does")
    quoted = span(text, "robot-client: line 0: starts at a WRIST singularity")
    async with controller() as (_, ports):  # the robot at q = 0
        code, _ = await client("move", "--pose", "0.38", "0.02", "0.12", *ports)
    assert code == 1
    assert_says(quoted, capsys.readouterr().err.splitlines(), "standard error")


async def test_the_controller_refuses_a_line_out_of_reach(capsys: pytest.CaptureFixture[str]) -> None:
    text = section("kinematics.md", "What `robot-client move --pose` does")
    (example,) = fenced(text, "bash")
    last = command(example.splitlines()[-1])
    async with controller() as (_, ports):
        code, _ = await client("move", "--joints", *map(str, CENTRE), *ports)
        assert code == 0, capsys.readouterr().err
        code, _ = await client(*last, "--linear", *ports)
    assert code == 1
    assert_says(span(text, "robot-client: the controller refused line 0"), capsys.readouterr().err.splitlines())


# -- cartesian.md ------------------------------------------------------------------------------------


def test_the_cell_file_shown_has_the_shipped_settings() -> None:
    shown = tomllib.loads(fenced(section("cartesian.md", "Supervision"), "text")[0])
    shipped = tomllib.loads((ROOT / "robot_server" / "models" / "cell_example.toml").read_text(encoding="utf-8"))
    assert shown == shipped


# -- trajectories.md ---------------------------------------------------------------------------------


def _examples() -> tuple[str, str]:
    text = section("trajectories.md", "Example")
    (csv_text,), (json_text,) = fenced(text, "csv"), fenced(text, "json")
    return csv_text, json_text


def _same(a: Trajectory, b: Trajectory, *, derivatives: bool = True) -> bool:
    same = a.joint_names == b.joint_names and np.array_equal(a.times, b.times)
    same = same and np.array_equal(a.positions, b.positions)
    if derivatives:
        for x, y in ((a.velocities, b.velocities), (a.accelerations, b.accelerations)):
            same = same and ((x is None and y is None) or (x is not None and y is not None and np.array_equal(x, y)))
    return same


def test_the_trajectory_examples_load_as_the_same_points_and_survive_a_save(tmp_path: Path) -> None:
    csv_text, json_text = _examples()
    (tmp_path / "wave.csv").write_text(csv_text, encoding="utf-8")
    (tmp_path / "wave.json").write_text(json_text, encoding="utf-8")
    from_csv, from_json = Trajectory.load(tmp_path / "wave.csv"), Trajectory.load(tmp_path / "wave.json")
    assert _same(from_csv, from_json, derivatives=False)
    assert from_csv.joint_names == tuple(f"joint_{j}" for j in range(1, 7)) and from_csv.duration == 2.0
    assert from_csv.velocities is None and from_json.velocities is not None
    for loaded in (from_csv, from_json):
        for suffix in ("csv", "json"):
            again = tmp_path / f"again.{suffix}"
            loaded.save(again)
            assert _same(Trajectory.load(again), loaded), (loaded, suffix)
    # what save writes for JSON has the layout the page shows
    data = json.loads((tmp_path / "again.json").read_text(encoding="utf-8"))
    assert set(data) == {"joint_names", "points"} and set(data["points"][0]) == {"time", "positions", "velocities"}


@pytest.mark.slow
async def test_the_trajectory_example_commands_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    csv_text, json_text = _examples()
    (tmp_path / "wave.csv").write_text(csv_text, encoding="utf-8")
    (tmp_path / "wave.json").write_text(json_text, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    (commands,) = fenced(section("trajectories.md", "Example"), "sh")
    ran = []
    async with controller() as (emu, ports):
        for line in commands.splitlines():
            argv = command(line)
            code, out = await client(*argv, *ports)
            assert code == 0, (line, out, capsys.readouterr().err)
            ran.append(argv[0])
            if argv[0] == "run" and argv[1].startswith("wave"):
                assert np.allclose(positions(emu), 0.0, atol=2e-3)  # out and back
    assert ran.count("run") == 3 and "record" in ran
    recorded = Trajectory.load(tmp_path / "still.json")
    assert recorded.joint_names == tuple(f"joint_{j}" for j in range(1, 7)) and len(recorded) > 1


#: how each row of trajectories.md's table of unusable files changes the example
BREAKAGES: dict[str, Callable[[str, str], tuple[str, str]]] = {
    '`"time": 1` left out': lambda c, j: ("wave.json", _without_time(j)),
    "last time changed to 1": lambda c, j: ("wave.csv", c.replace("\n2,", "\n1,")),
    "a value left out": lambda c, j: ("wave.csv", c.replace("1,0.3,0.2,0,0,0,0", "1,0.3,0.2,0,0,0")),
    "named `shoulder`": lambda c, j: ("wave.csv", c.replace(",joint_2,", ",shoulder,")),
}


def _without_time(json_text: str) -> str:
    data = json.loads(json_text)
    del data["points"][1]["time"]
    return json.dumps(data)


def _breakage_rows() -> dict[str, str]:
    rows = {}
    for line in section("trajectories.md", "Example").splitlines():
        if line.startswith("| `wave."):
            first, says_ = (cell.strip() for cell in line.strip().strip("|").split("|"))
            key = next((k for k in BREAKAGES if k in first), first)
            (rows[key],) = spans(says_)
    return rows


def test_every_unusable_file_of_the_table_is_checked() -> None:
    assert set(_breakage_rows()) == set(BREAKAGES)


@pytest.mark.parametrize("change", list(BREAKAGES))
def test_the_messages_for_unusable_files(
    change: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    name, broken = BREAKAGES[change](*_examples())
    assert broken not in _examples()
    (tmp_path / name).write_text(broken, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    with refused_port() as port:  # refused before connecting: nothing listens anyway
        code = cli.main(["run", name, "--motion-port", str(port), "--state-port", str(port)], io.StringIO())
    err = capsys.readouterr().err
    assert code == 2, err
    assert_says(_breakage_rows()[change], err.splitlines(), "standard error")
