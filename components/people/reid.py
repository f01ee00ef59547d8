"""Knowing someone again by their build: a skeleton's bone lengths, measured over a
track's life, and a gallery of the people who left every view.

People differ in height (about 9 cm between adults) and in the breadth of their
shoulders and hips; a camera measures a bone to 1-3 cm in one frame, and a track
averages its frames, so after half a second a build is known to a few millimetres.
When someone walks out of every view and, seconds later, someone comes in, the
tracker asks the gallery whether the newcomer is built like one of those who left;
only a clear answer (one within the noise, and likelier than any other by
`LIKELIHOOD_RATIO`) gives the newcomer the old identity.

Only bones that keep their length whatever a person does are used (not the arms,
which reach and bend): head-neck, neck-torso, shoulder and hip breadth, torso to
hips, thighs and shanks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from components.domain.skeleton import J

SIZES: tuple[tuple[tuple[str, str], ...], ...] = (
    (("head", "neck"),),
    (("neck", "torso"),),
    (("left_shoulder", "right_shoulder"),),
    (("left_hip", "right_hip"),),
    (("torso", "left_hip"), ("torso", "right_hip")),
    (("left_hip", "left_knee"), ("right_hip", "right_knee")),
    (("left_knee", "left_foot"), ("right_knee", "right_foot")),
)
"""The body's sizes: each the mean length of one or two (left and right) bones."""
_A = np.array([J[a] for size in SIZES for a, _ in size])
_B = np.array([J[b] for size in SIZES for _, b in size])
_OF = np.array([k for k, size in enumerate(SIZES) for _ in size])

POSTURE = 0.01
"""m: how much a measured bone changes with posture (where a camera puts a joint on
the body moves a little as it turns and bends), added to the noise of every size."""
KNOWN = POSTURE / 3.0
"""m: a size known this well (1 sigma) is known: its noise adds a tenth of the posture
term's variance (after about a second of frames at 4 m)."""
SURE = 0.99
"""A build within this quantile of the noise (chi-square over the sizes compared) may
be the same person's."""
LIKELIHOOD_RATIO = 20.0
"""How much likelier the best match must be than the next before it is taken."""
REMEMBER = 60.0
"""s: how long the gallery remembers someone who left."""
FRAMES_TO_KNOW = 15
"""Detections of a new track before its build is compared (half a second at 30 Hz)."""
WALK_SPEED = 1.6
"""m/s: how far someone who left may have walked since (ISO 13855's walking speed)."""
_GATE = [math.inf] + [float(chi2.ppf(SURE, k)) for k in range(1, len(SIZES) + 1)]


def sizes(joints: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sizes of many skeletons (n, 15, 3) with their per-joint noise (n, 15): values
    and variances (n, len(SIZES)), NaN where a size's bones are unseen."""
    a, b = joints[:, _A], joints[:, _B]
    length = np.sqrt(np.square(a - b).sum(axis=2))  # (n, bones), NaN if unseen
    var = np.square(sigma[:, _A]) + np.square(sigma[:, _B])
    seen = np.isfinite(length) & np.isfinite(var)
    n = len(SIZES)
    count = np.zeros((len(joints), n))
    total = np.zeros((len(joints), n))
    var_total = np.zeros((len(joints), n))
    for bone, k in enumerate(_OF):
        count[:, k] += seen[:, bone]
        total[:, k] += np.where(seen[:, bone], length[:, bone], 0.0)
        var_total[:, k] += np.where(seen[:, bone], var[:, bone], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / count, var_total / np.square(count)  # NaN where count is 0


@dataclass
class Build:
    """A track's sizes so far: inverse-variance weighted means."""

    weighted: np.ndarray = field(default_factory=lambda: np.zeros(len(SIZES)))
    weight: np.ndarray = field(default_factory=lambda: np.zeros(len(SIZES)))
    known: bool = False
    """Every size is known to `KNOWN` or better: more detections change nothing that
    matters (`distance` adds `POSTURE` to the noise), so they are not added."""

    def add(self, values: np.ndarray, variances: np.ndarray) -> None:
        """One detection's sizes (NaN: unseen)."""
        if self.known:
            return
        seen = np.isfinite(values) & (variances > 0)
        w = np.where(seen, 1.0 / np.where(seen, variances, 1.0), 0.0)
        self.weighted += np.where(seen, values, 0.0) * w
        self.weight += w
        self.known = bool((self.weight >= 1.0 / KNOWN**2).all())

    def log_likelihood(self, other: Build) -> tuple[float, int]:
        """The log-likelihood that `other` is this build (over the sizes both know, and
        how many), or -inf if beyond the chi-square `SURE` quantile of the noise."""
        both = (self.weight > 0) & (other.weight > 0)
        if not both.any():
            return -math.inf, 0
        noise = 1.0 / self.weight[both] + 1.0 / other.weight[both] + POSTURE**2
        d2, k = self.distance(other)
        if not d2 <= _GATE[k]:
            return -math.inf, k
        return -0.5 * (d2 + float(np.log(2 * math.pi * noise).sum())), k

    def distance(self, other: Build) -> tuple[float, int]:
        """Squared distance in units of the noise over the sizes both know, and how many."""
        both = (self.weight > 0) & (other.weight > 0)
        if not both.any():
            return math.inf, 0
        a = self.weighted[both] / self.weight[both]
        b = other.weighted[both] / other.weight[both]
        noise = 1.0 / self.weight[both] + 1.0 / other.weight[both] + POSTURE**2
        return float(np.sum(np.square(a - b) / noise)), int(both.sum())


@dataclass(eq=False)
class Departed:
    """Someone who left every view: their identity, build, where and when last seen."""

    id: int
    build: Build
    place: tuple[float, float]
    when: float


class Gallery:
    """The people who left, to know them again (module docstring)."""

    def __init__(self) -> None:
        self.departed: list[Departed] = []

    def leave(self, who: Departed) -> None:
        """Someone left (or an identity given wrongly comes back); remember them for
        `REMEMBER`."""
        if who not in self.departed:
            self.departed.append(who)

    def forget(self, who: Departed | None) -> None:
        """One thought gone was not: they are no one to know again."""
        if who in self.departed:
            self.departed.remove(who)

    def recognise(self, build: Build, place: tuple[float, float], when: float) -> Departed | None:
        """The one who left whom a newcomer (`build`, first seen at `place` at `when`)
        clearly is, taken from the gallery; None if no one clearly.

        Each who left is scored by how likely the newcomer's build is theirs (within the
        noise: `SURE`) and how likely they are to come back here now: anywhere within a
        walk (`WALK_SPEED`) of where they left, which is a short stretch of the views'
        edge for someone who left a moment ago and the whole room after a while (the
        likelihood falls as 1 / reach). The best must be `LIKELIHOOD_RATIO` likelier than
        the next: one who left a moment ago where the newcomer appears is told from one
        who left long ago even if their builds are alike, and two who left alike, at
        once, from the same place are not told apart."""
        self.departed = [d for d in self.departed if when - d.when <= REMEMBER]
        scored = []
        for d in self.departed:
            reach = WALK_SPEED * max(when - d.when, 0.0) + 1.0
            if not math.hypot(place[0] - d.place[0], place[1] - d.place[1]) <= reach:
                continue
            log_likelihood, k = build.log_likelihood(d.build)
            if k and math.isfinite(log_likelihood):
                scored.append((log_likelihood - math.log(reach), d))
        if not scored:
            return None
        scored.sort(key=lambda s: -s[0])
        if len(scored) > 1 and scored[0][0] - scored[1][0] < math.log(LIKELIHOOD_RATIO):
            return None  # no clear answer
        self.departed.remove(scored[0][1])
        return scored[0][1]
