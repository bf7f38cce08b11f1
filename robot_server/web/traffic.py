"""The web view's traffic list: the last frames of every connection, cut from a tap and decoded on
demand.

:class:`TrafficTap` is a :class:`~simple_message.connection.Tap` on every server of the emulator.
It cuts each direction of each connection into frames (the byte order detected per direction, as a
dissector does) and keeps the newest ``capacity`` in a ring, numbered from 1; nothing is decoded
until a page asks (:meth:`TrafficTap.since`), and each frame's JSON is made once however many pages
show it. A direction whose bytes cannot be framed (a bad length prefix) adds one entry saying so and
is not read further, like the connection itself, which the server closes.
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import dataclass, field

from simple_message.connection import TapLink
from simple_message.errors import FrameError
from simple_message.framing import FrameDecoder, decode_or_error
from simple_message.jsonio import message_to_json
from simple_message.messages import Message, type_name
from simple_message.wire import ByteOrder, WireFormat

__all__ = ["TrafficTap", "summary", "link_port", "link_peer"]

#: frames kept (the page's list shows as many)
DEFAULT_CAPACITY = 200
#: the longest body summary sent (characters)
SUMMARY_LENGTH = 160
#: distinct frames whose decoding is remembered
CACHE_SIZE = 1024
_UNKNOWN: dict[str, object] = {"msg_type": None, "name": None, "comm": None, "reply": None, "summary": ""}


@dataclass(eq=False)
class _Entry:
    n: int
    time_ns: int
    link: TapLink
    incoming: bool
    frame: bytes
    order: ByteOrder | None
    #: why the direction stopped being framed (then ``frame`` is empty)
    error: str = ""
    json: str = field(default="", repr=False)


class TrafficTap:
    """Keeps the last ``capacity`` frames of every connection (see the module doc); ``real_size``:
    the float size the frames are decoded with (the emulator's)."""

    def __init__(self, real_size: int = 4, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"the traffic list holds at least 1 frame, not {capacity}")
        self.real_size = real_size
        self._ring: deque[_Entry] = deque(maxlen=capacity)
        self._decoders: dict[tuple[TapLink, bool], FrameDecoder] = {}
        self._cache: dict[tuple[bytes, ByteOrder | None], dict[str, object]] = {}
        #: frames seen so far (the number of the newest)
        self.count = 0

    # -- the Tap protocol ------------------------------------------------------------------------

    def opened(self, link: TapLink, time_ns: int) -> None:
        for incoming in (True, False):
            self._decoders[(link, incoming)] = FrameDecoder(None)

    def data(self, link: TapLink, outgoing: bool, data: bytes, time_ns: int) -> None:
        key = (link, not outgoing)
        decoder = self._decoders.get(key)
        if decoder is None:
            return  # a direction that failed to frame: no longer read
        try:
            decoder.feed(data)
            while (frame := decoder.next_frame()) is not None:
                self._add(_Entry(0, time_ns, link, not outgoing, frame, decoder.byte_order))
        except FrameError as exc:
            del self._decoders[key]
            self._add(_Entry(0, time_ns, link, not outgoing, b"", None, error=str(exc)))

    def closed(self, link: TapLink, by_peer: bool, time_ns: int) -> None:
        for incoming in (True, False):
            self._decoders.pop((link, incoming), None)

    # -- reading ---------------------------------------------------------------------------------

    def _add(self, entry: _Entry) -> None:
        self.count += 1
        entry.n = self.count
        self._ring.append(entry)

    @property
    def first(self) -> int:
        """The number of the oldest frame kept (``count + 1`` when none is)."""
        return self._ring[0].n if self._ring else self.count + 1

    def since(self, n: int) -> list[str]:
        """The JSON objects (text) of the frames numbered ``n`` and later that are still kept,
        oldest first."""
        skip = max(0, n - self.first)
        ring = self._ring
        return [self._json(ring[i]) for i in range(skip, len(ring))]

    def _json(self, entry: _Entry) -> str:
        if not entry.json:
            out: dict[str, object] = {
                "n": entry.n,
                "time": entry.time_ns / 1e9,
                "port": link_port(entry.link),
                "peer": link_peer(entry.link),
                "dir": "in" if entry.incoming else "out",
            }
            out.update(self._decoded(entry))
            entry.json = json.dumps(out, separators=(",", ":"))
        return entry.json

    def _decoded(self, entry: _Entry) -> dict[str, object]:
        """Type, comm, reply and summary of a frame, decoded once per distinct frame: the state
        topics go to every state client in the same bytes, and are decoded once a round."""
        if entry.error:
            return {**_UNKNOWN, "name": "UNFRAMEABLE", "summary": f"not read further: {entry.error}"[:SUMMARY_LENGTH]}
        key = (entry.frame, entry.order)
        known = self._cache.get(key)
        if known is not None:
            return known
        wire = WireFormat(entry.order or ByteOrder.LITTLE, self.real_size)
        msg = decode_or_error(entry.frame, wire)
        if isinstance(msg, Message):
            obj = message_to_json(msg, self.real_size)
            names = obj.get("names", {})
            known = {
                "msg_type": obj["msg_type"],
                "name": obj["name"],
                "comm": names.get("comm_type", str(obj["comm_type"])),
                "reply": names.get("reply_code", str(obj["reply_code"])),
                "summary": summary(obj["body"]),
            }
        else:  # a body that does not decode: the header did
            kind = msg.msg_type
            name = None if kind is None else type_name(kind)
            known = {**_UNKNOWN, "msg_type": kind, "name": name, "summary": f"malformed: {msg}"[:SUMMARY_LENGTH]}
        if len(self._cache) >= CACHE_SIZE:
            self._cache.clear()
        self._cache[key] = known
        return known


def link_port(link: TapLink) -> str:
    """The server a connection came to (``motion``, ``state``, ``io``): the first word of its name."""
    return link.name.split(" ", 1)[0]


def link_peer(link: TapLink) -> str:
    """``host:port`` of the peer, or what names a serial port or pty (its link's name after the role)."""
    if link.peer is None:
        return link.name.split(" ", 1)[-1]
    host, port = link.peer[0], link.peer[1]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def summary(body: object, limit: int = SUMMARY_LENGTH) -> str:
    """A one-line summary of a decoded body (``message_to_json``'s): ``key=value`` pairs, numbers
    short, the unused zero slots at the end of joint arrays left out (``…``), cut at ``limit``."""
    text = _pairs(body) if isinstance(body, dict) else _short(body)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _pairs(body: dict[object, object]) -> str:
    return " ".join(f"{k}={_short(v)}" for k, v in body.items())


def _short(value: object) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else str(value)
    if isinstance(value, int | str):
        return str(value)
    if isinstance(value, list):
        items = list(value)
        end = len(items)
        while end > 1 and items[end - 1] in (0, 0.0):
            end -= 1
        shown = ", ".join(_short(v) for v in items[:end])
        return f"[{shown}{', …' if end < len(items) else ''}]"
    if isinstance(value, dict):
        return "{" + _pairs(value) + "}"
    return str(value)
