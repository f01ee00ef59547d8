"""The simulated LWR 4+ behind the robot interface: MuJoCo stepped at 1 kHz.

`SimulatedArm` is the physics and the arm's own safety, without any I/O:

* joint **position** mode (stiff servos) or **impedance** mode (soft servos,
  the arm yields to contact), switched at run time;
* **brakes**: engaged, the joints are held rigidly where they stood (an ideal
  brake) and setpoints are refused until released;
* a **watchdog**: when more than `watchdog_cycles` cycles in a row ran without a
  new setpoint while
  the arm was being commanded, the brakes engage (a dead interpolator must never
  leave the arm coasting);
* a **setpoint guard**: a setpoint further from the last one than the joint
  velocity limits allow in the elapsed time (or not finite) is refused and the
  brakes engage: the robot never jumps.

Every brake engagement carries a reason, kept for the interface to publish.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from components.robot import lwr4
from components.sim.scene import Scene

MODES = {"position": (2500.0, 120.0), "impedance": (300.0, 25.0)}
"""Servo stiffness (N m/rad) and damping (N m s/rad) per control mode."""


@dataclass
class ArmStatus:
    """What the interface reports besides joint values."""

    braked: bool
    reason: str
    mode: str
    time: float


class SimulatedArm:
    """MuJoCo LWR 4+ with brakes, watchdog and setpoint guard (see module docstring)."""

    def __init__(
        self,
        q0: tuple[float, ...] = lwr4.HOME,
        scene: Scene | None = None,
        watchdog_cycles: int = 5,
        mode: str = "position",
    ):
        self.model = mujoco.MjModel.from_xml_string(lwr4.mjcf((scene or Scene()).bodies()))
        self.data = mujoco.MjData(self.model)
        self.dt = float(self.model.opt.timestep)
        self.data.qpos[:7] = q0
        self.data.ctrl[:7] = q0
        mujoco.mj_forward(self.model, self.data)
        self.tcp_site = self.model.site("tcp").id
        self.watchdog_cycles = watchdog_cycles
        self.velocity_limit = np.array(lwr4.VELOCITY_LIMIT)
        self.braked = True  # an arm powers up with its brakes on
        self.reason = "power on"
        self.mode = ""
        self.set_mode(mode)
        self._since_setpoint = 0
        self._fresh = False
        self._commanded = False
        self._last_setpoint = np.array(q0, dtype=float)
        self._held = np.array(q0, dtype=float)

    @property
    def commanded(self) -> bool:
        """True while released and receiving setpoints (the watchdog is armed)."""
        return self._commanded and not self.braked

    @property
    def time(self) -> float:
        """Simulated time (s) since power on."""
        return float(self.data.time)

    @property
    def q(self) -> np.ndarray:
        """Measured joint positions (rad)."""
        return self.data.qpos[:7].copy()

    @property
    def qd(self) -> np.ndarray:
        """Measured joint velocities (rad/s)."""
        return self.data.qvel[:7].copy()

    @property
    def torque(self) -> np.ndarray:
        """Actuator torques (N m)."""
        return self.data.actuator_force[:7].copy()

    def tcp(self) -> np.ndarray:
        """Measured TCP pose in the base frame (4x4)."""
        out = np.eye(4)
        out[:3, :3] = self.data.site_xmat[self.tcp_site].reshape(3, 3)
        out[:3, 3] = self.data.site_xpos[self.tcp_site]
        return out

    def set_mode(self, mode: str) -> None:
        """Switch between 'position' and 'impedance' servo gains."""
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}: one of {', '.join(MODES)}")
        kp, kv = MODES[mode]
        self.model.actuator_gainprm[:7, 0] = kp
        self.model.actuator_biasprm[:7, 1] = -kp
        self.model.actuator_biasprm[:7, 2] = -kv
        self.mode = mode

    def brake(self, reason: str) -> None:
        """Engage the brakes: hold the joints where they are now."""
        if not self.braked:
            self.braked, self.reason = True, reason
            self._held = self.q
            self.data.ctrl[:7] = self._held
        self._commanded = False

    def release(self) -> None:
        """Release the brakes; the arm holds its pose until setpoints arrive."""
        if self.braked:
            self.braked, self.reason = False, ""
            self.data.ctrl[:7] = self.data.qpos[:7]
            self._last_setpoint = self.q
            self._since_setpoint = 0
            self._commanded = False

    def command(self, setpoint: np.ndarray) -> bool:
        """A joint position setpoint for the next cycles; False if refused (and braked)."""
        if self.braked:
            return False
        setpoint = np.asarray(setpoint, dtype=float)
        if setpoint.shape != (7,) or not np.all(np.isfinite(setpoint)):
            self.brake("setpoint is not 7 finite joint values")
            return False
        elapsed = self.dt * (self._since_setpoint + 1)  # cycles since the previous setpoint
        allowed = self.velocity_limit * elapsed * 1.5 + 1e-6
        # the first setpoint after release is checked against the measured joints
        reference = self._last_setpoint if self._commanded else self.q
        step = np.abs(setpoint - reference)
        if np.any(step > allowed):
            joint = int(np.argmax(step / allowed))
            self.brake(
                f"setpoint jump on {lwr4.JOINTS[joint]}: {np.degrees(step[joint]):.2f} deg "
                f"in {elapsed * 1e3:.0f} ms"
            )
            return False
        # PD toward the setpoint with its velocity as reference: ctrl = q* + (kv/kp) qd*
        # turns MuJoCo's kp (ctrl - q) - kv qd into kp (q* - q) + kv (qd* - qd), no lag
        velocity = (setpoint - reference) / elapsed if self._commanded else 0.0
        kp, kv = MODES[self.mode]
        limit = np.array(lwr4.POSITION_LIMIT)
        self.data.ctrl[:7] = np.clip(setpoint + (kv / kp) * velocity, -limit, limit)
        self._last_setpoint = setpoint
        self._since_setpoint = 0
        self._fresh = True
        self._commanded = True
        return True

    def step(self) -> None:
        """One physics cycle (1 ms), after the watchdog."""
        if self._commanded and not self._fresh:
            self._since_setpoint += 1
            if self._since_setpoint > self.watchdog_cycles:
                self.brake(f"watchdog: no setpoint for {self._since_setpoint} cycles")
        self._fresh = False
        if self.braked:
            self.data.qpos[:7] = self._held
            self.data.qvel[:7] = 0.0
        mujoco.mj_step(self.model, self.data)
        if self.braked:
            self.data.qpos[:7] = self._held
            self.data.qvel[:7] = 0.0

    def status(self) -> ArmStatus:
        """Brakes, why, mode and time."""
        return ArmStatus(self.braked, self.reason, self.mode, self.time)
