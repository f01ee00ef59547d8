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

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from components.domain.skeleton import depth_sigma

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


def robust_cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Median joint distance over the joints both see: (n, m), inf if none in common."""
    return _median_seen(joint_distances(a, b), a, b)


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
    with np.errstate(invalid="ignore"):
        return np.nanmax(np.where(np.isnan(joints[..., 0]), np.nan, sigma), axis=1, initial=0.0)


def _in_sigmas(
    median: np.ndarray, worst_a: np.ndarray, worst_b: np.ndarray, slack: float = 0.0
) -> np.ndarray:
    """`normalized_cost` from the median distances and each side's sigma."""
    if not median.size:
        return median
    scale = np.sqrt(np.square(worst_a)[:, None] + np.square(worst_b)[None, :])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.maximum(median - slack, 0.0) / scale


def _median_seen(d: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The median of `d` (n, m, 15) over the joints both a (n, 15, 3) and b (m, 15, 3) see."""
    if not d.size:
        return np.full(d.shape[:2], np.inf)
    seen_a, seen_b = ~np.isnan(a[..., 0]), ~np.isnan(b[..., 0])  # (n, 15), (m, 15)
    count = (seen_a.astype(float) @ seen_b.T.astype(float)).astype(int)  # joints both see
    ordered = np.sort(d, axis=2).reshape(-1, d.shape[2])  # unseen (NaN) joints sort last
    rows = np.arange(len(ordered))
    # the median of the seen joints (low == high when their count is odd)
    low = ordered[rows, np.maximum((count.ravel() - 1) // 2, 0)]
    high = ordered[rows, count.ravel() // 2]
    median = ((low + high) / 2.0).reshape(count.shape)
    median[count == 0] = np.inf
    return median


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
    finite = np.where(cost <= gate, cost, BEYOND_GATE)  # NaN and inf are beyond it too
    rows, cols = linear_sum_assignment(finite)
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if cost[i, j] <= gate]


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
    """Cluster the users of all cameras into people, merging cameras one after the
    other (in name order) into the growing set of groups: "hungarian" pairs a camera's
    users with the groups on `normalized_cost` (the group's fused sigma, the user's),
    gated at `GATE_SIGMAS`; "rule" is eq. 3.9. `batches` holds each
    camera's users as arrays (camera, joints (n, 15, 3), sigma (n, 15)); returns each
    group's members as (camera, row), the fused joints (g, 15, 3) and sigma (g, 15).

    Groups keep running sums of weighted joints and weights, so adding a camera's users
    costs a few array operations whatever the number of groups (`fuse` of the members
    gives the same result)."""
    noise_gated = matcher == "hungarian"
    groups: list[list[tuple[str, int]]] = []
    weighted = np.zeros((0, 15, 3))
    total = np.zeros((0, 15))
    fused = np.zeros((0, 15, 3))
    batches = sorted(batches, key=lambda b: b[0])
    if not batches:
        return groups, fused, total
    every = np.concatenate([b[1] for b in batches])
    sigmas = np.concatenate([b[2] for b in batches])
    weights = _weights(every, sigmas)
    worst = worst_sigma(every, sigmas)
    contributions = np.where(weights[..., None] > 0, every, 0.0) * weights[..., None]
    first = 0
    for camera, joints, _ in batches:
        weight = weights[first : first + len(joints)]
        contribution = contributions[first : first + len(joints)]
        first += len(joints)
        if not groups or not len(joints):
            pairs = []
        elif noise_gated:
            with np.errstate(divide="ignore"):
                group_worst = 1.0 / np.sqrt(np.where(total > 0, total, np.inf).min(axis=1))
            cost = _in_sigmas(
                robust_cost(fused, joints), group_worst, worst[first - len(joints) : first]
            )
            pairs = gated_pairs(cost, GATE_SIGMAS)
        else:
            pairs = rule_matches(fused, joints)
        if pairs:
            rows = np.array([i for i, _ in pairs])
            cols = np.array([j for _, j in pairs])
            weighted[rows] += contribution[cols]
            total[rows] += weight[cols]
            for i, j in pairs:
                groups[i].append((camera, j))
        matched = {j for _, j in pairs}
        fresh = [j for j in range(len(joints)) if j not in matched]
        if fresh:
            groups.extend([(camera, j)] for j in fresh)
            weighted = np.concatenate([weighted, contribution[fresh]])
            total = np.concatenate([total, weight[fresh]])
        with np.errstate(invalid="ignore", divide="ignore"):
            fused = weighted / total[..., None]
        fused[total == 0] = np.nan
    with np.errstate(divide="ignore"):
        sigma_out = 1.0 / np.sqrt(total)
    sigma_out[total == 0] = np.nan  # unseen: no sigma (never an infinite one)
    return groups, fused, sigma_out


def group(detections: list[Detection], matcher: str = "hungarian") -> list[list[Detection]]:
    """The people (as their detections) of one frame; see `group_and_fuse`."""
    return [members for members, _, _ in group_and_fuse(detections, matcher)]


def noise_for(joints_in_camera: np.ndarray, lateral: float = 0.01) -> np.ndarray:
    """Per-joint sigma (m) of a camera's skeleton(s) (..., 15, 3) from its depths (z along
    the axis)."""
    z = joints_in_camera[..., 2]
    return np.sqrt(np.square(depth_sigma(z)) + lateral**2)
