"""The server suite's rule runner: each rule judged once and reported with its title and source.

A rule is judged by a check: a coroutine function that returns a verdict, or raises
:class:`~.server_checks._Skip` (the rule cannot be judged: SKIP with the reason) or :class:`_Abort`
(the motion phase cannot go on: this rule FAILs with the evidence so far, and the motion rules after
it SKIP). A rule judged once is not judged again. The rules ``--only`` and ``--skip`` leave out
are not reported, though a check another rule needs (a connection) can be run for them anyway,
unreported. The report lists the rules in the catalogue's order (:data:`~.expectations.SERVER_RULES`),
whatever order they ran in.
"""

from __future__ import annotations

import fnmatch
import time
from collections.abc import Awaitable, Callable, Sequence

from .expectations import SERVER_RULES
from .report import Evidence, Report, RuleResult, Verdict
from .server_checks import _Skip, _Verdict

__all__ = ["RuleRunner"]

#: evidence items reported per rule (a note says how many more there were)
SHOWN = 12


class _Abort(Exception):
    """The motion phase cannot go on (the server stopped answering, or a move failed): this rule
    FAILs with the reason and the evidence so far, the rules after it SKIP."""

    def __init__(self, reason: str, evidence: list[Evidence] | None = None) -> None:
        super().__init__(reason)
        self.evidence = evidence or []


class RuleRunner:
    """Runs the rules of one server-suite run into ``report``; ``only`` and ``skip`` are rule
    patterns (fnmatch) to run only and to leave out."""

    def __init__(self, report: Report, only: Sequence[str] = (), skip: Sequence[str] = ()) -> None:
        self.report = report
        self.only = tuple(only)
        self.skip = tuple(skip)
        self.results: dict[str, _Verdict] = {}
        #: why the motion phase was aborted, once a check raised :class:`_Abort`
        self.aborted: str | None = None

    def wanted(self, rule: str) -> bool:
        if self.only and not any(fnmatch.fnmatchcase(rule, p) for p in self.only):
            return False
        return not any(fnmatch.fnmatchcase(rule, p) for p in self.skip)

    async def rule(
        self, rule: str, check: Callable[[], Awaitable[_Verdict]], *, always: bool = False
    ) -> _Verdict | None:
        """Judge ``rule`` by ``check`` and report it, if it is wanted (``always``: run the check
        anyway, unreported: a connection the other rules need)."""
        if rule in self.results:
            return self.results[rule]
        wanted = self.wanted(rule)
        if not wanted and not always:
            return None
        title, source = SERVER_RULES[rule]
        started = time.monotonic()
        try:
            result = await check()
        except _Skip as skip:
            result = _Verdict(Verdict.SKIP, str(skip))
        except _Abort as abort:
            self.aborted = self.aborted or str(abort)
            result = _Verdict(Verdict.FAIL, str(abort), abort.evidence)
        if not wanted:
            return result
        self.results[rule] = result
        evidence = result.evidence[:SHOWN]
        if len(result.evidence) > SHOWN:
            evidence.append(Evidence.note(f"... and {len(result.evidence) - SHOWN} more"))
        self.report.add(
            RuleResult(rule, title, result.verdict, result.detail, source, evidence, time.monotonic() - started)
        )
        return result

    def skip_all(self, rules: Sequence[str], reason: str) -> None:
        """SKIP each of ``rules`` not judged yet, with ``reason``."""
        for rule in rules:
            if self.wanted(rule) and rule not in self.results:
                title, source = SERVER_RULES[rule]
                self.results[rule] = _Verdict(Verdict.SKIP, reason)
                self.report.add(RuleResult(rule, title, Verdict.SKIP, reason, source))

    def reported(self, rule: str) -> RuleResult | None:
        """The result reported for ``rule``, if it was."""
        return next((r for r in self.report.results if r.rule == rule), None)

    def in_catalogue_order(self) -> None:
        """Sort the report's results into the catalogue's order."""
        order = list(SERVER_RULES)
        self.report.results.sort(key=lambda r: order.index(r.rule))
