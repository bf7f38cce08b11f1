"""The simple-message command: decode and encode, hex lines and raw streams, errors."""

from __future__ import annotations

import contextlib
import io
import json
import os
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from simple_message import BE32, BE64, LE32, JointTrajPt, Status
from simple_message.cli import main

from .refdata import DATA, load_vectors


def run(
    argv: list[str],
    stdin: str | bytes = "",
    monkeypatch: pytest.MonkeyPatch | None = None,
    capsys: pytest.CaptureFixture[str] | None = None,
) -> tuple[int, list[dict], list[dict]]:  # type: ignore[type-arg]
    assert monkeypatch is not None and capsys is not None
    if isinstance(stdin, bytes):
        buf = io.BytesIO(stdin)
        monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(buf))
    else:
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    code = main(argv)
    out, err = capsys.readouterr()
    return (
        code,
        [json.loads(line) for line in out.splitlines() if line.startswith("{")],
        [json.loads(line) for line in err.splitlines() if line.startswith("{")],
    )


def test_decode_vector_file(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(["decode", str(DATA / "vectors_le.txt")], monkeypatch=monkeypatch, capsys=capsys)
    assert code == 0 and err == []
    assert len(out) == 26
    pt = next(o for o in out if o["label"] == "JOINT_TRAJ_PT_REQUEST_SEQ3")
    assert pt["msg_type"] == 11 and pt["name"] == "JOINT_TRAJ_PT" and pt["comm_type"] == 2 and pt["reply_code"] == 0
    assert pt["body"] == {
        "sequence": 3,
        "joint_data": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.0, 0.0, 0.0, 0.0],
        "velocity": 0.5,
        "duration": 1.25,
    }
    status = next(o for o in out if o["label"] == "STATUS_TOPIC_ERROR")
    assert status["body"] == {
        "drives_powered": -1,
        "e_stopped": 1,
        "error_code": 1234,
        "in_error": 1,
        "in_motion": 0,
        "mode": 1,
        "motion_possible": 0,
    }
    full = next(o for o in out if o["label"] == "JOINT_TRAJ_PT_FULL_REQUEST")
    assert set(full["body"]) == {
        "robot_id",
        "sequence",
        "valid_fields",
        "time",
        "positions",
        "velocities",
        "accelerations",
    }
    unknown = next(o for o in out if o["label"] == "UNHANDLED_TYPE_9999_REPLY_FAILURE")
    assert unknown["body"] == {"raw": ""} and unknown["name"] == "UNKNOWN"
    ack = next(o for o in out if o["label"] == "JOINT_TRAJ_PT_REPLY_SUCCESS")
    assert ack["body"] == {}


def test_decode_then_encode_is_byte_exact(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    for fname, order in (("vectors_le.txt", "little"), ("vectors_be.txt", "big")):
        _, out, _ = run(["decode", "--byte-order", order, str(DATA / fname)], monkeypatch=monkeypatch, capsys=capsys)
        lines = "\n".join(json.dumps(o) for o in out)
        monkeypatch.setattr(sys, "stdin", io.StringIO(lines))
        assert main(["encode", "--byte-order", order]) == 0
        hex_out = capsys.readouterr().out.split()
        assert [bytes.fromhex(h) for h in hex_out] == [v.frame for v in load_vectors(fname)]


def test_decode_autodetects_each_line(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(
        ["decode", "--byte-order", "auto", str(DATA / "motoman_fs100_simple_move.segments.txt")],
        monkeypatch=monkeypatch,
        capsys=capsys,
    )
    assert code == 0 and len(out) == 164
    assert out[0]["label"].split()[1:] == ["50241", "55753"]


def test_decode_raw_stream_and_errors(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    stream = Status().encode(BE32) + JointTrajPt(1).encode(BE32)
    good = tmp_path / "good.bin"
    good.write_bytes(stream)
    code, out, err = run(["decode", "--raw", "--byte-order", "big", str(good)], monkeypatch=monkeypatch, capsys=capsys)
    assert code == 0 and [o["name"] for o in out] == ["STATUS", "JOINT_TRAJ_PT"] and err == []
    bad = tmp_path / "bad.bin"
    bad.write_bytes(stream + b"\xff\xff\xff\xff" + bytes(20))
    code, out, err = run(["decode", "--raw", "--byte-order", "big", str(bad)], monkeypatch=monkeypatch, capsys=capsys)
    assert code == 1 and len(out) == 2 and err[0]["type"] == "FrameError"


def test_decode_reports_malformed_lines_and_goes_on(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    good = JointTrajPt(1).encode(LE32).hex()
    text = "\n".join(
        [
            "# comment",
            "zz",  # not hex
            "0c000000",  # truncated
            "130000000b0000000200000000000000" + "00" * 7,  # 7-byte body: malformed JOINT_TRAJ_PT
            f"GOOD {good}",
        ]
    )
    code, out, err = run(["decode"], text, monkeypatch=monkeypatch, capsys=capsys)
    assert code == 1
    assert [o["label"] for o in out] == ["GOOD"]
    assert [e["type"] for e in err] == ["BadHex", "TruncatedFrame", "MalformedMessage"]
    assert [e["line"] for e in err] == [2, 3, 4]


def test_encode_json_lines(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    text = "\n".join(
        [
            json.dumps({"name": "JOINT_TRAJ_PT", "body": {"sequence": 0, "joint_data": [0.1, 0.2], "velocity": 0.5}}),
            json.dumps({"msg_type": 11, "comm_type": 3, "reply_code": 1, "body": {}}),
            json.dumps({"msg_type": 9999, "comm_type": 3, "reply_code": 2, "body": {"raw": ""}}),
            json.dumps({"name": "JOINT_FEEDBACK", "body": {"positions": ["NaN", "Infinity"]}}),
            json.dumps({"name": "NOPE"}),
            json.dumps({"name": "PING", "body": {"bogus": 1}}),
            "not json",
        ]
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    assert main(["encode"]) == 1
    captured = capsys.readouterr()
    frames = captured.out.split()
    assert frames[0] == JointTrajPt(0, [0.1, 0.2], 0.5).encode(LE32).hex()
    assert frames[1] == "0c0000000b0000000300000001000000"
    assert frames[2] == "0c0000000f2700000300000002000000"
    assert len(frames) == 4
    errors = [json.loads(e) for e in captured.err.splitlines()]
    assert [e["line"] for e in errors] == [5, 6, 7]
    assert "bogus" in errors[1]["error"]


def test_python_dash_m_entry_point(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "simple_message", "decode", "--byte-order", "big", str(DATA / "vectors_be.txt")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert len(result.stdout.splitlines()) == 26


# -- in process: the paths a user meets (raw streams on stdin/stdout, missing files, interrupts) -----------


def test_decode_raw_from_stdin_reports_a_truncated_tail(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    stream = Status().encode(LE32) + JointTrajPt(7).encode(LE32)
    code, out, err = run(["decode", "--raw"], stream + stream[:10], monkeypatch=monkeypatch, capsys=capsys)
    assert code == 1
    assert [o["name"] for o in out] == ["STATUS", "JOINT_TRAJ_PT"] and out[1]["body"]["sequence"] == 7
    assert err == [{"error": "10 bytes at the end do not make a whole frame", "type": "TruncatedFrame"}]


def test_decode_float64_big_endian(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    frame = JointTrajPt(2, [0.1, -1.5], 0.25, 3.0).encode(BE64)
    argv = ["decode", "--byte-order", "big", "--float64"]
    code, out, _ = run(argv, frame.hex(), monkeypatch=monkeypatch, capsys=capsys)
    assert code == 0
    assert out[0]["body"]["joint_data"][:2] == [0.1, -1.5] and out[0]["body"]["duration"] == 3.0  # 0.1: a double


def test_encode_raw_writes_the_frames_to_stdout(
    monkeypatch: pytest.MonkeyPatch, capsysbinary: pytest.CaptureFixture[bytes]
) -> None:
    lines = [{"name": "PING", "comm_type": 2, "body": {}}, {"name": "JOINT_TRAJ_PT", "body": {"sequence": 4}}]
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(json.dumps(line) for line in lines) + "\n# done\n"))
    assert main(["encode", "--raw", "--byte-order", "big"]) == 0
    out = capsysbinary.readouterr().out
    ping = bytes.fromhex("0000000c000000010000000200000000")
    assert out[: len(ping)] == ping and out[len(ping) :] == JointTrajPt(4).encode(BE32)


def test_a_missing_file_is_one_error_line_and_status_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("decode", "encode"):
        assert main([command, str(tmp_path / "missing.txt")]) == 2
        errors = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
        assert len(errors) == 1 and errors[0]["type"] == "OSError" and "missing.txt" in errors[0]["error"]


class _Interrupted(io.StringIO):
    """Standard input on which the user presses Ctrl-C."""

    def __iter__(self) -> _Interrupted:
        return self

    def __next__(self) -> str:
        raise KeyboardInterrupt


def test_ctrl_c_exits_130(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "stdin", _Interrupted())
    assert main(["decode"]) == 130


def test_a_reader_that_goes_away_ends_the_command_quietly(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    read, write = os.pipe()
    os.close(read)  # `simple-message decode FILE | head`, once head has exited
    stdout = open(write, "w", encoding="utf-8")  # noqa: SIM115 - closed below
    try:
        monkeypatch.setattr(sys, "stdout", stdout)
        frames = tmp_path / "frames.txt"
        frames.write_text("\n".join(JointTrajPt(k).encode(LE32).hex() for k in range(2000)))
        assert main(["decode", str(frames)]) == 0
        assert os.readlink(f"/proc/self/fd/{write}") == os.devnull  # the rest goes nowhere
    finally:
        with contextlib.suppress(OSError):
            stdout.close()


def test_help_and_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0 and "decode" in capsys.readouterr().out
    for argv in ([], ["decode", "--byte-order", "sideways"], ["encode", "--byte-order", "auto"]):
        with pytest.raises(SystemExit) as info:
            main(argv)
        err = capsys.readouterr().err  # one line, which names the help (not argparse's usage block)
        assert info.value.code == 2 and err.startswith("simple-message") and err.count("\n") == 1, err
        assert "error: " in err and "--help')" in err, err


@pytest.mark.usefixtures("plain_imports")
def test_python_dash_m_in_process(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "argv", ["simple_message", "decode", str(DATA / "vectors_le.txt")])
    with pytest.raises(SystemExit) as info:
        runpy.run_module("simple_message", run_name="__main__", alter_sys=True)
    assert info.value.code == 0 and len(capsys.readouterr().out.splitlines()) == 26
