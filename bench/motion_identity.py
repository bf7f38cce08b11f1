"""Motion identity: does a change to the controller's planning leave every motion bit for bit as it was?

    python bench/motion_identity.py record FILE.npz     # run every case, keep the servo ticks and log lines
    python bench/motion_identity.py compare OLD.npz NEW.npz

For refactoring the control layer (issue 37 split the motion queue into functions with it). The
streaming benchmark (``bench/streaming.py``) runs servers in real time, so two runs of the same code
give different records; here the controller runs in process on its own stepped clock, so the same
code gives the same record, and a refactoring must too. The cases are the streaming benchmark's
trajectories (dense 2 s and 1 s, sparse, over-fast, JOINT_TRAJ_PT_FULL 2 s and 1 s) for jibot_zxs
and puma560, under every interpolation policy: streamed one point every 1, 5 and 12 ms, all at once,
with gaps (the queue runs dry), stopped part way, cut off half way and downloaded; FULL points also
positions-only, on the MotoROS controller settings (cubics run as given, increment feed-forward),
with the start check off, and as two motion groups sharing one time scale (``min_scale``). Each run
keeps every servo tick's command position, velocity and acceleration and the actual position, and
the log lines of the ``robot_server`` loggers; ``compare`` says which runs differ (exit 1 if any).
About a minute on 2 cores.
"""

from __future__ import annotations

import argparse
import io
import logging
import sys
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from robot_server.control import POLICIES
from robot_server.control.controller import Controller, ControllerConfig, submit_together
from robot_server.control.points import Point, PointRejected
from robot_server.loader import load_model
from robot_server.model import RobotModel

sys.path.insert(0, str(Path(__file__).resolve().parent))
from streaming import CASES, Trajectory, traj_pt_messages

Rows = list[np.ndarray]
LOG = "robot_server"


def _row(tick: object) -> np.ndarray:
    t = tick  # a Tick: command position, velocity, acceleration, actual position
    return np.array([*t.command_position, *t.command_velocity, *t.command_acceleration, *t.actual_position])  # type: ignore[attr-defined]


def _stream(
    controllers: Sequence[Controller],
    points: Sequence[Sequence[Point]],
    every: int,
    log: io.StringIO,
    *,
    gaps: Sequence[int] = (),
    stop_at: int | None = None,
) -> Rows:
    """Points arriving one per ``every`` ticks (0: all in the first tick), to one controller or to
    several together (motion groups, ``submit_together``); the first group's ticks are kept."""
    rows: Rows = []
    count = len(points[0])
    tick = sent = 0
    next_tick = 0
    lead = controllers[0]
    while (sent < count or lead.moving or tick < 10) and tick < 40_000:
        while sent < count and tick >= next_tick:
            pairs = [(c, p[sent]) for c, p in zip(controllers, points, strict=True)]
            try:
                if len(pairs) > 1:
                    submit_together(pairs, first=sent == 0)
                elif sent == 0:
                    lead.start(pairs[0][1])
                else:
                    lead.add(pairs[0][1])
                log.write(f"{tick} ok {sent}\n")
            except PointRejected as exc:
                log.write(f"{tick} refused {sent} {exc}\n")
            sent += 1
            next_tick = tick + every + (gaps[sent] if sent < len(gaps) else 0)
        if stop_at is not None and tick == stop_at:
            log.write(f"{tick} stop {lead.stop()!r}\n")
        rows.append(_row(lead.step()))
        for other in controllers[1:]:
            other.step()
        tick += 1
    rows.extend(_row(lead.step()) for _ in range(50))
    return rows


def _download(controller: Controller, points: Sequence[Point], log: io.StringIO) -> Rows:
    try:
        controller.start_download(points[0])
        for p in points[1:-1]:
            controller.add(p)
        controller.finish_download(points[-1])
        log.write("download ok\n")
    except PointRejected as exc:
        log.write(f"download refused {exc}\n")
    rows: Rows = []
    for _ in range(12_000):
        rows.append(_row(controller.step()))
        if not controller.moving and len(rows) > 100:
            break
    return rows


Run = Callable[[io.StringIO], Rows]


def _cases(model: RobotModel) -> list[tuple[str, Run]]:
    """Every run for ``model``, each bound to its own points (``partial``: nothing late-bound)."""
    q0 = np.clip(np.zeros(model.dof), model.lower, model.upper)
    runs: list[tuple[str, Run]] = []

    def make(**settings: Any) -> Controller:
        return Controller(model, ControllerConfig(**settings))

    def streamed(
        settings: list[dict[str, Any]], points: list[list[Point]], every: int, log: io.StringIO, **kw: Any
    ) -> Rows:
        return _stream([make(**s) for s in settings], points, every, log, **kw)

    def downloaded(settings: dict[str, Any], points: list[Point], log: io.StringIO) -> Rows:
        return _download(make(**settings), points, log)

    for case in CASES:
        if case.profile != "generic":
            continue
        traj = Trajectory.plan(q0, case.planned_duration(model), case.points)
        name = f"{model.name}/{case.slug}"
        if case.full:
            full = [
                Point(traj.positions[j], traj.velocities[j], traj.accelerations[j], time=float(traj.times[j]))
                for j in range(len(traj))
            ]
            bare = [Point(traj.positions[j], time=float(traj.times[j])) for j in range(len(traj))]
            slower = [
                Point(0.5 * traj.positions[j], 0.5 * traj.velocities[j], time=float(traj.times[j]))
                for j in range(len(traj))
            ]
            motoros = {"follow_given_acceleration": True, "increment_feedforward": True}
            runs += [
                (f"{name}/every1", partial(streamed, [{}], [full], 1)),
                (f"{name}/every5", partial(streamed, [{}], [full], 5)),
                (f"{name}/download", partial(downloaded, {}, full)),
                (f"{name}/motoros", partial(streamed, [motoros], [full], 5)),
                (f"{name}/no-start-check", partial(streamed, [{"start_tolerance": None}], [full], 5)),
                (f"{name}/groups", partial(streamed, [{}, {}], [full, slower], 5)),
            ]
            runs += [
                (f"{name}/positions-only/{p}", partial(streamed, [{"policy": p}], [bare], 5)) for p in sorted(POLICIES)
            ]
            continue
        points = [
            Point(
                np.array(m.joint_data[: model.dof], dtype=float),
                duration=float(m.duration),
                velocity_ratio=float(m.velocity),
            )
            for m in traj_pt_messages(traj, model)
        ]
        half = points[: len(points) // 2 + 1]
        gaps = [40 if i >= 5 and (i - 5) % 7 == 0 else 0 for i in range(len(points))]
        for policy in sorted(POLICIES):
            s = [{"policy": policy}]
            key = f"{name}/{policy}"
            runs += [
                (f"{key}/every1", partial(streamed, s, [points], 1)),
                (f"{key}/every5", partial(streamed, s, [points], 5)),
                (f"{key}/gaps", partial(streamed, s, [points], 5, gaps=gaps)),
                (f"{key}/stop", partial(streamed, s, [points], 5, stop_at=300)),
                (f"{key}/download", partial(downloaded, s[0], points)),
                (f"{key}/truncated", partial(streamed, s, [half], 5)),
                (f"{key}/burst", partial(streamed, s, [half], 0)),
                (f"{key}/slow", partial(streamed, s, [half], 12)),
            ]
    return runs


def record(path: Path) -> None:
    handler_text = io.StringIO()
    handler = logging.StreamHandler(handler_text)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s %(message)s"))
    logger = logging.getLogger(LOG)
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    arrays: dict[str, np.ndarray] = {}
    logs: dict[str, str] = {}
    for name in ("jibot_zxs", "puma560"):
        for key, run in _cases(load_model(name)):
            handler_text.seek(0)
            handler_text.truncate()
            own = io.StringIO()
            arrays[key] = np.array(run(own))
            logs[key] = own.getvalue() + handler_text.getvalue()
    np.savez_compressed(path, **arrays, __logs__=np.array([f"{k}\n{v}" for k, v in logs.items()]))
    print(f"{path}: {len(arrays)} runs, {sum(a.shape[0] for a in arrays.values())} servo ticks")


def compare(old: Path, new: Path) -> int:
    a, b = np.load(old), np.load(new)
    names = sorted(set(a.files) | set(b.files) - {"__logs__"})
    differ = [n for n in names if n not in a.files or n not in b.files or not np.array_equal(a[n], b[n])]
    logs_a = dict(s.split("\n", 1) for s in a["__logs__"].tolist())
    logs_b = dict(s.split("\n", 1) for s in b["__logs__"].tolist())
    log_differ = sorted(k for k in set(logs_a) | set(logs_b) if logs_a.get(k) != logs_b.get(k))
    for name in differ:
        print(f"differs: {name}")
    for name in log_differ:
        print(f"log differs: {name}")
    runs = len([n for n in names if n != "__logs__"])
    print(f"{runs} runs: {len(differ)} differ in their servo ticks, {len(log_differ)} in their log lines")
    return 1 if differ or log_differ else 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("record", help="run every case and write FILE.npz").add_argument("file", type=Path)
    cmp = commands.add_parser("compare", help="say which runs differ between two records")
    cmp.add_argument("old", type=Path)
    cmp.add_argument("new", type=Path)
    args = parser.parse_args(argv)
    if args.command == "record":
        record(args.file)
        return 0
    return compare(args.old, args.new)


if __name__ == "__main__":
    sys.exit(main())
