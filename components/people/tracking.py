"""Persistent people tracks: identities across frames and occlusions, confirmation
and deletion.

Association: each frame's people are paired with the tracks, the most recently seen
tracks first (a track that just lost its person must not take a neighbour's), on the
median joint distance in units of the noise (`fusion.normalized_cost`). A track's
joints are predicted at its body's walking velocity; the noise allowed between the
prediction and the detection grows with the time since the track was last seen (a
walker turns, stops, swings their limbs), so a person hidden for up to `keep_for`
(2 s) behind someone is found again where they reappear.

Confirmation: ghost skeletons (false positives under 1 s, thesis 3.4) are
single-camera artifacts that stand still, so a track is confirmed when two or more
cameras see the person at once, or after `confirm_after` of detection by a credible
camera, or sooner (`confirm_walking`) when it has walked a body's length since it
appeared: people walk in, ghosts do not walk. Only confirmed tracks count as people;
tracks unseen for longer than `keep_for` are deleted. Which unseen tracks still stand
for someone in the room is the detector's to say (it knows where the cameras look).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from components.people.fusion import GATE_SIGMAS, gated_pairs, normalized_cost

TORSO = 2
LIMB_MOTION = 0.05
"""m: how far a limb may move against the body between two frames (a swinging arm)."""
TURN_SPEED = 0.7
"""m/s: how fast a walker may leave the predicted path (turning, stopping, starting)."""
MOST_MOTION = 1.0
"""m: the most motion allowed between a prediction and a detection, however long the
track was unseen."""
VELOCITY_TIME = 0.5
"""s: the time constant of the walking velocity's smoothing (a torso seen at 4 m moves
by 1 m/s from frame to frame in its noise alone; this leaves about 0.2 m/s)."""
WALKED = 0.3
"""m: a track whose torso moved this far from where it appeared is someone walking."""


@dataclass
class Person:
    """One fused detection of a frame: joints, per-joint sigma, the cameras that saw it."""

    joints: np.ndarray
    sigma: np.ndarray
    cameras: frozenset[str]
    trusted: bool = True
    """False when only a non-master camera sees it where another camera should (a
    camera whose calibration is wrong produces exactly such misplaced copies)."""


@dataclass
class Track:
    """A person followed over time."""

    id: int
    joints: np.ndarray
    sigma: np.ndarray
    first_seen: float
    last_seen: float
    confirmed: bool = False
    cameras: frozenset[str] = field(default_factory=frozenset)
    frames: int = 0
    untrusted: int = 0
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The body's walking velocity (m/s, floor plane: z is 0)."""
    born: tuple[float, float] | None = None
    """The torso's floor position where the track appeared."""
    walked: float = 0.0
    """The farthest the torso has been from `born` (m)."""

    at: float = 0.0
    """When `joints` stood there: the last detection, or the last frame it was coasted to."""

    def predicted(self, now: float) -> np.ndarray:
        """The joints where the person should be at `now`, walking on as they were (for
        at most a second unseen: after that, a walker has likely changed course)."""
        walked = min(max(now - self.last_seen, 0.0), 1.0) - min(self.at - self.last_seen, 1.0)
        return self.joints + self.velocity * walked

    def _seen(self, person: Person, now: float) -> None:
        """Take this frame's detection: joints, velocity, how far it walked."""
        dt = now - self.last_seen
        bx, by, _ = self.joints[TORSO].tolist()  # floats: cheaper than numpy for three
        ax, ay, az = person.joints[TORSO].tolist()
        seen_after = math.isfinite(ax + ay + az)
        if 0.0 < dt <= 0.5 and seen_after and math.isfinite(bx + by):
            gain = min(1.0, dt / VELOCITY_TIME)
            vx, vy, _ = self.velocity.tolist()
            vx += gain * ((ax - bx) / dt - vx)
            vy += gain * ((ay - by) / dt - vy)
            self.velocity = np.array([vx, vy, 0.0])
        elif dt > 0.5:
            self.velocity = np.zeros(3)
        if seen_after:
            if self.born is None:
                self.born = (ax, ay)
            self.walked = max(self.walked, math.hypot(ax - self.born[0], ay - self.born[1]))
        self.joints, self.sigma = person.joints, person.sigma
        self.last_seen, self.at, self.cameras = now, now, person.cameras
        self.frames += 1
        self.untrusted += not person.trusted


class PeopleTracker:
    """Associates each frame's people with tracks and manages their lives (module
    docstring)."""

    def __init__(
        self,
        confirm_after: float = 1.0,
        keep_for: float = 2.0,
        cameras_to_confirm: int = 2,
        confirm_walking: float = 0.2,
    ):
        self.confirm_after, self.keep_for = confirm_after, keep_for
        self.cameras_to_confirm, self.confirm_walking = cameras_to_confirm, confirm_walking
        self.tracks: list[Track] = []
        self._ids = itertools.count(1)

    def update(self, people: list[Person], now: float) -> list[Track]:
        """Feed one frame; returns the live tracks (tentative and confirmed)."""
        unmatched = list(range(len(people)))
        for tier in self._tiers(now):
            if not unmatched:
                break
            tracks = [self.tracks[i] for i in tier]
            candidates = [people[j] for j in unmatched]
            pairs = self._associate(tracks, candidates, now)
            for i, j in pairs:
                tracks[i]._seen(candidates[j], now)
            taken = {unmatched[j] for _, j in pairs}
            unmatched = [j for j in unmatched if j not in taken]
        for j in unmatched:
            person = people[j]
            track = Track(next(self._ids), person.joints, person.sigma, now, now)
            track._seen(person, now)
            track.last_seen = now
            self.tracks.append(track)
        self.tracks = [t for t in self.tracks if now - t.last_seen <= self.keep_for]
        for track in self.tracks:
            if track.last_seen < now:  # unseen: coasted on, so it is reported where it walks
                track.joints, track.at = track.predicted(now), now
        for track in self.tracks:
            if not track.confirmed and track.last_seen == now and self._credible(track, now):
                track.confirmed = True
        return list(self.tracks)

    def _tiers(self, now: float) -> list[list[int]]:
        """Track indices grouped by the frames since they were last seen, freshest first."""
        tiers: dict[int, list[int]] = {}
        for i, track in enumerate(self.tracks):
            tiers.setdefault(round((now - track.last_seen) * 30.0), []).append(i)
        return [tiers[k] for k in sorted(tiers)]

    def _associate(
        self, tracks: list[Track], people: list[Person], now: float
    ) -> list[tuple[int, int]]:
        """Gated global assignment of these tracks (seen equally long ago) to people."""
        unseen = now - tracks[0].last_seen
        motion = min(LIMB_MOTION + TURN_SPEED * unseen, MOST_MOTION)
        cost = normalized_cost(
            np.stack([t.predicted(now) for t in tracks]),
            np.stack([t.sigma for t in tracks]),
            np.stack([p.joints for p in people]),
            np.stack([p.sigma for p in people]),
            slack=motion,
        )
        return gated_pairs(cost, GATE_SIGMAS)

    def _credible(self, track: Track, now: float) -> bool:
        """Whether a tentative track, seen this frame, is someone (module docstring)."""
        if len(track.cameras) >= self.cameras_to_confirm:
            return True
        if track.untrusted * 2 > track.frames:  # mostly seen where it should not be
            return False
        age = now - track.first_seen
        return age >= self.confirm_after or (age >= self.confirm_walking and track.walked >= WALKED)

    @property
    def people(self) -> list[Track]:
        """Confirmed tracks: the people in the room (and those lately hidden)."""
        return [t for t in self.tracks if t.confirmed]
