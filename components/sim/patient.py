"""The simulated patient's head, with the reference tool on its head clamp.

The reference tool (RTO) is screwed to the head clamp, so where the RTO goes the
head and the target on the skull go too: the trackers see the head move through
it. `HeadMotion` is the motion as a function of time, composed of what a
scenario asks for (thesis 3.2: motion compensation of the patient's head):

* **drift**: a slow constant velocity (the head settling in the clamp);
* **bump**: a displacement reached along a smooth (cosine) ramp of `duration`
  (someone knocks the table: 5 mm in 50 ms);
* **breathing**: a sinusoid of an amplitude and a period along an axis.

Offsets are translations in the robot base frame; the head does not rotate (a
rotation of the clamp would be a larger accident than the ones simulated).
`PatientHead` publishes the RTO's pose in the robot base frame on `pose` at its
activity's rate; the simulated trackers observe the RTO there. Given the real arm's
TCP (`tcp`, the simulation's ground truth) and the procedure, it is also the
referee of navigation: `report()` says how far the real TCP is from the target on
the head, which no component of the deployment can know.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from components.domain.geometry import invert, matrix_to_quat, norm, pose_from_list, pose_matrix
from components.domain.rigs import standard_rigs
from framework.component import Component, In, Out, operation
from framework.errors import FwError
from framework.messages import EventMessage, Pose
from framework.ports import ReadStatus
from framework.properties import prop


@dataclass(frozen=True)
class Bump:
    """A displacement `offset` (m) reached from `start` (s) along a cosine ramp."""

    start: float
    offset: tuple[float, float, float]
    duration: float

    def at(self, t: float) -> np.ndarray:
        """The part of the offset done at time `t`."""
        if t <= self.start:
            return np.zeros(3)
        elapsed = t - self.start
        u = 1.0 if elapsed >= self.duration else elapsed / self.duration
        return np.asarray(self.offset) * (0.5 - 0.5 * math.cos(math.pi * u))


@dataclass
class HeadMotion:
    """The head's translation (m, base frame) as a function of time (s)."""

    settled: np.ndarray = field(default_factory=lambda: np.zeros(3))  # from ended motions
    drift_since: float = 0.0
    drift_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bumps: list[Bump] = field(default_factory=list)
    breathing: tuple[float, float, np.ndarray] | None = None  # amplitude, period, axis

    def offset(self, t: float) -> np.ndarray:
        """Where the head is at `t`, relative to where it started."""
        out = self.settled + self.drift_velocity * max(0.0, t - self.drift_since)
        for bump in self.bumps:
            out = out + bump.at(t)
        if self.breathing is not None:
            amplitude, period, axis = self.breathing
            out = out + axis * amplitude * math.sin(2.0 * math.pi * t / period)
        return out

    def drift(self, t: float, velocity: tuple[float, float, float]) -> None:
        """From `t`, drift at `velocity` (m/s); a zero velocity stops the drift."""
        self.settled = self.settled + self.drift_velocity * max(0.0, t - self.drift_since)
        self.drift_since = t
        self.drift_velocity = np.asarray(velocity, dtype=float)

    def bump(self, t: float, offset: tuple[float, float, float], duration: float) -> None:
        """From `t`, move by `offset` (m) within `duration` (s)."""
        self.bumps.append(Bump(t, tuple(float(v) for v in offset), duration))  # type: ignore[arg-type]

    def breathe(self, amplitude: float, period: float, axis: tuple[float, float, float]) -> None:
        """A sinusoidal motion (m, s) along `axis`; amplitude 0 stops it."""
        direction = np.asarray(axis, dtype=float)
        length = norm(direction)
        if amplitude == 0.0:
            self.breathing = None
            return
        if not (length > 0 and period > 0 and math.isfinite(amplitude)):
            raise ValueError("breathing needs a non-zero axis and a positive period")
        self.breathing = (amplitude, period, direction / length)


def _finite(name: str, values: Any, count: int = 3) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if len(out) != count or not all(math.isfinite(v) for v in out):
        raise FwError(f"{name} needs {count} finite numbers, got {values!r}")
    return out


class PatientHead(Component):
    """Publishes the reference tool on the head clamp (robot base frame) as the head
    moves; scenarios move it by operations (module docstring)."""

    procedure_file = prop(
        str,
        "",
        doc="procedure YAML whose target on the patient is refereed ('': none)",
        file="procedure",
    )
    pose = Out(Pose, doc="the reference tool on the head clamp, robot base frame")
    tcp = In(Pose, doc="the real arm's TCP (ground truth), for the referee")
    goals = In(
        EventMessage,
        doc="the navigator's goals: the target as the operator defined it last (the "
        "referee scores the approach against the current target, not the file's)",
    )

    def __init__(self, name: str):
        super().__init__(name)
        self.motion: HeadMotion | None = None
        """How the head moves, made by `configure`."""

    def configure_hook(self) -> bool:
        self.home = invert(standard_rigs()[0].rto_from_base)  # base_from_rto at rest
        self.motion = HeadMotion()
        self.frame_number = 0
        self.target: np.ndarray | None = None  # where the target is...
        self.target_frame = "patient"  # ...on the patient, or in the robot base
        if self.procedure_file:
            from components.domain.procedure import load_procedure

            procedure = load_procedure(self.procedure_file)
            self.target, self.target_frame = procedure.target, procedure.frame("target")
        return True

    def target_error(self) -> float | None:
        """How far (m) the real TCP is from the target now (None: unknown): the target
        as the navigator last said it was defined (`e_DEFINE_TARGET`), else the
        procedure file's; on the head, it moves with the head."""
        self._follow_target()
        status, tcp = self.tcp.read()
        if self.target is None or status is ReadStatus.NO_DATA or tcp is None:
            return None
        target = (
            self.base_from_rto() @ self.target if self.target_frame == "patient" else self.target
        )
        return norm(pose_matrix(tcp)[:3, 3] - target[:3, 3])

    def _follow_target(self) -> None:
        """Take the target the navigator's latest goals say was defined."""
        status, goals = self.goals.read()
        if status is not ReadStatus.NEW or goals is None:
            return
        defined = goals.payload.get("target")
        if not isinstance(defined, dict) or defined.get("frame") not in ("patient", "base"):
            return
        try:
            self.target = pose_from_list(defined.get("pose"))
        except (TypeError, ValueError):
            self.refuse("goals", f"a target that is not a pose: {defined.get('pose')!r:.80}")
            return
        self.target_frame = defined["frame"]

    def base_from_rto(self, t: float | None = None) -> np.ndarray:
        """The reference tool's pose in the robot base frame at `t` (default: now)."""
        out = self.home.copy()
        out[:3, 3] += self.motion.offset(self.clock.now() if t is None else t)
        return out

    def update_hook(self) -> None:
        pose = self.base_from_rto()
        self.frame_number += 1
        self.pose.write(
            Pose(
                tuple(float(v) for v in pose[:3, 3]),  # type: ignore[arg-type]
                matrix_to_quat(pose[:3, :3]),
                time.time(),
                0.0,
                self.frame_number,
                True,
                "base",
                "rto",
            )
        )

    @operation
    def drift(self, vx: float = 0.0, vy: float = 0.0, vz: float = 0.0) -> dict[str, Any]:
        """Drift at (vx, vy, vz) mm/s from now on (all zero: stop drifting)."""
        velocity = _finite("drift", (vx, vy, vz))
        self.motion.drift(self.clock.now(), tuple(v / 1000.0 for v in velocity))  # type: ignore[arg-type]
        return self.report()

    @operation
    def bump(
        self, dx: float = 0.0, dy: float = 0.0, dz: float = 0.0, duration_ms: float = 50.0
    ) -> dict[str, Any]:
        """Move the head by (dx, dy, dz) mm within `duration_ms` (a knock on the table)."""
        offset = _finite("bump", (dx, dy, dz))
        if not (math.isfinite(duration_ms) and duration_ms >= 0):
            raise FwError(f"duration_ms must be >= 0, got {duration_ms!r}")
        self.motion.bump(
            self.clock.now(),
            tuple(v / 1000.0 for v in offset),  # type: ignore[arg-type]
            duration_ms / 1000.0,
        )
        return self.report()

    @operation
    def breathe(
        self, amplitude_mm: float = 1.0, period_s: float = 4.0, axis: list[float] | None = None
    ) -> dict[str, Any]:
        """Breathing-like motion along `axis` (default: up); amplitude 0 stops it."""
        try:
            self.motion.breathe(
                amplitude_mm / 1000.0, float(period_s), _finite("axis", axis or (0, 0, 1))
            )
        except ValueError as exc:
            raise FwError(str(exc)) from None
        return self.report()

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """How far the head is from where it started (mm) and what moves it."""
        motion = self.motion
        if motion is None:
            return {"offset_mm": [0.0, 0.0, 0.0]}
        offset = motion.offset(self.clock.now())
        error = self.target_error()
        return {
            "target_error_mm": None if error is None else round(error * 1000.0, 3),
            "offset_mm": [round(float(v) * 1000.0, 3) for v in offset],
            "drift_mm_s": [round(float(v) * 1000.0, 3) for v in motion.drift_velocity],
            "bumps": len(motion.bumps),
            "breathing": motion.breathing is not None,
        }
