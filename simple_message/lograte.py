"""A bounded log for what peers cause: at most a fixed number of lines per second per connection.

A peer that sends garbage as fast as it can must not write the server's log as fast as it can: a
fuzzing client once turned 40 MB of frames into 62 MB of log. Every line a connection causes goes
through its :class:`LogBudget`: a token bucket (``rate`` lines per second, bursts of ``burst``)
shared by all the causes of that connection. A line over the budget is not written but counted
by its cause (its format string), and the counts come out in one summary line the next time the
budget allows a line, and when the connection ends::

    motion ('127.0.0.1', 40522): suppressed 1873 lines in 9.8 s: 1870 x malformed message: %s; 3 x ...

So a flood costs at most ``burst + rate x seconds`` lines per connection, and nothing is lost
without a count. What no single connection causes (connections coming and going by the thousand,
the lines a controller writes for each trajectory a client starts) is bounded by a
:class:`BudgetFilter`: one budget over whole loggers, whoever writes to them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping

__all__ = ["LogBudget", "BudgetFilter", "lane", "LINES_PER_SECOND", "BURST"]

#: record attributes of a budget's summary line: the budget, and the counts it summarises by cause
_SUMMARY = "log_budget_summary"
_COUNTS = "log_budget_counts"
#: a record attribute: the :func:`lane` of a line
_LANE = "log_budget_lane"

#: lines per second a connection may cause once its burst is spent
LINES_PER_SECOND = 5.0
#: lines a connection may cause at once
BURST = 20


class LogBudget:
    """The log lines one connection may cause (see the module doc)."""

    __slots__ = ("_clock", "_first_logger", "_last", "_since", "_suppressed", "_tokens", "burst", "name", "rate")

    def __init__(
        self,
        name: str,
        *,
        rate: float = LINES_PER_SECOND,
        burst: int = BURST,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if rate <= 0.0 or burst < 1:
            raise ValueError(f"a log budget needs rate > 0 and burst >= 1, not {rate}, {burst}")
        self.name = name
        self.rate = rate
        self.burst = burst
        self._clock = clock
        self._tokens = float(burst)
        self._last = clock()
        #: lines not written since the last summary, by cause (format string)
        self._suppressed: dict[str, int] = {}
        self._since = 0.0
        self._first_logger: logging.Logger | None = None

    @property
    def suppressed(self) -> int:
        """Lines held back and not yet summarised."""
        return sum(self._suppressed.values())

    def log(self, logger: logging.Logger, level: int, msg: str, *args: object, exc_info: bool = False) -> bool:
        """Write ``"<name>: " + msg % args`` to ``logger`` if the budget allows; returns whether it did."""
        if not logger.isEnabledFor(level):
            return False
        if not self.admit(logger, msg):
            return False
        logger.log(level, "%s: " + msg, self.name, *args, exc_info=exc_info)
        return True

    def admit(self, logger: logging.Logger, msg: str, counts: Mapping[str, int] | None = None) -> bool:
        """Take a line of cause ``msg`` from the budget: ``True`` if it may be written (after the
        summary of what was held back, written here to ``logger``), ``False`` if it is counted.
        A line that is itself a summary brings its ``counts`` (by cause): held back, they are
        counted here in its place."""
        now = self._clock()
        self._tokens = min(float(self.burst), self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens < 1.0:
            if not self._suppressed:
                self._since = now
                self._first_logger = logger
            suppressed = self._suppressed
            for cause, n in (counts or {msg: 1}).items():
                suppressed[cause] = suppressed.get(cause, 0) + n
            return False
        self._tokens -= 1.0
        if self._suppressed:
            self._tokens = max(0.0, self._tokens - 1.0)  # the summary is a line too
            self._summarise(logger, now)
        return True

    def flush(self) -> None:
        """Write the summary of what is still held back (the connection ends)."""
        if self._suppressed and self._first_logger is not None:
            self._summarise(self._first_logger, self._clock())

    def _summarise(self, logger: logging.Logger, now: float) -> None:
        counts, self._suppressed = self._suppressed, {}
        causes = sorted(counts.items(), key=lambda item: -item[1])
        shown = "; ".join(f"{n} x {cause}" for cause, n in causes[:3])
        more = f"; {len(causes) - 3} more causes" if len(causes) > 3 else ""
        total = sum(counts.values())
        logger.warning(
            "%s: suppressed %d log lines in %.1f s: %s%s",
            self.name,
            total,
            now - self._since,
            shown,
            more,
            extra={_SUMMARY: self, _COUNTS: counts},
        )


def lane(name: str) -> dict[str, object]:
    """``extra=lane(name)`` puts a log line in a lane of its own under a :class:`BudgetFilter`
    that has one: a flood of ordinary lines cannot crowd it out (the robot stopping, an e-stop)."""
    return {_LANE: name}


class BudgetFilter(logging.Filter):
    """A :class:`LogBudget` over whole loggers, whoever writes to them: added to several loggers,
    it bounds the lines they write together (a ceiling over the per-connection budgets, for what
    no one connection causes: many connections coming and going, the controller's own lines).
    ``lanes`` give lines marked with :func:`lane` budgets of their own."""

    def __init__(self, budget: LogBudget, lanes: Mapping[str, LogBudget] | None = None) -> None:
        super().__init__()
        self.budget = budget
        self.lanes = dict(lanes or {})
        self._loggers: list[logging.Logger] = []

    def filter(self, record: logging.LogRecord) -> bool:
        source = getattr(record, _SUMMARY, None)
        if source is self.budget or source in self.lanes.values():
            return True  # its own summary
        budget = self.lanes.get(getattr(record, _LANE, ""), self.budget)
        # a line, or another budget's summary (one per connection that ends: under churn, many)
        return budget.admit(logging.getLogger(record.name), str(record.msg), getattr(record, _COUNTS, None))

    def install(self, *names: str) -> BudgetFilter:
        """Add this filter to the loggers ``names``; returns itself."""
        for name in names:
            logger = logging.getLogger(name)
            logger.addFilter(self)
            self._loggers.append(logger)
        return self

    def remove(self) -> None:
        """Take this filter off its loggers, after writing the summary of what it held back."""
        for budget in (self.budget, *self.lanes.values()):
            budget.flush()
        for logger in self._loggers:
            logger.removeFilter(self)
        self._loggers.clear()
