"""Helpers for reading this project's TOML files strictly: the name a misspelled one was meant to be."""

from __future__ import annotations

import difflib
from collections.abc import Callable, Mapping, Sequence

__all__ = ["closest", "did_you_mean", "show"]


def closest(name: str, known: Sequence[str], aliases: Mapping[str, str] | None = None) -> str | None:
    """The known name ``name`` was most likely meant to be: the one ``aliases`` gives for it (a
    synonym no spelling resembles: ``tcp`` for ``tool``), else the closest by
    :func:`difflib.get_close_matches` (case-insensitive), else None."""
    alias = (aliases or {}).get(name.lower())
    if alias is not None and alias in known:
        return alias
    lowered = {k.lower(): k for k in known}
    close = difflib.get_close_matches(name.lower(), list(lowered), n=1)
    return lowered[close[0]] if close else None


def did_you_mean(
    name: str, known: Sequence[str], style: Callable[[str], str] = str, aliases: Mapping[str, str] | None = None
) -> str:
    """The end of an "unknown name" message: ``; did you mean X?`` for the :func:`closest` known
    name, else ``(known: A, B, ...)``. ``style`` writes a name the way the file writes it
    (``[limits]`` for a table)."""
    match = closest(name, known, aliases)
    if match is not None:
        return f"; did you mean {style(match)}?"
    return f" (known: {', '.join(style(k) for k in known)})"


def show(value: float) -> str:
    """A number as a file would write it: ``130`` rather than ``130.0``, ``572.958`` as is."""
    if value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(value)
