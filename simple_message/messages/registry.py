"""Which classes decode which ``msg_type``: the public message registry.

:func:`register` makes a message type known to decoding, encoding by name, the JSON form
(:mod:`..jsonio`) and the ``simple-message`` command; :func:`unregister` and
:func:`scoped_registry` undo it; :func:`lookup`, :func:`message_types`, :func:`type_name`,
:func:`type_for_name` and :func:`message_class` read it. A registration (:class:`MessageSpec`) may
turn enum fields into enum members (:data:`Converter`); the codecs of its classes are then
recompiled (:mod:`.codec`). ``CONTRIBUTING.md`` ("Adding a vendor message set") says how a vendor's
module uses it. (This is the registry of message types; :mod:`simple_message.registry` is the
table type of the named extension points, dialects and the like.)
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag
from types import MappingProxyType
from typing import Any, TypeAlias

from ..constants import CommType, MsgType
from ..errors import SimpleMessageError
from . import base as base_module
from . import codec as codec_module
from .base import DummyReply, HeaderOnly, Message, RawMessage
from .codec import _clear_fast, _refresh_codecs

# The tables whose methods are called here, bound by assignment for the reason base.py gives.
MESSAGE_CLASSES = codec_module.MESSAGE_CLASSES
_CLASS_CONVERTERS = codec_module._CLASS_CONVERTERS
_NAMES = base_module._NAMES

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


_REGISTRY: dict[int, MessageSpec] = {}
#: Registered names and aliases -> msg_type (MsgType's own names are looked up after these).
_BY_NAME: dict[str, int] = {}

_NAME_RE = re.compile(r"[A-Z][A-Z0-9_]*")
#: Classes that stand for shapes of any type; they are never registered.
_SHAPES: tuple[type[Message], ...] = (HeaderOnly, DummyReply, RawMessage)


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
