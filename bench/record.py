"""Record benchmark: what ``robot-server --record FILE`` writes for a moving robot, and how long
writing it holds up the server's exit.

    python bench/record.py [--seconds S] [--repeat N]

The paper's robot (6 joints, 1 ms servo ticks) moves all the time (random targets within half
the limits, velocity ratio 0.5, the next one queued as the robot nears the last) for S seconds (default 60,
the default ``--record-seconds``) on the simulated clock, into one :class:`~robot_server.Recorder`.
Then the same record is written each way, in the same run so that the machine's load weighs on
all of them alike: ``before`` is the writer this project had until the record was made bounded
(``csv.writer``, ``repr`` of every value: 17 significant digits), then today's ``Recorder.save``
by suffix: ``.csv`` (9 decimals, numpy-vectorised), ``.csv.gz`` (the same, gzip level 1),
``.npz`` (exact float64 columns, deflate level 1). Each write is timed N times (default 2); the
table shows the shortest (wall clock, and the process's CPU time, which a busy machine inflates
less), the size, the size per second of record and the largest difference
between a value read back and the value recorded.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import tempfile
import time
from pathlib import Path

import numpy as np

from robot_server import Recorder, load_model
from robot_server.control import Controller, ControllerConfig, Point
from robot_server.control.recorder import _ORDER


def moving_record(seconds: float) -> tuple[Recorder, tuple[str, ...]]:
    model = load_model("jibot_zxs")
    controller = Controller(model, ControllerConfig(policy="quintic"))
    recorder = Recorder(model.dof, capacity=round(seconds / controller.config.servo_period))
    controller.start(Point(np.zeros(model.dof)))
    rng = np.random.default_rng(1)
    while controller.time < seconds - 1e-9:
        if controller.remaining < 0.1:
            controller.add(Point(rng.uniform(0.5 * model.lower, 0.5 * model.upper), velocity_ratio=0.5))
        controller.run_for(min(0.1, seconds - controller.time), recorder)
    return recorder, model.joint_names


def before(recorder: Recorder, path: Path, names: tuple[str, ...]) -> None:
    """The writer before: one ``repr`` per value, through :mod:`csv`."""
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(recorder.header(names))
        times = recorder.time()
        start = float(times[0])
        data = np.concatenate([recorder.get(q) for q in _ORDER], axis=1)
        rows = zip(times.tolist(), data.tolist(), recorder.points().tolist(), recorder.tool().tolist(), strict=True)
        for t, row, n, tcp in rows:
            writer.writerow([repr(t - start)] + [repr(x) for x in row] + [repr(t), n] + [repr(x) for x in tcp])


def read_back(path: Path) -> np.ndarray:
    if path.suffix == ".npz":
        with np.load(path) as archive:
            return np.column_stack([archive[name] for name in archive.files])
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as stream:
        return np.loadtxt(stream, delimiter=",", skiprows=1)


def read_back_reference(recorder: Recorder, names: tuple[str, ...]) -> np.ndarray:
    """The recorded values, as the columns of the file."""
    times = recorder.time()
    data = np.concatenate([recorder.get(q) for q in _ORDER], axis=1)
    return np.column_stack([times - times[0], data, times, recorder.points(), recorder.tool()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds of record (default: %(default)g)")
    parser.add_argument("--repeat", type=int, default=2, help="writes of each kind, the shortest shown")
    args = parser.parse_args()
    recorder, names = moving_record(args.seconds)
    reference = read_back_reference(recorder, names)
    print(f"{len(recorder)} ticks ({args.seconds:g} s of a moving 6-joint robot), {reference.shape[1]} columns\n")
    print("| format | size (MB) | MB per second of record | write (s) | CPU (s) | largest difference read back |")
    print("|---|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as folder:
        kinds = [
            ("before: .csv, repr", Path(folder, "before.csv"), lambda p: before(recorder, p, names)),
            ("now: .csv", Path(folder, "now.csv"), lambda p: recorder.save(p, names)),
            ("now: .csv.gz", Path(folder, "now.csv.gz"), lambda p: recorder.save(p, names)),
            ("now: .npz", Path(folder, "now.npz"), lambda p: recorder.save(p, names)),
        ]
        for label, path, write in kinds:
            times, cpu = [], []
            for _ in range(max(1, args.repeat)):
                began, used = time.perf_counter(), time.process_time()
                write(path)
                times.append(time.perf_counter() - began)
                cpu.append(time.process_time() - used)
            size = path.stat().st_size / 1e6
            error = float(np.nanmax(np.abs(read_back(path) - reference)))
            cells = [label, f"{size:.1f}", f"{size / args.seconds:.3f}", f"{min(times):.2f}", f"{min(cpu):.2f}"]
            print("| " + " | ".join([*cells, f"{error:.1e}"]) + " |")


if __name__ == "__main__":
    main()
