"""Camera calibration for people detection (thesis 3.4.3, Fig. 3.15).

Kinect-Kinect: both cameras see the inner corners of a chessboard (5 x 6 squares,
640 x 560 mm) in a few poses; the rigid transform between them is the least-squares
fit of the corresponding 3-D corners (Kabsch). Master Kinect-robot: an RGB marker on
the end-effector seen in N robot poses is the same AX = YB problem as the trackers',
solved by `components.domain.calibration.hand_eye` (reused, not copied).
"""

from __future__ import annotations

import numpy as np

from components.domain.calibration import CalibrationError, HandEyeResult, hand_eye

SQUARES = (5, 6)
BOARD = (0.64, 0.56)  # m


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid transform T (4x4) minimising |T source - target| over corresponding
    points (rows; NaN rows ignored), and each point's residual (m)."""
    keep = ~(np.isnan(source).any(axis=1) | np.isnan(target).any(axis=1))
    src, dst = source[keep], target[keep]
    if len(src) < 3:
        raise CalibrationError("a rigid fit needs at least 3 points seen by both cameras")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise CalibrationError("a corner position is infinite")
    spread = np.linalg.svd(src - src.mean(axis=0), compute_uv=False)
    if spread[1] < 1e-3 * spread[0]:
        raise CalibrationError(
            "the points seen by both cameras lie on one line: the rotation about it is "
            "unobservable; show the board in more poses (or more of it)"
        )
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rotation, cd - rotation @ cs
    residuals = np.linalg.norm(src @ rotation.T + t[:3, 3] - dst, axis=1)
    return t, residuals


def chessboard_corners(
    squares: tuple[int, int] = SQUARES, size: tuple[float, float] = BOARD
) -> np.ndarray:
    """Inner corners of the board in its own frame (z = 0), m."""
    nx, ny = squares
    xs = np.arange(1, nx) * size[0] / nx
    ys = np.arange(1, ny) * size[1] / ny
    grid = np.array([(x, y, 0.0) for y in ys for x in xs])
    return grid - np.array([size[0] / 2, size[1] / 2, 0.0])


def kinect_to_kinect(
    corners_a: list[np.ndarray], corners_b: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """camera_a_from_camera_b from the board's corners seen by both, over all poses."""
    return rigid_fit(np.vstack(corners_b), np.vstack(corners_a))


def kinect_to_robot(
    marker_in_camera: list[np.ndarray], ee_in_base: list[np.ndarray]
) -> HandEyeResult:
    """Master Kinect-robot: A_k = X B_k Y with A the end-effector marker in the camera
    frame, B the end-effector in the base frame; X = camera_from_base."""
    return hand_eye(marker_in_camera, ee_in_base)
