"""The sensors file: the trackers the Sensor Manager chooses from, their priorities,
rates, tolerances, limits and calibration frames (thesis 3.3.4). Shared by the Sensor
Manager, the navigator and the simulated rigs; read with file:line errors."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from components.domain.geometry import as_matrix
from framework import schema
from framework.errors import LocatedError
from framework.filekinds import FileKind, schema_then
from framework.yamlio import load_yaml

SCHEMA = "components.domain:sensors.schema.json"


class SensorConfigError(LocatedError):
    """A sensors file is wrong (the message names file:line and the field)."""


@dataclass
class SensorConfig:
    """One tracker as the Sensor Manager knows it."""

    name: str
    priority: int
    rate: float
    stale_periods: float = 2.0
    max_speed: float = 1.0
    tolerance_position: float = 0.005
    tolerance_angle: float = math.radians(3.0)
    limits: dict[str, float] = field(default_factory=dict)
    master_from_sensor: np.ndarray = field(default_factory=lambda: np.eye(4))  # C_i
    rto_from_base: np.ndarray = field(default_factory=lambda: np.eye(4))  # X_i
    ee_from_cto: np.ndarray = field(default_factory=lambda: np.eye(4))  # Y_i
    sensor_from_base: np.ndarray | None = None  # S_i: the tracker's calibration to the robot
    tip: np.ndarray | None = None  # the TCP in the CTO frame, from pivoting (m)

    @property
    def cto_from_ee(self) -> np.ndarray:
        """The end-effector in the CTO frame: Y^-1, its translation the TCP pivoting
        found (`tip`) where there is one (the hand-eye fit's is less exact)."""
        out = np.linalg.inv(self.ee_from_cto)
        if self.tip is not None:
            out[:3, 3] = self.tip
        return out


@dataclass
class SensorsConfig:
    """All sensors, in priority order, and the re-entry hysteresis."""

    sensors: list[SensorConfig]
    hysteresis: int = 5
    master: str = ""


def load_sensors(path: str | Path) -> SensorsConfig:
    """Read a sensors YAML; every error names file:line and the field."""
    doc = load_yaml(path)
    schema.refuse_retired(
        doc,
        "sensors",
        "keys",
        SensorConfigError,
        lambda name: (
            f"sensor {name!r}: 'keys' are no longer read: the topology wires the "
            f"Sensor Manager's ports {name}_cto and {name}_rto (connections:), so "
            "fw validate and fw ls see them; delete 'keys' here"
        ),
    )
    schema.require(doc, SCHEMA, SensorConfigError)
    data = doc.data

    def fail(message: str, where: tuple[Any, ...]) -> SensorConfigError:
        return SensorConfigError(message, doc.location(where))

    sensors = []
    for name, spec in data["sensors"].items():
        here = ("sensors", name)
        calibration = spec.get("calibration") or {}
        frames = {}
        for frame in ("C", "X", "Y", "S"):
            if frame == "S" and frame not in calibration:
                frames[frame] = None
                continue
            try:
                frames[frame] = as_matrix(calibration.get(frame, np.eye(4).tolist()))
            except ValueError as exc:
                raise fail(str(exc), (*here, "calibration", frame)) from None
        tolerance = spec.get("tolerance") or {}
        tip = calibration.get("tip")  # finite: the schema says so
        sensors.append(
            SensorConfig(
                name=name,
                priority=spec["priority"],
                rate=float(spec["rate"]),
                stale_periods=float(spec.get("stale_periods", SensorConfig.stale_periods)),
                max_speed=float(spec.get("max_speed", SensorConfig.max_speed)),
                tolerance_position=float(
                    tolerance.get("position", SensorConfig.tolerance_position)
                ),
                tolerance_angle=math.radians(
                    float(tolerance.get("angle_deg", math.degrees(SensorConfig.tolerance_angle)))
                ),
                limits={k: float(v) for k, v in (spec.get("limits") or {}).items()},
                master_from_sensor=frames["C"],
                rto_from_base=frames["X"],
                ee_from_cto=frames["Y"],
                sensor_from_base=frames["S"],
                tip=None if tip is None else np.array(tip, dtype=float),
            )
        )
    priorities = [s.priority for s in sensors]
    if len(set(priorities)) != len(priorities):
        raise fail("two sensors share a priority: make the order explicit", ("sensors",))
    sensors.sort(key=lambda s: s.priority)
    hysteresis = data.get("hysteresis", SensorsConfig.hysteresis)  # the schema says >= 1
    master = data.get("master", sensors[0].name)
    if master not in {s.name for s in sensors}:
        raise fail(f"master {master!r} is not one of the sensors", ("master",))
    return SensorsConfig(sensors, hysteresis, master)


SENSORS_FILE = FileKind(
    "sensors",
    "sensors",
    "the trackers the Sensor Manager chooses from (limits, calibration)",
    schema_then(SCHEMA, load_sensors, "sensors"),
)
