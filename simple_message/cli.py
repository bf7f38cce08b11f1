"""``simple-message``: decode and encode simple_message frames, like tshark for this protocol.

``simple-message decode [--byte-order little|big|auto] [--float64] [--raw] [--port P] [--type T] [--import M] [FILE]``
    Reads hex frames, one line per frame or per TCP segment (a line may be ``NAME HEX`` as in the
    conformance vector files, or ``time src dst HEX`` as in the capture segment files: the last
    token is the hex, the rest becomes ``"label"``; ``#`` lines and blank lines are skipped), or
    with ``--raw`` a binary byte stream, or a pcap/pcapng capture (a FILE that begins like one:
    TCP reassembled per connection and direction by :mod:`.capture`; each message also gets
    ``"time"``, ``"src"`` and ``"dst"``; ``--port`` and ``--type`` filter). Prints one JSON object
    per message on stdout. A malformed frame (or a gap in a capture) prints an error object on
    stderr; the command goes on and exits 1 at the end. A file that is not a readable capture
    although it begins like one is one error line, exit 1.

``simple-message encode [--byte-order little|big] [--float64] [--raw] [--import MODULE] [FILE]``
    Reads JSON objects, one per line, and prints each frame as a hex line (``--raw``: binary).

``simple-message replay FILE --against HOST[:PORT,...]``
    Plays a capture's client side against a controller and compares the replies (:mod:`.replay`).

``simple-message conformance server HOST ...`` / ``simple-message conformance client ...``
    The conformance suites (:mod:`.conformance`): judge a server or a client by the real peers'
    behaviour; a table, ``--json``, ``--junit``; exit 0 when no rule FAILed.

FILE defaults to standard input. Decode and encode know every message type in the registry of
:mod:`.messages`; ``--import MODULE`` (repeatable) imports a module first, e.g. one that registers
a vendor message set, so that its types decode and encode by name too.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Iterator
from typing import IO, Any

from .capture import CapturedMessage, CaptureError, capture_format, captured_messages, format_address
from .cliargs import (
    ArgumentParser,
    add_import_argument,
    add_log_level_argument,
    add_version_argument,
    client_port,
    import_all,
    positive_float,
    positive_int,
    preimport,
)
from .errors import FrameError, SimpleMessageError
from .framing import FrameDecoder
from .jsonio import message_from_json, message_to_json
from .messages import decode, encode, type_for_name
from .wire import ByteOrder, WireFormat

__all__ = ["main", "add_wire_arguments", "wire_from_args", "add_import_argument", "import_modules", "preimport"]

log = logging.getLogger("simple_message.cli")


def add_wire_arguments(
    parser: argparse.ArgumentParser, *, allow_auto: bool = True, default: str | None = "little", default_text: str = ""
) -> None:
    """The ``--byte-order`` and ``--float64`` options shared by every command of the project
    (``default`` None: the command decides, and says how in ``default_text``)."""
    choices = ["little", "big", "auto"] if allow_auto else ["little", "big"]
    said = default_text or f"{default}, the ROS default build"
    parser.add_argument(
        "--byte-order",
        choices=choices,
        default=default,
        help=f"wire byte order (default: {said}; Fanuc and FS100 use big)"
        + ("; auto detects it from the first length prefix" if allow_auto else ""),
    )
    parser.add_argument("--float64", action="store_true", help="reals are float64 (the FLOAT64 build)")


def wire_from_args(args: argparse.Namespace, default: str = "little") -> tuple[WireFormat, bool]:
    """The wire format the options ask for, and whether the byte order is to be detected
    (``default``: the byte order when the option was left to the command)."""
    chosen = args.byte_order if args.byte_order is not None else default
    auto = chosen == "auto"
    order = ByteOrder.LITTLE if auto else ByteOrder(chosen)
    return WireFormat(order, 8 if args.float64 else 4), auto


def import_modules(names: list[str]) -> bool:
    """Import ``names`` in order; report the first failure on stderr and return ``False``."""
    failure = import_all(names)
    if failure is not None:
        _emit_error(type(failure[1]).__name__, f"cannot import {failure[0]}: {failure[1]}")
        return False
    return True


def _emit_error(kind: str, message: str, **extra: Any) -> None:
    print(json.dumps({"error": message, "type": kind, **extra}), file=sys.stderr)


class _Decoding:
    def __init__(self, wire: WireFormat, auto: bool, out: IO[str]) -> None:
        self.wire = wire
        self.auto = auto
        self.out = out
        self.errors = 0

    def frames(self, decoder: FrameDecoder, **where: Any) -> None:
        """Print every message ``decoder`` holds; report a framing error and stop there."""
        while True:
            try:
                frame = decoder.next_frame()
            except FrameError as exc:
                self.errors += 1
                _emit_error(type(exc).__name__, str(exc), **where)
                return
            if frame is None:
                return
            wire = self.wire.with_byte_order(decoder.byte_order or self.wire.byte_order)
            try:
                obj = message_to_json(decode(frame, wire), wire.real_size)
            except SimpleMessageError as exc:
                self.errors += 1
                _emit_error(type(exc).__name__, str(exc), hex=frame.hex(), **where)
                continue
            obj.update(where)
            self.out.write(json.dumps(obj) + "\n")

    def new_decoder(self) -> FrameDecoder:
        return FrameDecoder(None if self.auto else self.wire.byte_order)

    def leftover(self, decoder: FrameDecoder, **where: Any) -> None:
        if decoder.buffered and not decoder.failed:
            self.errors += 1
            _emit_error("TruncatedFrame", f"{decoder.buffered} bytes at the end do not make a whole frame", **where)


def _hex_lines(stream: IO[str]) -> Iterator[tuple[int, str | None, str]]:
    for number, line in enumerate(stream, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        tokens = text.split()
        label = " ".join(tokens[:-1]) or None
        yield number, label, tokens[-1]


def _is_capture(path: str) -> bool:
    """Whether ``path`` is a file that begins like a pcap or pcapng capture (a pipe or a device is
    not looked into: what was read from it would be lost to the hex reader)."""
    if not os.path.isfile(path):
        return False
    with open(path, "rb") as probe:
        return capture_format(probe.read(4)) is not None


def _msg_types(names: list[str]) -> set[int] | None:
    """The msg_types ``--type`` names (a name or alias in any case, or a number); ``None`` after
    reporting one that is neither."""
    types: set[int] = set()
    for name in names:
        try:
            msg_type: int | None = int(name, 0)
        except ValueError:
            msg_type = type_for_name(name)
        if msg_type is None:
            _emit_error("UsageError", f"--type {name}: no message type of that name (give a name or a number)")
            return None
        types.add(msg_type)
    return types


def _decode_capture(args: argparse.Namespace) -> int:
    """``decode`` of a pcap/pcapng capture: messages on stdout, gaps and errors on stderr."""
    wire, auto = wire_from_args(args, default="auto")
    types = _msg_types(args.types) if args.types else None
    if args.types and types is None:
        return 2
    out = sys.stdout
    errors = 0
    try:
        for item in captured_messages(args.file, wire, auto, ports=args.ports or None, types=types):
            if isinstance(item, CapturedMessage):
                where: dict[str, Any] = {
                    "time": item.time,
                    "src": format_address(item.src),
                    "dst": format_address(item.dst),
                }
                if item.message is None:
                    errors += 1
                    _emit_error(type(item.error).__name__, str(item.error), hex=item.frame.hex(), **where)
                    continue
                obj = message_to_json(item.message, wire.real_size)
                obj.update(where)
                out.write(json.dumps(obj) + "\n")
                continue
            errors += 1
            extra: dict[str, Any] = {}
            if item.time is not None:
                extra["time"] = item.time
            if item.src is not None and item.dst is not None:
                extra["src"] = format_address(item.src)
                extra["dst"] = format_address(item.dst)
            if item.start is not None:
                extra["start"] = item.start
            if item.end is not None:
                extra["end"] = item.end
            _emit_error(item.kind.value, item.message, **extra)
    except CaptureError as exc:
        _emit_error(type(exc).__name__, str(exc))
        return 1
    return 1 if errors else 0


def _host_and_ports(text: str) -> tuple[str, str]:
    """``HOST[:PORT,...]``, an IPv6 address in brackets (``[::1]:50240,50241``) or alone (``::1``)."""
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        return host, rest.removeprefix(":")
    if text.count(":") == 1:
        host, _, listed = text.partition(":")
        return host, listed
    return text, ""  # a name, an IPv4 address, or a bare IPv6 address


def _replay(args: argparse.Namespace) -> int:
    """``replay``: the capture's client side against ``--against``, a table, exit 0 iff all match."""
    import asyncio

    from .replay import ReplayError, exchanges, format_table, from_capture, replay, server_ports

    wire, auto = wire_from_args(args, default="auto")
    host, listed = _host_and_ports(args.against)
    try:
        items, wire, problems = from_capture(args.file, wire, auto, ports=args.ports or None)
    except CaptureError as exc:
        _emit_error(type(exc).__name__, str(exc))
        return 1
    for problem in problems:
        print(f"simple-message replay: {args.file}: {problem}", file=sys.stderr)
    plan = exchanges(items)
    if not plan:
        _emit_error("ReplayError", f"{args.file}: no client message to replay")
        return 1
    captured = server_ports(items)
    try:
        targets = [client_port(p) for p in listed.split(",")] if listed else captured
    except argparse.ArgumentTypeError as exc:
        _emit_error("UsageError", f"--against {args.against}: {exc}")
        return 2
    if len(targets) != len(captured):
        _emit_error(
            "UsageError",
            f"--against {args.against}: the capture has {len(captured)} controller port(s) "
            f"({', '.join(map(str, captured))}); give as many",
        )
        return 2
    ports = dict(zip(captured, targets, strict=True))
    options = {"keep_timing": args.keep_timing, "remap": args.remap, "reply_timeout": args.reply_timeout}
    try:
        outcomes = asyncio.run(replay(plan, host, ports, wire, **options))
    except ReplayError as exc:
        _emit_error("ReplayError", str(exc))
        return 1
    print(format_table(outcomes))
    return 0 if all(o.match for o in outcomes) else 1


#: a file's first bytes that say what it is when it is no capture and no hex text
_NOT_TEXT = {b"\x1f\x8b": "a gzip-compressed file: gunzip it first", b"\x28\xb5\x2f\xfd": "a zstd-compressed file"}
_CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap", ".ntar")


def _not_a_capture(path: str) -> str | None:
    """Why ``path``, which is no capture, cannot be read as hex text either (None: it may be)."""
    if not os.path.isfile(path):
        return None
    with open(path, "rb") as probe:
        head = probe.read(4096)
    for magic, what in _NOT_TEXT.items():
        if head.startswith(magic):
            return what
    if path.lower().endswith(_CAPTURE_SUFFIXES):
        return "not a pcap or pcapng capture (its first bytes are no capture's)" if head else "an empty file"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not a character cut at the end of the probe
            return "a binary file: neither a pcap/pcapng capture nor hex lines (--raw reads a byte stream)"
    return None


def _decode(args: argparse.Namespace) -> int:
    if not args.raw and args.file != "-" and _is_capture(args.file):
        return _decode_capture(args)
    if not args.raw and args.file != "-" and (why := _not_a_capture(args.file)) is not None:
        _emit_error("CaptureError", f"{args.file}: {why}")
        return 1
    if args.ports or args.types:
        _emit_error("UsageError", "--port and --type apply to pcap/pcapng captures only")
        return 2
    wire, auto = wire_from_args(args)
    job = _Decoding(wire, auto, sys.stdout)
    if args.raw:
        stream = open(args.file, "rb") if args.file != "-" else sys.stdin.buffer  # noqa: SIM115
        with stream:
            decoder = job.new_decoder()
            while chunk := stream.read(65536):
                decoder.feed(chunk)
                job.frames(decoder)
                if decoder.failed:
                    break
            job.leftover(decoder)
        return 1 if job.errors else 0
    text = open(args.file, encoding="utf-8", errors="replace") if args.file != "-" else sys.stdin  # noqa: SIM115
    with text:
        for number, label, hexdata in _hex_lines(text):
            where: dict[str, Any] = {"line": number}
            if label is not None:
                where["label"] = label
            try:
                data = bytes.fromhex(hexdata)
            except ValueError:
                job.errors += 1
                _emit_error("BadHex", f"not hexadecimal: {hexdata[:40]!r}", **where)
                continue
            decoder = job.new_decoder()
            decoder.feed(data)
            job.frames(decoder, **where)
            job.leftover(decoder, **where)
    return 1 if job.errors else 0


def _encode(args: argparse.Namespace) -> int:
    wire, _ = wire_from_args(args)
    errors = 0
    out = sys.stdout.buffer if args.raw else None
    text = open(args.file, encoding="utf-8") if args.file != "-" else sys.stdin  # noqa: SIM115
    with text:
        for number, line in enumerate(text, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            try:
                frame = encode(message_from_json(json.loads(line)), wire)
            except (json.JSONDecodeError, SimpleMessageError) as exc:
                errors += 1
                _emit_error(type(exc).__name__, str(exc), line=number)
                continue
            if out is not None:
                out.write(frame)
            else:
                sys.stdout.write(frame.hex() + "\n")
    if out is not None:
        out.flush()
    return 1 if errors else 0


_DECODE = """Read simple_message frames and print one JSON object per message on stdout.

The input is hex, one line per frame or per TCP segment: a line may be NAME HEX (as in the
conformance vector files) or TIME SRC DST HEX (as in the capture segment files); the last token is
the hex and the rest becomes "label"; lines starting with # and blank lines are skipped. With --raw
the input is a binary byte stream. A malformed frame prints an error object on stderr; the command
goes on and exits 1 at the end.

A FILE that begins like a pcap or pcapng capture (tcpdump, Wireshark, robot-server --capture) is
read as one: each TCP connection is reassembled per direction (out-of-order segments put back in
order, retransmissions dropped) and its frames decoded; each message also gets "time" (seconds
since the epoch, from the capture), "src" and "dst" ("address:port", IPv6 in brackets). Link types:
Ethernet, Linux cooked (SLL, SLL2), raw IP and BSD loopback; IPv4 and IPv6. Bytes missing from the
capture are reported as a "Gap" error object with the byte range, and decoding of that direction
restarts after them; an incomplete frame at the end of a connection is a "TruncatedFrame". Use
--byte-order auto (each direction's byte order detected) or big for big-endian controllers (Fanuc,
Motoman). --port and --type filter captures only. A file that begins like a capture but is
truncated or malformed is one "CaptureError" object on stderr and exit status 1."""

_ENCODE = """Read JSON objects, one per line (as decode prints them), and print each message's frame as a
hex line on stdout, or with --raw as binary. Lines starting with # and blank lines are skipped. A
line that does not encode prints an error object on stderr; the command goes on and exits 1 at the
end."""

_REPLAY = """Play the client side of a captured session (a pcap/pcapng capture) against a controller or the
emulator, and compare each reply with the captured one by kind: message type, comm type, reply code,
and a MotoROS MOTO_MOTION_REPLY's result and subcode (values such as positions are not compared).
Requests go as fast as the protocol allows (or with --keep-timing, no earlier than in the capture); a
request the captured controller answered BUSY is sent again while the target answers BUSY. Prints a
table, one line per request or topic sent, and a summary; exits 0 only when every reply matches."""

_REPLAY_EXAMPLE = """Example, a real FS100's session against the emulator (its ports 50240 and 50241):
  robot-server --profile motoros --byte-order big --interpolation-period 0.002 &
  simple-message replay motoman_fs100_simple_move.pcapng --against 127.0.0.1 --remap 6"""

_TYPES = """Every message type of the registry decodes and encodes by name; --import MODULE (repeatable)
imports a module first, e.g. one that registers a vendor message set."""


def _add_port_filter(parser: argparse.ArgumentParser, help: str) -> None:
    parser.add_argument(
        "--port", dest="ports", action="append", default=[], type=client_port, metavar="PORT", help=help
    )


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="simple-message",
        description="Decode, encode and replay ROS-Industrial simple_message frames; judge servers and clients.",
        epilog="Run 'simple-message COMMAND --help' for a command's options.",
    )
    add_version_argument(parser)
    add_log_level_argument(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", help="what to do")
    dec = sub.add_parser(
        "decode",
        help="frames (hex lines, --raw bytes or a pcap/pcapng capture) to JSON lines",
        description=f"{_DECODE}\n\n{_TYPES}",
    )
    add_wire_arguments(dec, default=None, default_text="little for hex and bytes, auto for a capture")
    dec.add_argument("--raw", action="store_true", help="input is a binary byte stream, not hex lines")
    add_import_argument(dec)
    _add_port_filter(dec, "captures only: keep the connections with PORT at either end (repeatable)")
    dec.add_argument(
        "--type",
        dest="types",
        action="append",
        default=[],
        metavar="TYPE",
        help="captures only: keep the messages of this type, a name (any case) or a number (repeatable)",
    )
    dec.add_argument(
        "file",
        nargs="?",
        default="-",
        metavar="FILE",
        help="input file: hex lines, bytes with --raw, or a pcap/pcapng capture (default: stdin)",
    )
    dec.set_defaults(func=_decode)
    rep_ = sub.add_parser(
        "replay",
        help="play a capture's client side against a controller and compare the replies",
        description=_REPLAY,
        epilog=_REPLAY_EXAMPLE,
    )
    add_wire_arguments(rep_, default="auto", default_text="auto, detected from the capture's first frame")
    add_import_argument(rep_)
    rep_.add_argument("file", metavar="FILE", help="a pcap/pcapng capture of a session")
    rep_.add_argument(
        "--against",
        required=True,
        metavar="HOST[:PORT,...]",
        help="the controller to replay against; the capture's controller ports, ascending, map to the PORTs "
        "given (default: the same port numbers)",
    )
    _add_port_filter(rep_, "replay only the connections with PORT at either end (repeatable)")
    rep_.add_argument(
        "--keep-timing",
        action="store_true",
        help="send each request no earlier than the capture did (default: at once)",
    )
    rep_.add_argument(
        "--remap",
        type=positive_int,
        metavar="JOINTS",
        help="move the trajectory points to where the target robot stands, for a robot of JOINTS joints "
        "(the slots beyond them cleared)",
    )
    rep_.add_argument(
        "--reply-timeout", type=positive_float, default=5.0, metavar="SECONDS", help="per reply (default: 5)"
    )
    rep_.set_defaults(func=_replay)
    enc = sub.add_parser(
        "encode",
        help="JSON lines to frames (hex lines or --raw bytes)",
        description=f"{_ENCODE}\n\n{_TYPES}",
    )
    add_wire_arguments(enc, allow_auto=False)
    enc.add_argument("--raw", action="store_true", help="write binary frames instead of hex lines")
    add_import_argument(enc)
    enc.add_argument(
        "file", nargs="?", default="-", metavar="FILE", help="input file: JSON objects, one a line (default: stdin)"
    )
    enc.set_defaults(func=_encode)
    from .conformance.command import add_conformance_parser

    add_conformance_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if not import_modules(args.imports):
        return 2
    try:
        return int(args.func(args))
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): stop quietly, as other Unix tools do.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)  # stdout's descriptor now points there itself
        return 0
    except OSError as exc:
        _emit_error("OSError", str(exc))
        return 2
    except KeyboardInterrupt:
        return 130
