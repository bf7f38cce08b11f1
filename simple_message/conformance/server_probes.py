"""The server suite's probes: the requests that cannot move anything, and what the replies must be.

On the motion port, before any motion and whether or not motion is allowed: a PING (the profiles
whose motion port takes one, §2), a burst of requests in one segment answered one by one in order
with none extra (§3: replies carry no request id), a request and a TOPIC of a type nobody assigns
(a FAILURE, or MotoROS's INVALID 3003; a TOPIC is ignored, §3, §8.1), MotoROS's CHECK_MOTION_READY,
and the reference library's list of malformed frames (:mod:`.malformed`), each on a connection of
its own, after each of which the server must go on serving: the state port keeps sending and a new
motion connection is answered (§1.2, §1.5, §11). Nothing here is a trajectory point: the only
motion request sent is a STOP (the liveness request of the profiles that answer no PING), and a
robot that moves while the malformed frames are sent FAILs the rule.

Each probe is a check of :class:`~.server_runner.RuleRunner`: it returns a verdict with its evidence
or raises :class:`~.server_checks._Skip`.
"""

from __future__ import annotations

from ..constants import CommType, InvalidSubcode, MotoCommand, MotoResult, MsgType, ReplyCode
from ..dialects import ReplyStyle
from ..messages import Message, MotoMotionCtrl, MotoMotionReply, Ping, RawMessage
from .links import ProbeLink, Seen
from .malformed import malformed_cases
from .report import Evidence, Verdict
from .server_checks import _Skip, _Verdict
from .server_session import Session

__all__ = ["Probes"]


class Probes:
    """The request rules of one run, sent through ``session``."""

    def __init__(self, session: Session) -> None:
        self.session = session
        self.options = session.options
        self.expect = session.expect
        self.dialect = session.dialect
        self.robot = session.robot

    async def ping(self) -> _Verdict:
        if not self.expect.ping:
            raise _Skip(
                f"the {self.options.profile} profile's motion port takes only JOINT_TRAJ_PT ({self.expect.source})"
            )
        assert self.session.motion is not None
        sent, reply = await self.session.exchange(self.session.motion, Ping())
        ev = [sent.evidence()] + ([reply.evidence()] if reply else [])
        if reply is None:
            return _Verdict(Verdict.FAIL, f"no reply within {self.options.reply_timeout:g} s", ev)
        msg = reply.message
        if msg is None or msg.msg_type != MsgType.PING:
            return _Verdict(Verdict.FAIL, "the reply is not a PING", ev)
        if msg.comm_type != CommType.SERVICE_REPLY or msg.reply_code != ReplyCode.SUCCESS:
            return _Verdict(Verdict.FAIL, "the PING reply is not a SERVICE_REPLY with SUCCESS", ev)
        latency = (reply.time - sent.time) * 1000
        return _Verdict(Verdict.PASS, f"PING answered in {latency:.1f} ms", ev)

    async def order(self) -> _Verdict:
        assert self.session.motion is not None and self.session.wire is not None
        if self.expect.unknown_types:
            unknown = RawMessage(self.options.unknown_type)
            burst: list[Message] = [Ping(), unknown, Ping(), unknown, Ping()]
        else:
            burst = [self.session.stop_message()] * 3
        sentinel = self.session.liveness()
        link = self.session.motion
        link.skip_pending()
        sent = link.send(b"".join(m.encode(self.session.wire) for m in burst), None)
        ev = [Evidence.note(f"{len(burst)} requests in one segment: " + ", ".join(_name(m) for m in burst))]
        ev.append(sent.evidence())
        replies: list[Seen] = []
        for _ in burst:
            reply = await link.next_frame(self.options.reply_timeout)
            if reply is None:
                break
            replies.append(reply)
        ev.extend(r.evidence() for r in replies)
        if len(replies) < len(burst):
            return _Verdict(Verdict.FAIL, f"{len(replies)} replies to {len(burst)} requests", ev)
        for k, (request, reply) in enumerate(zip(burst, replies, strict=True)):
            if not self.session.answers(request, reply):
                return _Verdict(Verdict.FAIL, f"reply {k + 1} does not answer request {k + 1} ({_name(request)})", ev)
        # one per request, none extra: the sentinel's reply must be the very next frame
        s_sent, s_reply = await self.session.exchange(link, sentinel, keep=True)
        ev += [s_sent.evidence()] + ([s_reply.evidence()] if s_reply else [])
        if s_reply is None:
            return _Verdict(Verdict.FAIL, "no reply to the request sent after the burst", ev)
        if not self.session.answers(sentinel, s_reply) or s_reply.time < s_sent.time:
            return _Verdict(Verdict.FAIL, "an extra frame came before the next request's reply", ev)
        return _Verdict(Verdict.PASS, f"{len(burst)} replies in order, then the next request's reply", ev)

    async def unknown_type(self) -> _Verdict:
        if not self.expect.unknown_types:
            raise _Skip(f"the {self.options.profile} profile's servers take no other type ({self.expect.source})")
        assert self.session.motion is not None
        request = RawMessage(self.options.unknown_type)
        sent, reply = await self.session.exchange(self.session.motion, request)
        ev = [sent.evidence()] + ([reply.evidence()] if reply else [])
        if reply is None or reply.message is None:
            return _Verdict(Verdict.FAIL, f"no reply to type {self.options.unknown_type} (the client would hang)", ev)
        msg = reply.message
        if self.dialect.reply_style is ReplyStyle.MOTO_MOTION_REPLY:
            if not isinstance(msg, MotoMotionReply):
                return _Verdict(Verdict.FAIL, "MotoROS answers an unknown type with MOTO_MOTION_REPLY", ev)
            if msg.result != MotoResult.INVALID or msg.subcode != InvalidSubcode.MSGTYPE:
                return _Verdict(Verdict.FAIL, f"result {msg.result} subcode {msg.subcode}, not INVALID 3003", ev)
            if msg.command != self.options.unknown_type:
                return _Verdict(Verdict.WARN, f"INVALID 3003, but command {msg.command} is not the type sent", ev)
            return _Verdict(Verdict.PASS, "MOTO_MOTION_REPLY INVALID 3003 (MSGTYPE)", ev)
        if msg.msg_type != self.options.unknown_type or msg.comm_type != CommType.SERVICE_REPLY:
            return _Verdict(Verdict.FAIL, "the reply is not a SERVICE_REPLY of the type sent", ev)
        if msg.reply_code != ReplyCode.FAILURE:
            return _Verdict(Verdict.FAIL, f"reply_code {msg.reply_code}, not FAILURE", ev)
        return _Verdict(Verdict.PASS, "FAILURE, as the C++ MessageManager answers", ev)

    async def unknown_topic(self) -> _Verdict:
        if not self.expect.unknown_types:
            raise _Skip(f"the {self.options.profile} profile's servers take no other type ({self.expect.source})")
        assert self.session.motion is not None and self.session.wire is not None
        topic = RawMessage(self.options.unknown_type, comm_type=CommType.TOPIC)
        sentinel = Ping()
        link = self.session.motion
        link.skip_pending()
        sent = link.send(topic.encode(self.session.wire) + sentinel.encode(self.session.wire), None)
        first = await link.next_frame(self.options.reply_timeout)
        ev = [sent.evidence()] + ([first.evidence()] if first else [])
        motoros = self.dialect.reply_style is ReplyStyle.MOTO_MOTION_REPLY
        if first is None:
            return _Verdict(Verdict.FAIL, "no reply at all (not even to the PING after the TOPIC)", ev)
        if motoros:
            msg = first.message
            if not (isinstance(msg, MotoMotionReply) and msg.result == MotoResult.INVALID):
                return _Verdict(Verdict.FAIL, "MotoROS answers every message but replies: INVALID 3003 expected", ev)
            second = await link.next_frame(self.options.reply_timeout)
            if second is not None:
                ev.append(second.evidence())
            if not self.session.answers(sentinel, second):
                return _Verdict(Verdict.FAIL, "the PING after the TOPIC was not answered next", ev)
            return _Verdict(Verdict.PASS, "answered INVALID 3003, as MotoROS does, then the PING", ev)
        if not self.session.answers(sentinel, first):
            return _Verdict(Verdict.FAIL, "the TOPIC was answered; a TOPIC gets no reply (§3)", ev)
        return _Verdict(Verdict.PASS, "ignored; the PING after it answered next", ev)

    async def check_motion_ready(self) -> _Verdict:
        assert self.session.motion is not None
        request = MotoMotionCtrl(0, 0, MotoCommand.CHECK_MOTION_READY)
        sent, reply = await self.session.exchange(self.session.motion, request)
        ev = [sent.evidence()] + ([reply.evidence()] if reply else [])
        msg = reply.message if reply else None
        if not isinstance(msg, MotoMotionReply):
            return _Verdict(Verdict.FAIL, "no MOTO_MOTION_REPLY", ev)
        if msg.command != MotoCommand.CHECK_MOTION_READY:
            return _Verdict(Verdict.FAIL, f"the reply's command is {msg.command}, not 200101 (echoed)", ev)
        if msg.result == MotoResult.TRUE:
            return _Verdict(Verdict.PASS, "TRUE: ready", ev)
        if msg.result in {MotoResult.FALSE, MotoResult.NOT_READY}:
            if not 5000 <= msg.subcode < 6000:
                return _Verdict(Verdict.WARN, f"not ready, but subcode {msg.subcode} is no NOT_READY reason (5xxx)", ev)
            return _Verdict(Verdict.PASS, f"not ready, subcode {msg.subcode}", ev)
        return _Verdict(Verdict.FAIL, f"result {msg.result}: neither TRUE nor FALSE", ev)

    async def malformed(self) -> _Verdict:
        if self.expect.no_malformed is not None:
            raise _Skip(self.expect.no_malformed)
        assert self.session.wire is not None
        o = self.options
        port = o.ports["motion"]
        ev: list[Evidence] = []
        failures: list[str] = []
        still = self.robot.joints()
        if self.session.motion is not None:
            # a server that takes one client at a time (the C++ TcpServer, ABB's and Fanuc's, §6)
            # must be free for the cases' connections; the suite's own link is opened again after
            await self.session.motion.close()
        for case in malformed_cases(self.session.wire):
            witness_before = len(self.session.state.frames) if self.session.state else 0
            # the state port is the witness only while it is sending (its silence is state.rate's)
            witnessing = self.robot.fresh()
            link = ProbeLink("malformed", self.session.wire)
            try:
                await link.open(o.host, port, o.reply_timeout)
            except (OSError, TimeoutError) as exc:
                failures.append(case.name)
                ev.append(Evidence.note(f"{case.name}: the motion port refused a connection: {exc}"))
                break
            link.send(case.data)
            closed = await link.wait_closed(0.3 if case.hold else 0.15)
            answered = [f.evidence() for f in link.frames[:2]]
            await link.close()
            fate = "closed by the server" if closed else "left open"
            if answered:
                fate += f", {len(link.frames)} frame(s) back"
            # another connection stays served: the state port kept sending, and a new motion
            # connection is answered
            witness_ok = not witnessing or await self.robot.witness(witness_before)
            probe = ProbeLink("motion", self.session.wire)
            alive = False
            try:
                await probe.open(o.host, port, o.reply_timeout)
                request = self.session.liveness()
                _, reply = await self.session.exchange(probe, request)
                alive = self.session.answers(request, reply)
            except (OSError, TimeoutError):
                alive = False
            finally:
                await probe.close()
            ok = alive and witness_ok
            ev.append(Evidence.note(f"{case.name} ({case.what}): {fate}" + ("; served after it" if ok else "")))
            ev.extend(answered[:1])
            if not alive:
                failures.append(case.name)
                ev.append(Evidence.note(f"{case.name}: a new motion connection was not answered afterwards"))
                break
            if not witness_ok:
                failures.append(case.name)
                ev.append(Evidence.note(f"{case.name}: the state port sent nothing while it was handled"))
        moved = self.robot.moved_since(still)
        if moved:
            failures.append("motion")
            ev.append(Evidence.note(f"the robot moved while malformed frames were sent: {moved}"))
        elif still is not None and not self.robot.fresh():
            failures.append("state")
            ev.append(Evidence.note("the state port went silent: whether the robot moved cannot be told"))
        if failures:
            return _Verdict(Verdict.FAIL, "not served after: " + ", ".join(failures), ev)
        return _Verdict(
            Verdict.PASS, f"{len(malformed_cases(self.session.wire))} malformed frames survived, served throughout", ev
        )


def _name(msg: Message) -> str:
    if isinstance(msg, RawMessage):
        return f"type {msg.msg_type}"
    return msg.name
