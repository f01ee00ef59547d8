"""The Workspace People Detector's computation (thesis 3.4.4, Fig. 3.17).

Per frame: each camera's users into the master camera frame (eq. 3.8); group users
across cameras (eq. 3.9 rule or the global assignment) and fuse them weighted by
their noise; into the robot base frame (eq. 3.10); persistent tracks; envelopes with
a noise margin; distances between robot link capsules and every person; the number
of people inside the area around the table.

Where the cameras look is what the detector knows and the tracker does not: whether
someone first seen by one camera stands where people come into sight (at the edge of
its view, `_entering`), and whether a track no camera sees this frame still stands
for someone (hidden behind others) or is gone (out of every view, at a view's edge,
or missed in a clear view: `_whereabouts`), judged on the whole body.

Bad input is contained: non-finite joints become unseen joints, a camera that stops
simply contributes nothing, and a camera whose calibration is wrong cannot create
people where another camera looks (its users fail to match the others and are not
trusted: a person only a non-master camera sees, where another reporting camera
should see them too, is never confirmed, and the disagreement is recorded
(`disagreements`); the master camera is trusted on ties).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from components.domain.distance import capsule_distances, closest_pair
from components.domain.skeleton import LIMBS, body_center, body_centers, envelopes
from components.people.fusion import cluster, noise_for
from components.people.tracking import PeopleTracker, Person, Track


@dataclass
class CameraConfig:
    """One camera: its name and where it is (master_from_camera, eq. 3.8)."""

    name: str
    master_from_camera: np.ndarray
    lateral_noise: float = 0.01
    verified: bool = False
    """Calibration showed it agrees with the master (board residuals): trusted from the
    first frame; runtime disagreement still makes it a suspect."""


@dataclass
class DetectorConfig:
    """Cameras, the master-to-robot transform (eq. 3.10) and the policies."""

    cameras: list[CameraConfig]
    base_from_master: np.ndarray = field(default_factory=lambda: np.eye(4))
    matcher: str = "hungarian"
    area_center: tuple[float, float] = (0.0, 0.0)  # robot base frame, m
    area_radius: float = 1.5
    margin_sigmas: float = 3.0
    confirm_after: float = 1.0
    missed_for: float = 0.2
    """s: a person in a camera's clear view that the camera misses still counts this long."""
    hidden_for: float = 2.0
    """s: a person hidden behind others from every camera still counts this long."""


@dataclass
class Frame:
    """What one frame produced."""

    tracks: list[Track]
    people: list[Track]
    users_near: int
    min_distance: float
    closest: tuple[int, str, int] | None  # (track id, limb, robot link index)
    rejected_joints: int
    suspects: list[Track] = field(default_factory=list)
    """Lasting single-camera detections from an unverified or suspect camera."""
    guarded: list[Track] = field(default_factory=list)
    """Whom the robot keeps its distance from (speed and separation monitoring): the
    people (two cameras seeing someone confirm them in that frame) and the suspects."""
    envelopes: tuple[np.ndarray, np.ndarray, np.ndarray] = field(
        default_factory=lambda: (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    )
    """The guarded's envelope capsules (p, q, radius; base frame, m), noise margin in
    the radii: what the robot keeps its distance from, and what `min_distance` is to."""


Group = tuple[frozenset[str], np.ndarray, np.ndarray]
"""A person of one frame: the cameras that saw them, fused joints (15, 3) and sigma (15,)."""

SUSPECT = 30.0
"""Frames of net disagreement with the master before a camera is suspect: a second at
the Kinect's 30 Hz, longer than a ghost lives. A master's ghost where another camera
looks is missed by that camera for the ghost's whole life (up to 27 frames); at 5
frames it took the other camera's trust, and the people only it saw went uncounted for
as long as it took to earn it back (a scene's MOTA fell from 0.99 to 0.63). A bumped
camera's copies are refused at once where the master should see them too (`missing`):
this is for the places only it sees."""
DOUBT_FOR = 1.0
"""s: how long a verified camera may go on seeing people alone where a verified camera
should see them too before it must earn its trust again: longer than a ghost lives
(under 1 s), so a ghost is no evidence against its camera; a bumped camera's copies
are contradicted every frame. (The contradicted copies themselves are never trusted
meanwhile: only the camera's other lone people wait on this.)"""


def _fraction_in_view(points: np.ndarray) -> float:
    """Share of camera-frame points inside the Kinect's view (vectorised `_in_view`)."""
    from components.people.kinect_sim import FAR, H_FOV, NEAR, V_FOV

    if not len(points):
        return 0.0
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    inside = (
        (z >= NEAR)
        & (z <= FAR)
        & (np.abs(np.arctan2(x, z)) <= H_FOV / 2)
        & (np.abs(np.arctan2(y, z)) <= V_FOV / 2)
    )
    return float(inside.mean())


FULLY_IN_VIEW = 0.8
"""Fraction of a body that must be in a camera's view before missing it counts against it."""
SHADOW = 0.35
"""m: a person this close to the line from a camera through a nearer person's torso
may be hidden by them (a body is ~0.4 m wide; limbs widen the shadow)."""


STEP = 0.15
"""m: how close to the edge of a camera's view someone first seen there may be and still
be taken for someone walking in (a walker's step in the few frames a camera may drop
or take to report them; a ghost appears anywhere in the view, seldom so close)."""

RECENT = 0.5
"""s: a person who stops counting (left every camera's view, or missed in clear view)
is still kept at a distance by the robot this long (their envelope stays)."""


def _behind(point: np.ndarray, torsos: np.ndarray, camera_from_base: np.ndarray) -> bool:
    """Whether a camera-frame point is in the shadow of one of `torsos` (base frame, k x
    3), seen from the camera: further along its line of sight, within `SHADOW` of it."""
    if not len(torsos):
        return False
    o = torsos @ camera_from_base[:3, :3].T + camera_from_base[:3, 3]
    depth = np.sqrt(np.einsum("ij,ij->i", o, o))
    along = (o @ point) / depth
    lateral = np.linalg.norm(point - (along / depth)[:, None] * o, axis=1)
    return bool(((along > depth + 0.1) & (lateral < SHADOW)).any())


class PeopleDetectorCore:
    """Everything between camera users and robot-person distances."""

    def __init__(self, config: DetectorConfig):
        self.config = config
        self.cameras = {c.name: c for c in config.cameras}
        self.tracker = PeopleTracker(config.confirm_after, config.hidden_for)
        self.master = config.cameras[0].name if config.cameras else ""
        self.disagreements: dict[tuple[str, str], int] = {}
        self.suspicion: dict[str, float] = {}
        """Per camera: grows while it misses people the master sees where it should see
        them, shrinks while it agrees; a suspect camera's lone users are not trusted."""
        self.verified: set[str] = {self.master} | {c.name for c in config.cameras if c.verified}
        """Cameras verified by calibration or seen with a verified camera (fused into one
        person): only their lone users can become people. A camera whose calibration is
        grossly wrong never fuses with anyone, so its misplaced users stay suspects."""
        self.doubt: dict[str, float] = {}
        """Per verified camera: since when, frame after frame, a verified camera should
        have seen some of its lone people too (`_update_trust`)."""

    def process(
        self,
        users: dict[str, list[tuple[int, np.ndarray]]],
        now: float,
        robot: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> Frame:
        """One frame: `users` per camera (camera-frame joints), robot link capsules
        (p, q, r in the base frame) if known."""
        names = sorted(n for n, u in users.items() if u and n in self.cameras)  # others: ignored
        counts = [len(users[n]) for n in names]
        rejected = 0
        joints, sigma = np.zeros((0, 15, 3)), np.zeros((0, 15))
        camera_of = np.zeros(0, dtype=int)
        if names:
            joints = np.array([j for n in names for _, j in users[n]], dtype=float)  # (N, 15, 3)
            finite = np.isfinite(joints).all(axis=2)
            rejected = int((~finite).sum() - np.isnan(joints).all(axis=2).sum())
            joints[~finite] = np.nan
            camera_of = np.repeat(np.arange(len(names)), counts)
            lateral = np.array([self.cameras[n].lateral_noise for n in names])
            sigma = noise_for(joints, lateral[camera_of, None])
            sigma[~finite] = 0.0
            # into the robot base, each camera's users by its registration at once
            registration = np.array([self._base_from_camera(n) for n in names])
            rotation = registration[camera_of, :3, :3].transpose(0, 2, 1)  # (N, 3, 3)
            joints = joints @ rotation + registration[camera_of, None, :3, 3]
            keep = finite.any(axis=1)  # a skeleton with nothing seen is nobody
            joints, sigma, camera_of = joints[keep], sigma[keep], camera_of[keep]
        reporting = [name for name in users if name in self.cameras]
        group_of, fused, fused_sigma = cluster(joints, sigma, camera_of, self.config.matcher)
        seen_by: list[set[str]] = [set() for _ in range(len(fused))]
        for group, camera in zip(group_of.tolist(), camera_of.tolist(), strict=True):
            seen_by[group].add(names[camera])
        grouped = [
            (frozenset(cameras), fused[i], fused_sigma[i]) for i, cameras in enumerate(seen_by)
        ]
        self._update_suspicion(grouped, reporting, fused)
        missing: dict[int, list[str]] = {}
        """Per lone user of a non-master camera: the reporting cameras that should see
        them too and do not (a misplaced copy, or a ghost)."""
        for i, (cameras, joints, _) in enumerate(grouped):
            if len(cameras) == 1 and self.master not in cameras:
                camera = next(iter(cameras))
                missing[i] = self._should_see(joints, cameras, reporting, np.delete(fused, i, 0))
                for other in missing[i]:
                    self.disagreements[(camera, other)] = (
                        self.disagreements.get((camera, other), 0) + 1
                    )
        contradicted = {
            next(iter(grouped[i][0]))
            for i, others in missing.items()
            if set(others) & self.verified
        }
        self._update_trust(grouped, contradicted, now)
        people = []
        for i, (cameras, joints, sigma) in enumerate(grouped):
            trusted = True
            if i in missing:
                camera = next(iter(cameras))
                trusted = (
                    not missing[i]
                    and self.suspicion.get(camera, 0.0) < SUSPECT
                    and camera in self.verified
                )
            entering = len(cameras) == 1 and self._entering(joints, next(iter(cameras)))
            if entering and i not in missing:  # the master's: no one may contradict it
                others = np.delete(fused, i, 0)
                entering = not self._should_see(joints, cameras, reporting, others)
            people.append(Person(joints, sigma, cameras, trusted, entering))
        tracks = self.tracker.update(people, now)
        seen_now: np.ndarray | None = None
        confirmed, lately = [], []
        for t in tracks:
            verdict = "there"
            if t.confirmed and t.last_seen < now:
                if seen_now is None:
                    seen = [s.joints for s in tracks if s.last_seen == now]
                    seen_now = np.stack(seen) if seen else np.zeros((0, 15, 3))
                verdict = self._whereabouts(t, now, reporting, seen_now)
            if t.confirmed and verdict == "there":
                confirmed.append(t)
                continue
            if t.confirmed:
                self.tracker.lose(t, left=verdict == "left")
            if t.gone and now - t.last_seen <= RECENT:
                lately.append(t)
        near = 0
        if confirmed:
            where = body_centers(np.stack([t.joints for t in confirmed]))[:, :2]
            offset = where - np.array(self.config.area_center)
            with np.errstate(invalid="ignore"):  # nobody seen at all: NaN, not near
                near = int((np.hypot(offset[:, 0], offset[:, 1]) <= self.config.area_radius).sum())
        # lasting detections nobody corroborates are not people, but the robot keeps its
        # distance from them too: distrust must never hide a real person from a STOP
        suspects = [
            t
            for t in tracks
            if not t.confirmed
            and t.last_seen == now
            and now - t.first_seen >= self.config.confirm_after
        ]
        guarded = confirmed + suspects + lately
        envelope = self._envelopes(guarded)
        distance, closest = float("inf"), None
        if robot is not None and guarded:
            distance, closest = self._distances(guarded, envelope, robot)
        return Frame(
            tracks,
            confirmed,
            near,
            distance,
            closest,
            rejected,
            suspects,
            guarded,
            envelope[:3],
        )

    def _whereabouts(self, track: Track, now: float, reporting: list[str], seen: np.ndarray) -> str:
        """Whether a confirmed track no camera saw this frame still stands for someone
        ("there"), is missed where cameras look ("missed"), or "left" every view.
        Judged on their whole body where they should be now (the joints no camera saw
        where the body's shape puts them: someone walking out of a view is last seen
        with only the joints still inside it): in some camera's clear view, there for
        `missed_for`; hidden behind others from every camera that has them in view (or
        where a camera that sent nothing this frame would report them: a dropped frame
        is no evidence), for up to `hidden_for`; out of every camera's view, or at its
        edge (under `FULLY_IN_VIEW` of the body inside it, where a camera stops
        reporting someone walking out), not at all."""
        unseen = now - track.last_seen
        if unseen > self.config.hidden_for:
            return "missed"
        body = track.whole()
        body = body[np.isfinite(body).all(axis=1)]
        if not len(body):
            return "left"
        torsos = seen[:, 2][np.isfinite(seen[:, 2]).all(axis=1)]
        clear = hidden = False
        for name in self.cameras:
            camera_from_base = self._camera_from_base(name)
            points = body @ camera_from_base[:3, :3].T + camera_from_base[:3, 3]
            inside = _fraction_in_view(points)
            if name not in reporting:  # this camera sent nothing (a dropped frame): unknown
                hidden |= inside > 0.5  # where it would report them, they may well be
                continue
            if inside < FULLY_IN_VIEW:
                continue  # out of this camera's view, or at its edge: walking out
            if _behind(points.mean(axis=0), torsos, camera_from_base):
                hidden = True  # behind someone
            else:
                clear = True
        if clear:
            return "there" if unseen <= self.config.missed_for else "missed"
        return "there" if hidden else "left"

    def _entering(self, joints: np.ndarray, camera: str) -> bool:
        """Whether a body one camera sees stands where people come into its sight: a
        step of `STEP` (sideways or in depth) would leave no more than half of it in
        view. Joints the camera does not see count as out of view (someone coming in
        at the edge, or out from behind someone, is seen in part)."""
        camera_from_base = self._camera_from_base(camera)
        rotation, origin = camera_from_base[:3, :3], camera_from_base[:3, 3]
        points = joints @ rotation.T + origin  # unseen joints stay NaN: never in view
        for axis in (0, 2):  # the camera's sideways and depth directions, on the floor
            step = rotation[axis].copy()
            step[2] = 0.0
            norm = float(np.hypot(step[0], step[1]))
            if norm < 1e-6:
                continue
            shift = rotation @ (step * (STEP / norm))
            for sign in (1.0, -1.0):
                if _fraction_in_view(points + sign * shift) <= 0.5:
                    return True
        return False

    def _envelopes(
        self, people: list[Track]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`skeleton.envelopes` of these tracks (an unknown sigma counts as 5 cm)."""
        if not people:
            empty = np.zeros((0, 3))
            none = np.zeros(0, dtype=int)
            return empty, empty, np.zeros(0), none, none
        joints = np.stack([t.joints for t in people])
        sigma = np.stack([t.sigma for t in people])
        return envelopes(joints, np.where(np.isnan(sigma), 0.05, sigma), self.config.margin_sigmas)

    def _update_trust(self, grouped: list[Group], contradicted: set[str], now: float) -> None:
        """Cameras seen fusing with a verified camera become verified; a verified camera
        that sees people alone where a verified camera should see them too
        (`contradicted`) in every frame for `DOUBT_FOR`, never fusing with a verified
        camera meanwhile, loses its trust (bumped after calibration: its copies land
        beside or far from the real people). Seeing people no other camera can see is
        no evidence: cameras in a room's corners share few people."""
        agreeing: set[str] = set()
        for cameras, _, _ in grouped:
            if len(cameras) > 1 and cameras & self.verified:
                self.verified |= cameras
                agreeing |= cameras
        doubted = (contradicted & self.verified) - agreeing - {self.master}
        for camera in set(self.doubt) - doubted:  # agreed, or nothing contradicted
            del self.doubt[camera]
        for camera in doubted:
            since = self.doubt.setdefault(camera, now)
            if now - since >= DOUBT_FOR:
                self.verified.discard(camera)
                del self.doubt[camera]
                self.disagreements[(camera, self.master)] = (
                    self.disagreements.get((camera, self.master), 0) + 1
                )

    def _update_suspicion(
        self, grouped: list[Group], reporting: list[str], fused: np.ndarray
    ) -> None:
        """Cameras that see the master's people with it grow trusted; those that miss
        people the master sees where they should see them grow suspect."""
        for i, (cameras, joints, _) in enumerate(grouped):
            if self.master not in cameras:
                continue
            for camera in cameras:  # agrees with the master (nothing to do if unsuspected)
                if self.suspicion.get(camera) and camera != self.master:
                    self.suspicion[camera] = max(0.0, self.suspicion[camera] - 1.0)
            if cameras == {self.master}:
                others = np.delete(fused, i, axis=0)
                for camera in self._should_see(joints, cameras, reporting, others):
                    self.suspicion[camera] = min(3 * SUSPECT, self.suspicion.get(camera, 0.0) + 1.0)
                    if self.suspicion[camera] >= SUSPECT:  # trust, even from calibration, is lost
                        self.verified.discard(camera)
                    self.disagreements[(camera, self.master)] = (
                        self.disagreements.get((camera, self.master), 0) + 1
                    )

    def _base_from_camera(self, name: str) -> np.ndarray:
        """A camera's registration into the robot base (eq. 3.8 then 3.10), cached."""
        cache = self.__dict__.setdefault("_registrations", {})
        if name not in cache:
            cache[name] = self.config.base_from_master @ self.cameras[name].master_from_camera
        return cache[name]

    def _camera_from_base(self, name: str) -> np.ndarray:
        """The inverse of a camera's registration (cached: calibrations are constant)."""
        cache = self.__dict__.setdefault("_inverse_registrations", {})
        if name not in cache:
            cache[name] = np.linalg.inv(self._base_from_camera(name))
        return cache[name]

    def _should_see(
        self,
        joints: np.ndarray,
        seen_by: frozenset[str],
        reporting: list[str],
        others: np.ndarray,
    ) -> list[str]:
        """Reporting cameras that should see this person (torso inside their field of view,
        not hidden behind another person of `others` (k, 15, 3)) but did not."""
        torso = body_center(joints)
        if not np.isfinite(torso).all():
            return []
        torsos = others[:, 2][np.isfinite(others[:, 2]).all(axis=1)]
        missing = []
        for name in reporting:
            if name in seen_by:
                continue
            camera_from_base = self._camera_from_base(name)
            point = camera_from_base[:3, :3] @ torso + camera_from_base[:3, 3]
            body = joints[np.isfinite(joints).all(axis=1)] @ camera_from_base[:3, :3].T
            body += camera_from_base[:3, 3]
            if _fraction_in_view(body) < FULLY_IN_VIEW:
                continue  # at the edge of its view a camera may rightly lose the person
            if not _behind(point, torsos, camera_from_base):
                missing.append(name)
        return missing

    def _distances(
        self,
        people: list[Track],
        envelope: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        robot: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> tuple[float, tuple[int, str, int] | None]:
        p, q, r, owner, limb = envelope
        matrix = capsule_distances(robot[0], robot[1], robot[2], p, q, r)
        value, link, column = closest_pair(matrix)
        if link < 0:
            return float("inf"), None
        a, b, _ = LIMBS[limb[column]]
        return value, (people[owner[column]].id, f"{a}-{b}", link)
