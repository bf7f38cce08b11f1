"""03: a vendor's own messages, and the dialect that says which reply answers which request.

A made-up conveyor controller ("Beltway") takes BELT_SPEED (1901) and answers it, not with an
echo, but with a message of another type, BELT_STATE (1902), which it also publishes as a topic.
Two frozen dataclasses describe the bodies; ``register`` puts them in the message registry, so
decode, encode, the JSON form and the ``simple-message`` command know them; a ``Dialect`` says how
the controller answers, so a client given it takes BELT_STATE as the reply to BELT_SPEED. A client
held to the generic rules refuses that reply. Everything runs in-process on 127.0.0.1.

Run: python examples/03_vendor_message.py
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import ClassVar

from simple_message import (
    BE32,
    GENERIC,
    Client,
    CommType,
    Dialect,
    Message,
    ReplyCode,
    ReplyStyle,
    Server,
    Session,
    UnexpectedReply,
    decode,
    register,
)
from simple_message.dialects import register as register_dialect


@dataclass(frozen=True, slots=True)
class BeltSpeed(Message):
    """BELT_SPEED (1901) request: run conveyor ``belt`` at ``speed`` m/s."""

    belt: int = 0
    speed: float = 0.0
    MSG_TYPE: ClassVar[int] = 1901
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("belt", "i"), ("speed", "r"))


@dataclass(frozen=True, slots=True)
class BeltState(Message):
    """BELT_STATE (1902) topic, and the reply to BELT_SPEED: a belt's speed (m/s) and travel (m)."""

    belt: int = 0
    speed: float = 0.0
    travel: float = 0.0
    comm_type: int = field(default=CommType.TOPIC, kw_only=True)
    MSG_TYPE: ClassVar[int] = 1902
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = (("belt", "i"), ("speed", "r"), ("travel", "r"))


register(BeltSpeed)  # named BELT_SPEED after the class; a vendor module does this at import
register(BeltState)
BELTWAY = register_dialect(
    Dialect(
        name="beltway",
        description="Beltway conveyor controller (made up for this example)",
        motion_port=11900,
        state_port=11902,
        io_port=None,
        wire=BE32,
        reply_style=ReplyStyle.ECHO,
        replies={BeltSpeed.MSG_TYPE: frozenset({BeltState.MSG_TYPE})},  # BELT_SPEED is answered by BELT_STATE
    )
)

frame = BeltSpeed(2, 0.25).encode(BE32)
print("BELT_SPEED frame:", frame.hex(" ", 4), "->", decode(frame, BE32))


def on_speed(request: Message, session: Session) -> Message:
    assert isinstance(request, BeltSpeed)
    return BeltState(request.belt, request.speed, 12.5, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)


async def main() -> None:
    server = Server(BELTWAY.wire)  # 127.0.0.1
    server.handle(BeltSpeed.MSG_TYPE, on_speed)
    port = await server.serve_tcp(port=0)
    try:
        async with Client.tcp("127.0.0.1", port, BELTWAY.wire, dialect=BELTWAY) as client:
            reply = await client.request(BeltSpeed(2, 0.25), timeout=2.0)
            print(f"reply: {reply.name} {ReplyCode(reply.reply_code).name}: {reply}")
        async with Client.tcp("127.0.0.1", port, BELTWAY.wire, dialect=GENERIC) as generic:
            try:
                await generic.request(BeltSpeed(2, 0.25), timeout=2.0)
            except UnexpectedReply as exc:
                print("a client held to the generic rules refuses it:", exc)
    finally:
        await server.close()


asyncio.run(main())
