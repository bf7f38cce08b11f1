"""How fixed layouts are packed and unpacked: one precompiled struct per class and wire format.

A message class with a ``LAYOUT`` (:mod:`.base`) is encoded and decoded by a :class:`_Codec`, made
the first time the class meets a wire format and kept in that format's ``codecs``. Decoding is the
protocol's hot path, so a codec generates its decoding functions as straight-line code for its class
and sets the fields without running the constructor (:func:`_builder`). :func:`fast_decoders` gives
:meth:`.framing.FrameDecoder.feed_messages` its tables per wire format.

The tables that registering fills and decoding reads are kept here too: :data:`MESSAGE_CLASSES`
(which classes decode a ``msg_type``) and the converters of each class's enum fields. Only
:mod:`.registry` changes them, and it recompiles the codecs concerned
(:func:`_refresh_codecs`) and empties the fast tables whenever it does.
"""

from __future__ import annotations

import keyword
import struct
import weakref
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING, Any

from ..constants import HEADER_SIZE, LENGTH_SIZE, CommType, ReplyCode
from ..errors import LocalProtocolError
from ..wire import WireFormat

if TYPE_CHECKING:
    from .base import Message

_HEADER = "iiii"  # length prefix + msg_type + comm_type + reply_code, always int32

# Small caches that turn wire ints into enum members without the cost of Enum.__call__.
_COMM = {int(c): c for c in CommType}
_REPLY = {int(c): c for c in ReplyCode}
_SERVICE_REPLY = int(CommType.SERVICE_REPLY)
#: a run whose frame this many frames on still has the run's header is decoded by iter_unpack
#: (setting that up costs about what decoding two frames one by one does)
_LONG_RUN = 8

#: Message class per type for requests and topics (index 0) and for SERVICE_REPLYs (index 1).
#: Kept by :func:`~.registry.register` and :func:`~.registry.unregister` (the decoder's lookup
#: table); do not change it directly.
MESSAGE_CLASSES: dict[int, tuple[type[Message], type[Message]]] = {}
#: Converters per fixed-layout class, read when a codec compiles its ``unpack`` (kept by the registry).
_CLASS_CONVERTERS: dict[type[Message], dict[str, Mapping[int, Any]]] = {}
#: Every compiled codec per class, so that a change of converters recompiles them.
_LIVE_CODECS: dict[type[Message], weakref.WeakSet[_Codec]] = {}


def _body_format(layout: tuple[tuple[str, str], ...]) -> str:
    """The struct format of a body LAYOUT ("r" = one real, "r10" = ten)."""
    return "".join(f"{code[1:]}{code[0]}" if len(code) > 1 else code for _, code in layout)


class _Codec:
    """A precompiled struct for one fixed-layout class in one wire format.

    The struct covers the whole frame (prefix, header, body), so a frame is packed or unpacked in a
    single call. Decoding is the protocol's hot path, so its functions are generated as
    straight-line code per class (as :mod:`dataclasses` generates ``__init__``; a generic per-field
    loop costs a third of the time):

    * ``unpack(frame)`` decodes one whole frame of exactly ``struct.size`` bytes;
    * ``unpack_run(buf, pos, end, msg_type, comm, reply, out)`` decodes, straight from a stream
      (``bytes``, complete frames up to ``end``), the frame at ``pos``, whose header the caller
      read (its ``msg_type``, ``comm`` and ``reply`` as wire ints, and a length prefix equal to
      :attr:`length`), and every frame after it with the same header, appending each message to the
      list ``out``; it returns the position after the last. Messages of one type mostly come in such
      runs (a trajectory, a feedback topic), so the caller reads one header per run. The first frame
      is unpacked on its own; once the next one has the same 16 header bytes, the rest of the run
      is unpacked by one :meth:`struct.Struct.iter_unpack` over the complete frames left (header and
      body, so no position is computed and no call is made per frame in Python), each frame's four
      header ints compared with the run's, and the run ends at the first that differs.

    Neither runs the class's ``__init__``/``__post_init__`` (decoding never has). What
    ``Message.__post_init__`` checks, the layout guarantees: each joint array is a slice of exactly
    10 unpacked reals, so it is already the tuple of 10 floats that ``_normalise_arrays`` makes of
    an argument (and never more than 10); ints are ints of their field's wire range. The fields are
    set through the class's builder (:func:`_builder`) when it has one.
    """

    __slots__ = (
        "__weakref__",
        "arrays",
        "body",
        "builder",
        "length",
        "plan",
        "scalars",
        "struct",
        "unpack",
        "unpack_run",
    )

    unpack: Callable[[bytes], Message]
    unpack_run: Callable[[bytes, int, int, int, int, int, list[Any]], int]

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
        #: the rest of a run is unpacked by these (see :meth:`_run_structs`)
        self.scalars, self.arrays = self._run_structs(cls, wire)
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

        def build(comm: str, reply: str, value_of: Callable[[int, int, int], str], indent: str) -> list[str]:
            """Statements that make ``o``; ``value_of(k, start, stop)`` is the expression of field k."""
            values = [("comm_type", comm), ("reply_code", reply)]
            for k, (name, start, stop) in enumerate(self.plan):
                value = value_of(k, start, stop)
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

        def item(offset: int) -> Callable[[int, int, int], str]:
            """Field k as an item (or a slice) of the unpacked values ``v``, at its index - ``offset``."""
            return lambda k, start, stop: f"v[{start - offset}]" if stop < 0 else f"v[{start - offset}:{stop - offset}]"

        def named(k: int, start: int, stop: int) -> str:
            return f"f{k}"  # a local of the run's loop (an array: its own tuple, straight from its struct)

        size = self.struct.size
        # The rest of a run, one iter_unpack per part: the header and the scalar fields (each array
        # skipped as padding), and each array alone (its values come out as the field's own tuple).
        scalars, arrays = self.scalars, self.arrays
        env["_view"] = memoryview
        env["_zip"] = zip
        iterators = ["_scalars(frames)"]
        env["_scalars"] = scalars.iter_unpack
        targets = ["h0", "h1", "h2", "h3"] + [f"f{k}" for k, (_, _, stop) in enumerate(self.plan) if stop < 0]
        loop_target = "(" + ", ".join(targets) + ")"
        for k, array in arrays:
            env[f"_array{k}"] = array.iter_unpack
            iterators.append(f"_array{k}(frames)")
            loop_target += f", f{k}"
        loop_source = iterators[0] if len(iterators) == 1 else "_zip(" + ", ".join(iterators) + ")"
        source = [
            "def unpack(frame):",
            "    v = _unpack(frame)",
            *build("_COMM.get(v[2], v[2])", "_REPLY.get(v[3], v[3])", item(0), "    "),
            "    return o",
            "def unpack_run(buf, pos, end, msg_type, comm, reply, out):",
            "    comm_type = _COMM.get(comm, comm)",
            "    reply_code = _REPLY.get(reply, reply)",
            f"    head = buf[pos:pos + {LENGTH_SIZE + HEADER_SIZE}]",
            "    same = buf.startswith",
            f"    last = end - {size}",
            "    v = _unpack_body(buf, pos)",
            *build("comm_type", "reply_code", item(4), "    "),
            "    out.append(o)",
            f"    pos += {size}",
            "    if pos > last or not same(head, pos):",
            "        return pos",
            f"    if pos + {(_LONG_RUN - 1) * size} > last or not same(head, pos + {(_LONG_RUN - 1) * size}):",
            "        while True:  # a short run, frame by frame",
            "            v = _unpack_body(buf, pos)",
            *build("comm_type", "reply_code", item(4), "            "),
            "            out.append(o)",
            f"            pos += {size}",
            "            if pos > last or not same(head, pos):",
            "                return pos",
            "    first = len(out)",
            f"    frames = _view(buf)[pos:pos + (end - pos) // {size} * {size}]",
            f"    for {loop_target} in {loop_source}:",
            f"        if h1 != msg_type or h2 != comm or h3 != reply or h0 != {self.length}:",
            "            break",
            *build("comm_type", "reply_code", named, "        "),
            "        out.append(o)",
            f"    return pos + (len(out) - first) * {size}",
        ]
        exec("\n".join(source), env)  # generated from the class's own LAYOUT only
        self.unpack = env["unpack"]
        self.unpack_run = env["unpack_run"]

    def _run_structs(
        self, cls: type[Message], wire: WireFormat
    ) -> tuple[struct.Struct, list[tuple[int, struct.Struct]]]:
        """The structs a run is unpacked with, each the size of a whole frame: the four header ints
        and the scalar fields (the arrays skipped), and, per array field (its plan index), that
        array alone."""
        sizes = [wire.struct(_body_format(((name, code),))).size for name, code in cls.LAYOUT]
        scalar_format = _HEADER
        arrays: list[tuple[int, str]] = []
        offset = LENGTH_SIZE + HEADER_SIZE
        for k, ((name, code), nbytes) in enumerate(zip(cls.LAYOUT, sizes, strict=True)):
            if self.plan[k][2] < 0:
                scalar_format += code
            else:
                scalar_format += f"{nbytes}x"
                arrays.append((k, f"{offset}x{_body_format(((name, code),))}{self.struct.size - offset - nbytes}x"))
            offset += nbytes
        structs = [(k, wire.struct(layout)) for k, layout in arrays]
        scalars = wire.struct(scalar_format)
        assert all(s.size == self.struct.size for _, s in [(0, scalars), *structs]), cls
        return scalars, structs

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


def _refresh_codecs(classes: Iterable[type[Message]]) -> None:
    """Recompile the decoders of ``classes`` in every wire format, for their current converters."""
    _clear_fast()
    for cls in set(classes):
        for codec in list(_LIVE_CODECS.get(cls, ())):
            codec.compile(cls)
