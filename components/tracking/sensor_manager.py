"""The Sensor Manager (thesis 3.3.4, Fig. 3.13): which tracker can be trusted now.

For every sensor, each cycle, the fault tree of 3.3.3 in its order:

1. `cto_missing` / `rto_missing`: the device reports the tool MISSING
   (occlusion, out of the field of view);
2. `stale`: no new frame for `stale_periods` periods (driver crash, cable cut,
   power loss), or `no_data` before the first frame;
3. `corrupt`: NaN or non-unit quaternion, or an impossible jump of the CTO;
4. `calibration`: the robot pose this sensor gives disagrees, beyond the
   tolerance, with the prediction from the robot's kinematics and the
   calibration (the reference tool was moved); without kinematics, with the
   other healthy sensors (two sensors that disagree are both distrusted: the
   robot stops rather than follow the wrong one).

The first healthy sensor in priority order wins; a sensor that was unhealthy
(or at start) is used again only after `hysteresis` consecutive healthy
samples. Outputs: the best sensor or none, its velocity limits and
calibration, the robot pose in the master frame (eq. 3.5), every sensor's
health and cause.

`SensorManagerCore` is the deterministic logic (time is passed in); the
`SensorManager` component feeds it from ports.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from components.tracking.geometry import (
    as_matrix,
    invert,
    pose_matrix,
    rotation_angle,
)
from framework.component import Component, In, Out, operation
from framework.errors import FwError, Location
from framework.messages import EventMessage, Pose
from framework.ports import ConnPolicy, InputPort, ReadStatus
from framework.properties import prop
from framework.yamlio import load_yaml

CAUSES = ("no_data", "cto_missing", "rto_missing", "stale", "corrupt", "calibration")


class SensorConfigError(FwError):
    """A sensors file is wrong (the message names file:line and the field)."""


@dataclass
class SensorConfig:
    """One tracker as the Sensor Manager knows it."""

    name: str
    priority: int
    rate: float
    keys: dict[str, str]
    stale_periods: float = 2.0
    max_speed: float = 1.0
    tolerance_position: float = 0.005
    tolerance_angle: float = math.radians(3.0)
    limits: dict[str, float] = field(default_factory=dict)
    master_from_sensor: np.ndarray = field(default_factory=lambda: np.eye(4))  # C_i
    rto_from_base: np.ndarray = field(default_factory=lambda: np.eye(4))  # X_i
    ee_from_cto: np.ndarray = field(default_factory=lambda: np.eye(4))  # Y_i


@dataclass
class SensorsConfig:
    """All sensors, in priority order, and the re-entry hysteresis."""

    sensors: list[SensorConfig]
    hysteresis: int = 5
    master: str = ""


def load_sensors(path: str | Path) -> SensorsConfig:
    """Read a sensors YAML; every error names file:line and the field."""
    doc = load_yaml(path)
    data = doc.data if isinstance(doc.data, dict) else None

    def fail(message: str, where: tuple[Any, ...]) -> SensorConfigError:
        loc: Location = doc.location(where)
        return SensorConfigError(f"{loc}: {message}")

    if data is None or not isinstance(data.get("sensors"), dict) or not data["sensors"]:
        raise fail("a sensors file needs a `sensors:` mapping", ())
    sensors = []
    for name, spec in data["sensors"].items():
        here = ("sensors", name)
        if not isinstance(spec, dict):
            raise fail("a sensor is a mapping of settings", here)
        for required in ("priority", "rate", "keys"):
            if required not in spec:
                raise fail(f"sensor {name!r} needs `{required}`", here)
        keys = spec["keys"]
        if not (isinstance(keys, dict) and set(keys) == {"cto", "rto"}):
            raise fail("`keys` must map cto and rto to bus keys", (*here, "keys"))
        try:
            calibration = spec.get("calibration") or {}
            tolerance = spec.get("tolerance") or {}
            sensors.append(
                SensorConfig(
                    name=name,
                    priority=int(spec["priority"]),
                    rate=float(spec["rate"]),
                    keys=dict(keys),
                    stale_periods=float(spec.get("stale_periods", 2.0)),
                    max_speed=float(spec.get("max_speed", 1.0)),
                    tolerance_position=float(tolerance.get("position", 0.005)),
                    tolerance_angle=math.radians(float(tolerance.get("angle_deg", 3.0))),
                    limits={k: float(v) for k, v in (spec.get("limits") or {}).items()},
                    master_from_sensor=as_matrix(calibration.get("C", np.eye(4).tolist())),
                    rto_from_base=as_matrix(calibration.get("X", np.eye(4).tolist())),
                    ee_from_cto=as_matrix(calibration.get("Y", np.eye(4).tolist())),
                )
            )
        except (TypeError, ValueError) as exc:
            raise fail(f"sensor {name!r}: {exc}", here) from None
        if sensors[-1].rate <= 0:
            raise fail("`rate` must be positive (Hz)", (*here, "rate"))
    priorities = [s.priority for s in sensors]
    if len(set(priorities)) != len(priorities):
        raise fail("two sensors share a priority: make the order explicit", ("sensors",))
    sensors.sort(key=lambda s: s.priority)
    hysteresis = data.get("hysteresis", 5)
    if not isinstance(hysteresis, int) or hysteresis < 1:
        raise fail("`hysteresis` is a whole number of samples >= 1", ("hysteresis",))
    master = data.get("master", sensors[0].name)
    if master not in {s.name for s in sensors}:
        raise fail(f"master {master!r} is not one of the sensors", ("master",))
    return SensorsConfig(sensors, hysteresis, master)


@dataclass
class Health:
    """A sensor's verdict for one cycle."""

    ok: bool
    cause: str = ""
    detail: str = ""
    streak: int = 0


@dataclass
class _Track:
    config: SensorConfig
    cto: Pose | None = None
    rto: Pose | None = None
    cto_at: float = -math.inf
    rto_at: float = -math.inf
    previous_cto: Pose | None = None
    previous_cto_at: float = -math.inf
    fresh: bool = False
    streak: int = 0
    health: Health = field(default_factory=lambda: Health(False, "no_data"))


@dataclass
class Decision:
    """What one cycle decided."""

    best: str | None
    health: dict[str, Health]
    robot_pose: np.ndarray | None
    changed: bool


class SensorManagerCore:
    """The fault tree and the choice, without any I/O (time is an argument)."""

    def __init__(self, config: SensorsConfig):
        self.config = config
        self.tracks = [_Track(s) for s in config.sensors]
        self.by_name = {t.config.name: t for t in self.tracks}
        self.best: str | None = None
        self.kinematics: np.ndarray | None = None
        count = len(config.sensors)
        # latest CTO then RTO samples per sensor, as plain lists: one np.array per cycle is
        # cheaper than writing rows into arrays at every sample
        self._points: list[tuple[float, ...]] = [(0.0, 0.0, 0.0)] * (2 * count)
        self._quats: list[tuple[float, ...]] = [(0.0, 0.0, 0.0, 1.0)] * (2 * count)
        self._index = {s.name: i for i, s in enumerate(config.sensors)}
        self._all = np.arange(count)
        self._c = np.stack([s.master_from_sensor for s in config.sensors])
        self._x = np.stack([s.rto_from_base for s in config.sensors])
        self._tol_pos2 = np.array([s.tolerance_position**2 for s in config.sensors])
        self._tol_cos = np.cos([s.tolerance_angle for s in config.sensors])
        self._y = np.stack([s.ee_from_cto for s in config.sensors])
        self._y_inv = invert(np.stack([s.ee_from_cto for s in config.sensors]))
        self.last: Decision | None = None

    def offer(self, sensor: str, tool: str, pose: Pose, arrival: float) -> None:
        """A new sample of `tool` (cto/rto) from `sensor`, received at `arrival`."""
        track = self.by_name[sensor]
        row = self._index[sensor] + (0 if tool == "cto" else len(self.tracks))
        self._points[row] = pose.position
        w, x, y, z = pose.orientation
        self._quats[row] = (x, y, z, w)  # scipy's order
        if tool == "cto":
            if track.cto is not None:
                track.previous_cto, track.previous_cto_at = track.cto, track.cto_at
            track.cto, track.cto_at = pose, arrival
        else:
            track.rto, track.rto_at = pose, arrival
        track.fresh = True

    def set_kinematics(self, base_from_ee: np.ndarray | None) -> None:
        """The robot's end-effector in its base frame from joints (None: unknown)."""
        self.kinematics = base_from_ee

    def _basic(self, track: _Track, now: float) -> Health:
        """Fault-tree levels 1-3 (missing, stale, corrupt)."""
        cfg = track.config
        if track.cto is None or track.rto is None:
            return Health(False, "no_data", "no frame yet")
        if not track.cto.valid:
            return Health(False, "cto_missing", "the robot's tool is not seen")
        if not track.rto.valid:
            return Health(False, "rto_missing", "the reference tool is not seen")
        limit = cfg.stale_periods / cfg.rate
        age = now - min(track.cto_at, track.rto_at)
        if age > limit:
            return Health(
                False, "stale", f"no new frame for {age * 1e3:.0f} ms (limit {limit * 1e3:.0f} ms)"
            )
        for pose in (track.cto, track.rto):
            w, x, y, z = pose.orientation
            px, py, pz = pose.position
            norm2 = w * w + x * x + y * y + z * z
            if not math.isfinite(px + py + pz + norm2) or abs(norm2 - 1.0) > 2e-3:
                return Health(False, "corrupt", f"{pose.tool}: not a finite unit pose")
        previous = track.previous_cto
        if previous is not None and previous.valid and math.isfinite(sum(previous.position)):
            dt = max(track.cto_at - track.previous_cto_at, 1.0 / cfg.rate)
            jump = math.dist(track.cto.position, previous.position)
            if jump > cfg.max_speed * dt + 5 * max(track.cto.rms, 1e-4):
                return Health(
                    False,
                    "corrupt",
                    f"the robot's tool jumped {jump * 1e3:.1f} mm in {dt * 1e3:.0f} ms",
                )
        return Health(True)

    def evaluate(self, now: float) -> Decision:
        """One cycle: every sensor's health, the best sensor, the robot pose (eq. 3.5)."""
        healthy: list[int] = []
        for index, track in enumerate(self.tracks):
            track.health = self._basic(track, now)
            if track.health.ok:
                healthy.append(index)
        candidates = np.array(healthy, dtype=int)
        local = master = np.zeros((0, 4, 4))
        if healthy:
            local, master = self._robot_poses(candidates)
            self._check_calibration(candidates, local, master)
        row = {index: k for k, index in enumerate(healthy)}
        best, robot = None, None
        for index, track in enumerate(self.tracks):
            if track.health.ok:
                if track.fresh:
                    track.streak += 1
            else:
                track.streak = 0
            track.health.streak = track.streak
            track.fresh = False
            eligible = track.health.ok and (
                track.streak >= self.config.hysteresis or track.config.name == self.best
            )
            if best is None and eligible:
                best = track.config.name
                robot = master[row[index]] if index in row else None
        changed = best != self.best
        self.best = best
        self.last = Decision(best, {t.config.name: t.health for t in self.tracks}, robot, changed)
        return self.last

    def _robot_poses(self, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the CTO in each sensor's reference-tool frame, the end-effector in the master
        frame) for the candidate sensors, batched.

        Eq. 3.5 with C_i = X_master X_i^-1 (eq. 3.3) mapping sensor i's reference frame
        into the master's: ee = C_i (T_RTO,i)^-1 T_CTO,i Y_i^-1. (The thesis writes C_i^-1
        in eq. 3.5, which matches the opposite direction for C.) The end-effector, not
        the CTO, is compared across sensors: each sensor sees its own markers."""
        n = len(self.tracks)
        every = len(candidates) == n
        quats, points = np.array(self._quats), np.array(self._points)
        if not every:
            rows = np.concatenate([candidates, candidates + n])
            quats, points = quats[rows], points[rows]
        rotations = Rotation.from_quat(quats).as_matrix()  # one C call for every tool
        k = len(candidates)
        rto_t = np.swapaxes(rotations[k:], 1, 2)
        local = np.zeros((k, 4, 4))
        local[:, :3, :3] = rto_t @ rotations[:k]
        local[:, :3, 3] = (rto_t @ (points[:k] - points[k:])[:, :, None])[:, :, 0]
        local[:, 3, 3] = 1.0
        c = self._c if every else self._c[candidates]
        y_inv = self._y_inv if every else self._y_inv[candidates]
        return local, c @ local @ y_inv

    def _check_calibration(
        self, candidates: np.ndarray, local: np.ndarray, master: np.ndarray
    ) -> None:
        """Fault-tree level 4: against kinematics if known, else against each other."""
        if not len(candidates):
            return
        if self.kinematics is not None:
            every = len(candidates) == len(self.tracks)
            x = self._x if every else self._x[candidates]
            y = self._y if every else self._y[candidates]
            predicted = x @ self.kinematics @ y
            diff = local[:, :3, 3] - predicted[:, :3, 3]
            offsets2 = (diff * diff).sum(axis=1)
            # trace(A^T B) = 1 + 2 cos(angle): compare cosines, no arccos for healthy rows
            cosines = ((local[:, :3, :3] * predicted[:, :3, :3]).sum(axis=(1, 2)) - 1.0) / 2.0
            bad = (offsets2 > self._tol_pos2[candidates]) | (cosines < self._tol_cos[candidates])
            offsets = np.sqrt(offsets2)
            angles = np.arccos(np.clip(cosines, -1.0, 1.0))
            for k in np.flatnonzero(bad):
                self.tracks[candidates[k]].health = Health(
                    False,
                    "calibration",
                    f"{offsets[k] * 1e3:.1f} mm, "
                    f"{math.degrees(angles[k]):.2f} deg away from the robot's kinematics",
                )
            return
        if len(candidates) < 2:
            return
        for k, i in enumerate(candidates):
            agree = 0
            others = [j for j in range(len(candidates)) if j != k]
            for j in others:
                if self._close(i, master[k], master[j]):
                    agree += 1
            if agree * 2 < len(others) or (len(others) == 1 and agree == 0):
                names = ", ".join(self.tracks[candidates[j]].config.name for j in others)
                self.tracks[i].health = Health(
                    False, "calibration", f"disagrees with {names} beyond tolerance"
                )

    def _close(self, i: int, a: np.ndarray, b: np.ndarray) -> bool:
        cfg = self.tracks[i].config
        offset = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
        angle = float(rotation_angle(a[:3, :3].T @ b[:3, :3]))
        return offset <= cfg.tolerance_position and angle <= cfg.tolerance_angle


class SensorManager(Component):
    """Feeds `SensorManagerCore` from the trackers' ports and publishes its decisions."""

    sensors_file = prop(str, "", doc="sensors YAML (priorities, keys, calibration, limits)")
    rate = prop(float, 1000.0, unit="Hz", min=1.0, max=5000.0, doc="evaluation rate")
    ee_pose = In(Pose, doc="end-effector in the robot base frame, from joints (optional)")
    robot_pose = Out(Pose, doc="end-effector in the master frame (eq. 3.5), best sensor")
    status = Out(EventMessage, doc="best sensor, its limits, every sensor's health")

    def configure_hook(self) -> bool:
        try:
            if not self.sensors_file:
                raise SensorConfigError("property sensors_file is empty")
            config = load_sensors(self.sensors_file)
        except FwError as exc:
            self.last_error = str(exc)
            return False
        self.core = SensorManagerCore(config)
        self.tracker_ports: list[tuple[str, str, InputPort[Pose]]] = []
        for sensor in config.sensors:
            for tool, key in sensor.keys.items():
                port = self.add_input(f"{sensor.name}_{tool}", Pose, key, ConnPolicy("buffer", 64))
                self.tracker_ports.append((sensor.name, tool, port))
        self._last_status = 0.0
        return True

    def cleanup_hook(self) -> None:
        for _, _, port in getattr(self, "tracker_ports", []):
            port.close()

    def update_hook(self) -> None:
        now = time.monotonic()
        for sensor, tool, port in self.tracker_ports:
            while True:
                status, pose = port.read()
                if status is not ReadStatus.NEW:
                    break
                self.core.offer(sensor, tool, pose, now)
        status, ee = self.ee_pose.read()
        if status is not ReadStatus.NO_DATA and ee is not None:
            self.core.set_kinematics(pose_matrix(ee))
        decision = self.core.evaluate(now)
        if decision.robot_pose is not None:
            from components.tracking.geometry import matrix_to_quat

            position = tuple(float(v) for v in decision.robot_pose[:3, 3])
            self.robot_pose.write(
                Pose(
                    position,
                    matrix_to_quat(decision.robot_pose[:3, :3]),
                    time.time(),
                    0.0,
                    0,
                    True,
                    self.core.config.master,
                    "ee",
                )
            )
        if decision.changed or now - self._last_status > 0.5:
            self._last_status = now
            self.status.write(
                EventMessage(time.time(), "tracking", self.name, self.describe_decision(decision))
            )

    def describe_decision(self, decision: Decision) -> dict[str, Any]:
        """The decision as plain data."""
        best = self.core.by_name[decision.best].config if decision.best else None
        return {
            "best": decision.best,
            "limits": best.limits if best else {},
            "calibration": best.master_from_sensor.tolist() if best else None,
            "health": {
                n: {"ok": h.ok, "cause": h.cause, "detail": h.detail}
                for n, h in decision.health.items()
            },
        }

    @operation
    def current(self) -> dict[str, Any]:
        """The latest decision (best sensor, limits, health of every sensor)."""
        core = getattr(self, "core", None)
        last = core.last if core is not None else None
        if last is None:  # not configured yet, or no cycle run yet
            return {"best": None, "limits": {}, "calibration": None, "health": {}}
        return self.describe_decision(last)
