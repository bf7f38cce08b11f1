"""What every test runs under: a guard that fails a test which leaks asyncio tasks, threads, file
descriptors (sockets, pipes, files) or logging filters, naming what leaked.

* **Tasks**: the tasks still pending on the test's event loop once the test and its async fixtures
  are done, just before pytest-asyncio's runner closes the loop (which would cancel them
  silently). They get a bounded time to finish first (a task cancelled on the way out needs a
  turn of the loop); what is still pending then is a leak.
* **Threads**: threads alive after the test that were not before, once each has been joined
  (bounded).
* **File descriptors**: entries of ``/proc/self/fd`` that were not there before the test, after
  the event loop has closed, a garbage collection and a bounded wait; a socket is named by its
  addresses (from ``/proc/net``).
* **Logging filters**: filters added to a logger and not taken off (an emulator's log ceiling left
  behind would swallow the next test's log lines).

A test that binds a fixed port in the kernel's ephemeral range (``ip_local_port_range``: MotoROS's
50240-50242 are in it) fails at the bind, naming the port: any outgoing connection of the machine
may hold that port as its local one, and the bind then fails now and then (CI did, on 50242).
Tests bind port 0, or a fixed port below the range (the generic profile's 11000 and 11002), or a
port the kernel gave a bind of port 0 earlier in the same test; a test that has a reason to bind one
says so with ``@pytest.mark.fixed_ports_allowed("why")``. (Watched: binds in this process during the
test and its function-scoped fixtures; not a robot-server process the test starts, nor fixtures of a
wider scope.)

The guard only speaks when the test itself passed (a failing test says enough). A test that has a
reason to leak says so with ``@pytest.mark.leaks_allowed("why")``: its leaks are then a warning.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import operator
import os
import socket
import threading
import time
import warnings
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest

#: how long leftovers may take to go away after a test (seconds): a bound, never a delay
SETTLE = float(os.environ.get("LEAK_GUARD_SETTLE", "2.0"))
#: the same for descriptors, checked once the loop has closed and the new threads have ended:
#: what is left then closes with a garbage collection or not at all
FD_SETTLE = min(SETTLE, 0.5)
_POLL = 0.01

_PENDING_TASKS = pytest.StashKey[list[str]]()
#: tests whose setup or call failed (the guard stays silent about them)
_FAILED: set[str] = set()
_RUNNER_FIXTURE = "_function_scoped_runner"


class LeakWarning(UserWarning):
    """Leaks of a test marked ``leaks_allowed``."""


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "leaks_allowed(reason): the leak guard (tests/conftest.py) only warns about this test's leaked "
        "tasks, threads and file descriptors; say why they are acceptable",
    )
    config.addinivalue_line(
        "markers",
        "fixed_ports_allowed(reason): the test may bind fixed ports in the kernel's ephemeral range "
        "(tests/conftest.py); say why",
    )


# -- the test's outcome --------------------------------------------------------------------------------


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    # a plain hook, after the report is made (a wrapper of pytest_runtest_makereport would sit in
    # the stack that renders the failure)
    if report.failed and report.when in ("setup", "call"):
        _FAILED.add(report.nodeid)


# -- tasks: checked before the runner closes the loop -------------------------------------------------


@pytest.hookimpl(wrapper=True)
def pytest_fixture_setup(
    fixturedef: pytest.FixtureDef[object], request: pytest.FixtureRequest
) -> Generator[None, object, object]:
    result = yield
    if fixturedef.argname == _RUNNER_FIXTURE and isinstance(result, asyncio.Runner):
        # A fixture's finalizers run last-in first-out: this one runs after the async fixtures'
        # teardowns (pytest-asyncio adds them later) and before the runner closes the loop.
        node = request.node
        fixturedef.addfinalizer(lambda: _check_tasks(result, node))
    return result


def _check_tasks(runner: asyncio.Runner, node: pytest.Item) -> None:
    loop = runner.get_loop()
    if loop.is_closed() or loop.is_running():
        return
    pending = runner.run(_settle_tasks(SETTLE))
    if pending:
        node.stash[_PENDING_TASKS] = [_describe_task(task) for task in pending]


async def _settle_tasks(limit: float) -> list[asyncio.Task[object]]:
    """Wait (at most ``limit`` s) for the loop's other tasks to finish; the ones still pending."""
    me = asyncio.current_task()
    loop = asyncio.get_running_loop()
    end = loop.time() + limit
    await asyncio.sleep(0)  # one turn: callbacks scheduled by the test's last step run
    while True:
        pending = [t for t in asyncio.all_tasks() if t is not me and not t.done()]
        remaining = end - loop.time()
        if not pending or remaining <= 0:
            return pending
        await asyncio.wait(pending, timeout=remaining)


def _describe_task(task: asyncio.Task[object]) -> str:
    coro = task.get_coro()
    name = getattr(coro, "__qualname__", repr(coro))
    where = ""
    frames = task.get_stack(limit=1)
    if frames:
        code = frames[-1].f_code
        where = f", waiting at {Path(code.co_filename).name}:{frames[-1].f_lineno} in {code.co_name}"
    return f"task {task.get_name()!r} running {name}{where}"


# -- threads and descriptors: checked once every fixture is torn down -----------------------------------


def _fds() -> dict[int, str]:
    """Open descriptors and what they are (``/proc/self/fd``), but the standard streams (pytest's
    capture moves them)."""
    found = {}
    for entry in os.listdir("/proc/self/fd"):
        if int(entry) <= 2:
            continue
        try:
            found[int(entry)] = os.readlink(f"/proc/self/fd/{entry}")
        except OSError:  # the listing's own descriptor, closed by now
            continue
    return found


def _socket_names() -> dict[str, str]:
    """``socket:[inode]`` -> its local and remote address (TCP, TCP6 and UNIX sockets)."""
    names: dict[str, str] = {}
    for table, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        try:
            lines = Path(f"/proc/self/net/{table}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 9:
                state = _TCP_STATES.get(fields[3], fields[3])
                names[f"socket:[{fields[9]}]"] = (
                    f"{table} socket {_address(fields[1], family)} -> {_address(fields[2], family)} {state}"
                )
    try:
        lines = Path("/proc/self/net/unix").read_text().splitlines()[1:]
    except OSError:
        lines = []
    for line in lines:
        fields = line.split()
        if len(fields) > 6:
            names[f"socket:[{fields[6]}]"] = "unix socket " + (fields[7] if len(fields) > 7 else "(unnamed)")
    return names


_TCP_STATES = {
    "01": "ESTABLISHED",
    "02": "SYN_SENT",
    "03": "SYN_RECV",
    "04": "FIN_WAIT1",
    "05": "FIN_WAIT2",
    "06": "TIME_WAIT",
    "07": "CLOSE (unconnected)",
    "08": "CLOSE_WAIT",
    "09": "LAST_ACK",
    "0A": "LISTEN",
    "0B": "CLOSING",
}


def _address(text: str, family: int) -> str:
    host, port = text.split(":")
    raw = bytes.fromhex(host)  # 32-bit words in host (little-endian) order
    raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return f"{socket.inet_ntop(family, raw)}:{int(port, 16)}"


def _new_fds(before: dict[int, str]) -> dict[int, str]:
    return {fd: target for fd, target in _fds().items() if before.get(fd) != target}


def _poll(condition: Callable[[], bool], limit: float) -> None:
    """Check ``condition`` until it holds or ``limit`` seconds have passed (a bounded poll)."""
    end = time.monotonic() + limit
    while not condition() and time.monotonic() < end:
        time.sleep(_POLL)


def _leaked_threads(before: set[threading.Thread]) -> list[threading.Thread]:
    new = [t for t in threading.enumerate() if t not in before and t is not threading.current_thread()]
    end = time.monotonic() + SETTLE
    for thread in new:
        thread.join(max(0.0, end - time.monotonic()))
    return [t for t in new if t.is_alive()]


def _filters() -> set[tuple[str, int]]:
    """(logger name, filter id) of every filter on a logger."""
    loggers = [logging.getLogger(), *(logging.getLogger(name) for name in list(logging.Logger.manager.loggerDict))]
    return {(logger.name, id(f)) for logger in loggers for f in logger.filters}


def _describe_thread(thread: threading.Thread) -> str:
    target = getattr(thread, "_target", None)
    runs = f" running {getattr(target, '__qualname__', repr(target))}" if target is not None else ""
    return f"thread {thread.name!r}{' (daemon)' if thread.daemon else ''}{runs}"


@pytest.fixture(autouse=True)
def leak_guard(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fails the test if it leaves tasks, threads or descriptors behind (see the module doc).

    Being autouse it is set up before pytest-asyncio's runner fixture (which pytest-asyncio adds to
    each async test) and so torn down after it: the loop is closed by then and its own descriptors
    are gone; tasks are checked earlier, by the runner's finalizer (:func:`_check_tasks`)."""
    threads = set(threading.enumerate())
    fds = _fds()
    filters = _filters()
    yield
    item = request.node
    if item.nodeid in _FAILED:
        _FAILED.discard(item.nodeid)
        return
    leaks = list(item.stash.get(_PENDING_TASKS, []))
    leaks += [_describe_thread(t) for t in _leaked_threads(threads)]
    leaks += [f"a logging filter on {name!r}" for name, _ in sorted(_filters() - filters)]
    new = _new_fds(fds)
    if new:
        gc.collect()  # descriptors only garbage holds (closed with a ResourceWarning)
        _poll(lambda: not _new_fds(fds), FD_SETTLE)
        new = _new_fds(fds)
    if new:
        sockets = _socket_names()
        leaks += [f"fd {fd} {sockets.get(target, target)}" for fd, target in sorted(new.items())]
    if not leaks:
        return
    marker = item.get_closest_marker("leaks_allowed")
    text = f"{item.nodeid} leaked:\n  " + "\n  ".join(leaks)
    if marker is not None:
        reason = marker.args[0] if marker.args else "no reason given"
        warnings.warn(LeakWarning(f"{text}\n(allowed: {reason})"), stacklevel=1)
        return
    pytest.fail(text, pytrace=False)


def _ephemeral_ports() -> range:
    """The ports the kernel hands out as connections' local ports."""
    try:
        low, high = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return range(int(low), int(high) + 1)
    except (OSError, ValueError):
        return range(32768, 61000)  # Linux's default


class EphemeralPortBound(RuntimeError):
    """A test bound a fixed port the kernel may have given an outgoing connection."""


#: ports the kernel handed out to a bind of port 0 during the running test: binding one again (a
#: server restarting on its port, a port shown to be taken) is the test's own business; forgotten
#: when the test ends (a later test binding it would be the flaky case again)
_HANDED_OUT: set[int] = set()
_EPHEMERAL = _ephemeral_ports()
_BIND = socket.socket.bind
_INET = (socket.AF_INET, socket.AF_INET6)


def _checked_bind(self: socket.socket, address: object) -> None:
    port = None
    if self.family in _INET and isinstance(address, tuple) and len(address) >= 2:
        with contextlib.suppress(TypeError):
            port = operator.index(address[1])  # an int, or a numpy integer
    if port is not None and port in _EPHEMERAL and port not in _HANDED_OUT:
        raise EphemeralPortBound(
            f"a test binds port {port}, in the kernel's ephemeral range "
            f"({_EPHEMERAL.start}-{_EPHEMERAL.stop - 1}): an outgoing connection may hold it; bind port 0 "
            "(or mark the test fixed_ports_allowed, saying why)"
        )
    _BIND(self, address)  # type: ignore[arg-type]
    if port == 0:
        _HANDED_OUT.add(self.getsockname()[1])


@pytest.fixture(autouse=True)
def _no_fixed_ephemeral_ports(request: pytest.FixtureRequest) -> Iterator[None]:
    """Refuses a bind to a fixed port in the ephemeral range during the test and its function-scoped
    fixtures (see the module doc; a robot-server process of the test's, a module- or session-scoped
    fixture are not watched)."""
    if request.node.get_closest_marker("fixed_ports_allowed") is not None:
        yield
        return
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(socket.socket, "bind", _checked_bind)
        try:
            yield
        finally:
            _HANDED_OUT.clear()


@pytest.fixture(scope="session", autouse=True)
def _uvloop_opened_once() -> None:
    """uvloop (the optional extra, which ``simple_message.endpoints.run`` and ``robot-server`` use
    when installed) opens a pipe with its first event loop and keeps it for the life of the process:
    open it before any test's descriptors are counted, so it is not taken for a leak."""
    try:
        import uvloop
    except ImportError:
        return
    uvloop.new_event_loop().close()


@pytest.fixture
def plain_imports(monkeypatch: pytest.MonkeyPatch) -> None:
    """For ``runpy.run_module`` of this project's packages (``python -m ...`` in process): the
    package is a pytest plugin (entry point ``pytest11``), so pytest rewrites the asserts of its
    modules, and its import hook lacks the ``get_code`` runpy needs; without the hook the module
    loads as ``python -m`` loads it."""
    import sys

    monkeypatch.setattr(sys, "meta_path", [f for f in sys.meta_path if type(f).__name__ != "AssertionRewritingHook"])
