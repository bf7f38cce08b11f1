"""The README's quick start draws the paper's Fig. 6: its first command installs what the figure
needs, and the demo it runs writes the figure (run here with ``--simulated``, so in seconds); the
README shows the figure the demo drew."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: one bound for the whole demo on a simulated clock (about 10 s on two cores)
TIMEOUT = 300.0
PNG = b"\x89PNG\r\n\x1a\n"


def quick_start() -> tuple[str, list[str]]:
    """The quick start section's text and its commands (the lines of its sh block but comments)."""
    section = README[README.index("## Quick start") : README.index("\n## ", README.index("## Quick start"))]
    block = re.search(r"^```sh\n(.*?)^```", section, re.MULTILINE | re.DOTALL)
    assert block is not None, "the quick start has no sh block"
    commands = [line for line in block.group(1).splitlines() if line.strip() and not line.startswith("#")]
    return section, commands


def test_the_quick_start_is_two_commands_and_the_first_installs_the_plot_extra() -> None:
    _, commands = quick_start()
    assert len(commands) == 2, commands
    first = commands[0]
    assert first.startswith("python3 -m venv .venv && . .venv/bin/activate && ")
    installs = re.findall(r"pip install -e '\.\[([a-z,]+)\]'", first)
    assert installs, f"the first command installs no extra: {first}"
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    needs = [requirement for name in installs[0].split(",") for requirement in extras[name]]
    assert any(re.match(r"matplotlib\b", requirement) for requirement in needs), needs
    assert first.split(" && ")[-1] == "robot-client demo"


def test_the_readme_shows_the_figure_the_demo_drew() -> None:
    section, _ = quick_start()
    assert "](docs/figures/demo_fig6.png)" in section
    figure = ROOT / "docs" / "figures" / "demo_fig6.png"
    assert figure.read_bytes().startswith(PNG)
    assert "first command's own `demo-output/demo_fig6.png`" in section  # how it was made


@pytest.mark.slow
def test_the_first_commands_demo_writes_the_figure(tmp_path: Path) -> None:
    assert importlib.util.find_spec("matplotlib") is not None, (
        "matplotlib is not installed: the first command installs it (the plot extra), and the dev extra must too"
    )
    _, commands = quick_start()
    demo = shlex.split(commands[0].split(" && ")[-1])
    # as written, on a simulated clock; --embedded: a robot-server someone left on the default ports
    # is not the fresh machine's (there, nothing answers and the demo starts its own emulator)
    argv = [*demo, "--simulated", "--embedded"]
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    figure = tmp_path / "demo-output" / "demo_fig6.png"
    assert "figure: demo-output/demo_fig6.png" in done.stdout.splitlines()
    assert figure.read_bytes().startswith(PNG) and figure.stat().st_size > 10_000
