"""Navigation on the patient: where the procedure's goals are now, in the robot's terms.

The target lives on the patient, in the frame of the reference tool on the head
clamp (the master tracker's, thesis eq. 3.5). The robot moves by its own model
(nominal kinematics from the joints), which is a few millimetres off the real
arm, and the head may move. Each tracker sample closes that loop:

    E = C_i RTO_i^-1 CTO_i Y_i^-1      the end-effector on the patient, as tracked
                                       (the TCP where pivoting found it in the CTO)
    B = K(q(t_sample)) E^-1            the patient in the robot's nominal base frame

`B` absorbs everything between the model and the patient: joint offsets, link
errors, calibration, the head's motion. A goal given on the patient is then
`B T_goal` in the frame the interpolator plans in: steering the nominal TCP there
puts the real TCP on the target, within the tracker's accuracy.

* `B` is low-pass filtered (time constant `smoothing`), so a tracker's noise does
  not reach the robot as a step; the interpolator also rate-limits the correction.
  A noisy tracker is filtered more: each sample's weight is capped so that at most
  `jitter` (RMS) of its noise reaches the goals, from the RMS the tracker reports
  for its two tools (an exponential filter of weight w passes sigma*sqrt(w/(2-w))
  of white noise sigma). A sample more than `NEWS` (3) times its noise away from
  the filtered view is news, not noise (the head moved): it is not held back, so a
  heavy filter does not slow the following of a bump. With the SEEG procedure's
  0.07 mm the Vicra (0.25 mm per tool, 20 Hz) steers with a ~0.65 s time constant
  near the filtered view, the Certus (0.1 mm, 100 Hz) with `smoothing`.
* **A swap is bumpless**: two trackers' calibrations differ by millimetres (each
  hand-eye fit absorbs the arm's model errors its own way). At a swap, the new
  tracker's view is carried by what differs between the two trackers' views, as the
  Sensor Manager measured it with both samples taken at the same instant and
  averaged over a second (`offsets` of its status: the calibrations' difference,
  never the patient's or the robot's motion), and the carry fades over
  `swap_settle` (10 s): the robot keeps the previous tracker's registration across
  the swap and drifts to the new tracker's own view (after t seconds, at most
  |offset| e^(-t/10 s) from it), while the new tracker's samples follow the head
  from the first one. Without a measured offset (the trackers were never healthy
  together), the carry is what makes the new view agree with `B` as it was, averaged
  over the new tracker's first `swap_average` (0.5 s); it then also carries whatever
  the head did between the last sample of the one and the first of the other.
* **The patient's motion** is measured apart, independent of the arm's model
  errors: the reference tool placed in the base by the tracker's own calibration
  to the robot (`S`), against where the registration found it. Farther than
  `max_motion`, or faster than `max_speed` over the last second (a displacement
  of more than `max_speed` x 1 s within a second: a 5 mm bump is 5 mm/s), the
  navigation refuses until the patient is registered again: the robot must not
  chase a patient who is being moved.
* **A sample that cannot be** is not steered by either: one that puts the patient
  farther from the registration than `max_motion` plus `max_model_error` (what the
  arm's model may be off by, 5 mm) is held, then refused like a patient's motion: a
  tool loose on the arm or a wrong tracker must not drag the goals.
* Without any sample (no tracker), `B` is the registration: the goals are where
  the calibration put the patient (the arm's model errors stay uncorrected).

`NavigatorCore` is the logic (time and poses in, goals out); the `Navigator`
component wires it to ports.
"""

from __future__ import annotations

import bisect
import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from components.domain.geometry import invert, norm, pose_from_list, pose_list, pose_matrix
from components.domain.lwr4 import Kinematics
from components.domain.procedure import Procedure, load_procedure
from components.domain.sensors import SensorsConfig, load_sensors
from framework.clock_offset import UNMEASURED
from framework.component import Component, In, Out, operation
from framework.messages import EventMessage, JointState, Pose
from framework.ports import ReadStatus
from framework.properties import prop

SPEED_WINDOW = 1.0  # s over which the patient's speed is averaged
LEVER = 0.25  # m: the goals lie within this of the reference tool on the head clamp
JOINT_MEMORY = 0.5  # s of joint states kept to match the samples' stamps
NEWS = 3.0
"""A sample this many times its noise from the filtered view is news (the head moved),
not noise: it is not held back to `jitter`."""


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
        confirm: float = 0.3,
        swap_settle: float = 10.0,
        swap_average: float = 0.5,
        jitter: float = math.inf,
        max_model_error: float = 0.005,
    ):
        """`registration`: the patient frame in the robot base where the calibration
        found it (X^-1 of the master tracker)."""
        if not (smoothing > 0 and max_motion > 0 and max_speed > 0 and jitter > 0 and confirm >= 0):
            raise ValueError(
                "smoothing, max_motion, max_speed and jitter must be positive, confirm not negative"
            )
        self.trackers = trackers
        self.registration = np.asarray(registration, dtype=float).copy()
        self.smoothing = smoothing
        self.max_motion = max_motion
        self.max_speed = max_speed
        self.confirm = confirm
        self.swap_settle = swap_settle
        self.swap_average = swap_average
        self.jitter = jitter
        self.max_model_error = max_model_error
        self._carry: np.ndarray | None = None  # offset carried from the previous tracker
        self._carry_t = 0.0
        self._carry_base = np.eye(4)  # B when the swap came
        self._carry_samples = 0  # how many of the new tracker's samples the carry averages
        self._carry_until = -math.inf  # the carry is averaged until then
        self.base_from_patient = self.registration.copy()  # B, filtered
        self.tracker: str | None = None  # whose samples steer now
        self._last_t: float | None = None
        self._times: list[float] = []
        self._joints: list[np.ndarray] = []
        self._patient: deque[tuple[float, np.ndarray]] = deque()  # (t, position) in the base
        self.patient_offset = np.zeros(3)
        self.patient_speed = 0.0
        self.refused = ""
        self.suspect = ""  # a motion beyond the limits, not yet confirmed
        self._suspect_since = 0.0
        self.offsets: dict[str, np.ndarray] = {}  # the trackers' same-instant differences

    # --- inputs ------------------------------------------------------------------------
    def joints(self, stamp: float, q: np.ndarray) -> None:
        """A measured joint state (stamped on the clock of the samples' stamps: this
        host's, `Component.local_stamp`)."""
        self._times.append(stamp)
        self._joints.append(np.asarray(q, dtype=float))
        if stamp - self._times[0] > 2 * JOINT_MEMORY:
            cut = bisect.bisect_left(self._times, stamp - JOINT_MEMORY)
            del self._times[:cut], self._joints[:cut]

    def joints_at(self, stamp: float) -> np.ndarray | None:
        """The joint state at `stamp` (None before the first): between the two measured
        around it, linearly (the robot's joints come at 100 Hz: a tracker's sample falls
        between two, and the nearer of them would be up to 5 ms, 0.4 mm at 7.5 cm/s,
        off); before the first or after the last, that one."""
        times = self._times
        if not times:
            return None
        k = bisect.bisect_left(times, stamp)
        if k == 0:
            return self._joints[0]
        if k == len(times):
            return self._joints[-1]
        before, after = times[k - 1], times[k]
        u = (stamp - before) / (after - before)
        a = self._joints[k - 1]
        return a + (self._joints[k] - a) * u

    def offer(
        self,
        tracker: str,
        cto: np.ndarray,
        rto: np.ndarray,
        base_from_ee: np.ndarray,
        t: float,
        noise: float = 0.0,
    ) -> bool:
        """A tracker's sample (CTO and RTO in its frame) with the nominal end-effector
        pose at the sample's stamp and its noise (m RMS, both tools together); False if
        the tracker is unknown (nothing changes)."""
        frames = self.trackers.get(tracker)
        if frames is None:
            return False
        previous = self.tracker
        swapped = tracker != previous and previous is not None
        if tracker != self.tracker:
            self._patient.clear()  # another tracker: its own view of the patient's motion
            self.suspect = ""
        reason = ""
        if frames.base_from_sensor is not None:
            patient = frames.base_from_sensor @ rto @ invert(frames.master_from_sensor)
            reason = self._watch_patient(t, patient[:3, 3])
        on_patient = frames.master_from_sensor @ invert(rto) @ cto @ frames.cto_from_ee
        measured = base_from_ee @ invert(on_patient)
        self._judge(t, reason or self._implausible(measured))
        self.tracker = tracker
        if self.suspect or self.refused:
            self._last_t = t
            return True  # the goals hold still: the robot does not chase a moved patient
        if swapped:
            self._carry_t, self._carry_base, self._carry_samples = t, self.base_from_patient, 0
            new, old = self.offsets.get(tracker), self.offsets.get(previous)  # type: ignore[arg-type]
            if new is not None and old is not None:
                # B_old = K E_old^-1 = B_new (E_new E_old^-1), measured at one instant
                self._carry, self._carry_until = new @ invert(old), -math.inf
            else:
                self._carry_until = t + self.swap_average
        if t <= self._carry_until:
            # no measured offset: the one that makes the new view agree with B as it was,
            # averaged over the new tracker's first samples (one sample carries its
            # whole noise into the goals for seconds)
            self._carry_samples += 1
            offset = invert(measured) @ self._carry_base
            if self._carry_samples == 1:
                self._carry = offset
            else:
                self._carry = blend(self._carry, offset, 1.0 / self._carry_samples)
        if self._carry is not None:
            fade = math.exp(-max(0.0, t - self._carry_t) / self.swap_settle)
            measured = measured @ blend(np.eye(4), self._carry, fade)
        if self._last_t is None:
            weight = 1.0  # the first sample replaces the registration
        else:
            weight = 1.0 - math.exp(-max(0.0, t - self._last_t) / self.smoothing)
            if self._apart(measured) <= NEWS * noise:  # noise: filtered down to `jitter`
                weight = min(weight, self.noise_weight(noise))
        self.base_from_patient = blend(self.base_from_patient, measured, weight)
        self._last_t = t
        return True

    def _apart(self, measured: np.ndarray) -> float:
        """How far a sample's view of the patient is from the filtered one (m, a turn
        counted at `LEVER`)."""
        b = self.base_from_patient
        shift = norm(measured[:3, 3] - b[:3, 3])
        return shift + norm(pin.log3(b[:3, :3].T @ measured[:3, :3])) * LEVER

    def noise_weight(self, noise: float) -> float:
        """The largest weight a sample of this noise (m RMS) may have in the filter so
        that at most `jitter` of it reaches the goals (1: no cap)."""
        if not noise > self.jitter:
            return 1.0
        x = (self.jitter / noise) ** 2
        return 2.0 * x / (1.0 + x)

    def tracker_offsets(self, offsets: dict[str, np.ndarray]) -> None:
        """The Sensor Manager's same-instant differences of the trackers' views (each
        against one reference: E_i E_ref^-1), for the next swap's carry."""
        self.offsets = dict(offsets)

    def register(self) -> None:
        """The patient is where the tracking sees it now (the surgeon re-registered):
        its motion is measured from here on."""
        self.registration[:3, 3] += self.patient_offset
        self.patient_offset = np.zeros(3)
        self._patient.clear()
        self.refused = ""
        self.suspect = ""

    # --- outputs -----------------------------------------------------------------------
    def goal(self, on_patient: np.ndarray) -> np.ndarray:
        """A goal given on the patient, in the robot's nominal base frame now."""
        return self.base_from_patient @ on_patient

    # --- internals ---------------------------------------------------------------------
    def _watch_patient(self, t: float, position: np.ndarray) -> str:
        """Why the patient's motion is beyond the limits ("" if it is not)."""
        self.patient_offset = position - self.registration[:3, 3]
        window = self._patient
        window.append((t, position))
        while window and t - window[0][0] > SPEED_WINDOW:
            window.popleft()
        self.patient_speed = norm(position - window[0][1]) / SPEED_WINDOW
        moved = norm(self.patient_offset)
        if moved > self.max_motion:
            reason = (
                f"the patient moved {moved * 1e3:.1f} mm from where it was registered "
                f"(limit {self.max_motion * 1e3:.1f} mm)"
            )
        elif self.patient_speed > self.max_speed:
            reason = (
                f"the patient moves at {self.patient_speed * 1e3:.1f} mm/s "
                f"(limit {self.max_speed * 1e3:.1f} mm/s)"
            )
        else:
            reason = ""
        return reason

    def _implausible(self, measured: np.ndarray) -> str:
        """Why a sample's view of the patient cannot be (""  if it can): farther from the
        registration than the patient may move plus what the arm's model may be off by,
        at any point within `LEVER` of the reference tool. A tool loose on the arm or a
        wrong tracker must not steer the robot."""
        shift = norm(measured[:3, 3] - self.registration[:3, 3])
        turn = norm(pin.log3(self.registration[:3, :3].T @ measured[:3, :3]))
        off = shift + turn * LEVER
        limit = self.max_motion + self.max_model_error
        if off <= limit:
            return ""
        return (
            f"the tracked end-effector puts the patient {off * 1e3:.1f} mm from where it "
            f"was registered (limit {limit * 1e3:.1f} mm: its motion plus the arm's model "
            "error): a tool moved on the arm, or a tracker is wrong"
        )

    def _judge(self, t: float, reason: str) -> None:
        """Hold the goals while a motion beyond the limits lasts; refuse it once it
        lasted `confirm`, as seen by the same tracker."""
        if not reason:
            self.suspect = ""
            return
        if not self.suspect:
            self._suspect_since = t
        self.suspect = reason
        if t - self._suspect_since >= self.confirm and not self.refused:
            self.refused = reason


def frames_of(sensors: SensorsConfig) -> tuple[dict[str, TrackerFrames], np.ndarray]:
    """Every tracker's frames from a sensors configuration, and the registration (the
    patient frame in the robot base, from the master's X)."""
    trackers = {}
    for s in sensors.sensors:
        trackers[s.name] = TrackerFrames(
            s.master_from_sensor,
            s.cto_from_ee,
            None if s.sensor_from_base is None else invert(s.sensor_from_base),
        )
    master = next(s for s in sensors.sensors if s.name == sensors.master)
    return trackers, invert(master.rto_from_base)


def core_for(procedure: Procedure, sensors: SensorsConfig) -> NavigatorCore:
    """The navigation a procedure asks for (its `navigation:` limits), on the trackers
    and registration of a sensors configuration."""
    trackers, registration = frames_of(sensors)
    n = procedure.navigation
    return NavigatorCore(
        trackers,
        registration,
        smoothing=n.smoothing,
        max_motion=n.max_patient_motion,
        max_speed=n.max_patient_speed,
        confirm=n.confirm,
        jitter=n.jitter,
        max_model_error=n.max_model_error,
    )


class Navigator(Component):
    """Where the procedure's goals are now in the robot's nominal base frame, from the
    tracker whose tools are connected to `cto` and `rto` (the chart's tracker swap
    rewires them: the swap changes what steers). Goals given in the base frame pass
    unchanged; goals on the patient follow the patient (module docstring).

    Publishes `goals` on tracker samples at most `goals_rate` times a second (at once when
    what steers, a refusal, a hold or a goal's revision changes), and at least every
    `idle` of its activity:
    `{goals: {name: [x y z qw qx qy qz]}, revisions: {name: n}, tracker, refused,
    patient_mm, patient_speed_mm_s}`; a goal defined anew has a new revision (a motion
    heading for the old one is not steered to the new one).
    `tracker` names whose samples steer (None once they stop for `stale`); `refused`
    says why the patient's motion is refused ("" when it is not); `holding`, why the
    goals hold still while a motion beyond the limits awaits confirmation. The interpolator
    steers by it and stops on a refusal; the Supervisor raises e_PATIENT_MOVED."""

    procedure_file = prop(
        str, "", doc="procedure YAML (goals and their frames)", required=True, file="procedure"
    )
    sensors_file = prop(
        str, "", doc="sensors YAML (each tracker's calibration)", required=True, file="sensors"
    )
    stale = prop(
        float, 0.25, unit="s", min=0.01, max=5.0, doc="no sample for this long: no tracker steers"
    )
    goals_rate = prop(
        float,
        50.0,
        unit="Hz",
        min=1.0,
        max=1000.0,
        doc="goals at most this often (the interpolator's rate; each is encoded and decoded "
        "in the Supervisor): a 100 Hz Certus made every sample a message",
    )
    cto = In(Pose, doc="the robot's tool as the tracker in use sees it (rewired per tracker)")
    rto = In(Pose, doc="the reference tool on the head clamp, as the same tracker sees it")
    tracking = In(
        EventMessage,
        doc="the Sensor Manager's status: its same-instant offsets between the trackers' "
        "views (what a swap carries); without it a swap carries the view as it was",
    )
    joints = In(
        JointState,
        doc="measured joints: the nominal pose at each sample's stamp",
        policy={"type": "buffer", "size": 512},
    )
    goals = Out(EventMessage, doc="where the goals are now, base frame; tracker; refusal")
    sources = Out(
        EventMessage,
        doc="first valid sample from a tracker that did not steer before: {tracker, "
        "sample_stamp} (stamped on receipt; a sensor swap's latency ends here)",
    )

    def __init__(self, name: str):
        super().__init__(name)
        self.core: NavigatorCore | None = None
        """The navigation, made by `configure` from the procedure and the sensors."""

    def configure_hook(self) -> bool:
        self.procedure: Procedure = load_procedure(self.procedure_file)
        self.core = core_for(self.procedure, load_sensors(self.sensors_file))
        self.kinematics = Kinematics()
        self._rto: Pose | None = None
        self._last_sample = -math.inf
        self.revisions: dict[str, int] = {}  # how often each goal was defined anew
        self._said: tuple[Any, ...] = ()  # what the last goals said besides the poses
        self._said_at = -math.inf  # ...and when (the component's clock)
        return True

    def update_hook(self) -> None:
        while True:
            status, state = self.joints.read()
            if status is not ReadStatus.NEW:
                break
            stamp = self.local_stamp("joints", state.stamp)
            if stamp is not None:  # None: the robot's host is not measured yet
                self.core.joints(stamp, np.asarray(state.position))
        status, tracking = self.tracking.read()
        if status is ReadStatus.NEW and tracking is not None:
            self._take_offsets(tracking.payload.get("offsets"))
        status, rto = self.rto.read()
        if status is ReadStatus.NEW:
            self._rto = rto
        status, cto = self.cto.read()
        if status is ReadStatus.NEW and self._usable(cto):
            # the tracker's stamp on the joints' clock (another host's may run apart)
            stamp = self.local_stamp("cto", cto.stamp)
            if stamp is None:
                self.refuse("cto", f"{cto.frame!r}: {UNMEASURED}")
                self._say_goals()
                return
            q = self.core.joints_at(stamp)
            steered = self.steering()
            if q is not None and self.core.offer(
                cto.frame,
                pose_matrix(cto),
                pose_matrix(self._rto),  # type: ignore[arg-type]
                self.kinematics.tcp(q),
                stamp,
                math.hypot(cto.rms, self._rto.rms),  # type: ignore[union-attr]
            ):
                self._last_sample = time.time()
                if cto.frame != steered:
                    payload = {"tracker": cto.frame, "sample_stamp": stamp}
                    self.sources.write(
                        EventMessage(self._last_sample, "tracked_source", self.name, payload)
                    )
            elif cto.frame not in self.core.trackers:
                self.refuse("cto", f"samples of {cto.frame!r}, a tracker the sensors file lacks")
        self._say_goals()

    def idle_hook(self) -> None:
        self._said_at = -math.inf  # silent for `idle`: say them whatever the rate
        self.update_hook()

    def _say_goals(self) -> None:
        """Publish the goals if `goals_rate` allows it, or if anything but the poses
        changed (what steers, a refusal, a hold, a revision)."""
        core, at = self.core, self.clock.now()
        said = (self.steering(), core.refused, core.suspect, tuple(self.revisions.items()))
        # 3/4 of a period: a sample a little early on a 2x faster tracker still counts
        if said == self._said and at - self._said_at < 0.75 / self.goals_rate:
            return
        self._said, self._said_at = said, at
        self.goals.write(EventMessage(time.time(), "goals", self.name, self.report()))

    def _take_offsets(self, offsets: Any) -> None:
        """Keep the Sensor Manager's offsets of the trackers this navigator knows; a
        status whose offsets are not poses is refused (the last good ones stay)."""
        if not isinstance(offsets, dict):
            return
        try:
            taken = {
                name: pose_from_list(pose)
                for name, pose in offsets.items()
                if name in self.core.trackers
            }
        except (TypeError, ValueError) as exc:
            self.refuse("tracking", f"offsets that are not poses: {exc}")
            return
        self.core.tracker_offsets(taken)

    def _usable(self, cto: Pose) -> bool:
        """Both tools seen, finite, by the same tracker."""
        rto = self._rto
        return (
            rto is not None
            and cto.valid
            and rto.valid
            and cto.frame == rto.frame
            and cto.is_finite()
            and rto.is_finite()
        )

    def steering(self) -> str | None:
        """The tracker whose samples steer now (None when they stopped)."""
        if time.time() - self._last_sample > self.stale:
            return None
        return self.core.tracker

    @operation
    def define_target(
        self,
        x: float,
        y: float,
        z: float,
        roll: float,
        pitch: float,
        yaw: float,
        frame: str = "patient",
    ) -> dict[str, Any]:
        """A new target (m, deg) on the patient (the reference tool's frame) or, with
        `frame="base"`, in the robot base frame; every follower of `goals` takes it."""
        self.procedure.define_target((x, y, z), (roll, pitch, yaw), frame)
        self.revisions["target"] = self.revisions.get("target", 0) + 1
        return self.report()

    @operation
    def register(self) -> dict[str, Any]:
        """The patient is where the tracking sees it now: measure its motion from here
        (after the surgeon checked the registration; clears a refusal)."""
        self.core.register()
        report = self.report()
        self.goals.write(EventMessage(time.time(), "goals", self.name, report))  # no wait
        return report

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """The goals now (base frame), the tracker that steers, the patient's motion."""
        core = self.core
        if core is None:
            return {"goals": {}, "tracker": None, "refused": ""}
        goals = {}
        for name, pose in self.procedure.goals.items():
            goal = core.goal(pose) if self.procedure.frame(name) == "patient" else pose
            goals[name] = pose_list(goal)
        target = self.procedure.goals.get("target")
        return {
            "goals": goals,
            "revisions": {name: self.revisions.get(name, 0) for name in goals},
            # the target as defined (the operator's, exact), for whoever scores the approach
            "target": None
            if target is None
            else {"frame": self.procedure.frame("target"), "pose": pose_list(target)},
            "tracker": self.steering(),
            "refused": core.refused,
            "holding": core.suspect,
            "patient_mm": [round(float(v) * 1e3, 3) for v in core.patient_offset],
            # where the patient's reference tool is (base frame, m): for the 3D view
            "patient": [round(float(v), 4) for v in core.base_from_patient[:3, 3]],
            # the sphere around the target in which the approach slows (a 3D view's)
            "critical_radius": self.procedure.critical_radius,
            "patient_speed_mm_s": round(core.patient_speed * 1e3, 3),
        }
