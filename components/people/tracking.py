"""Persistent people tracks: identities across frames, occlusions and absences;
when a track is someone; when it is dropped.

Association: each frame's people are paired with the tracks, the most recently seen
tracks first (a track that just lost its person must not take a neighbour's), on the
median joint distance in units of the noise (`fusion.normalized_cost`): near where
walking on at the body's velocity would put them, or within a walk (1.6 m/s, any
direction) of where they were last seen, whichever is nearer (someone hidden who
turns back is not where walking on would put them). A person hidden for up to
`keep_for` (2 s) behind someone is found again where they reappear.

Confirmation: ghost skeletons (false positives under 1 s, thesis 3.4) are
single-camera artifacts that stand still and appear anywhere in a view. A track is
someone when two or more cameras see them at once; or, seen by one credible camera,
when they came into sight where people do (at the edge of a view: `Person.entering`,
the detector's to say), when they walked beyond the noise (`WALK_SIGMAS`), or after
`confirm_after`. Only confirmed tracks count as people.

Lives: a tentative track unseen for `TENTATIVE_KEEP` is dropped. A confirmed track
the detector judges gone (`lose`) stops counting and is remembered in a gallery by
its build, where and when it left (`reid`). If it left every view it takes no more
detections after `TENTATIVE_KEEP`; if cameras look where it is and miss it, it takes
them for `keep_for` (and counts again once credible). Who comes into sight is a
newcomer, and once credible, takes back the identity of one who left if it is clearly theirs: by where
and when they appear against where and when each left (someone back a moment later
where they left is told from one who left long ago), and by their build, checked
again once it is known. One mechanism serves someone who turns back at the edge of a
view and someone who comes back a minute later.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from components.domain.skeleton import standing
from components.people.fusion import GATE_SIGMAS, gated_pairs, normalized_cost
from components.people.reid import FRAMES_TO_KNOW, Build, Departed, Gallery, sizes

TORSO = 2
FRAME = 1.0 / 30.0
"""s: a camera frame (30 Hz)."""
LIMB_MOTION = 0.05
"""m: how far a limb may move against the body between two frames (a swinging arm)."""
TURN_SPEED = 0.7
"""m/s: how fast a walker may leave the predicted path (turning, stopping, starting)."""
WALK_SPEED = 1.6
"""m/s: how fast someone unseen may have walked away from where they were last seen, in
any direction (ISO 13855's walking speed; a walker who turns back at the edge of a
view is not where walking on would put them)."""
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
    since: float = 0.0
    """When this sighting began: the track's birth, or its first detection after more
    than `TENTATIVE_KEEP` unseen."""
    gone: bool = False
    """Judged gone (`lose`): remembered in the gallery, counts no more, and takes
    detections only while `PeopleTracker._findable`."""
    born: tuple[float, float] | None = None
    """The torso's floor position where this sighting began."""
    born_sigma: float = math.inf
    """The noise (1 sigma, m) of `born`."""
    walked: float = 0.0
    """The farthest the torso has been from `born` in this sighting (m)."""
    build: Build = field(default_factory=Build)
    """The body's sizes measured so far (`reid`): who it is, should it leave and return."""
    known: bool = False
    """Its build was compared with the people who left once known well enough
    (`FRAMES_TO_KNOW` detections in)."""
    born_id: int = 0
    """The identity it was born with (`id` may be one it took from the gallery)."""
    reclaimed: Departed | None = None
    """The one who left whose identity it took, until its build confirms it."""
    departed: Departed | None = None
    """Its entry in the gallery while judged gone."""
    left: bool = False
    """Judged gone because it left every view (not missed where cameras look)."""
    was_confirmed: bool = False
    """It has counted before (a track found again is not a newcomer)."""
    origin: tuple[float, float] = (math.nan, math.nan)
    """The torso's floor position when first seen."""
    shape: np.ndarray = field(default_factory=lambda: UPRIGHT.copy())
    """Each joint relative to the torso, as last seen (`UPRIGHT` until then): where
    the joints a camera does not see now must be, to tell whether it should."""

    entered: bool = False
    """This sighting began where people come into sight (`Person.entering`): someone
    walking in, not a ghost, which appears anywhere."""

    at: float = 0.0
    """When `joints` stood there: the last detection, or the last frame it was coasted to."""

    def predicted(self, now: float) -> np.ndarray:
        """The joints where the person should be at `now`, walking on as they were (for
        at most a second unseen: after that, a walker has likely changed course)."""
        return self.joints + self.velocity * self.walk_to(now)

    def walk_to(self, now: float) -> float:
        """How long (s) to walk `joints` on at `velocity` to where they should be at `now`
        (`predicted`)."""
        return min(max(now - self.last_seen, 0.0), 1.0) - self.coasted()

    def coasted(self) -> float:
        """How long (s) `joints` have been walked on since the last detection."""
        return min(self.at - self.last_seen, 1.0)

    def last_place(self) -> np.ndarray:
        """The joints where it was last seen (before any coasting)."""
        return self.joints - self.velocity * self.coasted()

    def whole(self) -> np.ndarray:
        """All 15 joints at the track's place: its joints, the unseen ones where the
        body's shape puts them (NaN only when nothing was ever seen)."""
        return complete(self.joints, self.shape)

    def _seen(
        self,
        person: Person,
        now: float,
        size: tuple[np.ndarray, np.ndarray] | None = None,
        relative: np.ndarray | None = None,
    ) -> None:
        """Take this frame's detection: joints, velocity, how far it walked, its sizes
        (`relative`: its joints less its torso, if the caller has them for many)."""
        if size is not None:
            self.build.add(*size)
        if now - self.last_seen > TENTATIVE_KEEP or not self.frames:  # a new sighting
            self.since, self.entered, self.born, self.walked = now, person.entering, None, 0.0
        ax, ay, az = person.joints[TORSO].tolist()  # floats: cheaper than numpy for three
        if math.isfinite(ax + ay + az):
            if relative is None:
                relative = person.joints - person.joints[TORSO]
            np.copyto(self.shape, relative, where=relative == relative)  # NaN: unseen
            self.path.append((now, ax, ay))
            while now - self.path[0][0] > VELOCITY_WINDOW:
                self.path.popleft()
            self.velocity = _slope(self.path)
            if self.born is None:
                self.born = (ax, ay)
                self.born_sigma = float(person.sigma[TORSO])
                if math.isnan(self.origin[0]):  # the first place its torso was seen
                    self.origin = (ax, ay)
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


def _appeared(track: Track) -> tuple[float, float]:
    """Where a track was first seen: its torso then, or where its body puts the torso
    if it was not seen yet (someone at the edge of a view)."""
    if math.isfinite(track.origin[0]):
        return track.origin
    torso = complete(track.joints, track.shape)[TORSO]
    return (float(torso[0]), float(torso[1]))


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
        self.gallery = Gallery()
        self._ids = itertools.count(1)

    def update(self, people: list[Person], now: float) -> list[Track]:
        """Feed one frame; returns the live tracks (tentative and confirmed)."""
        unmatched = list(range(len(people)))
        measured: list[tuple[np.ndarray, np.ndarray]] = []
        # the frame's people as arrays, once: their joints, noise, joints less the torso
        joints = np.stack([p.joints for p in people]) if people else np.zeros((0, 15, 3))
        noise = np.stack([p.sigma for p in people]) if people else np.zeros((0, 15))
        relative = joints - joints[:, TORSO : TORSO + 1]

        def size(k: int, build: Build) -> tuple[np.ndarray, np.ndarray] | None:
            """Person k's sizes, if `build` still takes them (measured once per frame,
            and not at all in a frame where every build is known)."""
            if build.known:
                return None
            if not measured:
                measured.append(sizes(joints, noise))
            values, variances = measured[0]
            return values[k], variances[k]

        for tier in self._tiers(now):
            if not unmatched:
                break
            tracks = [self.tracks[i] for i in tier]
            pairs = self._associate(tracks, joints[unmatched], noise[unmatched], now)
            for i, j in pairs:
                k = unmatched[j]
                if tracks[i].gone:
                    self._found_again(tracks[i])
                tracks[i]._seen(people[k], now, size(k, tracks[i].build), relative[k])
            taken = {unmatched[j] for _, j in pairs}
            unmatched = [j for j in unmatched if j not in taken]
        for j in unmatched:
            person = people[j]
            track = Track(next(self._ids), person.joints, person.sigma, now, now)
            track.born_id = track.id
            track._seen(person, now, size(j, track.build), relative[j])
            self.tracks.append(track)
        kept = []
        for t in self.tracks:
            if now - t.last_seen <= (self.keep_for if t.confirmed or t.gone else TENTATIVE_KEEP):
                kept.append(t)
            elif t.confirmed:  # unseen too long (the detector loses them before)
                self._depart(t)
        self.tracks = kept
        for track in self.tracks:
            if track.last_seen < now:  # unseen: coasted on, so it is reported where it walks
                track.joints, track.at = track.predicted(now), now
        back: set[int] = set()
        for track in self.tracks:
            if not track.confirmed and track.last_seen == now and self._credible(track, now):
                if not track.was_confirmed and not track.known:
                    self._recognise(track)
                track.confirmed = track.was_confirmed = True
            if track.confirmed and not track.known and track.frames >= FRAMES_TO_KNOW:
                track.known = True
                self._recognise(track)
            if track.reclaimed is not None:
                back.add(track.id)
        if back:  # who came back is no longer kept as gone (their envelope is the new
            # track's), once it cannot be found again (`_found_again`)
            self.tracks = [
                t
                for t in self.tracks
                if not (t.gone and t.id in back and not self._findable(t, now))
            ]
        return list(self.tracks)

    def _depart(self, track: Track) -> None:
        """Remember one who left by their build, where and when last seen."""
        where = complete(track.last_place(), track.shape)[TORSO]
        track.departed = Departed(track.id, track.build, (where[0], where[1]), track.last_seen)
        self.gallery.leave(track.departed)

    def _found_again(self, track: Track) -> None:
        """A track judged gone a moment ago is there after all: it is no one to know
        again, and a newcomer who took its identity meanwhile gives it back (the track
        followed the person frame to frame; the newcomer only looked like them)."""
        if track.departed in self.gallery.departed:
            self.gallery.forget(track.departed)
        else:
            for other in self.tracks:
                if other.reclaimed is track.departed:
                    other.id, other.reclaimed = other.born_id, None
        track.gone, track.departed = False, None

    def _recognise(self, track: Track) -> None:
        """Give a confirmed newcomer the identity of one who left, if clearly theirs: at
        once when confirmed (where and when they appeared, and what little of their build
        one frame shows), and again once their build is known (`FRAMES_TO_KNOW`), which
        may keep the identity, take a clearer one, or give it back."""
        taken = track.reclaimed
        if taken is not None:
            self.gallery.leave(taken)  # judged afresh, against everyone who left
        former = self.gallery.recognise(track.build, _appeared(track), track.first_seen)
        still_theirs = (
            former is None
            and taken is not None
            and taken in self.gallery.departed
            and math.isfinite(track.build.log_likelihood(taken.build)[0])
        )
        if still_theirs:  # no clearer answer, and the build does not deny it
            self.gallery.forget(taken)
            former = taken
        track.reclaimed = former
        track.id = former.id if former is not None else track.born_id

    def _tiers(self, now: float) -> list[list[int]]:
        """Track indices grouped by the frames since they were last seen, freshest first.
        A track judged gone because it left every view is associated only for
        `TENTATIVE_KEEP` after it was last seen (a camera that loses someone at the
        edge of its view for a frame or two): who comes back later is a newcomer, known
        again through the gallery (a track kept for longer took the next person to
        appear where it left). One missed where cameras look is associated `keep_for`."""
        tiers: dict[int, list[int]] = {}
        for i, track in enumerate(self.tracks):
            if track.gone and not self._findable(track, now):
                continue
            tiers.setdefault(round((now - track.last_seen) / FRAME), []).append(i)
        return [tiers[k] for k in sorted(tiers)]

    def _findable(self, track: Track, now: float) -> bool:
        """Whether a track judged gone may still take detections (`_tiers`)."""
        return now - track.last_seen <= (TENTATIVE_KEEP if track.left else self.keep_for)

    def _associate(
        self, tracks: list[Track], joints: np.ndarray, noise: np.ndarray, now: float
    ) -> list[tuple[int, int]]:
        """Gated global assignment of these tracks (seen equally long ago) to people
        (their joints and noise): near where walking on would put them, or within a walk
        in any direction of where they were last seen, whichever is nearer."""
        unseen = now - tracks[0].last_seen
        sigma = np.stack([t.sigma for t in tracks])
        at = np.stack([t.joints for t in tracks])
        velocity = np.array([t.velocity for t in tracks])[:, None, :]
        ahead = normalized_cost(
            at + velocity * np.array([t.walk_to(now) for t in tracks])[:, None, None],
            sigma,
            joints,
            noise,
            slack=min(LIMB_MOTION + TURN_SPEED * unseen, MOST_MOTION),
        )
        if unseen <= 1.5 * FRAME:  # seen last frame: no one turns back in a frame
            return gated_pairs(ahead, GATE_SIGMAS)
        around = normalized_cost(
            at - velocity * np.array([t.coasted() for t in tracks])[:, None, None],
            sigma,
            joints,
            noise,
            slack=min(LIMB_MOTION + WALK_SPEED * unseen, MOST_MOTION),
        )
        return gated_pairs(np.minimum(ahead, around), GATE_SIGMAS)

    def _credible(self, track: Track, now: float) -> bool:
        """Whether a tentative track, seen this frame, is someone (module docstring)."""
        if len(track.cameras) >= self.cameras_to_confirm:
            return True
        if track.untrusted * 2 > track.frames:  # mostly seen where it should not be
            return False
        if track.entered and not track.untrusted:
            return True
        age = now - track.since
        return (
            age >= self.confirm_after
            or track.walked >= WALK_SIGMAS * math.sqrt(2) * track.born_sigma
        )

    def lose(self, track: Track, left: bool = True) -> None:
        """The person a confirmed track stood for is gone: they `left` every view, or
        cameras that look where they are miss them. It no longer counts, and is
        remembered in the gallery, so that who comes back, once credible as any
        newcomer, takes their identity again if clearly theirs. Who left takes no more
        detections after `TENTATIVE_KEEP` (someone else may come in where they left);
        who is missed where cameras look is likely still there, and the track takes
        their detections for `keep_for` (it counts again once credible). The track
        stays `keep_for` for its last place (the robot keeps its distance a while)."""
        track.confirmed, track.gone, track.left = False, True, left
        self._depart(track)

    @property
    def people(self) -> list[Track]:
        """Confirmed tracks: the people in the room (and those lately hidden)."""
        return [t for t in self.tracks if t.confirmed]
