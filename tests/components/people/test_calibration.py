"""Spec: camera calibration recovers known truth; residuals are reported."""

import numpy as np
import pytest

from components.domain.calibration import protocol_poses
from components.domain.geometry import look_at, rigid
from components.people.calibration import (
    chessboard_corners,
    kinect_to_kinect,
    kinect_to_robot,
    rigid_fit,
)
from components.people.kinect_sim import KinectModel


def test_rigid_fit_is_exact_without_noise_and_ignores_unseen_points():
    rng = np.random.default_rng(0)
    truth = rigid((0.3, -1.0, 2.0), (0.2, -0.4, 1.0))
    src = rng.normal(size=(12, 3))
    dst = src @ truth[:3, :3].T + truth[:3, 3]
    dst[3] = np.nan
    fit, residuals = rigid_fit(src, dst)
    assert np.allclose(fit, truth) and residuals.max() < 1e-9 and len(residuals) == 11
    with pytest.raises(ValueError, match="at least 3 points"):
        rigid_fit(src[:2], dst[:2])


def test_two_kinects_calibrated_with_four_board_poses():
    cam_a = KinectModel("a", look_at((0.0, -2.5, 2.0), (0.0, 0.0, 1.0)))
    cam_b = KinectModel("b", look_at((2.5, 0.5, 2.0), (0.0, 0.0, 1.0)))
    corners = chessboard_corners()
    assert corners.shape == (20, 3)
    seen_a, seen_b = [], []
    for k in range(4):  # the board held in four poses between the cameras
        board = rigid((0.2 * k - 0.3, 0.1, 1.2), (0.3, 0.5 + 0.2 * k, 0.4 * k))
        world = corners @ board[:3, :3].T + board[:3, 3]
        for cam, out in ((cam_a, seen_a), (cam_b, seen_b)):
            points = cam.to_camera(world)
            out.append(points + cam.noise(points))
    fit, residuals = kinect_to_kinect(seen_a, seen_b)
    truth = np.linalg.inv(cam_a.world_from_camera) @ cam_b.world_from_camera
    # depth sigma at 2.5-3 m is 9-13 mm, plus 10 mm lateral: centimetres at the lever arm
    assert np.linalg.norm(fit[:3, 3] - truth[:3, 3]) < 0.05
    assert np.median(residuals) < 0.05, "Kinect noise: a few cm, the thesis saw ~35 mm"


def test_the_master_kinect_to_robot_reuses_the_hand_eye_solver():
    x_true = rigid((0.5, -1.8, 1.6), (1.2, 0.1, -0.3))  # camera_from_base
    y_true = rigid((0.0, 0.0, 0.05), (0.0, 0.0, 0.0))  # ee_from_marker
    poses = protocol_poses(8, 1)
    fit = kinect_to_robot([x_true @ b @ y_true for b in poses], poses)
    assert np.allclose(fit.x, x_true, atol=1e-6)


def test_corners_on_one_line_are_refused_not_solved():
    from components.domain.calibration import CalibrationError

    line = np.array([[0.1 * k, 0.0, 2.0] for k in range(6)])
    with pytest.raises(CalibrationError, match="lie on one line"):
        rigid_fit(line, line + 0.01)
