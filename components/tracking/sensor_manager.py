"""The Sensor Manager (thesis 3.3.4, Fig. 3.13): which tracker can be trusted now.

For every sensor, each cycle, the fault tree of 3.3.3 in its order:

1. `cto_missing` / `rto_missing`: the device reports the tool MISSING
   (occlusion, out of the field of view);
2. `stale`: no new frame for `stale_periods` periods (driver crash, cable cut,
   power loss), or `no_data` before the first frame;
3. `corrupt`: NaN or non-unit quaternion, or an impossible jump of the CTO;
4. `calibration`: the robot pose this sensor gives disagrees, beyond the
   tolerance, with the prediction from the robot's kinematics (at the sample's
   stamp, so a late sample of a moving robot is not a fault) and the
   calibration; without kinematics, with the other healthy sensors (two sensors
   that disagree are both distrusted: the robot stops rather than follow the
   wrong one). Which pose is compared depends on the calibration:
   * with the tracker's calibration to the robot base (`S`), its view of the
     robot's tool in its own frame: a reference tool on the patient's head may
     move with the head (the navigation follows it) without a fault, while a
     tracker pushed out of place is one. Sensors that pass must then agree with
     each other about where the patient is (their reference tools share the
     head clamp): one whose reference tool slipped on its mount is the odd one
     out (of two, the one further from where the calibration found the patient),
     and once it stayed so for two periods of the slowest of them (not a moment
     when the head moved between two trackers' samples), it stays distrusted,
     alone or not, until its calibration is redone (`trust`): a slipped reference
     tool does not slip back;
   * without `S` (the thesis: a reference tool fixed to the table), the robot in
     the reference tool's frame: a moved reference tool is a fault.
   A sample is compared with the robot's pose of its time (between the two around
   its stamp), once a pose at or after its stamp has come: while the robot's side runs
   behind the trackers (a busy host, a slow link), the newest sample it covers is
   checked, and a sensor whose newest sample is more than `CHECK_LAG_LIMIT` ahead of
   the robot's newest pose is a `calibration` fault (it cannot be checked) until the
   robot's side catches up. A sample in a pause of the robot's poses (wider than
   `POSE_GAP_LIMIT`) is not judged by a pose of another time; for `CHECK_LAG_LIMIT`
   at most (then it cannot be checked: a fault).

The first healthy sensor in priority order wins; a sensor that was unhealthy
(or at start) is used again only after `hysteresis` consecutive healthy
samples. Outputs: the best sensor or none, its velocity limits and
calibration, the robot pose in the master frame (eq. 3.5), every sensor's
health and cause.

`SensorManagerCore` is the deterministic logic (time is passed in); the
`SensorManager` component feeds it from ports.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from components.domain.geometry import (
    invert,
    matrix_to_quat,
    norm,
    pose_list,
    pose_matrix,
    quat_to_matrix,
    rotation_angle,
)
from components.domain.sensors import SensorConfig, SensorsConfig, load_sensors
from framework.clock_offset import UNMEASURED
from framework.component import Component, FileInput, In, Out, operation
from framework.errors import FwError
from framework.messages import EventMessage, Pose
from framework.ports import ConnPolicy, InputPort, ReadStatus
from framework.properties import prop

KINEMATICS_MEMORY = 1.0  # s of robot poses kept to match the samples' stamps
STATUS_PERIOD = 0.5  # s between tracking statuses when nothing changes (a change: at once)
STALE_MARGIN = 0.001
"""Event-driven, the Sensor Manager looks again this long after a staleness deadline (s):
a sample exactly at the limit is not stale yet."""
POSE_GAP_LIMIT = 0.03
"""s: the widest pause in the robot's poses a sample's check may fall in. The poses come
at 100 Hz (10 ms; 30 ms: two missing; the pose between two is interpolated, 56 um off
over 30 ms at the procedure's 0.5 m/s^2); in a wider one (the robot's side was starved)
where the tool was is not known (the 100 ms pauses seen are 7.5 mm at the approach's
7.5 cm/s, more while it accelerates): a tracker's sample there is not checked (its
sensor keeps its last verdict; `unchecked` counts them)."""
CHECK_LAG_LIMIT = 0.5
"""The most a sensor's newest sample may be ahead of the robot's newest pose (s) for its
calibration to count as checked: further ahead, the robot's side is too far behind."""
CAUSES = ("no_data", "cto_missing", "rto_missing", "stale", "corrupt", "calibration")
STAMP_UNCERTAINTY = 0.002
"""s: how far a sample's stamp may be from its capture (a Vicra's frame-clock stamp is
within about 1 ms of it on a quiet line): paid in distance at the tool's speed when two
trackers' views are compared at one instant."""
OFFSET_SMOOTHING = 1.0
"""s: the time constant over which the trackers' same-instant differences are averaged
(`SensorManagerCore.offsets`): their noise averages out, a slow drift is followed."""


@dataclass
class Health:
    """A sensor's verdict for one cycle. A calibration fault carries its `numbers`
    (the poses compared, their times, the tolerance), for the recording and the event."""

    ok: bool
    cause: str = ""
    detail: str = ""
    streak: int = 0  # consecutive healthy samples (the cycle fills it in)
    numbers: dict[str, Any] = field(default_factory=dict)


class History:
    """One tool's recent valid samples of a tracker: stamps (rising) and poses (x y z
    qw qx qy qz), the last `KINEMATICS_MEMORY` seconds of them (both ends kept). A
    stamp older than the newest means the device started again: what was kept goes."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.poses: list[tuple[float, ...]] = []

    def add(self, stamp: float, pose: tuple[float, ...]) -> None:
        """Keep a sample taken at `stamp`."""
        times = self.times
        if times and stamp <= times[-1]:
            if stamp == times[-1]:
                self.poses[-1] = pose
                return
            times.clear()
            self.poses.clear()
        times.append(stamp)
        self.poses.append(pose)
        if stamp - times[0] > KINEMATICS_MEMORY:
            cut = bisect.bisect_left(times, stamp - KINEMATICS_MEMORY)
            del times[:cut], self.poses[:cut]

    def newest(self) -> float:
        """The newest stamp (-inf when nothing is kept)."""
        return self.times[-1] if self.times else -math.inf

    def at_or_before(self, t: float) -> tuple[float, tuple[float, ...]] | None:
        """The newest sample taken at or before `t` (None: none)."""
        k = bisect.bisect_right(self.times, t)
        return (self.times[k - 1], self.poses[k - 1]) if k else None

    def at(self, t: float) -> tuple[np.ndarray, float, float] | None:
        """The tool's pose at `t` (x y z qw qx qy qz), linear between the samples around
        it (normalised quaternion), with how far it may be off from that line (m: the
        tool's fastest speed over those samples and their neighbours, times half their
        interval; 0 on a sample) and that speed (m/s). None when the samples do not
        reach `t`."""
        times = self.times
        if not times or not times[0] <= t <= times[-1]:
            return None
        k = bisect.bisect_left(times, t)  # times[k] >= t
        lo, hi = max(0, k - 2), min(len(times) - 1, k + 1)
        speed = 0.0
        for j in range(lo, hi):
            dt = times[j + 1] - times[j]
            if dt > 0.0:
                speed = max(speed, math.dist(self.poses[j + 1][:3], self.poses[j][:3]) / dt)
        if times[k] == t:
            return np.array(self.poses[k]), 0.0, speed
        t0, t1 = times[k - 1], times[k]
        w = (t - t0) / (t1 - t0)
        a, b = np.array(self.poses[k - 1]), np.array(self.poses[k])
        if float(a[3:] @ b[3:]) < 0.0:  # the same rotation, the nearer way round
            b[3:] = -b[3:]
        pose = a + w * (b - a)
        pose[3:] /= norm(pose[3:])
        return pose, speed * (t1 - t0) / 2.0, speed


@dataclass
class _Track:
    config: SensorConfig
    streak: int = 0
    code: int = -1
    health: Health = field(default_factory=lambda: Health(False, "no_data"))


@dataclass
class Decision:
    """What one cycle decided."""

    best: str | None
    health: dict[str, Health]
    robot_pose: np.ndarray | None
    changed: bool


_NEVER = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -math.inf)
_NO_PREVIOUS = (math.nan, math.nan, math.nan, -math.inf, 0.0)
_NO_DATA, _CTO_MISSING, _RTO_MISSING, _STALE, _CORRUPT, _JUMP, _CALIBRATION = range(1, 8)


class SensorManagerCore:
    """The fault tree and the choice, without any I/O (time is an argument).

    Samples are kept as plain per-row lists (rows 0..n-1 the CTOs, n..2n-1 the RTOs):
    `offer` is called for every sample and must stay cheap; `evaluate` turns them into
    arrays once per cycle and runs levels 1-4 of the fault tree on every sensor at
    once, so a cycle costs about the same with 2 or 16 sensors."""

    def __init__(self, config: SensorsConfig):
        self.config = config
        self.tracks = [_Track(s) for s in config.sensors]
        self.by_name = {t.config.name: t for t in self.tracks}
        self.best: str | None = None
        self.kinematics: np.ndarray | None = None
        # recent (stamp, base_from_ee): a sample is checked against where the robot was
        # when the sample was taken, not where it is when the sample arrives
        self._times: list[float] = []  # sorted stamps of `_poses`
        self._poses: list[np.ndarray] = []
        self._stamps = [0.0] * len(config.sensors)  # each sensor's latest CTO stamp
        # each sensor's recent valid samples of both tools, to check the newest CTO the
        # robot's poses cover and to compare trackers at one instant; the latest verdict
        # of the check against the robot
        self._samples = [History() for _ in config.sensors]  # the CTOs
        self._references = [History() for _ in config.sensors]  # the RTOs
        self._verdicts: dict[int, Health | None] = {}  # the latest check's, None: passed
        # what each sensor's verdict is about: its sample's stamp and the robot pose's it
        # was checked against; the same pair again would give the same verdict
        self._checked: dict[int, tuple[float, float]] = {}
        self.unchecked = 0
        """Samples left unchecked against kinematics: no robot pose of their time."""
        self._pose_checked: dict[int, float] = {}  # sensor -> when one was last checked
        n = self._n = len(config.sensors)
        sensors = config.sensors
        self._index = {s.name: i for i, s in enumerate(sensors)}
        # a row per tool sample: x y z, qw qx qy qz, valid (1/0), arrival
        # (written in place: a row assignment is cheaper than building arrays each cycle)
        self._rows = np.array([_NEVER] * (2 * n))
        # per sensor: the CTO sample before the latest (x y z, arrival) and the latest's RMS
        self._before = np.array([_NO_PREVIOUS] * n)
        self._last_cto: list[tuple[float, ...]] = [_NEVER] * n
        self._fresh = [False] * n
        self._stale_limit = np.array([s.stale_periods / s.rate for s in sensors])
        self._period = np.array([1.0 / s.rate for s in sensors])
        self._max_speed = np.array([s.max_speed for s in sensors])
        self._c = np.stack([s.master_from_sensor for s in sensors])
        self._x = np.stack([s.rto_from_base for s in sensors])
        self._tol_pos = np.array([s.tolerance_position for s in sensors])
        self._tol_pos2 = self._tol_pos**2
        self._tol_angle = np.array([s.tolerance_angle for s in sensors])
        self._tol_cos = np.cos(self._tol_angle)
        self._y = np.stack([s.ee_from_cto for s in sensors])
        self._y_inv = invert(self._y)
        # sensors calibrated to the robot (S) are checked in their own frame, so a reference
        # tool that moves with the patient's head is not mistaken for a calibration fault
        self._camera = np.array([s.sensor_from_base is not None for s in sensors])
        self._s = np.stack(
            [np.eye(4) if s.sensor_from_base is None else s.sensor_from_base for s in sensors]
        )
        self._s_inv = invert(self._s)
        self._base_from_rto = invert(self._x)  # where each reference tool was at calibration
        self._moved: dict[int, Health] = {}  # reference tools found moved, by sensor
        self._odd_checks: dict[int, int] = {}  # consecutive checks found the odd one out
        self._compared: tuple[float, tuple[int, ...]] = (-math.inf, ())  # the last check...
        self._odd: dict[int, Health] = {}  # ...and whom it found odd
        self._cto_from_ee = np.stack([s.cto_from_ee for s in sensors])
        self._offsets: dict[int, np.ndarray] = {}  # same-instant views against the master
        self._offsets_at: dict[int, float] = {}  # ...and the instant last measured
        self._now = 0.0
        self.last: Decision | None = None

    def offer(self, sensor: str, tool: str, pose: Pose, arrival: float) -> None:
        """A new sample of `tool` (cto/rto) from `sensor`, received at `arrival`."""
        index = self._index[sensor]
        row = index
        if tool == "cto":
            last = self._last_cto[index]
            if last[7]:
                self._before[index] = (last[0], last[1], last[2], last[8], pose.rms)
            else:  # judged against where it was last seen, over the time since
                self._before[index, 4] = pose.rms
        else:
            row += self._n
        sample = (*pose.position, *pose.orientation, float(pose.valid), arrival)
        self._rows[row] = sample
        if row == index:
            self._last_cto[index] = sample
            self._stamps[index] = pose.stamp
        if pose.valid and math.isfinite(pose.stamp) and pose.is_finite():
            history = self._samples if row == index else self._references
            history[index].add(pose.stamp, sample[:7])
        self._fresh[index] = True

    def set_kinematics(self, base_from_ee: np.ndarray | None, stamp: float | None = None) -> None:
        """The robot's end-effector in its base frame from joints (None: unknown), taken
        at `stamp` (the clock of the samples' stamps; None: no history, use it for all).
        A pose not newer than the last one (or without a finite stamp) is ignored: the
        history stays in time order."""
        times = self._times
        if stamp is not None and (not math.isfinite(stamp) or (times and stamp <= times[-1])):
            return
        self.kinematics = base_from_ee
        if base_from_ee is None or stamp is None:
            self._times.clear()
            self._poses.clear()
            self._checked.clear()  # without history every check is against the latest
            return
        self._times.append(stamp)
        self._poses.append(base_from_ee)
        if stamp - self._times[0] > 2 * KINEMATICS_MEMORY:  # trim now and then, not per sample
            cut = bisect.bisect_left(self._times, stamp - KINEMATICS_MEMORY)
            del self._times[:cut], self._poses[:cut]

    def _comparable(
        self, candidates: np.ndarray
    ) -> tuple[list[int], list[float], list[tuple[float, ...]], dict[int, Health]]:
        """Which candidates' calibration can be checked now, and with which CTO sample:
        (positions in `candidates`, the samples' stamps, the samples), and the verdicts
        of the sensors too far ahead of the robot's poses. A sample is covered when a
        robot pose at or after its stamp has come, so the pose of its time lies between
        two known ones (`_kinematics_at`). A candidate with nothing covered yet (within
        the limit) is left out: it keeps its latest verdict."""
        times = self._times
        if len(times) < 2:  # no history: the latest pose stands for every sample
            rows = self._rows
            stamps = [self._stamps[i] for i in candidates.tolist()]
            return (
                list(range(len(candidates))),
                stamps,
                [tuple(rows[i, :7]) for i in candidates],
                {},
            )
        horizon = times[-1]  # a later sample waits for a pose after it (no extrapolation)
        positions, stamps, samples, behind = [], [], [], {}
        for k, i in enumerate(candidates.tolist()):
            ahead = self._stamps[i] - times[-1]
            if not ahead <= CHECK_LAG_LIMIT:
                why = (
                    f"the robot's poses are {ahead * 1e3:.0f} ms behind its samples "
                    f"(limit {CHECK_LAG_LIMIT:g} s)"
                    if math.isfinite(ahead)
                    else "its sample has no valid stamp"
                )
                behind[i] = Health(False, "calibration", f"cannot be checked: {why}")
                continue
            covered = self._samples[i].at_or_before(horizon)
            if covered is not None:
                positions.append(k)
                stamps.append(covered[0])
                samples.append(covered[1])
        return positions, stamps, samples, behind

    def _kinematics_at(self, t: float) -> np.ndarray | None:
        """The end-effector pose at time `t`: a pose of that very instant, or between the
        two robot poses around it (position linear, rotation of the earlier one: 5 ms
        apart, a tenth of a degree at the arm's turning speed). None when no pose is
        known around `t`: older than every pose kept, newer than the newest (never asked:
        `_comparable` waits for a pose after a sample), or between two poses more than
        `POSE_GAP_LIMIT` apart (the robot's stream paused there: a moving tool would look
        like a tracker's fault)."""
        assert self.kinematics is not None
        times, poses = self._times, self._poses
        if len(times) < 2:
            return self.kinematics
        k = bisect.bisect_left(times, t)
        if k < len(times) and times[k] == t:
            return poses[k]
        if k == 0 or k == len(times):
            return None
        t0, t1 = times[k - 1], times[k]  # t0 < t < t1: the stamps only increase
        if t1 - t0 > POSE_GAP_LIMIT:
            return None
        pose = poses[k - 1].copy()
        pose[:3, 3] += (t - t0) / (t1 - t0) * (poses[k][:3, 3] - poses[k - 1][:3, 3])
        return pose

    def _pose_times(self, t: float) -> dict[str, float]:
        """The robot poses' times around `t` (for a fault's numbers)."""
        times = self._times
        if not times:
            return {}
        k = bisect.bisect_left(times, t)
        out = {"pose_nearest": times[self._nearest(t)], "pose_newest": times[-1]}
        if 0 < k < len(times):
            out["pose_gap_ms"] = round((times[k] - times[k - 1]) * 1e3, 3)
        return out

    def _nearest(self, t: float) -> int:
        """The index of the robot pose nearest in time to `t` (a tie: the later one)."""
        times = self._times
        k = min(bisect.bisect_left(times, t), len(times) - 1)
        if k > 0 and t - times[k - 1] < times[k] - t:
            k -= 1
        return k

    def _fault_codes(self, now: float, rows: np.ndarray, before: np.ndarray) -> np.ndarray:
        """Fault-tree levels 1-3 for every sensor: 0 (healthy) or the first cause found."""
        n = self._n
        at, valid = rows[:, 8], rows[:, 7] != 0.0
        quats = rows[:, 3:7]
        norm2 = np.einsum("ij,ij->i", quats, quats)
        unfit = ~np.isfinite(rows[:, :3].sum(axis=1) + norm2) | (np.abs(norm2 - 1.0) > 2e-3)
        with np.errstate(invalid="ignore"):  # -inf - -inf before a second frame
            dt = np.maximum(at[:n] - before[:, 3], self._period)
        step = rows[:n, :3] - before[:, :3]
        jump2 = np.einsum("ij,ij->i", step, step)  # NaN before a second frame: no jump
        allowed = self._max_speed * dt + 5 * np.maximum(before[:, 4], 1e-4)
        leaves = (
            (at[:n] == -math.inf) | (at[n:] == -math.inf),
            ~valid[:n],
            ~valid[n:],
            now - np.minimum(at[:n], at[n:]) > self._stale_limit,
            unfit[:n] | unfit[n:],
            jump2 > allowed * allowed,
        )
        codes = np.zeros(n, dtype=np.int8)
        for code in range(len(leaves), 0, -1):  # the first leaf in the tree's order wins
            codes[leaves[code - 1]] = code
        return codes

    def _describe(self, index: int, code: int, now: float) -> Health:
        """The verdict of one sensor, in words (only built when its verdict changes)."""
        n = self._n
        if code == 0:
            return Health(True)
        if code == _NO_DATA:
            return Health(False, "no_data", "no frame yet")
        if code == _CTO_MISSING:
            return Health(False, "cto_missing", "the robot's tool is not seen")
        if code == _RTO_MISSING:
            return Health(False, "rto_missing", "the reference tool is not seen")
        if code == _STALE:
            age = now - min(self._rows[index, 8], self._rows[index + n, 8])
            limit = self._stale_limit[index]
            return Health(
                False, "stale", f"no new frame for {age * 1e3:.0f} ms (limit {limit * 1e3:.0f} ms)"
            )
        if code == _CORRUPT:
            return Health(False, "corrupt", "a tool's pose is not a finite unit pose")
        if code == _JUMP:
            before = self._before[index]
            jump = math.dist(self._rows[index, :3], before[:3])
            dt = max(self._rows[index, 8] - before[3], self._period[index])
            return Health(
                False,
                "corrupt",
                f"the robot's tool jumped {jump * 1e3:.1f} mm in {dt * 1e3:.0f} ms",
            )
        raise AssertionError(code)  # calibration verdicts are built by _check_calibration

    def due_in(self, now: float) -> float | None:
        """How long until a sensor that is not stale yet becomes stale if nothing more
        arrives (s; None: every sensor is stale or has never sent): when to look again
        without a sample to wake on."""
        n = self._n
        at = self._rows[:, 8]
        deadlines = np.minimum(at[:n], at[n:]) + self._stale_limit
        ahead = deadlines[deadlines >= now]
        return float(ahead.min() - now) if len(ahead) else None

    def evaluate(self, now: float) -> Decision:
        """One cycle: every sensor's health, the best sensor, the robot pose (eq. 3.5)."""
        rows = self._rows
        self._now = now
        codes = self._fault_codes(now, rows, self._before)
        candidates = np.flatnonzero(codes == 0)
        local = np.zeros((0, 4, 4))
        verdicts: dict[int, Health] = {}
        if len(candidates):
            local = self._local_poses(candidates, rows)
            verdicts = self._check_calibration(candidates, local)
            for index in verdicts:
                codes[index] = _CALIBRATION
            self._measure_offsets([i for i in candidates.tolist() if i not in verdicts])
        best, robot = None, None
        hysteresis, fresh = self.config.hysteresis, self._fresh
        for index, (track, code) in enumerate(zip(self.tracks, codes.tolist(), strict=True)):
            if code == _CALIBRATION:
                track.health = verdicts[index]
            elif code != track.code:
                track.health = self._describe(index, code, now)
            track.code = code
            if code:
                track.streak = 0
            elif fresh[index]:
                track.streak += 1
            track.health.streak = track.streak
            if best is None and not code:
                name = track.config.name
                if track.streak >= hysteresis or name == self.best:
                    best = name
                    k = candidates.tolist().index(index)
                    robot = self._c[index] @ local[k] @ self._y_inv[index]
        self._fresh = [False] * self._n
        changed = best != self.best
        self.best = best
        self.last = Decision(best, {t.config.name: t.health for t in self.tracks}, robot, changed)
        return self.last

    def _measure_offsets(self, healthy: list[int]) -> None:
        """How each healthy tracker's view of the end-effector on the patient differs
        from the master's, measured at one instant (both trackers' samples taken at the
        same `t`, between the samples around it): E_i E_master^-1, with E = C RTO^-1 CTO
        (the TCP in the CTO frame), averaged over `OFFSET_SMOOTHING`. The calibrations'
        difference, never the patient's or the robot's motion: what a swap must carry
        (the navigator). Kept when a tracker stops being healthy: its last one stands."""
        master = self._index[self.config.master]
        if master not in healthy:
            return
        for index in healthy:
            if index == master:
                continue
            pair = (master, index)
            t = min(min(self._samples[i].newest(), self._references[i].newest()) for i in pair)
            if not math.isfinite(t) or t <= self._offsets_at.get(index, -math.inf):
                continue
            views = []
            for i in pair:
                cto, rto = self._samples[i].at(t), self._references[i].at(t)
                if cto is None or rto is None:
                    break
                tools = _matrices(np.array([cto[0], rto[0]]))
                views.append(self._c[i] @ invert(tools[1]) @ tools[0] @ self._cto_from_ee[i])
            if len(views) < 2:
                continue
            offset = views[1] @ invert(views[0])
            last = self._offsets.get(index)
            if last is None:
                self._offsets[index] = offset
            else:
                weight = 1.0 - math.exp(-(t - self._offsets_at[index]) / OFFSET_SMOOTHING)
                self._offsets[index] = _nlerp(last, offset, weight)
            self._offsets_at[index] = t

    def offsets(self) -> dict[str, np.ndarray]:
        """Each tracker's view of the end-effector on the patient against the master's,
        measured at one instant and averaged (`_measure_offsets`): a swap from tracker a
        to b carries offsets[b] @ offsets[a]^-1. The master's is the identity."""
        out = {self.config.master: np.eye(4)}
        for index, offset in self._offsets.items():
            out[self.tracks[index].config.name] = offset
        return out

    def _local_poses(self, candidates: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The CTO in each candidate sensor's reference-tool frame, batched.

        Eq. 3.5 with C_i = X_master X_i^-1 (eq. 3.3) mapping sensor i's reference frame
        into the master's: ee = C_i (T_RTO,i)^-1 T_CTO,i Y_i^-1. (The thesis writes C_i^-1
        in eq. 3.5, which matches the opposite direction for C.) The end-effector, not
        the CTO, is compared across sensors: each sensor sees its own markers."""
        n = self._n
        if len(candidates) != n:
            rows = rows[np.concatenate([candidates, candidates + n])]
        points, quats = rows[:, :3], rows[:, 3:7]
        rotations = quat_to_matrix(quats)
        k = len(candidates)
        rto_t = np.swapaxes(rotations[k:], 1, 2)
        local = np.zeros((k, 4, 4))
        local[:, :3, :3] = rto_t @ rotations[:k]
        local[:, :3, 3] = (rto_t @ (points[:k] - points[k:])[:, :, None])[:, :, 0]
        local[:, 3, 3] = 1.0
        return local

    def _check_calibration(self, candidates: np.ndarray, local: np.ndarray) -> dict[int, Health]:
        """Fault-tree level 4, against kinematics if known, else against each other:
        the verdicts of the sensors that fail it, by sensor index."""
        failed: dict[int, Health] = {}
        if self.kinematics is not None:
            positions, stamps, samples, behind = self._comparable(candidates)
            verdicts = self._verdicts
            times = self._times
            if len(times) >= 2:  # with history, a verdict is about a sample and a pose
                checked, pairs = self._checked, []
                for p, t in zip(positions, stamps, strict=True):
                    pairs.append((int(candidates[p]), (t, times[self._nearest(t)])))
                new = [k for k, (index, pair) in enumerate(pairs) if checked.get(index) != pair]
                if len(new) < len(positions):
                    positions = [positions[k] for k in new]
                    stamps = [stamps[k] for k in new]
                    samples = [samples[k] for k in new]
                checked.update(pairs[k] for k in new)
            poses = [self._kinematics_at(t) for t in stamps]
            known: list[int] = []
            now, last = self._now, self._pose_checked
            for k, pose in enumerate(poses):
                index = int(candidates[positions[k]])
                if pose is not None:
                    known.append(k)
                    last[index] = now
                    continue
                self.unchecked += 1  # no robot pose of its time: its verdict holds, a while
                since = now - last.setdefault(index, now)
                if since > CHECK_LAG_LIMIT:
                    verdicts[index] = Health(
                        False,
                        "calibration",
                        f"cannot be checked: no robot pose of its samples' times for "
                        f"{since * 1e3:.0f} ms (limit {CHECK_LAG_LIMIT:g} s)",
                        numbers={
                            "check": "kinematics",
                            "time": stamps[k],
                            **self._pose_times(stamps[k]),
                        },
                    )
            if known:
                verdicts.update(
                    self._against_kinematics(
                        candidates[[positions[k] for k in known]],
                        [stamps[k] for k in known],
                        [samples[k] for k in known],
                        np.stack([poses[k] for k in known]),
                    )
                )
            verdicts.update(behind)  # until checked again, a sensor keeps its verdict
            camera = self._camera[candidates]
            for index in candidates.tolist():
                verdict = verdicts.get(index)
                if verdict is not None:
                    failed[index] = verdict
            bad = np.isin(candidates, list(failed))
            agreed = np.flatnonzero(camera & ~bad)
            if len(agreed) >= 2:
                failed.update(self._references_agree(candidates[agreed]))
            for index in candidates.tolist():
                if index in self._moved and index not in failed:
                    failed[index] = self._moved[index]
            return failed
        if len(candidates) < 2:
            return failed
        master = self._c[candidates] @ local @ self._y_inv[candidates]
        for k, i in enumerate(candidates):
            others = [j for j in range(len(candidates)) if j != k]
            agree = sum(self._close(int(i), master[k], master[j]) for j in others)
            if agree * 2 < len(others):  # fewer than half agree (one other: it must)
                names = ", ".join(self.tracks[candidates[j]].config.name for j in others)
                failed[int(i)] = Health(
                    False, "calibration", f"disagrees with {names} beyond tolerance"
                )
        return failed

    def _against_kinematics(
        self,
        checked: np.ndarray,
        stamps: list[float],
        samples: list[tuple[float, ...]],
        kinematics: np.ndarray,
    ) -> dict[int, Health | None]:
        """Each checked sensor's CTO sample against the robot's kinematics at its stamp
        (`kinematics`, one pose per sample): its verdict (None: within tolerance), by
        sensor index."""
        camera = self._camera[checked]
        x = self._x[checked]
        x[camera] = self._s[checked[camera]]
        # the CTO as seen, in the tracker's frame (against S K Y), or in the reference
        # tool's frame (against X K Y)
        measured = _matrices(np.array(samples))
        if not camera.all():
            rto = self._rto_matrices(checked[~camera])
            measured[~camera] = invert(rto) @ measured[~camera]
        predicted = x @ kinematics @ self._y[checked]
        diff = measured[:, :3, 3] - predicted[:, :3, 3]
        offsets2 = (diff * diff).sum(axis=1)
        # trace(A^T B) = 1 + 2 cos(angle): compare cosines, no arccos for healthy rows
        cosines = ((measured[:, :3, :3] * predicted[:, :3, :3]).sum(axis=(1, 2)) - 1.0) / 2.0
        wrong = (offsets2 > self._tol_pos2[checked]) | (cosines < self._tol_cos[checked])
        verdicts: dict[int, Health | None] = {}
        for k, index in enumerate(checked.tolist()):
            if not wrong[k]:
                verdicts[index] = None
                continue
            angle = math.degrees(math.acos(min(1.0, max(-1.0, cosines[k]))))
            verdicts[index] = Health(
                False,
                "calibration",
                f"{math.sqrt(offsets2[k]) * 1e3:.1f} mm, "
                f"{angle:.2f} deg away from the robot's kinematics",
                numbers={
                    "check": "kinematics",
                    "time": stamps[k],
                    **self._pose_times(stamps[k]),
                    "measured_mm": _mm(measured[k, :3, 3]),
                    "predicted_mm": _mm(predicted[k, :3, 3]),
                    "apart_mm": round(math.sqrt(offsets2[k]) * 1e3, 3),
                    "tolerance_mm": round(float(self._tol_pos[index]) * 1e3, 3),
                    "angle_deg": round(angle, 3),
                },
            )
        return verdicts

    def _references_agree(self, sensors: np.ndarray) -> dict[int, Health]:
        """The verdicts of the sensors whose view of the patient is the odd one out, from
        the latest instant all of them were compared at (a new comparison each time the
        slowest of them has a new sample; between, the last one's verdicts hold). One
        found odd at two comparisons running (two samples of the slowest tracker) is
        latched: it stays distrusted, alone or not, until `trust`."""
        compared = tuple(sensors.tolist())
        t = min(self._references[i].newest() for i in compared)
        if (t, compared) != self._compared and math.isfinite(t):
            odd = self._check_references(sensors, t)
            if odd is not None:
                self._compared, self._odd = (t, compared), odd
                for index in compared:
                    if index not in odd:
                        self._odd_checks.pop(index, None)
                        continue
                    self._odd_checks[index] = self._odd_checks.get(index, 0) + 1
                    if self._odd_checks[index] >= 2:
                        self._moved[index] = odd[index]
        return {i: h for i, h in self._odd.items() if i in compared}

    def trust(self, name: str) -> bool:
        """Trust again a sensor whose reference tool was found moved (its calibration was
        redone); False if it was not distrusted."""
        self._odd_checks.pop(self._index[name], None)
        self._odd.pop(self._index[name], None)
        return self._moved.pop(self._index[name], None) is not None

    def _rto_matrices(self, sensors: np.ndarray) -> np.ndarray:
        """The latest RTO of these sensors, in their own frames."""
        return _matrices(self._rows[sensors + self._n])

    def _check_references(self, sensors: np.ndarray, t: float) -> dict[int, Health] | None:
        """Sensors calibrated to the robot must also agree about where the patient is:
        their reference tools sit on the same head clamp, so each one's reference tool,
        placed in the robot base by its calibration (S) and mapped into the master's
        reference frame (C), is the same pose, at the same instant. Each sensor's
        reference tool is taken at `t` (between its samples around it), so a head that
        moves is seen alike by all (a fast tracker sees a bump before a slow one's next
        frame: their newest samples differ by the motion in between). Two agree within
        the larger of their tolerances, widened by what the interpolation and the stamps
        may miss of the motion each measured. One that disagrees with most others (of
        two, the one further from where the calibration found the patient) had its
        reference tool moved on its mount: its verdict, with the numbers. None when some
        sensor's samples do not reach `t`."""
        aligned = [self._references[i].at(t) for i in sensors.tolist()]
        if any(a is None for a in aligned):
            return None
        rto = _matrices(np.array([a[0] for a in aligned]))  # type: ignore[index]
        patient = self._s_inv[sensors] @ rto @ invert(self._c[sensors])
        slack = np.array([a[1] + a[2] * STAMP_UNCERTAINTY for a in aligned])  # type: ignore[index]
        master = self._base_from_rto[self._index[self.config.master]]
        moved = np.linalg.norm(patient[:, :3, 3] - master[:3, 3], axis=1)
        k_all = range(len(sensors))
        apart = {(k, j): norm(patient[k, :3, 3] - patient[j, :3, 3]) for k in k_all for j in k_all}
        tolerance = {
            (k, j): max(self._tol_pos[sensors[k]], self._tol_pos[sensors[j]]) + slack[k] + slack[j]
            for k in k_all
            for j in k_all
        }

        def agree(k: int, j: int) -> bool:
            turn = float(rotation_angle(patient[k, :3, :3].T @ patient[j, :3, :3]))
            limit = max(self._tol_angle[sensors[k]], self._tol_angle[sensors[j]])
            return apart[k, j] <= tolerance[k, j] and turn <= limit

        suspects = []
        for k in k_all:
            others = [j for j in k_all if j != k]
            if sum(agree(k, j) for j in others) * 2 < len(others):
                suspects.append(k)
        if len(suspects) == len(sensors):  # nobody has a majority: trust the steadiest
            suspects.remove(int(np.argmin(moved)))
        failed = {}
        for k in suspects:
            others = [j for j in k_all if j != k]
            nearest = min(others, key=lambda j: apart[k, j])
            names = ", ".join(self.tracks[sensors[j]].config.name for j in others)
            failed[int(sensors[k])] = Health(
                False,
                "calibration",
                f"disagrees with {names} by {apart[k, nearest] * 1e3:.1f} mm about where the "
                f"patient is (tolerance {tolerance[k, nearest] * 1e3:.1f} mm at "
                f"{t:.3f} s): its reference tool moved on the head clamp",
                numbers={
                    "check": "patient",
                    "time": t,
                    "patient_mm": {
                        self.tracks[sensors[j]].config.name: _mm(patient[j, :3, 3]) for j in k_all
                    },
                    "apart_mm": round(apart[k, nearest] * 1e3, 3),
                    "tolerance_mm": round(tolerance[k, nearest] * 1e3, 3),
                },
            )
        return failed

    def _close(self, i: int, a: np.ndarray, b: np.ndarray) -> bool:
        cfg = self.tracks[i].config
        offset = norm(a[:3, 3] - b[:3, 3])
        angle = float(rotation_angle(a[:3, :3].T @ b[:3, :3]))
        return offset <= cfg.tolerance_position and angle <= cfg.tolerance_angle


def _nlerp(a: np.ndarray, b: np.ndarray, weight: float) -> np.ndarray:
    """The pose `weight` of the way from `a` to `b`: linear in position, normalised
    linear in the quaternion (the offsets it averages differ by fractions of a degree)."""
    qa, qb = np.array(matrix_to_quat(a[:3, :3])), np.array(matrix_to_quat(b[:3, :3]))
    if float(qa @ qb) < 0.0:
        qb = -qb
    q = qa + weight * (qb - qa)
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix(q / norm(q))
    out[:3, 3] = a[:3, 3] + weight * (b[:3, 3] - a[:3, 3])
    return out


def _mm(position: np.ndarray) -> list[float]:
    """A position (m) as millimetres for a report."""
    return [round(float(v) * 1e3, 3) for v in position]


def _matrices(vectors: np.ndarray) -> np.ndarray:
    """Poses (x y z qw qx qy qz per row) as 4x4 matrices."""
    out = np.zeros((len(vectors), 4, 4))
    out[:, :3, :3] = quat_to_matrix(vectors[:, 3:7])
    out[:, :3, 3] = vectors[:, :3]
    out[:, 3, 3] = 1.0
    return out


def _numbers(health: Health) -> dict[str, Any]:
    """A verdict's numbers for a message (none when it has none)."""
    return {"numbers": health.numbers} if health.numbers else {}


TOOLS = ("cto", "rto")
"""The tools of every tracker: the calibration tool on the robot, the reference tool."""


def _tracker_inputs(config: SensorsConfig, file: str) -> list[tuple[str, str, FileInput]]:
    """(sensor, tool, input) of every tracker tool the sensors file names: the port
    `<sensor>_<tool>`, usually fed by the tracker component's `<tool>` output."""
    return [
        (
            sensor.name,
            tool,
            FileInput(
                f"{sensor.name}_{tool}",
                Pose,
                f"{file}: sensors.{sensor.name}",
                f"{sensor.name}.{tool}",
                ConnPolicy("buffer", 64),
            ),
        )
        for sensor in config.sensors
        for tool in TOOLS
    ]


class SensorManager(Component):
    """Feeds `SensorManagerCore` from the trackers' ports and publishes its decisions,
    once per cycle of its activity: periodic, or (cheaper) event-driven on the trackers'
    ports, when it also wakes by itself just after the next staleness deadline, so a
    tracker that falls silent is found as soon as its limit has passed."""

    sensors_file = prop(
        str, "", doc="sensors YAML (priorities, calibration, limits)", required=True, file="sensors"
    )
    ee_pose = In(
        Pose,
        doc="end-effector in the robot base frame, from joints (optional); every pose is "
        "kept (64 of them): each tracker sample is checked against the pose of its time",
        policy={"type": "buffer", "size": 64},
    )
    robot_pose = Out(
        Pose,
        doc="end-effector in the master frame (eq. 3.5), best sensor; a stream: put on the "
        "bus only while a reader in another process listens (no reader in SEEG: each put a "
        "hand-over of the interpreter lock in the Sensor Manager's process)",
        stream=True,
    )
    status = Out(EventMessage, doc="best sensor, its limits, every sensor's health")

    @classmethod
    def file_inputs(cls, properties: dict[str, Any]) -> list[FileInput]:
        """A `<sensor>_cto` and `<sensor>_rto` Pose input per sensor of the sensors file
        (the topology connects them, usually from the tracker's `cto` and `rto`)."""
        file = str(properties.get("sensors_file", ""))
        return [wanted for _, _, wanted in _tracker_inputs(load_sensors(file), file)]

    def __init__(self, name: str):
        super().__init__(name)
        self.core: SensorManagerCore | None = None
        """The decisions, made by `configure` from the sensors file."""

    def configure_hook(self) -> bool:
        config = load_sensors(self.sensors_file)
        ports = {port.name: port for port in self.file_ports()}
        self.core = SensorManagerCore(config)
        self.tracker_ports: list[tuple[str, str, InputPort[Pose]]] = [
            (sensor, tool, ports[wanted.port])
            for sensor, tool, wanted in _tracker_inputs(config, self.sensors_file)
        ]
        self._last_status = -math.inf  # the first cycle says where tracking stands
        self._frames: dict[tuple[str, str], int] = {}
        self._postponed = False
        return True

    def update_hook(self, idle: bool = False) -> None:
        """Take every new sample, then decide: once per tracker frame, not once per
        sample. A tracker sends its two tools of a frame back to back; woken by the
        first, the manager waits for the second (once: the next wake decides whatever
        came, and a silent tracker is found by the idle wake, `idle`). Runs in the
        component's event thread."""
        now = self.clock.now()
        frames = self._frames
        for sensor, tool, port in self.tracker_ports:
            while True:
                status, pose = port.read()
                if status is not ReadStatus.NEW:
                    break
                # samples and robot poses are paired in time on this host's clock
                stamp = self.local_stamp(f"{sensor}_{tool}", pose.stamp)
                if stamp is None:
                    self.refuse(f"{sensor}_{tool}", UNMEASURED)
                    continue
                if stamp != pose.stamp:
                    pose = dataclasses.replace(pose, stamp=stamp)
                self.core.offer(sensor, tool, pose, now)
                frames[sensor, tool] = pose.frame_number
        while True:  # every pose since the last update (200 Hz; the trackers' are 20-100)
            status, ee = self.ee_pose.read()
            if status is not ReadStatus.NEW or ee is None:
                break
            stamp = self.local_stamp("ee_pose", ee.stamp)
            if stamp is None:
                self.refuse("ee_pose", UNMEASURED)
                continue
            self.core.set_kinematics(pose_matrix(ee), stamp)
        if not idle and not self._postponed and self._half_a_frame():
            self._postponed = True
            return
        self._postponed = False
        decision = self.core.evaluate(now)
        if decision.robot_pose is not None:
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
        if decision.changed or now - self._last_status >= STATUS_PERIOD:
            self._last_status = now
            self.status.write(
                EventMessage(time.time(), "tracking", self.name, self.describe_decision(decision))
            )
        due = self.core.due_in(now)
        status_due = self._last_status + STATUS_PERIOD - now
        self.idle_within = status_due if due is None else min(due + STALE_MARGIN, status_due)

    def idle_hook(self) -> None:
        """No sample for a while (event-driven): a staleness deadline or the status is due."""
        self.update_hook(idle=True)

    def _half_a_frame(self) -> bool:
        """Whether a tracker's newest samples of its two tools are of different frames
        (the other tool's sample of the newer frame is on its way)."""
        frames = self._frames
        for sensor in self.core.by_name:
            cto, rto = frames.get((sensor, "cto")), frames.get((sensor, "rto"))
            if cto is not None and rto is not None and cto != rto:
                return True
        return False

    def describe_decision(self, decision: Decision) -> dict[str, Any]:
        """The decision as plain data."""
        best = self.core.by_name[decision.best].config if decision.best else None
        return {
            "best": decision.best,
            "limits": best.limits if best else {},
            "calibration": best.master_from_sensor.tolist() if best else None,
            "health": {
                n: {"ok": h.ok, "cause": h.cause, "detail": h.detail, **_numbers(h)}
                for n, h in decision.health.items()
            },
            # same-instant differences of the trackers' views (what a swap carries)
            "offsets": {n: pose_list(p) for n, p in self.core.offsets().items()},
            "unchecked": self.core.unchecked,  # samples in a pause of the robot's poses
        }

    @operation
    def trust(self, sensor: str) -> dict[str, Any]:
        """Trust again a sensor found with its reference tool moved on the head clamp,
        once its calibration was redone (`fw calibrate`); the latest decision."""
        if sensor not in self.core.by_name:
            raise FwError(f"no sensor {sensor!r}: one of {', '.join(self.core.by_name)}")
        if not self.core.trust(sensor):
            raise FwError(f"{sensor} is not distrusted for a moved reference tool")
        return self.current()

    @operation(readonly=True)
    def current(self) -> dict[str, Any]:
        """The latest decision (best sensor, limits, health of every sensor)."""
        core = self.core
        last = core.last if core is not None else None
        if last is None:  # not configured yet, or no cycle run yet
            return {"best": None, "limits": {}, "calibration": None, "health": {}}
        return self.describe_decision(last)
