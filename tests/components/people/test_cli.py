"""Spec: `fw calibrate-cameras` calibrates a topology's cameras, writes a cameras file
the detector loads, keeps the file's other settings, and refuses clearly."""

import warnings

import numpy as np
import pytest
import yaml

from components.domain.geometry import as_matrix, look_at
from components.people.cli import CameraCalibrationError, board_poses, cameras_of
from components.people.component import CameraConfigError, load_cameras
from components.people.kinect_sim import KinectModel
from framework.cli import main

SEEG = "topologies/seeg.yaml"


def test_calibrated_cameras_are_verified_close_to_the_truth_and_keep_the_files_settings(
    tmp_path, capsys
):
    out = tmp_path / "cameras.yaml"
    out.write_text(
        "area: {center: [0.6, 0.0], radius: 1.2}\nmatcher: rule\n"
        "cameras: {kinect_1: {lateral_noise: 0.02}}\n"
    )
    assert main(["calibrate-cameras", SEEG, "-o", str(out)]) == 0
    assert "kinect_1" in capsys.readouterr().out
    config = load_cameras(str(out))
    assert [c.name for c in config.cameras] == ["kinect_0", "kinect_1"], "named as components"
    assert config.area_radius == 1.2 and config.matcher == "rule", "settings kept"
    k1 = config.cameras[1]
    assert k1.verified and k1.lateral_noise == 0.02
    truth = {c.name: c.model.world_from_camera for c in cameras_of(SEEG)}
    estimated = config.base_from_master @ k1.master_from_camera
    point = np.array([0.6, 0.0, 0.2, 1.0])  # above the table, where people lean
    in_camera = np.linalg.inv(truth["kinect_1"]) @ point
    assert np.linalg.norm((estimated @ in_camera)[:3] - point[:3]) < 0.08, "Kinect-grade error"


def test_a_camera_with_large_board_residuals_is_written_unverified_with_a_warning(tmp_path, capsys):
    out = tmp_path / "cameras.yaml"
    assert main(["calibrate-cameras", SEEG, "-o", str(out), "--max-residual", "1"]) == 0
    assert "written unverified" in capsys.readouterr().err
    config = load_cameras(str(out))
    assert [c.verified for c in config.cameras] == [False, False]


def test_a_topology_without_cameras_or_an_unknown_master_is_refused_clearly(tmp_path, capsys):
    assert main(["calibrate-cameras", "topologies/tracking.yaml", "-o", str(tmp_path / "c")]) == 1
    assert "no components.people.kinect_sim:KinectSim components" in capsys.readouterr().err
    assert main(["calibrate-cameras", SEEG, "--master", "k9", "-o", str(tmp_path / "c")]) == 1
    assert "master 'k9' is not one of" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_cameras_that_share_no_view_cannot_hold_a_board_between_them():
    a = KinectModel("a", look_at((0.0, -3.0, 2.0), (0.0, -6.0, 1.0)))
    b = KinectModel("b", look_at((0.0, 3.0, 2.0), (0.0, 6.0, 1.0)))
    with pytest.raises(CameraCalibrationError, match="share too little view"):
        board_poses(a, b, 4, np.random.default_rng(0))


def test_a_verified_flag_that_is_not_a_boolean_is_located(tmp_path):
    path = tmp_path / "cameras.yaml"
    path.write_text("cameras:\n  k0: {}\n  k1: {verified: yes please}\n")
    with pytest.raises(
        CameraConfigError, match=r"cameras.yaml:3:8: cameras.k1.verified: expected true or false"
    ):
        load_cameras(str(path))


def test_the_seeg_cameras_file_is_a_calibration_of_the_seeg_topology():
    with open("procedures/seeg/cameras.yaml") as f:
        written = yaml.safe_load(f)
    truth = {c.name: c.model.world_from_camera for c in cameras_of(SEEG)}
    assert set(written["cameras"]) == set(truth)
    placed = as_matrix(written["base_from_master"])
    error = np.linalg.norm(placed[:3, 3] - truth["kinect_0"][:3, 3])
    assert 0.0 < error < 0.1, "estimated (not the truth), within Kinect-grade error"


def test_a_cameras_file_that_still_names_bus_keys_is_refused_with_what_to_do(tmp_path):
    path = tmp_path / "cameras.yaml"
    path.write_text("cameras:\n  k0: {}\n  k1: {key: kinect/1/users}\n")
    with pytest.raises(CameraConfigError, match=r"cameras.yaml:3:8: cameras.k1.key: .*no longer"):
        load_cameras(str(path))


@pytest.mark.parametrize("where", ["base_from_master", "cameras.k0.calibration"])
@pytest.mark.parametrize("value", ["[1e308, 0, 0, 0]", "[1e200, 1e200, 1e200, 1e200]"])
def test_a_huge_quaternion_is_refused_at_its_line_without_a_numeric_warning(tmp_path, where, value):
    """Values past float overflow in a transform are a located error like any other
    wrong transform (numpy's raw 'overflow encountered' never reaches the user)."""
    transform = f"{{position: [0, 0, 0], quaternion: {value}}}"
    if where == "base_from_master":
        text = f"base_from_master: {transform}\ncameras:\n  k0: {{}}\n"
        line = 1
    else:
        text = f"cameras:\n  k0: {{calibration: {transform}}}\n"
        line = 2
    path = tmp_path / "cameras.yaml"
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CameraConfigError, match=f"cameras.yaml:{line}:.*{where}.*unit length"):
            load_cameras(str(path))
