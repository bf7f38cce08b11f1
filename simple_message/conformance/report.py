"""The report of a conformance run: one verdict per rule, with its evidence, as a terminal table,
JSON and JUnit XML (so that a CI system shows each rule as a test).

A rule's verdict is PASS, FAIL, WARN (the peer works but not as the real peers do, e.g. a state
topic's jitter) or SKIP (the rule does not apply, or needs what was not allowed, such as motion).
Its evidence is what was sent and received: frames in hex with their decoded form, and notes. A run
exits 0 when no rule FAILs.
"""

from __future__ import annotations

import enum
import json
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Any

from ..jsonio import message_to_json
from ..messages import Message

__all__ = ["Verdict", "Evidence", "RuleResult", "Report"]


class Verdict(enum.StrEnum):
    """What a rule found."""

    PASS = "PASS"
    FAIL = "FAIL"
    #: works, but not as the real peers do
    WARN = "WARN"
    #: not applicable, or not allowed (motion without --allow-motion)
    SKIP = "SKIP"


@dataclass(frozen=True)
class Evidence:
    """One thing a rule saw: a frame ``sent`` or ``received`` (hex, and decoded when it decodes), or a note."""

    kind: str
    text: str
    decoded: dict[str, Any] | None = None

    @classmethod
    def frame(cls, direction: str, frame: bytes, message: Message | None = None, real_size: int = 4) -> Evidence:
        return cls(direction, frame.hex(), None if message is None else message_to_json(message, real_size))

    @classmethod
    def note(cls, text: str) -> Evidence:
        return cls("note", text)

    def line(self) -> str:
        """One line for the terminal: the hex, and the decoded header and body (cut at 240 characters)."""
        if self.kind == "note":
            return self.text
        if not self.decoded:
            return f"{self.kind}: {self.text}"
        d = self.decoded
        body = json.dumps(d.get("body", {}), separators=(",", ":"))
        if len(body) > 240:
            body = body[:237] + "..."
        header = f"{d.get('name')} comm {d.get('comm_type')} reply {d.get('reply_code')}"
        return f"{self.kind}: {self.text}\n        = {header} {body}"


@dataclass
class RuleResult:
    """A rule's verdict: ``rule`` is its identifier (``framing.replies-in-order``), ``title`` what it
    checks, ``detail`` why this verdict, ``source`` the real peer behaviour it comes from."""

    rule: str
    title: str
    verdict: Verdict
    detail: str = ""
    source: str = ""
    evidence: list[Evidence] = field(default_factory=list)
    seconds: float = 0.0


@dataclass
class Report:
    """The results of one run against ``target`` (``suite``: ``server`` or ``client``)."""

    suite: str
    target: str
    results: list[RuleResult] = field(default_factory=list)
    started: float = field(default_factory=time.time)

    def add(self, result: RuleResult) -> RuleResult:
        self.results.append(result)
        return result

    def counts(self) -> dict[Verdict, int]:
        return {v: sum(r.verdict is v for r in self.results) for v in Verdict}

    @property
    def exit_code(self) -> int:
        """0 when no rule FAILed, else 1."""
        return 1 if any(r.verdict is Verdict.FAIL for r in self.results) else 0

    def table(self, *, evidence: bool = False) -> str:
        """The terminal report: a line per rule, the evidence of those not passed (or all with
        ``evidence``), and the totals."""
        width = max((len(r.rule) for r in self.results), default=4)
        lines = [f"simple_message conformance, {self.suite} suite, against {self.target}", ""]
        for r in self.results:
            lines.append(f"{r.verdict.value:<4}  {r.rule:<{width}}  {r.detail or r.title}")
            if evidence or r.verdict in (Verdict.FAIL, Verdict.WARN):
                lines.extend(f"      {e.line()}" for e in r.evidence)
        counts = self.counts()
        lines.append("")
        lines.append(", ".join(f"{counts[v]} {v.value}" for v in Verdict) + f" of {len(self.results)} rules")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {
            "suite": self.suite,
            "target": self.target,
            "started": self.started,
            "counts": {v.value: n for v, n in self.counts().items()},
            "results": [
                {
                    "rule": r.rule,
                    "title": r.title,
                    "verdict": r.verdict.value,
                    "detail": r.detail,
                    "source": r.source,
                    "seconds": r.seconds,
                    "evidence": [{"kind": e.kind, "text": e.text, "decoded": e.decoded} for e in r.evidence],
                }
                for r in self.results
            ],
        }

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=2)

    def junit(self) -> str:
        """JUnit XML: one testsuite, a testcase per rule (FAIL a failure, SKIP skipped, WARN a pass
        whose system-out says so), the evidence in system-out."""
        counts = self.counts()
        suite = ET.Element(
            "testsuite",
            name=f"simple_message conformance ({self.suite})",
            tests=str(len(self.results)),
            failures=str(counts[Verdict.FAIL]),
            errors="0",
            skipped=str(counts[Verdict.SKIP]),
            time=f"{sum(r.seconds for r in self.results):.3f}",
            timestamp=time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(self.started)),
            hostname=self.target,
        )
        for r in self.results:
            case = ET.SubElement(suite, "testcase", classname=f"conformance.{self.suite}", name=r.rule)
            case.set("time", f"{r.seconds:.3f}")
            if r.verdict is Verdict.FAIL:
                ET.SubElement(case, "failure", message=r.detail or r.title).text = r.title
            elif r.verdict is Verdict.SKIP:
                ET.SubElement(case, "skipped", message=r.detail or r.title)
            out = [f"{r.verdict.value}: {r.detail or r.title}"]
            if r.source:
                out.append(f"from: {r.source}")
            out.extend(e.line() for e in r.evidence)
            ET.SubElement(case, "system-out").text = "\n".join(out)
        root = ET.Element("testsuites")
        root.append(suite)
        ET.indent(root)
        return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
