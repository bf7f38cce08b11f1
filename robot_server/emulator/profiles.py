"""Which controller the emulator plays: one :class:`EmulatorProfile` per controller family.

A profile is data plus one builder. The data: the family's :class:`~simple_message.dialects.Dialect`
(default ports, byte order, float size, reply style: the protocol's side, shared with the client and
the endpoints), the ports the controller serves and its rules on each (how many connections it takes,
whether it answers TOPICs), and the controller's own settings (its start tolerance). The builder
makes the profile's :class:`Behaviour`: the message handlers it puts on the emulator's servers and
the state topics it publishes. :class:`~.server.Emulator` creates each port's server from the
profile's rules; a behaviour only registers handlers and hooks, it never changes a server's
settings.

Adding a controller family is one module that defines its behaviour (or reuses one) and calls
:func:`register_profile`; ``robot-server --profile NAME`` then serves it (CONTRIBUTING.md, "Adding a
dialect").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

from simple_message.dialects import Dialect
from simple_message.endpoints import Server, Session
from simple_message.fixed_reads import DiscardReads, FixedReads
from simple_message.registry import Registry
from simple_message.wire import WireFormat

from .cell import RobotCell
from .io_table import IoTable
from .owner import MotionOwner, OnDisconnect

__all__ = [
    "PROFILES",
    "ROLES",
    "Behaviour",
    "EmulatorProfile",
    "PortRules",
    "ProfileContext",
    "STATE_LINK",
    "int_option",
    "never_read",
    "profile_named",
    "register_profile",
    "unregister_profile",
]

#: ``Session.data`` key of a link that carries the state topics as well as motion (a serial link):
#: it gets what the state port's clients get, subscriptions included
STATE_LINK = "carries_state"

#: the roles a profile may serve, in the order they are bound
ROLES = ("motion", "state", "io")


class ReaderFactory(Protocol):
    """Makes a connection's frame cutter: ``reader(wire, lenient=...)`` (a FixedReads subclass)."""

    def __call__(self, wire: WireFormat, *, lenient: bool = False) -> FixedReads: ...


def never_read(wire: WireFormat, *, lenient: bool = False) -> FixedReads:
    """The reader of a port its controller never reads (RAPID's, KAREL's and VAL3's state servers
    only send): whatever a client sends there is dropped unanswered, a PING included."""
    return DiscardReads(wire)


def int_option(
    profile: str, options: Mapping[str, str], key: str, default: int, *, allowed: range | Sequence[int], what: str
) -> int:
    """A whole-number ``--profile-option KEY=VALUE`` (``default`` when not given); a value not in
    ``allowed`` (described by ``what``) is refused with a :class:`ValueError` that names it."""
    text = options.get(key, str(default))
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value not in allowed:
        raise ValueError(f"{profile} profile option {key}={text!r}: expected a whole number {what}")
    return value


@dataclass(frozen=True)
class PortRules:
    """What the emulated controller allows on one of its ports."""

    #: connections it takes at once (``None``: the emulator's ``max_connections`` setting)
    max_connections: int | None = None
    #: TOPICs of a type it does not handle go to the unknown-request handler too (MotoROS answers
    #: every message that is not a reply)
    answer_topics: bool = False
    #: its clients only listen (a state port): a full port never closes one for being silent
    listen_only: bool = False
    #: a connection beyond ``max_connections``: closed at once, or left waiting unserved until one
    #: ends (a controller whose server accepts its next client only when the last has gone: the
    #: newcomer's connect succeeds in the listen backlog and nothing answers it)
    excess: Literal["close", "wait"] = "close"
    #: how the controller cuts its input: ``None`` by the length prefix; else a
    #: :class:`~simple_message.fixed_reads.FixedReads` made per connection (``--lenient`` given)
    reader: ReaderFactory | None = None
    #: each frame written in these pieces, one write each (``None``: one write per frame)
    write_split: Callable[[bytes], Sequence[bytes]] | None = None


@dataclass(frozen=True)
class ProfileContext:
    """What a profile's builder gets from the emulator."""

    cell: RobotCell
    io_table: IoTable
    #: JOINT_FEEDBACK to every state client (the generic profile's ``--feedback``)
    feedback: bool = False
    #: the motion port's one client (listen with ``owner.when_gone``); ``None`` outside an emulator
    owner: MotionOwner | None = None
    #: ``--lenient``: the controller's harsh quirks (a stalled or misframed input, a server task that
    #: dies) are not reproduced; what would trigger them is dropped with a warning instead
    lenient: bool = False
    #: profile settings given on the command line (``--profile-option KEY=VALUE``), checked by the builder
    options: Mapping[str, str] = field(default_factory=dict)


class Behaviour(Protocol):
    """A profile's handlers and state topics, on the servers the emulator made for it."""

    def install(self, servers: Mapping[str, Server]) -> None:
        """Register handlers and hooks on the servers by role (only the profile's roles)."""

    def publish(self, server: Server, sessions: Iterable[Session]) -> None:
        """Send one round of state topics to ``sessions`` (through the state ``server``); called
        ``state_rate`` times a second (the profile's rate unless ``--state-rate`` says otherwise).
        A controller that sends some topics every Nth round counts the rounds itself."""

    # A behaviour may also have ``status() -> Status``: STATUS as its state topic reports it (the
    # web view shows that one; without it, the cell's own, :meth:`~.cell.RobotCell.status`); and
    # ``close() -> None``, called first when the emulator closes (before the shutdown stop): it ends
    # the tasks of its own (Fanuc's relay hand-over).


@dataclass(frozen=True)
class EmulatorProfile:
    """One controller family the emulator can play (see the module doc)."""

    dialect: Dialect
    build: Callable[[ProfileContext], Behaviour]
    #: the ports served, by role (``motion``, ``state``, ``io``), with the controller's rules
    ports: Mapping[str, PortRules] = field(
        default_factory=lambda: {"motion": PortRules(), "state": PortRules(listen_only=True)}
    )
    #: how far (rad) a trajectory's first point may be from where the robot is (``None``: the
    #: controller's default)
    start_tolerance: float | None = None
    #: given segments beyond the acceleration limit are run as given, not slowed down for
    #: (:attr:`.ControllerConfig.follow_given_acceleration`: MotoROS's way)
    follow_given_acceleration: bool = False
    #: the drives take position increments only (:attr:`.ControllerConfig.increment_feedforward`)
    increment_feedforward: bool = False
    description: str = ""
    #: state rounds per second of the controller played (``robot-server --state-rate`` overrides it)
    state_rate: float = 40.0
    #: what the robot does when the motion client goes away while it moves (``--on-disconnect``
    #: overrides it)
    on_disconnect: OnDisconnect = OnDisconnect.STOP
    #: the state topics of a round go out in one write per client; False: each message in its own
    #: write, at once, as every real controller sends them (MotoROS, RAPID, KAREL, VAL3 send each
    #: message with a call of its own)
    batch_topics: bool = False
    #: byte order, float size and reply style are the controller's own (the options that change
    #: them are refused unless they name the dialect's)
    fixed_wire: bool = False
    #: the profile settings ``--profile-option KEY=VALUE`` takes, with their help
    options: Mapping[str, str] = field(default_factory=dict)
    #: how its points are moved, when not by the interpolation policy (``--interpolation``): said in
    #: the ready line (Fanuc's and Stäubli's are the controller's own joint moves)
    motion: str | None = None

    def __post_init__(self) -> None:
        unknown = set(self.ports) - set(ROLES)
        if unknown:
            raise ValueError(f"unknown port roles {sorted(unknown)} (known: {', '.join(ROLES)})")
        if "motion" not in self.ports:
            raise ValueError("a profile serves at least the motion port")

    @property
    def name(self) -> str:
        return self.dialect.name

    def default_port(self, role: str) -> int | None:
        """The dialect's well-known port for ``role``, or None if this profile does not serve it."""
        if role not in self.ports:
            return None
        return self.dialect.ports.get(role)


#: Every profile the emulator can play, by name (the dialect's).
PROFILES: Registry[EmulatorProfile] = Registry("profile")


def register_profile(profile: EmulatorProfile, *, replace: bool = False) -> EmulatorProfile:
    """Make ``profile`` selectable by its name (``replace``: over one of the same name)."""
    return PROFILES.add(profile.name, profile, replace=replace)


def unregister_profile(name: str) -> None:
    """Forget the profile called ``name`` (tests that register their own)."""
    PROFILES.remove(name)


def profile_named(name: str) -> EmulatorProfile:
    """The registered profile called ``name``; :class:`ValueError` names the known ones."""
    return PROFILES.named(name)
