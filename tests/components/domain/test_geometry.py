"""Spec: quaternion <-> matrix conversions are exact inverses on random rotations."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from components.domain.geometry import matrix_to_quat, norm, quat_to_matrix, rotvec_matrix

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


def _lets_other_threads_run(call, times: int) -> int:
    """How often another thread ran while `call` ran up to `times` times (it stops at
    the first run): with the switch interval made huge, the other thread runs only when
    `call` releases the interpreter lock, and then only if it wins the lock back before
    `call` takes it again, which on a loaded host takes many releases."""
    import sys
    import threading
    import time

    ran, running = [0], [True]

    def other() -> None:
        while running[0]:
            ran[0] += 1
            time.sleep(0)  # hands the lock straight back

    interval = sys.getswitchinterval()
    sys.setswitchinterval(100.0)
    thread = threading.Thread(target=other, daemon=True)
    try:
        thread.start()
        time.sleep(0.01)  # it starts, and parks in sleep(0)
        before = ran[0]
        for _ in range(times):
            call()
            if ran[0] != before:
                break
        return ran[0] - before
    finally:
        running[0] = False
        sys.setswitchinterval(interval)
        thread.join()


def test_norm_keeps_the_interpreter_lock_where_numpy_s_own_releases_it():
    """A process with several busy threads pays a switch interval (5 ms) each time a
    small call releases the lock: `norm` must not (tests/test_architecture.py)."""
    v = np.array([0.3, -0.4, 1.2])
    assert _lets_other_threads_run(lambda: norm(v), times=5000) == 0
    assert _lets_other_threads_run(lambda: np.linalg.norm(v), times=50000) > 0  # why `norm` exists


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=16))
def test_norm_is_the_euclidean_length(values):
    assert np.isclose(norm(np.array(values)), np.linalg.norm(values), rtol=1e-12, atol=1e-12)
