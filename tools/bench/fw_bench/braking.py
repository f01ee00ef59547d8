"""Behavioural control on the MuJoCo arm (thesis 3.6.3.C, Fig. 4.6-4.8).

The interpolator drives the simulated LWR 4+ (MuJoCo, the real arm's errors, joint
impedance control as in the thesis: it trails a moving command) cycle by cycle on
the simulated clock, exactly as in the robot process but without the
network, so every run is repeatable. The TCP moves on a planar path (the thesis'
x-y trajectory); at a random moment after it reaches cruise speed a STOP is
asserted. Per trial:

* displacement: the farthest the arm's TCP (as its controller reports it: the
  model at the encoders, like the thesis' FRI pose) gets from where the STOP was
  asserted (the commanded position then: the interpolator returns there), the
  thesis' "displacement ... can reach 6 mm at 10 cm/s";
* RMSE per axis of the reported TCP against the command during the braking ramp
  (from the STOP until the command stands still): the thesis' Fig. 4.8 quantity,
  which is the arm's lag behind its command (about the speed x 70 ms);
* return error: the TCP at rest against the commanded STOP point.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import numpy as np

from components.domain import lwr4
from components.domain.procedure import load_procedure
from components.robot.interpolator import InterpolatorCore, Phase
from components.sim.arm import SimulatedArm
from fw_bench.files import seeg_file
from fw_bench.seeg_run import BenchError

SPEEDS = (0.01, 0.025, 0.05, 0.075, 0.10)
"""Cruise speeds of the thesis (m/s)."""
PLANAR_PATH = (0.20, 0.10, 0.0)
"""From the TCP at home, a straight path in the base x-y plane (m)."""
SETTLE = 0.3
"""Seconds the arm must stay still before a trial ends."""


@dataclass
class Trace:
    """One run, sampled every control cycle (1 ms)."""

    t: list[float] = field(default_factory=list)
    commanded: list[list[float]] = field(default_factory=list)
    actual: list[list[float]] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Time, commanded xyz, actual xyz, commanded path speed as arrays."""
        return (
            np.array(self.t),
            np.array(self.commanded),
            np.array(self.actual),
            np.array(self.speed),
        )


class Rig:
    """The interpolator feeding the MuJoCo arm, one cycle per `step`."""

    def __init__(self, speed: float):
        procedure = load_procedure(seeg_file("procedures", "seeg.yaml"))
        self.arm = SimulatedArm(mode="impedance", errors=lwr4.LWR4_ERRORS)
        self.arm.release()
        self.core = InterpolatorCore(
            self.arm.q,
            velocity=speed,
            acceleration=procedure.acceleration,
            brake_acceleration=procedure.brake_acceleration,
        )
        self.kinematics = lwr4.Kinematics()
        self.trace = Trace()
        goal = self.core.pose.copy()
        goal[:3, 3] += PLANAR_PATH
        self.goal = goal

    def step(self) -> None:
        """One control cycle: interpolator, arm command, physics, record."""
        q = self.core.step()
        self.arm.command(q)
        self.arm.step()
        self.trace.t.append(self.arm.time)
        self.trace.commanded.append(self.core.pose[:3, 3].tolist())
        self.trace.actual.append(self.measured()[:3].tolist())
        self.trace.speed.append(self.core.speed)

    def measured(self) -> np.ndarray:
        """The TCP as the arm's controller reports it (FRI's measured pose: the model
        at the encoders' joints), the thesis' "actual" position."""
        return self.kinematics.tcp(self.arm.q)[:3, 3]

    def mark(self, what: str) -> None:
        """Note an event (STOP, a speed change) at the current time."""
        self.trace.events.append((self.arm.time, what))

    def run_until_still(self, limit: float = 30.0) -> None:
        """Step until the command is stopped and the arm has stood still for SETTLE s."""
        still_since = None
        end = self.arm.time + limit
        while self.arm.time < end:
            self.step()
            at_rest = self.core.phase is Phase.STOPPED and float(np.max(np.abs(self.arm.qd))) < 1e-4
            if not at_rest:
                still_since = None
            elif still_since is None:
                still_since = self.arm.time
            elif self.arm.time - still_since >= SETTLE:
                return
        raise BenchError("the arm did not come to rest")


def stop_trial(speed: float, delay: float) -> dict[str, float]:
    """Cruise at `speed`, STOP `delay` s after reaching it; the trial's figures (mm)."""
    rig = Rig(speed)
    rig.core.go_to(rig.goal)
    while rig.core.speed < speed - 1e-9:
        rig.step()
    for _ in range(round(delay * 1000)):
        rig.step()
    rig.core.stop()
    rig.mark("STOP")
    start = len(rig.trace.t)
    asserted = rig.core.pose[:3, 3].copy()
    while rig.core.phase is Phase.STOPPING:
        rig.step()
    ramp = len(rig.trace.t)
    rig.run_until_still()
    _, commanded, actual, _ = rig.trace.arrays()
    after_cmd, after_actual = commanded[start:], actual[start:]
    rmse = np.sqrt(np.mean((actual[start:ramp] - commanded[start:ramp]) ** 2, axis=0))
    return {
        "speed_cm_s": speed * 100,
        "displacement_mm": float(np.max(np.linalg.norm(after_actual - asserted, axis=1))) * 1e3,
        "command_overshoot_mm": float(np.max(np.linalg.norm(after_cmd - asserted, axis=1))) * 1e3,
        "rmse_x_mm": float(rmse[0]) * 1e3,
        "rmse_y_mm": float(rmse[1]) * 1e3,
        "rmse_z_mm": float(rmse[2]) * 1e3,
        "return_error_mm": float(np.linalg.norm(actual[-1] - asserted)) * 1e3,
    }


def stops(trials: int, seed: int = 3) -> list[dict[str, float]]:
    """`trials` STOPs at every thesis speed, each at a random moment of the cruise."""
    rng = random.Random(seed)
    return [stop_trial(v, rng.uniform(0.0, 0.4)) for v in SPEEDS for _ in range(trials)]


def behaviour_trace() -> Trace:
    """Fig. 4.6/4.7: 7.5 cm/s, slowed to 2.5 cm/s and back (the critical area), then a
    STOP; commanded and actual TCP every cycle."""
    rig = Rig(0.075)
    rig.core.go_to(rig.goal)
    for seconds, action in ((1.2, 0.025), (1.0, 0.075), (0.8, None)):
        for _ in range(round(seconds * 1000)):
            rig.step()
        if action is not None:
            rig.core.set_limits(action)
            rig.mark(f"limit {action * 100:g} cm/s")
        else:
            rig.core.stop()
            rig.mark("STOP")
    rig.run_until_still()
    return rig.trace
