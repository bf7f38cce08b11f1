"""The scripts of ``examples/`` run as their docstrings say, each in a fresh interpreter, and
print what they promise; their README lists every one of them.

Each runs in a temporary directory (an example that writes a file writes it there, not into the
checkout) with the checkout first on ``PYTHONPATH``, bounded by a timeout.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
SCRIPTS = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
#: a line each script prints when it did what it shows
EXPECTED = {
    "01_frames.py": "each frame re-encodes byte for byte",
    "02_decode_capture.py": "motoman_fs100_simple_move.pcapng: 164 messages",
    "03_vendor_message.py": "reply: BELT_STATE SUCCESS",
    "04_stream_trajectory.py": "of the goal: True",
    "05_conformance.py": "no rule FAILed",
    "06_drive_robot.py": "stopped halfway: at rest at",
    "07_record_capture.py": "JOINT_TRAJ_PT SERVICE_REPLY",
}
#: the ones that start an emulator and move its robot in real time (a few seconds each)
SLOW = {"04_stream_trajectory.py", "05_conformance.py", "06_drive_robot.py"}
#: one script's bound (s): the longest takes about 5 s on two cores
TIMEOUT = 90.0


def test_there_are_examples_and_each_has_its_expected_line() -> None:
    assert len(SCRIPTS) >= 5
    assert set(SCRIPTS) == set(EXPECTED)


@pytest.mark.parametrize("script", [pytest.param(s, marks=[pytest.mark.slow] if s in SLOW else []) for s in SCRIPTS])
def test_the_example_runs(script: str, tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / script)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
        check=False,
    )
    output = f"{done.stdout}\n{done.stderr}"
    assert done.returncode == 0, f"{script} exited {done.returncode}:\n{output}"
    assert EXPECTED[script] in done.stdout, f"{script} did not print {EXPECTED[script]!r}:\n{output}"
    assert "Traceback" not in done.stderr, output


@pytest.mark.parametrize("script", SCRIPTS)
def test_the_example_says_what_it_shows_and_how_to_run_it(script: str) -> None:
    doc = ast.get_docstring(ast.parse((EXAMPLES / script).read_text(encoding="utf-8")))
    assert doc is not None and doc.startswith(f"{script[:2]}: "), f"{script}: no docstring, or not numbered"
    assert f"Run: python examples/{script}" in doc


def test_the_examples_readme_lists_every_script_and_nothing_else() -> None:
    readme = (EXAMPLES / "README.md").read_text(encoding="utf-8")
    listed = re.findall(r"^\* \[([0-9][0-9]_\w+\.py)\]\(\1\)", readme, re.MULTILINE)
    assert listed == SCRIPTS
    for target in re.findall(r"\]\(([^)#\s]+)\)", readme):
        assert (EXAMPLES / target).exists(), f"examples/README.md links to {target}, which is missing"
