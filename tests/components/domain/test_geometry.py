"""Spec: quaternion <-> matrix conversions are exact inverses on random rotations."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from components.domain.geometry import matrix_to_quat, quat_to_matrix, rotvec_matrix

quaternions = st.tuples(*[st.floats(-1, 1) for _ in range(4)]).filter(
    lambda q: sum(v * v for v in q) > 1e-3
)


@settings(max_examples=300, deadline=None)
@given(quaternions)
def test_matrix_to_quat_inverts_quat_to_matrix_with_w_non_negative(q):
    r = quat_to_matrix(np.array(q))
    back = matrix_to_quat(r)
    assert back[0] >= 0 and np.isclose(np.linalg.norm(back), 1.0)
    assert np.allclose(quat_to_matrix(np.array(back)), r, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(quaternions)
def test_quat_to_matrix_agrees_with_scipy(q):
    w, x, y, z = q
    assert np.allclose(quat_to_matrix(np.array(q)), Rotation.from_quat([x, y, z, w]).as_matrix())


rotvecs = st.tuples(*[st.floats(-4, 4) for _ in range(3)])


@settings(max_examples=200, deadline=None)
@given(rotvecs)
def test_rotvec_matrix_agrees_with_scipy_down_to_the_zero_rotation(v):
    assert np.allclose(rotvec_matrix(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
