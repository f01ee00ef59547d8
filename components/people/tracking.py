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
confirmed tracks unseen for longer than `keep_for` are deleted, tentative ones after
`TENTATIVE_KEEP`. Which unseen tracks still stand
for someone in the room is the detector's to say (it knows where the cameras look).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from components.people.fusion import GATE_SIGMAS, gated_pairs, normalized_cost
from components.people.skeleton import standing

TORSO = 2
LIMB_MOTION = 0.05
"""m: how far a limb may move against the body between two frames (a swinging arm)."""
TURN_SPEED = 0.7
"""m/s: how fast a walker may leave the predicted path (turning, stopping, starting)."""
MOST_MOTION = 1.0
"""m: the most motion allowed between a prediction and a detection, however long the
track was unseen."""
VELOCITY_WINDOW = 0.5
"""s: the walking velocity is the least-squares slope of the torso over this long (a
torso seen at 4 m moves by 1 m/s from frame to frame in its noise alone; the slope over
15 frames is good to about 0.05 m/s, and does not lag a steady walk as smoothing does)."""
WALK_SIGMAS = 4.3
"""How far (in units of the noise of a difference of two torso positions, sigma *
sqrt(2)) a track's torso must move from where it appeared to be someone walking: for
a ghost, which stands still, each frame goes this far with probability exp(-4.3^2 / 2)
= 1e-4, so fewer than 1 in 300 does in a ghost's life (under 30 frames)."""
TENTATIVE_KEEP = 0.2
"""s: a track not yet confirmed is dropped when unseen this long (a ghost's track must
not wait for the next ghost nearby and add up their lives to a confirmation)."""
_UPRIGHT = standing((0.0, 0.0), 0.0)
UPRIGHT = np.zeros_like(_UPRIGHT)
UPRIGHT[:, 2] = _UPRIGHT[:, 2] - _UPRIGHT[TORSO, 2]
"""Each joint's place relative to the torso of someone standing, for joints a track
has never seen (their height matters for what a camera sees; the side offsets, 10-27
cm, are left out as the person's facing is unknown)."""


@dataclass
class Person:
    """One fused detection of a frame: joints, per-joint sigma, the cameras that saw it."""

    joints: np.ndarray
    sigma: np.ndarray
    cameras: frozenset[str]
    trusted: bool = True
    """False when only a non-master camera sees it where another camera should (a
    camera whose calibration is wrong produces exactly such misplaced copies)."""
    entering: bool = False
    """Seen where someone comes into sight: at the edge of the views that could see
    them (the detector knows where cameras look)."""


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
    path: deque[tuple[float, float, float]] = field(default_factory=deque)
    """(time, x, y) of the torso over the last `VELOCITY_WINDOW`."""
    born: tuple[float, float] | None = None
    """The torso's floor position where the track appeared."""
    born_sigma: float = math.inf
    """The noise (1 sigma, m) of `born`."""
    walked: float = 0.0
    """The farthest the torso has been from `born` (m)."""
    shape: np.ndarray = field(default_factory=lambda: UPRIGHT.copy())
    """Each joint relative to the torso, as last seen (`UPRIGHT` until then): where
    the joints a camera does not see now must be, to tell whether it should."""

    entered: bool = False
    """Appeared where people come into sight (`Person.entering`): someone walking in,
    not a ghost, which appears anywhere."""

    at: float = 0.0
    """When `joints` stood there: the last detection, or the last frame it was coasted to."""

    def predicted(self, now: float) -> np.ndarray:
        """The joints where the person should be at `now`, walking on as they were (for
        at most a second unseen: after that, a walker has likely changed course)."""
        walked = min(max(now - self.last_seen, 0.0), 1.0) - min(self.at - self.last_seen, 1.0)
        return self.joints + self.velocity * walked

    def whole(self) -> np.ndarray:
        """All 15 joints at the track's place: its joints, the unseen ones where the
        body's shape puts them (NaN only when nothing was ever seen)."""
        return complete(self.joints, self.shape)

    def _seen(self, person: Person, now: float) -> None:
        """Take this frame's detection: joints, velocity, how far it walked."""
        ax, ay, az = person.joints[TORSO].tolist()  # floats: cheaper than numpy for three
        if math.isfinite(ax + ay + az):
            seen = ~np.isnan(person.joints).any(axis=1)
            self.shape[seen] = person.joints[seen] - person.joints[TORSO]
            self.path.append((now, ax, ay))
            while now - self.path[0][0] > VELOCITY_WINDOW:
                self.path.popleft()
            self.velocity = _slope(self.path)
            if self.born is None:
                self.born = (ax, ay)
                self.born_sigma = float(person.sigma[TORSO])
            self.walked = max(self.walked, math.hypot(ax - self.born[0], ay - self.born[1]))
        elif now - self.last_seen > VELOCITY_WINDOW:
            self.velocity = np.zeros(3)
        self.joints, self.sigma = person.joints, person.sigma
        self.last_seen, self.at, self.cameras = now, now, person.cameras
        self.frames += 1
        self.untrusted += not person.trusted


def complete(joints: np.ndarray, shape: np.ndarray = UPRIGHT) -> np.ndarray:
    """A skeleton (15, 3) with its unseen joints put where `shape` (each joint relative
    to the torso) says they are, about the torso the seen joints imply; all NaN if none
    is seen."""
    unseen = np.isnan(joints).any(axis=1)
    if not unseen.any() or unseen.all():
        return joints
    # the torso as seen, or else the torso each seen joint implies, averaged
    torso = joints[TORSO] if not unseen[TORSO] else (joints[~unseen] - shape[~unseen]).mean(axis=0)
    out = joints.copy()
    out[unseen] = torso + shape[unseen]
    return out


def _slope(path: deque[tuple[float, float, float]]) -> np.ndarray:
    """The least-squares velocity (x, y, 0) of (t, x, y) samples; 0 for fewer than two."""
    n = len(path)
    if n < 2:
        return np.zeros(3)
    t0 = path[-1][0]
    st = sx = sy = stt = stx = sty = 0.0
    for t, x, y in path:
        t -= t0
        st += t
        sx += x
        sy += y
        stt += t * t
        stx += t * x
        sty += t * y
    spread = n * stt - st * st
    if spread <= 0.0:
        return np.zeros(3)
    return np.array([(n * stx - st * sx) / spread, (n * sty - st * sy) / spread, 0.0])


class PeopleTracker:
    """Associates each frame's people with tracks and manages their lives (module
    docstring)."""

    def __init__(
        self,
        confirm_after: float = 1.0,
        keep_for: float = 2.0,
        cameras_to_confirm: int = 2,
    ):
        self.confirm_after, self.keep_for = confirm_after, keep_for
        self.cameras_to_confirm = cameras_to_confirm
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
            track.entered = person.entering
            track._seen(person, now)
            track.last_seen = now
            self.tracks.append(track)
        self.tracks = [
            t
            for t in self.tracks
            if now - t.last_seen <= (self.keep_for if t.confirmed else TENTATIVE_KEEP)
        ]
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
        if track.entered and not track.untrusted:
            return True
        age = now - track.first_seen
        return (
            age >= self.confirm_after
            or track.walked >= WALK_SIGMAS * math.sqrt(2) * track.born_sigma
        )

    @property
    def people(self) -> list[Track]:
        """Confirmed tracks: the people in the room (and those lately hidden)."""
        return [t for t in self.tracks if t.confirmed]
