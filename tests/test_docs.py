"""Every example in the README and docs/ runs as written: each ```bash and ```python block, in the
order given, against one ``robot-server`` on the default ports (as a reader who started it in
another terminal has it). Blocks fenced ```sh (installing, starting servers) or ```text (output,
or what a test machine has not: ROS) are not run. Later blocks may rely on earlier ones.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.test_rs_server_process import robot_server

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
#: the pages with examples, in the order docs/README.md lists them
PAGES = [
    "protocol.md",
    "emulator.md",
    "kinematics.md",
    "cartesian.md",
    "demo.md",
    "ros.md",
    "vendors.md",
    "troubleshooting.md",
    "conformance.md",
    "web.md",
    "testing.md",
]
BLOCK = re.compile(r"^```(bash|python)\n(.*?)^```\s*$", re.MULTILINE | re.DOTALL)
#: one block's bound (s): the longest, the demo, takes a few seconds
TIMEOUT = 120.0
DEFAULT_PORTS = (11000, 11002)


def blocks(page: str) -> Iterator[tuple[str, str]]:
    path = ROOT / page if page == "README.md" else ROOT / "docs" / page
    for match in BLOCK.finditer(path.read_text(encoding="utf-8")):
        yield match.group(1), match.group(2)


def test_every_page_with_examples_is_in_the_index() -> None:
    index = (ROOT / "docs" / "README.md").read_text(encoding="utf-8")
    with_examples = {p.name for p in (ROOT / "docs").glob("*.md") if p.name != "README.md" and any(blocks(p.name))}
    assert with_examples <= set(PAGES), with_examples - set(PAGES)
    assert all(f"({page})" in index for page in PAGES)


def test_every_relative_link_in_the_docs_points_at_a_file_the_repository_has() -> None:
    link = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
    for page in [ROOT / "README.md", ROOT / "CONTRIBUTING.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").glob("*.md")]:
        for target in link.findall(page.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+:", target):
                continue  # a web address
            assert (page.parent / target).exists(), f"{page.relative_to(ROOT)} links to {target}, which is missing"


def _free(port: int) -> bool:
    with socket.socket() as probe:
        # as robot-server binds: a port whose closed connections wait in TIME_WAIT is free (the
        # conformance examples make the server close some), one that something listens on is not
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@pytest.mark.parametrize("pages", [["README.md"], PAGES], ids=["README", "docs"])
async def test_the_examples_run_as_written(tmp_path: Path, pages: list[str]) -> None:
    if not all(_free(port) for port in DEFAULT_PORTS):
        pytest.fail(f"the examples use the default ports {DEFAULT_PORTS}; something else holds one of them")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    (tmp_path / "tests").symlink_to(ROOT / "tests")  # the README decodes the project's test vectors
    async with robot_server(tmp_path, "--motion-port", "11000", "--state-port", "11002", "--no-stdin") as server:
        ran = 0
        for page in pages:
            for number, (language, code) in enumerate(blocks(page), 1):
                command = (
                    ["bash", "-euo", "pipefail", "-c", code] if language == "bash" else [sys.executable, "-c", code]
                )
                done = subprocess.run(  # noqa: ASYNC221 - one block at a time, bounded; the server is another process
                    command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT, check=False
                )
                where = f"{page}, {language} block {number}"
                assert done.returncode == 0, f"{where} failed ({done.returncode}):\n{code}\n{done.stdout}{done.stderr}"
                ran += 1
        assert await server.terminate() == 0
    assert ran >= len(pages)
