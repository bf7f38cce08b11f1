"""Planning cost per point: what the controller spends on one JOINT_TRAJ_PT when it plans it.

    python bench/planning.py [--base DIR] [--rounds N] [--passes N] [--points N] [--policies NAME ...]

In a fleet (``robot-server --fleet``) every streamed point is planned on the event loop's thread,
between the servo ticks of every controller of the process, so what a point costs is what the fleet
can take. Per interpolation policy, a controller (jibot_zxs, default settings) is handed the
streaming benchmark's MoveIt-like trajectory (``bench/streaming.py``: a trapezoidal path parameter
along a joint move plus a bump; by default 401 points over 8 s) as JOINT_TRAJ_PT-like points
(velocity ratio of the critical joint, duration since the previous point, 10 s for the first):

* **streamed**: one point every interpolation period (4 ms) of controller time, the controller
  stepping in between (a point refused for a full queue is offered again at the next period), as a
  streaming client keeps it fed; every ``start``/``add`` call is timed alone and the table gives
  their sum over the points (the steps are not counted). A point refused for another reason counts
  as planned and the next one follows, as industrial_robot_client's streamer goes on after a
  FAILURE: ``quintic`` and ``cubic`` refuse most dense points (from rest to rest in 20 ms is beyond
  the acceleration limit; ``linear`` checks the velocity only, ``ruckig`` takes the time it needs),
  and the table says how many. The first three points, the costliest (the second decides the
  first one's state, from rest), are also given alone: what a client starting a trajectory costs
  the loop at once;
* **downloaded**: ``start_download``, ``add`` for each point, ``finish_download`` (the whole
  trajectory planned at once, slowed down once at the end), timed as a whole, over the points. A
  refused point drops the download: ``finish_download`` stops planning at the first segment beyond
  a limit, so the ``quintic`` and ``cubic`` downloads of dense points cost little.

The numbers are microseconds of the thread's CPU time per point (``time.thread_time``: time that
other jobs on the machine take from this one is not counted, the point's own work is). ``--base
DIR`` measures another checkout too (a git worktree of an earlier commit: ``git worktree add
/tmp/plan-base COMMIT``): each tree runs in its own process with that tree first on ``PYTHONPATH``,
the two alternating round by round, so both are measured in the same run under the same load. Each
process makes ``--passes`` passes per cell after a warm-up pass; the table gives the median over
all passes of all rounds (this VM shares its 2 cores with other jobs: medians, and more rounds,
steady the numbers).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MODES = ("streamed", "downloaded")
#: a trajectory's start: its first points, the costliest (the second point decides the first one's
#: state, from rest: a transient, time-optimal where it must be)
START = 3


Measured = dict[str, dict[str, list[float]]]


def _measure(policies: list[str], points: int, duration: float, passes: int) -> Measured:
    """In this process (whatever ``robot_server`` is first on the path): µs per point, per policy and
    mode, one value per pass; and ``refused``, the points refused while streaming."""
    import numpy as np

    from robot_server.control import POLICIES, Controller, ControllerConfig, Point, PointRejected, Reason
    from robot_server.loader import load_model

    sys.path.insert(0, str(HERE))
    from streaming import Trajectory, traj_pt_messages

    model = load_model("jibot_zxs")
    q0 = np.clip(np.zeros(model.dof), model.lower, model.upper)
    traj = Trajectory.plan(q0, duration, points)
    made = [
        Point(np.array(m.joint_data[: model.dof]), duration=float(m.duration), velocity_ratio=float(m.velocity))
        for m in traj_pt_messages(traj, model)
    ]

    refused: list[float] = []
    starts: list[float] = []

    def streamed(policy: str) -> float:
        ctl = Controller(model, ControllerConfig(policy=policy))
        sub = ctl.servo_ticks_per_interpolation
        spent, sent, ticks, bad = 0.0, 0, 0, 0
        while sent < len(made):
            if sent == START:
                starts.append(spent * 1e6)
            begin = time.thread_time()
            try:
                (ctl.start if sent == 0 else ctl.add)(made[sent])
            except PointRejected as exc:
                if exc.reason is not Reason.QUEUE_FULL:  # planned and refused: the next one follows
                    spent += time.thread_time() - begin
                    sent += 1
                    bad += 1
            else:
                spent += time.thread_time() - begin
                sent += 1
            for _ in range(sub):
                ctl.step()
            ticks += sub
            if ticks > 1_000_000:
                raise RuntimeError("the stream never drained")
        refused.append(bad)
        return spent / len(made) * 1e6

    def downloaded(policy: str) -> float:
        ctl = Controller(model, ControllerConfig(policy=policy, download_capacity=len(made) + 1))
        begin = time.thread_time()
        try:
            ctl.start_download(made[0])
            for point in made[1:-1]:
                ctl.add(point)
            ctl.finish_download(made[-1])
        except PointRejected:
            pass  # dropped whole (module doc)
        return (time.thread_time() - begin) / len(made) * 1e6

    out: Measured = {}
    for name in policies:
        if name not in POLICIES:
            continue
        out[name] = {}
        for mode, run in (("streamed", streamed), ("downloaded", downloaded)):
            run(name)  # warm-up: imports, caches
            out[name][mode] = [run(name) for _ in range(passes)]
        out[name]["refused"] = refused[-1:]
        out[name]["start"] = starts[-passes:]
    return out


def _child(tree: Path, args: argparse.Namespace) -> Measured:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])]))
    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        "_measure",
        "--points",
        str(args.points),
        "--duration",
        str(args.duration),
        "--passes",
        str(args.passes),
        "--policies",
        *args.policies,
    ]
    done = subprocess.run(command, env=env, cwd=tree, capture_output=True, text=True, timeout=1800, check=False)
    if done.returncode != 0:
        raise SystemExit(f"measuring {tree} failed:\n{done.stderr}")
    result = json.loads(done.stdout.splitlines()[-1])
    if not Path(result["module"]).resolve().is_relative_to(tree):
        raise SystemExit(f"measuring {tree} imported robot_server from {result['module']}")
    cells: Measured = result["cells"]
    return cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("action", nargs="?", default="table", choices=("table", "_measure"), help=argparse.SUPPRESS)
    parser.add_argument("--base", type=Path, metavar="DIR", help="another checkout to compare with (a git worktree)")
    parser.add_argument("--rounds", type=int, default=3, help="processes per tree, alternating (3)")
    parser.add_argument("--passes", type=int, default=3, help="passes per cell in each process, after a warm-up (3)")
    parser.add_argument("--points", type=int, default=401, help="points of the trajectory (401)")
    parser.add_argument("--duration", type=float, default=8.0, help="its planned time, s (8)")
    parser.add_argument(
        "--policies", nargs="+", default=["blend", "quintic", "cubic", "linear", "ruckig"], metavar="NAME"
    )
    args = parser.parse_args()
    if args.action == "_measure":
        import robot_server

        cells = _measure(args.policies, args.points, args.duration, args.passes)
        print(json.dumps({"module": robot_server.__file__, "cells": cells}))
        return
    trees = [("this tree", ROOT)]
    if args.base is not None:
        trees.insert(0, ("base", args.base.resolve()))
    samples: dict[str, dict[str, dict[str, list[float]]]] = {label: {} for label, _ in trees}
    for r in range(args.rounds):
        for label, tree in trees:
            print(f"round {r + 1}/{args.rounds}: {label} ({tree})", file=sys.stderr, flush=True)
            for policy, modes in _child(tree, args).items():
                for mode, values in modes.items():
                    samples[label].setdefault(policy, {}).setdefault(mode, []).extend(values)
    print(f"### planning cost per point (us), {args.points} JOINT_TRAJ_PT points over {args.duration:g} s, jibot_zxs")
    print()
    print(f"Median of {args.rounds} x {args.passes} passes per cell; streamed: `start`/`add` alone, one point per 4 ms")
    print("of controller time; downloaded: `start_download` ... `finish_download` as a whole.")
    print()
    last = trees[-1][0]
    if args.base is not None:
        print(
            "| policy | refused (streamed) | streamed before | streamed after | speed-up "
            "| downloaded before | downloaded after | speed-up |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
    else:
        print("| policy | refused (streamed) | streamed | downloaded |")
        print("|---|---:|---:|---:|")
    for policy, modes in samples[last].items():
        cells = [f"{max(modes['refused']):.0f} / {args.points}"]
        for mode in MODES:
            after = statistics.median(modes[mode])
            if args.base is not None and policy in samples["base"]:
                before = statistics.median(samples["base"][policy][mode])
                cells += [f"{before:,.0f}", f"{after:,.0f}", f"{before / after:.2f}x"]
            else:
                cells.append(f"{after:,.0f}")
        print(f"| {policy} | " + " | ".join(cells) + " |")
    print()
    print(f"A trajectory's first {START} points, streamed (us in all: what each client starting a trajectory costs")
    print("the fleet's loop at once):")
    print()
    print("| policy | before | after | speed-up |" if args.base is not None else "| policy | start |")
    print("|---|---:|---:|---:|" if args.base is not None else "|---|---:|")
    for policy, modes in samples[last].items():
        after = statistics.median(modes["start"])
        if args.base is not None and policy in samples["base"]:
            before = statistics.median(samples["base"][policy]["start"])
            print(f"| {policy} | {before:,.0f} | {after:,.0f} | {before / after:.2f}x |")
        else:
            print(f"| {policy} | {after:,.0f} |")


if __name__ == "__main__":
    main()
