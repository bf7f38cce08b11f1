"""The servo ticks a test reads: a still copy of a running controller's record, and a
``robot-server --record FILE.npz`` read back.

A controller's :class:`~robot_server.control.Recorder` grows while it runs (on another thread, in a
sync test). A test reads a copy (:func:`snapshot`) that holds what was recorded when it was
taken, so its time and its positions are the same ticks however long the reading takes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..control import Recorder

__all__ = ["read_npz", "snapshot"]


def snapshot(recorder: Recorder) -> Recorder:
    """A copy of ``recorder`` that no longer grows: the same ticks, the same ``dropped``."""
    return recorder.copy()


def read_npz(path: str | Path, joint_names: Sequence[str]) -> Recorder:
    """The record ``robot-server --record FILE.npz`` wrote (:meth:`Recorder.to_npz`) as a
    :class:`Recorder` (its ``time`` the controller's clock, as a live one's)."""
    return Recorder.from_npz(path, joint_names)
