"""A conformance suite for simple_message servers and clients (``simple-message conformance``).

The **server suite** (:mod:`.server`) connects to a running controller (real or emulated) and
probes it: framing, byte order and float size, replies, unknown types, malformed frames, PING, the
state topics, and, only when motion is allowed, small moves, STOP and refusals. The **client suite**
(:mod:`.client`) plays a controller for a client under test: it sits between the client and a
controller (by default the emulator, ``robot-server``, started for the run), watches every frame
both ways, injects a BUSY, a FAILURE and a dropped connection, and judges how the client reacts.

Both write a :class:`~.report.Report`: one verdict per rule with its evidence, as a table, JSON or
JUnit XML. The rules and the real peers' behaviour each comes from are listed in the project's
docs/conformance.md.
"""

from __future__ import annotations

from .report import Evidence, Report, RuleResult, Verdict

__all__ = ["Evidence", "Report", "RuleResult", "Verdict"]
