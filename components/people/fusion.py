"""Cross-camera matching and fusion of skeletons (thesis 3.4.2, eq. 3.8-3.10).

Two matchers: the thesis rule (eq. 3.9: two users are the same person when every
joint is within 0.45 m, taken greedily in order) as the baseline, and a global
assignment (Hungarian, scipy) on the median joint distance in units of the noise
(over the joints both cameras see), gated at `GATE_SIGMAS`. Matched skeletons are fused
joint by joint, weighted by the inverse variance of each camera's noise.

Why the gate comes from the noise, not from a distance: two people stand at least a
body's width (0.4 m) apart, one person's joints seen by two cameras differ by their
noise (1-3 cm at 1-4 m). A fixed 0.45 m gate fused neighbours into one person and
left their other detections as duplicates; a gate of 4 sigma keeps a person's views
together wherever the noise puts them and never reaches the next person.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from components.domain.skeleton import body_centers, depth_sigma

RULE_THRESHOLD = 0.45  # eq. 3.9, metres
GATE_SIGMAS = 4.03
"""The gate on `normalized_cost`: the 99.9% quantile of the length of a 3D error whose
axes have a standard deviation of 1 (the chi distribution with 3 degrees of freedom),
so a true pair is refused less than once in a thousand even if it shares one joint;
the median over more joints is tighter still. `noise_for`'s sigma bounds every axis,
so this errs towards keeping a person's views together."""


@dataclass
class Detection:
    """One camera's user in the master frame, with its per-joint noise (1 sigma, m)."""

    camera: str
    user_id: int
    joints: np.ndarray  # (15, 3), NaN where unseen
    sigma: np.ndarray  # (15,)


def joint_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-joint distances of every pair: (n, m, 15), NaN where either joint is unseen."""
    diff = a[:, None, :, :] - b[None, :, :, :]
    return np.sqrt(diff[..., 0] ** 2 + diff[..., 1] ** 2 + diff[..., 2] ** 2)


def rule_matches(
    a: np.ndarray, b: np.ndarray, threshold: float = RULE_THRESHOLD
) -> list[tuple[int, int]]:
    """Eq. 3.9 baseline: pair i, j when every joint seen by both is within `threshold`,
    greedily in index order, each user used once."""
    if not len(a) or not len(b):
        return []
    d = joint_distances(a, b)
    seen = ~np.isnan(d)
    ok = np.where(seen, d <= threshold, True).all(axis=2) & seen.any(axis=2)
    pairs, used = [], set()
    for i in range(len(a)):
        for j in range(len(b)):
            if ok[i, j] and j not in used:
                pairs.append((i, j))
                used.add(j)
                break
    return pairs


def robust_cost(a: np.ndarray, b: np.ndarray, within: float = math.inf) -> np.ndarray:
    """Median joint distance over the joints both see: (n, m), inf if none in common,
    or if their body centres lie farther than `within` apart on the floor (`SAME_BODY`:
    such a pair is not costed at all, which is what keeps a crowded frame cheap)."""
    n, m = len(a), len(b)
    median = np.full((n, m), np.inf)
    if not n or not m:
        return median
    fa, fb = (~np.isnan(a[..., 0])).astype(float), (~np.isnan(b[..., 0])).astype(float)
    count = fa @ fb.T  # joints both see, (n, m)
    if math.isfinite(within):
        ca, cb = body_centers(a), body_centers(b)
        dx = ca[:, None, 0] - cb[None, :, 0]
        dy = ca[:, None, 1] - cb[None, :, 1]
        candidates = (count > 0) & (dx * dx + dy * dy <= within * within)
        rows, cols = np.nonzero(candidates)
        if not len(rows):
            return median
        diff = a[rows] - b[cols]  # (pairs, 15, 3), NaN where either joint is unseen
        common = count[rows, cols]
    else:  # every pair: broadcast, no gathering
        diff = (a[:, None] - b[None, :]).reshape(n * m, -1, 3)
        common = count.ravel()
    squared = diff[..., 0] ** 2 + diff[..., 1] ** 2 + diff[..., 2] ** 2
    ordered = np.sort(squared, axis=1)  # NaN (unseen) last
    common = common.astype(int)
    pick = np.arange(len(ordered))
    # the median of the seen joints (low == high when their count is odd; with no joint
    # in common it is NaN, and the pair's cost inf)
    low = np.sqrt(ordered[pick, np.maximum((common - 1) // 2, 0)])
    high = np.sqrt(ordered[pick, common // 2])
    middle = (low + high) / 2.0
    if math.isfinite(within):
        median[rows, cols] = middle
    else:
        median = np.where(count > 0, middle.reshape(n, m), np.inf)
    return median


def normalized_cost(
    a: np.ndarray, sigma_a: np.ndarray, b: np.ndarray, sigma_b: np.ndarray, slack: float = 0.0
) -> np.ndarray:
    """The median joint distance over the joints both see, less `slack` (how far the
    joints may have moved between a and b, such as a walker's motion), in units of the
    noise sqrt(sigma_a^2 + sigma_b^2), each skeleton's sigma its largest joint's (a
    skeleton's joints lie within a metre of one another, so their sigmas differ little,
    and the largest errs toward keeping a person's views together): (n, m), inf if no
    joint in common. Compare with `GATE_SIGMAS`."""
    return _in_sigmas(robust_cost(a, b), worst_sigma(a, sigma_a), worst_sigma(b, sigma_b), slack)


def worst_sigma(joints: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Each skeleton's largest sigma over the joints it sees: (n,) of (n, 15, 3), (n, 15)."""
    return np.fmax.reduce(np.where(np.isnan(joints[..., 0]), 0.0, sigma), axis=1, initial=0.0)


def _in_sigmas(
    median: np.ndarray, worst_a: np.ndarray, worst_b: np.ndarray, slack: float = 0.0
) -> np.ndarray:
    """`normalized_cost` from the median distances and each side's sigma."""
    if not median.size:
        return median
    scale = np.sqrt(np.square(worst_a)[:, None] + np.square(worst_b)[None, :])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.maximum(median - slack, 0.0) / scale


SAME_BODY = 1.0
"""m: two views whose body centres (`skeleton.body_center`: the torso, or the mean of
the seen joints while it is hidden) lie farther apart than this on the floor are not
one person, and are not costed. A person's views differ by their noise (1-3 cm), and
a view that sees only part of the body puts its centre at most a reach (under 0.9 m,
a hand held out) from the torso. People stand 0.4 m apart, so in a crowd most pairs
are beyond it: what keeps a frame of 8 cameras x 16 people cheap is the pairs not
costed (fusion only: a tracker's few tracks against a frame's people cost less
than the bound)."""

BEYOND_GATE = 1e6


def hungarian_matches(
    a: np.ndarray, b: np.ndarray, gate: float = RULE_THRESHOLD
) -> list[tuple[int, int]]:
    """Globally best one-to-one pairing on `robust_cost`, keeping pairs under the gate."""
    if not len(a) or not len(b):
        return []
    return gated_pairs(robust_cost(a, b), gate)


def gated_pairs(cost: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """The one-to-one pairing with the most pairs under `gate`, and of those the
    cheapest (Hungarian). Every pair beyond the gate costs the same: were they priced
    as they are, the assignment could break a good pair to avoid a very bad one, and
    both would be lost to the gate (two people near each other, a third far away)."""
    if not cost.size:
        return []
    under = cost <= gate  # NaN and inf are beyond it too
    if not under.any():
        return []
    rows, cols = linear_sum_assignment(np.where(under, cost, BEYOND_GATE))
    keep = under[rows, cols]
    return list(zip(rows[keep].tolist(), cols[keep].tolist(), strict=True))


def fuse(detections: list[Detection]) -> tuple[np.ndarray, np.ndarray]:
    """Inverse-variance weighted joints and their fused sigma; NaN joints are skipped."""
    joints = np.stack([d.joints for d in detections])  # (k, 15, 3)
    sigma = np.stack([d.sigma for d in detections])  # (k, 15)
    with np.errstate(divide="ignore"):  # unseen joints may carry sigma 0: weight 0 anyway
        weight = np.where(np.isnan(joints).any(axis=2), 0.0, 1.0 / np.square(sigma))
    total = weight.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = np.nansum(joints * weight[..., None], axis=0) / total[:, None]
        fused_sigma = 1.0 / np.sqrt(total)
    fused[total == 0] = np.nan
    fused_sigma[total == 0] = np.nan  # unseen: no sigma (never an infinite one)
    return fused, fused_sigma


def _weights(joints: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Inverse-variance weights (..., 15); unseen joints weigh nothing."""
    with np.errstate(divide="ignore"):  # unseen joints may carry sigma 0: weight 0 anyway
        return np.where(np.isnan(joints).any(axis=-1), 0.0, 1.0 / np.square(sigma))


def group_and_fuse(
    detections: list[Detection], matcher: str = "hungarian"
) -> list[tuple[list[Detection], np.ndarray, np.ndarray]]:
    """Cluster the detections of all cameras into people (see `group_and_fuse_arrays`);
    each group as its detections with its fused joints and sigma."""
    by_camera: dict[str, list[Detection]] = {}
    for d in detections:
        by_camera.setdefault(d.camera, []).append(d)
    batches = [
        (camera, np.stack([u.joints for u in users]), np.stack([u.sigma for u in users]))
        for camera, users in by_camera.items()
    ]
    members, fused, sigma = group_and_fuse_arrays(batches, matcher)
    return [
        ([by_camera[c][k] for c, k in group], fused[i], sigma[i]) for i, group in enumerate(members)
    ]


def group_and_fuse_arrays(
    batches: list[tuple[str, np.ndarray, np.ndarray]], matcher: str = "hungarian"
) -> tuple[list[list[tuple[str, int]]], np.ndarray, np.ndarray]:
    """`cluster` the users of all cameras into people. `batches` holds each camera's
    users as arrays (camera, joints (n, 15, 3), sigma (n, 15)); returns each group's
    members as (camera, row), the fused joints (g, 15, 3) and sigma (g, 15)."""
    batches = sorted((b for b in batches if len(b[1])), key=lambda b: b[0])
    if not batches:
        return [], np.zeros((0, 15, 3)), np.zeros((0, 15))
    sizes = [len(b[1]) for b in batches]
    camera_of = np.repeat(np.arange(len(batches)), sizes)
    group_of, fused, sigma = cluster(
        np.concatenate([b[1] for b in batches]),
        np.concatenate([b[2] for b in batches]),
        camera_of,
        matcher,
    )
    names = [b[0] for b in batches]
    members: list[list[tuple[str, int]]] = [[] for _ in range(len(fused))]
    first = np.cumsum(sizes) - sizes
    for row, (group, camera) in enumerate(zip(group_of.tolist(), camera_of.tolist(), strict=True)):
        members[group].append((names[camera], row - int(first[camera])))
    return members, fused, sigma


def cluster(
    joints: np.ndarray, sigma: np.ndarray, camera_of: np.ndarray, matcher: str = "hungarian"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cluster users into people, in rounds: the first camera with users not yet
    grouped founds a group per user, and every other camera's ungrouped users are
    paired with those groups at once (each camera one to one: "hungarian" on
    `normalized_cost`, the founder's sigma against the user's, gated at `GATE_SIGMAS`;
    "rule" is eq. 3.9); who is left waits for the next round. When every camera sees
    everyone, one round groups them all. Rows are users (joints (n, 15, 3), sigma
    (n, 15)), `camera_of` their cameras (ascending: a camera's users are consecutive,
    in the order cameras found groups). Returns each user's group, and each group's
    fused joints (g, 15, 3) and sigma (g, 15) (`fuse` of its users gives the same).

    Why rounds and not a merge per camera into the fused groups: a frame's cost is
    numpy calls, not arithmetic (8 cameras x 16 users are a few thousand pairs), and
    a round pairs every camera against the founders in one cost matrix. The founder's
    noise is the right gate for a pair (one view against another), where a fused
    group's sigma only narrows as cameras join."""
    worst = worst_sigma(joints, sigma) if matcher == "hungarian" else None
    group_of = np.full(len(joints), -1)
    groups = 0
    free = np.arange(len(joints))
    while len(free):
        founding = camera_of[free] == camera_of[free[0]]
        found, rest = free[founding], free[~founding]
        group_of[found] = np.arange(groups, groups + len(found))
        groups += len(found)
        if not len(rest):
            break
        bounds = np.flatnonzero(np.diff(camera_of[rest])) + 1  # where each camera starts
        if worst is not None:
            median = robust_cost(joints[found], joints[rest], SAME_BODY)
            i, j = pairs_per_block(_in_sigmas(median, worst[found], worst[rest]), bounds)
        else:
            pairs = [
                (i, int(cols[j]))
                for cols in np.split(np.arange(len(rest)), bounds)
                for i, j in rule_matches(joints[found], joints[rest[cols]])
            ]
            i, j = np.array(pairs, dtype=int).reshape(-1, 2).T
        group_of[rest[j]] = group_of[found[i]]
        free = rest[group_of[rest] < 0]
    weights = _weights(joints, sigma)
    contributions = np.where(weights[..., None] > 0, joints, 0.0) * weights[..., None]
    order = np.argsort(group_of, kind="stable")
    starts = np.searchsorted(group_of[order], np.arange(groups))
    weighted = np.add.reduceat(contributions[order], starts, axis=0)
    total = np.add.reduceat(weights[order], starts, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = weighted / total[..., None]
        fused_sigma = 1.0 / np.sqrt(total)
    fused[total == 0] = np.nan
    fused_sigma[total == 0] = np.nan  # unseen: no sigma (never an infinite one)
    return group_of, fused, fused_sigma


def pairs_per_block(
    cost: np.ndarray, bounds: np.ndarray, gate: float = GATE_SIGMAS
) -> tuple[np.ndarray, np.ndarray]:
    """`gated_pairs` in each block of columns (split at `bounds`: a camera's users) of
    `cost`, as row and column indices. A block where no row and no column has more
    than one pair under the gate is paired as it stands (the assignment could only
    choose those pairs); only the others need the Hungarian."""
    under = cost <= gate
    starts = np.concatenate([[0], bounds])
    clear = (under.sum(axis=0) <= 1).all() and (np.add.reduceat(under, starts, axis=1) <= 1).all()
    if clear:
        return np.nonzero(under)
    rows, cols = [], []
    ends = [*bounds.tolist(), cost.shape[1]]
    for start, end in zip(starts.tolist(), ends, strict=True):
        for i, j in gated_pairs(cost[:, start:end], gate):
            rows.append(i)
            cols.append(start + j)
    return np.array(rows, dtype=int), np.array(cols, dtype=int)


def group(detections: list[Detection], matcher: str = "hungarian") -> list[list[Detection]]:
    """The people (as their detections) of one frame; see `group_and_fuse`."""
    return [members for members, _, _ in group_and_fuse(detections, matcher)]


def noise_for(joints_in_camera: np.ndarray, lateral: float | np.ndarray = 0.01) -> np.ndarray:
    """Per-joint sigma (m) of a camera's skeleton(s) (..., 15, 3) from its depths (z along
    the axis); `lateral` may differ per skeleton (an array that broadcasts to (..., 15))."""
    z = joints_in_camera[..., 2]
    return np.sqrt(np.square(depth_sigma(z)) + lateral**2)
