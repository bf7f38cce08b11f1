"""02: read a pcap/pcapng capture: every simple_message frame of every TCP connection, decoded.

By default the capture of a real Yaskawa FS100 (MotoROS, big-endian) shipped with the tests: a
client streams a short move while the controller publishes its state. The TCP streams are put back
together, each direction's byte order is detected, and each frame comes out as a message with its
time and addresses. The script counts the messages per connection direction and type, and how the
controller answered the requests (MotoROS answers a trajectory point BUSY while its slot is full).
Give your own capture (tcpdump's or Wireshark's, or one from ``robot-server --capture``) to read it.

Run: python examples/02_decode_capture.py [CAPTURE.pcapng]
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

from simple_message import CaptureEvent, CommType, MotoMotionReply, MotoResult, ReplyCode, captured_messages

SHIPPED = Path(__file__).resolve().parent.parent / "tests" / "data" / "motoman_fs100_simple_move.pcapng"
path = Path(sys.argv[1]) if len(sys.argv) > 1 else SHIPPED

kinds: Counter[tuple[str, str]] = Counter()
answers: Counter[str] = Counter()
first = last = 0.0
for item in captured_messages(path):
    if isinstance(item, CaptureEvent):  # a gap, a truncated frame: reported, never guessed
        print("event:", item.kind, item.message)
        continue
    first, last = first or item.time, item.time
    message = item.message
    if message is None:  # a frame whose body does not fit its type
        print("malformed:", item.error)
        continue
    kinds[f"{item.src[1]} -> {item.dst[1]}", message.name] += 1
    if message.comm_type == CommType.SERVICE_REPLY:
        outcome = MotoResult(message.result) if isinstance(message, MotoMotionReply) else ReplyCode(message.reply_code)
        answers[f"{message.name} {outcome.name}"] += 1

print(f"{path.name}: {kinds.total()} messages in {last - first:.2f} s")
for (direction, name), count in sorted(kinds.items()):
    print(f"  {direction:>15}  {name:<20} {count:4d}")
print("replies:", ", ".join(f"{what} x{count}" for what, count in answers.most_common()))
