"""07: record a program's own simple_message traffic as a pcapng file, then read it back.

A ``CaptureWriter`` is a tap: given to a server (or a client, or ``RobotDriver(tap=...)``) it writes
every chunk of bytes sent or received as TCP packets of a capture that Wireshark opens as it is
(what ``robot-server --capture`` and ``robot-client --capture`` do). Here a small server answers a
client's PINGs and a trajectory point on 127.0.0.1 while the tap records; the file is then decoded
like any tcpdump capture (example 02).

Run: python examples/07_record_capture.py [OUT.pcapng]   (default: own_traffic.pcapng here)
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from simple_message import (
    LE32,
    CapturedMessage,
    CaptureWriter,
    Client,
    CommType,
    JointTrajPt,
    MsgType,
    Ping,
    Server,
    captured_messages,
)


async def talk(capture: CaptureWriter) -> None:
    server = Server(LE32, tap=capture)  # every connection it accepts from now on is recorded
    server.handle(MsgType.JOINT_TRAJ_PT, lambda point, session: None)  # None: SUCCESS, the point echoed
    port = await server.serve_tcp(port=0)
    try:
        async with Client.tcp("127.0.0.1", port, LE32) as client:
            for _ in range(3):
                await client.request(Ping(), timeout=2.0)
            await client.request(JointTrajPt(0, (0.1, 0.2, 0.3)), timeout=2.0)
    finally:
        await server.close()


path = Path(sys.argv[1] if len(sys.argv) > 1 else "own_traffic.pcapng")
with CaptureWriter(path, application="examples/07_record_capture.py") as capture:
    asyncio.run(talk(capture))
print(f"wrote {path}: {capture.packets} packets (handshake, data, close)")

for item in captured_messages(path):
    assert isinstance(item, CapturedMessage) and item.message is not None
    src, dst = (f"{host}:{port}" for host, port in (item.src, item.dst))
    kind = CommType(item.message.comm_type).name
    print(f"  {src:>15} -> {dst:<15} {item.message.name:<13} {kind:<15} {len(item.frame)} bytes")
