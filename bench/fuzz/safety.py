"""What the fuzzer must never send, and the model of the server's framing that makes sure it does not.

The point is to show that invalid frames never move the robot, so no frame the server can cut from
what is sent may be a valid motion command. A per-connection model
of the server's framing (:class:`Shadow`: the length prefix in the server's byte order, 12 to 64 KiB
or the connection ends) cuts every batch exactly as the server will, and every frame it cuts,
whatever mutation made it, is checked by :func:`unsafe_reason` before a byte is written; a frame
that fails is not sent (counted as *rejected*). After a length prefix the server must refuse, at
most 8 more bytes follow (never a whole frame), and the connection is closed once the server has;
when no unit may follow an incomplete frame (wrong length prefixes), the frame is completed with
0x7F/0xFF bytes if that passes the check, else the connection is closed (*abandoned*): what the
server holds then is never completed. The check reads the frame with :mod:`struct` only,
not with the project's decoder, so that a bug shared by our decoder and our server cannot hide. It
reads msg_type in both byte orders; for the motion types below it reads the body in that order under
every layout with both real sizes (float32 and float64), at the start of the body *and* aligned to
its end (the C++ library accepts a longer body, reading fields from the end, docs/reference/protocol.md
§1.5); a layout the body is too short for does not apply (so a header-only or truncated body is
invalid). A position is *plausible* if it is finite and at most 1e3 in magnitude (1e3 rad or m is
beyond any joint's limit). The frame may be sent only if, under every layout that applies:

* JOINT_TRAJ_PT (11): position 0 is not plausible and the sequence is not -4 (STOP: a valid command,
  excluded as well);
* JOINT_TRAJ (12): the body is shorter than one point and its count (56 bytes), or made of the
  bytes 0x7F and 0xFF only (then every real at any offset, either byte order, either size, is NaN or
  at least 2^127 in magnitude);
* JOINT_TRAJ_PT_FULL (14): position 0 is not plausible (whatever ``valid_fields`` says: it is
  not trusted to hide the positions) and the sequence is not -4;
* MOTO_MOTION_CTRL (2001): the command is not one of MotoROS's (200100-200199): no valid motion
  control at all, not even CHECK_MOTION_READY or START_TRAJ_MODE, which do not move a robot
  themselves;
* JOINT_TRAJ_PT_FULL_EX (2016): for each group count 1-4 the body can hold, position 0 of every
  group is not plausible, and the sequence is not -4.

The generator (:mod:`bench.fuzz.generator`) poisons these frames on purpose (position 0, all
positions, or every real field, with NaN, infinities, 1e6 and more, or the bytes 0x7F/0xFF; commands
outside the range; sequences other than -4, reserved ones like -7 included; any comm_type), then
mutates them like the others; what the check refuses is generated again. Other fields are free:
velocities, times, groups, comm_type 0, 4 and more, ``valid_fields``. Nothing else moves a robot:
MOTO_MOTION_CTRL is never valid, IO writes and SELECT_TOOL are allowed.
"""

from __future__ import annotations

import random
import struct

from .protocol import HEADER, INT, MAX_LENGTH, MOTION_TYPES, MOTO_COMMANDS, PING, detect

#: a position is plausible when finite and at most this far from zero (rad or m)
PLAUSIBLE = 1e3
POISON_BYTES = b"\x7f\xff"

_REAL = {(o, r): struct.Struct(o + ("f" if r == 4 else "d")) for o in "<>" for r in (4, 8)}

#: any byte -> 0x7F or 0xFF (by its high bit): random bytes made poison
_TO_POISON = bytes(0x7F if b < 0x80 else 0xFF for b in range(256))


def poison_bytes(rng: random.Random, n: int) -> bytes:
    """``n`` random bytes among 0x7F and 0xFF (every real read from them is NaN or huge)."""
    return rng.randbytes(n).translate(_TO_POISON)


def _plausible(value: float) -> bool:
    return abs(value) <= PLAUSIBLE  # False for NaN and infinities


# -- the safety check: what may be sent (the module doc) -----------------------------------------


def unsafe_reason(frame: bytes) -> str | None:
    """``None`` if ``frame`` (prefix, header, body) is certainly not a valid motion command under any
    byte order, real size or layout, else why it might be one (the module doc has the rule).

    Reads the frame with :mod:`struct` only: independent of the project's decoder.
    """
    if len(frame) < HEADER:
        return None
    body = frame[HEADER:]
    for order in "<>":
        (msg_type,) = INT[order].unpack_from(frame, 4)
        if msg_type in MOTION_TYPES:
            reason = _motion_body_reason(msg_type, body, order)
            if reason is not None:
                return f"type {msg_type} ({'little' if order == '<' else 'big'}-endian): {reason}"
    return None


def _alignments(n: int, size: int) -> tuple[int, ...]:
    """Offsets a layout of ``size`` bytes can be read at in a body of ``n`` (start, end-aligned)."""
    if n < size:
        return ()
    return (0,) if n == size else (0, n - size)


def _motion_body_reason(msg_type: int, body: bytes, order: str) -> str | None:
    n = len(body)
    if not body.strip(POISON_BYTES):  # only 0x7F and 0xFF bytes: every real anywhere is invalid
        return None
    integer = INT[order].unpack_from
    if msg_type == 12:
        return None if n < 56 else "JOINT_TRAJ body of 56+ bytes with bytes other than 0x7F/0xFF"
    for r in (4, 8):
        real = _REAL[order, r].unpack_from
        if msg_type == 11:
            size = 4 + 12 * r
            for off in _alignments(n, size):
                if integer(body, off)[0] == -4:
                    return f"sequence -4 (STOP) at body offset {off}"
                if _plausible(real(body, off + 4)[0]):
                    return f"plausible position 0 (float{8 * r}, body offset {off})"
        elif msg_type == 14:
            size = 12 + 31 * r
            for off in _alignments(n, size):
                if integer(body, off + 4)[0] == -4:
                    return f"sequence -4 (STOP) at body offset {off}"
                if _plausible(real(body, off + 12 + r)[0]):
                    return f"plausible position 0 (float{8 * r}, body offset {off})"
        elif msg_type == 65001:  # robot_id, sequence, x, y, z, ...
            size = 8 + 9 * r
            for off in _alignments(n, size):
                if integer(body, off + 4)[0] == -4:
                    return f"sequence -4 (STOP) at body offset {off}"
                if _plausible(real(body, off + 8)[0]):
                    return f"plausible position x (float{8 * r}, body offset {off})"
        elif msg_type == 2001:
            size = 12 + 10 * r
            for off in _alignments(n, size):
                if integer(body, off + 8)[0] in MOTO_COMMANDS:
                    return f"a MotoROS command (float{8 * r}, body offset {off})"
        else:  # 2016
            stride = 8 + 31 * r
            for groups in range(1, 5):
                for off in _alignments(n, 8 + groups * stride):
                    if integer(body, off + 4)[0] == -4:
                        return f"sequence -4 at body offset {off}"
                    for g in range(groups):
                        if _plausible(real(body, off + 8 + g * stride + 8 + r)[0]):
                            return f"plausible position 0 of group {g} of {groups} (float{8 * r}, offset {off})"
    return None


class Shadow:
    """The server's framing of one connection, modelled: cuts what is sent exactly as the server
    will, checks every frame it cuts, and says when the server will close the connection.

    ``order`` is the server's byte order (``"<"``, ``">"``, or ``"auto"``: decided by the first
    length prefix, little-endian if plausible, as the server detects it).
    """

    __slots__ = ("fatal", "max_length", "order", "pending", "prefix", "rare", "rng", "type1")

    def __init__(
        self,
        order: str,
        max_length: int = MAX_LENGTH,
        *,
        rare: frozenset[int] = frozenset(),
        rng: random.Random | None = None,
    ) -> None:
        self.order = order
        #: types the server would cut that are let through only 2 % of the time (MotoROS closes its
        #: motion connection on them: each would cost a reconnection); not a safety matter
        self.rare = rare
        self.rng = rng or random.Random(0)
        self.prefix = INT[order] if order in "<>" else None
        self.max_length = max_length
        #: bytes of an incomplete frame the server holds
        self.pending = b""
        #: a fatal length prefix was sent: the server closes; nothing more may be sent
        self.fatal = False
        #: type-1 frames (PING) the server cut so far
        self.type1 = 0

    def add(self, unit: bytes, *, marker: bool = False) -> bytes | None:
        """What of ``unit`` may be sent next (all of it, or up to a fatal length prefix and a few
        bytes after it), the model updated; ``None`` if it may not be sent (a frame the server would
        cut is unsafe, or of type 1 and not a ``marker``), the model unchanged."""
        if self.fatal:
            return None
        pending = self.pending
        buf = pending + unit if pending else unit
        end = len(buf)
        pos = 0
        prefix = self.prefix
        type1 = 0
        fatal_at = -1
        while end - pos >= 4:
            if prefix is None:
                prefix = detect(buf)
                if prefix is None:
                    fatal_at = pos
                    break
            (length,) = prefix.unpack_from(buf, pos)
            if length < 12 or length > self.max_length:
                fatal_at = pos
                break
            stop = pos + 4 + length
            if stop > end:
                break
            frame = buf if pos == 0 and stop == end else buf[pos:stop]
            msg_type = prefix.unpack_from(frame, 4)[0]
            if msg_type == PING:
                if not marker:
                    return None
                type1 += 1
            elif msg_type in self.rare and self.rng.random() >= 0.02:
                return None
            if unsafe_reason(frame) is not None:
                return None
            pos = stop
        self.prefix = prefix
        self.type1 += type1
        if fatal_at >= 0:
            self.fatal = True
            self.pending = b""
            keep = fatal_at + 4 + min(8, end - fatal_at - 4) - len(pending)
            return unit[: max(keep, 0)]
        self.pending = buf[pos:] if pos < end else b""
        return unit

    def filler(self, rng: random.Random) -> bytes | None:
        """Bytes 0x7F/0xFF that complete the incomplete frame the server holds (``None`` if there is
        none, or its length prefix is not complete): a way out when no generated unit may follow."""
        if len(self.pending) < 4 or self.prefix is None:
            return None
        missing = 4 + self.prefix.unpack_from(self.pending, 0)[0] - len(self.pending)
        return poison_bytes(rng, missing)
