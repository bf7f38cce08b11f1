"""The server suite: probe a running simple_message server (a controller, real or emulated) and
judge it by the rules the real peers follow.

It connects to the server's state port first and listens (the server speaks first there: byte
order and float size are detected from its frames), then asks the motion port what can be asked
without moving anything (PING, requests of a type nobody assigns, a burst of requests, the
reference library's list of malformed frames), and watches the state topics throughout. Only with
``allow_motion`` does it send trajectory points, and only after STATUS says the robot is idle, in
AUTO and not in error.

This module holds the options and :class:`ServerSuite`, the run: the order the rules run in, and
what each group of them needs first. The rest is composed from:

* :mod:`.expectations`: the catalogue. What a profile's real servers do differently (which port
  answers a PING, how an unknown type is answered, which topics the state port sends at what rate),
  :data:`EXPECTATIONS`, from the project's protocol notes (docs/reference/protocol.md §3, §5, §8), and every
  rule with its source, :data:`SERVER_RULES` (the rules and their sources are listed in
  docs/conformance.md), in the groups the run takes them in;
* :mod:`.server_runner`: the rule runner (each rule judged once, SKIPs and aborts, the report in
  the catalogue's order);
* :mod:`.server_session`: the suite's links to the server, the wire format it speaks, one exchange
  of a request and its reply, and what the state link says of the robot;
* :mod:`.server_checks`: the passive checks, pure functions of what the server sent on its own
  (the state topics) and of every frame received (the framing);
* :mod:`.server_probes`: the requests that cannot move anything;
* :mod:`.server_motion`: the motion choreography: a small move, a move stopped, a point beyond the
  joints' range, MotoROS's trajectory mode, BUSY and start position; every move followed by one
  back to where the robot was.

The names in ``__all__`` are importable from here.
"""

from __future__ import annotations

import asyncio
import fnmatch
import time
from dataclasses import dataclass

from ..messages import message_class
from .expectations import EXPECTATIONS, MOTION_RULES, REQUEST_RULES, SERVER_RULES, STATE_RULES, Expectations
from .links import ProbeLink
from .report import Report
from .server_checks import (
    framing_body,
    framing_byte_order,
    framing_float_size,
    framing_length,
    reply_comm_types,
    state_consistency,
    state_joint_state,
    state_rate,
    state_status,
    state_topics,
)
from .server_motion import MotionRules
from .server_probes import Probes
from .server_runner import RuleRunner
from .server_session import Session

__all__ = ["ServerSuiteOptions", "ServerSuite", "Expectations", "EXPECTATIONS", "SERVER_RULES", "run_server_suite"]


@dataclass(frozen=True)
class ServerSuiteOptions:
    """Where the server is and what may be done to it."""

    host: str = "127.0.0.1"
    profile: str = "generic"
    #: None: the profile's port
    motion_port: int | None = None
    state_port: int | None = None
    io_port: int | None = None
    #: "little" | "big" | None: detected from the server's first frame
    byte_order: str | None = None
    #: 4 | 8 | None: detected
    float_size: int | None = None
    #: send trajectory points (it moves the robot)
    allow_motion: bool = False
    #: the small move, on joint ``joint`` (1-based)
    amplitude: float = 0.01
    joint: int = 1
    #: target reached within this (rad)
    tolerance: float = 0.001
    #: how long the state topics are watched before any motion (s)
    observe: float = 3.0
    #: the small move's duration (s); the stopped move takes twice as long
    move_time: float = 2.0
    reply_timeout: float = 2.0
    #: how long a move may take beyond its duration (s)
    motion_timeout: float = 10.0
    #: the joint-state rate expected (Hz); None: any above 1 Hz
    state_rate: float | None = None
    #: the msg_type used as an unknown type
    unknown_type: int = 65535
    #: rule patterns (fnmatch) to run only / to leave out
    only: tuple[str, ...] = ()
    skip: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.profile not in EXPECTATIONS:
            raise ValueError(f"unknown profile {self.profile!r} (known: {', '.join(EXPECTATIONS)})")
        if self.byte_order not in (None, "little", "big"):
            raise ValueError(f"byte order must be little or big, not {self.byte_order!r}")
        if self.float_size not in (None, 4, 8):
            raise ValueError(f"float size must be 4 or 8, not {self.float_size!r}")
        if not 1 <= self.joint <= 10:
            raise ValueError(f"joint must be 1..10, not {self.joint}")
        if not 0 < self.amplitude <= 0.2:
            raise ValueError(f"amplitude must be in (0, 0.2] rad, not {self.amplitude}")
        if not 0 < self.tolerance < self.amplitude:
            raise ValueError(f"tolerance must be in (0, amplitude), not {self.tolerance}")
        for name in ("observe", "move_time", "reply_timeout", "motion_timeout"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name.replace('_', ' ')} must be positive")
        if message_class(self.unknown_type) is not None or not 0 < self.unknown_type < 2**31:
            raise ValueError(
                f"unknown type {self.unknown_type} is a known message type (or out of range): choose one nobody "
                "assigns, e.g. 65535"
            )
        for pattern in self.only + self.skip:
            if not any(fnmatch.fnmatchcase(rule, pattern) for rule in SERVER_RULES):
                raise ValueError(f"{pattern!r} matches no rule (rules: {', '.join(SERVER_RULES)})")

    @property
    def ports(self) -> dict[str, int]:
        dialect = EXPECTATIONS[self.profile].dialect
        ports = {
            "motion": dialect.motion_port if self.motion_port is None else self.motion_port,
            "state": dialect.state_port if self.state_port is None else self.state_port,
        }
        # the generic nodes define an IO port but none of the real servers serves it (§6)
        if self.io_port is not None:
            ports["io"] = self.io_port
        elif dialect.io_port is not None and dialect.motion_control:
            ports["io"] = dialect.io_port
        return ports


class ServerSuite:
    """One run of the server suite against ``options.host``: :meth:`run` it once; :attr:`report`
    holds the rules judged (so far, if the run was cancelled)."""

    def __init__(self, options: ServerSuiteOptions) -> None:
        self.options = options
        self.expect = EXPECTATIONS[options.profile]
        self.dialect = self.expect.dialect
        self.report = Report("server", f"{options.host} ({options.profile})")
        self.session = Session(options)
        self.runner = RuleRunner(self.report, options.only, options.skip)
        self.probes = Probes(self.session)
        self.motion_rules = MotionRules(self.session, self.runner)
        self.motion_started: float | None = None  # when the first motion was sent (state rules stop there)

    @property
    def links(self) -> list[ProbeLink]:
        """The links whose frames the framing rules judge."""
        return self.session.links

    async def run(self) -> Report:
        """Run every rule (those not wanted are left out of the report) and return the report. If
        cancelled, the motion under way is stopped first and :attr:`report` holds the rules run."""
        try:
            await self._run()
        except asyncio.CancelledError:
            await self._framing_rules()  # what was received so far is judged too
            raise
        finally:
            await self.session.close()
            self.runner.in_catalogue_order()
        return self.report

    async def _run(self) -> None:
        o = self.options
        session, rule = self.session, self.runner.rule
        ports = o.ports
        state_ok = await rule("connect.state", lambda: session.connect("state", ports["state"]), always=True)
        await rule("connect.motion", lambda: session.connect("motion", ports["motion"]), always=True)
        if "io" in ports:
            await rule("connect.io", lambda: session.connect("io", ports["io"]))
        else:
            self.runner.skip_all(["connect.io"], f"the {o.profile} profile has no IO port")
        observe_from = time.monotonic()
        await session.decide_wire()
        motion_rules = REQUEST_RULES + MOTION_RULES
        if session.motion is None:
            self.runner.skip_all(motion_rules, "the motion port did not accept a connection")
        elif session.wire is None:
            self.runner.skip_all(motion_rules, "the byte order is unknown: no state frame arrived; pass --byte-order")
        else:
            await self._requests()
        # the state rules judge what came before any motion, over at least `observe` seconds
        if session.state is not None and state_ok is not None:
            wait = observe_from + o.observe - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
        self.motion_started = time.monotonic()
        await self._state_rules()
        if session.motion is not None and session.wire is not None:
            await self.motion_rules.run()
        await self._framing_rules()

    async def _requests(self) -> None:
        rule, probes = self.runner.rule, self.probes
        await rule("reply.ping", probes.ping)
        await rule("reply.order", probes.order)
        await rule("reply.unknown-type", probes.unknown_type)
        await rule("reply.unknown-topic", probes.unknown_topic)
        if self.dialect.motion_control:
            await rule("motoros.check-motion-ready", probes.check_motion_ready)
        else:
            self.runner.skip_all(
                ["motoros.check-motion-ready"], f"not a MotoROS server (profile {self.options.profile})"
            )
        await rule("malformed.survival", probes.malformed)
        await self.session.reopen_motion()

    async def _state_rules(self) -> None:
        names = STATE_RULES
        rule, session = self.runner.rule, self.session
        if session.state is None:
            self.runner.skip_all(names, "the state port did not accept a connection")
            return
        frames = session.robot.seen(self.motion_started)
        if not frames:
            self.runner.skip_all(names[1:], "the state port sent nothing")
        await rule("state.topics", lambda: state_topics(frames, self.options, self.expect, session.real))
        if frames:
            await rule(
                "state.rate",
                lambda: state_rate(
                    frames,
                    self.options,
                    self.expect,
                    state=session.state,
                    motion_started=self.motion_started,
                    real=session.real,
                ),
            )
            await rule("state.joint-state", lambda: state_joint_state(frames, session.real))
            await rule("state.status", lambda: state_status(frames, self.dialect, session.real))
            await rule("state.status-consistency", lambda: state_consistency(frames))

    async def _framing_rules(self) -> None:
        """The framing rules, judged over every frame received on every link."""
        rule, session = self.runner.rule, self.session
        received = [f for link in session.links for f in link.frames if not f.outgoing]
        await rule(
            "framing.byte-order",
            lambda: framing_byte_order(
                received, self.options, self.dialect, wire=session.wire, detected=session.detected, real=session.real
            ),
        )
        await rule("framing.float-size", lambda: framing_float_size(received, self.options, session.detected))
        await rule("framing.length", lambda: framing_length(received, session.links, session.real))
        await rule("framing.body", lambda: framing_body(received, self.dialect, session.real))
        await rule("reply.comm-type", lambda: reply_comm_types(received, session.real))


async def run_server_suite(options: ServerSuiteOptions) -> Report:
    """Run the server suite with ``options`` and return its report."""
    return await ServerSuite(options).run()
