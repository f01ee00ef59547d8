"""Spec: a tool's recent samples (`History`) give its pose at any instant they span,
linear between samples with a unit quaternion, the bound of that line's error and the
tool's speed; a device that starts again (older stamps) starts the memory again.

The Sensor Manager compares trackers and checks them against the robot at one instant
through these (docs/tracking.md), so a pose that is wrong here is a wrong verdict there."""

import math

import numpy as np
import pytest

from components.tracking.sensor_manager import KINEMATICS_MEMORY, History

IDENTITY = (1.0, 0.0, 0.0, 0.0)


def pose(x, q=IDENTITY):
    return (x, 0.0, 0.0, *q)


def about_z(degrees):
    half = math.radians(degrees) / 2.0
    return (math.cos(half), 0.0, 0.0, math.sin(half))


def moving(speed=0.1, period=0.01, count=11):
    """A tool moving along x at `speed` (m/s), sampled every `period` s from t = 0."""
    history = History()
    for k in range(count):
        history.add(k * period, pose(speed * k * period))
    return history


def test_between_two_samples_the_pose_is_on_the_line_between_them():
    history = moving(speed=0.1)
    at, bound, speed = history.at(0.0525)
    assert at[:3] == pytest.approx([0.00525, 0.0, 0.0])
    assert speed == pytest.approx(0.1)
    assert bound == pytest.approx(0.1 * 0.01 / 2), "half an interval at the tool's speed"


def test_on_a_sample_the_pose_is_that_sample_with_no_error_and_the_speed_around_it():
    history = moving(speed=0.2)
    at, bound, speed = history.at(0.05)
    assert list(at) == list(history.poses[5])
    assert bound == 0.0
    assert speed == pytest.approx(0.2), "the speed is measured on a sample too"


def test_the_speed_is_the_fastest_over_the_samples_around_and_their_neighbours():
    history = History()
    for k, x in enumerate([0.0, 0.0, 0.0, 0.003, 0.003, 0.003]):
        history.add(k * 0.01, pose(x))
    _, bound, speed = history.at(0.035)  # between two still samples, after a quick one
    assert history.at(0.015)[2] == pytest.approx(0.3), "the quick one is the next's too"
    assert speed == pytest.approx(0.3)
    assert bound == pytest.approx(0.3 * 0.01 / 2)


def test_outside_the_samples_there_is_no_pose():
    history = moving()
    assert history.at(-0.001) is None and history.at(0.1001) is None
    assert History().at(0.0) is None, "nothing kept"


def test_rotations_between_samples_stay_unit_quaternions():
    history = History()
    history.add(0.0, pose(0.0, about_z(0)))
    history.add(0.01, pose(0.0, about_z(90)))
    at, _, _ = history.at(0.005)
    assert np.linalg.norm(at[3:]) == pytest.approx(1.0)
    assert at[3:] == pytest.approx(about_z(45)), "half-way round, normalised"


def test_a_quaternion_and_its_negative_are_the_same_rotation_between_samples():
    history = History()
    q = about_z(30)
    history.add(0.0, pose(0.0, q))
    history.add(0.01, pose(0.0, tuple(-c for c in q)))
    at, _, _ = history.at(0.005)
    assert np.all(np.isfinite(at)), "not the zero quaternion half-way"
    assert at[3:] == pytest.approx(q), "the nearer way round"


def test_a_sample_with_the_newest_stamp_again_replaces_it_and_keeps_the_rest():
    history = moving(count=3)
    history.add(0.02, pose(0.5))
    assert history.at(0.02)[0][0] == 0.5
    assert history.at(0.0)[0][0] == 0.0, "the older samples stay"
    assert history.times == [0.0, 0.01, 0.02]


def test_an_older_stamp_means_the_device_started_again_and_the_memory_with_it():
    history = moving(count=5)
    history.add(0.015, pose(0.7))
    assert history.newest() == 0.015
    assert history.at(0.0) is None, "what was kept is gone"
    assert history.at(0.015)[0][0] == 0.7 and history.at_or_before(0.02) == (0.015, pose(0.7))


def test_the_memory_keeps_its_last_second_each_stamp_with_its_own_pose():
    period = 0.01
    count = round(3 * KINEMATICS_MEMORY / period)
    history = moving(speed=0.1, period=period, count=count)
    newest = (count - 1) * period
    assert history.times[0] == pytest.approx(newest - KINEMATICS_MEMORY, abs=period)
    assert history.times[0] >= newest - KINEMATICS_MEMORY - 1e-9
    for t, kept in zip(history.times, history.poses, strict=True):
        assert kept[0] == pytest.approx(0.1 * t), "times and poses trimmed together"


def test_at_or_before_gives_the_newest_sample_not_after_the_instant():
    history = moving(count=4)
    assert history.at_or_before(0.025) == (0.02, pose(0.1 * 0.02))
    assert history.at_or_before(0.02) == (0.02, pose(0.1 * 0.02))
    assert history.at_or_before(-0.1) is None
    assert History().newest() == -math.inf
