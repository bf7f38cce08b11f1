"""What the abb, fanuc and staubli profiles' ports share: one client each (a second waits in the
backlog), state ports that never read, reads that wait for their rest as long as the connection
lasts. The rules, with the controllers' file:line, are in docs/vendors.md."""

from __future__ import annotations

import pytest

from tests.rawpeer import joint_traj_pt, vectors
from tests.stepped import step
from tests.vendor import connect, until, vendor_emulator, written

VENDORS = ("abb", "fanuc", "staubli")
ORDER = {"abb": "<", "fanuc": ">", "staubli": "<"}


@pytest.mark.parametrize("profile", VENDORS)
async def test_the_state_port_reads_nothing_a_ping_gets_no_reply_and_the_stream_goes_on(profile: str) -> None:
    order = ORDER[profile]
    async with vendor_emulator(profile) as (emu, clock, _wire):
        state = await connect(emu, "state", order)
        await state.send(vectors(order)["PING_REQUEST"] * 3 + b"\xff" * 100)  # PINGs, then rubbish
        await step(clock, 1.2)  # the Staubli state client's first second
        frames = [await state.frame() for _ in range(12)]
        assert all(f.comm_type == 1 for f in frames)  # the state topics only: no reply
        assert {f.msg_type for f in frames} <= {10, 13}
        (session,) = emu.state_server.sessions
        assert session.connection.link.buffered == 0  # dropped, not held
        assert not session.connection.closed


@pytest.mark.parametrize("profile", VENDORS)
async def test_a_read_begun_waits_for_its_rest_unless_lenient(profile: str) -> None:
    async with vendor_emulator(profile) as (emu, _clock, _wire):
        motion = await connect(emu, "motion", ORDER[profile])
        await motion.send(b"\x00\x00")  # half a length prefix
        await step(_clock, 0.1)
        (session,) = emu.motion_server.sessions
        assert session.connection.frame_timeout is None  # the controller waits for ever
    async with vendor_emulator(profile, lenient=True) as (emu, _clock, _wire):
        motion = await connect(emu, "motion", ORDER[profile])
        await step(_clock, 0.1)
        (session,) = emu.motion_server.sessions
        assert session.connection.frame_timeout == emu.config.frame_timeout


@pytest.mark.parametrize("profile", ["fanuc", "staubli"])
async def test_one_motion_client_a_second_waits_unanswered_and_is_served_when_the_first_goes(profile: str) -> None:
    order = ORDER[profile]
    request = joint_traj_pt(vectors(order)["JOINT_TRAJ_PT_REQUEST_SEQ3"], 0, [0.0] * 6, 0.5, 0.1, order=order)
    async with vendor_emulator(profile) as (emu, clock, wire):
        first = await connect(emu, "motion", order)
        second = await connect(emu, "motion", order)
        await second.send(request)
        await step(clock, 0.5)
        assert written(wire, "motion", order) == []  # in the backlog: not read, not answered
        await first.close()
        await until(clock, lambda: len(written(wire, "motion", order)) == 1, what="the second client's reply")
        reply = await second.frame()
        assert reply.comm_type == 3 and reply.ints(1)[0] == 0  # its point's sequence, answered
