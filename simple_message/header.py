"""Header validation: the rules of the C++ library's ``SimpleMessage::validateMessage``.

Decoding never applies these rules (a capture must decode whatever was on the wire); servers and
clients apply them explicitly. The rules (docs/reference/protocol.md §1.2):

* ``msg_type`` 0 is invalid;
* ``comm_type`` 0 is invalid;
* a SERVICE_REPLY must carry SUCCESS or FAILURE, not INVALID;
* a TOPIC or SERVICE_REQUEST must carry reply_code INVALID ("unused").

Unknown comm_type values such as 4 pass, as in the C++ library.
"""

from __future__ import annotations

from .constants import CommType, MsgType, ReplyCode
from .errors import HeaderError
from .messages import Message

__all__ = ["header_error", "validate_header"]


def header_error(msg_type: int, comm_type: int, reply_code: int) -> HeaderError | None:
    """The :class:`~.errors.HeaderError` these header fields earn, or ``None`` if they are valid."""
    problem: str | None = None
    if msg_type == MsgType.INVALID:
        problem = "msg_type 0 (INVALID)"
    elif comm_type == CommType.INVALID:
        problem = "comm_type 0 (INVALID)"
    elif comm_type == CommType.SERVICE_REPLY:
        if reply_code == ReplyCode.INVALID:
            problem = "a SERVICE_REPLY with reply_code INVALID"
    elif reply_code != ReplyCode.INVALID:
        problem = f"reply_code {reply_code} on a message that is not a SERVICE_REPLY"
    if problem is None:
        return None
    return HeaderError(
        f"invalid header ({problem}): msg_type={msg_type} comm_type={comm_type} reply_code={reply_code}",
        msg_type=msg_type,
        comm_type=comm_type,
        reply_code=reply_code,
    )


def validate_header(msg: Message) -> None:
    """Raise :class:`~.errors.HeaderError` if ``msg``'s header breaks the C++ validation rules."""
    error = header_error(msg.msg_type, msg.comm_type, msg.reply_code)
    if error is not None:
        raise error
