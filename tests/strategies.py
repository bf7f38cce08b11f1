"""Hypothesis strategies: random messages of every type, valid in a given wire format."""

from __future__ import annotations

from typing import Any

from hypothesis import strategies as st

from simple_message import (
    CommType,
    DhLink,
    DummyReply,
    ExGroup,
    GetDhParameters,
    GetDhParametersReply,
    GetVersion,
    HeaderOnly,
    JointFeedbackEx,
    JointTraj,
    JointTrajPtFullEx,
    Message,
    Ping,
    RawMessage,
    TrajPoint,
    WireFormat,
    decode,
    encode,
)
from simple_message.messages import MESSAGE_CLASSES

INT32 = st.integers(-(2**31), 2**31 - 1)
UINT32 = st.integers(0, 2**32 - 1)


def reals(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[float]:
    if wire.real_size == 4:
        return st.floats(width=32, allow_nan=allow_nan)
    return st.floats(allow_nan=allow_nan)


def arrays(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[list[float]]:
    return st.lists(reals(wire, allow_nan), min_size=0, max_size=10)


def comm_for(cls: type[Message]) -> st.SearchStrategy[int]:
    """comm_type values for which decode picks ``cls`` for its msg_type."""
    request, reply = MESSAGE_CLASSES[cls.MSG_TYPE]
    if request is reply:
        return INT32
    if cls is reply:
        return st.just(int(CommType.SERVICE_REPLY))
    return INT32.filter(lambda c: c != CommType.SERVICE_REPLY)


def _field(code: str, wire: WireFormat, allow_nan: bool) -> st.SearchStrategy[Any]:
    if code == "i":
        return INT32
    if code == "I":
        return UINT32
    if code == "r":
        return reals(wire, allow_nan)
    return arrays(wire, allow_nan)


def ex_groups(wire: WireFormat, allow_nan: bool, count: int) -> st.SearchStrategy[list[ExGroup]]:
    group = st.builds(
        ExGroup,
        INT32,
        INT32,
        reals(wire, allow_nan),
        arrays(wire, allow_nan),
        arrays(wire, allow_nan),
        arrays(wire, allow_nan),
    )
    return st.lists(group, min_size=count, max_size=count)


@st.composite
def _full_ex(draw: st.DrawFn, wire: WireFormat, allow_nan: bool) -> JointTrajPtFullEx:
    count = draw(st.integers(0, 4))
    groups = draw(ex_groups(wire, allow_nan, count))
    n = draw(INT32) if count == 4 else count  # short form: n == len(groups); full form: 4 groups, any n
    return JointTrajPtFullEx(
        n, draw(INT32), groups, comm_type=draw(comm_for(JointTrajPtFullEx)), reply_code=draw(INT32)
    )


@st.composite
def _dh_reply(draw: st.DrawFn, wire: WireFormat, allow_nan: bool) -> GetDhParametersReply:
    axes = draw(st.integers(1, 8))
    link = st.builds(
        DhLink, reals(wire, allow_nan), reals(wire, allow_nan), reals(wire, allow_nan), reals(wire, allow_nan)
    )
    groups = draw(st.lists(st.lists(link, min_size=axes, max_size=axes), min_size=4, max_size=4))
    return GetDhParametersReply(groups, comm_type=CommType.SERVICE_REPLY, reply_code=draw(INT32))


def _decodes_as(msg: Message, wire: WireFormat, cls: type[Message]) -> bool:
    try:
        return type(decode(encode(msg, wire), wire)) is cls
    except Exception:
        return False


def messages(wire: WireFormat, allow_nan: bool = False) -> st.SearchStrategy[Message]:
    """Any message of any type that round-trips in ``wire``."""
    options: list[st.SearchStrategy[Message]] = []
    for request, reply in set(MESSAGE_CLASSES.values()):
        for cls in {request, reply}:
            if cls.LAYOUT:
                kwargs = {name: _field(code, wire, allow_nan) for name, code in cls.LAYOUT}
                options.append(st.builds(cls, comm_type=comm_for(cls), reply_code=INT32, **kwargs))
    options.append(st.builds(Ping, st.none() | st.lists(INT32, max_size=10), comm_type=INT32, reply_code=INT32))
    options.append(st.builds(GetVersion, comm_type=comm_for(GetVersion), reply_code=INT32))
    options.append(st.builds(GetDhParameters, comm_type=comm_for(GetDhParameters), reply_code=INT32))
    point = st.builds(TrajPoint, INT32, arrays(wire, allow_nan), reals(wire, allow_nan), reals(wire, allow_nan))
    options.append(st.builds(JointTraj, st.lists(point, max_size=5), comm_type=INT32, reply_code=INT32))
    options.append(_full_ex(wire, allow_nan))
    options.append(
        st.builds(
            JointFeedbackEx,
            INT32,
            st.integers(0, 4).flatmap(lambda n: ex_groups(wire, allow_nan, n)),
            comm_type=INT32,
            reply_code=INT32,
        )
    )
    options.append(_dh_reply(wire, allow_nan))
    unknown = INT32.filter(lambda t: t not in MESSAGE_CLASSES)
    options.append(st.builds(RawMessage, unknown, st.binary(max_size=120), comm_type=INT32, reply_code=INT32))
    header_only_types = [
        (t, c) for t in MESSAGE_CLASSES for c in (1, 2, 3) if _decodes_as(HeaderOnly(t, comm_type=c), wire, HeaderOnly)
    ]
    options.append(
        st.sampled_from(header_only_types).flatmap(
            lambda tc: st.builds(HeaderOnly, st.just(tc[0]), comm_type=st.just(tc[1]), reply_code=INT32)
        )
    )
    dummy_types = [t for t in MESSAGE_CLASSES if _decodes_as(DummyReply(t), wire, DummyReply)]
    options.append(st.builds(DummyReply, st.sampled_from(dummy_types), arrays(wire, allow_nan), reply_code=INT32))
    return st.one_of(options)
