"""Wire formats: byte order and the size of ``shared_real``.

simple_message has no negotiation (docs/reference/protocol.md §1.3, §10 pitfall 2): both peers must be built
alike. Ints and the length prefix are always int32; reals are float32, or float64 in the FLOAT64
build. The reference library's default build writes host order, little-endian on every PC, which
is this module's default; Fanuc and the Motoman FS100 speak big-endian.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cache
from typing import Any

__all__ = ["ByteOrder", "WireFormat", "LE32", "BE32", "LE64", "BE64", "DEFAULT_FORMAT"]


class ByteOrder(StrEnum):
    """Byte order of every int, real and the length prefix on the wire."""

    LITTLE = "little"
    BIG = "big"

    @property
    def struct_char(self) -> str:
        return "<" if self is ByteOrder.LITTLE else ">"


@dataclass(frozen=True, slots=True)
class WireFormat:
    """How numbers are laid out on one link.

    ``real_size`` is 4 (float32, the ROS default) or 8 (the FLOAT64 build). There is no big-endian
    float64 build of the reference library, but peers in other languages may speak it, so it is
    allowed here.
    """

    byte_order: ByteOrder = ByteOrder.LITTLE
    real_size: int = 4
    #: Prefix + header struct (four int32), precomputed for the hot decode path.
    header: struct.Struct = field(init=False, repr=False, compare=False, hash=False)
    #: Per-message-class codecs, filled lazily by :mod:`.messages` (an implementation detail); one
    #: dict shared by all equal formats, so that a format made again (e.g. by :meth:`with_byte_order`
    #: for each autodetecting link) does not compile them again.
    codecs: dict[type, Any] = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        # Accept the plain strings "little" and "big" too (e.g. from a command line).
        object.__setattr__(self, "byte_order", ByteOrder(self.byte_order))
        if self.real_size not in (4, 8):
            raise ValueError(f"real_size must be 4 or 8 bytes, not {self.real_size!r}")
        object.__setattr__(self, "header", self.struct("iiii"))
        object.__setattr__(self, "codecs", _CODECS.setdefault((self.byte_order, self.real_size), {}))

    @property
    def real_char(self) -> str:
        return "f" if self.real_size == 4 else "d"

    def struct(self, layout: str) -> struct.Struct:
        """A cached :class:`struct.Struct` for ``layout``, where ``r`` stands for one real."""
        return _compile(self.byte_order.struct_char, self.real_char, layout)

    def with_byte_order(self, byte_order: ByteOrder) -> WireFormat:
        return WireFormat(byte_order, self.real_size)

    def __str__(self) -> str:
        return f"{self.byte_order.value}-endian float{self.real_size * 8}"


#: The codecs dict of each format (byte order, real size): at most four.
_CODECS: dict[tuple[ByteOrder, int], dict[type, Any]] = {}


@cache
def _compile(order: str, real: str, layout: str) -> struct.Struct:
    return struct.Struct(order + layout.replace("r", real))


LE32 = WireFormat(ByteOrder.LITTLE, 4)
BE32 = WireFormat(ByteOrder.BIG, 4)
LE64 = WireFormat(ByteOrder.LITTLE, 8)
BE64 = WireFormat(ByteOrder.BIG, 8)
#: The ROS default build: little-endian float32.
DEFAULT_FORMAT = LE32
