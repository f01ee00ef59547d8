"""The simulated LWR 4+ behind the robot interface: MuJoCo stepped at 1 kHz.

`SimulatedArm` is the physics and the arm's own safety, without any I/O:

* joint **position** mode (stiff servos that track the commanded motion) or
  **impedance** mode (the LWR's joint impedance control, as in the thesis: soft
  springs with damping on the measured velocity and no velocity feed-forward from
  FRI's position commands, so the arm trails a moving command by `kv/kp`, 70 ms; fitted to the thesis' Fig. 4.8, docs/seeg.md), switched at run time;
* a **real arm**, not its model (`lwr4.ArmErrors`): the encoders read the link
  angles minus the joints' zero offsets and plus the gears' twist under the torque
  they carry; the bodies have the real link lengths. `q` is what the encoders say,
  `tcp()` where the TCP truly is;
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

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from components.domain import lwr4
from components.domain.ik import _fwkernel
from components.sim.scene import Scene

MODES = {"position": (2500.0, 120.0), "impedance": (300.0, 21.0)}
"""Servo stiffness (N m/rad) and damping (N m s/rad) per control mode."""
FEED_FORWARD = {"position": True, "impedance": False}
"""Whether the mode's servo is given the commanded velocity (position control tracks a
moving command; joint impedance control only pulls toward the commanded position)."""
_LIMITS = tuple(float(v) for v in lwr4.POSITION_LIMIT)


def _finite(value: float) -> bool:
    """A finite number (an int beyond any float is not)."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


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
        errors: lwr4.ArmErrors = lwr4.NOMINAL,
    ):
        self.errors = errors
        self.model = mujoco.MjModel.from_xml_string(lwr4.mjcf((scene or Scene()).bodies(), errors))
        self.data = mujoco.MjData(self.model)
        self.dt = float(self.model.opt.timestep)
        self._offset = np.array(errors.joint_offset, dtype=float)
        stiffness = errors.joint_stiffness
        self._compliance = np.zeros(7) if stiffness is None else 1.0 / np.array(stiffness)
        self._reference_guard = False  # True: `_command` and `_sense` in Python, not the kernel
        for _ in range(3):  # the links settle where the encoders read q0, servos idle
            self.data.qpos[:7] = np.asarray(q0, dtype=float) + self._offset - self._twist()
            self.data.ctrl[:7] = self.data.qpos[:7]
            mujoco.mj_forward(self.model, self.data)
        self._sense()
        self.tcp_site = self.model.site("tcp").id
        self.watchdog_cycles = watchdog_cycles
        self.velocity_limit = np.array(lwr4.VELOCITY_LIMIT)
        self._velocity_limit = tuple(float(v) for v in lwr4.VELOCITY_LIMIT)
        self.braked = True  # an arm powers up with its brakes on
        self.reason = "power on"
        self.mode = ""
        self.set_mode(mode)
        self._since_setpoint = 0
        self._fresh = False
        self._commanded = False
        self._last_setpoint = tuple(float(v) for v in q0)
        self._held = self.data.qpos[:7].copy()  # link angles the brakes hold
        self._at_rest = False  # braked and stepped once since: nothing left to simulate

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
        """Measured joint positions (rad): the encoders, on the motors' side (read-only:
        what the last physics step left; a new array after each)."""
        if self._q is None:
            q = np.array(self._q_values)
            q.flags.writeable = False
            self._q = q
        return self._q

    @property
    def q_values(self) -> tuple[float, ...]:
        """`q` as plain floats (what a measurement datagram carries)."""
        return self._q_values

    def _twist(self) -> np.ndarray:
        """How far each motor is ahead of its link: the gear's twist under the torque
        it carries (the servo's and the gravity compensation's)."""
        return (self.data.actuator_force[:7] + self.data.qfrc_gravcomp[:7]) * self._compliance

    def _sense(self) -> None:
        """Read the encoders and what the servos aim by, once per physics step (every
        reading of a cycle reads these: the state changes only in a step); in the
        compiled kernel where it was built (`arm_sense`: `_sense_reference`'s operations,
        which a spec holds it to)."""
        if _fwkernel is None or self._reference_guard:
            self._sense_reference()
            return
        data = self.data
        self._q_values, aim, self._torque = _fwkernel.arm_sense(
            data.qpos[:7], data.actuator_force[:7], data.qfrc_gravcomp[:7],
            self._compliance, self._offset,
        )  # fmt: skip
        self._aim = list(aim)
        self._q = None  # made from `_q_values` when someone reads `q`

    def _sense_reference(self) -> None:
        """`_sense` in numpy."""
        twist = self._twist()
        q = self.data.qpos[:7] + twist - self._offset
        q.flags.writeable = False
        self._q = q
        self._q_values = tuple(q.tolist())
        self._aim = (self._offset - twist).tolist()  # link angle = setpoint + this
        self._torque = tuple(self.data.actuator_force[:7].tolist())

    @property
    def last_setpoint(self) -> tuple[float, ...]:
        """The setpoint the servos were last given (cmdJntPos while commanded)."""
        return self._last_setpoint

    @property
    def qd(self) -> np.ndarray:
        """Measured joint velocities (rad/s)."""
        return self.data.qvel[:7].copy()

    @property
    def torque(self) -> np.ndarray:
        """Actuator torques (N m)."""
        return np.array(self._torque)

    @property
    def torque_values(self) -> tuple[float, ...]:
        """`torque` as plain floats (what a measurement datagram carries)."""
        return self._torque

    def tcp(self) -> np.ndarray:
        """Where the TCP truly is, in the base frame (4x4): what a tracker sees, not
        what the controller's model computes from `q`."""
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
            self._held = self.data.qpos[:7].copy()
            self.data.ctrl[:7] = self._held
        self._commanded = False

    def release(self) -> None:
        """Release the brakes; the arm holds its pose until setpoints arrive."""
        if self.braked:
            self.braked, self.reason = False, ""
            self._at_rest = False
            self.data.ctrl[:7] = self.data.qpos[:7]
            self._last_setpoint = self._q_values
            self._since_setpoint = 0
            self._commanded = False

    def command(self, setpoint: np.ndarray | tuple[float, ...]) -> bool:
        """A joint position setpoint for the next cycles; False if refused (and braked).
        The guard and the servo targets run in the compiled kernel where it was built
        (`servo_aim`, the same arithmetic as `_command`, which a spec holds it to)."""
        if self.braked:
            return False
        if _fwkernel is None or self._reference_guard:
            return self._command(setpoint)
        values = setpoint.tolist() if isinstance(setpoint, np.ndarray) else setpoint
        elapsed = self.dt * (self._since_setpoint + 1)
        reference = self._last_setpoint if self._commanded else self._q_values
        if FEED_FORWARD[self.mode] and self._commanded:
            kp, kv = MODES[self.mode]
            feed_forward = kv / kp / elapsed
        else:
            feed_forward = 0.0
        joint = _fwkernel.servo_aim(
            values,
            reference,
            self._velocity_limit,
            self._aim,
            _LIMITS,
            1.5 * elapsed,
            feed_forward,
            self.data.ctrl[:7],
        )
        if joint == -2:
            self.brake("setpoint is not 7 finite joint values")
            return False
        if joint >= 0:
            self._jumped(values, reference, joint, elapsed)
            return False
        self._last_setpoint = tuple(values)
        self._since_setpoint = 0
        self._fresh = True
        self._commanded = True
        return True

    def _jumped(
        self, values: Any, reference: tuple[float, ...], joint: int, elapsed: float
    ) -> None:
        step = abs(values[joint] - reference[joint])
        self.brake(
            f"setpoint jump on {lwr4.JOINTS[joint]}: {math.degrees(step):.2f} deg "
            f"in {elapsed * 1e3:.0f} ms"
        )

    def _command(self, setpoint: np.ndarray | tuple[float, ...]) -> bool:
        """`command` in plain Python: the reference of the kernel's `servo_aim`."""
        values = setpoint.tolist() if isinstance(setpoint, np.ndarray) else list(setpoint)
        if (
            len(values) != 7
            or not all(isinstance(v, float | int) for v in values)
            or not all(map(_finite, values))
        ):
            self.brake("setpoint is not 7 finite joint values")
            return False
        elapsed = self.dt * (self._since_setpoint + 1)  # cycles since the previous setpoint
        # the first setpoint after release is checked against the measured joints
        reference = self._last_setpoint if self._commanded else self._q_values
        # in position mode, PD toward the setpoint with its velocity as reference:
        # ctrl = q* + (kv/kp) qd* turns MuJoCo's kp (ctrl - q) - kv qd into
        # kp (q* - q) + kv (qd* - qd), no lag; in impedance mode the damping acts on
        # the measured velocity alone, and the arm trails the command
        if FEED_FORWARD[self.mode] and self._commanded:
            kp, kv = MODES[self.mode]
            feed_forward = kv / kp / elapsed
        else:
            feed_forward = 0.0
        # seven joints in one pass of plain floats: numpy's per-call cost on 7-element
        # arrays was most of the simulated KRC's cycle
        reach = 1.5 * elapsed
        aim = self._aim  # link angle = setpoint + this
        target = [0.0] * 7
        worst, joint = 1.0, -1
        for j, (v, r, limit, a, bound) in enumerate(
            zip(values, reference, self._velocity_limit, aim, _LIMITS, strict=True)
        ):
            delta = v - r
            ratio = abs(delta) / (limit * reach + 1e-6)
            if ratio > worst:
                worst, joint = ratio, j
            t = v + a + delta * feed_forward
            target[j] = -bound if t < -bound else bound if t > bound else t
        if joint >= 0:
            self._jumped(values, reference, joint, elapsed)
            return False
        self.data.ctrl[:7] = target
        self._last_setpoint = tuple(values)
        self._since_setpoint = 0
        self._fresh = True
        self._commanded = True
        return True

    def step(self) -> None:
        """One physics cycle (1 ms), after the watchdog. Braked and stepped once since,
        the arm is at a fixed point (held links, no velocity, servos aimed where they
        stand, a static room): only time passes, and the physics is not run again
        (the simulated KRC spends its braked minutes waiting, not integrating)."""
        if self._commanded and not self._fresh:
            self._since_setpoint += 1
            if self._since_setpoint > self.watchdog_cycles:
                self.brake(f"watchdog: no setpoint for {self._since_setpoint} cycles")
        self._fresh = False
        if self._at_rest:
            self.data.time += self.dt
            return
        if self.braked:
            self.data.qpos[:7] = self._held
            self.data.qvel[:7] = 0.0
        mujoco.mj_step(self.model, self.data)
        if self.braked:
            self.data.qpos[:7] = self._held
            self.data.qvel[:7] = 0.0
            self._at_rest = True
        self._sense()

    def status(self) -> ArmStatus:
        """Brakes, why, mode and time."""
        return ArmStatus(self.braked, self.reason, self.mode, self.time)


def resting_tcp(q: np.ndarray, errors: lwr4.ArmErrors) -> np.ndarray:
    """Where the TCP of a real arm (`errors`) rests when its encoders read `q` (4x4, base
    frame): what a tracker sees while the controller's model says `Kinematics.tcp(q)`."""
    return SimulatedArm(tuple(np.asarray(q, dtype=float)), errors=errors).tcp()
