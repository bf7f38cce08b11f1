"""What the emulators of one process share: the controllers' clock, their servo wake-ups, the state topics' ticker.

A fleet (:mod:`robot_server.fleet`) runs many controllers in one process and one event loop. Each
as its own process would wake its control loop every interpolation period and keep a timer for its
state topics' deadlines; together they would wake the process hundreds of times per period.
:class:`Shared` gives them one :class:`~..control.SharedLoop` per interpolation period (one wake-up
runs every controller's period, but a controller at rest that nothing waits on is left out until it
is read or changed: :meth:`~..control.ControlLoop.park`), one :class:`~.ticker.Ticker` for every state topic, and one
:class:`StateRounds` schedule per state period, whose slots spread the controllers' rounds over
the period, so that they do not all fall due at the same instant and wait for one another. Each
round, and each controller's period, runs in that controller's context (its log lines name it).
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import sys
import time
from collections.abc import Callable

from ..control import Clock, ControlLoop, SharedLoop
from .ticker import Ticker

__all__ = ["Shared", "StateRounds"]

#: how often a thread holding the GIL lets another that waits for it run (s; :meth:`Shared.start`)
SWITCH_INTERVAL = 0.0002
#: how far apart the slots of a period's state rounds are (s): :class:`StateRounds`
SLOT = 0.002

#: the most slots a period is cut into (a period longer than a second has slots further apart)
MAX_SLOTS = 500

#: a state round: called with its deadline (``time.monotonic()``), or told how many it missed
RoundCallback = Callable[[float], None]
SkipCallback = Callable[[int], None]


class Shared:
    """The clock, wake-ups and ticker of a process's emulators (see the module doc). Make it and
    :meth:`start` it in the running loop, before the emulators start; :meth:`close` it after they
    have closed."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        #: one shared control loop per (interpolation period, servo ticks in it)
        self.loops: dict[tuple[float, int], SharedLoop] = {}
        self._tasks: list[asyncio.Task[object]] = []
        self.ticker: Ticker | None = None
        #: one schedule of state rounds per period
        self.rounds: dict[float, StateRounds] = {}

    def start(self) -> None:
        if self.clock.realtime and self.ticker is None:
            self.ticker = Ticker()
            if self.ticker.kind == "thread":
                # The ticker's thread needs the GIL for the moment it takes to hand a wake-up over;
                # a loop busy with many controllers holds it until the interpreter asks it to let
                # go, every switch interval (5 ms by default: a state round up to 5 ms late). Asked
                # every 0.2 ms instead, the hand-over waits at most that; a lone thread is never asked.
                sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL))

    def join(self, loop: ControlLoop) -> None:
        """Run ``loop``'s periods at the shared wake-ups of its interpolation period from the next one on."""
        ctl = loop.controller
        key = (ctl.config.interpolation_period, ctl.servo_ticks_per_interpolation)
        shared = self.loops.get(key)
        if shared is None:
            shared = self.loops[key] = SharedLoop(self.clock, *key)
            self._tasks.append(
                asyncio.get_running_loop().create_task(
                    shared.run(), name=f"shared control loop {key}", context=contextvars.Context()
                )
            )
        shared.add(loop)

    def catch_up(self) -> None:
        """Run the control periods now due (:meth:`SharedLoop.catch_up`): every controller's
        servers call this before they handle a request."""
        for shared in self.loops.values():
            shared.catch_up()

    def leave(self, loop: ControlLoop) -> None:
        for shared in self.loops.values():
            shared.remove(loop)

    def state_rounds(self, period: float) -> StateRounds:
        """The schedule of every emulator's state rounds of ``period`` seconds (made on first use)."""
        rounds = self.rounds.get(period)
        if rounds is None:
            rounds = self.rounds[period] = StateRounds(period, self.ticker)
            self._tasks.append(
                asyncio.get_running_loop().create_task(
                    rounds.run(), name=f"state rounds {period:g} s", context=contextvars.Context()
                )
            )
        return rounds

    async def close(self) -> None:
        for shared in self.loops.values():
            shared.stop()
        for task in self._tasks:
            task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        if self.ticker is not None:
            self.ticker.close()
            self.ticker = None


class StateRounds:
    """The state rounds of many emulators with one period, on one schedule.

    The period is cut into slots :data:`SLOT` apart; each emulator takes the slot with the fewest
    (so that their rounds spread over the period); one wake-up runs every round of its slot, in the
    order they joined. A process with hundreds of controllers wakes a few hundred times a second
    for their state, however many they are, and no round waits for more than its slot's share of
    the others. A late wake-up (a busy loop) runs the rounds due meanwhile; over a period behind (a
    stalled machine) each controller's round runs once and the ones before are skipped: never a
    burst of one controller's rounds. ``now`` is the clock of the deadlines (a test's, else
    ``time.monotonic``; the ticker's sleeps must be on the same)."""

    def __init__(self, period: float, ticker: Ticker | None, now: Callable[[], float] = time.monotonic) -> None:
        self.period = period
        self._now = now
        self.slots = min(MAX_SLOTS, max(1, round(period / SLOT)))
        self.spacing = period / self.slots
        self._ticker = ticker
        #: each slot's rounds: (publish, skipped, the context each runs in: its controller's, for the log)
        self._members: list[list[tuple[RoundCallback, SkipCallback, contextvars.Context]]] = [
            [] for _ in range(self.slots)
        ]
        self._joined = asyncio.Event()

    def add(self, publish: RoundCallback, skipped: SkipCallback) -> None:
        slot = min(range(self.slots), key=lambda s: len(self._members[s]))
        self._members[slot].append((publish, skipped, contextvars.copy_context()))
        self._joined.set()

    def remove(self, publish: RoundCallback) -> None:
        for members in self._members:
            members[:] = [m for m in members if m[0] != publish]

    async def _sleep_until(self, deadline: float) -> None:
        if self._ticker is not None:
            await self._ticker.sleep_until(deadline)
        else:  # a simulated or stepped clock keeps the loop busy: its own timers serve
            await asyncio.sleep(max(0.0, deadline - self._now()))

    async def run(self) -> None:
        members, slots, spacing, now = self._members, self.slots, self.spacing, self._now
        origin = now()
        j = 0  # the last slot run, counted from origin (its rounds are members[j % slots])
        while True:
            if not any(members):
                self._joined.clear()
                await self._joined.wait()
                origin, j = now(), 0  # no rounds were due meanwhile
            j += 1
            for _ in range(slots):  # on to the next slot that has rounds to run
                if members[j % slots]:
                    break
                j += 1
            await self._sleep_until(origin + j * spacing)
            # every slot due by now runs (a busy loop's wake-up comes late: the rounds due meanwhile
            # run in it, else each wake-up would run one slot's and the others would fall behind)
            due = max(j, int((now() - origin) // spacing))
            if due - j >= slots:  # over a period behind: each round once, the rounds before skipped
                missed = due - slots + 1 - j
                for slot in range(slots):
                    count = missed // slots + (1 if (slot - j) % slots < missed % slots else 0)
                    if count:
                        for _, skipped, context in members[slot]:
                            context.run(skipped, count)
                j += missed
            for k in range(j, due + 1):
                for publish, _, context in tuple(members[k % slots]):
                    context.run(publish, origin + k * spacing)
            j = due
