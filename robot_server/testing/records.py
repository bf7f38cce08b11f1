"""The servo ticks a test reads: a still copy of a running controller's record, and a
``robot-server --record FILE.npz`` read back.

A controller's :class:`~robot_server.control.Recorder` grows while it runs (on another thread, in a
sync test). A test reads a copy (:func:`snapshot`) that holds what was recorded when it was
taken, so its time and its positions are the same ticks however long the reading takes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..control import Recorder
from ..control.recorder import QUANTITIES

__all__ = ["read_npz", "snapshot"]


def _filled(dof: int, decimation: int, dropped: int, columns: dict[str, np.ndarray]) -> Recorder:
    """A recorder holding the given columns (oldest first; ``time`` the controller's clock,
    one ``(ticks, dof)`` array per quantity, ``points``, ``tool``), as if it had recorded them."""
    ticks = len(columns["time"])
    copy = Recorder(dof, capacity=max(1, ticks), decimation=decimation)
    if ticks:
        # the ring's rows placed so that its oldest one is where dropped ticks would have left it
        shift = dropped % ticks
        copy._time[:] = np.roll(columns["time"], shift)
        for index, quantity in enumerate(QUANTITIES):
            copy._data[:, index, :] = np.roll(columns[quantity], shift, axis=0)
        copy._points[:] = np.roll(columns["points"], shift)
        copy._tool[:] = np.roll(columns["tool"], shift, axis=0)
    copy._count = ticks + dropped
    copy._seen = (ticks + dropped) * decimation
    return copy


def snapshot(recorder: Recorder) -> Recorder:
    """A copy of ``recorder`` that no longer grows: the same ticks, the same ``dropped``."""
    columns: dict[str, np.ndarray] = {"time": recorder.time(), "points": recorder.points(), "tool": recorder.tool()}
    for quantity in QUANTITIES:
        columns[quantity] = recorder.get(quantity)
    return _filled(recorder.dof, recorder.decimation, recorder.dropped, columns)


def read_npz(path: str | Path, joint_names: Sequence[str]) -> Recorder:
    """The record ``robot-server --record FILE.npz`` wrote (:meth:`Recorder.to_npz`) as a
    :class:`Recorder` (its ``time`` the controller's clock, as a live one's)."""
    dof = len(joint_names)
    header = Recorder(dof).header(joint_names)
    with np.load(path, allow_pickle=False) as archive:
        data = {name: archive[name] for name in header}
    at = 1
    per_quantity: dict[str, np.ndarray] = {}
    # the header's order: actual position, velocity, acceleration, then the command's, then the error
    order = (
        "actual_position",
        "actual_velocity",
        "actual_acceleration",
        "command_position",
        "command_velocity",
        "command_acceleration",
        "following_error",
    )
    for quantity in order:
        names = header[at : at + dof]
        per_quantity[quantity] = np.stack([data[n] for n in names], axis=1) if names else np.zeros((0, dof))
        at += dof
    times = data[header[at]]
    points = data[header[at + 1]]
    tool = np.stack([data[n] for n in header[at + 2 :]], axis=1)
    return _filled(dof, 1, 0, {"time": times, "points": points, "tool": tool, **per_quantity})
