"""The simulated KUKA LWR 4+ as a machine of its own: MuJoCo physics and its controller.

A real LWR 4+ has its own controller (the KRC): the robot interface commands it
over FRI, and the controller brakes by itself when the commands stop. `ArmController`
is that machine in simulation, hosted in a process of its own (topology process
`arm`), so that killing or hanging the robot interface's process brakes the arm as
pulling the FRI cable would:

* every cycle (1 kHz) it steps `SimulatedArm` and publishes its `measured` state (the
  encoders' joints, the TCP its nominal model computes from them, brakes, latch) and,
  at `truth_rate`, the ground-truth `tcp` that the simulated OR's trackers observe:
  with `model_errors: lwr4` the two differ by a few millimetres, as a real arm's do;
  while braked it runs `monitor_cycles` cycles per update and publishes once per
  update (FRI's monitor mode: nothing is commanded, nothing moves), which is what
  keeps the idle deployment cheap; released, every cycle again (command mode);
* joint setpoints arrive on `command`; brake, release, reset and mode requests on
  `request` (the FRI commands that switch the controller's mode);
* **command watchdog**: released and being commanded, no setpoint for
  `watchdog_cycles` of its own cycles (a hung interface) engages the brakes;
* **link watch**: the liveliness token of its `commander` vanishes (the interface's
  process died and its link closed): brakes at the next cycle;
* brakes the controller applies by itself (watchdog, link, the setpoint guard of
  `SimulatedArm`) and brakes the interface asks for as a safety stop **latch**:
  `release` is refused until a `reset`, which the interface sends only on the
  operator's RELEASE.

Its cycles count its own time: if the whole host stalls, the arm stalls with it and
no cycle passes without the interface having had the chance to answer.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from components.domain.geometry import matrix_to_quat
from components.domain.lwr4 import HOME, LWR4_ERRORS, NOMINAL, Kinematics
from components.sim.arm import MODES, SimulatedArm
from framework import keys
from framework.component import Component, In, Out, operation
from framework.messages import ArmState, EventMessage, JointState, Pose
from framework.ports import ReadStatus
from framework.properties import prop

MODEL_ERRORS = {"lwr4": LWR4_ERRORS, "none": NOMINAL}
"""How the simulated arm differs from its model: as a real LWR 4+ (components/domain/lwr4.py),
or not at all."""
SELF_BRAKES = ("watchdog", "setpoint", "link")
"""Brake reasons of the controller's own safety: they latch."""


class ArmController(Component):
    """The simulated LWR 4+ and its controller-side safety (see the module docstring)."""

    watchdog_cycles = prop(
        int, 40, min=1, max=10000, doc="own cycles without a setpoint, while commanded, that brake"
    )
    mode = prop(str, "position", choices=list(MODES), doc="joint servo mode at power on")
    model_errors = prop(
        str,
        "lwr4",
        choices=list(MODEL_ERRORS),
        doc="the arm vs its nominal model: a real LWR 4+'s errors, or none",
    )
    commander = prop(str, "", doc="component whose lost link brakes the arm ('' for none)")
    lockstep_ms = prop(
        float, 2.0, unit="ms", min=0.0, max=100.0, doc="wait for a late setpoint (0: never)"
    )
    monitor_cycles = prop(
        int,
        10,
        min=1,
        max=40,
        doc="while braked (FRI monitor mode), cycles per update and per measured state",
    )
    truth_rate = prop(
        float, 200.0, unit="Hz", min=1.0, max=1000.0, doc="how often the ground-truth tcp goes out"
    )
    command = In(JointState, doc="joint position setpoints (rad), one per cycle")
    request = In(
        EventMessage,
        doc="brake {reason, latch}, release, reset, mode {mode}",
        policy={"type": "buffer", "size": 16},
    )
    measured = Out(ArmState, doc="joints, flange tool pose, brakes and latch, every cycle")
    tcp = Out(Pose, doc="ground-truth tool pose in the base frame (what trackers see)")

    def __init__(self, name: str):
        super().__init__(name)
        self.arm: SimulatedArm | None = None
        """The machine, made by `configure`."""

    def configure_hook(self) -> bool:
        self.arm = SimulatedArm(
            HOME,
            watchdog_cycles=self.watchdog_cycles,
            mode=self.mode,
            errors=MODEL_ERRORS[self.model_errors],
        )
        self.kinematics = Kinematics()
        self.latched = ""
        self.releases = 0
        self.refused = ""
        self.cycle = 0
        self.served = 0
        self._on_time = True
        self._link_lost = ""
        self._commander_seen = False
        self._arrived = threading.Event()
        self._link: Any = None
        return True

    def start_hook(self) -> bool:
        self.command.on_data = lambda _port: self._arrived.set()
        if self.commander and self.bus is not None and self._link is None:
            self._link = self.bus.watch(keys.alive(self.commander), self._on_link)
        return True

    def stop_hook(self) -> None:
        self._brake("controller stopped", latch=True)

    def cleanup_hook(self) -> None:
        if self._link is not None:
            self._link.undeclare()
            self._link = None

    def _on_link(self, _key: str, alive: bool) -> None:
        if alive:
            self._commander_seen = True
        elif self._commander_seen:
            self._link_lost = f"link to {self.commander} lost"

    def _brake(self, reason: str, latch: bool) -> None:
        self.arm.brake(reason)
        if latch and not self.latched:
            self.latched = reason

    # -- the cycle -----------------------------------------------------------------------
    def update_hook(self) -> None:
        arm = self.arm
        # wait for a late setpoint, but only while the commander keeps up: once it has
        # missed a cycle, waiting would only stretch the watchdog's cycles
        if arm.commanded and self.lockstep_ms > 0 and self._on_time and not self.command.pending():
            self._arrived.clear()
            if not self.command.pending():
                self._arrived.wait(self.lockstep_ms / 1000.0)
        self._on_time = self.command.pending() > 0
        while True:
            status, request = self.request.read()
            if status is not ReadStatus.NEW:
                break
            self._serve(request)
            self.served += 1
        was_braked = arm.braked
        status, sample = self.command.read()
        if status is ReadStatus.NEW and not arm.braked:
            arm.command(np.asarray(sample.position))  # the setpoint guard may brake
        if self._link_lost:
            reason, self._link_lost = self._link_lost, ""
            self._brake(reason, latch=True)
        steps = self.periods_per_update  # the cycles since the last update
        for _ in range(steps):
            arm.step()  # the command watchdog may brake
        if arm.braked and not was_braked and arm.reason.startswith(SELF_BRAKES):
            self.latched = self.latched or arm.reason
        self.cycle += steps
        # Braked, nothing moves and nothing is commanded: report every few cycles (FRI's
        # monitor mode); released, every cycle again (command mode).
        self.periods_per_update = self.monitor_cycles if arm.braked else 1
        self._publish(steps)

    def _serve(self, request: EventMessage) -> None:
        payload = request.payload or {}
        if request.name == "brake":
            self._brake(str(payload.get("reason", "interface")), bool(payload.get("latch")))
        elif request.name == "release":
            if self.latched:
                self.refused = f"release refused: latched ({self.latched}); reset first"
            elif self.arm.braked:
                self.arm.release()
                self.releases += 1
                self.refused = ""
        elif request.name == "reset":
            self.latched = ""
        elif request.name == "mode":
            try:
                self.arm.set_mode(str(payload.get("mode")))
            except ValueError as exc:
                self.refused = str(exc)

    def _publish(self, steps: int = 1) -> None:
        arm, stamp = self.arm, time.time()
        q = arm.q
        nominal = self.kinematics.tcp(q)
        data = arm.data
        self.measured.write(
            ArmState(
                stamp,
                self.cycle,
                self.served,
                tuple(q.tolist()),
                tuple(data.qvel[:7].tolist()),
                tuple(data.actuator_force[:7].tolist()),
                (*nominal[:3, 3].tolist(), *matrix_to_quat(nominal[:3, :3])),
                arm.braked,
                bool(self.latched),
                self.latched or arm.reason,
            )
        )
        every = max(1, round(1000.0 / self.truth_rate))
        if self.cycle % every < steps:  # a multiple of `every` was passed: trackers sample slower
            tcp = arm.tcp()
            position = tuple(float(v) for v in tcp[:3, 3])
            quaternion = matrix_to_quat(tcp[:3, :3])
            self.tcp.write(Pose(position, quaternion, stamp, 0.0, self.cycle, True, "base", "tcp"))  # type: ignore[arg-type]

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Brakes, latch, why, releases so far, servo mode, simulated time, joints."""
        arm = self.arm
        if arm is None:
            return {"braked": True, "latched": False, "reason": "not configured"}
        return {
            "braked": arm.braked,
            "latched": bool(self.latched),
            "reason": self.latched or arm.reason,
            "releases": self.releases,
            "refused": self.refused,
            "mode": arm.mode,
            "cycle": self.cycle,
            "time": round(arm.time, 4),
            "q": [round(v, 5) for v in arm.q.tolist()],
        }
