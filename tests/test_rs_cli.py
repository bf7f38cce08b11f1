"""``robot-server`` in process: ``main(argv)`` with argument errors, ``--help``, and runs on
loopback ended by the signals the command obeys (SIGTERM, SIGINT).

``main`` installs its signal handlers on the event loop, so it runs in the main thread (these
tests are synchronous) and a helper thread plays the user: it waits until the emulator has started
(the handlers are installed by then), looks and talks to it, and sends the signal. Every wait is
bounded. tests/test_rs_server_process.py runs the installed command as a process.
"""

from __future__ import annotations

import contextlib
import os
import runpy
import signal
import socket
import struct
import sys
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from robot_server import cli
from robot_server.emulator import Emulator
from tests.rawpeer import PREFIX, vectors

#: the bound of every wait on the server (s)
WAIT = 30.0
V = vectors("<")
BE = vectors(">")


@dataclass
class Run:
    """What the helper thread sees of one ``main`` run."""

    started: threading.Event = field(default_factory=threading.Event)
    finished: threading.Event = field(default_factory=threading.Event)
    applied: list[str] = field(default_factory=list)
    changed: threading.Condition = field(default_factory=threading.Condition)
    emulators: list[Emulator] = field(default_factory=list)

    @property
    def emulator(self) -> Emulator:
        return self.emulators[0]

    def wait_applied(self, count: int) -> list[str]:
        """The fault commands applied, once there are ``count`` of them."""
        with self.changed:
            assert self.changed.wait_for(lambda: len(self.applied) >= count, WAIT), self.applied
            return list(self.applied)


@pytest.fixture
def run(monkeypatch: pytest.MonkeyPatch) -> Run:
    """Watches ``main``: the emulator it starts and the fault commands it applies."""
    seen = Run()

    class Watched(Emulator):
        async def start(self) -> Emulator:
            await super().start()
            seen.emulators.append(self)
            seen.started.set()
            return self

    original = cli._apply

    def apply(emulator: Emulator, command: str) -> None:
        original(emulator, command)
        with seen.changed:
            seen.applied.append(command)
            seen.changed.notify_all()

    monkeypatch.setattr(cli, "Emulator", Watched)
    monkeypatch.setattr(cli, "_apply", apply)
    return seen


def serve(run: Run, argv: list[str], user: Callable[[Run], None], stop: signal.Signals = signal.SIGTERM) -> int:
    """``main(argv)`` in this (the main) thread; ``user(run)`` in a helper thread once the emulator
    has started, then ``stop`` is sent to the process, which ``main`` handles by shutting down."""
    failure: list[BaseException] = []

    def helper() -> None:
        try:
            run.started.wait(WAIT)
            if run.finished.is_set() or not run.started.is_set():
                return  # main returned (or never started): nothing to stop
            try:
                user(run)
            finally:
                os.kill(os.getpid(), stop)
        except BaseException as exc:  # reported by the test, in its thread
            failure.append(exc)

    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    thread = threading.Thread(target=helper, name="robot-server user")
    thread.start()
    try:
        code = cli.main(argv)
    finally:
        run.finished.set()
        run.started.set()  # wakes a helper still waiting for a start that will not come
        thread.join(WAIT)
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert not thread.is_alive()
    if failure:
        raise failure[0]
    return code


@contextlib.contextmanager
def stdin_lines(text: str) -> Iterator[None]:
    """Standard input (descriptor 0, which the command reads) holds ``text`` and then ends."""
    read, write = os.pipe()
    saved = os.dup(0)
    try:
        os.write(write, text.encode())
        os.close(write)
        os.dup2(read, 0)
        yield
    finally:
        os.dup2(saved, 0)
        os.close(saved)
        os.close(read)


def blocking_request(port: int, frame: bytes, order: str = "<") -> bytes:
    """One request and its reply over a plain blocking socket (the helper thread has no loop)."""
    with socket.create_connection(("127.0.0.1", port), timeout=WAIT) as sock:
        sock.sendall(frame)
        return read_frame(sock, order)


def read_frame(sock: socket.socket, order: str = "<") -> bytes:
    def exactly(n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            assert chunk, "the server closed the connection"
            data += chunk
        return data

    prefix = exactly(PREFIX)
    (length,) = struct.unpack(order + "i", prefix)
    return prefix + exactly(length)


PORTS = ["--motion-port", "0", "--state-port", "0"]


# -- runs ----------------------------------------------------------------------------------------------


def test_a_run_takes_faults_from_stdin_and_the_command_line_and_writes_one_record_per_group(
    run: Run, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    record = tmp_path / "trace.csv"
    argv = [*PORTS, "--speedup", "4", "--model", "jibot_zxs", "--model", "puma560", "--fault", "0:drives off"]
    argv += ["--record", str(record), "--record-seconds", "5", "--log-level", "INFO"]
    replies: list[bytes] = []

    def user(run: Run) -> None:
        applied = run.wait_applied(4)
        assert sorted(applied) == ["drives off", "estop", "explode", "reset"]
        replies.append(blocking_request(run.emulator.ports["motion"], V["PING_REQUEST"]))

    caplog.set_level("INFO", logger="robot_server")
    with stdin_lines("estop\n\nreset\nexplode\n"):
        assert serve(run, argv, user) == 0
    assert replies == [V["PING_REPLY_SUCCESS"]]
    out = capsys.readouterr().out
    assert out.startswith("robot-server ready: generic profile, jibot_zxs + puma560, motion 127.0.0.1:")
    messages = [r.getMessage() for r in caplog.records]
    for applied in ("applied: drives off", "applied: estop", "applied: reset", "fault: emergency stop engaged"):
        assert applied in messages, messages
    assert any("explode" in r.getMessage() for r in caplog.records if r.levelname == "WARNING")
    assert "shutting down" in messages
    # one CSV per motion group, every servo tick of controller time since the start
    first, second = record.read_text().splitlines(), (tmp_path / "trace.g1.csv").read_text().splitlines()
    assert first[0].startswith("time,") and second[0].startswith("time,")
    assert len(first) == len(second) > 1


def test_a_cell_file_sets_the_supervision_and_manual_motion_allows_motion_in_manual(run: Run) -> None:
    argv = [*PORTS, "--cell", "cell_example", "--manual-motion", "--no-stdin", "--log-level", "WARNING"]
    seen: list[object] = []

    def user(run: Run) -> None:
        cell = run.emulator.cell
        supervision = cell.groups[0].supervision
        seen.extend([supervision.floor, supervision.manual_speed, [b.name for b in supervision.forbidden]])
        seen.append(cell.manual_motion)  # (what MANUAL then does: tests/test_rs_lines_emulator.py)

    assert serve(run, argv, user) == 0
    assert seen == [-0.2, 0.25, ["fixture"], True]


def test_sigint_ends_a_motoros_run_and_the_state_port_publishes_until_then(run: Run) -> None:
    argv = [*PORTS, "--io-port", "0", "--profile", "motoros", "--byte-order", "big", "--no-stdin"]
    argv += ["--state-rate", "200", "--log-level", "WARNING"]
    topics: list[int] = []

    def user(run: Run) -> None:
        assert set(run.emulator.ports) == {"motion", "state", "io"}
        with socket.create_connection(("127.0.0.1", run.emulator.ports["state"]), timeout=WAIT) as sock:
            topics.extend(struct.unpack_from(">i", read_frame(sock, ">"), 4)[0] for _ in range(4))
        reply = blocking_request(run.emulator.ports["motion"], BE["PING_REQUEST"], ">")
        assert struct.unpack_from(">iii", reply, 4) == (1, 3, 1)  # PING, SERVICE_REPLY, SUCCESS

    assert serve(run, argv, user, stop=signal.SIGINT) == 0
    assert set(topics) <= {10, 13, 15, 2017} and 13 in topics  # STATUS among the state topics


def test_a_record_that_cannot_be_written_at_exit_fails_with_one_line(
    run: Run, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "gone"
    folder.mkdir()

    def user(_run: Run) -> None:
        folder.rmdir()  # writable when the command started, gone when it exits

    assert serve(run, [*PORTS, "--no-stdin", "--record", str(folder / "trace.csv")], user) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("robot-server: cannot write the record:") and "\n" not in err


def test_a_taken_port_fails_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = cli.main(["--motion-port", str(port), "--state-port", "0", "--no-stdin"])
    assert code == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("robot-server: ") and "\n" not in err


# -- arguments -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--model", "nosuchrobot"], "nosuchrobot"),
        (["--state-rate", "5000"], "state-rate"),
        (["--fault", "1:explode"], "explode"),
        (["--record", "{tmp}/missing/run.csv"], "no directory"),  # refused before, not after
        (["--record", "{tmp}"], "is a directory"),
        (["--record-seconds", "7200"], "record-seconds"),
        # the fleet file's bounds: no period of years, no servo tick of a nanosecond, no capture of 1e308 MB
        (["--interpolation-period", "1e300"], "--interpolation-period is at most 1 s"),
        (["--servo-period", "1e-9"], "more than 1000 ticks per --interpolation-period"),
        (["--capture-max-mb", "1e308"], "--capture-max-mb is at most 1e+06"),
        (["--profile", "nosuch"], "unknown profile 'nosuch'"),
        (["--interpolation", "nosuch"], "nosuch"),
        (["--import", "tests.no_such_module"], "cannot import tests.no_such_module"),
        (["--model", "{tmp}/bad.toml"], "bad.toml"),
        (["--cell", "nosuch"], "no such cell file"),
        (["--cell", "{tmp}/bad.toml"], "bad.toml"),
    ],
)
def test_bad_values_fail_with_one_line_naming_the_problem(
    args: list[str], words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "bad.toml").write_text("this is not [toml")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert cli.main([*argv, "--no-stdin"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("robot-server: ") and words in lines[0], lines
    assert captured.out == ""


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--speedup", "0"], "must be > 0"),
        (["--motion-port", "70000"], "a port is 0..65535"),
        (["--fault", "soon"], "expected SECONDS:COMMAND"),
        (["--fault=-1:estop"], "expected SECONDS:COMMAND"),
        (["--byte-order", "middle"], "invalid choice"),
    ],
)
def test_malformed_arguments_are_usage_errors(args: list[str], words: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(args)
    assert info.value.code == 2
    assert words in capsys.readouterr().err


def test_a_record_too_large_for_memory_fails_with_one_line(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def no_memory(self: Emulator, seconds: float) -> list[object]:
        raise MemoryError

    monkeypatch.setattr(Emulator, "record", no_memory)
    assert cli.main(["--record", str(tmp_path / "trace.csv"), "--no-stdin"]) == 2
    assert "a smaller --record-seconds" in capsys.readouterr().err


def test_help_lists_the_fault_commands_profiles_and_policies(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: robot-server")
    for words in ("fault commands", "estop", "alarm CODE", "generic:", "motoros:", "quintic:"):
        assert words in out, words


@pytest.mark.usefixtures("plain_imports")
def test_python_dash_m_robot_server_is_the_command(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sys, "argv", ["robot_server", "--state-rate", "0"])
    with pytest.raises(SystemExit) as info:
        runpy.run_module("robot_server", run_name="__main__", alter_sys=True)
    assert info.value.code == 2
    assert "must be > 0" in capsys.readouterr().err


def test_fault_commands_are_checked_by_their_first_word() -> None:
    cli._check_command("alarm 12 hot")  # the arguments are the fault's business, at run time
    for bad in ("", "   ", "teleport now"):
        with pytest.raises(ValueError, match="unknown fault command"):
            cli._check_command(bad)
