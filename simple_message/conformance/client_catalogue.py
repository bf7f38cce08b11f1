"""The client suite's catalogue: its rules, what each checks and the real peer behaviour it comes
from, and each rule's findings as the observer collects them.

:data:`RULES` lists the rules in report order; :func:`rule_findings` gives each its title and source
(some depend on whether the controller played is MotoROS: its stop, its sequences, its reaction to
a refused point) and an empty :class:`Findings`. The observer (:mod:`.client_rules`) adds the
failures, warnings and evidence of each as the client's frames pass, and each gives its verdict at
the end: FAIL when anything failed, else WARN, else PASS when something was checked, else SKIP with
what the client should do to exercise it. Details and evidence are capped (:data:`MAX_DETAILS`,
:data:`MAX_EVIDENCE`): nothing a client sends grows them without bound.
"""

from __future__ import annotations

from typing import Final

from .report import Evidence, RuleResult, Verdict

__all__ = ["RULES", "INJECTION_RULES", "Findings", "rule_findings"]

#: the rules, in report order
RULES: Final = (
    "client.byte-order",
    "client.stop-and-wait",
    "client.sequence",
    "client.point-fields",
    "client.first-point",
    "client.stop",
    "client.busy-reaction",
    "client.failure-reaction",
    "client.reconnect",
)


#: evidence items per rule, failure details kept per rule
MAX_EVIDENCE = 10
MAX_DETAILS = 20
#: the rule that reports each injection
INJECTION_RULES: Final = {
    "busy": "client.busy-reaction",
    "failure": "client.failure-reaction",
    "drop": "client.reconnect",
}


class Findings:
    """One rule's findings: failures and warnings (details capped), evidence (capped), and how many
    things it checked."""

    def __init__(self, rule: str, title: str, source: str) -> None:
        self.rule = rule
        self.title = title
        self.source = source
        self.checked = 0
        self.failures: list[str] = []
        self.fail_count = 0
        self.warnings: list[str] = []
        self.warn_count = 0
        self.evidence: list[Evidence] = []
        self.samples: list[Evidence] = []
        self.notes: list[Evidence] = []

    def fail(self, detail: str, *evidence: Evidence) -> None:
        self.fail_count += 1
        if len(self.failures) < MAX_DETAILS:
            self.failures.append(detail)
        self.keep(*evidence)

    def warn(self, detail: str, *evidence: Evidence) -> None:
        self.warn_count += 1
        if len(self.warnings) < MAX_DETAILS:
            self.warnings.append(detail)
        self.keep(*evidence)

    def sample(self, *evidence: Evidence) -> None:
        """Representative evidence of a pass (shown when nothing failed or warned)."""
        for item in evidence:
            if len(self.samples) < 3:
                self.samples.append(item)

    def note(self, text: str) -> None:
        if len(self.notes) < 4:
            self.notes.append(Evidence.note(text))

    def keep(self, *evidence: Evidence) -> None:
        for item in evidence:
            if len(self.evidence) < MAX_EVIDENCE:
                self.evidence.append(item)

    def result(self, passed: str, skipped: str) -> RuleResult:
        if self.fail_count:
            verdict, detail, shown = Verdict.FAIL, _summary(self.failures, self.fail_count), self.evidence
        elif self.warn_count:
            verdict, detail, shown = Verdict.WARN, _summary(self.warnings, self.warn_count), self.evidence
        elif self.checked:
            verdict, detail, shown = Verdict.PASS, passed, self.samples
        else:
            verdict, detail, shown = Verdict.SKIP, skipped, []
        evidence = (self.notes + list(shown))[:MAX_EVIDENCE]
        return RuleResult(self.rule, self.title, verdict, detail, self.source, evidence)


def _summary(details: list[str], count: int) -> str:
    more = count - 1
    return details[0] + (f" (and {more} more)" if more else "")


def rule_findings(moto: bool) -> dict[str, Findings]:
    """Every rule's empty findings, with its title and source (``moto``: the controller played is
    MotoROS)."""
    return {
        "client.byte-order": Findings(
            "client.byte-order",
            "every frame the client sends is in the controller's byte order",
            "every peer is built for one byte order and cannot detect another (docs/reference/protocol.md §1.3, "
            "§10 pitfall 1: Fanuc and the FS100 big-endian, the rest little-endian)",
        ),
        "client.stop-and-wait": Findings(
            "client.stop-and-wait",
            "one point request (STOP included) awaits its reply at a time",
            "industrial_robot_client JointTrajectoryStreamer: one request in flight (docs/reference/protocol.md §4.2); "
            "replies carry no request id, and MotoROS and Fanuc keep a 1-point buffer (§8.1, §8.3)",
        ),
        "client.sequence": Findings(
            "client.sequence",
            "sequence numbers count 0, 1, 2... per trajectory; special values used as real peers do",
            "REP-I0006 (out-of-order points abort) and the reference streamer and downloader "
            "(docs/reference/protocol.md §4.1, §4.2, §4.4)"
            + ("; MotoROS refuses negative sequences with INVALID/3005 (§8.1)" if moto else ""),
        ),
        "client.point-fields": Findings(
            "client.point-fields",
            "point fields are finite and in range",
            "JOINT_TRAJ_PT: a velocity ratio in [0, 1] and a segment duration (docs/reference/protocol.md §4.3); "
            "JOINT_TRAJ_PT_FULL: MotoROS requires valid_fields 0x07 and time < 14400 s (§8.1, motoman#244)",
        ),
        "client.first-point": Findings(
            "client.first-point",
            "each trajectory starts where the robot is",
            "MotoROS refuses a start more than 30 pulses away (INVALID/3011, docs/reference/protocol.md §8.1, "
            "§10 pitfall 10); motoman_driver and the reference action start from the current joint state",
        ),
        "client.stop": Findings(
            "client.stop",
            "a STOP is well formed, answered before the next point, and followed by a new trajectory",
            (
                "motoman_driver: stop is MOTO_MOTION_CTRL STOP_MOTION as a request (docs/reference/protocol.md §8.1)"
                if moto
                else "JointTrajectoryInterface::trajectoryStop: JOINT_TRAJ_PT sequence -4 as a SERVICE_REQUEST, "
                "acknowledged (docs/reference/protocol.md §4.2, §11 item 8; ros-industrial/abb#42)"
            ),
        ),
        "client.busy-reaction": Findings(
            "client.busy-reaction",
            "after MotoROS's BUSY, the same point is sent again",
            "motoman_driver retries a point answered BUSY (docs/reference/protocol.md §8.1; the FS100 trace: 48 BUSY "
            "replies out of 58)",
        ),
        "client.failure-reaction": Findings(
            "client.failure-reaction",
            "after a refused point, no later point of that trajectory",
            (
                "motoman_driver aborts on any result but SUCCESS and BUSY (docs/reference/protocol.md §8.1)"
                if moto
                else "a refused point is not queued (REP-I0006: reply_code says whether it was enqueued); "
                "the reference streamer ignores reply codes (industrial_core#118, "
                "docs/reference/protocol.md §10 pitfall 6)"
            ),
        ),
        "client.reconnect": Findings(
            "client.reconnect",
            "after a reconnect, nothing of the interrupted trajectory is sent again",
            "industrial_core PR #263: after a reconnect, streamed points may be skipped or repeated "
            "(docs/reference/protocol.md §7, §10 pitfall 11, §12 test 7)",
        ),
    }
