"""The old home of :class:`~simple_message.capture.CaptureWriter` (now ``simple_message.capture.writer``):
kept so that ``from simple_message.capture_writer import CaptureWriter`` goes on working."""

from __future__ import annotations

from .capture.writer import DEFAULT_FILES, DEFAULT_MAX_BYTES, MAX_SEGMENT, CaptureWriter, rotated_name

__all__ = ["CaptureWriter", "DEFAULT_FILES", "DEFAULT_MAX_BYTES", "MAX_SEGMENT", "rotated_name"]
