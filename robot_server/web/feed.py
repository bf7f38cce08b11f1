"""What the web view's pages are sent: the model once, then samples of the controller, decimated.

A :class:`Feed` watches one :class:`~robot_server.emulator.Emulator`. :meth:`Feed.sample` (called
``rate`` times a second of wall time by the web server while a page is open, whatever the number of
pages; never while none is) reads each
motion group's latest servo tick, the STATUS the state port reports, the policy, the queues and the
connected clients, and keeps the samples of the last ``window`` seconds; every page is then sent at
most one update per sample, made for it from shared pieces (each piece encoded to JSON once, not
once per page). Points the controllers accept (:attr:`~.emulator.cell.RobotCell.point_listeners`)
and frames on the wire (:class:`~.traffic.TrafficTap`) are numbered, and each page has its own
cursor into them (:class:`Page`): a page that falls behind misses samples (its plots have a gap)
but gets every waypoint and frame still kept, and counts the frames it could not be sent. The
points are heard only between :meth:`Feed.attach` and :meth:`Feed.detach` (while pages are open);
:func:`status_of` is the STATUS part alone, as the fleet's index shows it.

The messages are JSON text; docs/web.md describes them field by field.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from simple_message.constants import RobotMode
from simple_message.messages import Status

from ..emulator.cell import Wakeup
from ..model import JointType, RobotModel
from ..workspace import Box, Supervision
from .traffic import DEFAULT_CAPACITY, TrafficTap, link_peer

if TYPE_CHECKING:
    from ..control import Point
    from ..emulator import Emulator

__all__ = ["Feed", "Page", "PROTOCOL_VERSION", "MAX_RATE", "MAX_FRAMES_PER_UPDATE", "status_of"]

#: the version of the messages (docs/web.md); the page says so when it gets another
PROTOCOL_VERSION = 1
#: updates per second per page, at most
MAX_RATE = 60.0
#: waypoints kept for pages that connect later (the last window's, at most this many)
MAX_WAYPOINTS = 5000
#: frames sent to a page in one update, at most (the newest; the others are counted as skipped)
MAX_FRAMES_PER_UPDATE = 40


def _compact(obj: object) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


def _matrix(m: NDArray[np.float64]) -> list[float]:
    """A 4x4 homogeneous matrix as 16 numbers, row-major."""
    return [float(x) for x in np.asarray(m, dtype=float).reshape(16)]


def _box(box: Box) -> dict[str, Any]:
    return {"name": box.name, "lower": list(box.lower), "upper": list(box.upper)}


def describe_model(model: RobotModel, supervision: Supervision) -> dict[str, Any]:
    """A motion group as the page draws it: the chain (base, each joint's fixed transforms before
    and after its motion, its axis, offset and limits, the tool) and the workspace zones."""
    joints = [
        {
            "name": joint.name,
            "type": "prismatic" if joint.type is JointType.PRISMATIC else "revolute",
            "lower": joint.position[0],
            "upper": joint.position[1],
            "offset": joint.offset,
            "pre": _matrix(joint.pre),
            "axis": [float(x) for x in joint.axis],
            "post": _matrix(joint.post),
        }
        for joint in model.joints
    ]
    zones = {
        "allowed": None if supervision.allowed is None else _box(supervision.allowed),
        "forbidden": [_box(b) for b in supervision.forbidden],
        "floor": supervision.floor,
    }
    return {
        "name": model.name,
        "joints": joints,
        "base": _matrix(model.base),
        "tool": _matrix(model.tool),
        "zones": zones,
    }


def status_of(emulator: Emulator) -> dict[str, Any]:
    """The STATUS the emulator's state port reports (its profile's, e.g. MotoROS's motion possible
    only in trajectory mode), as the page's lights show it."""
    emulator.cell.sync()
    reported = getattr(emulator.behaviour, "status", None)
    status: Status = reported() if callable(reported) else emulator.cell.status()
    return {
        "drives_powered": bool(status.drives_powered == 1),
        "e_stopped": bool(status.e_stopped == 1),
        "in_error": bool(status.in_error == 1),
        "error_code": int(status.error_code),
        "in_motion": bool(status.in_motion == 1),
        "motion_possible": bool(status.motion_possible == 1),
        "mode": _mode(status.mode),
    }


def _finite(values: list[float]) -> list[float | None]:
    """JSON has no NaN or infinity: such a value is sent as null (a gap in the plot)."""
    return [v if math.isfinite(v) else None for v in values]


@dataclass
class Page:
    """One connected page's cursors: the next waypoint and frame numbers it has not been sent."""

    waypoint: int = 1
    frame: int = 1
    #: frames that were no longer kept when this page could be sent them
    skipped: int = 0
    #: the number of the last sample sent (0: none)
    sample: int = 0


class Feed:
    """Samples an emulator for the web view's pages (see the module doc). Make it before the
    emulator starts: its traffic tap goes on the servers then. The accepted points are heard from
    :meth:`attach` to :meth:`detach`."""

    def __init__(
        self, emulator: Emulator, *, rate: float = 30.0, window: float = 10.0, frames: int = DEFAULT_CAPACITY
    ) -> None:
        if not 0.0 < rate <= MAX_RATE:
            raise ValueError(f"the web view's update rate must be in (0, {MAX_RATE:g}] per second, not {rate}")
        if not window > 0.0:
            raise ValueError(f"the plotted window must be > 0 s, not {window}")
        self.emulator = emulator
        self.rate = rate
        self.window = window
        config = emulator.config
        self.traffic = TrafficTap(real_size=config.wire.real_size, capacity=frames)
        emulator.taps.append(self.traffic)
        self._listening = False
        self._groups = [describe_model(g.model, g.supervision) for g in emulator.cell.groups]
        #: (controller time, sample JSON), oldest first: the last window's
        self._samples: deque[tuple[float, str]] = deque(maxlen=math.ceil(window * rate) + 1)
        self.samples = 0  # samples taken (the number of the newest)
        self._waypoints: deque[tuple[int, float, str]] = deque(maxlen=MAX_WAYPOINTS)
        self.waypoints = 0  # points accepted so far (the number of the newest)
        self._state = "{}"  # the JSON pieces of the newest sample that are not numbered
        self._sampled = Wakeup()

    def attach(self) -> None:
        """Hear of accepted points from now on (a page opened). The samples and waypoints kept from
        an earlier time are dropped: nothing was heard in between, and the plots would join them."""
        if self._listening:
            return
        self._listening = True
        self._samples.clear()
        self._waypoints.clear()
        self.emulator.cell.point_listeners.append(self._accepted)

    def detach(self) -> None:
        """Stop hearing of accepted points (no page is open; the traffic tap stays on the servers
        until they close)."""
        self._listening = False
        with contextlib.suppress(ValueError):
            self.emulator.cell.point_listeners.remove(self._accepted)

    # -- taking samples --------------------------------------------------------------------------

    def _accepted(self, group: int, point: Point) -> None:
        if point.positions is None:
            return
        t = self.emulator.cell.groups[group].time
        self.waypoints += 1
        positions = _finite([float(x) for x in point.positions])
        self._waypoints.append((self.waypoints, t, _compact({"g": group, "t": t, "p": positions})))

    def sample(self) -> None:
        """Take one sample now and wake the pages waiting in :meth:`next_sample`."""
        emulator = self.emulator
        cell = emulator.cell
        cell.sync()
        groups = []
        t = cell.groups[0].command.time
        for controller in cell.groups:
            tick = controller.command
            groups.append(
                {
                    "cp": _finite(tick.command_position),
                    "cv": _finite(tick.command_velocity),
                    "ca": _finite(tick.command_acceleration),
                    "ap": _finite(tick.actual_position),
                    "av": _finite(tick.actual_velocity),
                    "aa": _finite(tick.actual_acceleration),
                    "fe": _finite(tick.following_error),
                }
            )
        self.samples += 1
        self._samples.append((t, _compact({"t": t, "groups": groups})))
        horizon = t - self.window
        while self._waypoints and self._waypoints[0][1] < horizon:
            self._waypoints.popleft()
        state = {
            "status": status_of(emulator),
            "policy": emulator.config.interpolation,
            "queue": [{"fill": c.queue_fill, "capacity": c.queue_capacity} for c in cell.groups],
            "clients": self.clients(),
        }
        self._state = _compact(state)[1:-1]  # the members, spliced into each update
        self._sampled.wake()

    async def next_sample(self) -> None:
        """Wait for the next :meth:`sample`."""
        await self._sampled.wait()

    def clients(self) -> list[dict[str, Any]]:
        """Who is connected: port, peer address, the profile played, the byte order and float size
        spoken to each."""
        profile = self.emulator.config.profile
        out = []
        for role, server in self.emulator.servers.items():
            for session in sorted(server.sessions, key=lambda s: s.name):
                wire = session.wire
                out.append(
                    {
                        "port": role,
                        "peer": link_peer(session.connection.tap_link),
                        "profile": profile,
                        "byte_order": wire.byte_order.value,
                        "float64": wire.real_size == 8,
                    }
                )
        return out

    # -- messages --------------------------------------------------------------------------------

    def hello(self, page: Page, *, name: str | None = None, control: dict[str, Any] | None = None) -> str:
        """The first message to a page: the emulator (``name``: its name in a fleet), the model, the
        last window's samples and waypoints, the traffic kept, and ``control`` (whether this page
        may send commands, and why not); moves the page's cursors past what it holds."""
        cfg = self.emulator.config
        emulator = {
            "name": name,
            "profile": cfg.profile,
            "policy": cfg.interpolation,
            "byte_order": cfg.byte_order,
            "float64": bool(cfg.float64),
            "ports": dict(self.emulator.ports),
            "speedup": cfg.speedup,
            "simulated": not self.emulator.clock.realtime,
            "rate": self.rate,
            "window": self.window,
            "ready": self.emulator.describe(),
        }
        frames = self.traffic.since(self.traffic.first)
        page.frame = self.traffic.count + 1
        page.waypoint = self.waypoints + 1
        page.sample = self.samples
        return (
            f'{{"type":"hello","version":{PROTOCOL_VERSION},"emulator":{_compact(emulator)},'
            f'"groups":{_compact(self._groups)},'
            f'"control":{_compact(control or {"commands": True, "why": None})},'
            f'"history":[{",".join(s for _, s in self._samples)}],'
            f'"waypoints":[{",".join(w for _, _, w in self._waypoints)}],'
            f'"traffic":[{",".join(frames)}]}}'
        )

    def update(self, page: Page) -> str | None:
        """The next update for a page (``None``: no sample since its last one)."""
        if self.samples == page.sample or not self._samples:
            return None
        page.sample = self.samples
        kept = self._waypoints
        start = max(0, page.waypoint - kept[0][0]) if kept else 0
        waypoints = [kept[i][2] for i in range(start, len(kept))]
        page.waypoint = self.waypoints + 1
        # at most MAX_FRAMES_PER_UPDATE of the newest frames: a list scrolling faster than that is
        # unreadable, and decoding more would hold up the controller's loop
        first = max(self.traffic.first, self.traffic.count + 1 - MAX_FRAMES_PER_UPDATE)
        if page.frame < first:
            page.skipped += first - page.frame
            page.frame = first
        frames = self.traffic.since(page.frame)
        page.frame = self.traffic.count + 1
        return (
            f'{{"type":"update","sample":{self._samples[-1][1]},"waypoints":[{",".join(waypoints)}],'
            f'{self._state},"traffic":[{",".join(frames)}],"skipped":{page.skipped}}}'
        )


def _mode(value: int) -> str:
    try:
        return RobotMode(value).name
    except ValueError:
        return str(value)
