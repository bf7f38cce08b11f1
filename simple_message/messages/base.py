"""What every message is, and whole frames in and out.

:class:`Message` is the base of every message class: the header fields ``comm_type`` and
``reply_code``, the class's ``MSG_TYPE``, and the ``LAYOUT`` its body is encoded by (a body that is
no fixed struct overrides ``_encode_body`` and ``_decode_body``). :func:`encode` and :func:`decode`
turn a message into one whole frame (length prefix, header, body) and back; fixed layouts go through
their :mod:`.codec`, and the registry (:mod:`.registry`) says which class decodes a ``msg_type``.
Three classes stand for shapes a frame of any type may take (:class:`HeaderOnly`,
:class:`DummyReply`, :class:`RawMessage`); what decoding promises is in the package's docstring.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, ClassVar

from ..constants import HEADER_SIZE, LENGTH_SIZE, MAX_JOINTS, CommType, MsgType, ReplyCode
from ..errors import LocalProtocolError, MalformedMessage
from ..wire import DEFAULT_FORMAT, WireFormat
from . import codec as codec_module
from .codec import _SERVICE_REPLY, _codec

# The tables decoding calls methods of are bound here by assignment, not by ``from .codec import``:
# CPython (3.11) compiles ``name.get(...)`` on a name bound by an import as an attribute load and a
# call instead of a method call, which made every decode() 5 to 8 % slower.
MESSAGE_CLASSES = codec_module.MESSAGE_CLASSES
_COMM = codec_module._COMM
_REPLY = codec_module._REPLY

Floats = tuple[float, ...]
#: Ten zero reals, the default of every joint array.
ZEROS: Floats = (0.0,) * MAX_JOINTS

#: Name per msg_type: the registered name, else the canonical MsgType name (READ_INPUT, INVALID, ...).
#: Kept by :mod:`.registry`; read by :attr:`Message.name` and in decoding's errors.
_NAMES: dict[int, str] = {int(member): member.name for member in MsgType}


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
        :func:`~.registry.type_name`."""
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
        f"{_NAMES.get(msg_type)} {CommType(comm).name if comm in _COMM else comm} body of {body_size} bytes "
        f"fits no layout of that type in {wire}",
        msg_type=msg_type,
        comm_type=comm,
        frame=bytes(frame),
    )
