"""simple_message traffic in pcap and pcapng captures: read (TCP reassembled, frames decoded) and
recorded.

:func:`read_capture` gives a capture's TCP segments; :func:`captured_messages` reassembles each
direction of each connection and decodes its byte stream with the project's
:class:`~simple_message.framing.FrameDecoder`, giving :class:`CapturedMessage` items and
:class:`CaptureEvent` items for what could not be decoded. ``simple-message decode CAPTURE`` prints
them. :class:`CaptureWriter` records a program's own traffic as a pcapng file.

The layers, each importing only those before it:

* :mod:`.formats`: pcap and pcapng files read into TCP segments (:class:`TcpSegment`); it knows
  nothing of simple_message;
* :mod:`.reassembly`: each direction's bytes put in order, what the capture lost reported as
  :class:`CaptureEvent` items;
* :mod:`.messages`: the bytes cut into frames and decoded (:func:`captured_messages`);
* :mod:`.writer`: the other way, a program's traffic written as a capture (:class:`CaptureWriter`).
"""

from __future__ import annotations

from .formats import LINK_TYPES, Address, TcpSegment, capture_format, format_address
from .messages import CapturedMessage, CaptureError, CaptureReader, captured_messages, read_capture
from .reassembly import DEFAULT_REORDER_LIMIT, CaptureEvent, EventKind
from .writer import DEFAULT_FILES, DEFAULT_MAX_BYTES, MAX_SEGMENT, CaptureWriter, rotated_name

#: the former name of :class:`TcpSegment` (a motion ``Segment`` exists elsewhere)
Segment = TcpSegment

__all__ = [
    "DEFAULT_FILES",
    "DEFAULT_MAX_BYTES",
    "DEFAULT_REORDER_LIMIT",
    "LINK_TYPES",
    "MAX_SEGMENT",
    "Address",
    "CaptureError",
    "CaptureEvent",
    "CaptureReader",
    "CaptureWriter",
    "CapturedMessage",
    "EventKind",
    "TcpSegment",
    "capture_format",
    "captured_messages",
    "format_address",
    "read_capture",
    "rotated_name",
]
