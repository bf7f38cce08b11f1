"""01: messages to bytes and back, with no sockets (the sans-I/O core).

A trajectory point is encoded as a frame; the frame arrives cut into pieces and glued to a PING,
as TCP may deliver it; the frame decoder cuts whole frames out of the byte stream, and each one
decodes to the message it was and re-encodes byte for byte.

Run: python examples/01_frames.py
"""

from __future__ import annotations

import json

from simple_message import LE32, FrameDecoder, JointTrajPt, Ping, decode, message_to_json

point = JointTrajPt(0, (0.1, 0.2, 0.3, 0.4, 0.5, 0.6), velocity=0.5, duration=1.0)
frame = point.encode(LE32)  # length prefix, header, body: little-endian, float32 reals
print(f"JOINT_TRAJ_PT frame: {len(frame)} bytes, starts {frame[:16].hex(' ', 4)}")

# what a socket might hand over: the point in two pieces, the second with a PING behind it
stream = frame + Ping().encode(LE32)
chunks = [stream[:7], stream[7:50], stream[50:]]

decoder = FrameDecoder()  # little-endian; FrameDecoder(None) would detect the byte order
frames = []
for chunk in chunks:
    decoder.feed(chunk)
    while (whole := decoder.next_frame()) is not None:
        frames.append(whole)
print(f"{len(chunks)} chunks of {[len(c) for c in chunks]} bytes -> {len(frames)} frames")

for whole in frames:
    message = decode(whole, LE32)
    print(message.name, json.dumps(message_to_json(message)["body"]))
    assert message.encode(LE32) == whole  # exact: the same bytes again

again = decode(frames[0], LE32)
assert isinstance(again, JointTrajPt) and frames[0] == frame
print(f"each frame re-encodes byte for byte; reals are float32: 0.1 comes back as {again.joint_data[0]!r}")
