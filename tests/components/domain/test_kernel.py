"""The compiled kernel (components/domain/_fwkernel.c) computes what the numpy and
Pinocchio references compute: the TCP pose with its Jacobian, one IK step, the path's pose
and the least capsule distance. The robot's 1 kHz cycle runs the kernel; the
references are what the rest of fw (and these specs) trust."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain import distance, ik, lwr4
from components.robot.interpolator import InterpolatorCore

pytestmark = pytest.mark.skipif(
    ik._fwkernel is None, reason="the compiled kernel was not built (pip install -e .)"
)
kernel = ik._fwkernel

KIN = lwr4.Kinematics()
IK = ik.DifferentialIK(KIN)
joints = st.tuples(*[st.floats(-limit, limit) for limit in lwr4.POSITION_LIMIT]).map(np.array)
small = st.floats(-0.05, 0.05)
coordinate = st.floats(-2.0, 2.0)
point = st.tuples(coordinate, coordinate, coordinate)


def _pose(rotation_vector: np.ndarray, position: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    out = np.eye(4)
    out[:3, :3] = pin.exp3(np.asarray(rotation_vector, dtype=float))
    out[:3, 3] = position
    return out


@settings(max_examples=100, deadline=None)
@given(joints)
def test_the_kernels_tcp_pose_and_jacobian_are_pinocchios(q):
    """The pose and the Jacobian in the base-aligned TCP frame, as Pinocchio has them."""
    pose, jac = np.empty((4, 4)), np.empty((6, 7))
    kernel.jacobian(KIN.placements, KIN.tool, np.ascontiguousarray(q), pose, jac)
    want_pose, want_jac = KIN.jacobian(q)
    assert np.allclose(pose, want_pose, atol=1e-12)
    assert np.allclose(jac, want_jac, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(joints, st.tuples(small, small, small), st.tuples(small, small, small))
def test_one_ik_step_is_the_reference_step(q, move, turn):
    q = np.clip(q, IK.lower, IK.upper)
    here = KIN.tcp(q)
    target = _pose(turn, here[:3, 3] + np.array(move))
    target[:3, :3] = target[:3, :3] @ here[:3, :3]
    stepped = IK.step(q, target)
    assert np.allclose(stepped, IK.step_reference(q, target), atol=1e-9)
    assert np.all(np.abs(stepped - q) <= IK.max_step + 1e-12)  # no joint faster than its limit


def test_a_step_toward_a_target_it_cannot_solve_falls_back_to_the_reference():
    q = np.array(lwr4.HOME)
    target = KIN.tcp(q)
    target[0, 3] = math.nan
    out = IK.step(q, target)
    reference = IK.step_reference(q, target)
    assert np.array_equal(np.isnan(out), np.isnan(reference))


@settings(max_examples=100, deadline=None)
@given(
    st.floats(0.0, 1.0),
    st.tuples(small, small, small),
    st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
    st.tuples(small, small, small, small, small, small),
)
def test_the_path_pose_is_the_reference_pose_with_the_steering_offset(u, move, turn, offset):
    core = InterpolatorCore(
        np.array(lwr4.HOME), velocity=0.05, acceleration=0.25, brake_acceleration=2.0, ik=IK
    )
    start = KIN.tcp(np.array(lwr4.HOME))
    goal = np.eye(4)
    goal[:3, 3] = start[:3, 3] + np.array(move)
    goal[:3, :3] = start[:3, :3] @ _pose(turn, np.zeros(3))[:3, :3]
    core._start_path(start, goal)
    core.offset = np.array(offset)
    s = u * core.length
    assert np.allclose(core._path_pose(s), core._offset_pose(core._pose_at(s)), atol=1e-12)


capsules = st.integers(0, 6).flatmap(
    lambda n: st.tuples(
        st.lists(point, min_size=n, max_size=n),
        st.lists(point, min_size=n, max_size=n),
        st.lists(st.floats(0.0, 0.3), min_size=n, max_size=n),
    )
)


def _arrays(c):
    a, b = (np.array(x, dtype=float).reshape(-1, 3) for x in c[:2])
    return a, b, np.array(c[2], dtype=float)


def _reference(a, b) -> float:
    matrix = distance.capsule_distances(*a, *b)
    return float(np.min(matrix)) if matrix.size else math.inf


@settings(max_examples=300, deadline=None)
@given(capsules, capsules)
def test_the_least_capsule_distance_is_the_references_minimum(first, second):
    a, b = _arrays(first), _arrays(second)
    got = distance.least_capsule_distance(*a, *b)
    want = _reference(a, b)
    assert got == pytest.approx(want, abs=1e-9) or (math.isinf(got) and math.isinf(want))
    assert got <= want + 1e-9  # never a larger separation than there is


@settings(max_examples=100, deadline=None)
@given(capsules.filter(lambda c: len(c[2]) > 0), st.integers(0, 2))
def test_a_nan_anywhere_makes_the_least_distance_nan_never_a_clear_verdict(first, which):
    a = _arrays(first)
    arm = KIN.capsules(np.array(lwr4.HOME))
    poisoned = [x.copy() for x in a]
    poisoned[which].flat[0] = math.nan
    assert math.isnan(distance.least_capsule_distance(arm.a, arm.b, arm.radius, *poisoned))


def test_the_kernel_refuses_arrays_of_the_wrong_shape_with_a_message():
    arm = KIN.capsules(np.array(lwr4.HOME))
    with pytest.raises(ValueError, match="capsules"):
        kernel.capsule_min(arm.a, arm.b, arm.radius[:2], arm.a, arm.b, arm.radius)
