"""A pick-and-place cell, simulated: fw's second procedure, which is not surgery.

A feeder puts parts at a pick spot; a gantry (a Cartesian robot) carries them to a bin
with a gripper; a light curtain guards the cell's opening. In automatic mode the gantry
follows the planner; in hands-on mode it follows a handle the operator pushes (the
thesis' future-work "hands-on" mode), and the chart allows that switch only while the
gripper holds nothing. The gantry brakes in its own control loop when the curtain is
broken, when its setpoints stop, and when the safety monitor trips (a lost or hung
process); only the operator's RELEASE, through the chart, clears that stop.

These components use only fw's public API (framework.component, messages, ports,
properties, errors): they live with the procedure, as an integrator's would, and the
topology finds them through `import_paths:`.
"""

from __future__ import annotations

import math
import time
from typing import Any

from framework.component import Component, ConfigureError, In, Out, operation
from framework.errors import FwError
from framework.messages import EventMessage, Pose, Scalar
from framework.ports import ReadStatus
from framework.properties import prop

POSES: dict[str, tuple[float, float, float]] = {
    "home": (0.0, 0.0, 0.30),
    "pick": (0.40, 0.0, 0.05),
    "bin": (0.0, 0.40, 0.10),
}
"""Where the planner can send the gantry (m, in the cell's frame)."""
REACHED = 0.001
"""The gantry is at a goal when it is this close (m)."""


def _pose(position: tuple[float, ...] | list[float]) -> Pose:
    x, y, z = (float(v) for v in position)
    return Pose(position=(x, y, z), stamp=time.time(), valid=True, frame="cell")


class _Emitter(Component):
    """A component that raises chart events on its `events` port (fw/events)."""

    events = Out(EventMessage, doc="events for the Coordinator (fw/events)")

    def emit(self, name: str, **payload: Any) -> None:
        self.events.write(EventMessage(time.time(), name, self.name, payload))


class Feeder(_Emitter):
    """A conveyor: asked for a part (`request`), it brings one to the pick spot
    `interval` s after the last was taken and says so (e_PART); a part already there is
    announced at once. Asking, not announcing unasked, means no part goes unnoticed
    while the gantry is busy."""

    emits = ("e_PART",)
    interval = prop(float, 0.5, min=0.0, max=60.0, unit="s", doc="between parts")

    def __init__(self, name: str):
        super().__init__(name)
        self.delivered = 0
        self.waiting = False
        self.asked = False
        self.taken_at = -math.inf

    def update_hook(self) -> None:
        if not self.asked:
            return
        if not self.waiting and time.monotonic() - self.taken_at >= self.interval:
            self.waiting = True
            self.delivered += 1
        if self.waiting:
            self.asked = False
            self.emit("e_PART", part=self.delivered)

    @operation
    def request(self) -> dict[str, Any]:
        """The cell is ready for the next part."""
        self.asked = True
        return self.report()

    @operation
    def take(self) -> dict[str, Any]:
        """The gripper took the part at the pick spot."""
        if not self.waiting:
            raise FwError("no part at the pick spot")
        self.waiting, self.taken_at = False, time.monotonic()
        return self.report()

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Parts delivered so far and whether one waits at the pick spot."""
        return {"delivered": self.delivered, "waiting": self.waiting}


class Gripper(_Emitter):
    """Closes on a part (e_GRIPPED, or e_MISSED every `miss_every`-th time) and opens
    (e_DROPPED), each after `stroke` s."""

    emits = ("e_GRIPPED", "e_MISSED", "e_DROPPED")
    stroke = prop(float, 0.2, min=0.0, max=5.0, unit="s", doc="time to close or open")
    miss_every = prop(int, 0, min=0, max=1000, doc="miss every n-th grip (0: never)")

    def __init__(self, name: str):
        super().__init__(name)
        self.holding = False
        self.grips = 0
        self.placed = 0
        self.moving: tuple[str, float] | None = None  # ('close' | 'open', since)

    @operation
    def close(self) -> dict[str, Any]:
        """Close on whatever is between the fingers."""
        self.moving = ("close", time.monotonic())
        return self.report()

    @operation
    def open(self) -> dict[str, Any]:
        """Open (drop what it holds)."""
        self.moving = ("open", time.monotonic())
        return self.report()

    def update_hook(self) -> None:
        if self.moving is None or time.monotonic() - self.moving[1] < self.stroke:
            return
        action, self.moving = self.moving[0], None
        if action == "open":
            self.placed += self.holding
            self.holding = False
            self.emit("e_DROPPED")
            return
        self.grips += 1
        self.holding = not (self.miss_every and self.grips % self.miss_every == 0)
        self.emit("e_GRIPPED" if self.holding else "e_MISSED")

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Whether it holds a part, how many grips it made and parts it let go of."""
        return {"holding": self.holding, "grips": self.grips, "placed": self.placed}


class Curtain(_Emitter):
    """The light curtain at the cell's opening: `beam` is 1 while nobody reaches in,
    0 while the beam is broken (e_CURTAIN when it breaks)."""

    emits = ("e_CURTAIN",)
    beam = Out(Scalar, doc="1: clear, 0: broken (every update)")

    def __init__(self, name: str):
        super().__init__(name)
        self.broken = False
        self.breaks = 0

    @operation
    def breach(self, broken: bool = True) -> dict[str, Any]:
        """Someone reaches into the cell (or, with broken=False, has left it)."""
        if broken and not self.broken:
            self.breaks += 1
            self.emit("e_CURTAIN")
        self.broken = bool(broken)
        return self.report()

    def update_hook(self) -> None:
        self.beam.write(Scalar(time.time(), 0.0 if self.broken else 1.0))

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Whether the beam is broken now, and how often it was."""
        return {"broken": self.broken, "breaks": self.breaks}


class Planner(_Emitter):
    """Moves a setpoint from where the gantry is to a named goal at `speed` (e_ARRIVED
    once the gantry is there)."""

    emits = ("e_ARRIVED",)
    speed = prop(float, 0.25, min=0.001, max=2.0, unit="m/s", doc="setpoint speed")
    position = In(Pose, doc="where the gantry is")
    setpoint = Out(Pose, doc="where the gantry should be now")

    def __init__(self, name: str):
        super().__init__(name)
        self.goal: str = ""
        self.commanded: list[float] | None = None
        self.measured: tuple[float, ...] | None = None
        self.arrived = True
        self.last = time.monotonic()

    @operation
    def go(self, where: str) -> dict[str, Any]:
        """Head for a named pose (home, pick, bin), from where the gantry is."""
        if where not in POSES:
            raise FwError(f"no pose {where!r} (known: {', '.join(POSES)})")
        if self.measured is None:
            raise FwError("the gantry's position is not known yet")
        self.goal, self.arrived = where, False
        self.commanded = list(self.measured)
        return self.report()

    @operation
    def hold(self) -> dict[str, Any]:
        """No goal: the setpoint stays where the gantry is (before automatic mode
        resumes, so no old setpoint pulls it away)."""
        self.goal, self.arrived = "", True
        return self.report()

    def update_hook(self) -> None:
        now = time.monotonic()
        step, self.last = self.speed * min(now - self.last, 0.1), now
        status, pose = self.position.read()
        if status is ReadStatus.NEW:
            self.measured = pose.position
        if not self.goal:  # hold where the gantry is
            if self.measured is not None:
                self.commanded = list(self.measured)
                self.setpoint.write(_pose(self.commanded))
            return
        assert self.commanded is not None
        goal = POSES[self.goal]
        delta = [g - c for g, c in zip(goal, self.commanded, strict=True)]
        distance = math.sqrt(sum(d * d for d in delta))
        if distance > step:
            self.commanded = [
                c + d * step / distance for c, d in zip(self.commanded, delta, strict=True)
            ]
        else:
            self.commanded = list(goal)
        self.setpoint.write(_pose(self.commanded))
        near = self.measured is not None and math.dist(self.measured, goal) < REACHED
        if near and not self.arrived:
            self.arrived = True
            self.emit("e_ARRIVED", where=self.goal)

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """The goal, and whether the gantry reached it."""
        return {"goal": self.goal, "arrived": self.arrived, "commanded": self.commanded}


class Handle(Component):
    """The hands-on handle: a setpoint the operator pushes around (simulated: `push`)."""

    position = In(Pose, doc="where the gantry is")
    setpoint = Out(Pose, doc="where the operator's hand takes the gantry")

    def __init__(self, name: str):
        super().__init__(name)
        self.target: list[float] | None = None

    @operation
    def push(self, dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> dict[str, Any]:
        """The operator's hand moves the handle by (dx, dy, dz) m (at most 5 cm)."""
        if self.target is None:
            raise FwError("the gantry's position is not known yet")
        move = [float(dx), float(dy), float(dz)]
        if not all(math.isfinite(v) and abs(v) <= 0.05 for v in move):
            raise FwError("a push moves at most 5 cm along each axis")
        self.target = [t + m for t, m in zip(self.target, move, strict=True)]
        return {"target": self.target}

    def update_hook(self) -> None:
        status, pose = self.position.read()
        if self.target is None and status is ReadStatus.NEW:
            self.target = list(pose.position)
        if self.target is not None:
            self.setpoint.write(_pose(self.target))

    @operation
    def follow(self) -> dict[str, Any]:
        """Start from where the gantry is now (when hands-on begins)."""
        self.target = None
        return {"target": None}


class Gantry(_Emitter):
    """The robot: a Cartesian gantry that follows its setpoint at no more than
    `max_speed`, and brakes in its own loop (the module docstring): a broken light
    curtain, setpoints that stop while released, a safety monitor trip. Those stops
    latch and are told to the chart (e_STOP with the reason); `acknowledge` (the
    operator's RELEASE) clears one when everything is healthy and nobody is in the cell."""

    hosts_safety_monitor = True
    emits = ("e_STOP",)
    max_speed = prop(float, 0.3, min=0.001, max=2.0, unit="m/s", doc="never faster")
    setpoint_cycles = prop(int, 20, min=1, max=10000, doc="cycles without setpoint: stop")
    setpoint = In(Pose, doc="where to be (the planner, or the handle when hands-on)")
    beam = In(Scalar, doc="the light curtain (1 clear, 0 broken)")
    position = Out(Pose, doc="where the gantry is, every cycle")

    def __init__(self, name: str):
        super().__init__(name)
        self.at = list(POSES["home"])
        self.goal: list[float] | None = None
        self.braked = True
        self.latched = ""
        self.reason = "power on"
        self.quiet = 0
        self.broken = False
        self.moved = 0.0
        self.last = time.monotonic()

    def configure_hook(self) -> bool:
        if self.safety is None:
            raise ConfigureError("the gantry runs only under a safety monitor (safety:)")
        return True

    def update_hook(self) -> None:
        now = time.monotonic()
        dt, self.last = min(now - self.last, 0.1), now
        status, pose = self.setpoint.read()
        if status is ReadStatus.NEW and all(math.isfinite(v) for v in pose.position):
            self.goal, self.quiet = list(pose.position), 0
        else:
            self.quiet += 1
        beam_status, beam = self.beam.read()
        self.broken = broken = beam_status is not ReadStatus.NO_DATA and beam.value < 0.5
        reason = self.safety.check(not self.braked)
        if not reason and broken and not self.braked:
            reason = "the light curtain is broken"
        if not reason and not self.braked and self.quiet >= self.setpoint_cycles:
            reason = f"no setpoint for {self.quiet} cycles"
        if reason and not self.latched:
            self.latched = self.reason = reason
            self.braked = True
            self.safety.trip(reason)
            self.emit("e_STOP", reason=reason)
        if not self.braked and self.goal is not None:
            delta = [g - a for g, a in zip(self.goal, self.at, strict=True)]
            distance = math.sqrt(sum(d * d for d in delta))
            step = min(distance, self.max_speed * dt)
            if distance > 0:
                self.at = [a + d * step / distance for a, d in zip(self.at, delta, strict=True)]
                self.moved += step
        self.position.write(_pose(self.at))

    @operation
    def brake(self, reason: str = "stop") -> dict[str, Any]:
        """Stop where it is and hold."""
        self.braked, self.reason = True, reason
        return self.report()

    @operation
    def release(self) -> dict[str, Any]:
        """Follow the setpoint again; refused while a stop is latched or a safety input
        is not healthy (it starts from where it is: no jump to an old setpoint)."""
        if self.latched:
            raise FwError(f"safety stop latched ({self.latched}): only RELEASE clears it")
        if self.broken:
            raise FwError("the light curtain is broken: someone is in the cell")
        why = self.safety.ready() if self.safety is not None else ""
        if why:
            raise FwError(why)
        self.goal, self.quiet = None, 0
        self.braked, self.reason = False, ""
        return self.report()

    @operation
    def acknowledge(self) -> dict[str, Any]:
        """The operator's RELEASE: clear a latched stop if every input is healthy (the
        brakes stay on until `release`)."""
        if self.broken:
            raise FwError("the light curtain is broken: someone is in the cell")
        why = self.safety.acknowledge() if self.safety is not None else ""
        if why:
            raise FwError(why)
        self.latched = ""
        return self.report()

    @operation(exclusive=False)
    def await_ready(self, timeout: float = 5.0) -> dict[str, Any]:
        """Wait (at most `timeout` s) until every safety input is healthy, so the cell
        offers START only once the gantry sees everything it depends on."""
        end = time.monotonic() + timeout
        while True:
            why = self.safety.ready() if self.safety is not None else ""
            if not why:
                return self.report()
            if time.monotonic() >= end:
                raise FwError(f"not ready after {timeout:g} s: {why}")
            time.sleep(0.01)

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Brakes, the latched stop and its reason, where it is, how far it moved."""
        return {
            "braked": self.braked,
            "latched": self.latched,
            "reason": self.reason,
            "at": [round(v, 4) for v in self.at],
            "moved": round(self.moved, 4),
        }
