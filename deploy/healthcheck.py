#!/usr/bin/env python3
"""robot-server-healthcheck: does the robot-server of this container answer?

The image's HEALTHCHECK and the Kubernetes probes run it. It takes robot-server's own options, the
few that say where a controller is (``--profile``, ``--host``, the ports, the byte order,
``--import``, ``--fleet``), so that ``robot-server-healthcheck --profile abb`` checks what
``robot-server --profile abb`` serves. Given none, it reads them off the robot-server process it
finds in /proc (PID 1 in a container): the image's check then follows whatever command the
container was started with, one controller or a fleet, with no settings of its own.

For each controller it checks that every port the controller serves is listening, and then sends a
PING on the motion port and waits for its SUCCESS reply, where the family's motion port answers
PINGs (the generic controller, MotoROS). ABB's, Fanuc's and Staubli's servers take trajectory points
only (ABB's stops on anything else, Fanuc's misframes it: ``Dialect.ping``), so for them nothing is
sent: the check is the listening ports alone, read from /proc/net/tcp, which costs the robot nothing.

Exit status 0: every controller healthy; 1: one is not (each controller's line says why); 2: the
options or the fleet file cannot be read, or no robot-server was found.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib
import sys
import time
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from simple_message import ByteOrder, Client, MsgType, Ping, ReplyCode, SimpleMessageError, WireFormat
from simple_message.dialects import Dialect, dialect

#: the addresses a server binds to reach every interface, and the loopback address to ask there
WILDCARDS = {"": "127.0.0.1", "0.0.0.0": "127.0.0.1", "::": "::1", "[::]": "::1"}
#: the options that say where the controllers are: given none, they are read off the server's process
LOCATING = ("fleet", "profile", "host", "motion_port", "state_port", "io_port", "byte_order", "float64", "imports")
#: /proc/net/tcp's state of a listening socket
TCP_LISTEN = "0A"


class Unreadable(Exception):
    """The options, the fleet file or the process table say nothing usable (exit status 2)."""


@dataclass(frozen=True)
class Controller:
    """Where one controller is and how it speaks."""

    name: str
    dialect: Dialect
    host: str
    ports: dict[str, int]
    wire: WireFormat


def server_options(argv: Sequence[str]) -> argparse.Namespace:
    """The options of ``robot-server`` that locate its controllers; the others are ignored."""
    p = argparse.ArgumentParser(prog="robot-server-healthcheck", description=__doc__.split("\n\n")[0])
    p.add_argument("--fleet", metavar="FILE.toml")
    p.add_argument("--profile")
    p.add_argument("--host")
    p.add_argument("--motion-port", type=int)
    p.add_argument("--state-port", type=int)
    p.add_argument("--io-port", type=int)
    p.add_argument("--byte-order", choices=("little", "big", "auto"))
    p.add_argument("--float64", action="store_true")
    p.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE")
    p.add_argument("--timeout", type=float, default=3.0, help="per check, in seconds (default: 3)")
    options, _ = p.parse_known_args(list(argv))
    return options


def find_server(proc: Path = Path("/proc")) -> list[str]:
    """robot-server's arguments, from the command line of its process: PID 1's in a container,
    else the lowest PID's that runs ``robot-server`` (or ``python -m robot_server``)."""
    found: list[tuple[int, list[str]]] = []
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            words = [w.decode(errors="replace") for w in (entry / "cmdline").read_bytes().split(b"\0")[:-1]]
        except OSError:
            continue
        for k, word in enumerate(words):
            if Path(word).name == "robot-server" or (word == "robot_server" and k > 0 and words[k - 1] == "-m"):
                found.append((int(entry.name), words[k + 1 :]))
                break
    if not found:
        raise Unreadable("no robot-server process found (give its options: robot-server-healthcheck --help)")
    return min(found)[1]


def _wire(d: Dialect, byte_order: str | None, float64: bool) -> WireFormat:
    order = d.wire.byte_order if byte_order in (None, "auto") else ByteOrder(byte_order)
    return WireFormat(order, 8 if float64 else d.wire.real_size)


def _ports(d: Dialect, motion: int | None, state: int | None, io: int | None) -> dict[str, int]:
    """The ports to check: motion and state, which every family serves; the IO port when given
    (which families serve one is the emulator's profile's to say, too costly to import here)."""
    ports = {"motion": motion or d.motion_port, "state": state or d.state_port}
    if io:
        ports["io"] = io
    return ports


def _family(name: str) -> Dialect:
    try:
        return dialect(name)
    except (KeyError, ValueError) as exc:
        raise Unreadable(f"unknown profile {name!r}: {exc}") from None


def controllers(options: argparse.Namespace) -> list[Controller]:
    """The controllers the options describe: one, or each of the fleet file's."""
    for module in options.imports:
        importlib.import_module(module)
    if options.fleet is None:
        d = _family(options.profile or "generic")
        ports = _ports(d, options.motion_port, options.state_port, options.io_port)
        wire = _wire(d, options.byte_order, options.float64)
        return [Controller(d.name, d, options.host or "127.0.0.1", ports, wire)]
    try:
        data = tomllib.loads(Path(options.fleet).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise Unreadable(f"{options.fleet}: {exc}") from None
    defaults = data.get("defaults", {})
    tables = data.get("controller", [])
    if not isinstance(defaults, dict) or not isinstance(tables, list) or not tables:
        raise Unreadable(f"{options.fleet}: no [[controller]] tables")
    found = []
    for table in tables:
        c = {**defaults, **table}
        d = _family(str(c.get("profile", "generic")))
        ports = _ports(d, c.get("motion_port"), c.get("state_port"), c.get("io_port"))
        wire = _wire(d, c.get("byte_order"), bool(c.get("float64", False)))
        found.append(Controller(str(c.get("name", "?")), d, str(c.get("host", "127.0.0.1")), ports, wire))
    return found


def listening(port: int, proc_net: Path = Path("/proc/net")) -> bool:
    """Whether a TCP socket of this network namespace listens on ``port`` (any address)."""
    for table in ("tcp", "tcp6"):
        try:
            lines = (proc_net / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 3 and fields[3] == TCP_LISTEN and int(fields[1].rsplit(":", 1)[1], 16) == port:
                return True
    return False


async def check(c: Controller, timeout: float) -> tuple[bool, str]:
    """One controller's verdict and the line that says it."""
    closed = [f"{role} {port}" for role, port in c.ports.items() if port and not listening(port)]
    if closed:
        return False, f"not listening: {', '.join(closed)}"
    if not c.dialect.ping:
        ports = ", ".join(str(p) for p in c.ports.values())
        return True, f"listening on {ports} (its motion port takes no PING: nothing sent)"
    host = WILDCARDS.get(c.host, c.host)
    client = Client.tcp(host, c.ports["motion"], c.wire, reconnect=None, dialect=c.dialect, name="healthcheck")
    start = time.perf_counter()
    try:
        await client.start(timeout, refused_ends=True)
        reply = await client.request(Ping(), timeout)
    except (OSError, TimeoutError, SimpleMessageError) as exc:
        return False, f"PING on {host}:{c.ports['motion']}: {type(exc).__name__}: {exc}"
    finally:
        await client.close()
    if reply.msg_type != MsgType.PING or reply.reply_code != ReplyCode.SUCCESS:
        return False, f"PING on {host}:{c.ports['motion']} answered by {reply!r}"
    return True, f"PING on {host}:{c.ports['motion']} answered in {(time.perf_counter() - start) * 1000:.1f} ms"


async def check_all(found: Sequence[Controller], timeout: float) -> bool:
    verdicts = await asyncio.gather(*(check(c, timeout) for c in found))
    for c, (ok, line) in zip(found, verdicts, strict=True):
        print(f"{c.name} ({c.dialect.name}): {'ok' if ok else 'UNHEALTHY'}: {line}", flush=True)
    return all(ok for ok, _ in verdicts)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        options = server_options(sys.argv[1:] if argv is None else argv)
        timeout = options.timeout
        if not any(getattr(options, key) for key in LOCATING):
            options = server_options(find_server())
        found = controllers(options)
    except (Unreadable, ImportError) as exc:
        print(f"robot-server-healthcheck: {exc}", file=sys.stderr)
        return 2
    return 0 if asyncio.run(check_all(found, timeout)) else 1


if __name__ == "__main__":
    sys.exit(main())
