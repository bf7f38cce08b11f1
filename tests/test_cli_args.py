"""The three commands' shared command line (``simple_message/cliargs.py``): ``--version``,
``--log-level`` in any case, help for every subcommand and option with the defaults shown, usage
errors in one line (exit status 2), numbers that refuse nonsense, and the rule for ports: a server
binds 0..65535 (0: any free port), a client connects to 1..65535.

Everything runs in process (``main(argv)``; robot-client's ``main(argv, out)``).
"""

from __future__ import annotations

import argparse
import asyncio
import io
import os
import re
import signal
from collections.abc import Callable, Iterator
from importlib import metadata
from typing import Any

import pytest

from client import cli as client_cli
from robot_server import cli as server_cli
from robot_server.emulator import Emulator
from simple_message import cli as sm_cli
from simple_message import cliargs
from simple_message.cliargs import (
    client_port,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    server_port,
)
from tests.refdata import DATA

#: each command: its name, its parser, and ``main`` taking only ``argv``
COMMANDS: dict[str, tuple[Callable[[], argparse.ArgumentParser], Callable[[list[str]], int]]] = {
    "simple-message": (sm_cli.build_parser, sm_cli.main),
    "robot-server": (server_cli.parser, server_cli.main),
    "robot-client": (client_cli.parser, lambda argv: client_cli.main(argv, io.StringIO())),
}


def one_line(err: str) -> str:
    """The one line a usage error prints on stderr."""
    assert err.count("\n") == 1 and err.endswith("\n"), err
    return err


def usage_error(main: Callable[[list[str]], int], argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """``main(argv)`` must stop with exit status 2 and one line on stderr, nothing on stdout."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    return one_line(captured.err)


def parsers(parser: argparse.ArgumentParser, path: str) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """``parser`` and every subcommand's parser under it, with the command line that reaches it."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from parsers(sub, f"{path} {name}")


def every_parser() -> list[tuple[str, argparse.ArgumentParser]]:
    return [found for name, (build, _) in COMMANDS.items() for found in parsers(build(), name)]


def subcommands() -> list[tuple[str, argparse.ArgumentParser]]:
    return [(path, parser) for path, parser in every_parser() if " " in path]


# -- --version -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", COMMANDS)
def test_version_prints_the_distribution_version_and_exits_0(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    _, main = COMMANDS[name]
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out == f"{name} {metadata.version('simple-message-stack')}\n"
    assert re.fullmatch(rf"{name} \d+\.\d+\S*\n", out)


def test_the_version_is_unknown_when_the_distribution_is_not_installed(monkeypatch: pytest.MonkeyPatch) -> None:
    def not_installed(name: str) -> str:
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", not_installed)
    assert cliargs.distribution_version() == "unknown"


def test_the_distribution_name_is_the_projects() -> None:
    pyproject = (DATA.parent.parent / "pyproject.toml").read_text()
    assert f'name = "{cliargs.DISTRIBUTION}"' in pyproject


# -- --log-level ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("level", ["debug", "DEBUG", "Info", "warning", "eRRor", "critical"])
def test_log_level_takes_any_case(level: str) -> None:
    assert sm_cli.build_parser().parse_args(["--log-level", level, "decode"]).log_level == level.upper()
    assert server_cli.parser().parse_args(["--log-level", level]).log_level == level.upper()
    assert client_cli.parser().parse_args(["status", "--log-level", level]).log_level == level.upper()


def test_log_level_debug_is_accepted_by_each_command(capsys: pytest.CaptureFixture[str]) -> None:
    # simple-message runs to the end; the other two stop at a later check, after the level was taken
    assert sm_cli.main(["--log-level", "debug", "decode", str(DATA / "vectors_le.txt")]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 26
    assert server_cli.main(["--log-level", "debug", "--profile", "nosuch", "--no-stdin"]) == 2
    assert "unknown profile 'nosuch'" in one_line(capsys.readouterr().err)
    assert client_cli.main(["move", "--log-level", "debug", "--joints", "1"], io.StringIO()) == 2
    assert "needs 6 values" in one_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("name", "argv"),
    [
        ("simple-message", ["--log-level", "verbose", "decode"]),
        ("robot-server", ["--log-level", "verbose"]),
        ("robot-client", ["status", "--log-level", "verbose"]),
    ],
)
def test_an_unknown_log_level_is_a_usage_error_naming_the_levels(
    name: str, argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    err = usage_error(COMMANDS[name][1], argv, capsys)
    assert "unknown level 'verbose'" in err and "DEBUG, INFO, WARNING, ERROR, CRITICAL" in err


# -- help ----------------------------------------------------------------------------------------------


def test_there_are_subcommands_to_check() -> None:
    paths = [path for path, _ in subcommands()]
    assert "simple-message decode" in paths and "simple-message encode" in paths
    for command in ("ping", "status", "monitor", "move", "run", "stop", "record", "demo"):
        assert f"robot-client {command}" in paths


@pytest.mark.parametrize(("path", "parser"), every_parser(), ids=[path for path, _ in every_parser()])
def test_every_command_has_a_description_of_whole_sentences(path: str, parser: argparse.ArgumentParser) -> None:
    assert parser.description, f"{path}: no description"
    # a description cut off mid-sentence (e.g. the first line of a docstring) does not end a sentence
    assert parser.description.rstrip().endswith("."), f"{path}: {parser.description!r}"


@pytest.mark.parametrize(("path", "parser"), every_parser(), ids=[path for path, _ in every_parser()])
def test_every_option_and_positional_has_help(path: str, parser: argparse.ArgumentParser) -> None:
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help and action.help is not argparse.SUPPRESS, f"{path}: {action.option_strings or action.dest}"
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                assert choice.help, f"{path} {choice.dest}: no summary"


@pytest.mark.parametrize(("path", "parser"), every_parser(), ids=[path for path, _ in every_parser()])
def test_every_default_is_shown(path: str, parser: argparse.ArgumentParser) -> None:
    formatter = parser._get_formatter()
    assert isinstance(formatter, cliargs.HelpFormatter), path
    for action in parser._actions:
        if action.default in (None, False, argparse.SUPPRESS, []) or isinstance(action, argparse._HelpAction):
            continue
        shown = formatter._expand_help(action)
        assert "default" in shown, f"{path} {action.option_strings or action.dest}: {shown!r}"
    parser.format_help()  # every help string formats (no stray %)


@pytest.mark.parametrize(
    ("name", "argv", "words"),
    [
        ("simple-message", ["--help"], ["(default: WARNING)", "--version", "DEBUG, INFO"]),
        ("simple-message", ["decode", "--help"], ["(default: little", "(default: stdin)", "TIME SRC DST HEX"]),
        (
            "robot-server",
            ["--help"],
            ["(default: the controller's: 40 generic", "(default: 0.004)", "(default: INFO)", "(default: 128)"],
        ),
        ("robot-server", ["--help"], ["0: any free port", "(default: generic", "(default: blend)"]),
        ("robot-client", ["ping", "--help"], ["--count N", "at least 1 (default: 5)", "1..65535"]),
        ("robot-client", ["demo", "--help"], ["(default: demo-output)", "(default: linear cubic quintic ruckig"]),
        (
            "robot-client",
            ["run", "--help"],
            ["FILE", "the trajectory file", "(default: the profile's:"],
        ),
    ],
)
def test_help_shows_the_defaults_and_rules(
    name: str, argv: list[str], words: list[str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")  # one line per option: the words are not broken
    with pytest.raises(SystemExit) as info:
        COMMANDS[name][1](argv)
    assert info.value.code == 0
    out = capsys.readouterr().out
    for word in words:
        assert word in out, word


@pytest.mark.parametrize(("path", "parser"), every_parser(), ids=[path for path, _ in every_parser()])
def test_help_fits_the_terminal_and_keeps_the_tables(
    path: str, parser: argparse.ArgumentParser, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "80")
    text = parser.format_help()
    assert max(len(line) for line in text.splitlines()) <= 80, text
    if path == "robot-server":  # the epilog's table of fault commands, one a line as written
        assert "\n  estop                engage the emergency stop" in text
        assert "\n  mode auto|manual     operating mode" in text


def test_a_description_keeps_its_paragraphs_and_indented_lines() -> None:
    formatter = cliargs.HelpFormatter("prog", width=40)
    text = "One paragraph that is long enough to be wrapped at forty columns.\n\nAnother.\n  kept   as   is\nlast"
    filled = formatter._fill_text(text, 40, "")
    assert filled.splitlines() == [
        "One paragraph that is long enough to be",
        "wrapped at forty columns.",
        "",
        "Another.",
        "  kept   as   is",
        "last",
    ]


# -- usage errors: one line, exit status 2 --------------------------------------------------------------


@pytest.mark.parametrize("count", ["0", "-3"])
def test_ping_count_below_1_is_a_usage_error(count: str, capsys: pytest.CaptureFixture[str]) -> None:
    err = usage_error(COMMANDS["robot-client"][1], ["ping", "--count", count], capsys)
    assert (
        err
        == f"robot-client ping: error: argument --count: must be >= 1, not {count} (see 'robot-client ping --help')\n"
    )


def test_ping_count_takes_an_integer(capsys: pytest.CaptureFixture[str]) -> None:
    assert client_cli.parser().parse_args(["ping", "--count", "1"]).count == 1
    err = usage_error(COMMANDS["robot-client"][1], ["ping", "--count", "2.5"], capsys)
    assert "argument --count: must be an integer >= 1, not '2.5'" in err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["monitor", "--duration", "-1"], "argument --duration: must be > 0, not -1"),
        (["monitor", "--duration", "0"], "argument --duration: must be > 0, not 0"),
        (["record", "states.csv", "--duration", "-5"], "argument --duration: must be > 0"),
        (["status", "--timeout", "0"], "argument --timeout: must be > 0"),
        (["status", "--timeout", "nan"], "argument --timeout: must be > 0 and finite, not nan"),
        (["demo", "--speedup", "0"], "argument --speedup: must be > 0"),
        (["demo", "--speedup", "inf"], "argument --speedup: must be > 0 and finite"),
        (["status", "--motion-port", "0"], "argument --motion-port: a port is 1..65535, not 0"),
        (["status", "--state-port", "65536"], "argument --state-port: a port is 1..65535, not 65536"),
        (["status", "--state-port", "http"], "argument --state-port: a port is 1..65535, not 'http'"),
        (["teleport"], "invalid choice: 'teleport'"),
        ([], "the following arguments are required: COMMAND"),
    ],
)
def test_robot_client_refuses_nonsense_in_one_line(
    argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    err = usage_error(COMMANDS["robot-client"][1], argv, capsys)
    assert err.startswith("robot-client") and words in err, err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--state-rate", "0"], "argument --state-rate: must be > 0, not 0"),
        (["--state-rate", "-40"], "argument --state-rate: must be > 0"),
        (["--interpolation-period", "-0.004"], "argument --interpolation-period: must be > 0"),
        (["--servo-period", "0"], "argument --servo-period: must be > 0"),
        (["--servo-period", "inf"], "argument --servo-period: must be > 0 and finite"),
        (["--speedup", "nan"], "argument --speedup: must be > 0 and finite"),
        (["--queue-size", "0"], "argument --queue-size: must be >= 1, not 0"),
        (["--queue-size", "-1"], "argument --queue-size: must be >= 1"),
        (["--max-connections", "0"], "argument --max-connections: must be >= 1, not 0"),
        (["--frame-timeout", "-1"], "argument --frame-timeout: must be > 0"),
        (["--record-seconds", "0"], "argument --record-seconds: must be > 0"),
        (["--fault=-1:estop"], "expected SECONDS:COMMAND"),
        (["--fault", "inf:estop"], "expected SECONDS:COMMAND"),
        (["--fault", "nan:estop"], "expected SECONDS:COMMAND"),
        (["--motion-port", "65536"], "argument --motion-port: a port is 0..65535 (0: any free port), not 65536"),
        (["--io-port", "-1"], "argument --io-port: a port is 0..65535"),
    ],
)
def test_robot_server_refuses_nonsense_in_one_line(
    argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    err = usage_error(COMMANDS["robot-server"][1], [*argv, "--no-stdin"], capsys)
    assert err.startswith("robot-server: error: ") and words in err, err
    assert err.endswith("(see 'robot-server --help')\n")


@pytest.mark.parametrize(
    "argv", [[], ["decode", "--byte-order", "sideways"], ["encode", "--byte-order", "auto"], ["transcode"]]
)
def test_simple_message_usage_errors_are_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert usage_error(COMMANDS["simple-message"][1], argv, capsys).startswith("simple-message")


# -- ports: servers bind 0 (any free port), clients connect to 1..65535 ----------------------------------


def test_the_server_accepts_port_0_for_every_port() -> None:
    args = server_cli.parser().parse_args(["--motion-port", "0", "--state-port", "0", "--io-port", "0"])
    assert (args.motion_port, args.state_port, args.io_port) == (0, 0, 0)
    args = server_cli.parser().parse_args(["--motion-port", "65535"])
    assert args.motion_port == 65535


def test_the_client_accepts_1_to_65535() -> None:
    args = client_cli.parser().parse_args(["status", "--motion-port", "1", "--state-port", "65535"])
    assert (args.motion_port, args.state_port) == (1, 65535)


def test_each_command_takes_the_shared_types() -> None:
    """The rules live in one module: no command has a copy of its own."""
    types: dict[str, Any] = {}
    for path, parser in every_parser():
        for action in parser._actions:
            if action.type is not None:
                types[f"{path} {action.dest}"] = action.type
    for port in ("motion_port", "state_port", "io_port"):
        assert types[f"robot-server {port}"] is server_port
    for command in ("ping", "status", "monitor", "move", "run", "stop", "record", "demo"):
        assert types[f"robot-client {command} motion_port"] is client_port
        assert types[f"robot-client {command} state_port"] is client_port
        assert types[f"robot-client {command} timeout"] is positive_float
    assert types["robot-client ping count"] is positive_int
    for module in (sm_cli, server_cli, client_cli):
        assert not hasattr(module, "_positive") and not hasattr(module, "_port"), module.__name__


def test_robot_server_binds_free_ports_with_port_0(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A whole run in process: bound to free ports, then SIGTERM (sent once it has started) ends it, 0."""
    bound: list[dict[str, int]] = []

    class Started(Emulator):
        async def start(self) -> Emulator:
            await super().start()
            bound.append(dict(self.ports))
            asyncio.get_running_loop().call_soon(os.kill, os.getpid(), signal.SIGTERM)
            return self

    monkeypatch.setattr(server_cli, "Emulator", Started)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        argv = ["--motion-port", "0", "--state-port", "0", "--no-stdin", "--log-level", "warning"]
        assert server_cli.main(argv) == 0
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    [ports] = bound
    assert ports["motion"] > 0 and ports["state"] > 0 and ports["motion"] != ports["state"]
    assert f"127.0.0.1:{ports['motion']}" in capsys.readouterr().out


# -- the types themselves --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kind", "good", "bad"),
    [
        (positive_float, {"0.5": 0.5, "1e3": 1000.0}, ["0", "-1", "inf", "-inf", "nan", "x", ""]),
        (non_negative_float, {"0": 0.0, "2.5": 2.5}, ["-0.1", "inf", "nan", "x"]),
        (positive_int, {"1": 1, "42": 42}, ["0", "-3", "1.5", "x"]),
        (non_negative_int, {"0": 0, "7": 7}, ["-1", "1.5", "x"]),
        (server_port, {"0": 0, "65535": 65535}, ["-1", "65536", "x"]),
        (client_port, {"1": 1, "65535": 65535}, ["0", "-1", "65536", "x"]),
        (cliargs.log_level, {"debug": "DEBUG", "Critical": "CRITICAL"}, ["verbose", ""]),
    ],
)
def test_the_types_take_what_they_say_and_refuse_the_rest(
    kind: Callable[[str], object], good: dict[str, object], bad: list[str]
) -> None:
    for text, value in good.items():
        assert kind(text) == value
    for text in bad:
        with pytest.raises(argparse.ArgumentTypeError):
            kind(text)
