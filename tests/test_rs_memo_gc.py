"""What the planning's checks keep in a queued segment's memo leaves the cyclic collector's scans
after one collection (issue 38: the collector's pauses of a streaming fleet)."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from robot_server.control import checks
from robot_server.control.blend import OVERSHOOT
from robot_server.control.entries import Entry, Settings, connect, overshoots
from robot_server.control.points import Limits, State
from robot_server.control.policies import Blend
from robot_server.control.segments import Chain, Segment, launch

DOF = 6


@pytest.mark.parametrize("shape", ["quintic", "launch"])
def test_a_checked_segment_keeps_nothing_the_collector_scans_but_its_own_memo(shape: str) -> None:
    """What the checks keep in a queued segment's memo leaves the cyclic collector's scans after one
    collection (tuples of floats; the keys naming settings are the settings' own, shared by every
    segment): a fleet keeps hundreds of segments queued, and every object of theirs the collector
    must scan lengthens its pauses, which a control period must wait out."""
    limits = Limits(np.full(DOF, -3.0), np.full(DOF, 3.0), np.full(DOF, 2.0), np.full(DOF, 8.0), np.full(DOF, 80.0))
    settings = Settings(limits, Blend())
    start = State(np.array([0.1, -0.2, 0.3, 0.0, 0.5, -0.4]), np.full(DOF, 0.3), np.full(DOF, -1.0))
    end = State(start.position + 0.2, np.zeros(DOF), np.zeros(DOF))
    if shape == "quintic":
        segment: Segment | None = connect(start, 2, end, 2, 0.5)
    else:  # a Chain: from rest with the acceleration ramped up at the jerk limit, then a quintic
        start = State(start.position, np.zeros(DOF), np.zeros(DOF))
        end = State(start.position + 0.5, np.full(DOF, 1.0), np.zeros(DOF))
        segment = launch(start.position, (end.position, end.velocity, end.acceleration), 1.0, np.full(DOF, 80.0))
        assert isinstance(segment, Chain)
    assert segment is not None
    entry = Entry(None, start.position, 0.5, start, segment.duration, end=end, segment=segment)
    assert entry.segment is not None
    checks.excess(settings, entry)
    checks.within_positions(settings, entry)
    checks.end_need(settings, entry)
    checks.acceleration_ratio(settings, entry)
    overshoots(entry, OVERSHOOT)
    gc.collect()
    memo = entry.segment.memo
    for key, value in memo.items():
        if isinstance(key, tuple) and settings in key:
            assert key is settings.end_need_key or key is settings.ratio_key, key
        elif isinstance(key, tuple):
            assert not gc.is_tracked(key), key
        if isinstance(value, tuple):
            assert not gc.is_tracked(value), (key, value)
    assert any(isinstance(k, tuple) and k[0] == "bound lows" for k in memo)
