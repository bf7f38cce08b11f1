"""Draws ``how_it_moves.png`` for the README: one joint of a MoveIt-like plan streamed as
industrial_robot_client streams it (9 points over 4 s), executed by the emulator's controller under
``blend`` and under the paper's rest-to-rest ``quintic``, against the plan itself.

    pip install -e '.[plot]' && python docs/figures/how_it_moves.py

The controllers run in process on their own clock (deterministic): the figure is the same every time.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from robot_server.control import Controller, ControllerConfig  # noqa: E402
from robot_server.loader import load_model  # noqa: E402
from tests.streams import Plan, ros_points, shape, stream  # noqa: E402

JOINT = 1  # joint 2: it turns back before the end


def main() -> None:
    model = load_model("jibot_zxs")
    plan = Plan.make(4.0, 9)
    t = np.linspace(0.0, plan.duration, 2001)
    q, v, _ = shape(plan.duration, t)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    top.plot(t, q[:, JOINT], color="0.6", lw=4, label="planned (the client's trajectory)")
    bottom.plot(t, v[:, JOINT], color="0.6", lw=4)
    for policy, colour in (("blend", "tab:blue"), ("quintic", "tab:red")):
        controller = Controller(model, ControllerConfig(policy=policy))
        record = stream(controller, ros_points(plan, model.max_velocity), 0.0)
        command = record.get("command_position")[:, JOINT]
        moving = np.flatnonzero(np.abs(np.diff(command)) > 1e-12)
        times = record.time() - record.time()[moving[0]]
        keep = times >= -0.05
        top.plot(times[keep], command[keep], color=colour, label=f"{policy}: the command")
        bottom.plot(times[keep], record.get("command_velocity")[keep, JOINT], color=colour)
    top.plot(plan.time, plan.position[:, JOINT], "ko", ms=5, label="points received")
    top.set_ylabel("joint 2 position (rad)")
    bottom.set_ylabel("joint 2 velocity (rad/s)")
    bottom.set_xlabel("time from the first motion (s)")
    top.legend(loc="upper left", fontsize=9)
    top.set_title("9 points over 4 s: blend passes through them, the rest-to-rest quintic stops at each")
    for axis in (top, bottom):
        axis.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(__file__).with_suffix(".png")
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()
