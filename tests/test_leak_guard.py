"""The leak guard of tests/conftest.py, on tests made to leak: it fails each one, naming what
leaked (a task, a thread, a listening socket), warns for a test marked ``leaks_allowed``, and
stays silent about clean tests, failing tests and garbage the collector closes."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

LEAKY = """
import asyncio, contextlib, socket, threading
import pytest

_keep = []


async def test_task():
    asyncio.get_running_loop().create_task(asyncio.sleep(3600), name="sleeper")


def test_thread():
    release = threading.Event()
    _keep.append(release)
    threading.Thread(target=release.wait, name="waiter", daemon=True).start()


async def test_server():
    _keep.append(await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0))


@pytest.mark.leaks_allowed("a test of the marker")
def test_allowed():
    _keep.append(socket.socket())


async def test_clean():
    task = asyncio.create_task(asyncio.sleep(3600))
    task.cancel()  # finishes on the next turn of the loop: not a leak
    server = await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0)
    reader, writer = await asyncio.open_connection("127.0.0.1", server.sockets[0].getsockname()[1])
    writer.close()
    server.close()
    await server.wait_closed()


def test_garbage():
    class Cycle:
        pass

    cycle = Cycle()
    cycle.me, cycle.sock = cycle, socket.socket()  # closed by the collector


@pytest.fixture
async def background():
    task = asyncio.create_task(asyncio.sleep(3600))
    yield task
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


async def test_async_fixture_cleans_up_after_the_test(background):
    assert not background.done()


def test_failing():
    _keep.append(socket.socket())
    assert False, "fails on its own"
"""


def test_the_guard_names_each_leak_and_nothing_else(tmp_path: Path) -> None:
    shutil.copy(Path(__file__).with_name("conftest.py"), tmp_path / "conftest.py")
    (tmp_path / "test_leaky.py").write_text(LEAKY)
    options = ["-o", "asyncio_mode=auto", "-o", "asyncio_default_fixture_loop_scope=function"]
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:randomly", "-p", "no:cacheprovider", *options, "-rA", "."],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "LEAK_GUARD_SETTLE": "0.2"},
        check=False,
    )
    out = result.stdout
    assert result.returncode == 1, out + result.stderr
    errors = set(re.findall(r"^ERROR test_leaky.py::(\w+)", out, re.MULTILINE))
    assert errors == {"test_task", "test_thread", "test_server"}, out
    assert re.search(r"test_task leaked:\n  task 'sleeper' running sleep", out), out
    assert re.search(r"test_thread leaked:\n  thread 'waiter' \(daemon\) running Event.wait", out), out
    assert re.search(r"test_server leaked:\n  fd \d+ tcp socket 127\.0\.0\.1:\d+ -> 0\.0\.0\.0:0 LISTEN", out), out
    assert re.search(r"LeakWarning: test_leaky.py::test_allowed leaked:\n\s+fd \d+ socket", out), out
    assert "(allowed: a test of the marker)" in out
    passed = set(re.findall(r"^PASSED test_leaky.py::(\w+)", out, re.MULTILINE))
    assert {"test_clean", "test_garbage", "test_async_fixture_cleans_up_after_the_test", "test_allowed"} <= passed
    assert re.search(r"^FAILED test_leaky.py::test_failing - AssertionError: fails on its own", out, re.MULTILINE)
    assert "test_failing leaked" not in out
