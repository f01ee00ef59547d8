"""Multi-object tracking metrics, as the MOT benchmarks define them: CLEAR-MOT (MOTA,
MOTP, identity switches) and the identity measures (IDF1, IDP, IDR).

Frame by frame, a ground-truth object and a hypothesis (a track) may match only
within `gate` (the distance between their positions). The matching follows the
CLEAR-MOT rules as motmetrics implements them:

1. a pair matched before (the object's last hypothesis, however long ago) is kept
   while both are present and still within the gate;
2. the remaining objects and hypotheses are matched by a minimum-cost assignment
   (as many pairs as the gate allows, then the least total distance);
3. a match of an object to another hypothesis than its last one is an identity
   switch; an object left unmatched is a miss, a hypothesis a false positive.

MOTA = 1 - (misses + false positives + switches) / objects; MOTP is the mean
distance of the matches. The identity measures match whole trajectories instead:
one global assignment of object ids to hypothesis ids maximising the frames they
are within the gate of each other (IDTP); IDF1 = 2 IDTP / (objects + hypotheses),
summed over frames. tests/tools/bench/fw_bench/test_mot.py proves these equal to
motmetrics on recorded and random sequences; the benchmark itself needs no pandas.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

INFEASIBLE = 1e9
"""The cost that stands for "beyond the gate" in an assignment (never chosen over a
feasible pair, and dropped if chosen at all)."""


def gated_assignment(cost: np.ndarray) -> list[tuple[int, int]]:
    """The most pairs with a finite cost, and among those the least total cost;
    non-finite entries cannot be paired."""
    if cost.size == 0:
        return []
    finite = np.isfinite(cost)
    if not finite.any():
        return []
    rows, cols = linear_sum_assignment(np.where(finite, cost, INFEASIBLE))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if finite[r, c]]


@dataclass
class MotAccumulator:
    """Feed it frame by frame (`update`), then read `summary`."""

    gate: float
    objects: int = 0
    hypotheses: int = 0
    detections: int = 0
    """Matched pairs (with the switches among them)."""
    misses: int = 0
    false_positives: int = 0
    switches: int = 0
    distance: float = 0.0
    frames: int = 0
    last: dict[int, int] = field(default_factory=dict)
    """Each object's last matched hypothesis (kept while the object is unseen)."""
    _pair_frames: dict[tuple[int, int], int] = field(default_factory=lambda: defaultdict(int))
    _object_frames: dict[int, int] = field(default_factory=lambda: defaultdict(int))
    _hypothesis_frames: dict[int, int] = field(default_factory=lambda: defaultdict(int))

    def update(self, truth: dict[int, np.ndarray], tracks: dict[int, np.ndarray]) -> dict[int, int]:
        """One frame: positions of the ground-truth objects and of the hypotheses, by
        id. Returns this frame's matches (object -> hypothesis)."""
        oids, hids = list(truth), list(tracks)
        cost = np.full((len(oids), len(hids)), np.inf)
        if oids and hids:
            a = np.array([np.asarray(truth[o], dtype=float) for o in oids])
            b = np.array([np.asarray(tracks[h], dtype=float) for h in hids])
            d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
            cost = np.where(d <= self.gate, d, np.inf)  # NaN positions never match
        for i, o in enumerate(oids):
            self._object_frames[o] += 1
            for j, h in enumerate(hids):
                if np.isfinite(cost[i, j]):
                    self._pair_frames[(o, h)] += 1
        for h in hids:
            self._hypothesis_frames[h] += 1
        matched: dict[int, int] = {}
        column = {h: j for j, h in enumerate(hids)}
        free_rows, free_cols = set(range(len(oids))), set(range(len(hids)))
        for i, o in enumerate(oids):  # 1. keep last matches still within the gate
            j = column.get(self.last.get(o, -1))
            if j is not None and j in free_cols and np.isfinite(cost[i, j]):
                matched[o] = hids[j]
                self.distance += float(cost[i, j])
                free_rows.discard(i)
                free_cols.discard(j)
        rows, cols = sorted(free_rows), sorted(free_cols)
        for r, c in gated_assignment(cost[np.ix_(rows, cols)]):  # 2. the rest
            o, h = oids[rows[r]], hids[cols[c]]
            if o in self.last and self.last[o] != h:
                self.switches += 1  # 3.
            matched[o] = h
            self.distance += float(cost[rows[r], cols[c]])
        self.last.update(matched)
        self.frames += 1
        self.objects += len(oids)
        self.hypotheses += len(hids)
        self.detections += len(matched)
        self.misses += len(oids) - len(matched)
        self.false_positives += len(hids) - len(matched)
        return matched

    def identity_tp(self) -> int:
        """IDTP: frames matched under the best one-to-one assignment of whole
        trajectories (object id -> hypothesis id)."""
        objects, hypotheses = sorted(self._object_frames), sorted(self._hypothesis_frames)
        if not objects or not hypotheses:
            return 0
        together = np.zeros((len(objects), len(hypotheses)))
        row = {o: i for i, o in enumerate(objects)}
        col = {h: j for j, h in enumerate(hypotheses)}
        for (o, h), n in self._pair_frames.items():
            together[row[o], col[h]] = n
        rows, cols = linear_sum_assignment(-together)
        return int(together[rows, cols].sum())

    def summary(self) -> dict[str, float]:
        """MOTA, MOTP (m), IDF1, IDP, IDR and the counts behind them."""
        idtp = self.identity_tp()
        objects, hypotheses = self.objects, self.hypotheses
        return {
            "MOTA": 1.0 - (self.misses + self.false_positives + self.switches) / objects
            if objects
            else float("nan"),
            "MOTP": self.distance / self.detections if self.detections else float("nan"),
            "IDF1": 2 * idtp / (objects + hypotheses) if objects + hypotheses else float("nan"),
            "IDP": idtp / hypotheses if hypotheses else float("nan"),
            "IDR": idtp / objects if objects else float("nan"),
            "objects": objects,
            "hypotheses": hypotheses,
            "detections": self.detections,
            "matches": self.detections - self.switches,  # as motmetrics counts them
            "misses": self.misses,
            "false_positives": self.false_positives,
            "id_switches": self.switches,
            "frames": self.frames,
        }
