"""Navigation on the patient (issue 17, thesis 3.2 and Fig. 4.2 in the patient frame).

The real arm (MuJoCo with `lwr4.LWR4_ERRORS`, position mode as deployed), its
interpolator and the navigator run cycle by cycle on the simulated clock; the
trackers of the synthetic world see the arm's true TCP and the reference tool on
the head, with their noise and rates; the navigator uses the calibration that
`fw calibrate` made on that arm (`procedures/seeg/sensors.yaml`). Every run is
repeatable (seeded). Errors are the real TCP's distance to the target where the
head truly is:

* `final_errors`: targets spread over the head, reached by the joints alone (the
  calibration's registration), Certus-guided and Vicra-guided;
* `head_bump`: a 5 mm bump of the head at the target, Certus- or Vicra-guided at
  the slow speed: the error over time, the time until it is back within 0.5 mm of the
  error it had before the bump (that error is the calibration's floor, ~0.5 mm),
  the fastest command step;
* `swap_transient`: the Certus gives way to the Vicra mid-path at 7.5 and 10 cm/s;
  the transient is the farthest the real TCP gets from the path the same run
  without the swap took (same noise), over the second after the swap (a distance
  to the path, not between equal times: being ahead or behind along it is none);
  over several seeds, as the Vicra's noise makes each swap different; with a
  noise-free Vicra (`quiet`), what the swap itself adds.

The simulated trackers' accuracy is white noise per frame, which the navigator's
filter averages away; a real tracker's volumetric accuracy (0.1 mm RMS Certus,
0.25 mm Vicra) is partly a bias over its volume that no filter removes, so real
guided errors would be larger by up to about those figures.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from components.domain import lwr4
from components.domain.geometry import invert, pose_matrix
from components.domain.procedure import load_procedure, pose_from
from components.domain.rigs import Rig, standard_rigs
from components.domain.sensors import load_sensors
from components.robot.interpolator import InterpolatorCore, Phase
from components.robot.navigation import core_for
from components.sim.arm import SimulatedArm
from fw_bench.files import seeg_file

TARGET_IN_BASE = (0.60, 0.0, 0.12)
"""The procedure's target where the head rests (base frame, tool pointing down)."""


@dataclasses.dataclass
class Run:
    """One approach: the real arm, its interpolator, the navigator, the trackers."""

    target: np.ndarray  # on the patient (the master reference tool's frame)
    tracker: str | None  # whose samples steer (None: the joints alone)
    velocity: float
    seed: int = 0
    head: Callable[[float], np.ndarray] | None = None  # t -> head offset (m, base)
    quiet: tuple[str, ...] = ()  # trackers whose noise is left out

    def __post_init__(self) -> None:
        procedure = load_procedure(seeg_file("procedures", "seeg.yaml"))
        self.nav = core_for(
            procedure, load_sensors(seeg_file("procedures", "seeg", "sensors.yaml"))
        )
        self.arm = SimulatedArm(lwr4.HOME, errors=lwr4.LWR4_ERRORS)
        self.arm.release()
        self.kinematics = lwr4.Kinematics()
        self.core = InterpolatorCore(
            self.arm.q,
            velocity=self.velocity,
            acceleration=procedure.acceleration,
            brake_acceleration=procedure.brake_acceleration,
        )
        self.rigs = {
            rig.name: dataclasses.replace(rig, noise=0.0) if rig.name in self.quiet else rig
            for rig in standard_rigs()
        }
        self.rng = np.random.default_rng(self.seed)
        self.t = 0.0
        self.commands: list[np.ndarray] = []
        self.errors: list[float] = []
        self.real: list[np.ndarray] = []

    def base_from_rto(self) -> np.ndarray:
        """Where the head's reference tool truly is now."""
        out = invert(self.rigs["certus"].rto_from_base)
        if self.head is not None:
            out[:3, 3] += self.head(self.t)
        return out

    def true_target(self) -> np.ndarray:
        return self.base_from_rto() @ self.target

    def error(self) -> float:
        """The real TCP's distance to the target where the head is now (m)."""
        return float(np.linalg.norm(self.arm.tcp()[:3, 3] - self.true_target()[:3, 3]))

    def _sample(self, rig: Rig) -> None:
        cto, rto = rig.observe(self.arm.tcp(), self.rng, self.t, base_from_rto=self.base_from_rto())
        base_from_ee = self.kinematics.tcp(self.arm.q)
        noise = float(np.hypot(cto.rms, rto.rms))
        self.nav.offer(rig.name, pose_matrix(cto), pose_matrix(rto), base_from_ee, self.t, noise)

    def start(self) -> Run:
        self.core.go_to(self.nav.goal(self.target))
        return self

    def run(self, seconds: float) -> Run:
        """Step `seconds` of 1 ms cycles, the tracker in use sampling at its rate."""
        for _ in range(round(seconds * 1000)):
            cycle = round(self.t * 1000)
            if self.tracker is not None:
                rig = self.rigs[self.tracker]
                if cycle % round(1000 / rig.rate) == 0:
                    self._sample(rig)
                    self.core.steer(self.nav.goal(self.target))
            q = self.core.step()
            self.arm.command(q)
            self.arm.step()
            self.commands.append(self.core.pose[:3, 3].copy())
            self.real.append(self.arm.tcp()[:3, 3].copy())
            self.errors.append(self.error())
            self.t += 0.001
        return self

    def until_reached(self, limit: float = 20.0) -> Run:
        while self.core.phase is not Phase.REACHED and self.t < limit:
            self.run(0.1)
        return self

    def fastest_command(self, since: int = 0) -> float:
        """The fastest the command moved over one cycle (m/s), from cycle `since`."""
        steps = np.linalg.norm(
            np.diff(np.array(self.commands[max(0, since - 1) :]), axis=0), axis=1
        )
        return float(steps.max()) * 1000


def targets(count: int, seed: int = 11) -> list[np.ndarray]:
    """Targets over the head (on the patient): within 4 cm of the procedure's, the
    tool tilted up to 10 deg from pointing down."""
    rng = np.random.default_rng(seed)
    rto_from_base = standard_rigs()[0].rto_from_base
    out = []
    for _ in range(count):
        position = np.array(TARGET_IN_BASE) + rng.uniform(-1, 1, 3) * (0.04, 0.04, 0.02)
        tilt = rng.uniform(-10, 10, 3)
        base = pose_from(tuple(position), (tilt[0], 180 + tilt[1], tilt[2]))
        out.append(rto_from_base @ base)
    return out


def final_errors(count: int, progress: Any = None) -> dict[str, list[float]]:
    """The real TCP's error at rest on each target (mm), by who steers."""
    out: dict[str, list[float]] = {"joints": [], "certus": [], "vicra": []}
    for k, target in enumerate(targets(count)):
        for mode in out:
            run = Run(target, None if mode == "joints" else mode, 0.075, seed=k)
            run.start().until_reached().run(1.0)
            out[mode].append(run.error() * 1e3)
        if progress:
            progress(k + 1, count)
    return out


def head_bump(seed: int = 0, bump: float = 0.005, tracker: str = "certus") -> dict[str, Any]:
    """An approach guided by `tracker`, slow near the target; the head is bumped `bump`
    m sideways once the TCP is there: the error over time and how long it took to be
    back within 0.5 mm of the error before the bump."""
    target = targets(1)[0]
    run = Run(target, tracker, 0.075, seed=seed)
    run.start().run(2.0)
    run.core.set_limits(0.01)  # the critical area's speed
    run.until_reached().run(0.5)
    t_bump = run.t
    settled = run.error() * 1e3  # the error floor: the calibration's, mostly Y's
    run.head = lambda t: np.array([0.0, bump if t >= t_bump else 0.0, 0.0])
    before = len(run.errors)
    run.run(3.0)
    after = np.array(run.errors[before:]) * 1e3
    outside = np.flatnonzero(after > settled + 0.5)
    recovered = (outside[-1] + 1) / 1000.0 if len(outside) else 0.0
    return {
        "t": [round(i / 1000.0, 3) for i in range(0, len(after), 10)],
        "error_mm": [round(float(v), 4) for v in after[::10]],
        "recovery_s": float(recovered),
        "before_mm": settled,
        "peak_mm": float(after.max()),
        "final_mm": float(after[-1]),
        "fastest_command_m_s": run.fastest_command(before),
        "refused": run.nav.refused,
    }


def breathing(tracker: str, seed: int = 0, amplitude: float = 0.001, period: float = 4.0) -> float:
    """Holding the target, guided by `tracker`, while the head rises and falls
    `amplitude` m every `period` s: the largest error over the last 4 s of 8 (mm), the
    price of the filter that keeps the tracker's noise from the goals."""
    run = Run(targets(1)[0], tracker, 0.075, seed=seed)
    run.start().run(2.0)
    run.core.set_limits(0.01)
    run.until_reached().run(0.5)
    t0 = run.t
    run.head = lambda t: np.array([0.0, 0.0, amplitude * math.sin(2 * math.pi * (t - t0) / period)])
    start = len(run.errors)
    run.run(8.0)
    return float(max(run.errors[start + 4000 :])) * 1e3


def swap_transient(
    velocity: float, seed: int = 0, trace: bool = False, quiet: bool = False
) -> dict[str, Any]:
    """The Certus gives way to the Vicra 1 s into a motion at `velocity`: how far the
    real TCP gets from the path of the same run without the swap, over the next
    second (mm). The swap-free run goes on half a second longer, so that a swapped run
    ahead along the path is not counted as off it. With `trace`, both runs' real TCP
    on the patient (the target's frame, mm) every 10 ms, for the figure."""
    target = pose_from(TARGET_IN_BASE, (0, 180, 0))
    on_patient = standard_rigs()[0].rto_from_base @ target
    runs = []
    for swap in (False, True):
        run = Run(on_patient, "certus", velocity, seed=seed, quiet=("vicra",) if quiet else ())
        run.start().run(1.0)
        mark = len(run.real)
        if swap:
            run.tracker = "vicra"
        run.run(1.0 if swap else 1.5)
        runs.append((run, mark))
    (plain, mark), (swapped, _) = runs
    path = np.array(plain.real[mark - 200 :])  # the path the swap-free run took
    apart = np.array([np.linalg.norm(path - point, axis=1).min() for point in swapped.real[mark:]])
    out: dict[str, Any] = {
        "speed_cm_s": velocity * 100,
        "seed": seed,
        "transient_mm": float(apart.max()) * 1e3,
        "fastest_command_m_s": swapped.fastest_command(),
    }
    if trace:
        target_from_base = invert(plain.true_target())  # the head does not move here

        def on_target(points: list[np.ndarray]) -> list[list[float]]:
            return [
                [
                    round(float(v) * 1e3, 4)
                    for v in target_from_base[:3, :3] @ p + target_from_base[:3, 3]
                ]
                for p in points[: len(swapped.real) : 10]
            ]

        out["trace"] = {
            "t": [round(i * 0.001, 3) for i in range(0, len(swapped.real), 10)],
            "swap_t": mark * 0.001,
            "without_swap_mm": on_target(plain.real),
            "with_swap_mm": on_target(swapped.real),
        }
    return out


def untracked_motion(velocity: float, swap_latency_ms: float, rate: float = 100.0) -> float:
    """How far the arm moves (mm) between the in-use tracker's last good frame and the
    next tracker steering: the frame in which the tool went MISSING (one period of the
    tracker) plus the swap's latency (thesis: < 2 mm at 10 cm/s)."""
    return velocity * (1.0 / rate + swap_latency_ms / 1000.0) * 1e3
