"""Each profile writes each state message with its own write, as its controller does (MotoROS's
state task calls mpSend per message, StateServer.c:150-186; RAPID, KAREL and VAL3 send per message
too). A client that reads one message per recv() (ra-mtp-ntnu/moto) depends on it: a round of
topics in one write gave it only the first message of every round."""

from __future__ import annotations

import struct

import pytest

from tests.stepped import step
from tests.vendor import connect, vendor_emulator

ROUND = {
    "generic": [10, 13],
    "motoros": [15, 15, 2017, 13],  # JOINT_FEEDBACK per group, JOINT_FEEDBACK_EX, STATUS
    "abb": [10, 13],
    "fanuc": [10],  # STATUS after every 11th
    "staubli": [10],  # STATUS with every 5th
}


@pytest.mark.parametrize("profile", sorted(ROUND))
async def test_every_state_message_is_a_write_of_its_own(profile: str) -> None:
    options: dict[str, object] = {"models": ("jibot_zxs", "puma560")} if profile == "motoros" else {}
    if profile == "motoros":
        options["io_port"] = 0
    order = ">" if profile == "fanuc" else "<"
    async with vendor_emulator(profile, **options) as (emu, clock, wire):
        state = await connect(emu, "state", order)
        await step(clock, 1.2)  # the Staubli state client's first second
        frames = [await state.frame() for _ in range(24)]
        writes = wire.out("state")
        for _, chunk in writes:
            (length,) = struct.unpack_from(order + "i", chunk, 0)
            assert len(chunk) == 4 + length, f"a write of {len(chunk)} bytes holds more than one message"
        kinds = [f.msg_type for f in frames]
        start = kinds.index(ROUND[profile][0])
        assert kinds[start : start + len(ROUND[profile])] == ROUND[profile]
