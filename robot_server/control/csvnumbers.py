"""The number format of a CSV record: every value to :data:`CSV_DECIMALS` decimals of its SI unit
(1 nrad, 1 nm, 1 ns) without trailing zeros, a whole number where a column says so.

:func:`format_rows` formats a block of rows with numpy (3-digit groups looked up in tables, not
Python per value: more than ten times faster than ``repr`` with :mod:`csv`); :func:`format_value` is
the same for one value (and the rows' special values: NaN, infinities, 1e9 or more).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["CSV_DECIMALS", "format_rows", "format_value"]

#: decimals of every non-integer value in a CSV record (SI units: 1 nrad, 1 nm, 1 ns)
CSV_DECIMALS = 9
_SCALE = 10**CSV_DECIMALS
#: values this large or larger (none in practice) are written with 12 significant digits
_HUGE = 1e9
#: below this, ``value * _SCALE`` is a double exact to the unit: the vectorised path's limit (about
#: 9e6; larger values are formatted one by one)
_EXACT = 2.0**53 / _SCALE


def _words(texts: Sequence[bytes]) -> NDArray[np.uint32]:
    """Each text (at most 4 bytes), NUL-padded, as one native uint32."""
    raw = b"".join(text.ljust(4, b"\0") for text in texts)
    return np.frombuffer(raw, dtype=np.uint8).copy().view(np.uint32)


# A value is six 4-byte words: sign and millions, thousands, units and the point, then three groups
# of three decimals, the last one followed by the separator; each word is looked up by its 3-digit
# group (plus 1000 x a case), and the NUL bytes that pad them are deleted at the end.
_DIGITS = [f"{i:03d}".encode() for i in range(1000)]
_LEAD = [d.lstrip(b"0") for d in _DIGITS]  # the leading group of a number (0: nothing) ...
_LEAD1 = [d or b"0" for d in _LEAD]  # ... of a number < 1000 (0: "0")
_TRAIL = [d.rstrip(b"0") for d in _DIGITS]  # the last group of decimals (0: nothing) ...
_TRAIL1 = [d or b"0" for d in _TRAIL]  # ... the first one (0: "0", so 1.0, not "1.")
_W_SIGN = _words(_LEAD + [b"-" + d for d in _LEAD])  # millions + 1000 x negative
_W_THOUSANDS = _words(_LEAD + _DIGITS)  # + 1000 x (millions > 0)
_W_UNITS = _words([d + b"." for d in _LEAD1] + [d + b"." for d in _DIGITS] + _LEAD1 + _DIGITS)  # + 2000 x integer
_W_DECIMALS = _words(_TRAIL1 + _DIGITS + [b""] * 1000)  # + 1000 x (more decimals follow), 2000: integer
_W_MICRO = _words(_TRAIL + _DIGITS)  # + 1000 x (more decimals follow)
_W_NANO = _words([d + b"," for d in _TRAIL] + [d + b"\n" for d in _TRAIL])  # + 1000 x last column


def format_rows(
    values: NDArray[np.float64], whole: NDArray[np.bool_], scratch: NDArray[np.uint32] | None = None
) -> bytes:
    """CSV lines of ``values`` (rows, columns): each value rounded to :data:`CSV_DECIMALS` decimals
    without trailing zeros (at least one: ``0.0``, ``-1.25``), or to a whole number in the columns
    ``whole`` marks; ``nan``, ``inf``, ``-inf``; values of 1e9 or more with 12 significant digits.
    The CSV's formatting, vectorised: :func:`format_value` is the same for one value. ``scratch``,
    ``(rows or more, columns, 6)`` uint32, saves allocating the work space on every call."""
    rows, columns = values.shape
    special = ~np.isfinite(values) | (np.abs(values) >= _EXACT)
    plain = np.where(special, 0.0, values) if special.any() else values
    m = np.rint(plain * np.where(whole, 1.0, float(_SCALE))).astype(np.int64)
    negative = m < 0
    m = np.abs(m)
    # (// and a product: np.divmod on int64 takes five times as long)
    integer = np.where(whole, m, m // _SCALE)
    decimals = m - integer * np.where(whole, 1, _SCALE)
    high = integer // 1000
    units = integer - high * 1000
    millions = high // 1000
    thousands = high - millions * 1000
    upper = decimals // 1000
    nano = decimals - upper * 1000
    milli = upper // 1000
    micro = upper - milli * 1000
    words = np.empty((rows, columns, 6), dtype=np.uint32) if scratch is None else scratch[:rows]
    words[..., 0] = _W_SIGN[millions + 1000 * negative]
    words[..., 1] = _W_THOUSANDS[thousands + 1000 * (millions > 0)]
    words[..., 2] = _W_UNITS[units + 1000 * (high > 0) + 2000 * whole]
    words[..., 3] = _W_DECIMALS[milli + np.where(whole, 2000, 1000 * ((micro > 0) | (nano > 0)))]
    words[..., 4] = _W_MICRO[micro + 1000 * (nano > 0)]
    last = np.zeros(columns, dtype=np.int64)
    last[-1] = 1000
    words[..., 5] = _W_NANO[nano + last]  # the separator alone where the value is special (0 there)
    for row, column in zip(*np.nonzero(special), strict=True):
        text = format_value(float(values[row, column]), bool(whole[column])).encode().ljust(20, b"\0")
        words[row, column, :5] = np.frombuffer(text, dtype=np.uint32)
    return words.tobytes().translate(None, b"\0")


def format_value(value: float, whole: bool = False) -> str:
    """One value as :func:`format_rows` writes it."""
    if not np.isfinite(value):
        return "nan" if np.isnan(value) else "inf" if value > 0 else "-inf"
    if abs(value) >= _HUGE:
        return f"{value:.12g}"
    if whole:  # (less than 1e9: 10 characters at most)
        return str(round(value))
    text = f"{value:.{CSV_DECIMALS}f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if text == "-0.0" else text
