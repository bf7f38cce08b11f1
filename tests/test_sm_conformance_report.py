"""The conformance report: verdicts, the terminal table, JSON and JUnit XML, the exit code."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

from simple_message import LE32, Ping, encode
from simple_message.conformance.report import Evidence, Report, RuleResult, Verdict


def sample() -> Report:
    report = Report("server", "127.0.0.1:11000")
    ping = Ping()
    report.add(
        RuleResult(
            "ping.answered",
            "a PING request is answered with a PING reply",
            Verdict.PASS,
            evidence=[Evidence.frame("sent", encode(ping, LE32), ping)],
            seconds=0.002,
        )
    )
    report.add(
        RuleResult(
            "framing.replies-in-order",
            "replies come in the order of the requests",
            Verdict.FAIL,
            "the reply to request 2 came before the reply to request 1",
            source="the C++ library answers each request in order",
            evidence=[Evidence.note("request 1 sent at 0.000 s, request 2 at 0.001 s")],
        )
    )
    report.add(RuleResult("state.jitter", "the state topics' jitter", Verdict.WARN, "p99 jitter 6.1 ms"))
    report.add(RuleResult("motion.small-move", "a small move", Verdict.SKIP, "needs --allow-motion"))
    return report


def test_a_failed_rule_makes_the_exit_code_1_and_only_then() -> None:
    report = sample()
    assert report.exit_code == 1
    assert report.counts() == {Verdict.PASS: 1, Verdict.FAIL: 1, Verdict.WARN: 1, Verdict.SKIP: 1}
    report.results = [r for r in report.results if r.verdict is not Verdict.FAIL]
    assert report.exit_code == 0


def test_the_table_shows_each_rule_and_the_evidence_of_those_not_passed() -> None:
    table = sample().table()
    assert "PASS  ping.answered" in table and "FAIL  framing.replies-in-order  the reply to request 2" in table
    assert "request 1 sent at 0.000 s" in table  # a failure's evidence
    assert "sent: 0c000000" not in table  # a pass's evidence only with evidence=True
    full = sample().table(evidence=True)
    assert "sent: 0c000000" in full and "= PING comm 2 reply 0 {}" in full  # hex, then decoded
    assert table.splitlines()[-1] == "1 PASS, 1 FAIL, 1 WARN, 1 SKIP of 4 rules"


def test_json_holds_every_field() -> None:
    data = json.loads(sample().dumps())
    assert data["counts"] == {"PASS": 1, "FAIL": 1, "WARN": 1, "SKIP": 1}
    first = data["results"][0]
    assert first["rule"] == "ping.answered" and first["verdict"] == "PASS"
    assert first["evidence"][0]["decoded"]["name"] == "PING"
    assert data["results"][1]["source"] == "the C++ library answers each request in order"


def test_junit_xml_has_a_testcase_per_rule() -> None:
    root = ET.fromstring(sample().junit())
    [suite] = root.findall("testsuite")
    assert suite.get("tests") == "4" and suite.get("failures") == "1" and suite.get("skipped") == "1"
    cases = {case.get("name"): case for case in suite.findall("testcase")}
    assert set(cases) == {"ping.answered", "framing.replies-in-order", "state.jitter", "motion.small-move"}
    failure = cases["framing.replies-in-order"].find("failure")
    assert failure is not None and "request 2" in (failure.get("message") or "")
    assert cases["motion.small-move"].find("skipped") is not None
    out = cases["state.jitter"].find("system-out")
    assert out is not None and (out.text or "").startswith("WARN: p99 jitter")
