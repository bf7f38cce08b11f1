"""What a run found, and how it is printed: the counts of a profile's server run (per port and in
all), the Markdown table of the profiles and the decoder, and the details below it: frames per port,
how many the server confirmably processed (before an answered marker), connections and how they
ended, probes, state messages, RSS over the run.

**Failures** (exit status 1): crashes (the server exited, or did not exit 0 within 30 s of SIGTERM),
hangs (probes unanswered within 1 s, stalled connections, state silences over 1 s), tracebacks,
motion, a monitor that saw no state at all, decoder failures, and with ``--max-rss-growth MB`` an
RSS growth above it. The RSS growth includes the server's warm-up (its first 10 % of the frames
or so, reported apart).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .decoder import DecoderReport

#: s without an answer to a fresh PING, or of state silence, that counts as a hang (the default)
HANG_AFTER = 1.0


@dataclass
class PortStats:
    frames: int = 0
    bytes: int = 0
    confirmed: int = 0  # frames before a marker the server answered
    connections: int = 0
    connect_failures: int = 0
    rejected: int = 0  # units the safety model refused (generated again)
    fatal: int = 0  # connections ended by a fatal length prefix (the server must close)
    unclosed: int = 0  # ... that the server did not close within CLOSE_TIMEOUT
    server_closed: int = 0  # connections the server closed otherwise (MotoROS rules, limits)
    stalls: int = 0
    abandoned: int = 0  # connections ended because no safe unit could follow
    bad_replies: int = 0  # replies that could not be framed
    markers: int = 0


@dataclass
class ProfileReport:
    """What one profile's server run found (the table's row and the details below it)."""

    profile: str
    hang_after: float = HANG_AFTER
    ports: dict[str, PortStats] = field(default_factory=dict)
    seconds: float = 0.0
    crashes: int = 0
    exit_code: int | None = None
    hangs: int = 0  # failed probes + stalled connections + state gaps
    probes: int = 0
    probe_failures: int = 0
    probe_max: float = 0.0
    state_messages: int = 0
    state_gaps: int = 0
    state_max_gap: float = 0.0
    motion: int = 0
    motion_detail: str = ""
    max_deviation: float = 0.0
    tracebacks: int | None = None
    traceback_excerpt: str = ""
    rss_before: float | None = None
    rss_after: float | None = None
    rss_max: float | None = None
    #: (frames sent, RSS MB) every probe interval
    rss_samples: list[tuple[int, float]] = field(default_factory=list)
    log_path: Path | None = None
    log_bytes: int = 0
    log_lines: int = 0
    dumps: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: the last batches of each connection by port role and client port (for the log reading of
    #: :mod:`bench.fuzz.server`)
    rings: dict[str, dict[int, deque[list[bytes]]]] = field(default_factory=dict, repr=False)

    @property
    def frames(self) -> int:
        return sum(p.frames for p in self.ports.values())

    @property
    def confirmed(self) -> int:
        return sum(p.confirmed for p in self.ports.values())

    @property
    def connections(self) -> int:
        return sum(p.connections for p in self.ports.values())

    @property
    def rss_growth(self) -> float | None:
        if self.rss_before is None or self.rss_after is None:
            return None
        return self.rss_after - self.rss_before

    @property
    def failures(self) -> int:
        blind = 1 if self.state_messages == 0 else 0  # the monitor saw nothing: motion unknown
        return self.crashes + self.hangs + (self.tracebacks or 0) + self.motion + blind


def _mb(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.1f}"


def table(reports: Sequence[ProfileReport], decoder: DecoderReport | None) -> str:
    out = [
        "| profile | frames | connections | crashes | hangs | tracebacks | motion | RSS before/after/growth (MB) "
        "| log lines/s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in reports:
        growth = r.rss_growth
        rss = f"{_mb(r.rss_before)} / {_mb(r.rss_after)} / " + ("n/a" if growth is None else f"{growth:+.1f}")
        tb = "n/a" if r.tracebacks is None else str(r.tracebacks)
        rate = f"{r.log_lines / r.seconds:.1f}" if r.seconds and r.tracebacks is not None else "n/a"
        out.append(
            f"| {r.profile} | {r.frames:,} | {r.connections:,} | {r.crashes} | {r.hangs} | {tb} | {r.motion} "
            f"| {rss} | {rate} |"
        )
    if decoder is not None:
        documented = ", ".join(f"{k} {v:,}" for k, v in sorted(decoder.exceptions.items()))
        out.append("")
        out.append("| decoder (in process) | frames | decode calls | seconds | exceptions | failures |")
        out.append("|---|---:|---:|---:|---|---:|")
        out.append(
            f"| FrameDecoder + decode + feed_messages, both byte orders, float32/64 | {decoder.frames:,} "
            f"| {decoder.decodes:,} | {decoder.seconds:.1f} | {documented or 'none'} | {decoder.failure_count} |"
        )
    return "\n".join(out)


def details(r: ProfileReport) -> str:
    out = [f"## {r.profile}: {r.seconds:.1f} s, {r.frames / max(r.seconds, 1e-9):,.0f} frames/s"]
    for role, p in r.ports.items():
        out.append(
            f"  {role}: {p.frames:,} frames ({p.bytes / 1e6:.1f} MB), {p.confirmed:,} confirmed processed, "
            f"{p.connections:,} connections ({p.fatal:,} ended by a bad length prefix, {p.unclosed} of them not "
            f"closed by the server; {p.server_closed:,} closed by the server otherwise; {p.connect_failures} "
            f"connect failures, {p.abandoned} abandoned), {p.rejected:,} units refused by the safety check, "
            f"{p.stalls} stalls, "
            f"{p.bad_replies} unframeable replies"
        )
    out.append(
        f"  probes: {r.probes} ({r.probe_failures} failed, slowest {r.probe_max * 1000:.0f} ms); state messages "
        f"{r.state_messages:,} (longest silence {r.state_max_gap * 1000:.0f} ms, {r.state_gaps} over "
        f"{r.hang_after:g} s); largest position change {r.max_deviation:g}"
    )
    if r.rss_samples:
        step = max(1, len(r.rss_samples) // 8)
        timeline = ", ".join(f"{f / 1000:,.0f}k: {m:.1f}" for f, m in [*r.rss_samples[::step], r.rss_samples[-1]])
        out.append(f"  RSS (MB) by frames sent: {timeline}")
        warm = next((m for f, m in r.rss_samples if f >= r.frames // 10), None)
        if warm is not None and r.rss_after is not None:
            out.append(f"  RSS growth after the first 10 % of the frames (warm-up): {r.rss_after - warm:+.1f} MB")
    out.append(
        f"  RSS max {_mb(r.rss_max)} MB; log {r.log_bytes / 1e6:.1f} MB, {r.log_lines:,} lines"
        + (f" ({r.log_path})" if r.log_path else "")
        + (f"; exit status {r.exit_code}" if r.exit_code is not None else "")
    )
    for note in r.notes[:20]:
        out.append(f"  note: {note}")
    if len(r.notes) > 20:
        out.append(f"  ... {len(r.notes) - 20} more notes")
    if r.traceback_excerpt:
        out.append("  first traceback:")
        out += ["    " + line for line in r.traceback_excerpt.splitlines()]
    for dump in r.dumps:
        out.append(f"  last frames of a connection that caused a traceback: {dump}")
    return "\n".join(out)


def decoder_details(d: DecoderReport) -> str:
    out = [
        f"## decoder: {d.units:,} units fed, {d.frames:,} frames cut, {d.decodes:,} decodes in {d.seconds:.1f} s "
        f"({d.frames / max(d.seconds, 1e-9):,.0f} frames/s); {d.quieted_nans:,} float32 signalling NaNs quieted "
        "(documented)"
    ]
    for kind, (count, what, data) in sorted(d.failures.items()):
        out.append(f"  FAILURE {kind}: {count:,} times; the shortest: {what}\n    bytes ({len(data)}): {data.hex()}")
    return "\n".join(out)
