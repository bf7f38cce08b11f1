"""What a test holds: the ``robot_controller`` factory and the handles it returns.

``robot_controller(...)`` in a sync test starts the controller on an event loop of its own, in a
thread, and returns a :class:`RobotController` whose methods block (bounded). In an async test
(the factory called while the test's loop runs) it starts the controller in the test's own loop:
``ctrl = await robot_controller(...)`` gives an :class:`AsyncRobotController`, whose waiting
methods are coroutines of the same names. Both have the same attributes. The factory stops every
controller it started when it is closed (the fixture's teardown), even after a failure.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import threading
from collections.abc import Callable, Coroutine, Generator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

from simple_message.messages import Status

from ..control import Recorder
from ..emulator import Emulator
from ..model import RobotModel
from .core import ControllerError, ControllerTimeout, Core, bounded
from .inprocess import InProcess
from .process import Process
from .settings import read_settings

__all__ = ["AsyncRobotController", "ControllerFactory", "RobotController"]

T = TypeVar("T")

#: wall-clock bound of reading a sync controller's state from its thread (s)
CALL_TIMEOUT = 10.0
#: wall-clock bound of a controller's thread ending once its loop is told to stop (s)
JOIN_TIMEOUT = 10.0
#: controller time the waits give by default (s)
DEFAULT_LIMIT = 60.0


class _LoopThread:
    """An event loop running in a thread of its own, for the controllers of sync tests."""

    def __init__(self, name: str) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self._main, name=f"robot_controller {name}", daemon=True)
        self.thread.start()

    def _main(self) -> None:
        loop = self.loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_forever()
        finally:
            try:
                tasks = [t for t in asyncio.all_tasks(loop) if not t.done()]
                for task in tasks:
                    task.cancel()
                loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
                loop.run_until_complete(loop.shutdown_asyncgens())
                loop.run_until_complete(loop.shutdown_default_executor())
            finally:
                asyncio.set_event_loop(None)
                loop.close()

    @property
    def here(self) -> bool:
        return threading.current_thread() is self.thread

    @property
    def alive(self) -> bool:
        return self.thread.is_alive() and not self.loop.is_closed()

    def run(self, coro: Coroutine[Any, Any, T], timeout: float | None = None) -> T:
        """Run ``coro`` on the loop and wait for it: at most ``timeout`` s, or (None) as long as
        it runs (its own waits are bounded) and the thread lives."""
        if self.here:
            coro.close()
            raise ControllerError("a controller's waiting methods cannot be called from its own thread (a predicate)")
        if not self.alive:
            coro.close()
            raise ControllerError("the controller has stopped")
        future = asyncio.run_coroutine_threadsafe(coro, self.loop)
        try:
            if timeout is not None:
                return future.result(timeout)
            while True:
                try:
                    return future.result(1.0)
                except concurrent.futures.TimeoutError:
                    if future.done():
                        raise
                    if not self.thread.is_alive():
                        raise ControllerError("the controller's thread ended") from None
        except concurrent.futures.TimeoutError:
            if future.done():
                raise  # the coroutine's own timeout
            future.cancel()
            raise ControllerTimeout(f"the controller did not answer within {timeout:g} s") from None
        except BaseException:
            future.cancel()
            raise

    def call(self, function: Callable[[], T]) -> T:
        """``function()`` on the loop's thread (between two steps of the controller)."""
        if self.here or not self.alive:
            return function()

        async def call() -> T:
            return function()

        return self.run(call(), CALL_TIMEOUT)

    def stop(self) -> None:
        if self.alive:
            self.loop.call_soon_threadsafe(self.loop.stop)
        if self.thread.is_alive() and not self.here:
            self.thread.join(JOIN_TIMEOUT)
            if self.thread.is_alive():
                raise ControllerError(f"the controller's thread did not end within {JOIN_TIMEOUT:g} s")


def _fault_command(command: object) -> str:
    """``command`` if it is a fault command's text, else :class:`TypeError` naming what was given
    (a wrong type is the test's mistake, not a command the controller refuses: not a
    :class:`~robot_server.emulator.FaultError`)."""
    if not isinstance(command, str):
        raise TypeError(
            f'fault: a fault command is text, as robot-server reads it on stdin ("estop", "alarm 1001 TEXT"), not '
            f"{command!r} ({type(command).__name__})"
        )
    return command


class _Handle:
    """What every controller handle has (see the module doc)."""

    def __init__(self, core: Core) -> None:
        self._core = core

    def __repr__(self) -> str:
        kind = "process" if isinstance(self._core, Process) else "in process"
        return f"<{type(self).__name__} {self.name}: {self.profile}, {kind}, ports {self._core.ports}>"

    def _ports(self) -> dict[str, int]:
        ports = self._core.ports
        if not ports:
            raise ControllerError(
                f"{self.name} has not started: in an async test, ctrl = await robot_controller(...)"
                if not self._core.closed
                else f"{self.name} never started"
            )
        return ports

    @property
    def name(self) -> str:
        """The controller's name (its files are named after it): ``c1``, ``c2``... or the ``name`` given."""
        return self._core.settings.name

    @property
    def profile(self) -> str:
        return self._core.settings.spec.config.profile

    @property
    def host(self) -> str:
        """The address to connect to (loopback unless ``host`` says otherwise)."""
        return self._core.host

    @property
    def ports(self) -> dict[str, int]:
        """Every port served, by role: ``motion``, ``state`` and, for profiles that have one, ``io``."""
        return dict(self._ports())

    @property
    def motion_port(self) -> int:
        return self._ports()["motion"]

    @property
    def state_port(self) -> int:
        return self._ports()["state"]

    @property
    def io_port(self) -> int | None:
        """The IO port (MotoROS), None for a profile without one."""
        return self._ports().get("io")

    @property
    def capture_path(self) -> Path | None:
        """The pcapng file every connection's traffic is recorded to (None: captures are off)."""
        return self._core.capture_path

    @property
    def model(self) -> RobotModel:
        """The robot model of motion group 0."""
        return self._core.models[0]

    @property
    def models(self) -> list[RobotModel]:
        """One robot model per motion group."""
        return list(self._core.models)

    @property
    def process(self) -> bool:
        """A ``robot-server`` process (``process=True``), not an emulator in this process."""
        return isinstance(self._core, Process)

    @property
    def stepped(self) -> bool:
        """The test moves the controller's clock (``speedup="step"``)."""
        return self._core.settings.stepped

    @property
    def speedup(self) -> float | str:
        return self._core.settings.speedup

    @property
    def closed(self) -> bool:
        return self._core.closed

    @property
    def emulator(self) -> Emulator:
        """The :class:`~robot_server.emulator.Emulator` itself (in process only). In a sync test it
        runs on another thread: read it there only through :meth:`RobotController.call`."""
        if not isinstance(self._core, InProcess):
            raise ControllerError(f"{self.name} is a robot-server process: it has no Emulator in this process")
        return self._core.emulator

    @property
    def pid(self) -> int | None:
        """The process id of a ``robot-server`` process (None in process)."""
        return self._core.pid if isinstance(self._core, Process) else None

    @property
    def log_path(self) -> Path | None:
        """The file a ``robot-server`` process's output goes to (None in process: its log is pytest's)."""
        return self._core.log_path if isinstance(self._core, Process) else None

    def describe(self) -> str:
        """The controller's state as a failed test's report gives it."""
        return self._core.describe()


class RobotController(_Handle):
    """A controller of a sync test: it runs on its own thread; every method blocks, bounded."""

    def __init__(self, core: Core, thread: _LoopThread) -> None:
        super().__init__(core)
        self._thread = thread

    def __await__(self) -> Generator[Any, None, AsyncRobotController]:
        raise TypeError(f"{self.name} was started outside an event loop (a sync test or fixture): use it without await")

    def call(self, function: Callable[[], T]) -> T:
        """``function()`` run on the controller's thread, between two of its steps: how a sync test
        reads the :attr:`emulator` safely."""
        return self._thread.call(function)

    @property
    def joints(self) -> tuple[float, ...]:
        """The actual joint positions of motion group 0 now (rad or m; a process's: as its state port sends them)."""
        return self._thread.call(self._core.joints)

    @property
    def status(self) -> Status:
        """STATUS now, as the profile's state port reports it."""
        return self._thread.call(self._core.status)

    @property
    def time(self) -> float:
        """Controller time (s) since the controller started."""
        return self._thread.call(self._core.time)

    @property
    def in_motion(self) -> bool:
        return self._thread.call(self._core.in_motion)

    @property
    def record(self) -> Recorder:
        """The servo ticks of motion group 0 recorded so far: a copy that no longer grows (read it
        once, then use it; a process's after :meth:`stop`)."""
        return self.records[0]

    @property
    def records(self) -> list[Recorder]:
        """:attr:`record` of every motion group."""
        return self._thread.call(self._core.records)

    def wait_idle(self, timeout: float = DEFAULT_LIMIT) -> float:
        """Wait until the robot is at rest, at most ``timeout`` s of controller time (a stepped clock
        is advanced until then); returns the controller time. Raises :class:`ControllerTimeout`."""
        return self._thread.run(self._core.wait_idle(bounded("timeout", timeout)))

    def fault(self, command: str) -> str:
        """Apply a fault command as ``robot-server`` reads them on stdin (``estop``, ``drives off``,
        ``drives on``, ``alarm CODE [TEXT]``, ``reset``, ``stop``, ``mode auto|manual``); returns what
        was done, raises :class:`~robot_server.emulator.FaultError` for a command it refuses and
        :class:`TypeError` for one that is not a ``str``."""
        return self._thread.run(self._core.fault(_fault_command(command)))

    def advance(self, seconds: float) -> float:
        """Let ``seconds`` of controller time pass (a stepped clock is moved; a real-time one waited
        for); returns the controller time."""
        return self._thread.run(self._core.advance(bounded("seconds", seconds)))

    def advance_until(
        self, predicate: Callable[[], bool], limit: float = DEFAULT_LIMIT, *, dt: float | None = None, what: str = ""
    ) -> float:
        """Advance (or wait) until ``predicate()`` holds, checked before every interpolation period
        (a stepped clock: in one run of the control loop, the controller's sockets served between
        periods; with ``dt``, after every advance of ``dt``) or every control period; at most
        ``limit`` s of controller time, else :class:`ControllerTimeout` (``what`` names the
        condition in its message). What ``predicate`` raises is raised here; the controller runs
        on. In process, ``predicate`` runs on the controller's thread: it may read this handle."""
        limit = bounded("limit", limit)
        dt = None if dt is None else bounded("dt", dt, positive=True)
        return self._thread.run(self._core.advance_until(predicate, limit, dt, what or "the condition"))

    def stop(self) -> None:
        """Stop the controller now (teardown does it otherwise): the robot brought to rest, every
        connection closed, the ports freed; a process's record can then be read."""
        if not self._core.closed and self._thread.alive:
            try:
                self._thread.run(self._core.close())
            finally:
                self._thread.stop()
        else:
            self._thread.stop()


class AsyncRobotController(_Handle):
    """A controller of an async test, in the test's own event loop: ``await`` it once to have it
    started; its waiting methods are coroutines."""

    def __init__(self, core: Core, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__(core)
        self.loop = loop
        self._starting: asyncio.Task[None] = loop.create_task(core.start(), name=f"start {core.settings.name}")

    def __await__(self) -> Generator[Any, None, AsyncRobotController]:
        return self._started().__await__()

    async def _started(self) -> AsyncRobotController:
        await asyncio.shield(self._starting)
        return self

    @property
    def joints(self) -> tuple[float, ...]:
        """The actual joint positions of motion group 0 now (rad or m; a process's: as its state port sends them)."""
        return self._core.joints()

    @property
    def status(self) -> Status:
        """STATUS now, as the profile's state port reports it."""
        return self._core.status()

    @property
    def time(self) -> float:
        """Controller time (s) since the controller started."""
        return self._core.time()

    @property
    def in_motion(self) -> bool:
        return self._core.in_motion()

    @property
    def record(self) -> Recorder:
        """The servo ticks of motion group 0 recorded so far: a copy that no longer grows (a
        process's after :meth:`stop`)."""
        return self.records[0]

    @property
    def records(self) -> list[Recorder]:
        return self._core.records()

    async def wait_idle(self, timeout: float = DEFAULT_LIMIT) -> float:
        """As :meth:`RobotController.wait_idle`."""
        timeout = bounded("timeout", timeout)
        await self._started()
        return await self._core.wait_idle(timeout)

    async def fault(self, command: str) -> str:
        """As :meth:`RobotController.fault`."""
        command = _fault_command(command)
        await self._started()
        return await self._core.fault(command)

    async def advance(self, seconds: float) -> float:
        """As :meth:`RobotController.advance`."""
        seconds = bounded("seconds", seconds)
        await self._started()
        return await self._core.advance(seconds)

    async def advance_until(
        self, predicate: Callable[[], bool], limit: float = DEFAULT_LIMIT, *, dt: float | None = None, what: str = ""
    ) -> float:
        """As :meth:`RobotController.advance_until`."""
        limit = bounded("limit", limit)
        dt = None if dt is None else bounded("dt", dt, positive=True)
        await self._started()
        return await self._core.advance_until(predicate, limit, dt, what or "the condition")

    async def stop(self) -> None:
        """As :meth:`RobotController.stop`."""
        await asyncio.wait({self._starting})  # a start half done is not undone by cancelling it: bounded
        if not self._starting.cancelled() and self._starting.exception() is not None:
            # a start that failed was reported where it was awaited: what is left is closed, not reported again
            with contextlib.suppress(Exception):
                await self._core.close()
            return
        await self._core.close()

    def stop_blocking(self) -> None:
        """:meth:`stop` from outside the loop (a fixture's teardown, once the test's loop has stopped)."""
        if self._core.closed and self._starting.done():
            return
        if self.loop.is_closed():
            raise ControllerError(f"{self.name}: its event loop closed before it was stopped")
        if self.loop.is_running():
            raise ControllerError(f"{self.name}: its event loop still runs: stop it there (await ctrl.stop())")
        self.loop.run_until_complete(self.stop())


class ControllerFactory:
    """``robot_controller``: starts emulated controllers and stops them all when closed.

    ``folder`` holds the files of the controllers (captures, a process's log and record), named
    after each controller; ``captures=False`` records no traffic."""

    def __init__(self, folder: Path, *, captures: bool = True) -> None:
        self.folder = folder
        self.captures = captures
        self.handles: list[RobotController | AsyncRobotController] = []
        #: the files this factory chose (not those the settings named), removed by :meth:`remove_files`
        self.files: list[Path] = []
        #: what went wrong stopping controllers before :meth:`close` (an async test's, on its loop)
        self.errors: list[BaseException] = []

    def __call__(
        self,
        profile: str = "generic",
        model: str | Path | Sequence[str | Path] = "jibot_zxs",
        speedup: float | str | None = None,
        process: bool = False,
        **settings: Any,
    ) -> RobotController:
        """Start an emulated controller (see the module doc). ``settings`` are ``robot-server``'s
        options with underscores (the keys of a fleet file's controller); ``speedup``: None (real
        time), a factor, or ``"step"``. In an async test, ``await`` the result."""
        name = settings.pop("name", None) or f"c{len(self.handles) + 1}"
        if any(h.name == name for h in self.handles):
            raise ValueError(f"name: this test has a controller {name!r} already")
        self.folder.mkdir(parents=True, exist_ok=True)
        capture = self.folder / f"{name}.pcapng" if self.captures else None
        record = self.folder / f"{name}.record.npz"
        checked = read_settings(
            name, profile, model, speedup=speedup, process=process, settings=settings, capture=capture, record=record
        )
        if capture is not None and checked.spec.config.capture == str(capture):
            self.files.append(capture)  # (a capture the settings name is the test's own)
        if process and checked.spec.record == record:
            self.files.append(record)
        core: Core
        if process:
            log_path = self.folder / f"{name}.log"
            self.files.append(log_path)
            core = Process(checked, log_path)
        else:
            core = InProcess(checked)
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            thread = _LoopThread(name)
            try:
                thread.run(core.start())
            except BaseException:
                with contextlib.suppress(Exception):
                    thread.run(core.close(), CALL_TIMEOUT)
                thread.stop()
                raise
            handle = RobotController(core, thread)
            self.handles.append(handle)
            return handle
        started = AsyncRobotController(core, loop)
        self.handles.append(started)
        return started  # type: ignore[return-value]  # awaited: RobotController.__await__ says what it gives

    # -- teardown ----------------------------------------------------------------------------------

    def describe(self) -> list[tuple[str, str]]:
        """Each controller's state now, titled, for a failed test's report."""
        sections = []
        for handle in self.handles:
            try:
                text = handle.call(handle.describe) if isinstance(handle, RobotController) else handle.describe()
            except Exception as exc:
                text = f"{handle.name}: its state could not be read: {exc!r}"
            sections.append((f"robot_controller {handle.name}", text))
        return sections

    async def aclose_in(self, loop: asyncio.AbstractEventLoop) -> list[BaseException]:
        """Stop the async controllers of ``loop`` (run on it, before it closes)."""
        ours = [h for h in self.handles if isinstance(h, AsyncRobotController) and h.loop is loop]
        results = await asyncio.gather(*(h.stop() for h in reversed(ours)), return_exceptions=True)
        return [r for r in results if isinstance(r, BaseException)]

    def close(self) -> list[BaseException]:
        """Stop every controller (last started first); the errors met on the way, each one stopped anyway."""
        errors, self.errors = self.errors, []
        for handle in reversed(self.handles):
            try:
                if isinstance(handle, RobotController):
                    handle.stop()
                else:
                    handle.stop_blocking()
            except Exception as exc:
                errors.append(exc)
        return errors

    def remove_files(self) -> None:
        """Remove the files the controllers left in :attr:`folder` (a capture's rotated parts too),
        then the folder if nothing else is in it."""
        for path in self.files:
            for part in [path, *path.parent.glob(f"{path.stem}.*{path.suffix}")]:
                with contextlib.suppress(FileNotFoundError):
                    part.unlink()
        with contextlib.suppress(OSError):
            self.folder.rmdir()

    # -- outside pytest: ``with ControllerFactory(folder) as robot_controller:`` (or ``async with``) ---------

    def __enter__(self) -> ControllerFactory:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self._raise(self.close(), kind)

    async def __aenter__(self) -> ControllerFactory:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.errors += await self.aclose_in(asyncio.get_running_loop())
        self._raise(self.close(), kind)

    @staticmethod
    def _raise(errors: list[BaseException], kind: type[BaseException] | None) -> None:
        if errors and kind is None:
            raise ControllerError("; ".join(str(e) for e in errors)) from errors[0]
