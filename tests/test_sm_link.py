"""The sans-I/O link: request/reply rules tested synchronously, through a pair of links."""

from __future__ import annotations

import pytest

from simple_message import BE32, LE32, CommType, JointPosition, JointTrajPt, MsgType, Ping, ReplyCode
from simple_message.dialects import ABB, DIALECTS, FANUC, GENERIC, MOTOROS, Dialect, ReplyStyle, dialect, register
from simple_message.errors import FrameError, LocalProtocolError
from simple_message.link import (
    NEED_DATA,
    Answered,
    Ended,
    Event,
    LateReply,
    Link,
    Malformed,
    Received,
    StrayReply,
    Unanswerable,
)
from simple_message.messages import HeaderOnly, Message, MotoMotionReply


def events(link: Link) -> list[Event]:
    out: list[Event] = []
    while (event := link.next_event()) is not NEED_DATA:
        assert not isinstance(event, type(NEED_DATA))
        out.append(event)
    return out


def reply(msg: Message, code: ReplyCode = ReplyCode.SUCCESS) -> Message:
    return msg.to_reply(code)


def short(msg: Message) -> bytes:
    """``msg``'s frame with the last 4 bytes of its body cut off: a body that does not decode."""
    frame = msg.encode(LE32)
    return (len(frame) - 8).to_bytes(4, "little") + frame[4:-4]


def test_a_request_and_its_reply_through_a_pair_of_links_in_any_chunking() -> None:
    client, server = Link(LE32), Link(autodetect=True)
    request, frame = client.send_request(JointTrajPt(3, (0.1,) * 10, velocity=0.5, duration=0.2))
    assert client.pending_requests == 1
    for i in range(len(frame)):  # one byte at a time
        server.receive_data(frame[i : i + 1])
    (received,) = events(server)
    assert isinstance(received, Received) and received.message.sequence == 3  # type: ignore[attr-defined]
    answer = server.send(reply(received.message))
    client.receive_data(answer)
    (answered,) = events(client)
    assert isinstance(answered, Answered) and answered.request is request
    assert answered.reply.reply_code == ReplyCode.SUCCESS
    assert client.pending_requests == 0
    assert client.next_event() is NEED_DATA


def test_an_abandoned_request_keeps_its_place_and_its_late_reply_is_consumed() -> None:
    client = Link(LE32)
    first, _ = client.send_request(JointTrajPt(0))
    second, _ = client.send_request(JointTrajPt(1))
    client.abandon(first)
    assert client.pending_requests == 1
    client.receive_data(reply(JointTrajPt(0)).encode(LE32) + reply(JointTrajPt(1)).encode(LE32))
    late, answered = events(client)
    assert isinstance(late, LateReply) and late.request is first
    assert isinstance(answered, Answered) and answered.request is second


def test_a_reply_that_never_came_does_not_shift_later_replies() -> None:
    client = Link(LE32, answers=GENERIC.answers)
    first, _ = client.send_request(Ping())
    second, _ = client.send_request(JointTrajPt(1))
    client.abandon(first)
    client.receive_data(reply(JointTrajPt(1)).encode(LE32))  # the PING's reply was lost
    (answered,) = events(client)
    assert isinstance(answered, Answered) and answered.request is second


def test_a_reply_of_another_type_ends_the_request_as_unanswerable_by_the_dialects_rule() -> None:
    moto = MotoMotionReply(0, 5, 0, 0, 0)  # MotoROS answers a JOINT_TRAJ_PT with it
    for rule, answers in ((MOTOROS.answers, True), (GENERIC.answers, False), (None, True)):
        client = Link(LE32) if rule is None else Link(LE32, answers=rule)
        request, _ = client.send_request(JointTrajPt(0))
        client.receive_data(moto.encode(LE32))
        (event,) = events(client)
        assert isinstance(event, Answered if answers else Unanswerable) and event.request is request
    # MotoROS echoes a PING (MotionServer.c): its MOTO_MOTION_REPLY cannot answer one, neither on a
    # MotoROS link nor on a link that does not know its peer (before the dialects, such a link took a
    # 2002 as the answer to any request, PING included: a deliberate change)
    for client in (Link(LE32, answers=MOTOROS.answers), Link(LE32)):
        client.send_request(Ping())
        client.receive_data(moto.encode(LE32))
        (event,) = events(client)
        assert isinstance(event, Unanswerable) and "MOTO_MOTION_REPLY" in event.describe()


def test_fanuc_acknowledges_a_point_with_a_joint_position_reply_and_abb_does_not() -> None:
    ack = JointPosition(7, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
    assert FANUC.answers(MsgType.JOINT_TRAJ_PT, ack)
    assert not ABB.answers(MsgType.JOINT_TRAJ_PT, ack)
    assert not FANUC.answers(MsgType.PING, ack)
    assert ABB.answers(MsgType.JOINT_TRAJ_PT, HeaderOnly(MsgType.JOINT_TRAJ_PT, comm_type=CommType.SERVICE_REPLY))


def test_malformed_bodies_stray_replies_and_the_end_of_the_stream_are_events() -> None:
    server = Link(LE32)
    server.receive_data(short(JointTrajPt(0)))
    (malformed,) = events(server)
    assert isinstance(malformed, Malformed) and malformed.error.msg_type == MsgType.JOINT_TRAJ_PT
    client = Link(LE32)
    request, _ = client.send_request(JointTrajPt(0))
    client.receive_data(short(reply(JointTrajPt(0))))
    (event,) = events(client)
    assert isinstance(event, Unanswerable) and event.request is request and event.error is not None
    client.receive_data(reply(Ping()).encode(LE32))
    (stray,) = events(client)
    assert isinstance(stray, StrayReply) and stray.reply is not None
    client.receive_data(b"")
    (ended,) = events(client)
    assert isinstance(ended, Ended) and ended.error is None and client.ended
    with pytest.raises(LocalProtocolError):
        client.receive_data(b"\x00")
    with pytest.raises(LocalProtocolError):
        client.send_request(Ping())


def test_frames_before_a_broken_length_prefix_are_delivered_then_the_link_ends() -> None:
    server = Link(LE32)
    server.receive_data(Ping().encode(LE32) + (-5).to_bytes(4, "little", signed=True) + bytes(12))
    received, ended = events(server)
    assert isinstance(received, Received) and received.message.msg_type == MsgType.PING
    assert isinstance(ended, Ended) and isinstance(ended.error, FrameError)


def test_close_hands_back_the_requests_still_waiting_not_the_abandoned_ones() -> None:
    client = Link(LE32)
    first, _ = client.send_request(Ping())
    second, _ = client.send_request(Ping())
    client.abandon(first)
    assert client.close() == [second]
    assert client.pending_requests == 0


def test_the_byte_order_is_detected_from_the_peers_first_frame_and_spoken_back() -> None:
    server = Link(LE32, autodetect=True)
    undetected = not server.detected
    server.receive_data(Ping().encode(BE32))
    (received,) = events(server)
    assert isinstance(received, Received)
    assert undetected and server.detected and server.wire == BE32
    assert server.send(reply(received.message)) == reply(Ping()).encode(BE32)
    fixed = Link(LE32)  # not autodetecting: the configured order stands
    fixed.receive_data(Ping().encode(LE32))
    assert fixed.wire == LE32


def test_identical_frames_in_one_read_each_mean_what_their_place_says() -> None:
    """Frames are cut and decoded in one pass per read: two identical frames in one read are two
    messages, and what a reply means still depends on what is pending when it comes."""
    server = Link(LE32, autodetect=True)
    server.receive_data(Ping().encode(BE32) * 2)  # a big-endian peer, detected from the first frame
    first, second = events(server)
    assert isinstance(first, Received) and isinstance(second, Received)
    assert first.message == second.message == Ping() and server.wire == BE32
    client = Link(LE32)
    ack = HeaderOnly(MsgType.JOINT_TRAJ_PT, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
    request, _ = client.send_request(JointTrajPt(0))
    client.receive_data(ack.encode(LE32) * 2)  # the same bytes: an answer, then a stray reply
    answered, stray = events(client)
    assert isinstance(answered, Answered) and answered.request is request and answered.reply == ack
    assert isinstance(stray, StrayReply) and stray.reply == ack


@pytest.mark.parametrize("autodetect", [False, True])
def test_a_link_that_hands_out_its_frames_means_the_same(autodetect: bool) -> None:
    """With ``on_frame`` set (frame logs, captures) the link cuts frames, then decodes them; without,
    it does both in one pass. Same events, in any chunking, up to and including a bad prefix."""
    ack = HeaderOnly(MsgType.JOINT_TRAJ_PT, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
    stream = b"".join(
        [
            JointTrajPt(1, (0.5,) * 10).encode(LE32),
            short(JointTrajPt(2)),  # a body that does not decode: Malformed
            ack.encode(LE32),  # answers the pending request
            ack.encode(LE32),  # stray
            short(JointTrajPt(3).to_reply()),  # a reply that does not decode: stray, with its error
            JointPosition(4).encode(LE32) * 3,
            (3).to_bytes(4, "little") + bytes(12),  # a bad length prefix: the end
        ]
    )
    outcomes = []
    for logged in (False, True):
        for chunk in (len(stream), 7, 1):
            link = Link(LE32, autodetect=autodetect)
            frames: list[bytes] = []
            if logged:
                link.on_frame = frames.append
            link.send_request(JointTrajPt(0))
            for i in range(0, len(stream), chunk):
                if link.ended:  # at the bad prefix: what follows it is never fed
                    break
                link.receive_data(stream[i : i + chunk])
            got = events(link)
            assert [type(e) for e in got] == [
                Received,
                Malformed,
                Answered,
                StrayReply,
                StrayReply,
                Received,
                Received,
                Received,
                Ended,
            ]
            assert isinstance(got[-1], Ended) and isinstance(got[-1].error, FrameError)
            assert len(frames) == (8 if logged else 0)
            outcomes.append([repr(e) for e in got])
    assert all(o == outcomes[0] for o in outcomes)


def test_only_requests_are_sent_as_requests() -> None:
    with pytest.raises(LocalProtocolError):
        Link().send_request(JointPosition(0))


def test_the_dialects_are_registered_data_and_a_new_one_is_one_value() -> None:
    assert {"generic", "abb", "fanuc", "motoros"} <= set(DIALECTS)
    assert dialect("motoros").ports == {"motion": 50240, "state": 50241, "io": 50242}
    assert FANUC.wire == BE32 and GENERIC.reply_style is ReplyStyle.ECHO
    with pytest.raises(KeyError, match="known: abb, fanuc, generic, motoros"):
        dialect("kuka")
    with pytest.raises(ValueError, match="already registered"):
        register(Dialect(**{**vars(GENERIC), "description": "another generic"}))
    assert register(GENERIC) is GENERIC  # the same value again is harmless (a module imported twice)
    acme = Dialect(
        name="acme",
        description="a made-up vendor whose motion server answers points with a STATUS reply",
        motion_port=12000,
        state_port=12001,
        io_port=None,
        wire=LE32,
        reply_style=ReplyStyle.HEADER_ONLY,
        replies={MsgType.JOINT_TRAJ_PT: frozenset({MsgType.STATUS})},
    )
    status_reply = HeaderOnly(MsgType.STATUS, comm_type=CommType.SERVICE_REPLY, reply_code=ReplyCode.SUCCESS)
    unknown_peer = Link(LE32)
    unknown_peer.send_request(JointTrajPt(0))
    unknown_peer.receive_data(status_reply.encode(LE32))
    assert isinstance(events(unknown_peer)[0], Unanswerable)
    register(acme)
    try:
        # a link that does not know its peer now accepts what the new dialect sends too
        unknown_peer = Link(LE32)
        unknown_peer.send_request(JointTrajPt(0))
        unknown_peer.receive_data(status_reply.encode(LE32))
        assert isinstance(events(unknown_peer)[0], Answered)
        assert dialect("acme").ports == {"motion": 12000, "state": 12001}
    finally:
        del DIALECTS["acme"]


def test_on_frame_set_while_a_backlog_waits_sees_every_later_frame_in_order() -> None:
    # a frame log switched on mid-stream: what waits undecoded goes through it, before new bytes
    frames = [JointTrajPt(i, comm_type=CommType.TOPIC).encode(LE32) for i in range(3010)]
    link = Link(LE32)
    link.receive_data(b"".join(frames[:3000]))  # far more than one decoding slice
    first = link.next_event()
    seen: list[bytes] = []
    link.on_frame = seen.append
    link.receive_data(b"".join(frames[3000:]))
    got = [first, *events(link)]
    assert [e.message.sequence for e in got if isinstance(e, Received)] == list(range(3010))  # type: ignore[attr-defined]
    assert len(got) == 3010
    assert len(seen) > 10 and seen == frames[-len(seen) :]  # every frame decoded from then on, in order
