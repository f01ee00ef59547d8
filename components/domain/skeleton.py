"""Skeletons (15 joints, thesis Fig. 3.14), the Kinect's noise model, envelopes.

A skeleton is a (15, 3) array of joint positions in metres (NaN where a joint is not
seen). Envelopes are capsules along the limbs plus a sphere for the head, each grown
by a margin of `sigmas` standard deviations of the depth noise at that distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

JOINTS = (
    "head",
    "neck",
    "torso",
    "left_shoulder",
    "left_elbow",
    "left_hand",
    "right_shoulder",
    "right_elbow",
    "right_hand",
    "left_hip",
    "left_knee",
    "left_foot",
    "right_hip",
    "right_knee",
    "right_foot",
)
J = {name: i for i, name in enumerate(JOINTS)}
LIMBS: tuple[tuple[str, str, float], ...] = (
    ("head", "head", 0.12),
    ("head", "neck", 0.07),
    ("neck", "torso", 0.17),
    ("left_shoulder", "right_shoulder", 0.08),
    ("torso", "left_hip", 0.15),
    ("torso", "right_hip", 0.15),
    ("left_hip", "right_hip", 0.10),
    ("left_shoulder", "left_elbow", 0.06),
    ("left_elbow", "left_hand", 0.05),
    ("right_shoulder", "right_elbow", 0.06),
    ("right_elbow", "right_hand", 0.05),
    ("left_hip", "left_knee", 0.08),
    ("left_knee", "left_foot", 0.07),
    ("right_hip", "right_knee", 0.08),
    ("right_knee", "right_foot", 0.07),
)
"""(from joint, to joint, radius in m) of every capsule; the head is a sphere."""
_A = np.array([J[a] for a, _, _ in LIMBS])
_B = np.array([J[b] for _, b, _ in LIMBS])
_R = np.array([r for _, _, r in LIMBS])


def depth_sigma(z: np.ndarray | float) -> np.ndarray:
    """Kinect v1 depth noise (1 sigma, m) at distance z (Khoshelham & Oude Elberink 2012)."""
    return 1.425e-3 * np.square(z)


def body_center(skeleton: np.ndarray) -> np.ndarray:
    """Where a person is (3,): the torso joint, or the mean of the seen joints while the
    torso is hidden (NaN when nothing is seen). A hidden torso must not hide a person."""
    torso = skeleton[2]
    if np.isfinite(torso).all():
        return torso
    seen = np.isfinite(skeleton).all(axis=1)
    return skeleton[seen].mean(axis=0) if seen.any() else np.full(3, np.nan)


def body_centers(skeletons: np.ndarray) -> np.ndarray:
    """`body_center` of many skeletons (n, 15, 3) at once: (n, 3)."""
    center = skeletons[:, 2].copy()
    hidden = ~np.isfinite(center).all(axis=1)
    if hidden.any():  # the mean of the seen joints, only where the torso is hidden
        some = skeletons[hidden]
        seen = np.isfinite(some).all(axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            center[hidden] = (
                np.where(seen[..., None], some, 0.0).sum(axis=1) / seen.sum(axis=1)[:, None]
            )
    return center


@dataclass(frozen=True)
class Build:
    """How a body is made, as far as a skeleton shows it: the height, and the breadth of
    the shoulders and hips and the length of the legs relative to a body of that height
    (1.0: the 1.75 m template's proportions)."""

    height: float = 1.75
    shoulders: float = 1.0
    hips: float = 1.0
    legs: float = 1.0

    @classmethod
    def drawn(cls, rng: np.random.Generator) -> Build:
        """Someone from a mixed adult population: height 1.72 +- 0.09 m (men and women
        together, clipped to 1.50-1.98 m), shoulder and hip breadth +- 6%, legs +- 3%
        relative to height (anthropometric surveys' spread between adults)."""
        return cls(
            float(np.clip(rng.normal(1.72, 0.09), 1.50, 1.98)),
            float(rng.normal(1.0, 0.06)),
            float(rng.normal(1.0, 0.06)),
            float(rng.normal(1.0, 0.03)),
        )


_SHOULDER_SIDE = [3, 4, 5, 6, 7, 8]
_HIP_SIDE = [9, 10, 11, 12, 13, 14]
_LEG_LIFT = [9, 10, 12, 13]  # hips and knees rise with longer legs (feet stay down)


def standing(
    at: tuple[float, float],
    facing: float = 0.0,
    height: float = 1.75,
    build: Build | None = None,
    floor: float = 0.0,
) -> np.ndarray:
    """A standing person's skeleton (world frame, z up) at floor position `at` on a
    floor at height `floor`, of a given height or `build`."""
    build = build or Build(height)
    s = build.height / 1.75
    local = (
        np.array(
            [
                (0.0, 0.0, 1.65),
                (0.0, 0.0, 1.47),
                (0.0, 0.0, 1.20),
                (0.0, 0.20, 1.45),
                (0.0, 0.25, 1.18),
                (0.0, 0.27, 0.93),
                (0.0, -0.20, 1.45),
                (0.0, -0.25, 1.18),
                (0.0, -0.27, 0.93),
                (0.0, 0.10, 0.95),
                (0.0, 0.11, 0.52),
                (0.0, 0.11, 0.08),
                (0.0, -0.10, 0.95),
                (0.0, -0.11, 0.52),
                (0.0, -0.11, 0.08),
            ]
        )
        * s
    )
    local[_SHOULDER_SIDE, 1] *= build.shoulders
    local[_HIP_SIDE, 1] *= build.hips
    local[_LEG_LIFT, 2] *= build.legs
    c, w = np.cos(facing), np.sin(facing)
    rotation = np.array([[c, -w, 0.0], [w, c, 0.0], [0.0, 0.0, 1.0]])
    return local @ rotation.T + np.array([at[0], at[1], floor])


def envelope(
    skeleton: np.ndarray, sigma: np.ndarray | float = 0.0, sigmas: float = 3.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capsules (p, q, radius) around a skeleton; `sigma` is the position noise (m) per
    joint or overall, and the margin is `sigmas` of it. Limbs with an unseen (NaN) end
    are left out."""
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (len(JOINTS),))
    p, q = skeleton[_A], skeleton[_B]
    seen = limbs_seen(skeleton)
    margin = sigmas * np.maximum(sigma[_A], sigma[_B])
    return p[seen], q[seen], (_R + margin)[seen]


def envelopes(
    skeletons: np.ndarray, sigma: np.ndarray, sigmas: float = 3.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`envelope` of many skeletons at once ((n, 15, 3), sigma (n, 15)): the capsules
    (p, q, radius) of all of them, and for each capsule its skeleton and limb index."""
    p, q = skeletons[:, _A], skeletons[:, _B]  # (n, limbs, 3)
    seen = ~(np.isnan(p).any(axis=2) | np.isnan(q).any(axis=2))
    radius = _R + sigmas * np.maximum(sigma[:, _A], sigma[:, _B])
    owner, limb = np.nonzero(seen)
    return p[seen], q[seen], radius[seen], owner, limb


def limbs_seen(skeleton: np.ndarray) -> np.ndarray:
    """Which of `LIMBS` have both ends seen (the capsules `envelope` returns, in order)."""
    p, q = skeleton[_A], skeleton[_B]
    return ~(np.isnan(p).any(axis=1) | np.isnan(q).any(axis=1))
