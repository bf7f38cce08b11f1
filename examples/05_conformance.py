"""05: run the conformance suite's server rules against an emulator started in this process.

The suite judges a simple_message server by what the real peers (the ROS-Industrial C++ library,
MotoROS, ABB's and Fanuc's servers) expect of it: framing, byte order, one reply per request in
order, unknown and malformed frames, the state topics, and, with ``allow_motion``, a small move,
STOP and a point beyond the limits. Each rule gets PASS, FAIL, WARN or SKIP with its evidence. The
same suite runs against a real controller with ``simple-message conformance server HOST``
(docs/conformance.md says how to do that safely). Exit status 0 when no rule FAILed.

Run: python examples/05_conformance.py
"""

from __future__ import annotations

import asyncio
import logging

from robot_server import Emulator, EmulatorConfig
from simple_message.conformance import Verdict
from simple_message.conformance.server import ServerSuiteOptions, run_server_suite


async def main() -> int:
    logging.basicConfig(level=logging.ERROR)  # the emulator logs each malformed frame it refuses: keep the table alone
    async with Emulator(EmulatorConfig(motion_port=0, state_port=0)) as emu:  # free ports on 127.0.0.1
        options = ServerSuiteOptions(
            "127.0.0.1",
            profile="generic",
            motion_port=emu.ports["motion"],
            state_port=emu.ports["state"],
            allow_motion=True,  # the emulated robot may move: 0.01 rad of joint 1, and back
            observe=1.0,  # watch the state topics 1 s (3 s by default)
            move_time=0.5,
        )
        report = await run_server_suite(options)
    print(report.table())
    counts = report.counts()
    print(f"{counts[Verdict.FAIL]} rules FAILed" if counts[Verdict.FAIL] else "no rule FAILed")
    return report.exit_code


raise SystemExit(asyncio.run(main()))
