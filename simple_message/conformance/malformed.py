"""The malformed frames a server must survive: those the reference C++ library rejects.

The list follows the reference peer's own rules (docs/reference/protocol.md §1.2 ``validateMessage``, §1.5
parse and size quirks): what the C++ library drops (a header it does not validate, a body shorter
than the type needs), what makes it drop the connection (a length ≤ 0), what it cannot take (a
length beyond its 1024-byte buffer), plus what a byte stream can always bring: a frame cut short,
a frame in the other byte order, noise. None of them is a motion message, so that a server that
misreads one still cannot be made to move by it: a short *body* is tried on JOINT_POSITION (10) as a
request, not on a trajectory point. And every case is shorter than :data:`FANUC_MIN_READ` bytes:
Fanuc's KAREL parser reads any 56 bytes as a trajectory point without looking at the type (§8.3),
so a longer case could be run as a move to the zero pose.

Each case is sent on a connection of its own; the suite then watches another connection (the state
port's) stay served and checks that a fresh connection is answered (:mod:`.server`, rule
``malformed.survival``).
"""

from __future__ import annotations

import random
import struct
from dataclasses import dataclass

from ..constants import CommType, MsgType, ReplyCode
from ..wire import ByteOrder, WireFormat

__all__ = ["MalformedCase", "malformed_cases", "FANUC_MIN_READ"]

#: the bytes Fanuc's KAREL parser waits for before it reads a point, whatever the type (§8.3)
FANUC_MIN_READ = 56


@dataclass(frozen=True)
class MalformedCase:
    """One malformed input: ``name``, why it is malformed (``what``, with the reference peer's rule
    it breaks), and its ``data``. ``hold``: the connection is kept open after it (a frame that
    announces more than it sends) rather than only until the server answers or closes."""

    name: str
    what: str
    data: bytes
    hold: bool = False


def malformed_cases(wire: WireFormat, seed: int = 1) -> list[MalformedCase]:
    """The cases in ``wire``'s byte order (each built field by field with :mod:`struct`, not with
    the project's encoder, so that a bug there cannot hide one)."""
    o = "<" if wire.byte_order is ByteOrder.LITTLE else ">"
    other = ">" if o == "<" else "<"

    def frame(length: int, msg_type: int, comm: int, reply: int, body: bytes = b"", *, order: str = o) -> bytes:
        return struct.pack(f"{order}4i", length, msg_type, comm, reply) + body

    ping, req, rep, topic = int(MsgType.PING), int(CommType.SERVICE_REQUEST), int(CommType.SERVICE_REPLY), 1
    invalid, success = int(ReplyCode.INVALID), int(ReplyCode.SUCCESS)
    noise = random.Random(seed).randbytes(48)
    return [
        MalformedCase(
            "length-zero", "length 0: the C++ receiver marks the link disconnected (§1.5)", struct.pack(f"{o}i", 0)
        ),
        MalformedCase("length-negative", "length -1 (§1.5)", struct.pack(f"{o}i", -1)),
        MalformedCase(
            "length-short",
            "length 8, below the 12-byte header: SimpleMessage::init fails (§1.5)",
            struct.pack(f"{o}3i", 8, ping, req),
        ),
        MalformedCase("msg-type-zero", "msg_type 0 (validateMessage, §1.2)", frame(12, 0, req, invalid)),
        MalformedCase("comm-type-zero", "comm_type 0 (validateMessage, §1.2)", frame(12, ping, 0, invalid)),
        MalformedCase("comm-type-unknown", "comm_type 4: warn and ignore (§3)", frame(12, ping, 4, invalid)),
        MalformedCase(
            "reply-without-code", "SERVICE_REPLY with reply_code INVALID (§1.2)", frame(12, ping, rep, invalid)
        ),
        MalformedCase(
            "request-with-code", "SERVICE_REQUEST with reply_code SUCCESS (§1.2)", frame(12, ping, req, success)
        ),
        MalformedCase(
            "topic-with-code", "TOPIC with reply_code SUCCESS (§1.2)", frame(12, int(MsgType.STATUS), topic, success)
        ),
        MalformedCase(
            "body-short",
            "JOINT_POSITION request with a 20-byte body (44 needed): the typed unload fails (§1.5)",
            frame(32, int(MsgType.JOINT_POSITION), req, invalid, bytes(20)),
        ),
        MalformedCase(
            "length-oversize",
            "length 1,000,000 with 48 bytes sent: beyond the C++ peers' 1024-byte buffer (§1.5)",
            frame(1_000_000, ping, req, invalid, bytes(36)),
            hold=True,
        ),
        MalformedCase(
            "length-huge", "length 2^31-1 with nothing after it", struct.pack(f"{o}i", 2**31 - 1) + bytes(12), hold=True
        ),
        MalformedCase(
            "truncated",
            "a PING cut after 10 of its 16 bytes, then the connection closed",
            frame(12, ping, req, invalid)[:10],
        ),
        MalformedCase(
            "wrong-byte-order",
            "a PING in the other byte order (its length reads 201,326,592; §10 pitfall 1)",
            frame(12, ping, req, invalid, order=other),
        ),
        MalformedCase("noise", "48 random bytes", noise),
    ]
