"""The control loop: asyncio drives sans-I/O controllers (:mod:`.controller`) on a :mod:`.clock`.

A :class:`ControlLoop` wakes once per interpolation period at absolute deadlines
(``origin + k x period``, k an integer) and runs that period's servo ticks; a late wake-up runs
them at once and the next deadline is unchanged, so lateness never accumulates (no drift), however
long the run. On a real-time clock every wake-up's lateness is measured (:class:`LoopStats`).
A :class:`SharedLoop` gives the control loops of many controllers (a fleet in one process) one
wake-up per period between them, and leaves out the periods of a controller at rest that nothing
waits on until something reads or changes it (:meth:`ControlLoop.park`). Either runs the period due
before a request is handled when asked (``catch_up``, the emulator's servers call it through
``Server.before_handler``): a burst of requests is handled one after another on the event loop,
and the wake-up would wait behind all of them.
This module is where the controllers meet the event loop and time; they know neither.
"""

from __future__ import annotations

import contextvars
import logging
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from .clock import Clock, SimulatedClock
from .controller import Controller
from .recorder import Recorder

__all__ = ["OVERRUNS_KEPT", "ControlLoop", "LoopStats", "SharedLoop", "overrun_times", "run_simulated"]

log = logging.getLogger(__name__)

#: how many overruns a :class:`LoopStats` keeps the times of (the latest)
OVERRUNS_KEPT = 64


@dataclass
class LoopStats:
    """What a :class:`ControlLoop` run did. Lateness is how long after its deadline a wake-up
    happened (controller time); an overrun is a wake-up later than one interpolation period."""

    ticks: int = 0
    wakes: int = 0
    overruns: int = 0
    #: the last :data:`OVERRUNS_KEPT` overruns: (``time.monotonic()`` when the late wake-up came,
    #: its lateness in s), to set beside what else the machine did then (another process's log, a
    #: timer of its own: ``bench/fleet.py`` runs one)
    late_wakes: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=OVERRUNS_KEPT))
    max_lateness: float = 0.0
    final_lateness: float = 0.0
    simulated: float = 0.0
    wall: float = 0.0

    @property
    def realtime_factor(self) -> float:
        return self.simulated / self.wall if self.wall > 0 else float("inf")


@dataclass
class ControlLoop:
    """Runs a controller on a clock: one wake-up per interpolation period at absolute deadlines,
    each running that period's servo ticks (and any missed ones, so a late wake-up catches up)."""

    controller: Controller
    clock: Clock
    #: records controller ticks while set (it may be set and cleared while the loop runs)
    recorder: Recorder | None = None
    stats: LoopStats = field(default_factory=LoopStats)
    #: further controllers stepped in lockstep (other motion groups; same periods)
    others: Sequence[Controller] = ()
    #: records the ticks of ``others`` (by position; None or missing: not recorded)
    other_recorders: list[Recorder | None] = field(default_factory=list)
    #: called after every wake-up's ticks (e.g. to hand points over or to wake waiting replies)
    on_wake: Callable[[], None] | None = None
    #: called (in the ``except`` block) when a period failed where no :meth:`run` raises it: in a
    #: :class:`SharedLoop`, which has dropped the loop, or in :meth:`catch_up`, after which the loop
    #: runs no more periods (a defect)
    on_failure: Callable[[], None] | None = None
    #: the context a :class:`SharedLoop` runs this loop's periods in (e.g. the log's controller name)
    context: contextvars.Context | None = None
    #: whether everything around the controller is idle too (no task waiting for its wake-ups, no
    #: periodic task with work to do): asked by a :class:`SharedLoop` before it parks the loop
    #: (:meth:`park`); None: never parked
    idle: Callable[[], bool] | None = None
    _running: bool = field(default=False, init=False)
    #: the first deadline and the index of the next period to run (``origin + k x period``), while running
    _origin: float = field(default=0.0, init=False)
    _k: int = field(default=0, init=False)
    _periods: int | None = field(default=None, init=False)
    _in_wake: bool = field(default=False, init=False)
    #: the shared loop that runs this loop's periods (:meth:`SharedLoop.add`)
    _shared: SharedLoop | None = field(default=None, init=False, repr=False)
    #: parked (:meth:`park`): the first of the shared loop's periods not run for this loop
    _parked_at: int | None = field(default=None, init=False)
    _warned_unsynced: bool = field(default=False, init=False)

    def stop(self) -> None:
        self._running = False

    def failed(self) -> None:
        if self.on_failure is not None:
            self.on_failure()

    def check(self, period: float, sub: int) -> None:
        """Every controller of this loop has the interpolation period ``period`` and ``sub`` servo
        ticks per period (ValueError otherwise)."""
        for ctl in (self.controller, *self.others):
            if ctl.config.interpolation_period != period or ctl.servo_ticks_per_interpolation != sub:
                raise ValueError("every controller of one loop must have the same interpolation and servo periods")

    @property
    def parked(self) -> bool:
        return self._parked_at is not None

    def may_park(self) -> bool:
        """Its shared loop may leave this loop's periods after the one just run (:meth:`park`): the
        controller rests (:attr:`.Controller.resting`), nothing records it, it has no other motion
        group, and its owner says everything around it is :attr:`idle`."""
        idle = self.idle
        return (
            idle is not None
            and self.recorder is None
            and not self.others
            and self.controller.resting
            and self._parked_at is None
            and idle()
        )

    def park(self, at: int) -> None:
        """Leave this loop's periods from the shared loop's period ``at`` on, until :meth:`unpark`.

        A controller at rest with nothing around it waiting replays the same period again and again
        (:mod:`.rest`): its shared loop need not run it at all. Whoever reads or changes the
        controller calls :meth:`unpark` first (the emulator does, before a request, a state round, a
        command, a wait), which passes the periods left out at once and steps the last of them, so
        that the controller stands where it would have stood, bit for bit, had every period run."""
        self._parked_at = at

    def unpark(self) -> None:
        """Bring a parked loop's controller up to its shared loop's last period and run it again
        at every period (nothing if not parked). Called inside a shared period (not done by the
        emulator), it is done right after that period."""
        at, shared = self._parked_at, self._shared
        if at is None:
            return
        if shared is None:  # left its shared loop: the controller stays where it is
            self._parked_at = None
            return
        if shared.in_period:
            shared.unpark_after_period(self)
            return
        self._parked_at = None
        owed = shared.next_period - at  # the shared periods run meanwhile, not for this loop
        if owed <= 0:
            return
        controller = self.controller
        if not controller.resting and not self._warned_unsynced:
            # changed while parked by something that did not bring it up first (RobotCell.sync):
            # the change counts from the last period left out, not from when it was made
            self._warned_unsynced = True
            log.warning("a controller at rest was changed without being brought up to now first (a defect)")
        controller.skip_resting(owed - 1)
        stats = self.stats
        stats.ticks += (owed - 1) * self.controller.servo_ticks_per_interpolation
        stats.wakes += owed - 1
        shared.wake_member(self)  # parked again, if it may be, after its next shared period

    def rest_again(self) -> None:
        """Park it again at once if it may be (after :meth:`unpark` for a read that changed
        nothing: a state round): else its next shared period runs it, and parks it then."""
        shared = self._shared
        if shared is not None and not shared.in_period and shared.realtime and self.may_park():
            self.park(shared.next_period)

    def wake(self) -> None:
        """One interpolation period of every controller of the loop: its servo ticks, recorded,
        then :attr:`on_wake`."""
        ctl = self.controller
        sub = ctl.servo_ticks_per_interpolation
        recorder = self.recorder  # may be attached or detached between wake-ups
        if self.others:
            others = [
                (c, self.other_recorders[i] if i < len(self.other_recorders) else None)
                for i, c in enumerate(self.others)
            ]
            for _ in range(sub):
                tick = ctl.step()
                if recorder is not None:
                    recorder.add(tick)
                for other, other_recorder in others:
                    other_tick = other.step()
                    if other_recorder is not None:
                        other_recorder.add(other_tick)
        else:  # no one sees the period's ticks but its last (a recorder aside): at rest, only that one is made
            ctl.step_period(recorder)
        if self.on_wake is not None:
            self.on_wake()
        stats = self.stats
        stats.ticks += sub
        stats.wakes += 1

    async def run(self, duration: float | None = None) -> LoopStats:
        """Run for ``duration`` seconds of controller time (None: until :meth:`stop`)."""
        ctl, clock = self.controller, self.clock
        period = ctl.config.interpolation_period
        self.check(period, ctl.servo_ticks_per_interpolation)
        self._origin = origin = clock.now()
        self._periods = periods = None if duration is None else round(duration / period)
        self._k = 0
        stats = self.stats
        self._running = True
        wall0 = time.perf_counter()
        try:
            while self._running and (periods is None or self._k < periods):
                k = self._k
                deadline = origin + k * period
                await clock.sleep_until(deadline)  # returns at once when late: the loop catches up
                if self._k != k:  # run meanwhile by catch_up
                    continue
                if clock.realtime:
                    _late(stats, clock.now() - deadline, period)
                self._wake_next()
        finally:
            self._running = False
            stats.simulated += self._k * period
            stats.wall += time.perf_counter() - wall0
        return stats

    def catch_up(self) -> None:
        """Run the period now due, if one is, before a request is handled: the same rule as
        :meth:`SharedLoop.catch_up` (one period per call; nothing on a simulated or stepped clock,
        nor inside a period, nor before :meth:`run` or after the periods it was given), for a
        controller that has its loop to itself (a lone ``robot-server``). A period that fails here
        ends the loop and calls :attr:`on_failure` (the emulator's e-stop), as one failing in
        :meth:`run` ends it."""
        if not (self._running and self.clock.realtime) or self._in_wake:
            return
        if self._periods is not None and self._k >= self._periods:
            return
        period = self.controller.config.interpolation_period
        deadline = self._origin + self._k * period
        now = self.clock.now()
        if deadline <= now:
            _late(self.stats, now - deadline, period)
            try:
                self._wake_next()
            except Exception:  # a defect in the period: as in run, the loop ends and the failure is told
                self._running = False
                self._k += 1  # that period is over: run, when it wakes, finds it run and ends
                self.failed()

    def _wake_next(self) -> None:
        self._in_wake = True
        try:
            self.wake()
        finally:
            self._in_wake = False
        self._k += 1


def _late(stats: LoopStats, lateness: float, period: float) -> None:
    stats.final_lateness = lateness
    stats.max_lateness = max(stats.max_lateness, lateness)
    if lateness > period:
        stats.overruns += 1
        stats.late_wakes.append((time.monotonic(), lateness))


def overrun_times(stats: LoopStats) -> str:
    """The overruns kept in ``stats`` for a log line: ``time.monotonic()`` of each late wake-up
    (s, microseconds) and its lateness (ms), oldest first."""
    return ", ".join(f"{at:.6f} +{late * 1e3:.3f} ms" for at, late in stats.late_wakes)


#: the periods a late :class:`SharedLoop` runs at once before it lets the event loop go on (200 ms
#: of the default 4 ms period)
CATCH_UP = 50


@dataclass
class SharedLoop:
    """Many control loops on one clock with one wake-up per interpolation period for all of them
    (the controllers of a fleet, :mod:`robot_server.fleet`): every member's period is run at each
    wake-up, in the order they joined, but a parked member's (:meth:`ControlLoop.park`). A loop
    joins (:meth:`add`) and leaves (:meth:`remove`) between wake-ups; its first period is the next
    wake-up's. The members keep their own counts of
    ticks and wake-ups; lateness and overruns are the shared wake-ups' (:attr:`stats`)."""

    clock: Clock
    #: the interpolation period every member runs at (s), and the servo ticks in it
    period: float
    sub: int
    stats: LoopStats = field(default_factory=LoopStats)
    _members: list[ControlLoop] = field(default_factory=list, init=False)
    #: loops that have joined so far (those that left included)
    joined: int = field(default=0, init=False)
    _running: bool = field(default=False, init=False)
    #: the first deadline and the index of the next period to run (``origin + k x period``)
    _origin: float = field(default=0.0, init=False)
    _k: int = field(default=0, init=False)
    _in_period: bool = field(default=False, init=False)
    #: parked loops whose unpark was asked for during a period (done right after it)
    _unpark_after: list[ControlLoop] = field(default_factory=list, init=False)

    def add(self, loop: ControlLoop) -> None:
        loop.check(self.period, self.sub)
        self._members.append(loop)
        loop._shared = self
        self.joined += 1

    def remove(self, loop: ControlLoop) -> None:
        if loop in self._members and not self._in_period:  # leaves standing where its periods brought it
            loop.unpark()  # (a period failing there removes it already)
        if loop in self._members:
            self._members.remove(loop)
            loop._shared = None
            loop._parked_at = None

    @property
    def in_period(self) -> bool:
        return self._in_period

    @property
    def realtime(self) -> bool:
        return self.clock.realtime

    @property
    def next_period(self) -> int:
        """The index of the next period to run (``origin + k x period``)."""
        return self._k

    @property
    def parked_members(self) -> int:
        """Members whose periods are left out now (:meth:`ControlLoop.park`)."""
        return sum(1 for loop in self._members if loop.parked)

    def unpark_after_period(self, loop: ControlLoop) -> None:
        if loop not in self._unpark_after:
            self._unpark_after.append(loop)

    @property
    def members(self) -> int:
        return len(self._members)

    def stop(self) -> None:
        self._running = False

    async def run(self) -> LoopStats:
        """Wake every interpolation period until :meth:`stop`, running every member's period (a
        parked member's left out)."""
        clock, period, stats = self.clock, self.period, self.stats
        self._origin = clock.now()
        self._k = 0
        self._running = True
        wall0 = time.perf_counter()
        try:
            while self._running:
                k = self._k
                deadline = self._origin + k * period
                await clock.sleep_until(deadline)
                if not clock.realtime:  # a simulated or stepped clock: one period per wake-up
                    self._run_period()
                    continue
                if self._k == k:  # not run meanwhile by catch_up
                    _late(stats, clock.now() - deadline, period)
                    self._run_period()
                self._run_due()
        finally:
            self._running = False
            stats.simulated += self._k * period
            stats.wall += time.perf_counter() - wall0
            for loop in tuple(self._members):  # the controllers stand where the periods run left them
                loop.unpark()
        return stats

    def catch_up(self) -> None:
        """Run the period now due, if one is: what a handler calls before it works (a burst of
        many clients' points is planned on the event loop's thread, one handler after another,
        and the wake-up would wait behind all of them). Like a controller whose interpolation
        task preempts its planner: the periods run on time, the requests wait a little. One
        period at most: a handler takes far less than a period, and a loop far behind (more work
        than the machine can do) catches up at its wake-ups, not at the cost of every request.
        Nothing on a simulated or stepped clock (its periods are its wake-ups'), nor inside a
        period."""
        if self._running and not self._in_period and self.clock.realtime:
            self._run_due(1)

    def _run_due(self, limit: int = CATCH_UP) -> None:
        # the periods due (late: the ones due meanwhile at once, at most ``limit``, then the event
        # loop goes on: between two of them it would take as long again)
        clock, period, stats = self.clock, self.period, self.stats
        for _ in range(limit):
            deadline = self._origin + self._k * period
            now = clock.now()
            if deadline > now:
                break
            _late(stats, now - deadline, period)
            self._run_period()

    def _run_period(self) -> None:
        self._in_period = True
        try:
            self._period()
        finally:
            self._in_period = False
        self._k += 1
        if self._unpark_after:
            waiting, self._unpark_after = self._unpark_after, []
            for loop in waiting:
                loop.unpark()

    def _period(self) -> None:
        # a parked member (at rest, nothing around it waiting: ControlLoop.park) is left out until
        # it is needed; on a simulated or stepped clock none is, the test reads the controllers
        park = self.clock.realtime
        k = self._k
        for loop in tuple(self._members):  # a member may leave during another's period
            if loop._parked_at is not None:
                continue
            if self.wake_member(loop) and park and loop.may_park():
                loop.park(k + 1)
        self.stats.ticks += self.sub
        self.stats.wakes += 1

    def wake_member(self, loop: ControlLoop) -> bool:
        """One period of ``loop``, in its context; a loop whose period fails leaves (and is told,
        :meth:`ControlLoop.failed`): False then."""
        try:
            if loop.context is None:
                loop.wake()
            else:
                loop.context.run(loop.wake)
            return True
        except Exception:  # pragma: no cover - a defect in one controller: that one stops
            self.remove(loop)
            try:
                if loop.context is None:
                    loop.failed()
                else:
                    loop.context.run(loop.failed)
            except Exception:  # its failure handler failed too: the others run on
                log.exception("a controller's control loop failed and could not be stopped")
            return False


async def run_simulated(controller: Controller, seconds: float, recorder: Recorder | None = None) -> LoopStats:
    """Convenience: run ``controller`` for ``seconds`` on a :class:`.SimulatedClock`."""
    return await ControlLoop(controller, SimulatedClock(controller.time), recorder).run(seconds)
