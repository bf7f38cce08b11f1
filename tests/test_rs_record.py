"""The record's files (``robot-server --record``, :meth:`Recorder.save`): the CSV's number format,
its size per second of a moving robot, the gzip and ``.npz`` forms, and what the command says it
wrote. The recorder's ring buffer and columns themselves: tests/test_rs_controller.py."""

from __future__ import annotations

import gzip
import io
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from client.trajectory import Trajectory
from robot_server import cli
from robot_server.control import Controller, ControllerConfig, Point, Recorder
from robot_server.control.controller import Tick
from robot_server.control.csvnumbers import CSV_DECIMALS, format_rows, format_value
from robot_server.control.recorder import QUANTITIES, record_format
from robot_server.loader import load_model

MODEL = load_model("jibot_zxs")
N = MODEL.dof
SERVO = 0.001
#: the largest difference between a CSV value and the double recorded: half the last decimal, and
#: as much again for the rounding of value x 1e9 (values below about 9e6)
PRECISION = 10.0**-CSV_DECIMALS


def moving(seconds: float, capacity: int) -> Recorder:
    """A recorder of the last ``capacity`` ticks of ``seconds`` of a robot moving all the time."""
    ctl = Controller(MODEL, ControllerConfig(policy="quintic", servo_period=SERVO))
    recorder = Recorder(N, capacity=capacity)
    ctl.start(Point(np.zeros(N)))
    rng = np.random.default_rng(7)
    while ctl.time < seconds - 1e-9:
        if ctl.remaining < 0.1:
            ctl.add(Point(rng.uniform(0.5 * MODEL.lower, 0.5 * MODEL.upper), velocity_ratio=0.5))
        ctl.run_for(min(0.1, seconds - ctl.time), recorder)
    return recorder


@pytest.fixture(scope="module")
def record() -> Recorder:
    """2.5 s of motion, the last 2 s kept: the ring has wrapped."""
    return moving(2.5, capacity=2000)


def recorded(recorder: Recorder) -> np.ndarray:
    """The values the files hold, in the header's order."""
    times = recorder.time()
    order = ["actual_position", "actual_velocity", "actual_acceleration", "command_position"]
    order += ["command_velocity", "command_acceleration", "following_error"]
    data = np.concatenate([recorder.get(q) for q in order], axis=1)
    return np.column_stack([times - times[0], data, times, recorder.points(), recorder.tool()])


# -- the number format -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (0.0, "0.0"),
        (-0.0, "0.0"),
        (1.0, "1.0"),
        (-1.25, "-1.25"),
        (0.151, "0.151"),
        (3600.001, "3600.001"),
        (1e-9, "0.000000001"),
        (-4e-10, "0.0"),  # below the last decimal
        (0.1 + 0.2, "0.3"),  # not 0.30000000000000004
        (-123456.5, "-123456.5"),
        (12345678.25, "12345678.25"),  # beyond the vectorised range: formatted alone, the same way
        (999999999.5, "999999999.5"),
        (2.5e9, "2500000000"),  # 1e9 and more: 12 significant digits
        (float("nan"), "nan"),
        (float("inf"), "inf"),
        (float("-inf"), "-inf"),
    ],
)
def test_a_value_is_written_to_nine_decimals_without_trailing_zeros(value: float, text: str) -> None:
    assert format_value(value) == text
    assert format_rows(np.array([[value, value]]), np.array([False, False])).decode() == f"{text},{text}\n"


def test_whole_columns_are_written_as_whole_numbers() -> None:
    values = np.array([[0.0, 0.5], [2.0, -0.25], [123456789.0, 1.0], [-7.0, 2.0]])
    whole = np.array([True, False])
    assert format_rows(values, whole).decode().splitlines() == ["0,0.5", "2,-0.25", "123456789,1.0", "-7,2.0"]
    assert [format_value(v, whole=True) for v in values[:, 0]] == ["0", "2", "123456789", "-7"]


def test_values_of_every_magnitude_read_back_within_the_last_decimal() -> None:
    rng = np.random.default_rng(3)
    values = rng.standard_normal(40_000) * 10.0 ** rng.integers(-12, 12, 40_000)
    values[::997] = np.nan
    values[1::1009] = np.inf
    values[2::1013] = -np.inf
    values = values.reshape(-1, 8)
    lines = format_rows(values, np.zeros(8, dtype=bool)).decode().splitlines()
    back = np.array([[float(cell) for cell in line.split(",")] for line in lines])
    assert back.shape == values.shape
    assert np.array_equal(np.isnan(back), np.isnan(values)) and np.array_equal(
        back[np.isinf(values)], values[np.isinf(values)]
    )
    fixed = np.isfinite(values) & (np.abs(values) < 1e9)
    assert np.all(np.abs(back[fixed] - values[fixed]) <= PRECISION)
    huge = np.isfinite(values) & ~fixed
    assert np.allclose(back[huge], values[huge], rtol=1e-11, atol=0.0)  # 12 significant digits
    # the same text as the one-value formatter, but for the last decimal of a value that lies within
    # a rounding error of half of it
    reference = [[format_value(v) for v in row] for row in values.tolist()]
    same = sum(
        cell == ref
        for line, row in zip(lines, reference, strict=True)
        for cell, ref in zip(line.split(","), row, strict=True)
    )
    assert same >= 0.99 * values.size


# -- the record's files ----------------------------------------------------------------------------


def test_the_csv_holds_the_kept_ticks_oldest_first_within_the_last_decimal(record: Recorder, tmp_path: Path) -> None:
    assert len(record) == 2000 and record.dropped == 500
    path = tmp_path / "run.csv"
    size = record.save(path, MODEL.joint_names)
    assert size == path.stat().st_size
    text = path.read_text()
    header = text.splitlines()[0].split(",")
    assert header == record.header(MODEL.joint_names) and "\r" not in text
    back = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = recorded(record)
    assert back.shape == expected.shape == (2000, 1 + 7 * N + 2 + 17)
    assert np.all(np.abs(back - expected) <= PRECISION)
    assert back[0, 0] == 0.0 and np.all(np.diff(back[:, 0]) > 0)  # oldest first, across the ring's wrap
    points = header.index("record.points")
    assert all(cell.isdigit() for cell in (line.split(",")[points] for line in text.splitlines()[1:]))
    # a text stream gets the same
    stream = io.StringIO()
    record.to_csv(stream, MODEL.joint_names)
    assert stream.getvalue() == text
    # still the trajectory layout: robot-client run replays it
    trajectory = Trajectory.load(path)
    assert trajectory.joint_names == MODEL.joint_names and len(trajectory) == 2000
    assert np.all(np.abs(trajectory.positions - record.get("actual_position")) <= PRECISION)


def test_a_moving_robot_costs_under_0_8_mb_a_second_of_csv_and_the_default_window_bounds_it(
    record: Recorder, tmp_path: Path
) -> None:
    path = tmp_path / "run.csv"
    record.save(path, MODEL.joint_names)
    per_second = path.stat().st_size / (len(record) * SERVO)
    assert per_second < 0.8e6  # 1.2 MB with repr (17 significant digits) before
    defaults = cli.parser().parse_args([])
    assert defaults.record_seconds == cli.DEFAULT_RECORD_SECONDS == 60.0
    assert per_second * defaults.record_seconds < 50e6  # the default record: under 50 MB
    # compressed: a third (gzip), a half (the exact doubles, deflated)
    for name, most in (("run.csv.gz", 0.3e6), ("run.npz", 0.4e6)):
        record.save(tmp_path / name, MODEL.joint_names)
        assert (tmp_path / name).stat().st_size / (len(record) * SERVO) < most, name


def test_a_csv_gz_is_the_same_csv_compressed(record: Recorder, tmp_path: Path) -> None:
    plain, packed = tmp_path / "run.csv", tmp_path / "run.csv.gz"
    record.save(plain, MODEL.joint_names)
    record.save(packed, MODEL.joint_names)
    assert gzip.decompress(packed.read_bytes()) == plain.read_bytes()
    assert np.array_equal(np.loadtxt(packed, delimiter=",", skiprows=1), np.loadtxt(plain, delimiter=",", skiprows=1))


def test_an_npz_holds_every_column_exactly_under_its_name(record: Recorder, tmp_path: Path) -> None:
    path = tmp_path / "run.npz"
    record.save(path, MODEL.joint_names)
    header = record.header(MODEL.joint_names)
    with np.load(path) as archive:
        assert archive.files == header
        back = np.column_stack([archive[name] for name in header])
        assert archive["record.points"].dtype == np.int64
        assert np.array_equal(archive["record.controller_time"], record.time())
    assert np.array_equal(back, recorded(record), equal_nan=True)


def test_an_empty_record_writes_its_header_alone(tmp_path: Path) -> None:
    empty = Recorder(N, capacity=10)
    empty.save(tmp_path / "run.csv", MODEL.joint_names)
    assert (tmp_path / "run.csv").read_text() == ",".join(empty.header(MODEL.joint_names)) + "\n"
    empty.save(tmp_path / "run.npz", MODEL.joint_names)
    with np.load(tmp_path / "run.npz") as archive:
        assert all(archive[name].size == 0 for name in archive.files)


def test_the_format_follows_the_name() -> None:
    assert [record_format(Path(n)) for n in ("a.csv", "a.CSV.GZ", "a.gz", "a.npz", "a", "a.txt")] == [
        "csv",
        "csv.gz",
        "csv.gz",
        "npz",
        "csv",
        "csv",
    ]
    names = ["run.csv", "run.csv.gz", "run.npz", "run", "run.txt"]
    assert [cli.record_path(Path(n), 1).name for n in names] == [
        "run.g1.csv",
        "run.g1.csv.gz",
        "run.g1.npz",
        "run.g1.csv",
        "run.g1.txt",
    ]
    assert cli.record_path(Path("d/run.csv.gz"), 0) == Path("d/run.csv.gz")


# -- what robot-server says --------------------------------------------------------------------------


def test_the_command_logs_what_each_file_holds(
    record: Recorder, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    whole = Recorder(N, capacity=3000)  # a second group at rest, without a TCP, that kept every tick
    zeros = np.zeros(N)
    for tick in range(1200):
        whole.add(Tick(tick * SERVO, *[zeros] * 7, points=0, tool=None))  # type: ignore[arg-type]
    group = SimpleNamespace(model=MODEL)
    emulator = SimpleNamespace(cell=SimpleNamespace(config=SimpleNamespace(servo_period=SERVO), groups=[group, group]))
    caplog.set_level(logging.INFO, logger="robot_server")
    cli.write_records(str(tmp_path / "run.csv.gz"), [record, whole], emulator)  # type: ignore[arg-type]
    messages = [r.getMessage() for r in caplog.records]
    first = tmp_path / "run.csv.gz"
    second = tmp_path / "run.g1.csv.gz"
    assert messages[0].startswith(f"record of group 0: 2000 ticks written to {first} (the last 2.0 s, ")
    assert messages[0].endswith("; 500 older ticks dropped, beyond --record-seconds 2)")
    assert f"{first.stat().st_size / 1e6:.1f} MB" in messages[0]
    assert messages[1].startswith(f"record of group 1: 1200 ticks written to {second} (the last 1.2 s, ")
    assert "dropped" not in messages[1]
    with gzip.open(second, "rt") as stream:
        lines = stream.read().splitlines()
    assert len(lines) == 1201 and lines[1].endswith(
        ",0,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan,nan"
    )


@pytest.fixture(scope="module")
def ticks() -> list[Tick]:
    """3000 ticks of a robot that moves, some of them without a TCP (as a tick of step_period)."""
    ctl = Controller(MODEL, ControllerConfig(policy="quintic", servo_period=SERVO))
    ctl.start(Point(np.zeros(N)))
    ctl.add(Point(0.3 * MODEL.upper, velocity_ratio=0.5))
    made = [ctl.step() for _ in range(3000)]
    return [t._replace(tool=None) if k < 7 or 1500 <= k < 1530 else t for k, t in enumerate(made)]


@pytest.mark.parametrize("decimation", [1, 3])
@pytest.mark.parametrize("capacity", [1, 10, 1000, 1024, 1500, 5000])
def test_a_recorder_holds_exactly_the_last_ticks_it_was_given(
    ticks: list[Tick], capacity: int, decimation: int
) -> None:
    """The ticks are written into the ring a block at a time: read in the middle of a block, across
    blocks, with a ring smaller or larger than a block, every value is the tick's own."""
    recorder = Recorder(N, capacity=capacity, decimation=decimation)
    for k, tick in enumerate(ticks):
        recorder.add(tick)
        if k in (2, 700, 1023, 2100):  # a read between two adds flushes; the adds go on after it
            kept = ticks[: k + 1 : decimation]
            assert len(recorder) == min(capacity, len(kept))
            assert recorder.time()[-1] == kept[-1].time
    kept = ticks[::decimation][-capacity:]
    assert len(recorder) == len(kept)
    assert recorder.dropped == max(0, len(ticks[::decimation]) - capacity)
    assert np.array_equal(recorder.time(), [t.time for t in kept])
    for index, quantity in enumerate(QUANTITIES):
        assert np.array_equal(recorder.get(quantity), [t[1 + index] for t in kept]), quantity
    assert np.array_equal(recorder.points(), [t.points for t in kept])
    tools = [[*t.tool.values(), t.tool.time] if t.tool is not None else [np.nan] * 17 for t in kept]
    assert np.array_equal(recorder.tool(), tools, equal_nan=True)
    assert ticks[0].tool is None and ticks[-1].tool is not None
    copy = recorder.copy()
    assert np.array_equal(copy.get("actual_position"), recorder.get("actual_position"))
    assert copy.dropped == recorder.dropped
    recorder.clear()
    assert len(recorder) == 0 and recorder.time().size == 0


def test_a_malformed_tick_is_refused_whole_and_the_block_keeps_the_others(ticks: list[Tick]) -> None:
    recorder = Recorder(N, capacity=100)
    for tick in ticks[:10]:
        recorder.add(tick)
    with pytest.raises(ValueError, match=f"a recorded tick holds 7 sequences of {N} numbers"):
        recorder.add(ticks[10]._replace(actual_position=[0.0] * (N - 1)))
    with pytest.raises(ValueError, match=f"a recorded tick holds 7 sequences of {N} numbers"):
        recorder.add(ticks[10]._replace(command_velocity=None))  # type: ignore[arg-type]
    for tick in ticks[10:20]:
        recorder.add(tick)
    assert len(recorder) == 20 and np.array_equal(recorder.time(), [t.time for t in ticks[:20]])

    class Drives:
        position = [0.0] * N
        velocity = [0.0] * (N + 1)
        acceleration = [0.0] * N

    ends = (ticks[0][1:4], ticks[1][1:4])
    with pytest.raises(ValueError, match=f"the drives' state holds 3 sequences of {N} numbers"):
        recorder.add_between(1.0, 0.5, ends, Drives(), points=0, tool=None)
    Drives.velocity = [0.0] * N
    with pytest.raises(ValueError, match=f"a setpoint holds position, velocity and acceleration of {N} joints"):
        recorder.add_between(1.0, 0.5, (ends[0], ends[1][:2]), Drives(), points=0, tool=None)  # type: ignore[arg-type]
    recorder.add_between(1.0, 0.5, ends, Drives(), points=0, tool=None)
    assert len(recorder) == 21 and recorder.time()[-1] == 1.0
    expected = 0.5 * np.array(ticks[0].command_position) + 0.5 * np.array(ticks[1].command_position)
    assert np.array_equal(recorder.get("command_position")[-1], expected)
    assert np.array_equal(recorder.get("following_error")[-1], expected)  # the actual position is 0


def test_an_instants_ring_too_short_for_the_record_is_an_error_not_a_wrong_tcp() -> None:
    ctl = Controller(MODEL, ControllerConfig(servo_period=SERVO))
    ctl.add_move(0.3 * MODEL.upper, speed=0.05)
    short = Recorder(N, 400, tool_meter=ctl.tool_meter, instants=3)
    for _ in range(300):
        ctl.step_period(short)
    with pytest.raises(ValueError, match="ring of 3 instants is too short for its 400 ticks"):
        short.tool()
    with pytest.raises(ValueError, match="too short"):
        short.tool_time()
