"""Saying a controller's quirk once: the first time a client trips on it, not every time.

A vendor profile reproduces what its real controller does with what it cannot read (a PING that
stalls Fanuc's relay, a STOP that stops nothing), and says so in one log line that names the rule
and its source. A client that trips on the same quirk again gets no new line: the lines are keyed
by the quirk's kind, a handful per profile, so neither the log nor the memory that remembers what
was said grows with what clients send (a text that names a message type or a byte count varies;
its kind does not).
"""

from __future__ import annotations

import logging

from simple_message.endpoints import Session

__all__ = ["Quirks"]


class Quirks:
    """The quirks one profile has said, by kind (see the module doc)."""

    def __init__(self, logger: logging.Logger) -> None:
        self._logger = logger
        self._said: set[str] = set()

    def say(self, session: Session, kind: str, text: str, level: int = logging.WARNING) -> bool:
        """Log ``text`` through ``session``'s budget unless a quirk of ``kind`` was said already;
        returns whether it was logged now."""
        if kind in self._said:
            return False
        self._said.add(kind)
        # the text is the line's cause in a budget summary (one per kind); the budget formats it
        # (its "<name>: " prefix is an argument), so a literal % is doubled
        session.log(self._logger, level, text.replace("%", "%%"))
        return True
