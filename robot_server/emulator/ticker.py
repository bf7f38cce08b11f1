"""Precise wake-ups for the state topics: a kernel timer the event loop watches, or one helper thread.

The event loop's own timers are not precise enough for a state topic: asyncio waits in epoll,
whose timeout is in whole milliseconds (rounded up), and uvloop's libuv timers count milliseconds
too, so a 250 Hz topic timed by ``asyncio.sleep`` comes up to a millisecond late, differently each
period. A :class:`Ticker` serves any number of tasks' absolute ``time.monotonic()`` deadlines (every
controller of a fleet, each with its own period) with one of:

* on Linux, a **timerfd**: a kernel timer armed for the earliest deadline at nanosecond resolution,
  whose descriptor the event loop watches like a socket's. It becomes readable at the deadline and
  wakes the loop at once; nothing else runs, so nothing waits for the GIL. (``os.timerfd_create``
  from Python 3.13; before it, the same two libc calls through ctypes.)
* elsewhere, a **thread** that sleeps until the earliest deadline (the OS's own precise sleep) and
  hands the wake-ups that are due to the loop in one ``call_soon_threadsafe``. While the loop is
  busy that hand-over waits for the GIL, up to the interpreter's switch interval.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import heapq
import itertools
import os
import sys
import threading
import time

__all__ = ["Ticker"]

_Entry = tuple[float, int, asyncio.Future[None]]


class Ticker:
    """Wakes tasks at absolute ``time.monotonic()`` deadlines within tens of microseconds (see the
    module doc). Make it inside the running loop; :meth:`close` releases its timer or thread."""

    def __init__(self) -> None:
        self._loop = asyncio.get_running_loop()
        #: (deadline, order, future): the earliest first
        self._heap: list[_Entry] = []
        self._order = itertools.count()
        self._closed = False
        self._timer = _TimerFd.make()
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        if self._timer is not None:
            self._loop.add_reader(self._timer.fd, self._fired)
        else:
            self._thread = threading.Thread(target=self._run, name="state-topics ticker", daemon=True)
            self._thread.start()

    @property
    def kind(self) -> str:
        """``timerfd`` or ``thread``: how the deadlines are kept."""
        return "timerfd" if self._timer is not None else "thread"

    async def sleep_until(self, deadline: float) -> None:
        """Wait until ``time.monotonic()`` reaches ``deadline`` (at once, yielding, if it has)."""
        if deadline <= time.monotonic():
            await asyncio.sleep(0)  # late: still let the others run
            return
        if self._closed:
            raise RuntimeError("the ticker is closed")
        future: asyncio.Future[None] = self._loop.create_future()
        with self._cond:
            earliest = not self._heap or deadline < self._heap[0][0]
            heapq.heappush(self._heap, (deadline, next(self._order), future))
            if earliest:
                if self._timer is not None:
                    self._timer.arm(deadline)
                else:
                    self._cond.notify()
        await future

    # -- timerfd: everything on the loop's thread --------------------------------------------------

    def _fired(self) -> None:
        assert self._timer is not None
        self._timer.clear()
        heap = self._heap
        now = time.monotonic()
        due = []
        while heap and heap[0][0] <= now:
            due.append(heapq.heappop(heap)[2])
        if heap:
            self._timer.arm(heap[0][0])
        _wake(due)

    # -- thread -----------------------------------------------------------------------------------

    def _run(self) -> None:
        heap = self._heap
        while True:
            with self._cond:
                while not self._closed and (not heap or (left := heap[0][0] - time.monotonic()) > 0.0):
                    self._cond.wait(None if not heap else left)  # a precise timed wait
                if self._closed:
                    return
                now = time.monotonic()
                due = []
                while heap and heap[0][0] <= now:
                    due.append(heapq.heappop(heap)[2])
            try:
                self._loop.call_soon_threadsafe(_wake, due)
            except RuntimeError:  # the loop closed under us
                return

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        if self._timer is not None:
            with contextlib.suppress(RuntimeError, ValueError):  # the loop may be closed already
                self._loop.remove_reader(self._timer.fd)
            self._timer.close()
        if self._thread is not None:
            self._thread.join(1.0)


def _wake(futures: list[asyncio.Future[None]]) -> None:
    for future in futures:
        if not future.done():  # not cancelled meanwhile
            future.set_result(None)


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", _Timespec), ("it_value", _Timespec)]


#: <sys/timerfd.h> and <time.h> on Linux
_CLOCK_MONOTONIC = 1
_TFD_NONBLOCK = os.O_NONBLOCK
_TFD_CLOEXEC = 0o2000000
_TFD_TIMER_ABSTIME = 1


class _TimerFd:
    """A Linux timerfd on CLOCK_MONOTONIC (the clock of ``time.monotonic()``), armed at absolute
    deadlines."""

    def __init__(self, fd: int, settime: object) -> None:
        self.fd = fd
        self._settime = settime

    @classmethod
    def make(cls) -> _TimerFd | None:
        """A timer, or None where there is none (not Linux; no libc)."""
        if not sys.platform.startswith("linux") or time.get_clock_info("monotonic").implementation != (
            "clock_gettime(CLOCK_MONOTONIC)"
        ):
            return None
        create = getattr(os, "timerfd_create", None)
        if create is not None:  # Python >= 3.13
            fd = create(time.CLOCK_MONOTONIC, flags=os.TFD_NONBLOCK | os.TFD_CLOEXEC)  # type: ignore[attr-defined]
            return cls(fd, None)
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
            libc.timerfd_create.argtypes = (ctypes.c_int, ctypes.c_int)
            libc.timerfd_settime.argtypes = (
                ctypes.c_int,
                ctypes.c_int,
                ctypes.POINTER(_Itimerspec),
                ctypes.POINTER(_Itimerspec),
            )
            fd = libc.timerfd_create(_CLOCK_MONOTONIC, _TFD_NONBLOCK | _TFD_CLOEXEC)
        except (OSError, AttributeError):
            return None
        if fd < 0:
            return None
        return cls(fd, libc.timerfd_settime)

    def arm(self, deadline: float) -> None:
        """Fire at ``deadline`` (``time.monotonic()`` seconds; at once if it has passed)."""
        nanoseconds = max(1, round(deadline * 1e9))
        if self._settime is None:
            os.timerfd_settime_ns(self.fd, flags=os.TFD_TIMER_ABSTIME, initial=nanoseconds)  # type: ignore[attr-defined]
            return
        value = _Itimerspec(_Timespec(0, 0), _Timespec(nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000))
        if self._settime(self.fd, _TFD_TIMER_ABSTIME, ctypes.byref(value), None) != 0:  # type: ignore[operator]
            raise OSError(ctypes.get_errno(), "timerfd_settime failed")

    def clear(self) -> None:
        with contextlib.suppress(BlockingIOError):  # woken for nothing: already read
            os.read(self.fd, 8)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.fd)
