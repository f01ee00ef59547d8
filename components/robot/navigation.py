"""Navigation on the patient: where the procedure's goals are now, in the robot's terms.

The target lives on the patient, in the frame of the reference tool on the head
clamp (the master tracker's, thesis eq. 3.5). The robot moves by its own model
(nominal kinematics from the joints), which is a few millimetres off the real
arm, and the head may move. Each tracker sample closes that loop:

    E = C_i RTO_i^-1 CTO_i Y_i^-1      the end-effector on the patient, as tracked
    B = K(q(t_sample)) E^-1            the patient in the robot's nominal base frame

`B` absorbs everything between the model and the patient: joint offsets, link
errors, calibration, the head's motion. A goal given on the patient is then
`B T_goal` in the frame the interpolator plans in: steering the nominal TCP there
puts the real TCP on the target, within the tracker's accuracy.

* `B` is low-pass filtered (time constant `smoothing`), so neither a tracker's
  noise nor the step between two trackers' calibrations (a swap) reaches the
  robot as a step; the interpolator also rate-limits the correction.
* **The patient's motion** is measured apart, independent of the arm's model
  errors: the reference tool placed in the base by the tracker's own calibration
  to the robot (`S`), against where the registration found it. Farther than
  `max_motion`, or faster than `max_speed` over the last second (a displacement
  of more than `max_speed` x 1 s within a second: a 5 mm bump is 5 mm/s), the
  navigation refuses until the patient is registered again: the robot must not
  chase a patient who is being moved.
* Without any sample (no tracker), `B` is the registration: the goals are where
  the calibration put the patient (the arm's model errors stay uncorrected).

`NavigatorCore` is the logic (time and poses in, goals out); the `Navigator`
component wires it to ports.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from components.tracking.geometry import invert
from components.tracking.sensor_manager import SensorsConfig

SPEED_WINDOW = 1.0  # s over which the patient's speed is averaged
JOINT_MEMORY = 0.5  # s of joint states kept to match the samples' stamps


@dataclass(frozen=True)
class TrackerFrames:
    """One tracker's calibration, as navigation uses it."""

    master_from_sensor: np.ndarray  # C
    cto_from_ee: np.ndarray  # Y^-1
    base_from_sensor: np.ndarray | None  # S^-1 (None: the tracker is not calibrated to the robot)


def blend(a: np.ndarray, b: np.ndarray, weight: float) -> np.ndarray:
    """The pose `weight` of the way from `a` to `b` (linear in position, geodesic in
    rotation)."""
    out = np.eye(4)
    out[:3, 3] = a[:3, 3] + weight * (b[:3, 3] - a[:3, 3])
    out[:3, :3] = a[:3, :3] @ pin.exp3(weight * pin.log3(a[:3, :3].T @ b[:3, :3]))
    return out


class NavigatorCore:
    """Where the goals are now in the robot's nominal base frame (module docstring)."""

    def __init__(
        self,
        trackers: dict[str, TrackerFrames],
        registration: np.ndarray,
        *,
        smoothing: float = 0.1,
        max_motion: float = 0.01,
        max_speed: float = 0.008,
    ):
        """`registration`: the patient frame in the robot base where the calibration
        found it (X^-1 of the master tracker)."""
        if not (smoothing > 0 and max_motion > 0 and max_speed > 0):
            raise ValueError("smoothing, max_motion and max_speed must be positive")
        self.trackers = trackers
        self.registration = np.asarray(registration, dtype=float).copy()
        self.smoothing = smoothing
        self.max_motion = max_motion
        self.max_speed = max_speed
        self.base_from_patient = self.registration.copy()  # B, filtered
        self.tracker: str | None = None  # whose samples steer now
        self.samples = 0
        self._last_t: float | None = None
        self._times: list[float] = []
        self._joints: list[np.ndarray] = []
        self._patient: deque[tuple[float, np.ndarray]] = deque()  # (t, position) in the base
        self.patient_offset = np.zeros(3)
        self.patient_speed = 0.0
        self.refused = ""

    # --- inputs ------------------------------------------------------------------------
    def joints(self, stamp: float, q: np.ndarray) -> None:
        """A measured joint state (stamps on the samples' clock)."""
        self._times.append(stamp)
        self._joints.append(np.asarray(q, dtype=float))
        if stamp - self._times[0] > 2 * JOINT_MEMORY:
            cut = bisect.bisect_left(self._times, stamp - JOINT_MEMORY)
            del self._times[:cut], self._joints[:cut]

    def joints_at(self, stamp: float) -> np.ndarray | None:
        """The joint state nearest in time to `stamp` (None before the first)."""
        times = self._times
        if not times:
            return None
        k = min(bisect.bisect_left(times, stamp), len(times) - 1)
        if k > 0 and stamp - times[k - 1] < times[k] - stamp:
            k -= 1
        return self._joints[k]

    def offer(
        self,
        tracker: str,
        cto: np.ndarray,
        rto: np.ndarray,
        base_from_ee: np.ndarray,
        t: float,
    ) -> bool:
        """A tracker's sample (CTO and RTO in its frame) with the nominal end-effector
        pose at the sample's stamp; False if the tracker is unknown (nothing changes)."""
        frames = self.trackers.get(tracker)
        if frames is None:
            return False
        on_patient = frames.master_from_sensor @ invert(rto) @ cto @ frames.cto_from_ee
        measured = base_from_ee @ invert(on_patient)
        if self._last_t is None:
            weight = 1.0  # the first sample replaces the registration
        else:
            weight = 1.0 - math.exp(-max(0.0, t - self._last_t) / self.smoothing)
        self.base_from_patient = blend(self.base_from_patient, measured, weight)
        self._last_t = t
        self.tracker = tracker
        self.samples += 1
        if frames.base_from_sensor is not None:
            patient = frames.base_from_sensor @ rto @ invert(frames.master_from_sensor)
            self._watch_patient(t, patient[:3, 3])
        return True

    def register(self) -> None:
        """The patient is where the tracking sees it now (the surgeon re-registered):
        its motion is measured from here on."""
        self.registration[:3, 3] += self.patient_offset
        self.patient_offset = np.zeros(3)
        self._patient.clear()
        self.refused = ""

    # --- outputs -----------------------------------------------------------------------
    def goal(self, on_patient: np.ndarray) -> np.ndarray:
        """A goal given on the patient, in the robot's nominal base frame now."""
        return self.base_from_patient @ on_patient

    # --- internals ---------------------------------------------------------------------
    def _watch_patient(self, t: float, position: np.ndarray) -> None:
        self.patient_offset = position - self.registration[:3, 3]
        window = self._patient
        window.append((t, position))
        while window and t - window[0][0] > SPEED_WINDOW:
            window.popleft()
        self.patient_speed = float(np.linalg.norm(position - window[0][1])) / SPEED_WINDOW
        moved = float(np.linalg.norm(self.patient_offset))
        if moved > self.max_motion:
            self.refused = (
                f"the patient moved {moved * 1e3:.1f} mm from where it was registered "
                f"(limit {self.max_motion * 1e3:.1f} mm)"
            )
        elif self.patient_speed > self.max_speed:
            self.refused = (
                f"the patient moves at {self.patient_speed * 1e3:.1f} mm/s "
                f"(limit {self.max_speed * 1e3:.1f} mm/s)"
            )


def frames_of(sensors: SensorsConfig) -> tuple[dict[str, TrackerFrames], np.ndarray]:
    """Every tracker's frames from a sensors configuration, and the registration (the
    patient frame in the robot base, from the master's X)."""
    trackers = {
        s.name: TrackerFrames(
            s.master_from_sensor,
            invert(s.ee_from_cto),
            None if s.sensor_from_base is None else invert(s.sensor_from_base),
        )
        for s in sensors.sensors
    }
    master = next(s for s in sensors.sensors if s.name == sensors.master)
    return trackers, invert(master.rto_from_base)
