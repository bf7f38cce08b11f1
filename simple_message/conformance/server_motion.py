"""The server suite's motion rules: the choreography that moves the robot.

Only with ``allow_motion`` does the suite send trajectory points, and only after STATUS says the
robot is idle, in AUTO and not in error (``motion.preconditions``): a small move of one joint
(``amplitude``, default 0.01 rad) during which STATUS must say in_motion, a move stopped once under
way, a point beyond any joint's range (refused, nothing moved), and on MotoROS its trajectory mode,
BUSY and start-position rules. Every move is followed by one back to where the robot was. A rule
that cannot go on (the server stopped answering, a move failed, the state port went silent) aborts
the motion phase: the rules after it SKIP, and the suite sends a STOP (and on MotoROS
STOP_TRAJ_MODE) whatever happened.

The rules are methods of :class:`MotionRules`: they send through the suite's
:class:`~.server_session.Session`, know the robot by its :class:`~.server_session.RobotView` and are
judged by its :class:`~.server_runner.RuleRunner`.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Awaitable, Callable, Sequence

from ..constants import (
    CommType,
    InvalidSubcode,
    MotoCommand,
    MotoResult,
    MsgType,
    ReplyCode,
    RobotMode,
    SpecialSeq,
    TriState,
    ValidFields,
)
from ..messages import (
    JointTrajPt,
    JointTrajPtFull,
    Message,
    MotoMotionCtrl,
    MotoMotionReply,
    Status,
)
from .expectations import MOTION_RULES, MOTOROS_MOTION_RULES
from .links import Seen
from .report import Evidence, Verdict
from .server_checks import STILL, _mode, _Skip, _status_text, _tri, _Verdict
from .server_runner import RuleRunner, _Abort
from .server_session import Session

__all__ = ["BEYOND_LIMITS", "BEYOND_SECONDS", "MotionRules"]

#: how far beyond the current position the out-of-limit point puts the joint (rad): beyond the
#: range of any revolute joint of an industrial arm
BEYOND_LIMITS = 100.0
#: the time the out-of-limit point is given (s): accepted by mistake, it would creep
BEYOND_SECONDS = 1000.0


class MotionRules:
    """The motion rules of one run: sent through ``session``, judged by ``runner``."""

    def __init__(self, session: Session, runner: RuleRunner) -> None:
        self.session = session
        self.runner = runner
        self.options = session.options
        self.expect = session.expect
        self.dialect = session.dialect
        self.robot = session.robot

    # -- motion -------------------------------------------------------------------------------------------------

    async def run(self) -> None:
        """The motion rules in their order (each SKIPs without ``allow_motion``, or once one
        aborted), then a STOP (and on MotoROS STOP_TRAJ_MODE) whatever happened."""
        names = MOTION_RULES
        moroso = self.dialect.motion_control
        if not moroso:
            self.runner.skip_all(MOTOROS_MOTION_RULES, f"not a MotoROS server (profile {self.options.profile})")
        if not self.options.allow_motion:
            self.runner.skip_all(names, "needs --allow-motion (it moves the robot)")
            return
        pre = await self.runner.rule("motion.preconditions", self._preconditions)
        if pre is None or pre.verdict is not Verdict.PASS:
            self.runner.skip_all(
                names, "motion.preconditions " + ("not run" if pre is None else "not met: " + pre.detail)
            )
            return
        steps: list[tuple[str, Callable[[], Awaitable[_Verdict]]]] = [
            ("motion.small-move", self._small_move),
            ("motion.stop", self._stop),
        ]
        if moroso:
            steps += [("motoros.busy", self._busy), ("motoros.start-position", self._start_position)]
        steps.append(("motion.out-of-limit", self._out_of_limit))
        try:
            if moroso:
                ready = await self.runner.rule("motoros.traj-mode", self._start_traj_mode)
                if ready is not None and ready.verdict is Verdict.FAIL:
                    raise _Abort("trajectory mode could not be started")
            for rule, check in steps:
                await self.runner.rule(rule, check)
                if self.runner.aborted:
                    # the robot may not be where the next rule needs it: no more motion
                    raise _Abort(self.runner.aborted)
        except _Abort as abort:
            self.runner.skip_all(names, f"an earlier motion rule failed: {abort}")
        finally:
            if self.session.motion is not None:
                with contextlib.suppress(Exception):
                    await self.session.exchange(self.session.motion, self.session.stop_message())
                if moroso:
                    with contextlib.suppress(Exception):
                        await self._stop_traj_mode_end()

    async def _preconditions(self) -> _Verdict:
        status = self.robot.status()
        joints = self.robot.joints()
        if status is None or joints is None:
            return _Verdict(Verdict.WARN, "no STATUS or joint state to check the robot by")
        if not self.robot.fresh():
            return _Verdict(Verdict.WARN, "the state port went silent: no motion sent without knowing the robot")
        ev = [Evidence.note(f"STATUS {_status_text(status)}")]
        problems = []
        if status.in_motion != TriState.FALSE:
            problems.append(f"in_motion {_tri(status.in_motion)}")
        if status.mode != RobotMode.AUTO:
            problems.append(f"mode {_mode(status.mode)}")
        if status.in_error != TriState.FALSE:
            problems.append(f"in_error {_tri(status.in_error)}")
        if status.e_stopped == TriState.TRUE:
            problems.append("e-stopped")
        if problems:
            return _Verdict(Verdict.WARN, ", ".join(problems) + ": no motion sent", ev)
        return _Verdict(Verdict.PASS, "idle, AUTO, not in error", ev)

    def _point(
        self, sequence: int, positions: Sequence[float], seconds: float, since_start: float, ratio: float = 0.1
    ) -> Message:
        if self.dialect.point_type == MsgType.JOINT_TRAJ_PT_FULL:
            return JointTrajPtFull(
                0,
                sequence,
                ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY,
                since_start,
                tuple(positions),
                (0.0,) * len(positions),
            )
        # a controller that moves at the velocity given (Stäubli) refuses 0 even for the first point
        velocity = ratio if seconds > 0 or not self.dialect.timed else 0.0
        return JointTrajPt(sequence, tuple(positions), velocity=velocity, duration=seconds)

    def _sequences(self) -> tuple[int, int]:
        """A two-point trajectory's sequence numbers: streamed (0, 1), or for ABB a download (-1,
        -3): its RAPID server only adds streamed points to its buffer and runs them at -3 (§8.2)."""
        if self.options.profile == "abb":
            return SpecialSeq.START_TRAJECTORY_DOWNLOAD, SpecialSeq.END_TRAJECTORY
        return 0, 1

    def _accepted(self, reply: Seen | None) -> bool:
        msg = reply.message if reply else None
        if msg is None:
            return False
        if isinstance(msg, MotoMotionReply):
            return msg.result == MotoResult.SUCCESS
        return msg.comm_type == CommType.SERVICE_REPLY and msg.reply_code == ReplyCode.SUCCESS

    def _target(self, start: tuple[float, ...], offset: float) -> list[float]:
        target = list(start)
        target[self.options.joint - 1] += offset
        return target

    async def _send_move(
        self,
        start: tuple[float, ...],
        target: Sequence[float],
        seconds: float,
        ev: list[Evidence],
        what: str,
        *,
        ratio: float = 0.1,
    ) -> None:
        """A two-point trajectory from where the robot is to ``target`` in ``seconds``, both points
        accepted (BUSY is resent: MotoROS's flow control); else :class:`_Abort` saying why, with
        the frames."""
        assert self.session.motion is not None
        first, second = self._sequences()
        for seq, pos, dt in ((first, start, 0.0), (second, target, seconds)):
            reply = await self._send_point(self._point(seq, pos, dt, dt, ratio), ev)
            if reply is None:
                why = "the connection was closed" if not self.session.motion.alive else "no reply"
                raise _Abort(f"{what}: {why} (point {seq})", ev)
            if not self._accepted(reply):
                raise _Abort(f"{what}: point {seq} was refused", ev)

    async def _send_point(self, point: Message, ev: list[Evidence]) -> Seen | None:
        assert self.session.motion is not None
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.options.motion_timeout
        while True:
            sent, reply = await self.session.exchange(self.session.motion, point)
            busy = (
                reply is not None
                and isinstance(reply.message, MotoMotionReply)
                and reply.message.result == MotoResult.BUSY
            )
            if not busy or loop.time() > deadline:
                ev.append(sent.evidence(self.session.real))
                if reply is not None:
                    ev.append(reply.evidence(self.session.real))
                return reply
            await asyncio.sleep(0.01)  # MotoROS's client resends a BUSY point every few ms

    async def _settle(self, timeout: float) -> tuple[float, ...] | None:
        """Wait for in_motion FALSE (or the joints still, when STATUS says UNKNOWN) in a STATUS
        sent after the wait began (one from before may predate a motion that has not begun yet:
        Fanuc sends STATUS about 4 times a second), and return the joints then."""
        last: list[tuple[float, ...]] = []
        began = time.monotonic()

        def done(joints: tuple[float, ...], _status: Status | None) -> bool:
            status = self.robot.status_since(began)
            if status is None:
                return False
            last.append(joints)
            if status is not None and status.in_motion == TriState.FALSE:
                return len(last) > 1 and _distance(last[-2], joints) <= STILL
            if status is not None and status.in_motion == TriState.TRUE:
                return False
            # in_motion UNKNOWN (the C++ default, §5): still over ten joint states
            return len(last) > 10 and _distance(last[-11], joints) <= STILL

        if not await self.robot.wait(done, timeout):
            return None
        return self.robot.joints()

    async def _return_to(self, start: tuple[float, ...]) -> None:
        """Move back to where a rule began (a rule leaves the robot where it found it)."""
        now = self.robot.joints()
        if now is None or _distance(now, start) <= self.options.tolerance:
            return
        ev: list[Evidence] = []
        await self._send_move(now, start, self.options.move_time, ev, "the move back to the start position")
        if await self._settle(self.options.move_time + self.options.motion_timeout) is None:
            raise _Abort("the move back to the start position did not end", ev)

    async def _small_move(self) -> _Verdict:
        o = self.options
        start = self.robot.joints()
        assert start is not None
        target = self._target(start, o.amplitude)
        ev = [
            Evidence.note(
                f"joint {o.joint}: {start[o.joint - 1]:.5f} -> {target[o.joint - 1]:.5f} rad in {o.move_time:g} s"
            )
        ]
        sent_at = time.monotonic()
        self.robot.saw_in_motion = False
        await self._send_move(start, target, o.move_time, ev, "a small move near the current position")
        final = await self._settle_after_motion(o.move_time + o.motion_timeout)
        took = time.monotonic() - sent_at
        await self.runner.rule("motion.in-motion", lambda: self._in_motion_verdict(final, ev, took))
        if final is None:
            raise _Abort(f"the move did not end within {o.move_time + o.motion_timeout:g} s", ev)
        error = _distance(final, target)
        ev.append(Evidence.note(f"reached {final[o.joint - 1]:.5f}, error {error:.5f} rad after {took:.2f} s"))
        await self._return_to(start)
        if error > o.tolerance:
            return _Verdict(Verdict.FAIL, f"stopped {error:.4f} rad from the target (tolerance {o.tolerance:g})", ev)
        return _Verdict(Verdict.PASS, f"target reached within {error:.5f} rad in {took:.2f} s", ev)

    async def _settle_after_motion(self, timeout: float) -> tuple[float, ...] | None:
        """Wait for the move to begin (in_motion TRUE or the joints leaving the start) and then end."""
        start = self.robot.joints()
        assert start is not None
        began = await self.robot.wait(
            lambda j, s: self.robot.saw_in_motion or _distance(j, start) > STILL,
            min(timeout, 2.0 + self.options.move_time / 2),
        )
        if not began:
            return self.robot.joints()
        return await self._settle(timeout)

    async def _in_motion_verdict(
        self, final: tuple[float, ...] | None, ev: list[Evidence], took: float = math.inf
    ) -> _Verdict:
        status = self.robot.status()
        if status is None:
            raise _Skip("no STATUS")
        if not self.robot.saw_in_motion:
            rate = self.expect.rates.get(MsgType.STATUS)
            if rate is not None and took < 2.0 / rate:
                # a controller that moves at its own speed may be done between two STATUS (Fanuc's
                # come about every 0.26 s): nothing seen, nothing wrong
                return _Verdict(
                    Verdict.WARN,
                    f"in_motion not seen TRUE: the move was over within {took:.2f} s, and STATUS comes every "
                    f"{1.0 / rate:.2f} s; try a larger --amplitude",
                    ev[:1],
                )
            return _Verdict(Verdict.FAIL, "in_motion never TRUE during the move", ev[:1])
        if final is None or status.in_motion != TriState.FALSE:
            return _Verdict(
                Verdict.FAIL,
                f"in_motion {_tri(status.in_motion)} after the move (a ROS goal would never succeed)",
                ev[:1],
            )
        return _Verdict(Verdict.PASS, "TRUE while moving, FALSE after", [])

    async def _stop(self) -> _Verdict:
        o = self.options
        start = self.robot.joints()
        assert start is not None and self.session.motion is not None
        seconds = 2 * o.move_time
        target = self._target(start, o.amplitude)
        ev: list[Evidence] = [Evidence.note(f"a {seconds:g} s move of joint {o.joint}, stopped once it moves")]
        # a controller that moves at the velocity given (Stäubli) is asked for 1 %: slow enough to stop
        ratio = 0.1 if self.dialect.timed else 0.01
        await self._send_move(start, target, seconds, ev, "the move to stop", ratio=ratio)
        # STOP once a tenth of the way is done (the move is then surely under way)
        moving = await self.robot.wait(lambda j, s: _distance(j, start) > o.amplitude / 10, seconds + o.motion_timeout)
        at_stop = self.robot.joints()
        if not moving or at_stop is None:
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            raise _Skip("the move did not begin; STOP not tried")
        stop = self.session.stop_message()
        sent, reply = await self.session.exchange(self.session.motion, stop)
        ev += [sent.evidence(self.session.real)] + ([reply.evidence(self.session.real)] if reply else [])
        if reply is None or not self.session.answers(stop, reply):
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            return _Verdict(
                Verdict.FAIL, f"STOP not answered within {o.reply_timeout:g} s (the client hangs, §10 pitfall 5)", ev
            )
        latency = (reply.time - sent.time) * 1000
        left = _distance(at_stop, target)
        if left <= o.tolerance:
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            raise _Skip(
                f"the move was over when STOP was sent (answered in {latency:.1f} ms): the server does not "
                "take the move's time (Fanuc runs at a fixed speed, §8.3); try a larger --move-time"
            )
        rest = max(2.0, o.move_time)
        final = await self._settle(rest)
        if final is None:
            await self._settle(seconds + o.motion_timeout)
            await self._return_to(start)
            return _Verdict(Verdict.FAIL, f"still moving {rest:g} s after STOP", ev)
        short = _distance(final, target)
        ev.append(
            Evidence.note(
                f"STOP sent {left:.5f} rad short of the target, answered in {latency:.1f} ms; came to rest "
                f"{short:.5f} rad short"
            )
        )
        await self._return_to(start)
        if short <= o.tolerance:
            known = self.expect.stop_stops_nothing
            if known is not None:
                return _Verdict(Verdict.WARN, f"the robot went on to the target after STOP: {known}", ev)
            return _Verdict(Verdict.FAIL, "the robot went on to the target after STOP", ev)
        return _Verdict(Verdict.PASS, f"answered in {latency:.1f} ms, stopped {short:.4f} rad short", ev)

    async def _out_of_limit(self) -> _Verdict:
        """A point far beyond any joint's range, timed to take 1000 s at 1 % of the speed limit, so
        that a server that wrongly accepts it would creep towards it, and a STOP at once on its
        reply: whatever the server does, the robot cannot go far."""
        o = self.options
        start = self.robot.joints()
        assert start is not None and self.session.motion is not None
        target = self._target(start, BEYOND_LIMITS)
        seconds = BEYOND_SECONDS
        ev: list[Evidence] = [
            Evidence.note(
                f"joint {o.joint} to {target[o.joint - 1]:.2f} rad ({BEYOND_LIMITS:g} rad beyond), in {seconds:g} s"
            )
        ]
        first_seq, second_seq = self._sequences()
        first = await self._send_point(self._point(first_seq, start, 0.0, 0.0), ev)
        if not self._accepted(first):
            raise _Skip("the trajectory's first point, at the current position, was refused")
        reply = await self._send_point(self._point(second_seq, target, seconds, seconds, ratio=0.01), ev)
        accepted = self._accepted(reply)
        if accepted and self.expect.acks_before_checking:
            # Fanuc's relay acknowledges what it reads, then checks it: a FAILURE follows, and it hangs up
            late = await self.session.motion.next_frame(self.options.reply_timeout)
            if late is not None:
                ev.append(late.evidence(self.session.real))
            if late is not None and late.message is not None and late.message.reply_code == ReplyCode.FAILURE:
                moved = await self.robot.wait(lambda j, s: _distance(j, start) > 10 * STILL, 0.5)
                closed = (
                    not self.session.motion.alive
                    or await self.session.motion.next_frame(self.options.reply_timeout) is None
                )
                await self.session.reopen_motion()
                if moved:
                    ev.append(Evidence.note(f"moved: {self.robot.moved_since(start)}"))
                    return _Verdict(Verdict.FAIL, "the robot moved towards a point beyond its limits", ev)
                return _Verdict(
                    Verdict.PASS,
                    "acknowledged as it was read, then refused (FAILURE)"
                    + (" and the connection closed" if closed else "")
                    + ", as Fanuc's relay does (ros_relay.kl:328-349); nothing moved",
                    ev,
                )
        if accepted or reply is None:
            with contextlib.suppress(Exception):
                await self.session.exchange(self.session.motion, self.session.stop_message())
        moved = await self.robot.wait(lambda j, s: _distance(j, start) > 10 * STILL, 0.5)
        fresh = self.robot.fresh()
        if not accepted and reply is not None:
            with contextlib.suppress(Exception):
                await self.session.exchange(
                    self.session.motion, self.session.stop_message()
                )  # close the trajectory begun
        if moved:
            ev.append(Evidence.note(f"moved: {self.robot.moved_since(start)}"))
            await self._settle(o.motion_timeout)
            await self._return_to(start)
            return _Verdict(Verdict.FAIL, "the robot moved towards a point beyond its limits", ev)
        if not fresh:
            raise _Abort("the state port went silent: whether the robot moved cannot be told", ev)
        if reply is None:
            return _Verdict(Verdict.FAIL, "no reply to the point (nothing moved)", ev)
        if accepted:
            if self.options.profile == "abb":
                # RAPID acknowledges every point; the motion task refuses it later (§8.2)
                return _Verdict(
                    Verdict.WARN, "acknowledged, as ABB's server acknowledges every point; nothing moved", ev
                )
            return _Verdict(
                Verdict.FAIL,
                "accepted a point beyond its limits (stopped at once; nothing moved): a client cannot "
                "know it will not run",
                ev,
            )
        return _Verdict(Verdict.PASS, "refused, nothing moved", ev)

    # -- MotoROS ---------------------------------------------------------------------------------------------

    async def _ctrl(
        self, command: MotoCommand, ev: list[Evidence], timeout: float | None = None
    ) -> MotoMotionReply | None:
        assert self.session.motion is not None
        sent, reply = await self.session.exchange(self.session.motion, MotoMotionCtrl(0, 0, command), timeout)
        ev.append(sent.evidence(self.session.real))
        if reply is not None:
            ev.append(reply.evidence(self.session.real))
        msg = reply.message if reply else None
        return msg if isinstance(msg, MotoMotionReply) else None

    async def _start_traj_mode(self) -> _Verdict:
        ev: list[Evidence] = []
        start = await self._ctrl(MotoCommand.START_TRAJ_MODE, ev, self.options.motion_timeout)
        if start is None or start.result != MotoResult.SUCCESS:
            return _Verdict(Verdict.FAIL, "START_TRAJ_MODE not answered SUCCESS", ev)
        ready = await self._ctrl(MotoCommand.CHECK_MOTION_READY, ev)
        if ready is None or ready.result != MotoResult.TRUE:
            return _Verdict(Verdict.FAIL, "not ready after START_TRAJ_MODE", ev)
        # the end of trajectory mode is judged when the suite stops it (_stop_traj_mode_end)
        return _Verdict(Verdict.PASS, "START_TRAJ_MODE SUCCESS, then ready", ev)

    async def _stop_traj_mode_end(self) -> None:
        ev: list[Evidence] = []
        stop = await self._ctrl(MotoCommand.STOP_TRAJ_MODE, ev)
        ready = await self._ctrl(MotoCommand.CHECK_MOTION_READY, ev)
        result = self.runner.reported("motoros.traj-mode")
        if result is None or result.verdict is not Verdict.PASS:
            return
        result.evidence.extend(ev[:4])
        if stop is None or stop.result != MotoResult.SUCCESS:
            result.verdict, result.detail = Verdict.FAIL, "STOP_TRAJ_MODE not answered SUCCESS"
        elif ready is None or ready.result == MotoResult.TRUE:
            result.verdict, result.detail = Verdict.FAIL, "still ready after STOP_TRAJ_MODE"
        else:
            result.detail = "START_TRAJ_MODE made it ready, STOP_TRAJ_MODE not ready"

    async def _busy(self) -> _Verdict:
        o = self.options
        start = self.robot.joints()
        assert start is not None and self.session.motion is not None
        count = 8
        step = o.move_time / 4
        ev: list[Evidence] = [
            Evidence.note(f"{count} points {step:g} s apart, each sent as soon as the last was taken")
        ]
        busy = 0
        points = [self._point(0, start, 0.0, 0.0)]
        for k in range(1, count):
            offset = o.amplitude * (k / (count - 1))
            points.append(self._point(k, self._target(start, offset), step, k * step))
        loop = asyncio.get_running_loop()
        deadline = loop.time() + o.motion_timeout + count * step
        for point in points:
            while True:
                sent, reply = await self.session.exchange(self.session.motion, point)
                msg = reply.message if reply else None
                if isinstance(msg, MotoMotionReply) and msg.result == MotoResult.BUSY:
                    busy += 1
                    if busy <= 3:
                        ev += [sent.evidence(self.session.real), reply.evidence(self.session.real)] if reply else []
                    if msg.sequence != getattr(point, "sequence", None):
                        return _Verdict(Verdict.FAIL, f"a BUSY reply names sequence {msg.sequence}", ev)
                    if loop.time() > deadline:
                        return _Verdict(Verdict.FAIL, "BUSY for longer than the trajectory lasts", ev)
                    await asyncio.sleep(0.01)
                    continue
                if not self._accepted(reply):
                    ev += [sent.evidence(self.session.real)] + ([reply.evidence(self.session.real)] if reply else [])
                    raise _Abort(f"point {getattr(point, 'sequence', '?')} refused", ev)
                break
        target = self._target(start, o.amplitude)
        final = await self._settle(count * step + o.motion_timeout)
        if final is None:
            raise _Abort("the trajectory did not end", ev)
        error = _distance(final, target)
        await self._return_to(start)
        ev.append(Evidence.note(f"{busy} BUSY replies; the last point reached within {error:.5f} rad"))
        if error > o.tolerance:
            return _Verdict(Verdict.FAIL, f"ended {error:.4f} rad from the last point: a BUSY point was lost", ev)
        return _Verdict(Verdict.PASS, f"{busy} BUSY replies, every point taken, the last reached", ev)

    async def _start_position(self) -> _Verdict:
        o = self.options
        start = self.robot.joints()
        assert start is not None
        off = self._target(start, o.amplitude)
        ev: list[Evidence] = [Evidence.note(f"sequence 0 at joint {o.joint} + {o.amplitude:g} rad")]
        reply = await self._send_point(self._point(0, off, 0.0, 0.0), ev)
        moved = await self.robot.wait(lambda j, s: _distance(j, start) > 10 * STILL, 0.5)
        msg = reply.message if reply else None
        if not moved and not self.robot.fresh():
            raise _Abort("the state port went silent: whether the robot moved cannot be told", ev)
        if moved:
            await self._settle(o.motion_timeout)
            await self._return_to(start)
            return _Verdict(Verdict.FAIL, "the robot moved (jumped to a start point away from it)", ev)
        if not isinstance(msg, MotoMotionReply):
            return _Verdict(Verdict.FAIL, "no MOTO_MOTION_REPLY", ev)
        if msg.result != MotoResult.INVALID or msg.subcode != InvalidSubcode.DATA_START_POS:
            verdict = Verdict.FAIL if msg.result == MotoResult.SUCCESS else Verdict.WARN
            return _Verdict(verdict, f"result {msg.result} subcode {msg.subcode}, not INVALID 3011", ev)
        return _Verdict(Verdict.PASS, "INVALID 3011 (DATA_START_POS), nothing moved", ev)


# -- helpers -----------------------------------------------------------------------------------------


def _distance(a: Sequence[float], b: Sequence[float]) -> float:
    return max((abs(x - y) for x, y in zip(a, b, strict=False)), default=0.0)
