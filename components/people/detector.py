"""The Workspace People Detector's computation (thesis 3.4.4, Fig. 3.17).

Per frame: each camera's users into the master camera frame (eq. 3.8); group users
across cameras (eq. 3.9 rule or the global assignment) and fuse them weighted by
their noise; into the robot base frame (eq. 3.10); persistent tracks; envelopes with
a noise margin; distances between robot link capsules and every person; the number
of people inside the area around the table. Bad input is contained: non-finite joints
become unseen joints, a camera that stops simply contributes nothing, and a camera
whose calibration is wrong cannot create people (its users fail to match the others
and stay tentative unless seen long enough).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from components.people.distance import capsule_distances, closest_pair
from components.people.fusion import Detection, group_and_fuse, noise_for
from components.people.skeleton import LIMBS, envelope, limbs_seen
from components.people.tracking import PeopleTracker, Person, Track


@dataclass
class CameraConfig:
    """One camera: its name and where it is (master_from_camera, eq. 3.8)."""

    name: str
    master_from_camera: np.ndarray
    lateral_noise: float = 0.01


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
    delete_after: float = 0.5


@dataclass
class Frame:
    """What one frame produced."""

    tracks: list[Track]
    people: list[Track]
    users_near: int
    min_distance: float
    closest: tuple[int, str, int] | None  # (track id, limb, robot link index)
    rejected_joints: int


class PeopleDetectorCore:
    """Everything between camera users and robot-person distances."""

    def __init__(self, config: DetectorConfig):
        self.config = config
        self.cameras = {c.name: c for c in config.cameras}
        self.tracker = PeopleTracker(config.confirm_after, config.delete_after)

    def process(
        self,
        users: dict[str, list[tuple[int, np.ndarray]]],
        now: float,
        robot: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> Frame:
        """One frame: `users` per camera (camera-frame joints), robot link capsules
        (p, q, r in the base frame) if known."""
        detections, rejected = [], 0
        for name, camera_users in users.items():
            camera = self.cameras.get(name)
            if camera is None:
                continue  # not configured: ignored, never a person
            transform = self.config.base_from_master @ camera.master_from_camera
            for uid, joints in camera_users:
                joints = np.array(joints, dtype=float)
                bad = ~np.isfinite(joints).all(axis=1)
                rejected += int(bad.sum() - np.isnan(joints).all(axis=1).sum())
                joints[bad] = np.nan
                if bad.all():
                    continue
                sigma = noise_for(joints, camera.lateral_noise)
                in_base = joints @ transform[:3, :3].T + transform[:3, 3]
                detections.append(Detection(name, uid, in_base, np.nan_to_num(sigma)))
        people = [
            Person(joints, sigma, frozenset(d.camera for d in members))
            for members, joints, sigma in group_and_fuse(detections, self.config.matcher)
        ]
        tracks = self.tracker.update(people, now)
        confirmed = [t for t in tracks if t.confirmed]
        near = 0
        center = np.array(self.config.area_center)
        for track in confirmed:
            torso = track.joints[2, :2]
            if (
                np.isfinite(torso).all()
                and np.linalg.norm(torso - center) <= self.config.area_radius
            ):
                near += 1
        distance, closest = float("inf"), None
        if robot is not None and confirmed:
            distance, closest = self._distances(confirmed, robot)
        return Frame(tracks, confirmed, near, distance, closest, rejected)

    def _distances(
        self, people: list[Track], robot: tuple[np.ndarray, np.ndarray, np.ndarray]
    ) -> tuple[float, tuple[int, str, int] | None]:
        owners, limbs, ps, qs, rs = [], [], [], [], []
        for track in people:
            p, q, r = envelope(
                track.joints, np.nan_to_num(track.sigma, nan=0.05), self.config.margin_sigmas
            )
            ps.append(p)
            qs.append(q)
            rs.append(r)
            owners += [track.id] * len(p)
            limbs += [
                f"{LIMBS[i][0]}-{LIMBS[i][1]}" for i in np.flatnonzero(limbs_seen(track.joints))
            ]
        matrix = capsule_distances(
            robot[0], robot[1], robot[2], np.vstack(ps), np.vstack(qs), np.hstack(rs)
        )
        value, link, column = closest_pair(matrix)
        if link < 0:
            return float("inf"), None
        return value, (owners[column], limbs[column], link)
