"""Spec: capsule distances are exact, symmetric, and agree with brute-force sampling."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.distance import capsule_distances, closest_pair, segment_distances

coord = st.floats(-2.0, 2.0, allow_nan=False)
point = st.tuples(coord, coord, coord)


def brute(p1, q1, p2, q2, n=401):
    s = np.linspace(0, 1, n)[:, None]
    a = np.asarray(p1) + s * (np.asarray(q1) - np.asarray(p1))
    b = np.asarray(p2) + s * (np.asarray(q2) - np.asarray(p2))
    return float(np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)))


def one(p1, q1, p2, q2):
    return float(
        segment_distances(np.array([p1]), np.array([q1]), np.array([p2]), np.array([q2]))[0, 0]
    )


@settings(max_examples=300, deadline=None)
@given(p1=point, q1=point, p2=point, q2=point)
def test_segment_distance_agrees_with_sampling_and_is_symmetric_and_non_negative(p1, q1, p2, q2):
    # nearly parallel segments are solved as parallel: the error is bounded by length x
    # angle, nanometres here, so the comparisons allow a micrometre
    tol = 1e-6
    d = one(p1, q1, p2, q2)
    assert d >= 0.0
    assert abs(d - one(p2, q2, p1, q1)) < tol
    sampled = brute(p1, q1, p2, q2)
    step = max(np.linalg.norm(np.subtract(q1, p1)), np.linalg.norm(np.subtract(q2, p2))) / 400
    assert d <= sampled + tol, "never farther than any sampled pair"
    assert sampled - d <= 2 * step + tol, "as close as the sampling resolution allows"


def test_known_cases():
    assert one((0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)) == 1.0  # parallel
    assert one((0, 0, 0), (1, 0, 0), (0.5, -1, 1), (0.5, 1, 1)) == 1.0  # crossing above
    assert one((0, 0, 0), (0, 0, 0), (3, 4, 0), (3, 4, 0)) == 5.0  # two points
    assert one((0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)) == 1.0  # collinear, apart


def test_capsules_touching_or_overlapping_have_non_positive_distance():
    p, q = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]])
    up = np.array([0.0, 0.15, 0.0])
    d = capsule_distances(p, q, [0.1], p + up, q + up, [0.05])
    assert abs(d[0, 0]) < 1e-12, "touching"
    d = capsule_distances(p, q, [0.2], p + up, q + up, [0.05])
    assert d[0, 0] < 0, "overlapping"


def test_all_pairs_at_once_and_the_closest_pair():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    c, d = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    matrix = segment_distances(a, b, c, d)
    assert matrix.shape == (7, 5)
    for i in range(7):
        for j in range(5):
            assert abs(matrix[i, j] - one(a[i], b[i], c[j], d[j])) < 1e-12
    value, row, col = closest_pair(matrix)
    assert value == matrix.min() and matrix[row, col] == value
    assert closest_pair(np.zeros((0, 3)))[0] == float("inf")


def test_short_segments_that_touch_are_at_distance_zero_whatever_their_size():
    """Found by the property test: two perpendicular segments of 61 um sharing an end
    were 61 um apart, and 16 mm in the other argument order."""
    for scale in (1e-5, 6.103515625e-05, 1e-3, 1.0):
        assert one((0, 0, scale), (0, 0, 0), (0, scale, 0), (0, 0, 0)) == 0.0
        assert one((0, 0, 0), (0, 0, scale), (0, 0.015625, 0), (0, 0, 0)) == 0.0
        assert one((0, 0.015625, 0), (0, 0, 0), (0, 0, 0), (0, 0, scale)) == 0.0
