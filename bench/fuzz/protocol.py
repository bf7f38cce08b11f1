"""The protocol as far as the fuzzer needs it (docs/reference/protocol.md §1-§4, §8.1): the header, the
types and their body layouts, which types move a robot, and frames built and read with
:mod:`struct` only, not with the project's decoder, so that a bug shared by our decoder and our
server cannot hide from the tool.
"""

from __future__ import annotations

import struct

HEADER = 16  # length prefix + msg_type + comm_type + reply_code
MAX_LENGTH = 64 * 1024  # the server's default largest length prefix (simple_message.framing)
PING = 1
MOTION_TYPES = frozenset({11, 12, 14, 2001, 2016, 65001})  # 65001: the project's CARTESIAN_LINE
#: MotoROS closes its motion connection on these (§8.1): sent rarely there, or every frame would
#: cost a reconnection
MOTOROS_CLOSING = frozenset({13, 15, 2002, 2017})
#: body layouts per type, (request or topic, reply); "r" is one real, "I" an unsigned int
LAYOUTS: dict[int, tuple[str, str]] = {
    1: ("", ""),
    2: ("", "3i"),
    10: ("i10r", "i10r"),
    13: ("7i", "7i"),
    15: ("2i31r", "2i31r"),
    2002: ("5i10r", "5i10r"),
    2003: ("I", "Ii"),
    2004: ("Ii", "Ii"),
    2005: ("II", "i"),
    2006: ("i", "i"),
    2007: ("I", "Ii"),
    2008: ("Ii", "Ii"),
    2009: ("II", "i"),
    2010: ("i", "i"),
    2011: ("ii", "ii"),
    2012: ("I", "Ii"),
    2013: ("II", "i"),
    2017: ("i" + "2i31r" * 4, "i" + "2i31r" * 4),
    2018: ("3i", "3i"),
    2020: ("", "128r"),
    65002: ("2i9r", "2i9r"),  # the project's TOOL_POSE (its subscription on the state port)
}
KNOWN_TYPES = tuple(sorted(set(LAYOUTS) | MOTION_TYPES))
UNKNOWN_TYPES: tuple[int, ...] = (0, -1, 3, 9, 16, 17, 19, 20, 21, 22, 999, 1000, 1300, 1400, 2000, 2014, 2015)
UNKNOWN_TYPES += (2019, 2021, 3000, 65003, 65535, 65536, 2**31 - 1, -(2**31))
MOTO_COMMANDS = range(200100, 200200)  # every MOTO_MOTION_CTRL command MotoROS has, and spares

#: int32 in either byte order, and a header (length prefix, msg_type, comm_type, reply_code)
INT = {o: struct.Struct(o + "i") for o in "<>"}
HEAD = {o: struct.Struct(o + "4i") for o in "<>"}


def frame_of(order: str, msg_type: int, comm: int, reply: int, body: bytes) -> bytes:
    return HEAD[order].pack(12 + len(body), msg_type, comm, reply) + body


def ping_request(order: str) -> bytes:
    return frame_of(order, PING, 2, 0, b"")


def detect(buf: bytes) -> struct.Struct | None:
    """The server's byte-order detection from a first length prefix (simple_message.framing)."""
    for order in "<>":
        length = INT[order].unpack_from(buf, 0)[0]
        if 12 <= length <= MAX_LENGTH:
            return INT[order]
    return None
