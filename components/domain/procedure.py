"""A procedure file (`procedures/seeg.yaml`): goals, areas and speeds of one surgery.

Read by the Supervisor and the Cartesian interpolator; every error names
file:line and the field, and nothing is half-loaded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from framework import schema
from framework.errors import FwError, LocatedError
from framework.filekinds import FileKind, schema_then
from framework.yamlio import load_yaml

SCHEMA = "components.domain:procedure.schema.json"
FRAMES = ("base", "patient")
"""The frames a goal may be given in: the robot base, or the reference tool on the head
clamp (the master tracker's), which moves with the patient."""


class ProcedureError(LocatedError):
    """A procedure file is wrong (file:line and the field in the message)."""


@dataclass(frozen=True)
class Speeds:
    """Path speeds (m/s) while one tracker is in use."""

    fast: float
    slow: float


@dataclass(frozen=True)
class Navigation:
    """How the tracked patient steers the robot (components/robot/navigation.py)."""

    smoothing: float = 0.1  # s
    max_patient_motion: float = 0.01  # m from where the patient was registered
    max_patient_speed: float = 0.008  # m/s, over the last second
    confirm: float = 0.3  # s a motion beyond the limits persists before it is refused
    jitter: float = 0.0001  # m RMS of a tracker's noise let through to the goals
    max_model_error: float = 0.005  # m the arm's model may be off, beyond the patient's motion


@dataclass
class Procedure:
    """What the Supervisor and the interpolator need to know about the surgery."""

    name: str
    goals: dict[str, np.ndarray]  # name -> 4x4 pose in its frame (`frames`)
    critical_radius: float
    target_tolerance: float
    acceleration: float
    brake_acceleration: float
    max_near: int
    collision_distance: float
    speeds: dict[str, Speeds] = field(default_factory=dict)
    frames: dict[str, str] = field(default_factory=dict)  # name -> "base" (default) or "patient"
    navigation: Navigation = field(default_factory=Navigation)

    def frame(self, goal: str) -> str:
        """The frame a goal is given in: "base" or "patient"."""
        return self.frames.get(goal, "base")

    @property
    def target(self) -> np.ndarray:
        """The target pose (4x4)."""
        return self.goals["target"]

    @property
    def slowest(self) -> float:
        """The slowest speed of any tracker (m/s): the speed when nobody has said which
        tracker guides the robot."""
        return min(s.slow for s in self.speeds.values())

    def define_target(self, position: Any, rpy_deg: Any, frame: str = "base") -> np.ndarray:
        """Replace the target (m, deg) given in `frame` (base or patient); `FwError` for a
        pose that is not one or an unknown frame."""
        if frame not in FRAMES:
            raise FwError(f"target refused: frame {frame!r} is not one of {', '.join(FRAMES)}")
        try:
            self.goals["target"] = pose_from(position, rpy_deg)
        except ValueError as exc:
            raise FwError(f"target refused: {exc}") from None
        self.frames["target"] = frame
        return self.goals["target"]


def pose_from(position: Any, rpy_deg: Any) -> np.ndarray:
    """A 4x4 pose from a position (m) and roll-pitch-yaw angles (deg)."""
    p = [float(v) for v in position]
    r = [float(v) for v in rpy_deg]
    if len(p) != 3 or len(r) != 3 or not all(math.isfinite(v) for v in p + r):
        raise ValueError("a pose needs 3 finite position values and 3 finite angles")
    out = np.eye(4)
    out[:3, :3] = rpy_matrix(*(math.radians(v) for v in r))
    out[:3, 3] = p
    return out


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation of fixed-axis roll, pitch, yaw (rad): Rz(yaw) Ry(pitch) Rx(roll). (In
    numpy, not scipy: the supervision process then does not load scipy at all, which
    keeps it small, and a small process dies, and is seen dead, faster.)"""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def load_procedure(path: str | Path) -> Procedure:
    """Read and check a procedure file."""
    doc = load_yaml(path)
    schema.require(doc, SCHEMA, ProcedureError)
    data = doc.data

    def fail(message: str, *where: Any) -> ProcedureError:
        return ProcedureError(message, doc.location(where))

    def number(key: str, default: float | None = None, positive: bool = True) -> float:
        value = data.get(key, default)
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise fail(f"`{key}` must be a number", key)
        if positive and value <= 0:
            raise fail(f"`{key}` must be positive", key)
        return float(value)

    goals, frames = {}, {}
    for name in ("target", "home"):
        spec = data.get(name)
        if not isinstance(spec, dict) or "position" not in spec:
            raise fail(f"`{name}` needs a position (m) and rpy_deg (deg)", name)
        try:
            goals[name] = pose_from(spec["position"], spec.get("rpy_deg", (0, 0, 0)))
        except (TypeError, ValueError) as exc:
            raise fail(f"`{name}`: {exc}", name) from None
        frames[name] = spec.get("frame", "base")
    navigation = data.get("navigation") or {}
    defaults = Navigation()
    people = data.get("people", {}) or {}
    if not isinstance(people, dict):
        raise fail("`people` is a mapping (max_near, collision_distance)", "people")
    max_near = people.get("max_near", 2)
    if isinstance(max_near, bool) or not isinstance(max_near, int) or max_near < 0:
        raise fail("`max_near` is a whole number of people >= 0", "people", "max_near")
    collision = people.get("collision_distance", 0.10)
    if isinstance(collision, bool) or not isinstance(collision, int | float) or collision < 0:
        raise fail("`collision_distance` is a distance >= 0 (m)", "people", "collision_distance")
    trackers = data.get("trackers")
    if not isinstance(trackers, dict) or not trackers:
        raise fail("`trackers` maps each tracker to its fast and slow speeds (m/s)", "trackers")
    speeds = {}
    for tracker, spec in trackers.items():
        try:
            fast, slow = float(spec["fast"]), float(spec["slow"])
        except (TypeError, KeyError, ValueError):
            raise fail(
                f"tracker {tracker!r} needs `fast` and `slow` (m/s)", "trackers", tracker
            ) from None
        if not (0 < slow <= fast <= 0.25):
            raise fail(
                f"tracker {tracker!r}: need 0 < slow <= fast <= 0.25 m/s", "trackers", tracker
            )
        speeds[str(tracker)] = Speeds(fast, slow)
    return Procedure(
        name=str(data.get("procedure", Path(path).stem)),
        goals=goals,
        critical_radius=number("critical_radius", 0.05),
        target_tolerance=number("target_tolerance", 0.0005),
        acceleration=number("acceleration", 0.25),
        brake_acceleration=number("brake_acceleration", 2.0),
        max_near=max_near,
        collision_distance=float(collision),
        speeds=speeds,
        frames=frames,
        navigation=Navigation(
            float(navigation.get("smoothing", defaults.smoothing)),
            float(navigation.get("max_patient_motion", defaults.max_patient_motion)),
            float(navigation.get("max_patient_speed", defaults.max_patient_speed)),
            float(navigation.get("confirm", defaults.confirm)),
            float(navigation.get("jitter", defaults.jitter)),
            float(navigation.get("max_model_error", defaults.max_model_error)),
        ),
    )


PROCEDURE_FILE = FileKind(
    "procedure",
    "procedure",
    "goals, areas and speeds of one surgery (Supervisor, interpolator)",
    schema_then(SCHEMA, load_procedure, "procedure"),
)
