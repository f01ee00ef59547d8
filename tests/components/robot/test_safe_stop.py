"""Spec: a protective stop decelerates every joint to rest at no more than its limit,
along the joint-space line the arm was on, and never reverses a joint."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.robot.safe_stop import SafeStop

joints = st.lists(st.floats(-2.0, 2.0), min_size=7, max_size=7).map(np.array)
speeds = st.lists(st.floats(-1.5, 1.5), min_size=7, max_size=7).map(np.array)
DT = 0.001


@settings(max_examples=200, deadline=None)
@given(joints, speeds, st.floats(0.5, 50.0))
def test_the_stop_respects_the_deceleration_and_never_reverses(q, v, a):
    stop = SafeStop(q, v, np.full(7, a), DT)
    points = [stop.q0]
    for _ in range(100_000):
        if stop.done:
            break
        points.append(stop.step())
    assert stop.done
    path = np.array(points)
    velocity = np.diff(path, axis=0) / DT
    assert np.all(velocity * np.sign(v) >= -1e-9), "no joint reverses"
    assert np.all(np.abs(velocity) <= np.abs(v) + 1e-9), "no joint speeds up"
    if len(velocity) > 1:
        accel = np.diff(velocity, axis=0) / DT
        assert np.all(np.abs(accel) <= a * (1 + 1e-6) + 1e-6)
    assert np.allclose(path[-1], stop.stop_point)
    assert np.allclose(stop.stop_point, q + v * stop.duration / 2), "v T / 2 of travel"


@given(joints, speeds)
def test_the_arm_stays_on_the_line_it_was_following(q, v):
    stop = SafeStop(q, v, np.full(7, 8.0), DT)
    for t in np.linspace(0, stop.duration, 7):
        moved = stop.at(t) - q
        assert np.allclose(np.cross(moved[:3], v[:3]), 0, atol=1e-9)
        assert np.allclose(np.cross(moved[3:6], v[3:6]), 0, atol=1e-9)


def test_no_trustworthy_velocity_holds_where_it_is():
    q = np.zeros(7)
    stop = SafeStop(q, np.full(7, np.nan), np.full(7, 8.0), DT)
    assert stop.done and np.array_equal(stop.step(), q)


def test_one_deceleration_for_every_joint_is_the_same_as_one_per_joint_and_others_are_refused():
    q, v = np.zeros(7), np.linspace(-0.5, 0.5, 7)
    one, each = SafeStop(q, v, 2.0, 0.001), SafeStop(q, v, np.full(7, 2.0), 0.001)
    assert one.duration == each.duration == 0.25
    assert np.array_equal(one.at(0.1), each.at(0.1))
    with pytest.raises(ValueError, match="a deceleration per joint or one for all"):
        SafeStop(q, v, np.full((7, 1), 2.0), 0.001)
    with pytest.raises(ValueError):
        SafeStop(q, v, np.full(3, 2.0), 0.001)
