"""How a failed motion assertion is told: the message of a :class:`~.assertions.MotionAssertionError`
and the plot beside it.

The checks of :mod:`.assertions` decide that a motion failed and the facts of it (where, when, the
value, the bound, the excess); this module writes them out for a person. The message's first line
says where, when and by how much; the lines after it say what else went wrong (the worst of the
excursion, the other excursions, whether the robot had been within tolerance before), then come
small tables of the motion: the ticks around the first violation, or how the motion ended. Given a
``plot_dir`` and with matplotlib installed (the ``plot`` extra), :func:`draw` draws the offending
quantity over that stretch of time into a PNG file there, and the message names the file. Each
function of a failure returns the message and the file drawn (or None).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..arrays import Array

if TYPE_CHECKING:
    from ..model import RobotModel
    from .assertions import _Found, _Series

#: rows of the table around a violation, before its first tick and after it
CONTEXT = 3
#: samples in the table of how a joint ended (assert_reached)
TAIL = 8


# -- the failures ---------------------------------------------------------------------------------


def out_of_bounds(
    name: str,
    s: _Series,
    f: _Found,
    excess: Array,
    others: Sequence[tuple[_Series, _Found, Array]],
    *,
    value: float,
    bound: float,
    duration: float | None,
    plot_dir: str | Path | None,
    extra: Sequence[str] = (),
    full: tuple[Array, Array] | None = None,
    marks: Sequence[tuple[float, str]] = (),
) -> tuple[str, Path | None]:
    """The earliest violation ``f`` of the series ``s`` (``excess`` is its excess per row and
    column), with ``others``, the first violation of each other series that had one. ``value`` is
    beyond ``bound`` for ``duration`` seconds (None: to the end of the record). ``extra`` are lines
    of the check's own; ``full`` (times, and that series' values) is what to plot instead of the
    checked ticks, ``marks`` times to draw as lines, with their labels."""
    c, t, v = f.column, s.times, s.values[:, f.column]
    unit = s.units[c]
    above = value > bound
    bound_name = s.bound_names[1 if above else 0]
    first_excess = float(excess[f.first, c])
    if duration is not None:
        lasted = f"for {duration * 1000:.4g} ms (back within at t = {t[f.last + 1]:.4f} s)"
    else:
        lasted = f"and was still beyond it at the end of the record (t = {t[-1]:.4f} s)"
    direction = "above" if above else "below"
    lines = [
        f"{name}: {s.where[c]} {s.what} {s.went} {direction} {bound_name} at t = {t[f.first]:.4f} s "
        f"{lasted}: {value:.6g} {unit} {'>' if above else '<'} {bound:.6g} {unit}, by {first_excess:.4g} {unit}"
    ]
    if f.worst != f.first:
        lines.append(
            f"the worst of that excursion: {v[f.worst]:.6g} {unit}, by {excess[f.worst, c]:.4g} {unit} "
            f"at t = {t[f.worst]:.4f} s"
        )
    if f.excursions > 1 or others:
        row, column = f.largest
        names = ", ".join(dict.fromkeys(s.where[j] for j in f.columns))
        lines.append(
            f"{f.excursions} excursion(s) of the {s.what} in all (on {names}); the largest: "
            f"{s.where[column]}, by {excess[row, column]:.4g} {s.units[column]} at t = {t[row]:.4f} s"
        )
        for other, g, other_excess in others:
            oc = g.column
            beyond = other.bound_names[0 if other.values[g.first, oc] < other.low[oc] else 1]
            lines.append(
                f"also: {other.where[oc]} {other.what} beyond {beyond} from t = {other.times[g.first]:.4f} s, "
                f"by {other_excess[g.first, oc]:.4g} {other.units[oc]}"
            )
    lines.extend(extra)
    lines.append(around(s, f, excess, unit))
    plot_times, plot_values = (full[0], full[1][:, c]) if full is not None else (t, v)
    plot, said = draw(
        plot_dir,
        name,
        f"{s.where[c]} {s.what}",
        unit=unit,
        times=plot_times,
        values=plot_values,
        bound=bound,
        span=(float(t[f.first]), float(t[f.last])),
        marks=marks,
    )
    if said:
        lines.append(said)
    return "\n".join(lines), plot


def joints_off(
    name: str,
    model: RobotModel,
    times: Array,
    positions: Array,
    *,
    side: str,
    index: NDArray[np.intp],
    target: Array,
    tol: Array,
    units: tuple[str, ...],
    error: Array,
    excess: Array,
    k: int,
    inside: NDArray[np.bool_],
    plot_dir: str | Path | None,
) -> tuple[str, Path | None]:
    """The joints ``index`` ended (the last row of ``positions``) out of ``tol`` of ``target``:
    ``error`` per row and joint checked, ``excess`` beyond the tolerance at the end, ``k`` the
    joint checked that is told of (the farthest out, relative to its tolerance), ``inside`` the
    rows where every joint checked was within tolerance."""
    j = int(index[k])
    joint, unit = model.joint_names[j], units[j]
    lines = [
        f"{name}: {joint} {side} position ended {abs(error[-1, k]):.4g} {unit} from its target at "
        f"t = {times[-1]:.4f} s: {positions[-1, j]:.6g} {unit}, target {target[k]:.6g} {unit}, "
        f"tolerance {tol[k]:.4g} {unit}, by {excess[k]:.4g} {unit} beyond it",
        history(inside, times, np.max(np.abs(error) / tol, axis=1), "the target"),
        table(
            ("", "joint", "target", side, "error", "tolerance"),
            [
                (
                    "*" if excess[i] > 0 else "",
                    model.joint_names[int(jj)],
                    f"{target[i]:.6g}",
                    f"{positions[-1, int(jj)]:.6g}",
                    f"{error[-1, i]:+.4g}",
                    f"{tol[i]:.4g} {units[int(jj)]}",
                )
                for i, jj in enumerate(index)
            ],
        ),
        tail(times, positions[:, j], f"{joint} {side} position", unit, target[k]),
    ]
    what = f"{joint} {side} position"
    plot, said = draw(plot_dir, name, what, unit=unit, times=times, values=positions[:, j], band=(target[k], tol[k]))
    if said:
        lines.append(said)
    return "\n".join(lines), plot


def position_off(
    name: str,
    times: Array,
    *,
    side: str,
    position: Array,
    xyz: Array,
    offset: Array,
    distance: Array,
    angle: Array,
    tol: float,
    angle_tol: float,
    axis: int,
    inside: NDArray[np.bool_],
    plot_dir: str | Path | None,
) -> tuple[str, Path | None]:
    """The TCP (``xyz`` per instant, ``offset`` from the target ``position``, at ``distance``
    from it and turned ``angle`` from its orientation) ended out of ``tol`` of the target
    position; ``axis`` is the one of its largest offset, ``inside`` the instants within both
    tolerances."""
    lines = [
        f"{name}: the {side} TCP ended {distance[-1]:.4g} m from the target position at t = {times[-1]:.4f} s "
        f"(tolerance {tol:.4g} m, by {distance[-1] - tol:.4g} m beyond it); the largest offset is along "
        f"{'xyz'[axis]}: {offset[-1, axis]:+.4g} m",
        history(inside, times, np.maximum(distance / tol, angle / angle_tol), "the target pose"),
        table(
            ("axis", "target (m)", f"{side} (m)", "offset (m)"),
            [(a, f"{position[i]:.6g}", f"{xyz[-1, i]:.6g}", f"{offset[-1, i]:+.4g}") for i, a in enumerate("xyz")],
        ),
        tail(times, distance, f"TCP distance from the target ({side})", "m"),
    ]
    plot, said = draw(
        plot_dir, name, f"TCP distance from the target ({side})", unit="m", times=times, values=distance, bound=tol
    )
    if said:
        lines.append(said)
    return "\n".join(lines), plot


def orientation_off(
    name: str,
    times: Array,
    *,
    side: str,
    quaternion: Array,
    orientation: Array,
    distance: Array,
    angle: Array,
    tol: float,
    angle_tol: float,
    inside: NDArray[np.bool_],
    plot_dir: str | Path | None,
) -> tuple[str, Path | None]:
    """The TCP (``quaternion`` per instant, ``angle`` from the target ``orientation``, at
    ``distance`` from the target position) ended turned beyond ``angle_tol``; ``inside`` are the
    instants within both tolerances."""
    lines = [
        f"{name}: the {side} TCP ended turned {angle[-1]:.4g} rad from the target orientation at t = "
        f"{times[-1]:.4f} s (tolerance {angle_tol:.4g} rad, by {angle[-1] - angle_tol:.4g} rad beyond it): "
        f"(qw, qx, qy, qz) = ({', '.join(f'{x:.6g}' for x in quaternion[-1])}), target "
        f"({', '.join(f'{x:.6g}' for x in orientation)})",
        history(inside, times, np.maximum(distance / tol, angle / angle_tol), "the target pose"),
        tail(times, angle, f"TCP angle from the target ({side})", "rad"),
    ]
    plot, said = draw(
        plot_dir,
        name,
        f"TCP angle from the target ({side})",
        unit="rad",
        times=times,
        values=angle,
        bound=angle_tol,
    )
    if said:
        lines.append(said)
    return "\n".join(lines), plot


# -- the parts of a message -----------------------------------------------------------------------


def around(s: _Series, f: _Found, excess: Array, unit: str) -> str:
    """The table of the offending column around its first violation (``*``: beyond the bound)."""
    n = s.times.size
    picked = sorted(
        {*range(max(0, f.first - CONTEXT), min(n, f.first + CONTEXT + 1)), f.worst, f.last, min(n - 1, f.last + 1)}
    )
    c = f.column
    rows: list[tuple[str, ...]] = []
    previous = None
    for i in picked:
        if previous is not None and i > previous + 1:
            rows.append(("", "...", "", ""))
        e = float(excess[i, c])
        rows.append(("*" if e > 0 else "", f"{s.times[i]:.4f}", f"{s.values[i, c]:.6g}", f"{e:.4g}" if e > 0 else ""))
        previous = i
    return table(("", "time (s)", f"{s.where[c]} {s.what} ({unit})", f"excess ({unit})"), rows)


def history(inside: NDArray[np.bool_], times: Array, ratio: Array, what: str) -> str:
    """Whether, and when, the robot had been within tolerance of ``what`` before it ended out of it."""
    if not inside.any():
        k = int(np.argmin(ratio))
        closest = f"closest at t = {times[k]:.4f} s ({ratio[k]:.3g} x the tolerance)"
        return f"it never came within tolerance of {what}; {closest}"
    last = int(np.flatnonzero(inside)[-1])
    outside = np.flatnonzero(~inside[: last + 1])
    begin = int(outside[-1]) + 1 if outside.size else 0
    return (
        f"it was within tolerance of {what} from t = {times[begin]:.4f} s to t = {times[last]:.4f} s, "
        f"then left it at t = {times[last + 1]:.4f} s"
    )


def tail(times: Array, values: Array, what: str, unit: str, target: float | None = None) -> str:
    """How ``values`` ended: a few samples over the last second of the record."""
    n = times.size
    begin = int(np.searchsorted(times, times[-1] - 1.0))
    picked = np.unique(np.linspace(begin, n - 1, min(TAIL, n - begin)).round().astype(int))
    header = ("time (s)", f"{what} ({unit})") + (() if target is None else (f"minus target ({unit})",))
    rows = [
        (f"{times[i]:.4f}", f"{values[i]:.6g}") + (() if target is None else (f"{values[i] - target:+.4g}",))
        for i in picked
    ]
    return "how it ended:\n" + table(header, rows)


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Right-aligned columns, indented by two spaces."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    lines = ["  ".join(cell.rjust(w) for cell, w in zip(row, widths, strict=True)) for row in [header, *rows]]
    return "\n".join("  " + line.rstrip() for line in lines)


def draw(
    plot_dir: str | Path | None,
    name: str,
    what: str,
    *,
    unit: str,
    times: Array,
    values: Array,
    bound: float | None = None,
    band: tuple[float, float] | None = None,
    span: tuple[float, float] | None = None,
    marks: Sequence[tuple[float, str]] = (),
) -> tuple[Path | None, str]:
    """Draw ``values`` over the stretch of time around ``span`` (the violation) into a PNG under
    ``plot_dir``; returns the file and the line the message says about it."""
    if plot_dir is None:
        return None, ""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        return None, "plot: not drawn (matplotlib is not installed; the project's plot extra installs it)"
    if span is not None:
        pad = max(0.25, span[1] - span[0])
        shown = (times >= span[0] - pad) & (times <= span[1] + pad)
    else:
        shown = times >= times[-1] - 5.0  # how it ended: the last seconds
    for mark, _ in marks:
        shown |= times >= mark - 0.05
    figure = Figure(figsize=(7.0, 3.2), layout="constrained")
    axes = figure.subplots()
    axes.plot(times[shown], values[shown], linewidth=1.0, label=what)
    if bound is not None and math.isfinite(bound):
        axes.axhline(bound, color="tab:red", linewidth=0.8, linestyle="--", label=f"bound {bound:.6g} {unit}")
    if band is not None:
        centre, width = band
        axes.axhspan(centre - width, centre + width, color="tab:green", alpha=0.2, label="target ± tolerance")
    if span is not None:
        axes.axvspan(span[0], max(span[1], span[0] + 1e-4), color="tab:red", alpha=0.15, label="violation")
    for (mark, label), style in zip(marks, (":", "-."), strict=False):
        axes.axvline(mark, color="grey", linewidth=0.8, linestyle=style, label=label)
    axes.set_xlabel("controller time (s)")
    axes.set_ylabel(f"{what} ({unit})")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best", fontsize=7)
    axes.set_title(f"{name}: {what}", fontsize=9)
    folder = Path(plot_dir)
    folder.mkdir(parents=True, exist_ok=True)
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{name}-{what}").strip("_")
    path = folder / f"{stem}.png"
    number = 1
    while path.exists():
        number += 1
        path = folder / f"{stem}-{number}.png"
    figure.savefig(path, dpi=100)
    return path, f"plot: {path}"
