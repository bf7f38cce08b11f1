"""Precise wake-ups for the state topics: one helper thread for every deadline of a process.

The event loop's own timers are not precise enough for a state topic: asyncio waits in epoll,
whose timeout is in whole milliseconds (rounded up), and uvloop's libuv timers count milliseconds
too, so a 250 Hz topic timed by ``asyncio.sleep`` comes up to a millisecond late, differently each
period. A :class:`Ticker`'s thread sleeps until the earliest deadline it holds (the OS's own precise
sleep) and hands the wake-ups that are due to the loop in one ``call_soon_threadsafe``: portable, on
any event loop. One ticker serves any number of tasks (every controller of a fleet, each with its
own period), so a process has one such thread, not one per controller.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import threading
import time

__all__ = ["Ticker"]


class Ticker:
    """Wakes tasks at absolute ``time.monotonic()`` deadlines within tens of microseconds (see the
    module doc). Make it inside the running loop; :meth:`close` ends its thread."""

    def __init__(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._cond = threading.Condition()
        #: (deadline, order, future): the earliest first
        self._heap: list[tuple[float, int, asyncio.Future[None]]] = []
        self._order = itertools.count()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="state-topics ticker", daemon=True)
        self._thread.start()

    async def sleep_until(self, deadline: float) -> None:
        """Wait until ``time.monotonic()`` reaches ``deadline`` (at once, yielding, if it has)."""
        if deadline <= time.monotonic():
            await asyncio.sleep(0)  # late: still let the others run
            return
        future: asyncio.Future[None] = self._loop.create_future()
        with self._cond:
            if self._stop:
                raise RuntimeError("the ticker is closed")
            earliest = not self._heap or deadline < self._heap[0][0]
            heapq.heappush(self._heap, (deadline, next(self._order), future))
            if earliest:
                self._cond.notify()
        await future

    def _run(self) -> None:
        heap = self._heap
        while True:
            with self._cond:
                while not self._stop and (not heap or (left := heap[0][0] - time.monotonic()) > 0.0):
                    self._cond.wait(None if not heap else left)  # a precise timed wait
                if self._stop:
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
            self._stop = True
            self._cond.notify()
        self._thread.join(1.0)


def _wake(futures: list[asyncio.Future[None]]) -> None:
    for future in futures:
        if not future.done():  # not cancelled meanwhile
            future.set_result(None)
