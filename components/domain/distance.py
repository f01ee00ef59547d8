"""Distances between capsules (segments with radii), vectorised over all pairs.

A capsule is a segment [p, q] swept by a sphere of radius r; a sphere is a capsule
whose segment has zero length. The distance between two capsules is the distance
between their segments minus both radii (negative: they overlap). Robot links and
people's limbs are both capsules, so one kernel serves every robot-person pair.
"""

from __future__ import annotations

import numpy as np

from components.domain.kernel import _fwkernel

EPS = 1e-12
PARALLEL = 1e-14
"""sin^2 of the angle below which two segments are solved as parallel (1e-7 rad: the
error is at most length x angle, 0.2 um for 2 m segments)."""


def _unit(x: np.ndarray) -> np.ndarray:
    """`x` clamped to [0, 1] (two ufunc calls: np.clip's wrapper costs more than the work
    on the small arrays of a 1 kHz loop)."""
    return np.minimum(np.maximum(x, 0.0), 1.0)


def segment_distances(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Closest distance between segments [p1, q1] (shape (n, 3)) and [p2, q2] ((m, 3)),
    for every pair: an (n, m) array. Degenerate segments (points) are handled.

    Written for small arrays at 1 kHz (a robot's links against a few people): each numpy
    call costs about a microsecond whatever its size, so the steps are as few as the
    cases allow, and (n, 1) against (1, m) arrays broadcast instead of being expanded."""
    p1, q1, p2, q2 = (np.asarray(a, dtype=float) for a in (p1, q1, p2, q2))
    d1, d2 = q1 - p1, q2 - p2  # (n, 3), (m, 3)
    # the dot products of d1, d2 and r = p1 - p2 for every pair, by matrix products
    # (no (n, m, 3) temporaries until the closest points)
    a = np.einsum("ij,ij->i", d1, d1)[:, None]  # |d1|^2, (n, 1)
    e = np.einsum("ij,ij->i", d2, d2)[None, :]  # |d2|^2, (1, m)
    b = d1 @ d2.T
    c = np.einsum("ij,ij->i", d1, p1)[:, None] - d1 @ p2.T  # d1 . r
    f = p1 @ d2.T - np.einsum("ij,ij->i", d2, p2)[None, :]  # d2 . r
    ae = a * e
    denom = ae - b * b  # |d1|^2 |d2|^2 sin^2(angle)
    first_point, second_point = a <= EPS, e <= EPS  # (n, 1), (1, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        on_first = _unit(-c / a)  # the second's start projected on the first
        # parallel is a question of angle, not of size: two short perpendicular segments
        # have a tiny denominator too (an absolute threshold put them 16 mm apart when
        # they touched). General case: closest points of the infinite lines, s clamped
        s = np.where(denom > PARALLEL * ae, _unit((b * f - c * e) / denom), 0.0)
        if second_point.any():  # the second segment is a point: project it on the first
            s = np.where(second_point, on_first, s)
        t = np.where(second_point, 0.0, (b * s + f) / e)
        # t outside [0, 1]: clamp it and recompute s for the clamped t
        s = np.where(t < 0.0, on_first, np.where(t > 1.0, _unit((b - c) / a), s))
        if first_point.any():
            s = np.where(first_point, 0.0, s)
    t = _unit(t)
    # closest points r + s d1 - t d2, summed over the axes in order
    axis = (
        (p1[:, None, :] - p2[None, :, :])
        + s[:, :, None] * d1[:, None, :]
        - t[:, :, None] * d2[None, :, :]
    )
    return np.sqrt((axis * axis).sum(axis=2))


def capsule_distances(
    p1: np.ndarray, q1: np.ndarray, r1: np.ndarray, p2: np.ndarray, q2: np.ndarray, r2: np.ndarray
) -> np.ndarray:
    """Surface distance between every pair of capsules (negative when they overlap)."""
    return (
        segment_distances(p1, q1, p2, q2)
        - np.asarray(r1, dtype=float)[:, None]
        - np.asarray(r2, dtype=float)[None, :]
    )


def least_capsule_distance(
    p1: np.ndarray, q1: np.ndarray, r1: np.ndarray, p2: np.ndarray, q2: np.ndarray, r2: np.ndarray
) -> float:
    """The least surface distance between any capsule of the first set and any of the
    second (inf if either is empty; NaN if any pair's is): `min(capsule_distances(...))`,
    in the compiled kernel where it was built (one pass, no (n, m) arrays: a 1 kHz
    separation check against a crowd), which a spec holds to this module's formulas."""
    if _fwkernel is None:
        distances = capsule_distances(p1, q1, r1, p2, q2, r2)
        return float(np.min(distances)) if distances.size else float("inf")
    best, _, _ = _fwkernel.capsule_min(
        *(np.ascontiguousarray(x, dtype=float) for x in (p1, q1, r1, p2, q2, r2))
    )
    return float(best)


def closest_pair(distances: np.ndarray) -> tuple[float, int, int]:
    """(minimum distance, row, column) of a distance matrix; (inf, -1, -1) if empty."""
    if distances.size == 0:
        return float("inf"), -1, -1
    flat = int(np.argmin(distances))
    row, col = divmod(flat, distances.shape[1])
    return float(distances[row, col]), row, col
