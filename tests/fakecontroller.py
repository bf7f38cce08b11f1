"""A small scripted controller for testing the driver, built from the shared byte vectors.

It never uses the project's codec: replies and topics are reference frames (the C++ library's
vectors; for MotoROS, MOTO_MOTION_REPLY frames cut from the real FS100 capture) with fields patched
at their documented offsets, and what the driver sends is recorded raw, per connection, for the
tests to check field by field. A ``script(frame, count)`` decides each request's fate:

* ``Reply("success" | "failure")``: answer (generic: the echo of the request, or the library's
  header-only FAILURE), optionally after ``delay`` seconds;
* ``Reply("moto", result=..., subcode=...)``: a MOTO_MOTION_REPLY;
* ``DROP``: close the connection without answering (``then_drop=True``: right after answering);
* ``SILENT``: never answer.

When a trajectory point is acknowledged the fake robot jumps to it; it reports in_motion FALSE
when it stands on the last point it acknowledged (the tests send trajectories whose last point is
the goal).
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from tests.rawpeer import HEADER, PREFIX, Frame, vectors
from tests.refdata import load_segments

JOINT_TRAJ_PT, JOINT_TRAJ_PT_FULL, MOTO_MOTION_CTRL, MOTO_MOTION_REPLY = 11, 14, 2001, 2002
PING = 1
REQUEST, REPLY = 2, 3
SUCCESS, FAILURE = 1, 2


@dataclass(frozen=True)
class Reply:
    kind: str  # "success", "failure" or "moto"
    delay: float = 0.0
    result: int = 0
    subcode: int = 0
    #: close the connection right after this reply
    then_drop: bool = False


DROP = Reply("drop")
SILENT = Reply("silent")

Script = Callable[[Frame, int], Reply]


def _moto_reply_template() -> bytes:
    """A MOTO_MOTION_REPLY frame of the FS100 capture (big-endian)."""
    for _, src, _, payload in load_segments():
        frame = Frame(payload, ">")
        if src == 50240 and frame.msg_type == MOTO_MOTION_REPLY:
            return payload[: PREFIX + frame.length]
    raise AssertionError("the capture has no MOTO_MOTION_REPLY")


@dataclass
class FakeController:
    script: Script
    order: str = "<"
    joints: list[float] = field(default_factory=lambda: [0.0] * 6)
    #: frames received, one list per motion connection
    connections: list[list[Frame]] = field(default_factory=list)
    #: requests that arrived while an earlier one was still unanswered (must stay 0: one in flight)
    overlapping: int = 0
    state_period: float = 0.01
    #: STATUS written this long after JOINT_POSITION (a write of its own), not with it
    status_after: float | None = None
    #: state rounds published (over all state connections)
    rounds: int = 0

    def __post_init__(self) -> None:
        v = vectors(self.order)
        self._position = v["JOINT_POSITION_TOPIC"]
        self._status = v["STATUS_TOPIC"]
        self._failure = v["JOINT_TRAJ_PT_REPLY_FAILURE"]
        self._moto = _moto_reply_template() if self.order == ">" else b""
        self._goal: list[float] | None = None
        self._servers: list[asyncio.AbstractServer] = []
        self._tasks: set[asyncio.Task[None]] = set()
        self._writers: list[asyncio.StreamWriter] = []
        self.ports: dict[str, int] = {}
        self._count = 0

    # -- lifecycle ---------------------------------------------------------------------------------

    async def __aenter__(self) -> FakeController:
        motion = await asyncio.start_server(self._motion, "127.0.0.1", 0)
        state = await asyncio.start_server(self._state, "127.0.0.1", 0)
        self._servers = [motion, state]
        self.ports = {"motion": motion.sockets[0].getsockname()[1], "state": state.sockets[0].getsockname()[1]}
        return self

    async def __aexit__(self, *exc: object) -> None:
        for server in self._servers:
            server.close()
        for writer in self._writers:
            writer.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        for server in self._servers:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(server.wait_closed(), 2.0)

    def frames(self, msg_type: int | None = None, connection: int | None = None) -> list[Frame]:
        conns = self.connections if connection is None else [self.connections[connection]]
        return [f for c in conns for f in c if msg_type is None or f.msg_type == msg_type]

    # -- state port: JOINT_POSITION and STATUS, patched into the reference frames -----------------

    def _topics(self) -> tuple[bytes, bytes]:
        o = self.order
        position = bytearray(self._position)
        struct.pack_into(f"{o}i10f", position, HEADER, 0, *self.joints, *[0.0] * (10 - len(self.joints)))
        status = bytearray(self._status)
        moving = 0 if self._goal is None or self._goal == self.joints else 1
        # drives_powered, e_stopped, error_code, in_error, in_motion, mode (auto), motion_possible
        struct.pack_into(f"{o}7i", status, HEADER, 1, 0, 0, 0, moving, 2, 1)
        return bytes(position), bytes(status)

    async def _state(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.append(writer)
        try:
            while True:  # a periodic publisher, like a controller's state server
                position, status = self._topics()
                if self.status_after is None:
                    writer.write(position + status)
                else:
                    writer.write(position)
                    await writer.drain()
                    await asyncio.sleep(self.status_after)  # the controller's pace, not a wait for us
                    writer.write(status)
                self.rounds += 1
                await writer.drain()
                await asyncio.sleep(self.state_period)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self._tasks.discard(task)
            writer.close()

    # -- motion port -------------------------------------------------------------------------------

    async def _motion(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.append(writer)
        frames: list[Frame] = []
        self.connections.append(frames)
        o = self.order
        try:
            while True:
                prefix = await reader.readexactly(PREFIX)
                (length,) = struct.unpack(o + "i", prefix)
                frame = Frame(prefix + await reader.readexactly(length), o)
                frames.append(frame)
                self._count += 1
                if frame.comm_type != REQUEST:
                    if frame.msg_type == JOINT_TRAJ_PT and frame.ints(1)[0] != -4:
                        self._accept(list(frame.reals(6, 4)))  # a downloaded point
                    continue
                action = self.script(frame, self._count - 1)
                if action is DROP:
                    return
                if action is SILENT:
                    continue
                if action.delay:  # the fake's own latency; anything arriving meanwhile overlaps
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(reader.readexactly(PREFIX), action.delay)
                        self.overlapping += 1
                        return
                writer.write(self._answer(frame, action))
                await writer.drain()
                if action.then_drop:
                    return
        except (asyncio.IncompleteReadError, ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self._tasks.discard(task)
            writer.close()

    def _answer(self, frame: Frame, action: Reply) -> bytes:
        o = self.order
        if action.kind == "moto":
            reply = bytearray(self._moto)
            group, sequence = frame.ints(2) if frame.msg_type in (JOINT_TRAJ_PT_FULL, MOTO_MOTION_CTRL) else (0, 0)
            command = frame.ints(3)[2] if frame.msg_type == MOTO_MOTION_CTRL else frame.msg_type
            struct.pack_into(f"{o}5i", reply, HEADER, group, sequence, command, action.result, action.subcode)
            if frame.msg_type == JOINT_TRAJ_PT_FULL and action.result == 0:
                self._accept(list(frame.reals(6, 16)))
            return bytes(reply)
        if action.kind == "failure":
            failure = bytearray(self._failure)
            struct.pack_into(o + "i", failure, 4, frame.msg_type)
            return bytes(failure)
        echo = bytearray(frame.raw)  # the C++ library's SUCCESS reply echoes the request's body
        struct.pack_into(o + "ii", echo, 8, REPLY, SUCCESS)
        if frame.msg_type == JOINT_TRAJ_PT and frame.ints(1)[0] != -4:
            self._accept(list(frame.reals(6, 4)))
        return bytes(echo)

    def _accept(self, joints: list[float]) -> None:
        self.joints = joints
        self._goal = joints
