"""What the project's three commands (``simple-message``, ``robot-server``, ``robot-client``) share
on their command lines: the parser class, the help formatter, the argument types and the options
they define alike (``--version``, ``--log-level``, ``--import``, the wire options of a profile).

The parser (:class:`ArgumentParser`) reports a usage error in one line on stderr and exits 2, as
every other failure of the commands is reported in one line; its help shows every default. The
argument types refuse nonsense at parse time (a usage error): numbers that must be positive
(:func:`positive_float`, :func:`positive_int`), that may be 0 (:func:`non_negative_float`,
:func:`non_negative_int`), and ports: a server binds 0..65535, 0 meaning any free port
(:func:`server_port`), a client connects to 1..65535 (:func:`client_port`).
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import math
import re
import textwrap
from collections.abc import Sequence
from importlib import metadata
from typing import Any, NoReturn

__all__ = [
    "DISTRIBUTION",
    "LOG_LEVELS",
    "ArgumentParser",
    "HelpFormatter",
    "add_capture_arguments",
    "add_import_argument",
    "add_log_level_argument",
    "add_profile_wire_arguments",
    "add_version_argument",
    "client_port",
    "distribution_version",
    "options_after_command",
    "log_level",
    "non_negative_float",
    "non_negative_int",
    "positive_float",
    "positive_int",
    "preimport",
    "server_port",
]

#: the distribution the three commands come with (pyproject.toml, ``[project] name``)
DISTRIBUTION = "simple-message-stack"

#: the ``--log-level`` values (any case on the command line)
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")


# -- the parser and its help ---------------------------------------------------------------------------


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default, and keeps the line breaks of descriptions and epilogs.

    A default is added as ``(default: VALUE)`` unless the help already says it (it mentions
    ``default``, e.g. ``(default: the profile's)``) or there is none to show (``None``, a flag's
    ``False``, an empty list). Descriptions and epilogs are filled paragraph by paragraph: a blank
    line separates paragraphs and an indented line is kept as written (a table, an example), only
    wrapped under its text column when it is wider than the terminal.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if "default" in text or default is None or default is False or default == [] or default is argparse.SUPPRESS:
            return text
        if isinstance(default, float) and (action.option_strings or action.nargs in (argparse.OPTIONAL, "*")):
            return f"{text} (default: %(default)g)"  # 40, not 40.0
        return super()._get_help_string(action)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        lines: list[str] = []
        paragraph: list[str] = []

        def flush() -> None:
            if paragraph:
                lines.extend(textwrap.wrap(" ".join(paragraph), width, initial_indent=indent, subsequent_indent=indent))
                paragraph.clear()

        for line in text.splitlines():
            if not line.strip():
                flush()
                lines.append("")
            elif line[0].isspace():
                flush()
                lines.extend(_hanging(indent + line, width))
            else:
                paragraph.append(line.strip())
        flush()
        return "\n".join(lines)


def _hanging(line: str, width: int) -> list[str]:
    """An indented line as written, or, when too long, wrapped under its text column (``  name   text``)."""
    if len(line) <= width:
        return [line]
    column = re.match(r"\s+\S.*?\s{2,}(?=\S)", line) or re.match(r"\s*", line)
    assert column is not None
    hang = " " * min(column.end(), width // 2)
    return textwrap.wrap(line, width, subsequent_indent=hang) or [line]


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` with the project's help (:class:`HelpFormatter` unless told
    otherwise, also for subcommands) and a usage error in one line on stderr, exit status 2:
    ``PROG: error: MESSAGE (see 'PROG --help')``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        text = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {text} (see '{self.prog} --help')\n")


class _Unparsed(Exception):
    """What :func:`options_after_command`'s probe could not parse (the real parser reports it)."""


class _Probe(ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise _Unparsed(message)


def options_after_command(
    argv: Sequence[str], common: argparse.ArgumentParser, parser: argparse.ArgumentParser
) -> list[str]:
    """``argv`` with the options of ``common`` (the parent parser every subcommand of ``parser``
    shares) that were given before the subcommand moved after it, where argparse looks for them:
    ``robot-client --profile motoros status`` is ``robot-client status --profile motoros``. A bad
    value there is ``parser``'s usage error (exit status 2), and so are, before the subcommand, an
    option of a subcommand (it goes after it), an option no subcommand has (with a close name,
    when there is one), and options with no subcommand after them (the subcommands listed).
    ``--help`` and ``--version`` are left for ``parser`` to answer, with no subcommand after them
    whatever options came before."""
    args = list(argv)
    probe = _Probe(add_help=False, parents=[common], allow_abbrev=False)  # --mode is not --model
    probe.add_argument("rest", nargs=argparse.REMAINDER)
    try:
        known, extras = probe.parse_known_args(args)
    except _Unparsed as exc:
        parser.error(str(exc))
    rest = list(known.rest)
    answered = ("-h", "--help", "--version")
    stray = [a.split("=")[0] for a in extras if a.startswith("-") and a.split("=")[0] not in answered]
    commands = _subcommands(parser)
    if stray:
        name = stray[0]
        options = _options(parser, commands)
        if name not in options:
            # the options that may come here first (--modle, --mod: --model, not move's --mode)
            shared = sorted(o for o in common._option_string_actions if o.startswith("--"))
            prefixed = [o for o in shared if o.startswith(name)]
            close = prefixed if len(prefixed) == 1 else difflib.get_close_matches(name, shared, n=1, cutoff=0.75)
            if not close:
                close = difflib.get_close_matches(name, sorted(options), n=1, cutoff=0.75)  # not --pose for --bogus
            hint = f" (did you mean {close[0]}?)" if close else ""
            parser.error(f"{name} is not an option of any {parser.prog} command{hint}")
        takers = [command for command, sub in commands.items() if name in sub._option_string_actions]
        parser.error(
            f"{name} is not an option of {parser.prog} itself: a command's own options go after it"
            + (f" ({', '.join(takers)} {'takes' if len(takers) == 1 else 'take'} {name})" if takers else "")
        )
    asked = [a for a in extras if a.split("=")[0] in answered]
    if asked and not rest:
        return asked[:1]  # the help or the version, whatever options came before
    if args and not rest and commands:
        parser.error(
            f"a command is missing: {' '.join(args)} must be followed by one of {', '.join(commands)} "
            f"({parser.prog} [OPTIONS] COMMAND [OPTIONS])"
        )
    if extras or not rest or len(rest) == len(args):
        return args
    before = len(args) - len(rest)
    return [rest[0], *args[:before], *rest[1:]]


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """``parser``'s subcommands by name (none when it has none)."""
    found: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found.update(action.choices)
    return found


def _options(parser: argparse.ArgumentParser, commands: dict[str, argparse.ArgumentParser]) -> set[str]:
    """Every option string of ``parser`` and of its subcommands."""
    return {option for p in (parser, *commands.values()) for action in p._actions for option in action.option_strings}


# -- argument types ------------------------------------------------------------------------------------


def _number(text: str, rule: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number {rule}, not {text!r}") from None
    if math.isnan(value) or math.isinf(value):
        raise argparse.ArgumentTypeError(f"must be {rule} and finite, not {text}")
    return value


def _integer(text: str, rule: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer {rule}, not {text!r}") from None


def _at_least(value: float, text: str, lowest: float, strict: bool) -> None:
    if value < lowest or (strict and value == lowest):
        raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {lowest:g}, not {text}")


def positive_float(text: str) -> float:
    """A finite number > 0: a duration, a period, a rate, a factor."""
    value = _number(text, "> 0")
    _at_least(value, text, 0.0, strict=True)
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0: a time from the start, where 0 is the start itself."""
    value = _number(text, ">= 0")
    _at_least(value, text, 0.0, strict=False)
    return value


def positive_int(text: str) -> int:
    """An integer >= 1: a count, a capacity."""
    value = _integer(text, ">= 1")
    _at_least(value, text, 1, strict=False)
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0, for a count where 0 means something (none, no limit: the help says which)."""
    value = _integer(text, ">= 0")
    _at_least(value, text, 0, strict=False)
    return value


def _port(text: str, lowest: int, rule: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{rule}, not {text!r}") from None
    if not lowest <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{rule}, not {text}")
    return value


def server_port(text: str) -> int:
    """A port to bind: 0..65535, where 0 asks the system for any free port."""
    return _port(text, 0, "a port is 0..65535 (0: any free port)")


def client_port(text: str) -> int:
    """A port to connect to: 1..65535 (0 names no port to connect to)."""
    return _port(text, 1, "a port is 1..65535")


def log_level(text: str) -> str:
    """A :data:`LOG_LEVELS` name in any case, returned in upper case (what ``logging`` takes)."""
    level = text.strip().upper()
    if level not in LOG_LEVELS:
        raise argparse.ArgumentTypeError(f"unknown level {text!r} (choose from {', '.join(LOG_LEVELS)}; any case)")
    return level


# -- shared options ------------------------------------------------------------------------------------


def distribution_version() -> str:
    """The installed distribution's version, or ``"unknown"`` when it is not installed (a source tree)."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


def add_version_argument(parser: argparse.ArgumentParser) -> None:
    """``--version``: print ``PROG VERSION`` on stdout and exit 0."""
    parser.add_argument(
        "--version",
        action="version",
        version=f"%(prog)s {distribution_version()}",
        help=f"print the version ({DISTRIBUTION}) and exit",
    )


def add_capture_arguments(parser: argparse.ArgumentParser, what: str, default_mb: float) -> None:
    """``--capture FILE.pcapng`` (recording ``what``) and ``--capture-max-mb MB``, as
    :class:`~.capture.CaptureWriter` writes them (robot-server and robot-client)."""
    parser.add_argument(
        "--capture",
        metavar="FILE.pcapng",
        help=f"record {what} to a pcapng file that Wireshark and 'simple-message decode' read (a name ending in "
        ".pcap: classic pcap; replaced if it exists)",
    )
    parser.add_argument(
        "--capture-max-mb",
        type=positive_float,
        default=default_mb,
        metavar="MB",
        help="the capture's bound in megabytes, its files together: the file rotates at half of it (FILE.pcapng "
        "becomes FILE.1.pcapng), so the latest traffic is kept (default: %(default)g)",
    )


def add_log_level_argument(parser: argparse.ArgumentParser, default: str = "WARNING") -> None:
    """``--log-level LEVEL``: the logging threshold, one of :data:`LOG_LEVELS` in any case."""
    parser.add_argument(
        "--log-level",
        type=log_level,
        default=default,
        metavar="LEVEL",
        help=f"logging threshold on stderr: {', '.join(LOG_LEVELS)} (any case)",
    )


def add_import_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--import MODULE`` option: modules to import first (e.g. a vendor message set)."""
    parser.add_argument(
        "--import",
        dest="imports",
        action="append",
        default=[],
        metavar="MODULE",
        help="import MODULE first, e.g. one that registers a vendor message set, a dialect or a profile (repeatable)",
    )


def preimport(argv: Sequence[str] | None) -> str | None:
    """Import the modules ``argv`` names with ``--import`` now, before a command builds its parser
    from registries they add to (profiles, dialects, policies: so ``--help`` and the choices list
    them). Returns what went wrong, or None."""
    early = ArgumentParser(add_help=False)
    add_import_argument(early)
    known, _ = early.parse_known_args(argv)
    failure = import_all(known.imports)
    if failure is None:
        return None
    name, exc = failure
    return f"cannot import {name}: {type(exc).__name__}: {exc}"


def import_all(names: Sequence[str]) -> tuple[str, Exception] | None:
    """Import ``names`` in order; the first that fails and why, or None."""
    for name in names:
        try:
            importlib.import_module(name)
        except Exception as exc:  # anything a module can raise at import, RegistrationError included
            return name, exc
    return None


def add_profile_wire_arguments(parser: argparse.ArgumentParser, byte_orders: Sequence[str], defaults: str) -> None:
    """``--byte-order`` and ``--float64`` where the profile (its dialect) sets the wire format and
    the options override it; ``defaults`` says what the profiles use (e.g. ``"little"``)."""
    parser.add_argument(
        "--byte-order",
        choices=tuple(byte_orders),
        help=f"wire byte order (default: the profile's; {defaults})"
        + ("; auto detects it from each client's first frame" if "auto" in byte_orders else ""),
    )
    parser.add_argument(
        "--float64", action="store_const", const=True, help="8-byte reals (the FLOAT64 build; default: the profile's)"
    )
