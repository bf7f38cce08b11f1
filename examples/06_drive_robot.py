"""06: drive a robot from a script: ping, status, a planned move, a move stopped halfway.

What ``robot-client ping``, ``status``, ``move`` and Ctrl-C do, from Python. The planner times a
joint move within a share of the robot's limits; the driver runs it and returns at the goal. The
second move is cancelled once joint 1 has gone halfway: cancelling ``execute`` sends STOP, the
controller brakes to rest, and ``settle_after_stop`` waits for that and says where the robot is.
The controller is an emulator started in this process on free ports of 127.0.0.1; against a real
one, pass its address and ports to ``RobotDriver`` instead (and mind the robot's surroundings).

Run: python examples/06_drive_robot.py
"""

from __future__ import annotations

import asyncio
import contextlib

import numpy as np

from client.driver import RobotDriver
from client.planner import Planner
from robot_server import Emulator, EmulatorConfig, load_model
from simple_message import RobotMode, TriState


async def main() -> None:
    model = load_model("jibot_zxs")
    planner = Planner(model, velocity_scale=0.5, acceleration_scale=0.5)
    async with (
        Emulator(EmulatorConfig(motion_port=0, state_port=0)) as emu,
        RobotDriver("127.0.0.1", emu.ports["motion"], emu.ports["state"], model=model) as robot,
    ):
        print(f"PING answered in {await robot.ping() * 1e3:.1f} ms")
        here = (await robot.wait_state()).positions
        status = robot.status  # the latest STATUS, with the joint state
        assert status is not None
        mode, possible = RobotMode(status.mode).name, TriState(status.motion_possible).name
        print("at", np.round(here, 3).tolist(), f"in {mode}, motion possible: {possible}")

        ready = np.array([0.3, 0.2, -0.2, 0.0, 0.5, 0.0])
        move = planner.joint_move(here, ready)
        state = await robot.execute(move.sparse(rest_to_rest=True))
        print(f"moved to {np.round(state.positions, 3).tolist()} in {move.duration:.2f} s (planned)")

        back = planner.joint_move(ready, np.zeros(6))
        running = asyncio.create_task(robot.execute(back.sparse(rest_to_rest=True)))
        async for sample in robot.states():  # every joint-state sample as it arrives
            if sample.positions[0] < 0.15 or running.done():  # joint 1 halfway home (or the move failed)
                break
        running.cancel()  # STOP goes out; the task ends once the controller has answered it
        with contextlib.suppress(asyncio.CancelledError):
            await running
        rest = await robot.settle_after_stop()
        assert rest is not None
        print("stopped halfway: at rest at", np.round(rest.positions, 3).tolist())


asyncio.run(main())
