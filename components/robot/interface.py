"""The robot interface (the FRI role): the only component that moves the arm.

In simulation it steps the MuJoCo LWR 4+ one millisecond per update (at 1 kHz in
real time, or on the stepped clock in tests); a real FRI driver would be another
component with the same ports and operations, swapped in the topology. Safety
lives here too, below everything else: brakes at power on, a watchdog on the
setpoint stream, and a guard against setpoint jumps (see `arm.py`).

While it is being commanded, each cycle waits up to `lockstep_ms` (wall time) for
the controller's setpoint before stepping, like FRI's synchronous mode: on a
loaded host the simulated arm then runs slower than real time instead of
missing setpoints, and only a controller silent for `watchdog_cycles` such
waits (a dead one) makes the watchdog brake.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from components.robot.arm import MODES, SimulatedArm
from components.robot.lwr4 import HOME
from components.tracking.geometry import matrix_to_quat
from framework.component import Component, In, Out, operation
from framework.messages import EventMessage, JointState, Pose
from framework.ports import ReadStatus
from framework.properties import prop

SELF_BRAKES = ("watchdog", "setpoint")
"""Brake reasons of the arm's own safety (not asked for by the procedure)."""
STILL_RAD_S = 2e-3
STILL_CYCLES = 50
STILL_TIMEOUT = 2.0  # s


def tcp_message(tcp: np.ndarray, stamp: float, frame: str = "base") -> Pose:
    """A TCP pose (4x4) as a `Pose` message."""
    return Pose(
        tuple(float(v) for v in tcp[:3, 3]),  # type: ignore[arg-type]
        matrix_to_quat(tcp[:3, :3]),
        stamp,
        0.0,
        0,
        True,
        frame,
        "tcp",
    )


class RobotInterface(Component):
    """Steps the simulated LWR 4+, takes joint setpoints, publishes joints and TCP."""

    watchdog_cycles = prop(int, 5, min=1, max=1000, doc="cycles without setpoint before braking")
    mode = prop(str, "position", choices=list(MODES), doc="joint servo mode")
    lockstep_ms = prop(
        float, 20.0, unit="ms", min=0.0, max=1000.0, doc="wait for each setpoint (0: never)"
    )
    setpoint = In(JointState, doc="joint position setpoints (rad), one per cycle")
    joints = Out(JointState, doc="measured joints, every cycle")
    tcp = Out(Pose, doc="measured TCP in the robot base frame, every cycle")
    status = Out(EventMessage, doc="brakes, reason, mode (on change and at 2 Hz)")

    def configure_hook(self) -> bool:
        self.arm = SimulatedArm(HOME, watchdog_cycles=self.watchdog_cycles, mode=self.mode)
        self._reported: tuple[bool, str, str] | None = None
        self._last_status = -1.0
        self._brake_when_still: tuple[str, float] | None = None  # (reason, deadline)
        self._still_cycles = 0
        self._arrived = threading.Event()
        return True

    def start_hook(self) -> bool:
        self.setpoint.on_data = lambda _port: self._arrived.set()
        return True

    def update_hook(self) -> None:
        arm = self.arm
        if arm.commanded and self.lockstep_ms > 0 and not self.setpoint.pending():
            self._arrived.clear()
            if not self.setpoint.pending():
                self._arrived.wait(self.lockstep_ms / 1000.0)
        status, sample = self.setpoint.read()
        if status is ReadStatus.NEW and not arm.braked:
            arm.command(np.asarray(sample.position))
        arm.step()
        if self._brake_when_still is not None:
            self._brake_once_still()
        stamp = time.time()
        self.joints.write(
            JointState(
                stamp,
                tuple(arm.data.qpos[:7].tolist()),
                tuple(arm.data.qvel[:7].tolist()),
                tuple(arm.data.actuator_force[:7].tolist()),
            )
        )
        self.tcp.write(tcp_message(arm.tcp(), stamp))
        state = (arm.braked, arm.reason, arm.mode)
        now = time.monotonic()
        if state != self._reported or now - self._last_status > 0.5:
            self._reported, self._last_status = state, now
            self.status.write(EventMessage(stamp, "robot", self.name, self.report()))

    def _brake_once_still(self) -> None:
        assert self._brake_when_still is not None
        reason, deadline = self._brake_when_still
        still = float(np.max(np.abs(self.arm.data.qvel[:7]))) < STILL_RAD_S
        self._still_cycles = self._still_cycles + 1 if still else 0
        if self._still_cycles >= STILL_CYCLES or self.arm.time >= deadline:
            self.arm.brake(reason)
            self._brake_when_still = None

    def stop_hook(self) -> None:
        if hasattr(self, "arm"):
            self.arm.brake("robot interface stopped")

    @operation
    def brake(self, reason: str = "operator", when_still: bool = False) -> dict[str, Any]:
        """Engage the brakes now, or once the arm stands still (at most `STILL_TIMEOUT`
        later): the interpolator's own STOP brakes along the path first."""
        if when_still and not self.arm.braked:
            self._brake_when_still = (reason, self.arm.time + STILL_TIMEOUT)
            self._still_cycles = 0
        else:
            self.arm.brake(reason)
        return self.report()

    @operation
    def release(self) -> dict[str, Any]:
        """Release the brakes; the arm holds its pose until setpoints arrive."""
        self._brake_when_still = None
        self.arm.release()
        return self.report()

    @operation
    def set_mode(self, mode: str) -> dict[str, Any]:
        """Switch the joint servos to 'position' or 'impedance'."""
        self.arm.set_mode(mode)
        return self.report()

    @operation
    def report(self) -> dict[str, Any]:
        """Brakes, why they engaged, servo mode, simulated time, joints."""
        arm = getattr(self, "arm", None)
        if arm is None:
            return {"braked": True, "reason": "not configured", "mode": self.mode}
        return {
            "braked": arm.braked,
            "reason": arm.reason,
            "fault": arm.braked and arm.reason.startswith(SELF_BRAKES),
            "mode": arm.mode,
            "time": round(arm.time, 4),
            "q": [round(v, 5) for v in arm.q.tolist()],
        }
