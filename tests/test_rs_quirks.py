"""Quirks: each kind said once, however its text varies; a text with % in it is logged as is."""

from __future__ import annotations

import logging
from typing import Any, cast

import pytest

from robot_server.emulator.quirks import Quirks
from simple_message.endpoints import Session
from simple_message.lograte import LogBudget

log = logging.getLogger("tests.quirks")


class _Session:
    """What Quirks uses of a session: its budgeted log (a real budget, which formats the line)."""

    def __init__(self) -> None:
        self.budget = LogBudget("peer")

    def log(self, logger: logging.Logger, level: int, msg: str, *args: Any) -> bool:
        return self.budget.log(logger, level, msg, *args)


def test_a_kind_is_said_once_whatever_its_text(caplog: pytest.LogCaptureFixture) -> None:
    quirks = Quirks(log)
    session = cast(Session, _Session())
    with caplog.at_level(logging.WARNING, logger="tests.quirks"):
        said = [quirks.say(session, "other type", f"message type {t}: not read") for t in range(1000)]
        said.append(quirks.say(session, "stalled", "12 bytes (100%) wait unread"))
    assert said.count(True) == 2
    said_lines = [r.getMessage() for r in caplog.records]
    assert said_lines == ["peer: message type 0: not read", "peer: 12 bytes (100%) wait unread"]
