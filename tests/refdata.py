"""Shared test helpers: the conformance data files and their parsers."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DATA = Path(__file__).parent / "data"


@dataclass(frozen=True)
class Vector:
    """One frame of a reference vector file and the values the C++ library decoded from it."""

    name: str
    frame: bytes
    msg_type: int
    comm_type: int
    reply_code: int
    body_size: int
    fields: dict[str, Any]


_FIELD_NAMES = {
    "seq": "sequence",
    "joints": "joint_data",
    "pos": "positions",
    "vel": "velocities",
    "acc": "accelerations",
}


def _value(text: str) -> Any:
    if text.startswith("["):
        return [float(v) for v in text.strip("[]").split(",")]
    text = text.split("/", maxsplit=1)[0]  # "-1/START_TRAJECTORY_DOWNLOAD"
    if text.startswith("0x"):
        return int(text, 16)
    return float(text) if any(c in text for c in ".e") else int(text)


def load_vectors(name: str) -> list[Vector]:
    """Parse ``vectors_le.txt`` / ``vectors_be.txt``: each ``NAME HEX`` line after its comment."""
    vectors: list[Vector] = []
    comment = ""
    for line in (DATA / name).read_text().splitlines():
        if line.startswith("#"):
            comment = line
            continue
        if not line.strip():
            continue
        label, hexdata = line.split()
        decoded = comment.split("decoded by lib:", 1)[1]
        # key=value where value is a [list], or a token
        pairs = dict(re.findall(r"(\w+)=(\[[^\]]*\]|\S+)", decoded))
        head = {k: int(re.match(r"-?\d+", pairs.pop(k)).group()) for k in ("type", "comm", "reply")}  # type: ignore[union-attr]
        body_size = int(pairs.pop("body").rstrip("B"))
        fields = {_FIELD_NAMES.get(k, k): _value(v) for k, v in pairs.items()}
        vectors.append(
            Vector(label, bytes.fromhex(hexdata), head["type"], head["comm"], head["reply"], body_size, fields)
        )
    return vectors


def load_segments() -> list[tuple[float, int, int, bytes]]:
    """The FS100 capture's TCP segments: (time, src_port, dst_port, payload)."""
    segments = []
    for line in (DATA / "motoman_fs100_simple_move.segments.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t, src, dst, payload = line.split()
        segments.append((float(t), int(src), int(dst), bytes.fromhex(payload)))
    return segments
