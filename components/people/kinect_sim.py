"""Simulated Kinect v1 cameras seeing the people of the simulated OR as skeletons.

`KinectModel.observe` turns the true skeletons (world frame) into what one camera
reports: the users inside its field of view (57 x 43 deg, 0.8-4 m), each with a
per-camera user id (at most 16), joints in the camera frame with depth noise
sigma = 1.425e-3 z^2 (Khoshelham & Oude Elberink 2012) plus lateral noise, joints
hidden behind a nearer person dropped (NaN), whole frames dropped now and then,
and short ghost skeletons (false positives lasting under a second) as the thesis
observed. `KinectSim` is the component that publishes it on `kinect/<i>/users`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from components.domain.geometry import look_at, norm
from components.domain.skeleton import JOINTS, depth_sigma, standing
from framework.component import Component, In, Out, operation
from framework.messages import Skeleton, Skeletons
from framework.ports import ReadStatus
from framework.properties import prop

H_FOV, V_FOV = math.radians(57.0), math.radians(43.0)
NEAR, FAR = 0.8, 4.0
MAX_USERS = 16
BODY_RADIUS = 0.2  # how wide a person is, for hiding people behind


@dataclass
class KinectModel:
    """One camera: where it is and how it errs."""

    name: str
    world_from_camera: np.ndarray
    lateral_noise: float = 0.01
    dropout: float = 0.02
    ghost_rate: float = 0.02  # ghosts started per second
    floor: float = 0.0  # the floor's height, where ghosts stand as people do
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    """Frame dropouts and joint noise: drawn frame by frame."""
    ghost_rng: np.random.Generator | None = None
    """When and where ghosts appear (default: a stream spawned from `rng`): drawn ghost
    by ghost on the room's clock, apart from the frames, so the same seed gives the same
    ghosts at the same room times however many frames a busy host makes."""
    _ids: dict[int, int] = field(default_factory=dict)
    _ghosts: list[tuple[float, float, np.ndarray, int]] = field(default_factory=list)
    _next_ghost: float | None = None
    """Room time (s) the next ghost appears; None until the first frame."""
    _inverse: tuple[np.ndarray | None, np.ndarray] = (None, np.eye(4))
    """(world_from_camera, its inverse), kept while the pose is the same array."""

    def __post_init__(self) -> None:
        if self.ghost_rng is None:
            self.ghost_rng = self.rng.spawn(1)[0]

    def in_view(self, points: np.ndarray) -> np.ndarray:
        """Which camera-frame points are inside the field of view and depth range."""
        x, y, z = points[..., 0], points[..., 1], points[..., 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            return (
                (z >= NEAR)
                & (z <= FAR)
                & (np.abs(np.arctan2(x, z)) <= H_FOV / 2)
                & (np.abs(np.arctan2(y, z)) <= V_FOV / 2)
            )

    def to_camera(self, world: np.ndarray) -> np.ndarray:
        """World points (..., 3) into the camera frame."""
        if self._inverse[0] is not self.world_from_camera:  # a pose set anew
            self._inverse = (self.world_from_camera, np.linalg.inv(self.world_from_camera))
        camera_from_world = self._inverse[1]
        return world @ camera_from_world[:3, :3].T + camera_from_world[:3, 3]

    def _hidden(self, joints: np.ndarray, torsos: list[np.ndarray]) -> np.ndarray:
        """Joints (camera frame) behind a nearer person's body (their `torsos`: the mean
        of neck and torso, camera frame), seen from the camera."""
        hidden = np.zeros(len(joints), dtype=bool)
        for torso in torsos:
            if not np.isfinite(torso).all():
                continue
            depth = norm(torso)
            direction = torso / depth
            along = joints @ direction
            lateral = np.linalg.norm(joints - np.outer(along, direction), axis=1)
            hidden |= (along > depth + 0.1) & (lateral < BODY_RADIUS)
        return hidden

    def observe(
        self, people: dict[int, np.ndarray], now: float
    ) -> list[tuple[int, np.ndarray]] | None:
        """(user id, joints in the camera frame) for the frame taken at room time `now`
        (s); None when the camera drops the frame (it sends nothing, which is not the
        same as seeing no one)."""
        self._schedule_ghosts(now)
        if self.rng.random() < self.dropout:
            return None
        in_camera = {pid: self.to_camera(s) for pid, s in people.items()}
        inside = {pid: self.in_view(j) for pid, j in in_camera.items()}
        visible = {pid: j for pid, j in in_camera.items() if inside[pid].mean() > 0.5}
        # each person's mean depth and torso once per frame (the simulated room is the
        # costliest part of the cameras' process): the same numbers as per comparison
        depth = {pid: np.nanmean(j[:, 2]) for pid, j in visible.items()}
        torso = {pid: np.nanmean(j[[1, 2]], axis=0) for pid, j in visible.items()}
        out = []
        for pid, joints in sorted(visible.items(), key=lambda kv: depth[kv[0]]):
            nearer = [torso[o] for o in visible if o != pid and depth[o] < depth[pid]]
            seen = joints.copy()
            seen[self._hidden(seen, nearer) | ~inside[pid]] = np.nan
            if np.isnan(seen).all(axis=1).mean() > 0.6:
                continue  # mostly hidden: the camera loses this user
            seen += self.noise(seen)
            out.append((self._user_id(pid), seen))
        out += [(uid, g + self.noise(g)) for _, _, g, uid in self._ghosts]
        return out[:MAX_USERS]

    def noise(self, joints: np.ndarray) -> np.ndarray:
        """Depth noise along z (1.425e-3 z^2) plus lateral noise, per joint."""
        z = np.nan_to_num(joints[:, 2])
        noise = self.rng.normal(0.0, 1.0, joints.shape)
        noise[:, :2] *= self.lateral_noise
        noise[:, 2] *= depth_sigma(z)
        return noise

    def _user_id(self, person: int) -> int:
        if person not in self._ids:
            used = set(self._ids.values())
            self._ids[person] = next(i for i in range(1, 100) if i not in used)
        return self._ids[person]

    def _schedule_ghosts(self, now: float) -> None:
        """Start the ghosts due by room time `now` (a Poisson process of `ghost_rate`
        per second from the first frame) and forget the ended ones. A ghost is a body
        that is not there, standing 1.5-3.5 m in front of the camera somewhere across
        its view, reported as a person would be (the joints outside the view unseen, at
        most half the body out of it), for 0.1-0.9 s of the room's clock."""
        if self._next_ghost is None:
            self._next_ghost = now + self._ghost_gap()
        while self._next_ghost <= now:
            start = self._next_ghost
            self._next_ghost = start + self._ghost_gap()
            self._start_ghost(start, now)
        self._ghosts = [g for g in self._ghosts if g[1] > now]

    def _ghost_gap(self) -> float:
        """Room time (s) from one ghost to the next (inf: no ghosts)."""
        if not self.ghost_rate > 0.0:
            return math.inf
        assert self.ghost_rng is not None
        return float(self.ghost_rng.exponential(1.0 / self.ghost_rate))

    def _start_ghost(self, start: float, now: float) -> None:
        """Draw the ghost due at room time `start` and keep it if it stands in view and
        lasts past `now` (a frame late or dropped may come after a short one ended):
        every ghost draws the same numbers, so one left out shifts none after it."""
        rng = self.ghost_rng
        assert rng is not None
        eye = self.world_from_camera[:3, 3]
        axis = self.world_from_camera[:3, 2]
        heading = math.atan2(axis[1], axis[0]) + rng.uniform(-H_FOV / 2, H_FOV / 2)
        reach = rng.uniform(1.5, 3.5)
        facing = rng.uniform(0, 2 * math.pi)
        end = start + rng.uniform(0.1, 0.9)
        if end <= now:  # over before this frame (a clock that jumped: no body to build)
            return
        at = (eye[0] + reach * math.cos(heading), eye[1] + reach * math.sin(heading))
        ghost = self.to_camera(standing(at, facing, floor=self.floor))
        inside = self.in_view(ghost)
        if inside.mean() > 0.5:
            ghost[~inside] = np.nan
            self._ghosts.append((start, end, ghost, 50 + len(self._ghosts)))

    def to_message(self, users: list[tuple[int, np.ndarray]], stamp: float) -> Skeletons:
        """The `Skeletons` message of one frame (NaN joints sent with confidence 0)."""
        skeletons = []
        for uid, joints in users:
            confidence = np.where(np.isnan(joints).any(axis=1), 0.0, 1.0)
            skeletons.append(
                Skeleton(
                    uid, tuple(np.nan_to_num(joints).ravel().tolist()), tuple(confidence.tolist())
                )
            )
        return Skeletons(stamp, self.name, tuple(skeletons))


def frames(
    cameras: list[KinectModel], people: dict[int, np.ndarray], now: float
) -> dict[str, list[tuple[int, np.ndarray]]]:
    """What these cameras send for the frame at room time `now`, by name: a camera
    that drops the frame sends nothing and is left out."""
    sent = {c.name: c.observe(people, now) for c in cameras}
    return {name: users for name, users in sent.items() if users is not None}


def from_message(message: Skeletons) -> list[tuple[int, np.ndarray]]:
    """(user id, joints with NaN where confidence is 0) of a `Skeletons` message."""
    out = []
    for user in message.users:
        joints = np.array(user.joints, dtype=float).reshape(len(JOINTS), 3)
        joints[np.array(user.confidence) <= 0.0] = np.nan
        out.append((user.user_id, joints))
    return out


class KinectSim(Component):
    """Publishes one simulated camera's skeletons at 30 Hz (people placed by operation)."""

    position = prop(list, [0.0, -2.5, 2.2], doc="camera position in the world (m)")
    target = prop(list, [0.0, 0.0, 1.0], doc="point the camera looks at (m)")
    seed = prop(int, 0, doc="noise seed")
    ghost_rate = prop(float, 0.02, min=0.0, max=10.0, doc="ghosts per second")
    floor = prop(float, -0.8, unit="m", doc="floor height in the world frame (people_world's)")
    users = Out(Skeletons, doc="the users this camera sees")
    world = In(Skeletons, doc="true skeletons of the simulated OR (sim/people); else `place`")

    def configure_hook(self) -> bool:
        self.model = KinectModel(
            self.name,
            look_at(tuple(self.position), tuple(self.target)),
            ghost_rate=self.ghost_rate,
            floor=self.floor,
            rng=np.random.default_rng(self.seed),
        )
        self.people: dict[int, np.ndarray] = {}
        return True

    def update_hook(self) -> None:
        # the camera lives in the room's time: its ghosts come and go by the clock the
        # people walk by, not by a count of frames (a busy host makes fewer, longer ones)
        now = self.clock.now()
        status, truth = self.world.read()
        if status is not ReadStatus.NO_DATA and truth is not None:
            self.people = {
                u.user_id: np.array(u.joints, dtype=float).reshape(len(JOINTS), 3)
                for u in truth.users
            }
        frame = self.model.observe(self.people, now)
        if frame is not None:  # a dropped frame sends nothing
            self.users.write(self.model.to_message(frame, time.time()))

    @operation
    def place(self, person: int, x: float, y: float, facing: float = 0.0) -> None:
        """Put a standing person at floor position (x, y)."""
        self.people[person] = standing((x, y), facing, floor=self.floor)

    @operation
    def remove(self, person: int) -> None:
        """The person leaves the room."""
        self.people.pop(person, None)
