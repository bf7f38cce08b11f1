"""Typed, immutable simple_message messages and their exact wire encoding.

Each message type is a frozen dataclass whose fields are its body fields in wire order (names as in
simple-message.md §2.2 and §8.1, in snake_case), followed by the keyword-only header fields
``comm_type`` and ``reply_code``. The class knows its ``MSG_TYPE``; the length prefix is computed.
Besides the standard and MotoROS messages there are the project's own two extension messages,
CARTESIAN_LINE (65001) and TOOL_POSE (65002), in the range REP-I0004 leaves freely assignable
(``docs/protocol.md``, "Project extensions").

Decoding is exact: for every accepted frame, :func:`encode` of the decoded message gives back the
same bytes (data in fields that ``valid_fields`` marks invalid is kept, not zeroed; the one exception,
float32 signalling NaNs before CPython 3.14, is below). Shapes that real peers send and that do not
fit a type's layout are still decoded (§3):

* :class:`HeaderOnly`: a SERVICE_REPLY (or anything) with an empty body, as ABB and the C++
  ``MessageManager`` send for acks and FAILURE replies;
* :class:`DummyReply`: a SERVICE_REPLY carrying REP-I0006's alternative ``dummy_data: real[10]``;
* :class:`RawMessage`: a message type this package does not know; it re-encodes byte for byte.

A known type whose body fits none of its layouts raises :class:`~.errors.MalformedMessage`.

Which classes decode which ``msg_type`` is kept in a public registry (:func:`register`,
:func:`unregister`, :func:`lookup`, :func:`type_name`, :func:`type_for_name`). The standard and
MotoROS messages and the project's extensions are registered at the end of this module, each with
the converters that turn its enum fields into enum members; a vendor message set is one module of
classes plus :func:`register` calls (see ``CONTRIBUTING.md`` and ``tests/test_sm_registry.py``).
Encoding, decoding, the JSON form (:mod:`.jsonio`) and the ``simple-message`` command all consult
the registry.

One bit pattern does not survive before CPython 3.14: a float32 *signalling* NaN (exponent all ones,
bit 22 clear, nonzero payload, e.g. ``0x7FA00000``) comes back quieted, with bit 22 set and every
other bit kept (``0x7FE00000``), because :mod:`struct` converts a float32 to a Python float (a C
double) with a C cast, which quiets it; CPython 3.14's :mod:`struct` keeps it signalling on 64-bit
builds (gh-130317). Keeping it on older versions would take a NaN check of every message decoded and
encoded (about a fifth of the time decoding one takes), for a value that is never a valid joint
value, so it is not done. float64 reals (every NaN included) and float32 quiet NaNs with any sign and
payload, infinities, subnormals and -0.0 re-encode exactly.

Joint arrays are 10 wide on the wire (§1.4); constructors accept any shorter sequence (list, tuple,
numpy array) and pad it with zeros.
"""

from __future__ import annotations

import keyword
import re
import struct
import weakref
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, fields, is_dataclass
from enum import IntEnum, IntFlag
from types import MappingProxyType
from typing import Any, ClassVar, TypeAlias, cast

from .constants import (
    HEADER_SIZE,
    LENGTH_SIZE,
    MAX_JOINTS,
    MOTO_MAX_GROUPS,
    CommType,
    LineResult,
    MotoResult,
    MsgType,
    ReplyCode,
    RobotMode,
    TriState,
    ValidFields,
)
from .errors import LocalProtocolError, MalformedMessage, SimpleMessageError
from .wire import DEFAULT_FORMAT, WireFormat

__all__ = [
    "Message",
    "Ping",
    "GetVersion",
    "GetVersionReply",
    "JointPosition",
    "JointTrajPt",
    "TrajPoint",
    "JointTraj",
    "Status",
    "JointTrajPtFull",
    "JointFeedback",
    "MotoMotionCtrl",
    "MotoMotionReply",
    "ReadSingleIo",
    "ReadSingleIoReply",
    "WriteSingleIo",
    "WriteSingleIoReply",
    "ReadGroupIo",
    "ReadGroupIoReply",
    "WriteGroupIo",
    "WriteGroupIoReply",
    "IoCtrlReply",
    "ReadMRegister",
    "ReadMRegisterReply",
    "WriteMRegister",
    "WriteMRegisterReply",
    "ExGroup",
    "JointTrajPtFullEx",
    "JointFeedbackEx",
    "SelectTool",
    "GetDhParameters",
    "GetDhParametersReply",
    "DhLink",
    "CartesianLine",
    "CartesianLineReply",
    "ToolPose",
    "HeaderOnly",
    "DummyReply",
    "RawMessage",
    "Header",
    "encode",
    "decode",
    "read_header",
    "message_class",
    "MESSAGE_CLASSES",
    "ZEROS",
    "Converter",
    "MessageSpec",
    "RegistrationError",
    "register",
    "unregister",
    "lookup",
    "message_types",
    "type_name",
    "type_for_name",
    "scoped_registry",
]

Floats = tuple[float, ...]
#: Ten zero reals, the default of every joint array.
ZEROS: Floats = (0.0,) * MAX_JOINTS

_HEADER = "iiii"  # length prefix + msg_type + comm_type + reply_code, always int32
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


class RegistrationError(SimpleMessageError, ValueError):
    """A message registration is not well formed, or conflicts with one already made (its
    ``msg_type`` or one of its names is taken). Nothing was changed."""


#: What turns a decoded wire int into a richer value: an ``IntEnum`` or ``IntFlag`` class, or a
#: mapping from wire int to value. Ints that it does not map stay plain ints.
Converter: TypeAlias = type[IntEnum] | type[IntFlag] | Mapping[int, Any]

#: An ``IntFlag`` converter is expanded into a table of every combination of its bits; beyond this
#: many bits, give an explicit mapping instead.
_MAX_FLAG_BITS = 12


def _converter_table(converter: Converter) -> dict[int, Any]:
    """The lookup table (wire int -> value) of ``converter``; :class:`RegistrationError` if unusable.

    Tables are plain dicts so that decoding converts a value with one ``dict.get`` instead of the
    cost of ``Enum.__call__``.
    """
    if isinstance(converter, type):
        if issubclass(converter, IntFlag):
            mask = 0
            for member in converter:
                mask |= int(member)
            if mask < 0 or mask.bit_count() > _MAX_FLAG_BITS:
                raise RegistrationError(
                    f"{converter.__name__} has {mask.bit_count()} flag bits; give an explicit mapping instead"
                )
            table: dict[int, Any] = {}
            sub = mask
            while True:  # every subset of the defined bits, 0 included
                table[sub] = converter(sub)
                if sub == 0:
                    break
                sub = (sub - 1) & mask
            return dict(sorted(table.items()))
        if issubclass(converter, IntEnum):
            return {int(member): member for member in converter}
        raise RegistrationError(f"a converter must be an IntEnum or IntFlag class or a mapping, not {converter!r}")
    if isinstance(converter, Mapping):
        table = {}
        for key, value in converter.items():
            if isinstance(key, bool) or not isinstance(key, int):
                raise RegistrationError(f"converter keys must be wire ints, not {key!r}")
            table[int(key)] = value
        return table
    raise RegistrationError(f"a converter must be an IntEnum or IntFlag class or a mapping, not {converter!r}")


# Small caches that turn wire ints into enum members without the cost of Enum.__call__.
_COMM = {int(c): c for c in CommType}
_REPLY = {int(c): c for c in ReplyCode}
_SERVICE_REPLY = int(CommType.SERVICE_REPLY)
#: valid_fields of the EX groups (ExGroup is no message, so it converts this one field itself).
_VALID = _converter_table(ValidFields)


def _joints(value: Iterable[float], name: str) -> Floats:
    """Normalise a joint array: floats, padded with zeros to 10, at most 10 long."""
    items = tuple(float(v) for v in value)
    if len(items) > MAX_JOINTS:
        raise LocalProtocolError(f"{name} has {len(items)} values; the wire carries at most {MAX_JOINTS}")
    return items + ZEROS[len(items) :]


def _normalise_arrays(obj: object, names: Iterable[str]) -> None:
    """Normalise the joint-array fields ``names`` of a frozen dataclass in place (constructors only)."""
    for name in names:
        value = getattr(obj, name)
        if type(value) is not tuple or len(value) != MAX_JOINTS:
            object.__setattr__(obj, name, _joints(value, name))


def _body_format(layout: tuple[tuple[str, str], ...]) -> str:
    """The struct format of a body LAYOUT ("r" = one real, "r10" = ten)."""
    return "".join(f"{code[1:]}{code[0]}" if len(code) > 1 else code for _, code in layout)


# ---------------------------------------------------------------------------------------------
# Base class and the generic layout machinery
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Message:
    """Base of all messages: the two header fields that are not implied by the class."""

    comm_type: int = field(default=CommType.SERVICE_REQUEST, kw_only=True)
    reply_code: int = field(default=ReplyCode.INVALID, kw_only=True)

    #: The header ``msg_type`` of this class.
    MSG_TYPE: ClassVar[int] = MsgType.INVALID
    #: Body layout: (field name, struct code) in wire order; ``r`` is one real, ``r10`` ten.
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = ()
    #: Fields holding joint arrays, normalised by the constructor.
    ARRAYS: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        _normalise_arrays(self, self.ARRAYS)

    @property
    def msg_type(self) -> int:
        return self.MSG_TYPE

    @property
    def name(self) -> str:
        """The message type's name, e.g. ``JOINT_TRAJ_PT`` (``UNKNOWN`` for unknown types); see
        :func:`type_name`."""
        return _NAMES.get(self.msg_type, "UNKNOWN")

    def encode(self, wire: WireFormat = DEFAULT_FORMAT) -> bytes:
        """The whole frame: length prefix, header and body."""
        return encode(self, wire)

    def body_dict(self) -> dict[str, Any]:
        """The body fields as plain Python values (ints, floats, lists), for JSON and logging."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self) if f.name not in _HEADER_FIELDS}

    # -- hooks for messages whose layout is not a fixed struct ---------------------------------
    # The defaults describe an empty body (GET_VERSION and GET_DH_PARAMETERS requests); classes
    # with a LAYOUT never reach them, variable layouts override both.
    def _encode_body(self, wire: WireFormat) -> bytes:
        return b""

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        """Decode a variable layout; ``None`` if ``body`` fits no layout of this type."""
        return None if body else cls(comm_type=comm_type, reply_code=reply_code)

    def to_reply(self, reply_code: int = ReplyCode.SUCCESS) -> Message:
        """This message as a SERVICE_REPLY echoing the body (the C++ ``TypedMessage::toReply``)."""
        return _replace_header(self, CommType.SERVICE_REPLY, reply_code)


_HEADER_FIELDS = frozenset({"comm_type", "reply_code"})


def _replace_header(msg: Message, comm_type: int, reply_code: int) -> Message:
    obj = object.__new__(type(msg))
    for f in fields(msg):
        object.__setattr__(obj, f.name, getattr(msg, f.name))
    object.__setattr__(obj, "comm_type", comm_type)
    object.__setattr__(obj, "reply_code", reply_code)
    return obj


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if is_dataclass(value) and not isinstance(value, type):  # nested parts: TrajPoint, ExGroup, DhLink, ...
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value) if f.name not in _HEADER_FIELDS}
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        return int(value)
    return value


class _Codec:
    """A precompiled struct for one fixed-layout class in one wire format.

    The struct covers the whole frame (prefix, header, body), so a frame is packed or unpacked in a
    single call. Decoding is the protocol's hot path, so its functions are generated as
    straight-line code per class (as :mod:`dataclasses` generates ``__init__``; a generic per-field
    loop costs a third of the time):

    * ``unpack(frame)`` decodes one whole frame of exactly ``struct.size`` bytes;
    * ``unpack_run(buf, pos, end, comm_type, reply_code, append)`` decodes, straight from a stream
      (``bytes``, complete frames up to ``end``), the frame at ``pos``, whose header the caller
      read (its ``comm_type`` and ``reply_code``, and a length prefix equal to :attr:`length`), and
      every frame after it with the same 16 header bytes, passing each message to ``append``; it
      returns the position after the last. Messages of one type mostly come in such runs (a
      trajectory, a feedback topic), so the caller reads one header per run, and the run compares
      the next header's bytes instead of unpacking them.

    Neither runs the class's ``__init__``/``__post_init__`` (decoding never has). What
    ``Message.__post_init__`` checks, the layout guarantees: each joint array is a slice of exactly
    10 unpacked reals, so it is already the tuple of 10 floats that ``_normalise_arrays`` makes of
    an argument (and never more than 10); ints are ints of their field's wire range. The fields are
    set through the class's builder (:func:`_builder`) when it has one.
    """

    __slots__ = ("__weakref__", "body", "builder", "length", "plan", "struct", "unpack", "unpack_run")

    unpack: Callable[[bytes], Message]
    unpack_run: Callable[[bytes, int, int, int, int, Callable[[Message], object]], int]

    def __init__(self, cls: type[Message], wire: WireFormat) -> None:
        plan: list[tuple[str, int, int]] = []
        pos = 4
        for name, code in cls.LAYOUT:
            count = int(code[1:] or 1)
            plan.append((name, pos, pos + count if count > 1 else -1))
            pos += count
        self.struct = wire.struct(_HEADER + _body_format(cls.LAYOUT))
        #: the body alone (the 16 bytes of prefix and header skipped): values at plan index - 4
        self.body = wire.struct(f"{LENGTH_SIZE + HEADER_SIZE}x" + _body_format(cls.LAYOUT))
        self.length = self.struct.size - LENGTH_SIZE
        self.plan = tuple(plan)
        self.builder = _builder(cls)
        self.compile(cls)
        # (re)registering the class with other converters recompiles it (see _refresh_codecs)
        _LIVE_CODECS.setdefault(cls, weakref.WeakSet()).add(self)

    def compile(self, cls: type[Message]) -> None:
        """(Re)generate ``unpack`` and ``unpack_run`` for the class's current converters."""
        converters = _CLASS_CONVERTERS.get(cls, {})
        env: dict[str, Any] = {
            "_unpack": self.struct.unpack,
            "_unpack_body": self.body.unpack_from,
            "_new": object.__new__,
            "_set": object.__setattr__,
            "_cls": cls,
            "_builder": self.builder,
            "_COMM": _COMM,
            "_REPLY": _REPLY,
        }
        fast = self.builder is not None

        def build(comm: str, reply: str, offset: int, indent: str) -> list[str]:
            """Statements that make ``o`` from the unpacked values ``v`` (field k at k - offset)."""
            values = [("comm_type", comm), ("reply_code", reply)]
            for k, (name, start, stop) in enumerate(self.plan):
                value = f"v[{start - offset}]" if stop < 0 else f"v[{start - offset}:{stop - offset}]"
                if name in converters:
                    env[f"_conv{k}"] = dict(converters[name])  # a plain dict: .get is faster than a proxy's
                    value = f"_conv{k}.get({value}, {value})"
                values.append((name, value))
            lines = ["o = _builder()" if fast else "o = _new(_cls)"]
            for name, value in values:
                if fast and name.isidentifier() and not keyword.iskeyword(name):
                    lines.append(f"o.{name} = {value}")  # a specialised slot store on the builder
                else:
                    lines.append(f"_set(o, {name!r}, {value})")
            if fast:
                lines.append("o.__class__ = _cls")
            return [indent + line for line in lines]

        size = self.struct.size
        source = [
            "def unpack(frame):",
            "    v = _unpack(frame)",
            *build("_COMM.get(v[2], v[2])", "_REPLY.get(v[3], v[3])", 0, "    "),
            "    return o",
            "def unpack_run(buf, pos, end, comm_type, reply_code, append):",
            f"    head = buf[pos:pos + {LENGTH_SIZE + HEADER_SIZE}]",
            "    same = buf.startswith",
            "    comm_type = _COMM.get(comm_type, comm_type)",
            "    reply_code = _REPLY.get(reply_code, reply_code)",
            f"    last = end - {size}",
            "    while True:",
            "        v = _unpack_body(buf, pos)",
            *build("comm_type", "reply_code", 4, "        "),
            "        append(o)",
            f"        pos += {size}",
            "        if pos > last or not same(head, pos):",
            "            return pos",
        ]
        exec("\n".join(source), env)  # generated from the class's own LAYOUT only
        self.unpack = env["unpack"]
        self.unpack_run = env["unpack_run"]

    def pack(self, msg: Message) -> bytes:
        values: list[Any] = [self.length, msg.MSG_TYPE, msg.comm_type, msg.reply_code]
        for name, _start, stop in self.plan:
            if stop < 0:
                values.append(getattr(msg, name))
            else:
                values.extend(getattr(msg, name))
        try:
            return self.struct.pack(*values)
        except struct.error as exc:
            raise LocalProtocolError(f"cannot encode {type(msg).__name__}: {exc}") from None


def _builder(cls: type[Message]) -> type[Message] | None:
    """A subclass of ``cls`` that decoding builds instances with; ``None`` if ``cls`` cannot have one.

    A frozen dataclass's ``__setattr__`` raises, so its fields can only be set with
    ``object.__setattr__`` or the slot descriptors' ``__set__``: a C call through a wrapper per
    field, the largest cost of decoding. The builder gives back ``object``'s ``__setattr__`` and
    ``__delattr__`` (both: with either one overridden, every store goes through a Python-level
    lookup), so its fields are set with plain attribute stores, which the interpreter specialises
    to a direct slot write; the finished instance then becomes a ``cls`` by assigning its
    ``__class__``. That assignment is legal because the builder adds nothing to ``cls``'s layout
    (``__slots__ = ()``); it is checked here once on a probe. Decoded messages are thus exactly
    ``cls`` instances (``type(msg) is cls``). A class with its own metaclass or ``__new__``, an
    ``__init_subclass__`` (which creating the builder would run) or a ``__del__`` (which the
    probe's end would run) gets no builder: its fields are set with ``object.__setattr__``.
    """
    if type(cls) is not type or cls.__new__ is not object.__new__:
        return None
    if any("__init_subclass__" in vars(k) or "__del__" in vars(k) for k in cls.__mro__[:-1]):
        return None
    namespace = {
        "__slots__": (),
        "__init__": object.__init__,
        "__setattr__": object.__setattr__,
        "__delattr__": object.__delattr__,
        "__module__": cls.__module__,
        "__qualname__": f"_{cls.__qualname__}Builder",
        "__doc__": f"Builds decoded {cls.__name__} instances (an implementation detail of decoding).",
    }
    builder = type(f"_{cls.__name__}Builder", (cls,), namespace)
    try:
        probe = builder()
        probe.__class__ = cls
    except TypeError:
        return None
    return builder


def _codec(cls: type[Message], wire: WireFormat) -> _Codec:
    codec: _Codec | None = wire.codecs.get(cls)
    if codec is None:
        codec = wire.codecs[cls] = _Codec(cls, wire)
    return codec


class _FastTable(dict[int, "_Codec | None"]):
    """msg_type -> the codec of the class that decodes it (requests and topics, or SERVICE_REPLYs),
    ``None`` for a type without a fixed layout; filled on first lookup (``[]``). Only registered
    types are kept: a stream can carry any int32 as its msg_type."""

    __slots__ = ("replies", "wire")

    def __init__(self, wire: WireFormat, replies: bool) -> None:
        super().__init__()
        self.wire = wire
        self.replies = replies

    def __missing__(self, msg_type: int) -> _Codec | None:
        pair = MESSAGE_CLASSES.get(msg_type)
        if pair is None:
            return None
        cls = pair[1] if self.replies else pair[0]
        codec = _codec(cls, self.wire) if cls.LAYOUT else None
        self[msg_type] = codec
        return codec


class _FastTables:
    """What :meth:`.framing.FrameDecoder.feed_messages` decodes with in one wire format (an
    implementation detail of this package). ``requests`` and ``replies`` (requests and topics,
    SERVICE_REPLYs): see :class:`_FastTable`, look up with ``[]``, not ``.get``. ``small``: header-only
    frames (PING, acks, FAILURE replies) already decoded, by their 16 bytes; the same bytes decode to
    the same immutable message, so each is decoded once (the decoder bounds how many it keeps).
    All three are emptied whenever the registry or a converter changes."""

    __slots__ = ("replies", "requests", "small")

    def __init__(self, wire: WireFormat) -> None:
        self.requests = _FastTable(wire, False)
        self.replies = _FastTable(wire, True)
        self.small: dict[bytes, Message] = {}

    def clear(self) -> None:
        self.requests.clear()
        self.replies.clear()
        self.small.clear()


#: The fast tables per wire format (byte order, real size). They live as long as the module (a
#: FrameDecoder keeps them) and are emptied whenever the registry or a converter changes.
_FAST: dict[tuple[str, int], _FastTables] = {}


def _clear_fast() -> None:
    for tables in _FAST.values():
        tables.clear()


def fast_decoders(wire: WireFormat) -> _FastTables:
    """The :class:`_FastTables` of ``wire`` (the same object for every equal format, kept current
    as the registry changes), for :meth:`.framing.FrameDecoder.feed_messages`."""
    key = (wire.byte_order, wire.real_size)
    tables = _FAST.get(key)
    if tables is None:
        tables = _FAST[key] = _FastTables(wire)
    return tables


# ---------------------------------------------------------------------------------------------
# Standard messages (simple-message.md §2.2)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Ping(Message):
    """PING (1). The C++ library and MotoROS send an empty body (§0 item 2); REP-I0006 documents
    ``data: shared_int[10]``, which is accepted and kept (``data`` is then a 10-tuple of ints)."""

    data: tuple[int, ...] | None = None
    MSG_TYPE: ClassVar[int] = MsgType.PING

    def __post_init__(self) -> None:
        if self.data is not None:
            items = tuple(int(v) for v in self.data)
            if len(items) > MAX_JOINTS:
                raise LocalProtocolError(f"PING data has {len(items)} ints; at most {MAX_JOINTS}")
            object.__setattr__(self, "data", items + (0,) * (MAX_JOINTS - len(items)))

    def body_dict(self) -> dict[str, Any]:
        return {} if self.data is None else {"data": list(self.data)}

    def _encode_body(self, wire: WireFormat) -> bytes:
        if self.data is None:
            return b""
        return wire.struct(f"{MAX_JOINTS}i").pack(*self.data)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        if not body:
            return cls(comm_type=comm_type, reply_code=reply_code)
        s = wire.struct(f"{MAX_JOINTS}i")
        if len(body) != s.size:
            return None
        return cls(s.unpack(body), comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class GetVersion(Message):
    """GET_VERSION (2) request: empty body (REP-I0006; no known peer implements it, §2.1)."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_VERSION


@dataclass(frozen=True, slots=True)
class GetVersionReply(Message):
    """GET_VERSION (2) reply: ``major, minor, patch``."""

    major: int = 0
    minor: int = 0
    patch: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.GET_VERSION
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("major", "i"), ("minor", "i"), ("patch", "i"))


@dataclass(frozen=True, slots=True)
class JointPosition(Message):
    """JOINT_POSITION (10): the state message of the generic nodes, ABB and Fanuc; also Fanuc's
    ack of a JOINT_TRAJ_PT (a SERVICE_REPLY echoing the sequence, §3)."""

    sequence: int = 0
    joint_data: Floats = ZEROS
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_POSITION
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("sequence", "i"), ("joint_data", "r10"))
    ARRAYS: ClassVar[tuple[str, ...]] = ("joint_data",)


@dataclass(frozen=True, slots=True)
class JointTrajPt(Message):
    """JOINT_TRAJ_PT (11): one point, a velocity ratio in (0, 1] and a segment duration (§4.3)."""

    sequence: int = 0
    joint_data: Floats = ZEROS
    velocity: float = 0.0
    duration: float = 0.0
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ_PT
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("sequence", "i"),
        ("joint_data", "r10"),
        ("velocity", "r"),
        ("duration", "r"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("joint_data",)


@dataclass(frozen=True, slots=True)
class TrajPoint:
    """One point inside a JOINT_TRAJ (12) message: the JOINT_TRAJ_PT body without a header."""

    sequence: int = 0
    joint_data: Floats = ZEROS
    velocity: float = 0.0
    duration: float = 0.0

    def __post_init__(self) -> None:
        _normalise_arrays(self, ("joint_data",))


#: A JOINT_TRAJ point is laid out as a JOINT_TRAJ_PT body.
_TRAJ_POINT = _body_format(JointTrajPt.LAYOUT)
#: JOINT_TRAJ holds at most this many points (``JointTraj::MAX_NUM_POINTS``).
JOINT_TRAJ_MAX_POINTS = 200


@dataclass(frozen=True, slots=True)
class JointTraj(Message):
    """JOINT_TRAJ (12), deprecated and unused by any peer, in the C++ library's layout: the points
    (52 bytes each in float32), then the point count as the *last* int32 (§2.2). At most 200."""

    points: tuple[TrajPoint, ...] = ()
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ

    def __post_init__(self) -> None:
        points = tuple(
            p if isinstance(p, TrajPoint) else TrajPoint(**p) if isinstance(p, Mapping) else TrajPoint(*p)
            for p in self.points
        )
        if len(points) > JOINT_TRAJ_MAX_POINTS:
            raise LocalProtocolError(f"JOINT_TRAJ holds at most {JOINT_TRAJ_MAX_POINTS} points, not {len(points)}")
        object.__setattr__(self, "points", points)

    def _encode_body(self, wire: WireFormat) -> bytes:
        s = wire.struct(_TRAJ_POINT)
        parts = [s.pack(p.sequence, *p.joint_data, p.velocity, p.duration) for p in self.points]
        parts.append(wire.struct("i").pack(len(self.points)))
        return b"".join(parts)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        s = wire.struct(_TRAJ_POINT)
        if len(body) < 4 or (len(body) - 4) % s.size:
            return None
        (count,) = wire.struct("i").unpack_from(body, len(body) - 4)
        if count != (len(body) - 4) // s.size or count > JOINT_TRAJ_MAX_POINTS:
            return None
        points = []
        for k in range(count):
            v = s.unpack_from(body, k * s.size)
            points.append(TrajPoint(v[0], v[1:11], v[11], v[12]))
        return cls(tuple(points), comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class Status(Message):
    """STATUS (13): the controller's tristates, alarm code and mode (§5)."""

    drives_powered: int = TriState.UNKNOWN
    e_stopped: int = TriState.UNKNOWN
    error_code: int = 0
    in_error: int = TriState.UNKNOWN
    in_motion: int = TriState.UNKNOWN
    mode: int = RobotMode.UNKNOWN
    motion_possible: int = TriState.UNKNOWN
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.STATUS
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("drives_powered", "i"),
        ("e_stopped", "i"),
        ("error_code", "i"),
        ("in_error", "i"),
        ("in_motion", "i"),
        ("mode", "i"),
        ("motion_possible", "i"),
    )


@dataclass(frozen=True, slots=True)
class JointTrajPtFull(Message):
    """JOINT_TRAJ_PT_FULL (14): time from start plus positions, velocities and accelerations, of
    which ``valid_fields`` says which are meaningful (§2.2)."""

    robot_id: int = 0
    sequence: int = 0
    valid_fields: int = ValidFields.NONE
    time: float = 0.0
    positions: Floats = ZEROS
    velocities: Floats = ZEROS
    accelerations: Floats = ZEROS
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ_PT_FULL
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("sequence", "i"),
        ("valid_fields", "i"),
        ("time", "r"),
        ("positions", "r10"),
        ("velocities", "r10"),
        ("accelerations", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("positions", "velocities", "accelerations")


@dataclass(frozen=True, slots=True)
class JointFeedback(Message):
    """JOINT_FEEDBACK (15): like JOINT_TRAJ_PT_FULL without a sequence (§2.2)."""

    robot_id: int = 0
    valid_fields: int = ValidFields.NONE
    time: float = 0.0
    positions: Floats = ZEROS
    velocities: Floats = ZEROS
    accelerations: Floats = ZEROS
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_FEEDBACK
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("valid_fields", "i"),
        ("time", "r"),
        ("positions", "r10"),
        ("velocities", "r10"),
        ("accelerations", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("positions", "velocities", "accelerations")


# ---------------------------------------------------------------------------------------------
# Yaskawa MotoROS extensions (simple-message.md §8.1)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MotoMotionCtrl(Message):
    """MOTO_MOTION_CTRL (2001): a motion command (:class:`~.constants.MotoCommand`)."""

    group_no: int = 0
    sequence: int = 0
    command: int = 0
    data: Floats = ZEROS
    MSG_TYPE: ClassVar[int] = MsgType.MOTO_MOTION_CTRL
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("group_no", "i"),
        ("sequence", "i"),
        ("command", "i"),
        ("data", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("data",)


@dataclass(frozen=True, slots=True)
class MotoMotionReply(Message):
    """MOTO_MOTION_REPLY (2002): MotoROS's answer to every motion-port message. The header
    reply_code is always SUCCESS; the outcome is ``result`` (0 = success) and ``subcode`` (§0 item
    3). The IO port's error reply uses this type with ``result``/``subcode`` at offsets 0 and 4 (the
    IoCtrlReply layout); it decodes here with those values in ``group_no`` and ``sequence``."""

    group_no: int = 0
    sequence: int = 0
    command: int = 0
    result: int = MotoResult.SUCCESS
    subcode: int = 0
    data: Floats = ZEROS
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.MOTO_MOTION_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("group_no", "i"),
        ("sequence", "i"),
        ("command", "i"),
        ("result", "i"),
        ("subcode", "i"),
        ("data", "r10"),
    )
    ARRAYS: ClassVar[tuple[str, ...]] = ("data",)


@dataclass(frozen=True, slots=True)
class ReadSingleIo(Message):
    """READ_SINGLE_IO (2003): read one IO bit at ``address`` (uint32)."""

    address: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.READ_SINGLE_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"),)


@dataclass(frozen=True, slots=True)
class ReadSingleIoReply(Message):
    """READ_SINGLE_IO_REPLY (2004): ``value`` (uint32) and ``result_code`` (:class:`~.constants.IoResult`)."""

    value: int = 0
    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.READ_SINGLE_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "I"), ("result_code", "i"))


@dataclass(frozen=True, slots=True)
class WriteSingleIo(Message):
    """WRITE_SINGLE_IO (2005): write ``value`` to the IO bit at ``address``."""

    address: int = 0
    value: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_SINGLE_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"), ("value", "I"))


@dataclass(frozen=True, slots=True)
class WriteSingleIoReply(Message):
    """WRITE_SINGLE_IO_REPLY (2006): ``result_code``."""

    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_SINGLE_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result_code", "i"),)


@dataclass(frozen=True, slots=True)
class ReadGroupIo(Message):
    """READ_GROUP_IO (2007): read an 8-bit IO group (e.g. address 1001 = OG#1)."""

    address: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.READ_GROUP_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"),)


@dataclass(frozen=True, slots=True)
class ReadGroupIoReply(Message):
    """READ_GROUP_IO_REPLY (2008): ``value`` and ``result_code``."""

    value: int = 0
    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.READ_GROUP_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "I"), ("result_code", "i"))


@dataclass(frozen=True, slots=True)
class WriteGroupIo(Message):
    """WRITE_GROUP_IO (2009): write ``value`` to the IO group at ``address``."""

    address: int = 0
    value: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_GROUP_IO
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("address", "I"), ("value", "I"))


@dataclass(frozen=True, slots=True)
class WriteGroupIoReply(Message):
    """WRITE_GROUP_IO_REPLY (2010): ``result_code``."""

    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_GROUP_IO_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result_code", "i"),)


@dataclass(frozen=True, slots=True)
class IoCtrlReply(Message):
    """MOTO_IOCTRL_REPLY (2011): ``result`` and ``subcode``. Defined by MotoROS, which in fact sends
    its IO error replies as type 2002 (see :class:`MotoMotionReply`)."""

    result: int = 0
    subcode: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.MOTO_IOCTRL_REPLY
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result", "i"), ("subcode", "i"))


@dataclass(frozen=True, slots=True)
class ReadMRegister(Message):
    """READ_MREGISTER (2012) request: ``register_number`` (M000-M999)."""

    register_number: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.READ_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("register_number", "I"),)


@dataclass(frozen=True, slots=True)
class ReadMRegisterReply(Message):
    """READ_MREGISTER (2012) SERVICE_REPLY: ``value`` and ``result_code``."""

    value: int = 0
    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.READ_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("value", "I"), ("result_code", "i"))


@dataclass(frozen=True, slots=True)
class WriteMRegister(Message):
    """WRITE_MREGISTER (2013) request: ``register_number`` (M000-M559) and ``value``."""

    register_number: int = 0
    value: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("register_number", "I"), ("value", "I"))


@dataclass(frozen=True, slots=True)
class WriteMRegisterReply(Message):
    """WRITE_MREGISTER (2013) SERVICE_REPLY: ``result_code``."""

    result_code: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.WRITE_MREGISTER
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("result_code", "i"),)


@dataclass(frozen=True, slots=True)
class ExGroup:
    """One motion group inside JOINT_TRAJ_PT_FULL_EX (2016) or JOINT_FEEDBACK_EX (2017): the
    JOINT_FEEDBACK body layout, 132 bytes in float32."""

    group_no: int = 0
    valid_fields: int = ValidFields.NONE
    time: float = 0.0
    positions: Floats = ZEROS
    velocities: Floats = ZEROS
    accelerations: Floats = ZEROS

    def __post_init__(self) -> None:
        _normalise_arrays(self, ("positions", "velocities", "accelerations"))

    def pack(self, wire: WireFormat) -> bytes:
        return wire.struct(_EX_GROUP).pack(
            self.group_no, self.valid_fields, self.time, *self.positions, *self.velocities, *self.accelerations
        )

    @classmethod
    def unpack_from(cls, body: bytes, offset: int, wire: WireFormat) -> ExGroup:
        v = wire.struct(_EX_GROUP).unpack_from(body, offset)
        return cls(v[0], _VALID.get(v[1], v[1]), v[2], v[3:13], v[13:23], v[23:33])


#: An EX group is laid out as a JOINT_FEEDBACK body (group_no in robot_id's place).
_EX_GROUP = _body_format(JointFeedback.LAYOUT)


def _ex_groups(groups: Iterable[ExGroup | dict[str, Any]]) -> tuple[ExGroup, ...]:
    return tuple(g if isinstance(g, ExGroup) else ExGroup(**g) for g in groups)


#: The default ``number_of_valid_groups`` of the EX messages: "not given", which the constructor
#: replaces with ``len(groups)``. It is ``None``, not an int, so that every int (-1 included) is a
#: count as given or decoded and re-encodes as itself; typed ``int`` because no instance keeps it.
_COUNT_OF_GROUPS = cast(int, None)


@dataclass(frozen=True, slots=True)
class JointTrajPtFullEx(Message):
    """JOINT_TRAJ_PT_FULL_EX (2016): one point for up to 4 motion groups, no per-group sequence.

    MotoROS accepts the short form (``8 + n x 132`` bytes, ``len(groups) == number_of_valid_groups``)
    and the full form (always 4 groups, 536 bytes). ``groups`` holds what is on the wire, so both
    forms re-encode exactly; ``number_of_valid_groups`` defaults to ``len(groups)`` when omitted, and
    any int given or decoded (-1 and other counts MotoROS refuses included) is kept as it is.
    """

    number_of_valid_groups: int = _COUNT_OF_GROUPS
    sequence: int = 0
    groups: tuple[ExGroup, ...] = ()
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_TRAJ_PT_FULL_EX

    def __post_init__(self) -> None:
        groups = _ex_groups(self.groups)
        if len(groups) > MOTO_MAX_GROUPS:
            raise LocalProtocolError(f"at most {MOTO_MAX_GROUPS} groups, not {len(groups)}")
        object.__setattr__(self, "groups", groups)
        if self.number_of_valid_groups is _COUNT_OF_GROUPS:
            object.__setattr__(self, "number_of_valid_groups", len(groups))

    @property
    def valid_groups(self) -> tuple[ExGroup, ...]:
        return self.groups[: max(0, self.number_of_valid_groups)]

    def _encode_body(self, wire: WireFormat) -> bytes:
        head = wire.struct("ii").pack(self.number_of_valid_groups, self.sequence)
        return head + b"".join(g.pack(wire) for g in self.groups)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        size = wire.struct(_EX_GROUP).size
        if len(body) < 8 or (len(body) - 8) % size:
            return None
        count = (len(body) - 8) // size
        n, seq = wire.struct("ii").unpack_from(body, 0)
        if count > MOTO_MAX_GROUPS or count not in (n, MOTO_MAX_GROUPS):
            return None
        groups = tuple(ExGroup.unpack_from(body, 8 + k * size, wire) for k in range(count))
        return cls(n, seq, groups, comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class JointFeedbackEx(Message):
    """JOINT_FEEDBACK_EX (2017): ``number_of_valid_groups`` then always 4 JOINT_FEEDBACK bodies
    (532 bytes in float32). Fewer groups given to the constructor are padded with zero groups;
    ``number_of_valid_groups`` defaults to the number of groups given (before padding) when omitted,
    and any int given or decoded (-1 included) is kept as it is."""

    number_of_valid_groups: int = _COUNT_OF_GROUPS
    groups: tuple[ExGroup, ...] = ()
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.JOINT_FEEDBACK_EX

    def __post_init__(self) -> None:
        groups = _ex_groups(self.groups)
        if len(groups) > MOTO_MAX_GROUPS:
            raise LocalProtocolError(f"at most {MOTO_MAX_GROUPS} groups, not {len(groups)}")
        if self.number_of_valid_groups is _COUNT_OF_GROUPS:
            object.__setattr__(self, "number_of_valid_groups", len(groups))
        object.__setattr__(self, "groups", groups + (ExGroup(),) * (MOTO_MAX_GROUPS - len(groups)))

    @property
    def valid_groups(self) -> tuple[ExGroup, ...]:
        return self.groups[: max(0, self.number_of_valid_groups)]

    def _encode_body(self, wire: WireFormat) -> bytes:
        return wire.struct("i").pack(self.number_of_valid_groups) + b"".join(g.pack(wire) for g in self.groups)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        size = wire.struct(_EX_GROUP).size
        if len(body) != 4 + MOTO_MAX_GROUPS * size:
            return None
        (n,) = wire.struct("i").unpack_from(body, 0)
        groups = tuple(ExGroup.unpack_from(body, 4 + k * size, wire) for k in range(MOTO_MAX_GROUPS))
        return cls(n, groups, comm_type=comm_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class SelectTool(Message):
    """SELECT_TOOL (2018): ``group_no``, ``tool`` (0..63), ``sequence``."""

    group_no: int = 0
    tool: int = 0
    sequence: int = 0
    MSG_TYPE: ClassVar[int] = MsgType.SELECT_TOOL
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("group_no", "i"), ("tool", "i"), ("sequence", "i"))


@dataclass(frozen=True, slots=True)
class GetDhParameters(Message):
    """GET_DH_PARAMETERS (2020) request: empty body."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_DH_PARAMETERS


@dataclass(frozen=True, slots=True)
class DhLink:
    """One axis of a GET_DH_PARAMETERS reply, in MotoPlus order."""

    theta: float = 0.0
    d: float = 0.0
    a: float = 0.0
    alpha: float = 0.0


#: Axes per group in MotoPlus's DH_PARAMETERS (``MAX_PULSE_AXES``). The SDK header is not public, but
#: MotoROS always sends 4 groups of 8 (a 512-byte body with float32) and MotoROS clients (the Python
#: ``moto`` package) parse exactly that, so a reply always carries 8 axes per group, unused ones 0.
#: Decoding still accepts fewer axes per group (derived from the body size) and pads them.
DH_AXES = 8


@dataclass(frozen=True, slots=True)
class GetDhParametersReply(Message):
    """GET_DH_PARAMETERS (2020) reply: 4 groups x 8 axes x (theta, d, a, alpha) reals (missing groups
    and axes are zero; a group of more than ``axes`` axes is an error). MotoROS sends 8 axes per
    group (``MAX_PULSE_AXES``, unverified); a reply with fewer per group decodes with ``axes`` set
    to their number, so it re-encodes to the same bytes."""

    groups: tuple[tuple[DhLink, ...], ...] = ()
    #: axes per group on the wire (1..8)
    axes: int = field(default=DH_AXES, kw_only=True)
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.GET_DH_PARAMETERS

    def __post_init__(self) -> None:
        groups = tuple(
            tuple(
                link if isinstance(link, DhLink) else DhLink(**link) if isinstance(link, dict) else DhLink(*link)
                for link in g
            )
            for g in self.groups
        )
        if len(groups) > MOTO_MAX_GROUPS:
            raise LocalProtocolError(f"at most {MOTO_MAX_GROUPS} groups, not {len(groups)}")
        axes = self.axes
        if not 1 <= axes <= DH_AXES:
            raise LocalProtocolError(f"a GET_DH_PARAMETERS reply has 1 to {DH_AXES} axes per group, not {axes}")
        if any(len(g) > axes for g in groups):
            raise LocalProtocolError(f"at most {axes} axes per group, not {max(len(g) for g in groups)}")
        padded = tuple(g + (DhLink(),) * (axes - len(g)) for g in groups)
        padded += ((DhLink(),) * axes,) * (MOTO_MAX_GROUPS - len(padded))
        object.__setattr__(self, "groups", padded)

    def _encode_body(self, wire: WireFormat) -> bytes:
        s = wire.struct("rrrr")
        return b"".join(s.pack(k.theta, k.d, k.a, k.alpha) for g in self.groups for k in g)

    @classmethod
    def _decode_body(cls, body: bytes, wire: WireFormat, comm_type: int, reply_code: int) -> Message | None:
        s = wire.struct("rrrr")
        if not body or len(body) % (MOTO_MAX_GROUPS * s.size) or len(body) > MOTO_MAX_GROUPS * DH_AXES * s.size:
            return None
        axes = len(body) // (MOTO_MAX_GROUPS * s.size)
        groups = tuple(
            tuple(DhLink(*s.unpack_from(body, (g * axes + k) * s.size)) for k in range(axes))
            for g in range(MOTO_MAX_GROUPS)
        )
        return cls(groups, axes=axes, comm_type=comm_type, reply_code=reply_code)


# ---------------------------------------------------------------------------------------------
# Project extensions, in the freely assignable range 65001-65535 of REP-I0004 (docs/protocol.md)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CartesianLine(Message):
    """CARTESIAN_LINE (65001) request: move the TCP of ``robot_id`` in a straight line to a pose.

    The target is ``x, y, z`` (m, in the cell frame) and the orientation ``qx, qy, qz, qw`` (a unit
    quaternion, Hamilton convention, in the x y z w order of ROS ``geometry_msgs``), reached at the
    TCP linear speed ``speed`` (m/s). ``blend_radius`` (m) lets the TCP leave this line that close
    to its end for the next one; 0 stops exactly at the end. ``sequence`` 0 starts a new series of
    lines, 1, 2, ... continue it, -4 (``SpecialSeq.STOP_TRAJECTORY``) stops, as for JOINT_TRAJ_PT.
    44 bytes in float32, 80 in float64. A TOPIC decodes with this class too; the SERVICE_REPLY is a
    :class:`CartesianLineReply`. Nothing is checked here (NaN included); the controller checks.
    """

    robot_id: int = 0
    sequence: int = 0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    qx: float = 0.0
    qy: float = 0.0
    qz: float = 0.0
    qw: float = 1.0
    speed: float = 0.0
    blend_radius: float = 0.0
    MSG_TYPE: ClassVar[int] = MsgType.CARTESIAN_LINE
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("sequence", "i"),
        ("x", "r"),
        ("y", "r"),
        ("z", "r"),
        ("qx", "r"),
        ("qy", "r"),
        ("qz", "r"),
        ("qw", "r"),
        ("speed", "r"),
        ("blend_radius", "r"),
    )


@dataclass(frozen=True, slots=True)
class CartesianLineReply(Message):
    """CARTESIAN_LINE (65001) SERVICE_REPLY: the request's ``robot_id`` and ``sequence`` and the
    outcome ``result`` (:class:`~.constants.LineResult`, 0 = accepted); 12 bytes. The header
    reply_code is SUCCESS when the line was accepted, FAILURE otherwise."""

    robot_id: int = 0
    sequence: int = 0
    result: int = LineResult.ACCEPTED
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.CARTESIAN_LINE
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("robot_id", "i"), ("sequence", "i"), ("result", "i"))


@dataclass(frozen=True, slots=True)
class ToolPose(Message):
    """TOOL_POSE (65002) topic: the actual TCP pose of ``robot_id`` at controller time ``time`` (s).

    ``tool`` is the active tool number (0 = the model's own tool); ``x, y, z`` (m) and ``qx, qy,
    qz, qw`` (unit quaternion, as in :class:`CartesianLine`) are the TCP pose in the cell frame and
    ``speed`` the TCP's actual linear speed (m/s). 44 bytes in float32, 80 in float64. Sent on the
    state port only to clients that asked for it by sending a TOOL_POSE (docs/protocol.md).
    """

    robot_id: int = 0
    tool: int = 0
    time: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    qx: float = 0.0
    qy: float = 0.0
    qz: float = 0.0
    qw: float = 1.0
    speed: float = 0.0
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = MsgType.TOOL_POSE
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (
        ("robot_id", "i"),
        ("tool", "i"),
        ("time", "r"),
        ("x", "r"),
        ("y", "r"),
        ("z", "r"),
        ("qx", "r"),
        ("qy", "r"),
        ("qz", "r"),
        ("qw", "r"),
        ("speed", "r"),
    )


# ---------------------------------------------------------------------------------------------
# Shapes that do not follow a type's own layout
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class HeaderOnly(Message):
    """Any message type with an empty body: ABB's JOINT_TRAJ_PT ack (11/3/1), the C++
    ``MessageManager``'s FAILURE reply to an unknown request (§3), MotoROS's PING reply."""

    type_id: int = 0
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)

    @property
    def msg_type(self) -> int:
        return self.type_id

    def body_dict(self) -> dict[str, Any]:
        return {}

    @classmethod
    def reply_to(cls, request: Message, reply_code: int = ReplyCode.SUCCESS) -> HeaderOnly:
        return cls(request.msg_type, reply_code=reply_code)


@dataclass(frozen=True, slots=True)
class DummyReply(Message):
    """A SERVICE_REPLY carrying REP-I0006's alternative ``dummy_data: real[10]`` body (§3)."""

    type_id: int = 0
    data: Floats = ZEROS
    comm_type: int = field(default=CommType.SERVICE_REPLY, kw_only=True)
    reply_code: int = field(default=ReplyCode.SUCCESS, kw_only=True)
    ARRAYS: ClassVar[tuple[str, ...]] = ("data",)

    @property
    def msg_type(self) -> int:
        return self.type_id

    def _encode_body(self, wire: WireFormat) -> bytes:
        return wire.struct("10r").pack(*self.data)

    def body_dict(self) -> dict[str, Any]:
        return {"dummy_data": list(self.data)}


@dataclass(frozen=True, slots=True)
class RawMessage(Message):
    """A message type this package does not know. Re-encodes byte for byte."""

    type_id: int = 0
    body: bytes = b""

    @property
    def msg_type(self) -> int:
        return self.type_id

    def _encode_body(self, wire: WireFormat) -> bytes:
        return self.body

    def body_dict(self) -> dict[str, Any]:
        return {"raw": self.body.hex()}


# ---------------------------------------------------------------------------------------------
# The message registry
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MessageSpec:
    """One registered message type: its number, its name and the classes that decode it."""

    #: The header ``msg_type``.
    msg_type: int
    #: Its name, as in :attr:`Message.name` and the ``"name"`` of the JSON form.
    name: str
    #: The class of requests and topics (any ``comm_type`` but SERVICE_REPLY).
    request: type[Message]
    #: The class of SERVICE_REPLYs (the request class if the type has no separate reply layout).
    reply: type[Message]
    #: Other names :func:`type_for_name` accepts for it.
    aliases: tuple[str, ...] = ()
    #: Field name -> table (wire int -> value) applied when decoding that field (read-only).
    converters: Mapping[str, Mapping[int, Any]] = field(default_factory=dict)

    @property
    def classes(self) -> tuple[type[Message], ...]:
        """The request class, then the reply class if it is another one."""
        return (self.request,) if self.reply is self.request else (self.request, self.reply)

    def message_class(self, comm_type: int) -> type[Message]:
        """The class that decodes this type with ``comm_type``."""
        return self.reply if comm_type == CommType.SERVICE_REPLY else self.request


#: Message class per type for requests and topics (index 0) and for SERVICE_REPLYs (index 1).
#: Kept by :func:`register` and :func:`unregister` (the decoder's lookup table); do not change it
#: directly.
MESSAGE_CLASSES: dict[int, tuple[type[Message], type[Message]]] = {}
_REGISTRY: dict[int, MessageSpec] = {}
#: Name per msg_type: the registered name, else the canonical MsgType name (READ_INPUT, INVALID, ...).
_NAMES: dict[int, str] = {int(member): member.name for member in MsgType}
#: Registered names and aliases -> msg_type (MsgType's own names are looked up after these).
_BY_NAME: dict[str, int] = {}
#: Converters per fixed-layout class, read when a codec compiles its ``unpack``.
_CLASS_CONVERTERS: dict[type[Message], dict[str, Mapping[int, Any]]] = {}
#: Every compiled codec per class, so that a change of converters recompiles them.
_LIVE_CODECS: dict[type[Message], weakref.WeakSet[_Codec]] = {}

_NAME_RE = re.compile(r"[A-Z][A-Z0-9_]*")
#: Classes that stand for shapes of any type; they are never registered.
_SHAPES: tuple[type[Message], ...] = ()  # filled below, once the classes exist


def _default_name(cls: type[Message]) -> str:
    """``MsgType``'s name for the type, else the class name in upper snake case (``AcmeGrip`` ->
    ``ACME_GRIP``)."""
    if cls.MSG_TYPE in MsgType._value2member_map_:
        return MsgType(cls.MSG_TYPE).name
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", "_", cls.__name__).upper()


def _check_class(cls: object, role: str) -> type[Message]:
    if not (isinstance(cls, type) and issubclass(cls, Message)) or cls is Message:
        raise RegistrationError(f"the {role} class must be a subclass of Message, not {cls!r}")
    if cls in _SHAPES:
        raise RegistrationError(f"{cls.__name__} stands for a shape of any type and cannot be registered")
    if "__dataclass_fields__" not in vars(cls):  # its own fields, not only inherited ones
        raise RegistrationError(f"{cls.__name__} must be decorated with @dataclass (like every Message)")
    msg_type = cls.MSG_TYPE
    if isinstance(msg_type, bool) or not isinstance(msg_type, int):
        raise RegistrationError(f"{cls.__name__}.MSG_TYPE must be an int, not {msg_type!r}")
    if msg_type == MsgType.INVALID or not _INT32_MIN <= msg_type <= _INT32_MAX:
        raise RegistrationError(f"{cls.__name__}.MSG_TYPE must be a nonzero int32, not {msg_type}")
    return cls


def _check_name(name: object, cls: type[Message]) -> str:
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise RegistrationError(f"the name of {cls.__name__} must be upper case letters, digits and '_', not {name!r}")
    return name


def _spec(
    request: type[Message],
    reply: type[Message] | None,
    name: str | None,
    aliases: Iterable[str],
    converters: Mapping[str, Converter] | None,
) -> MessageSpec:
    """A checked :class:`MessageSpec` (nothing registered yet)."""
    request = _check_class(request, "request")
    reply = request if reply is None else _check_class(reply, "reply")
    msg_type = int(request.MSG_TYPE)
    if msg_type != reply.MSG_TYPE:
        raise RegistrationError(
            f"{reply.__name__}.MSG_TYPE is {reply.MSG_TYPE}, but {request.__name__}.MSG_TYPE is {msg_type}"
        )
    name = _check_name(_default_name(request) if name is None else name, request)
    names = (name, *(_check_name(a, request) for a in aliases))
    if len(set(names)) != len(names):
        raise RegistrationError(f"the names of {request.__name__} repeat: {list(names)}")
    layouts = {cls: dict(cls.LAYOUT) for cls in (request, reply)}
    tables: dict[str, Mapping[int, Any]] = {}
    for field_name, converter in (converters or {}).items():
        codes = [layout[field_name] for layout in layouts.values() if field_name in layout]
        if not codes:
            raise RegistrationError(
                f"converter for {field_name!r}: no LAYOUT field of that name in {request.__name__}"
                + ("" if reply is request else f" or {reply.__name__}")
                + " (converters apply to fixed-layout int fields)"
            )
        if any(code not in ("i", "I") for code in codes):
            raise RegistrationError(f"converter for {field_name!r}: the field is not an int (i or I) field")
        tables[field_name] = MappingProxyType(_converter_table(converter))
    return MessageSpec(msg_type, name, request, reply, names[1:], MappingProxyType(tables))


def _same(a: MessageSpec, b: MessageSpec) -> bool:
    """Whether two registrations are the same (converter tables compared by content)."""

    def key(spec: MessageSpec) -> tuple[Any, ...]:
        tables = {f: dict(t) for f, t in spec.converters.items()}
        return (spec.msg_type, spec.name, spec.request, spec.reply, spec.aliases, tables)

    return key(a) == key(b)


def _install(spec: MessageSpec) -> None:
    _clear_fast()
    _REGISTRY[spec.msg_type] = spec
    MESSAGE_CLASSES[spec.msg_type] = (spec.request, spec.reply)
    _NAMES[spec.msg_type] = spec.name
    for name in (spec.name, *spec.aliases):
        _BY_NAME[name] = spec.msg_type
    for cls in spec.classes:
        own = {f for f, _ in cls.LAYOUT}
        tables = {f: t for f, t in spec.converters.items() if f in own}
        if tables:
            _CLASS_CONVERTERS[cls] = tables


def _remove(spec: MessageSpec) -> None:
    _clear_fast()
    del _REGISTRY[spec.msg_type]
    del MESSAGE_CLASSES[spec.msg_type]
    if spec.msg_type in MsgType._value2member_map_:
        _NAMES[spec.msg_type] = MsgType(spec.msg_type).name
    else:
        del _NAMES[spec.msg_type]
    for name in (spec.name, *spec.aliases):
        del _BY_NAME[name]
    for cls in spec.classes:
        _CLASS_CONVERTERS.pop(cls, None)


def _refresh_codecs(classes: Iterable[type[Message]]) -> None:
    """Recompile the decoders of ``classes`` in every wire format, for their current converters."""
    _clear_fast()
    for cls in set(classes):
        for codec in list(_LIVE_CODECS.get(cls, ())):
            codec.compile(cls)


def register(
    request: type[Message],
    reply: type[Message] | None = None,
    *,
    name: str | None = None,
    aliases: Iterable[str] = (),
    converters: Mapping[str, Converter] | None = None,
    replace: bool = False,
) -> MessageSpec:
    """Make :func:`decode`, the JSON form and the ``simple-message`` command know a message type.

    ``request`` is the class of the type's requests and topics; ``reply``, if the type's
    SERVICE_REPLY has another layout, the class of its replies (both must have the same
    ``MSG_TYPE``). ``name`` defaults to the :class:`~.constants.MsgType` name of the number, else
    to the request class's name in upper snake case (``AcmeGrip`` -> ``ACME_GRIP``); ``aliases``
    are further names :func:`type_for_name` accepts. ``converters`` maps a fixed-layout (``LAYOUT``)
    int field of either class to the :data:`Converter` that decoding applies to it, e.g.
    ``{"mode": RobotMode}``; unmapped values stay plain ints.

    Raises :class:`RegistrationError` if the classes or converters are not well formed, if a name
    is taken by another type (registered names and :class:`~.constants.MsgType` names), or if
    ``msg_type`` is already registered differently and ``replace`` is false. Registering exactly
    what is registered already is a no-op. Returns the :class:`MessageSpec` now in force.
    """
    spec = _spec(request, reply, name, aliases, converters)
    old = _REGISTRY.get(spec.msg_type)
    if old is not None:
        if _same(old, spec):
            return old
        if not replace:
            raise RegistrationError(
                f"msg_type {spec.msg_type} is already registered as {old.name} ({old.request.__name__}); "
                "pass replace=True to replace it"
            )
    for each in (spec.name, *spec.aliases):
        owner = _BY_NAME.get(each)
        if owner is None and each in MsgType.__members__:
            owner = int(MsgType[each])
        if owner is not None and owner != spec.msg_type:
            raise RegistrationError(f"the name {each!r} is already msg_type {owner}'s")
    affected = list(spec.classes)
    if old is not None:
        _remove(old)
        affected += old.classes
    _install(spec)
    _refresh_codecs(affected)
    return spec


def unregister(msg_type: int) -> MessageSpec:
    """Forget ``msg_type`` (it decodes as :class:`RawMessage` again) and return what was registered.

    Raises :class:`RegistrationError` if it is not registered. See also :func:`scoped_registry`.
    """
    spec = _REGISTRY.get(msg_type)
    if spec is None:
        raise RegistrationError(f"msg_type {msg_type} is not registered")
    _remove(spec)
    _refresh_codecs(spec.classes)
    return spec


@contextmanager
def scoped_registry() -> Iterator[None]:
    """Undo, on leaving the block, every :func:`register` and :func:`unregister` made inside it
    (the registry is left exactly as it was entered; for tests)."""
    saved = dict(_REGISTRY)
    try:
        yield
    finally:
        affected: list[type[Message]] = []
        for msg_type, spec in list(_REGISTRY.items()):
            if saved.get(msg_type) is not spec:
                _remove(spec)
                affected += spec.classes
        for msg_type, spec in saved.items():
            if _REGISTRY.get(msg_type) is not spec:
                _install(spec)
                affected += spec.classes
        _refresh_codecs(affected)


def lookup(msg_type: int) -> MessageSpec | None:
    """The registration of ``msg_type``, or ``None``."""
    return _REGISTRY.get(msg_type)


def message_types() -> tuple[MessageSpec, ...]:
    """Every registered message type, in ``msg_type`` order."""
    return tuple(_REGISTRY[t] for t in sorted(_REGISTRY))


def type_name(msg_type: int) -> str | None:
    """The name of ``msg_type``: its registered name, else its :class:`~.constants.MsgType` name
    (e.g. ``READ_INPUT``, which has no message class), else ``None``."""
    return _NAMES.get(msg_type)


def type_for_name(name: str) -> int | None:
    """The msg_type called ``name`` (any case): a registered name or alias, else a
    :class:`~.constants.MsgType` name or alias (``ROBOT_STATUS``); ``None`` if none is."""
    key = name.upper()
    msg_type = _BY_NAME.get(key)
    if msg_type is None and key in MsgType.__members__:
        msg_type = int(MsgType[key])
    return msg_type


def message_class(msg_type: int, comm_type: int = CommType.SERVICE_REQUEST) -> type[Message] | None:
    """The class that decodes ``msg_type`` with ``comm_type``, or ``None`` for unknown types."""
    pair = MESSAGE_CLASSES.get(msg_type)
    if pair is None:
        return None
    return pair[1] if comm_type == CommType.SERVICE_REPLY else pair[0]


# ---------------------------------------------------------------------------------------------
# Encode, decode
# ---------------------------------------------------------------------------------------------


def encode(msg: Message, wire: WireFormat = DEFAULT_FORMAT) -> bytes:
    """Encode ``msg`` as a whole frame (length prefix, header, body) in ``wire`` format.

    Raises :class:`~.errors.LocalProtocolError` if a field does not fit its wire type.
    """
    cls = type(msg)
    if cls.LAYOUT:
        return (wire.codecs.get(cls) or _codec(cls, wire)).pack(msg)
    body = msg._encode_body(wire)
    try:
        header = wire.header.pack(HEADER_SIZE + len(body), msg.msg_type, msg.comm_type, msg.reply_code)
    except struct.error as exc:
        raise LocalProtocolError(f"cannot encode {cls.__name__} header: {exc}") from None
    return header + body


class Header(tuple[int, int, int, int]):
    """``(length, msg_type, comm_type, reply_code)`` of a frame."""

    __slots__ = ()

    @property
    def length(self) -> int:
        return self[0]

    @property
    def msg_type(self) -> int:
        return self[1]

    @property
    def comm_type(self) -> int:
        return self[2]

    @property
    def reply_code(self) -> int:
        return self[3]


def read_header(frame: bytes, wire: WireFormat = DEFAULT_FORMAT) -> Header:
    """The prefix and header of ``frame`` (at least 16 bytes)."""
    return Header(wire.header.unpack_from(frame, 0))


def decode(frame: bytes, wire: WireFormat = DEFAULT_FORMAT) -> Message:
    """Decode one whole frame (as yielded by :class:`~.framing.FrameDecoder`).

    Never raises anything but :class:`~.errors.MalformedMessage` (a known type whose body fits none
    of its layouts, or a frame whose length prefix disagrees with its size). Header *semantics* are
    not checked here; apply :func:`~.header.validate_header` where the C++ rules are wanted.
    """
    size = len(frame)
    if size < LENGTH_SIZE + HEADER_SIZE:
        raise MalformedMessage(
            f"frame of {size} bytes is shorter than a header", msg_type=0, comm_type=0, frame=bytes(frame)
        )
    length, msg_type, comm, reply = wire.header.unpack_from(frame, 0)
    if length != size - LENGTH_SIZE:
        raise MalformedMessage(
            f"length prefix {length} disagrees with a frame of {size} bytes",
            msg_type=msg_type,
            comm_type=comm,
            frame=bytes(frame),
        )
    pair = MESSAGE_CLASSES.get(msg_type)
    if pair is None:
        comm_e, reply_e = _COMM.get(comm, comm), _REPLY.get(reply, reply)
        return RawMessage(msg_type, bytes(frame[16:]), comm_type=comm_e, reply_code=reply_e)
    cls = pair[1] if comm == _SERVICE_REPLY else pair[0]
    if cls.LAYOUT:
        codec = wire.codecs.get(cls) or _codec(cls, wire)
        if length == codec.length:
            return codec.unpack(frame)
    comm_e, reply_e = _COMM.get(comm, comm), _REPLY.get(reply, reply)
    result = None if cls.LAYOUT else cls._decode_body(bytes(frame[16:]), wire, comm_e, reply_e)
    if result is not None:
        return result
    body_size = size - 16
    if body_size == 0:
        return HeaderOnly(msg_type, comm_type=comm_e, reply_code=reply_e)
    if comm == CommType.SERVICE_REPLY and body_size == MAX_JOINTS * wire.real_size:
        return DummyReply(msg_type, wire.struct("10r").unpack_from(frame, 16), comm_type=comm_e, reply_code=reply_e)
    raise MalformedMessage(
        f"{type_name(msg_type)} {CommType(comm).name if comm in _COMM else comm} body of {body_size} bytes "
        f"fits no layout of that type in {wire}",
        msg_type=msg_type,
        comm_type=comm,
        frame=bytes(frame),
    )


# ---------------------------------------------------------------------------------------------
# The standard and MotoROS messages and the project's extensions, with their enum fields' converters
# ---------------------------------------------------------------------------------------------

_SHAPES = (HeaderOnly, DummyReply, RawMessage)

register(Ping)
register(JointPosition)
register(JointTrajPt)
register(JointTraj)
register(
    Status,
    converters={
        "drives_powered": TriState,
        "e_stopped": TriState,
        "in_error": TriState,
        "in_motion": TriState,
        "mode": RobotMode,
        "motion_possible": TriState,
    },
)
register(JointTrajPtFull, converters={"valid_fields": ValidFields})
register(JointFeedback, converters={"valid_fields": ValidFields})
register(MotoMotionCtrl)
register(MotoMotionReply, converters={"result": MotoResult})
register(ReadSingleIo)
register(ReadSingleIoReply)
register(WriteSingleIo)
register(WriteSingleIoReply)
register(ReadGroupIo)
register(ReadGroupIoReply)
register(WriteGroupIo)
register(WriteGroupIoReply)
register(IoCtrlReply)
register(JointTrajPtFullEx)
register(JointFeedbackEx)
register(SelectTool)
register(GetVersion, GetVersionReply)
register(ReadMRegister, ReadMRegisterReply)
register(WriteMRegister, WriteMRegisterReply)
register(GetDhParameters, GetDhParametersReply)

# The project's extensions (65001-65535, freely assignable)
register(CartesianLine, CartesianLineReply, converters={"result": LineResult})
register(ToolPose)
