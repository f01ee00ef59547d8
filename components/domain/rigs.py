"""A synthetic tracking world with known truth: trackers, tools, a moving robot.

Used by the simulated Certus, the Sensor Manager's tests and benchmarks, and the
calibration benchmarks: every transform is known, so every estimate can be checked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from components.domain.geometry import invert, matrix_to_quat, rigid
from components.domain.sensors import SensorConfig, SensorsConfig
from framework.messages import Pose


@dataclass
class Rig:
    """One tracker's geometry: where the reference tool is in its frame, where the robot
    base is from the reference tool, where its CTO markers sit on the end-effector."""

    name: str
    sensor_from_rto: np.ndarray
    rto_from_base: np.ndarray
    ee_from_cto: np.ndarray
    noise: float  # 3-D RMS, m
    rate: float

    @property
    def sensor_from_base(self) -> np.ndarray:
        """Where the robot base is in the tracker's frame (both stand still in the room)."""
        return self.sensor_from_rto @ self.rto_from_base

    def observe(
        self,
        base_from_ee: np.ndarray,
        rng: np.random.Generator,
        stamp: float = 0.0,
        frame: int = 0,
        base_from_rto: np.ndarray | None = None,
    ) -> tuple[Pose, Pose]:
        """(CTO, RTO) as the tracker reports them, with its noise. `base_from_rto`: where
        the reference tool is now, if the patient's head moved it (default: where it was
        when the rig was set up)."""
        sensor_from_base = self.sensor_from_base
        rto = self.sensor_from_rto if base_from_rto is None else sensor_from_base @ base_from_rto
        cto = sensor_from_base @ base_from_ee @ self.ee_from_cto
        return (
            self._pose(cto, rng, stamp, frame, "cto"),
            self._pose(rto, rng, stamp, frame, "rto"),
        )

    def _pose(
        self, t: np.ndarray, rng: np.random.Generator, stamp: float, frame: int, tool: str
    ) -> Pose:
        noise = rng.normal(0.0, self.noise / np.sqrt(3.0), 3) if self.noise else np.zeros(3)
        position = tuple(float(v) for v in t[:3, 3] + noise)
        return Pose(
            position, matrix_to_quat(t[:3, :3]), stamp, self.noise, frame, True, self.name, tool
        )


def standard_rigs() -> list[Rig]:
    """The thesis setup: a Certus (master, 100 Hz, 0.1 mm) and a Vicra (20 Hz, 0.25 mm)."""
    # the reference tool lies on the table beside the patient's head (components.sim.scene)
    rto_from_base = invert(rigid((0.45, -0.30, -0.06), (0.0, 0.0, 0.3)))
    return [
        Rig(
            "certus",
            # on a stand 1.6 m above the robot base and 1.6 m to its side, looking down at
            # the table (2.2 m away, inside the Certus's 1.5-7 m volume)
            rigid((-0.0525, 0.3293, 2.0873), (2.2691, -0.5253, 0.2295)),
            rto_from_base,
            rigid((0.0, 0.02, 0.08), (0.0, 0.1, 0.0)),
            0.0001,
            100.0,
        ),
        Rig(
            "vicra",
            # the Vicra looks down obliquely at the table: the reference tool and the
            # robot's tool from home to target, with 4 cm to spare, fit its pyramid
            rigid((0.1, 0.0241, 1.1927), (-2.0912, 1.2074, 0.5001)),
            rto_from_base,
            rigid((0.01, -0.03, 0.07), (0.0, -0.1, 0.2)),
            0.00025,
            20.0,
        ),
    ]


def sensors_config(
    rigs: list[Rig], hysteresis: int = 5, camera: bool = False, **overrides: float
) -> SensorsConfig:
    """A Sensor Manager configuration with the exact calibration of these rigs; with
    `camera`, each tracker's calibration to the robot base (S) too."""
    master = rigs[0]
    sensors = []
    for priority, rig in enumerate(rigs, start=1):
        sensors.append(
            SensorConfig(
                name=rig.name,
                priority=priority,
                rate=rig.rate,
                master_from_sensor=master.rto_from_base @ invert(rig.rto_from_base),
                rto_from_base=rig.rto_from_base,
                ee_from_cto=rig.ee_from_cto,
                sensor_from_base=rig.sensor_from_base if camera else None,
                limits={"max_velocity": 0.10, "max_acceleration": 0.5},
                **overrides,
            )
        )
    return SensorsConfig(sensors, hysteresis, master.name)


def ee_path(t: float) -> np.ndarray:
    """A slow end-effector motion in the robot base frame (m, rad)."""
    return rigid(
        (0.5 + 0.05 * np.sin(0.5 * t), 0.1 * np.cos(0.3 * t), 0.4 + 0.02 * np.sin(0.1 * t)),
        (0.0, np.pi / 2 + 0.1 * np.sin(0.2 * t), 0.0),
    )
