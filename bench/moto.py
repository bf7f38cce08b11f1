"""ra-mtp-ntnu/moto against the emulator's two-group MotoROS profile: does ``Moto(...)`` connect, and do its
motion, state and IO operations work? (that issue's acceptance check)

    python bench/moto.py [--moto PATH] [--connects 20]

moto (Apache-2.0) is not on PyPI (PyPI's ``moto`` is an AWS mock): ``--moto`` names a checkout of
https://github.com/ra-mtp-ntnu/moto, else an installed ``moto`` is used if it is that package. One ``robot-server
--profile motoros`` child (jibot_zxs + puma560, free ports read from its ready line) serves everything; moto's
hard-coded ports (class attributes) are set to its. Every moto socket has a 5 s timeout (connect, each recv).

**Connect**: ``--connects`` fresh ``Moto("127.0.0.1", [R1 group 0, R2 group 1])``, each closed afterwards (moto has
no close: its state reader is stopped and joined, its sockets closed). The constructor waits up to 5 s for a STATUS,
a JOINT_FEEDBACK and a JOINT_FEEDBACK_EX, decoding only the first message of each recv(1024), so each state message
must arrive alone. One that raises is a failure (text shown). Time: the constructor's, median and max.

**Operations**, on one more instance, a row each: STATUS and feedback; trajectory mode; a 3-point
JOINT_TRAJ_PT_FULL_EX for both groups (BUSY retried every 50 ms for at most 5 s: moto does not), queue counts,
in_motion 1 then 0, both groups within 1e-3 rad of the last point; a JOINT_TRAJ_PT_FULL for group 0, STOP_MOTION;
SELECT_TOOL (valid; INVALID 3017); GET_DH_PARAMETERS; STOP_TRAJ_MODE; servos off and on; RESET_ALARM; IO bits, groups
and error codes; "state reader": no moto state thread died on its own. Exit 0 if every row passes, else 1; 2 if moto
is not found. The table on stdout, progress on stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import re
import selectors
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, NoReturn

BENCH = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != BENCH]  # this moto.py must not shadow moto

HOST = "127.0.0.1"
COMMAND = ["-m", "robot_server", "--profile", "motoros", "--model", "jibot_zxs", "--model", "puma560"]
COMMAND += ["--motion-port", "0", "--state-port", "0", "--io-port", "0", "--no-stdin"]
TIMEOUT = 5.0  # every moto socket: connect and each recv (s)
TOL = 1e-3  # rad
BUSY_BACKOFF, BUSY_WAIT = 0.05, 5.0
REPO = "https://github.com/ra-mtp-ntnu/moto"


@dataclass
class Row:
    name: str
    passed: bool = False
    detail: str = ""


CLOSED: set[threading.Thread] = set()  # state readers this script stopped: their exceptions are expected
DIED: list[str] = []


def hook(args: threading.ExceptHookArgs) -> None:
    if args.thread not in CLOSED:
        DIED.append(f"{args.exc_type.__name__}: {args.exc_value}")


def die(message: str) -> NoReturn:
    print(f"error: {message}\nget moto: git clone {REPO}, then: python bench/moto.py --moto PATH", file=sys.stderr)
    sys.exit(2)


def load_moto(path: Path | None) -> Any:
    if path is not None:
        path = path.resolve()
        if not (path / "setup.py").is_file() or not (path / "moto" / "__init__.py").is_file():
            die(f"{path} is not a checkout of ra-mtp-ntnu/moto (setup.py and a moto/ package)")
        sys.path.insert(0, str(path))
    try:
        moto: Any = importlib.import_module("moto")
    except ImportError as e:
        die(f"moto cannot be imported ({e})")
    if not hasattr(moto, "Moto"):
        die(f"the moto found ({moto.__file__}) is not ra-mtp-ntnu/moto (PyPI's moto is an unrelated AWS mock)")
    return moto


def machine() -> str:
    sys.path.insert(0, str(BENCH))
    try:
        codec: Any = importlib.import_module("codec")  # bench/codec.py
    finally:
        sys.path.remove(str(BENCH))
    return str(codec.machine())


def start_server(log: IO[bytes]) -> tuple[subprocess.Popen[bytes], dict[str, int], str]:
    """The child and the ports of its ready line (read for at most 30 s)."""
    pipe = subprocess.PIPE
    proc = subprocess.Popen(
        [sys.executable, *COMMAND], cwd=BENCH.parent, stdin=subprocess.DEVNULL, stdout=pipe, stderr=log
    )
    assert proc.stdout is not None
    line, deadline = b"", time.monotonic() + 30.0
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while not line.endswith(b"\n") and (left := deadline - time.monotonic()) > 0:
            if sel.select(left):
                if not (chunk := os.read(proc.stdout.fileno(), 4096)):
                    break
                line += chunk
    text = line.decode(errors="replace").strip()
    return proc, {k: int(v) for k, v in re.findall(r"(motion|state|io) [\d.]+:(\d+)", text)}, text


def stop_server(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15.0)
        except subprocess.TimeoutExpired:
            print("robot-server did not exit within 15 s of SIGINT: killed", file=sys.stderr)
            proc.kill()
            proc.wait(10.0)


def construct(moto: Any) -> tuple[Any, float, str | None]:
    """A fresh Moto(...) for both groups (kept even when its constructor raises), the constructor's time, the error."""
    joints = [f"joint_{i}" for i in range(1, 7)]
    groups = [moto.ControlGroupDefinition(f"R{g + 1}", g, 6, joints) for g in (0, 1)]
    m = moto.Moto.__new__(moto.Moto)
    begin = time.perf_counter()
    try:
        m.__init__(HOST, groups)
    except Exception as e:
        return m, time.perf_counter() - begin, f"{type(e).__name__}: {e}"
    return m, time.perf_counter() - begin, None


def close(m: Any) -> None:
    """moto has no close: stop the state reader (it leaves after its next message), then close the sockets."""
    if (state := getattr(m, "_state_connection", None)) is not None:
        CLOSED.add(state._worker_thread)
        state._stop.set()
        if state._worker_thread.ident is not None:
            state._worker_thread.join(1.0)
    for name in ("_motion_connection", "_state_connection", "_io_connection", "_real_time_motion_connection"):
        if (conn := getattr(m, name, None)) is not None:
            with contextlib.suppress(OSError):
                conn._tcp_client._socket.shutdown(socket.SHUT_RDWR)  # wakes a reader still in recv()
            conn._tcp_client._socket.close()


def wait_for(pred: Callable[[], bool], timeout: float) -> str | None:
    """How long until pred() held (polled every 10 ms), or None if it did not within timeout."""
    start = time.monotonic()
    while not pred():
        if time.monotonic() - start > timeout:
            return None
        time.sleep(0.01)
    return f"{time.monotonic() - start:.2f} s"


@contextlib.contextmanager
def check(rows: list[Row], name: str) -> Iterator[Row]:
    """A table row: its block sets passed and detail; an exception fails it with its text."""
    print(f"  {name}", file=sys.stderr)
    row = Row(name)
    try:
        yield row
    except Exception as e:
        row.passed, row.detail = False, f"raised {type(e).__name__}: {e}"
    rows.append(row)


def operations(moto: Any, m: Any) -> list[Row]:
    sm, rows, zeros = moto.simple_message, list[Row](), [0.0] * 10
    ok, busy, true = sm.ResultType.SUCCESS, sm.ResultType.BUSY, sm.Ternary.TRUE
    valid = sm.ValidFields.TIME | sm.ValidFields.POSITION | sm.ValidFields.VELOCITY
    status, group = m.state.robot_status, m.control_groups

    def res(r: Any) -> str:
        return f"{getattr(r.body.result, 'name', r.body.result)} {int(r.body.subcode)}"

    def reply(name: str, call: Callable[[], Any], expected: str = "SUCCESS 0") -> None:
        with check(rows, f"motion: {name}") as row:
            row.detail = res(call())
            row.passed = row.detail == expected

    def send(pt: Any) -> tuple[Any, int]:
        retries, deadline = 0, time.monotonic() + BUSY_WAIT
        while (r := m.motion.send_joint_trajectory_point(pt)).body.result is busy and time.monotonic() < deadline:
            retries += 1
            time.sleep(BUSY_BACKOFF)
        return r, retries

    ex = m.state.joint_feedback_ex()
    start = [list(ex.joint_feedback_data[g].pos) for g in (0, 1)]

    def shifted(d: float) -> list[list[float]]:  # joint 1 of both groups moved by d
        return [[q[0] + d, *q[1:]] for q in start]

    with check(rows, "state: robot_status") as row:
        s, fields = status(), ("drives_powered", "e_stopped", "in_error", "in_motion", "mode", "motion_possible")
        row.detail = ", ".join(f"{f} {getattr(s, f).name}" for f in fields)
        row.passed = s.drives_powered is true and s.in_error.name == "FALSE" and s.mode.name == "AUTO"
    for g in (0, 1):
        with check(rows, f"state: joint_feedback group {g}") as row:
            row.detail = f"no JOINT_FEEDBACK of group {g} decoded within 2 s"
            if wait_for(lambda: m.state.joint_feedback(g) is not None, 2.0):  # noqa: B023 (called at once)
                f = m.state.joint_feedback(g)
                row.detail = (
                    f"groupno {f.groupno}, valid_fields {int(f.valid_fields)}, pos {[round(x, 3) for x in f.pos[:6]]}"
                )
                row.passed = f.groupno == g and len(f.pos) == 10
    with check(rows, "state: joint_feedback_ex") as row:
        groups = [f.groupno for f in ex.joint_feedback_data]
        row.passed, row.detail = groups == [0, 1], f"{ex.number_of_valid_groups} groups: {groups}"
    with check(rows, "motion: check_motion_ready / start_trajectory_mode") as row:
        before, begin = m.motion.check_motion_ready(), m.motion.start_trajectory_mode()
        after = m.motion.check_motion_ready()
        row.passed = before.body.result is not ok and begin.body.result is ok and after.body.result is ok
        row.detail = f"ready {res(before)}; START_TRAJ_MODE {res(begin)}; ready {res(after)}"
    with check(rows, "motion: JOINT_TRAJ_PT_FULL_EX, 3 points, 2 groups") as row:
        replies = []
        for seq, t, d in ((0, 0.0, 0.0), (1, 1.0, 0.2), (2, 2.0, 0.3)):
            data = [sm.JointTrajPtExData(g, valid, t, shifted(d)[g], zeros, zeros) for g in (0, 1)]
            replies.append(send(sm.JointTrajPtFullEx(2, seq, data)))
        row.passed = all(r.body.result is ok for r, _ in replies)
        row.detail = "; ".join(f"seq {i} {res(r)} after {n} BUSY" for i, (r, n) in enumerate(replies))
    with check(rows, "motion: check_queue_count") as row:
        replies = [(group[f"R{g + 1}"].check_queue_count(), g) for g in (0, 1)]
        row.passed = all(r.body.result is ok and int(r.body.subcode) >= 0 for r, _ in replies)
        row.detail = ", ".join(f"group {g} {res(r)}" for r, g in replies) + " (count in subcode)"
    with check(rows, "motion: STATUS in_motion 1 then 0") as row:
        up = wait_for(lambda: status().in_motion is true, 3.0)
        down = wait_for(lambda: status().in_motion.name == "FALSE", 12.0) if up else None
        row.passed, row.detail = bool(up and down), f"in_motion 1 after {up}, then 0 after {down} more"
    with check(rows, "motion: last point reached") as row:

        def error() -> float:
            pos = [(p, q) for g in (0, 1) for p, q in zip(group[f"R{g + 1}"].position, shifted(0.3)[g], strict=False)]
            return float(max(abs(p - q) for p, q in pos))

        row.passed = wait_for(lambda: error() <= TOL, 3.0) is not None
        row.detail = f"largest joint error {error():.1e} rad (both groups, joint 1 moved by 0.3 rad)"
    with check(rows, "motion: JOINT_TRAJ_PT_FULL group 0") as row:
        q = list(m.state.joint_feedback(0).pos)
        first = send(sm.JointTrajPtFull(0, 0, valid, 0.0, q, zeros, zeros))[0]
        second, retries = send(sm.JointTrajPtFull(0, 1, valid, 1.0, [q[0] - 0.2, *q[1:]], zeros, zeros))
        row.passed = first.body.result is ok and second.body.result is ok
        row.detail = f"seq 0 {res(first)}; seq 1 (-0.2 rad) {res(second)} after {retries} BUSY"
    with check(rows, "motion: stop_motion") as row:
        time.sleep(0.2)  # moving
        r = m.motion.stop_motion()
        rest = wait_for(lambda: status().in_motion.name == "FALSE", 3.0)
        row.passed, row.detail = r.body.result is ok and rest is not None, f"{res(r)}; in_motion 0 after {rest}"
    reply("select_tool(0, 1)", lambda: m.motion.select_tool(0, 1))
    reply("select_tool(0, 99)", lambda: m.motion.select_tool(0, 99), "INVALID 3017")
    with check(rows, "motion: get_dh_parameters") as row:
        dh = m.motion.get_dh_parameters().body.dh_parameters
        links = [sum(any((k.theta, k.d, k.a, k.alpha)) for k in dh[g].link) for g in range(len(dh))]
        row.passed, row.detail = links[0] > 0 and links[1] > 0, f"non-zero links per group: {links}"
    reply("stop_trajectory_mode", m.motion.stop_trajectory_mode)
    with check(rows, "motion: stop_servos / start_servos") as row:
        off = m.motion.stop_servos()
        t_off = wait_for(lambda: status().drives_powered.name == "FALSE", 3.0)
        on = m.motion.start_servos()
        t_on = wait_for(lambda: status().drives_powered is true, 3.0)
        row.passed = off.body.result is ok and on.body.result is ok and None not in (t_off, t_on)
        row.detail = f"STOP_SERVOS {res(off)}, drives off after {t_off}; START_SERVOS {res(on)}, on after {t_on}"
    reply("reset_alarm", m._motion_connection.reset_alarm)  # not on the Motion facade
    for kind, address, value in (("bit", 27010, 1), ("group", 1001, 42)):
        with check(rows, f"io: read/write {kind}") as row:
            read, write = getattr(m.io, f"read_{kind}"), getattr(m.io, f"write_{kind}")
            old, w, new, back = read(address).body, write(address, value).body, read(address).body, write(address, 0)
            row.passed = new.value == value and 0 == int(w.result_code) == int(back.body.result_code)
            row.detail = f"{address}: read {old.value} {old.result_code.name}; write {value} {w.result_code.name}; "
            row.detail += f"read {new.value} {new.result_code.name}"
    with check(rows, "io: invalid address / value") as row:
        codes = [int(m.io.read_bit(9).body.result_code), int(m.io.write_bit(10, 1).body.result_code)]
        codes.append(int(m.io.write_group(1001, 300).body.result_code))
        row.passed = codes == [1001, 1002, 1003]
        row.detail = f"read bit 9, write input bit 10, write group 1001 = 300: result codes {codes}"
    return rows


def run(moto: Any, connects: int, ports: dict[str, int]) -> tuple[list[Row], list[float], Counter[str]]:
    moto.motion_connection.MotionConnection.TCP_PORT_MOTION = ports["motion"]
    moto.state_connection.StateConnection.TCP_PORT_STATE = ports["state"]
    moto.io_connection.IoConnection.TCP_PORT_IO = ports["io"]
    times: list[float] = []
    failures: Counter[str] = Counter()
    for i in range(connects):
        m, seconds, error = construct(moto)
        close(m)
        times.append(seconds)
        if error is not None:
            failures[error] += 1
        print(f"connect {i + 1}/{connects}: {seconds:.3f} s {error or ''}", file=sys.stderr)
    seen = "".join(f"; {n}x {text}" for text, n in failures.items())
    rows = [Row(f"connect: Moto(...) x {connects}", not failures, f"{connects - failures.total()} connected{seen}")]
    print("operations", file=sys.stderr)
    for attempt in (1, 2, 3):
        m, _, error = construct(moto)
        if error is None:
            rows.append(Row("operations: Moto(...)", True, f"connected at attempt {attempt}"))
            break
        close(m)
    else:
        return [*rows, Row("operations", False, f"Moto(...) failed 3 times ({error}): nothing tested")], times, failures
    try:
        rows += operations(moto, m)
        alive = m._state_connection._worker_thread.is_alive()
    finally:
        close(m)
    return [*rows, Row("state reader", alive and not DIED, f"alive {alive}; died: {DIED or 'none'}")], times, failures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--moto", type=Path, metavar="PATH", help=f"a checkout of {REPO} (default: the installed moto)")
    parser.add_argument("--connects", type=int, default=20, metavar="N", help="Moto(...) constructions timed (20)")
    args = parser.parse_args()
    if args.connects < 1:
        parser.error("--connects must be >= 1")
    moto = load_moto(args.moto)
    threading.excepthook = hook
    socket.setdefaulttimeout(TIMEOUT)
    with tempfile.TemporaryFile() as log:
        proc, ports, ready = start_server(log)
        try:
            if not {"motion", "state", "io"} <= ports.keys():
                log.seek(0)
                sys.exit(f"robot-server did not start: {ready or log.read().decode(errors='replace')[-500:]}")
            rows, times, failures = run(moto, args.connects, ports)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            sys.exit(130)
        finally:
            stop_server(proc)
    print(f"# ra-mtp-ntnu/moto against robot-server --profile motoros (two groups): {machine()}")
    print(f"\nmoto: {Path(moto.__file__).parent}\nemulator: python {' '.join(COMMAND)}\nready line: {ready}\n")
    print("| check | result | detail |\n|---|---|---|")
    for row in rows:
        print(f"| {row.name} | {'PASS' if row.passed else 'FAIL'} | {row.detail.replace('|', '/')} |")
    print(
        "\nNot tested (moto bugs: they cannot work against any MotoROS controller): `m.rt.*` (its port 50243 exists "
        "only in a MotoROS fork), `m.motion.disconnect()` (MotoROS closes without a reply: moto raises struct.error)."
    )
    print(
        f"\nconnect: N {args.connects}, successes {args.connects - failures.total()}, "
        f"median {statistics.median(times):.3f} s, max {max(times):.3f} s"
    )
    sys.exit(0 if all(row.passed for row in rows) else 1)


if __name__ == "__main__":
    main()
