"""The pytest plugin (entry point ``pytest11``: ``robot_server``): the ``robot_controller`` fixture,
the report of a failed test's controllers, and the stopping of async tests' controllers before
their event loop closes.

pytest loads this module in every run of every project where the package is installed, so it
imports nothing of the emulator until a test asks for the fixture. ``pytest -p no:robot_server``
turns it off.

* ``robot_controller`` (:class:`~.handle.ControllerFactory`) keeps its controllers' files under the
  test's ``tmp_path`` (``robot_controller/``): each controller's traffic as pcapng, a process's log
  and record. They are removed when the test passes and kept when it fails; ``--robot-captures
  all`` keeps them always, ``none`` records no traffic.
* When a test fails (its setup or its call), a hook wrapping ``pytest_runtest_makereport`` adds
  one report section per controller: where it was, its STATUS, its capture file. It reads the
  controllers before the fixture's teardown stops them.
* An async test's controllers run in the test's event loop, which pytest-asyncio closes before
  the fixture's teardown: they are stopped by a finalizer of pytest-asyncio's runner, just before
  it closes the loop.

It needs pytest 8.0 or later (:data:`MIN_PYTEST`), whose pluggy knows the hook wrappers it uses
(``wrapper=True``, pluggy 1.1). pytest itself is no dependency of the package, so an older one is
met here, in every run: the plugin then installs no hook, and the fixture fails the test that asks
for it saying which versions it found (:func:`unsupported`). The run and its other tests go on.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Generator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import pluggy
import pytest

if TYPE_CHECKING:
    from .handle import ControllerFactory

__all__ = ["MIN_PLUGGY", "MIN_PYTEST", "robot_controller", "unsupported"]

F = TypeVar("F", bound=Callable[..., Any])

#: the oldest pytest the plugin runs in, and the pluggy its hook wrappers need (``wrapper=True``)
MIN_PYTEST = (8, 0)
MIN_PLUGGY = (1, 1)


def _release(version: str) -> tuple[int, ...]:
    """The leading numbers of a version (``8.1.0.dev3`` -> (8, 1, 0))."""
    numbers = []
    for part in version.split("."):
        digits = re.match(r"\d+", part)
        if digits is None:
            break
        numbers.append(int(digits.group()))
        if digits.group() != part:
            break
    return tuple(numbers)


def unsupported(pytest_version: str, pluggy_version: str) -> str | None:
    """Why the plugin cannot run in this pytest and pluggy, or None: it can."""
    if _release(pytest_version) >= MIN_PYTEST and _release(pluggy_version) >= MIN_PLUGGY:
        return None
    need, pluggy_need = ".".join(map(str, MIN_PYTEST)), ".".join(map(str, MIN_PLUGGY))
    return (
        f"robot_server's pytest plugin (the robot_controller fixture) needs pytest >= {need} (with pluggy >= "
        f"{pluggy_need}); this is pytest {pytest_version} with pluggy {pluggy_version}: "
        f"pip install 'pytest>={need}' 'pluggy>={pluggy_need}', or turn the plugin off with "
        "-p no:robot_server"
    )


#: why the plugin does nothing in this run but fail the fixture (None: it runs)
UNSUPPORTED = unsupported(pytest.__version__, getattr(pluggy, "__version__", "0"))


def _wrapper(*, tryfirst: bool = False) -> Callable[[F], F]:
    """``pytest.hookimpl(wrapper=True)``; with a pluggy too old to know it, the function as it is
    (the module's end takes it off: no hook)."""
    if UNSUPPORTED is not None:
        return lambda function: function
    return pytest.hookimpl(wrapper=True, tryfirst=tryfirst)


if UNSUPPORTED is None:  # (pytest.StashKey came with pytest 7)
    #: the factories of a test (on its item)
    _FACTORIES = pytest.StashKey[list["ControllerFactory"]]()
    #: the test failed in its setup or call (on its item): its controllers' files are kept
    _FAILED = pytest.StashKey[bool]()
    #: every factory not closed yet (on the config)
    _LIVE = pytest.StashKey[list["ControllerFactory"]]()
CAPTURE_CHOICES = ("failed", "all", "none")


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("robot_controller", "emulated robot controllers (robot_server.testing)")
    group.addoption(
        "--robot-captures",
        choices=CAPTURE_CHOICES,
        default="failed",
        help="the robot_controller fixture's traffic captures (pcapng) and files: kept for failed tests "
        "(default), for all tests, or none recorded",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_LIVE] = []


@pytest.fixture
def robot_controller(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[ControllerFactory]:
    """Start emulated robot controllers on free loopback ports:
    ``ctrl = robot_controller(profile="generic", model="jibot_zxs", speedup=None, process=False,
    **robot_server_settings)`` (in an async test: ``ctrl = await robot_controller(...)``). The
    handle gives host, motion_port, state_port, io_port, joints, status, time, record, model,
    capture_path, wait_idle(timeout), fault("estop"), advance(seconds) (speedup="step": the test
    moves the clock) and stop(). Every controller is stopped at teardown; a failed test's report
    names its pcapng capture and last state. See docs/testing.md."""
    if UNSUPPORTED is not None:
        pytest.fail(UNSUPPORTED, pytrace=False)
    from .core import ControllerError
    from .handle import ControllerFactory

    option = request.config.getoption("robot_captures", "failed")
    factory = ControllerFactory(tmp_path / "robot_controller", captures=option != "none")
    item = request.node
    item.stash.setdefault(_FACTORIES, []).append(factory)
    live = request.config.stash.setdefault(_LIVE, [])
    live.append(factory)
    errors: list[BaseException] = []
    try:
        yield factory
    finally:
        live.remove(factory)
        errors = factory.close()
        if option != "all" and not errors and not item.stash.get(_FAILED, False):
            factory.remove_files()
    if errors:
        text = "\n".join(f"  {e!r}" for e in errors)
        raise ControllerError(f"robot_controller: {len(errors)} controller(s) did not stop cleanly:\n{text}") from (
            errors[0]
        )


@_wrapper()
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, Any, Any]:
    report = yield
    factories = item.stash.get(_FACTORIES, None)
    if factories and report.failed:
        item.stash[_FAILED] = True
        if report.when in ("setup", "call"):
            for factory in factories:
                for title, text in factory.describe():
                    report.sections.append((title, text))
    return report


@_wrapper(tryfirst=True)
def pytest_fixture_setup(
    fixturedef: pytest.FixtureDef[Any], request: pytest.FixtureRequest
) -> Generator[None, Any, Any]:
    # tryfirst: the outermost wrapper adds its finalizer last, so it runs first of the runner's
    # (before another plugin's finalizer looks for tasks left on the loop)
    result = yield
    asyncio = sys.modules.get("asyncio")
    if asyncio is not None and isinstance(result, asyncio.Runner):
        config = request.config
        fixturedef.addfinalizer(lambda: _stop_async(config, result))
    return result


def _stop_async(config: pytest.Config, runner: Any) -> None:
    """Stop the async controllers of ``runner``'s loop (pytest-asyncio's), which is about to close."""
    factories = config.stash.get(_LIVE, [])
    if not factories:
        return
    loop = runner.get_loop()
    if loop.is_closed() or loop.is_running():
        return
    for factory in list(factories):
        factory.errors += runner.run(factory.aclose_in(loop))


if UNSUPPORTED is not None:
    # hooks this pytest cannot run: the fixture alone is left, to say why (pytest_addoption stays, so
    # that a --robot-captures in a project's addopts is still an option)
    del pytest_configure, pytest_runtest_makereport, pytest_fixture_setup
