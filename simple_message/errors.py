"""Typed errors of the protocol core.

As in h11, every error says whose fault it is:

* :class:`LocalProtocolError`: *we* tried to build or send something the protocol does not allow
  (a joint array longer than 10, a sequence that does not fit an int32, ...). Fix the caller.
* :class:`RemoteProtocolError`: the *peer* sent something we cannot accept. It carries the reply a
  server should answer with where one applies (:attr:`RemoteProtocolError.reply_code`, and for
  MotoROS peers :attr:`RemoteProtocolError.moto_result` / :attr:`RemoteProtocolError.moto_subcode`).

  - :class:`FrameError`: the byte stream itself is broken (a length prefix below 12, negative or
    above the maximum). Framing is by byte count only (docs/reference/protocol.md §1.1), so the stream
    cannot be resynchronised: the connection must be closed. :attr:`FrameError.fatal` is ``True``.
  - :class:`IncompleteFrame`: a frame was begun and its remaining bytes never came (a server's
    ``frame_timeout``); the connection is closed.
  - :class:`MalformedMessage`: one frame was delimited correctly but its body does not fit the
    layout of its message type. The frame's bytes are consumed and the stream stays aligned, so the
    connection can go on; a server answers a SERVICE_REQUEST with FAILURE.
  - :class:`HeaderError`: the header breaks the validation rules of the C++ library (§1.2).
"""

from __future__ import annotations

from .constants import InvalidSubcode, MotoResult, ReplyCode

__all__ = [
    "SimpleMessageError",
    "LocalProtocolError",
    "RemoteProtocolError",
    "FrameError",
    "IncompleteFrame",
    "MalformedMessage",
    "HeaderError",
    "ConnectionClosed",
    "NotConnected",
    "RequestTimeout",
    "RequestFailed",
    "UnexpectedReply",
]


class SimpleMessageError(Exception):
    """Base class of every error raised by the ``simple_message`` package."""


class LocalProtocolError(SimpleMessageError, ValueError):
    """We tried to build or send something invalid. Nothing was sent."""


class RemoteProtocolError(SimpleMessageError):
    """The peer sent something invalid.

    ``reply_code`` is what a server answers a SERVICE_REQUEST with (``None`` when no reply applies,
    e.g. the frame could not even be delimited); ``moto_result`` and ``moto_subcode`` are the
    MOTO_MOTION_REPLY equivalents used by MotoROS-style servers.
    """

    #: Whether the connection must be closed because the stream cannot be realigned.
    fatal: bool = False

    def __init__(
        self,
        message: str,
        *,
        reply_code: ReplyCode | None = ReplyCode.FAILURE,
        moto_result: MotoResult = MotoResult.INVALID,
        moto_subcode: int = InvalidSubcode.UNSPECIFIED,
        msg_type: int | None = None,
        comm_type: int | None = None,
    ) -> None:
        super().__init__(message)
        self.reply_code = reply_code
        self.moto_result = moto_result
        self.moto_subcode = moto_subcode
        #: Header fields of the offending frame, when they could be read.
        self.msg_type = msg_type
        self.comm_type = comm_type


class FrameError(RemoteProtocolError):
    """The length prefix is impossible; the connection must be closed (docs/reference/protocol.md §12 test 4)."""

    fatal = True

    def __init__(self, message: str, *, length: int | None = None) -> None:
        super().__init__(
            message,
            reply_code=None,
            moto_result=MotoResult.INVALID,
            moto_subcode=InvalidSubcode.MSGSIZE,
        )
        #: The offending length prefix, if one was read.
        self.length = length


class IncompleteFrame(FrameError):
    """The peer began a frame and sent nothing more for the allowed time: a half-sent message
    would otherwise hold its connection (and a server's place) for ever. The connection is closed."""

    def __init__(self, buffered: int, timeout: float) -> None:
        super().__init__(f"an incomplete frame ({buffered} bytes) and nothing more for {timeout:g} s")
        #: Bytes of the incomplete frame that had arrived.
        self.buffered = buffered
        self.timeout = timeout


class MalformedMessage(RemoteProtocolError):
    """A correctly delimited frame whose body does not match its type's layout (non-fatal)."""

    def __init__(self, message: str, *, msg_type: int, comm_type: int, frame: bytes) -> None:
        super().__init__(
            message,
            reply_code=ReplyCode.FAILURE,
            moto_result=MotoResult.INVALID,
            moto_subcode=InvalidSubcode.MSGSIZE,
            msg_type=msg_type,
            comm_type=comm_type,
        )
        #: The whole frame, prefix included, for logging.
        self.frame = frame


class HeaderError(RemoteProtocolError):
    """The header fails the C++ library's ``validateMessage`` rules (docs/reference/protocol.md §1.2)."""

    def __init__(self, message: str, *, msg_type: int, comm_type: int, reply_code: int) -> None:
        super().__init__(
            message,
            reply_code=ReplyCode.FAILURE,
            moto_result=MotoResult.INVALID,
            moto_subcode=InvalidSubcode.MSGHEADER,
            msg_type=msg_type,
            comm_type=comm_type,
        )
        #: The header's reply_code as received (named apart from the reply we would send).
        self.received_reply_code = reply_code


# -- errors of the asyncio layer (simple_message.connection, .endpoints) -------------------------


class ConnectionClosed(SimpleMessageError, ConnectionError):
    """The connection is closed or was lost; a pending request gets this at once, never a hang."""


class NotConnected(ConnectionClosed):
    """A client is between connections (connecting or reconnecting). Nothing was sent or queued."""


class RequestTimeout(SimpleMessageError, TimeoutError):
    """No reply arrived in time. The request was sent once and is never re-sent silently."""


class RequestFailed(SimpleMessageError):
    """The peer answered the request with reply_code FAILURE."""

    def __init__(self, message: str, reply: object) -> None:
        super().__init__(message)
        #: The FAILURE reply as received.
        self.reply = reply


class UnexpectedReply(RemoteProtocolError):
    """A SERVICE_REPLY that cannot answer the pending request: another message type, reply_code
    INVALID, or a body that fits no layout."""

    def __init__(self, message: str, reply: object = None) -> None:
        super().__init__(message, reply_code=None)
        #: The reply as received (a message, or ``None`` if it could not be decoded).
        self.reply = reply
