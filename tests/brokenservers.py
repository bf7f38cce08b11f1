"""A small generic simple_message controller with deliberate defects, for the conformance suite's
negative tests.

Written with raw asyncio streams and :mod:`struct` (not the project's endpoints or codec), so that
each defect is one ``if`` and no rule of the project's own server can mask it. Without defects it
passes the server suite, motion included: it answers PING, unknown types with FAILURE, trajectory
points (refusing any joint beyond ±3 rad), STOP at once, and publishes JOINT_POSITION and STATUS at
``rate`` Hz while moving its joints linearly to each accepted point.

Defects (``defects``):

* ``wrong-order-reply``: the second PING reply is in the other byte order;
* ``missing-reply``: requests of an unknown type are not answered;
* ``out-of-order``: the reply to an unknown type is sent after the next request's reply;
* ``header-only-status``: STATUS is sent header-only;
* ``slow-state``: the state topics at 0.4 Hz;
* ``moves-beyond-limits``: a point beyond the limits is accepted and run;
* ``state-dies``: the state port closes its connections half a second after they open.

Not defects, but what some real servers do: ``single_client`` (serve one motion connection at a
time, as the C++ TcpServer, ABB's and Fanuc's servers do, §6), ``status_first`` (STATUS before the
joint state in each round), ``real`` ``"d"`` (float64 reals).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
from collections.abc import Coroutine
from typing import Any

PING, JOINT_POSITION, JOINT_TRAJ_PT, STATUS = 1, 10, 11, 13
TOPIC, REQUEST, REPLY = 1, 2, 3
SUCCESS, FAILURE = 1, 2
LIMIT = 3.0
DEFECTS = frozenset(
    {
        "wrong-order-reply",
        "missing-reply",
        "out-of-order",
        "header-only-status",
        "slow-state",
        "moves-beyond-limits",
        "state-dies",
    }
)


class BrokenServer:
    def __init__(
        self,
        defects: frozenset[str] = frozenset(),
        order: str = "<",
        rate: float = 40.0,
        *,
        single_client: bool = False,
        status_first: bool = False,
        real: str = "f",
    ) -> None:
        unknown = defects - DEFECTS
        assert not unknown, unknown
        self.defects = defects
        self.order = order
        self.real = real
        self.status_first = status_first
        self._one_client = asyncio.Lock() if single_client else None
        self.rate = 0.4 if "slow-state" in defects else rate
        self.joints = [0.0] * 10
        self.target: list[float] | None = None
        self.speed = 0.0  # rad/s of the joint that moves most
        self.pings = 0
        self.ports: dict[str, int] = {}
        self._servers: list[asyncio.Server] = []
        self._tasks: set[asyncio.Task[None]] = set()
        self._writers: set[asyncio.StreamWriter] = set()
        self._state: set[asyncio.StreamWriter] = set()

    async def __aenter__(self) -> BrokenServer:
        for role, handler in (("motion", self._motion), ("state", self._state_client)):
            server = await asyncio.start_server(handler, "127.0.0.1", 0)
            self._servers.append(server)
            self.ports[role] = server.sockets[0].getsockname()[1]
        self._spawn(self._tick())
        return self

    async def __aexit__(self, *exc: object) -> None:
        for server in self._servers:
            server.close()
        for writer in list(self._writers):
            writer.close()
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for server in self._servers:
            await server.wait_closed()

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # -- frames ---------------------------------------------------------------------------------

    def frame(self, msg_type: int, comm: int, reply: int, body: bytes = b"", order: str | None = None) -> bytes:
        o = order or self.order
        return struct.pack(f"{o}4i", 12 + len(body), msg_type, comm, reply) + body

    # -- state ----------------------------------------------------------------------------------

    async def _state_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        self._state.add(writer)
        self._publish(writer)
        with contextlib.suppress(Exception):
            if "state-dies" in self.defects:
                await asyncio.wait_for(reader.read(), 0.5)
            else:
                await reader.read()  # until the client goes
        self._state.discard(writer)
        self._writers.discard(writer)
        writer.close()

    def _publish(self, writer: asyncio.StreamWriter) -> None:
        o = self.order
        moving = 1 if self.target is not None else 0
        joint = self.frame(JOINT_POSITION, TOPIC, 0, struct.pack(f"{o}i10{self.real}", 0, *self.joints))
        if "header-only-status" in self.defects:
            status = self.frame(STATUS, TOPIC, 0)
        else:
            status = self.frame(STATUS, TOPIC, 0, struct.pack(f"{o}7i", 1, 0, 0, 0, moving, 2, 1 - moving))
        writer.write(status + joint if self.status_first else joint + status)

    async def _tick(self) -> None:
        period = 1.0 / self.rate
        loop = asyncio.get_running_loop()
        last = loop.time()
        while True:
            await asyncio.sleep(period)
            now = loop.time()
            self._move(now - last)
            last = now
            for writer in list(self._state):
                self._publish(writer)

    def _move(self, dt: float) -> None:
        if self.target is None:
            return
        step = self.speed * dt
        done = True
        for k, (j, t) in enumerate(zip(self.joints, self.target, strict=True)):
            if abs(t - j) > step:
                self.joints[k] = j + math.copysign(step, t - j)
                done = False
            else:
                self.joints[k] = t
        if done:
            self.target = None

    # -- motion ---------------------------------------------------------------------------------

    async def _motion(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._one_client is None:
            await self._serve_motion(reader, writer)
            return
        async with self._one_client:  # the next connection waits, unanswered, until this one closes
            await self._serve_motion(reader, writer)

    async def _serve_motion(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        held: bytes | None = None
        o = self.order
        try:
            while True:
                (length,) = struct.unpack(f"{o}i", await reader.readexactly(4))
                if not 12 <= length <= 4096:
                    return  # a length that frames nothing: close this connection only
                data = await reader.readexactly(length)
                msg_type, comm, code = struct.unpack_from(f"{o}3i", data)
                body = data[12:]
                if comm != REQUEST or code != 0:
                    continue
                reply = self._answer(msg_type, body)
                if reply is None:
                    continue
                if msg_type not in (PING, JOINT_TRAJ_PT) and "out-of-order" in self.defects:
                    held = reply
                    continue
                writer.write(reply)
                if held is not None:
                    writer.write(held)
                    held = None
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            self._writers.discard(writer)
            writer.close()

    def _answer(self, msg_type: int, body: bytes) -> bytes | None:
        o = self.order
        if msg_type == PING:
            self.pings += 1
            order = (">" if o == "<" else "<") if self.pings == 2 and "wrong-order-reply" in self.defects else o
            return self.frame(PING, REPLY, SUCCESS, order=order)
        if msg_type != JOINT_TRAJ_PT:
            return None if "missing-reply" in self.defects else self.frame(msg_type, REPLY, FAILURE)
        size = 4 + 12 * struct.calcsize(self.real)
        if len(body) != size:
            return self.frame(msg_type, REPLY, FAILURE)
        sequence, *rest = struct.unpack(f"{o}i12{self.real}", body)
        joints, duration = list(rest[:10]), rest[11]
        if sequence == -4:
            self.target = None
            return self.frame(msg_type, REPLY, SUCCESS, body)
        beyond = any(abs(j) > LIMIT for j in joints)
        if beyond and "moves-beyond-limits" not in self.defects:
            return self.frame(msg_type, REPLY, FAILURE, body)
        distance = max(abs(a - b) for a, b in zip(joints, self.joints, strict=True))
        if distance > 0:
            self.speed = distance / duration if duration > 0 else 1.0
            self.target = joints
        return self.frame(msg_type, REPLY, SUCCESS, body)
