"""Messages as JSON objects, for the ``simple-message`` command and for clients in other languages.

One message is ``{"msg_type": int, "name": str, "comm_type": int, "reply_code": int, "body": {...}}``.
Body keys are the field names of the message's class: for the standard and MotoROS messages those of
docs/reference/protocol.md §2.2 and §8.1 in snake_case (``sequence``, ``joint_data``, ``velocity``,
``duration``, ``robot_id``, ``valid_fields``, ``time``, ``positions``, ...). Every type in the
message registry (:func:`~.messages.register`) has this form, vendor types included: names and
classes come from the registry, and a class is built from its body by calling it with the body's
keys (nested parts as objects). Special bodies:

* ``{}`` on a type whose default message has a body (every type but PING): a header-only message
  (ABB acks, FAILURE replies);
* ``{"dummy_data": [10 reals]}``: REP-I0006's alternative reply body;
* ``{"raw": "hex"}``: an unknown type's body, kept byte for byte (also accepted for known types when
  encoding, to write deliberately odd frames).

Where the protocol names a number, the object also has ``"names"``: the symbolic name of each such
field, header included (``{"comm_type": "TOPIC", "reply_code": "INVALID", "drives_powered": "TRUE",
"mode": "AUTO", ...}``; tri-states, modes, special sequence numbers, valid-field bits joined by
``|``, MotoROS commands, results and subcodes, IO result codes). A field that the message registry
gives an enum converter (:func:`~.messages.register`) is named by that enum, e.g. the ``result`` of
a CARTESIAN_LINE reply by :class:`~.constants.LineResult`; other fields are named by their field
name, which means the same thing in every message that has it. The numbers stay where they are and
decide; ``"names"`` is ignored when a message is built from JSON.

Reals that are not finite are written as the strings ``"NaN"``, ``"Infinity"`` and ``"-Infinity"``
(plain JSON has no such numbers) and accepted back in that form. In float32 formats each real is
printed as the shortest decimal that reads back to the same float32, so ``0.1`` prints as ``0.1``
and still re-encodes byte for byte.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import fields
from enum import Enum, Flag, IntEnum
from typing import Any

from .constants import (
    HEADER_SIZE,
    LENGTH_SIZE,
    CommType,
    IoResult,
    MotoCommand,
    MotoResult,
    ReplyCode,
    RobotMode,
    SpecialSeq,
    TriState,
    ValidFields,
    moto_subcode_name,
)
from .errors import LocalProtocolError
from .messages import (
    DummyReply,
    HeaderOnly,
    Message,
    RawMessage,
    encode,
    lookup,
    message_class,
    type_for_name,
)

__all__ = ["message_to_json", "message_from_json", "symbolic_names"]

_F32 = struct.Struct("<f")
_NONFINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


def _short_real(x: float, real_size: int) -> float | str:
    if not math.isfinite(x):
        return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")
    if real_size == 8:
        return x
    for digits in range(6, 10):
        candidate = float(f"{x:.{digits}g}")
        if _F32.unpack(_F32.pack(candidate))[0] == x:
            return candidate
    return x  # pragma: no cover - 9 significant digits always round-trip a float32


def _plain(value: Any, real_size: int) -> Any:
    if isinstance(value, float):
        return _short_real(value, real_size)
    if isinstance(value, list):
        return [_plain(v, real_size) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v, real_size) for k, v in value.items()}
    return value


#: body fields whose numbers the protocol names, and the names' enum (by field name: the same field
#: name means the same thing in every message that has it, unless the message's registration gives
#: the field a converter of its own, as CARTESIAN_LINE does for ``result``)
_NAMED: dict[str, type[IntEnum]] = {
    "drives_powered": TriState,
    "e_stopped": TriState,
    "in_error": TriState,
    "in_motion": TriState,
    "motion_possible": TriState,
    "mode": RobotMode,
    "command": MotoCommand,
    "result": MotoResult,
    "result_code": IoResult,
}


def _enum_name(kind: type[IntEnum], value: int) -> str | None:
    try:
        return kind(value).name
    except ValueError:
        return None


def _is_flag_table(table: Mapping[int, Any]) -> bool:
    """Whether a registered converter table is an ``IntFlag``'s (named below as ``valid_fields``)."""
    return any(isinstance(member, Flag) for member in table.values())


def symbolic_names(msg: Message) -> dict[str, str]:
    """The symbolic name of each of ``msg``'s numbers that the protocol names (see the module doc)."""
    names: dict[str, str] = {}
    for key, kind in (("comm_type", CommType), ("reply_code", ReplyCode)):
        name = _enum_name(kind, getattr(msg, key))
        if name is not None:
            names[key] = name
    body = msg.body_dict()
    spec = lookup(msg.msg_type)
    converters = spec.converters if spec is not None and type(msg) in spec.classes else {}
    for key, value in body.items():
        if not isinstance(value, int) or isinstance(value, bool):
            continue
        name = None
        table = converters.get(key)
        if table is not None and not _is_flag_table(table):  # the registered enum decides, named or not
            member = table.get(value)
            name = member.name if isinstance(member, Enum) else None
        elif key in _NAMED:
            name = _enum_name(_NAMED[key], value)
        elif key == "sequence" and value < 0:
            name = _enum_name(SpecialSeq, value)
        elif key == "valid_fields":
            name = "|".join(f.name for f in ValidFields if f and f & value and f.name) or "NONE"
        elif key == "subcode" and value:
            name = moto_subcode_name(int(body.get("result", 0)), value)
        if name is not None:
            names[key] = name
    return names


def message_to_json(msg: Message, real_size: int = 4) -> dict[str, Any]:
    """``msg`` as a JSON-ready dict; ``real_size`` (4 or 8) only affects how reals are printed."""
    out = {
        "msg_type": int(msg.msg_type),
        "name": msg.name,
        "comm_type": int(msg.comm_type),
        "reply_code": int(msg.reply_code),
        "body": _plain(msg.body_dict(), real_size),
    }
    names = symbolic_names(msg)
    if names:
        out["names"] = names
    return out


def _real(value: Any) -> Any:
    if isinstance(value, str):
        if value in _NONFINITE:
            return _NONFINITE[value]
        raise LocalProtocolError(f"{value!r} is not a number")
    if isinstance(value, list):
        return [_real(v) for v in value]
    if isinstance(value, dict):
        return {k: _real(v) for k, v in value.items()}
    return value


def _int(obj: dict[str, Any], key: str, default: int | None = None) -> int:
    value = obj.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise LocalProtocolError(f"{key!r} must be an integer, not {value!r}")
    return value


def _empty_body_is_own(cls: type[Message]) -> bool:
    """Whether ``cls``'s default message has an empty body (PING), so that ``{}`` means ``cls``."""
    try:
        return len(encode(cls())) == LENGTH_SIZE + HEADER_SIZE
    except (TypeError, ValueError):
        return False


def message_from_json(obj: Any) -> Message:
    """Build a message from the JSON form of :func:`message_to_json`.

    ``msg_type`` may be given as an int or by ``name`` (any name or alias of
    :func:`~.messages.type_for_name`); ``comm_type`` and ``reply_code`` default to the class's
    defaults. Raises :class:`~.errors.LocalProtocolError` with a clear reason otherwise.
    """
    if not isinstance(obj, dict):
        raise LocalProtocolError(f"a message must be a JSON object, not {type(obj).__name__}")
    if "msg_type" in obj:
        msg_type = _int(obj, "msg_type")
    elif "name" in obj:
        named = type_for_name(str(obj["name"]))
        if named is None:
            raise LocalProtocolError(f"unknown message name {obj['name']!r}")
        msg_type = named
    else:
        raise LocalProtocolError("a message needs 'msg_type' or 'name'")
    body = obj.get("body", {})
    if not isinstance(body, dict):
        raise LocalProtocolError(f"'body' must be an object, not {type(body).__name__}")
    header: dict[str, int] = {}
    for key in ("comm_type", "reply_code"):
        if key in obj:
            header[key] = _int(obj, key)
    comm = header.get("comm_type", 2)
    try:
        if "raw" in body:
            if set(body) != {"raw"}:
                raise LocalProtocolError("'raw' cannot be combined with other body fields")
            return RawMessage(msg_type, bytes.fromhex(str(body["raw"])), **header)
        if "dummy_data" in body:
            return DummyReply(msg_type, _real(body["dummy_data"]), **header)
        cls = message_class(msg_type, comm)
        if cls is None:
            raise LocalProtocolError(f'msg_type {msg_type} is unknown; give its body as {{"raw": hex}}')
        names = [f.name for f in fields(cls) if f.name not in ("comm_type", "reply_code")]
        if not body and names and not _empty_body_is_own(cls):
            return HeaderOnly(msg_type, **header)
        unknown = set(body) - set(names)
        if unknown:
            raise LocalProtocolError(f"{cls.__name__} has no field(s) {sorted(unknown)}; its fields are {names}")
        values = {k: _real(v) for k, v in body.items()}
        return cls(**values, **header)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, LocalProtocolError):
            raise
        raise LocalProtocolError(f"cannot build msg_type {msg_type} from {body!r}: {exc}") from None
