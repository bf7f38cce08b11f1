"""Header validation mirrors the C++ library's validateMessage (docs/reference/protocol.md §1.2, §12 test 3)."""

from __future__ import annotations

import pytest

from simple_message import (
    HeaderError,
    HeaderOnly,
    JointTrajPt,
    Ping,
    RawMessage,
    header_error,
    validate_header,
)


@pytest.mark.parametrize(
    ("msg_type", "comm", "reply"),
    [(0, 2, 0), (1, 0, 0), (1, 3, 0), (1, 2, 1), (1, 2, 2), (1, 1, 1), (11, 1, 2)],
)
def test_rejected_headers(msg_type: int, comm: int, reply: int) -> None:
    error = header_error(msg_type, comm, reply)
    assert isinstance(error, HeaderError)
    assert error.msg_type == msg_type and error.received_reply_code == reply
    assert error.reply_code == 2  # a server answers FAILURE
    with pytest.raises(HeaderError):
        validate_header(RawMessage(msg_type, comm_type=comm, reply_code=reply))


@pytest.mark.parametrize(
    "msg",
    [
        Ping(comm_type=1),
        Ping(comm_type=2),
        Ping(comm_type=3, reply_code=1),
        Ping(comm_type=3, reply_code=2),
        JointTrajPt(),
        HeaderOnly(11, reply_code=1),
        RawMessage(1234, comm_type=4),  # unknown comm types pass, as in the C++ library
    ],
)
def test_accepted_headers(msg: object) -> None:
    validate_header(msg)  # type: ignore[arg-type]
    assert header_error(msg.msg_type, msg.comm_type, msg.reply_code) is None  # type: ignore[attr-defined]
