"""04: stream a joint trajectory to an emulated controller started in this process.

The emulator serves the generic profile on free ports of 127.0.0.1 and runs in real time. The
client's ``RobotDriver`` connects to its motion and state ports and streams a time-stamped
trajectory (a one-second swing of joints 1 and 2, sampled every 50 ms) as JOINT_TRAJ_PT
requests, one in flight, every reply checked; ``execute`` returns when the robot is at the last
point and STATUS says it stopped moving. Then both sides say where the robot ended.

Run: python examples/04_stream_trajectory.py
"""

from __future__ import annotations

import asyncio
import time

import numpy as np

from client.driver import RobotDriver
from client.trajectory import Trajectory
from robot_server import Emulator, EmulatorConfig, load_model


async def main() -> None:
    model = load_model("jibot_zxs")  # the emulator's default robot: 6 joints, starts at q = 0
    goal = np.array([0.2, -0.15, 0.0, 0.0, 0.0, 0.0])
    times = np.linspace(0.0, 1.0, 21)
    shape = (1 - np.cos(np.pi * times)) / 2  # 0 to 1, at rest at both ends
    trajectory = Trajectory(times, np.outer(shape, goal))

    async with Emulator(EmulatorConfig(motion_port=0, state_port=0)) as emu:  # free ports
        motion, state = emu.ports["motion"], emu.ports["state"]
        print(f"emulator on 127.0.0.1: motion port {motion}, state port {state}")
        async with RobotDriver("127.0.0.1", motion, state, model=model) as robot:
            began = time.monotonic()
            final = await robot.execute(trajectory)  # mode="stream", the generic controller's usual way
            took = time.monotonic() - began
            print(f"{len(trajectory)} points streamed, the robot at rest after {took:.2f} s")
            print("the driver reads the robot at", np.round(final.positions, 4).tolist())
        controller = emu.cell.groups[0].command.command_position
        print("the controller's commanded position", np.round(controller, 4).tolist())
        error = float(np.max(np.abs(final.positions - goal)))
        print(f"within {error:.1e} rad of the goal: {error < 1e-3}")


asyncio.run(main())
