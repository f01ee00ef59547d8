"""Distances between capsules (segments with radii), vectorised over all pairs.

A capsule is a segment [p, q] swept by a sphere of radius r; a sphere is a capsule
whose segment has zero length. The distance between two capsules is the distance
between their segments minus both radii (negative: they overlap). Robot links and
people's limbs are both capsules, so one kernel serves every robot-person pair.
"""

from __future__ import annotations

import numpy as np

EPS = 1e-12


def segment_distances(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Closest distance between segments [p1, q1] (shape (n, 3)) and [p2, q2] ((m, 3)),
    for every pair: an (n, m) array. Degenerate segments (points) are handled."""
    p1, q1, p2, q2 = (np.asarray(a, dtype=float) for a in (p1, q1, p2, q2))
    d1 = (q1 - p1)[:, None, :]  # (n, 1, 3)
    d2 = (q2 - p2)[None, :, :]  # (1, m, 3)
    r = p1[:, None, :] - p2[None, :, :]  # (n, m, 3)
    a = np.einsum("ijk,ijk->ij", d1, d1)  # |d1|^2, broadcast (n, 1)
    e = np.einsum("ijk,ijk->ij", d2, d2)  # |d2|^2, (1, m)
    f = np.einsum("ijk,ijk->ij", d2, r)
    c = np.einsum("ijk,ijk->ij", d1, r)
    b = np.einsum("ijk,ijk->ij", d1, d2)
    a, e = np.broadcast_to(a, r.shape[:2]), np.broadcast_to(e, r.shape[:2])
    denom = a * e - b * b
    first_point, second_point = a <= EPS, e <= EPS
    with np.errstate(divide="ignore", invalid="ignore"):
        # general case: closest points of the infinite lines, s clamped to [0, 1]
        s = np.where(denom > EPS, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        # the second segment is a point: project it on the first
        s = np.where(second_point & ~first_point, np.clip(-c / a, 0.0, 1.0), s)
        s = np.where(first_point, 0.0, s)
        t = np.where(second_point, 0.0, (b * s + f) / e)
        # t outside [0, 1]: clamp it and recompute s for the clamped t
        t_low, t_high = t < 0.0, t > 1.0
        s = np.where(t_low & ~first_point, np.clip(-c / a, 0.0, 1.0), s)
        s = np.where(t_high & ~first_point, np.clip((b - c) / a, 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    closest = r + s[..., None] * d1 - t[..., None] * d2
    return np.sqrt(np.einsum("ijk,ijk->ij", closest, closest))


def capsule_distances(
    p1: np.ndarray, q1: np.ndarray, r1: np.ndarray, p2: np.ndarray, q2: np.ndarray, r2: np.ndarray
) -> np.ndarray:
    """Surface distance between every pair of capsules (negative when they overlap)."""
    return (
        segment_distances(p1, q1, p2, q2)
        - np.asarray(r1, dtype=float)[:, None]
        - np.asarray(r2, dtype=float)[None, :]
    )


def closest_pair(distances: np.ndarray) -> tuple[float, int, int]:
    """(minimum distance, row, column) of a distance matrix; (inf, -1, -1) if empty."""
    if distances.size == 0:
        return float("inf"), -1, -1
    flat = int(np.argmin(distances))
    row, col = divmod(flat, distances.shape[1])
    return float(distances[row, col]), row, col
