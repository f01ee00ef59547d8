"""Spec: cross-camera matching gates on the cameras' noise, the pairing keeps every
pair it can under the gate, and the cameras' users cluster into one group per person."""

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.geometry import look_at
from components.domain.skeleton import body_centers, standing
from components.people.fusion import (
    GATE_SIGMAS,
    SAME_BODY,
    gated_pairs,
    group_and_fuse_arrays,
    noise_for,
    normalized_cost,
    pairs_per_block,
    robust_cost,
)
from components.people.kinect_sim import KinectModel


def _brute_force(cost: np.ndarray, gate: float) -> tuple[int, float]:
    """The most pairs under the gate, then their least total cost, by enumeration."""
    n, m = cost.shape
    best = (0, 0.0)
    small, large = (n, m) if n <= m else (m, n)
    matrix = cost if n <= m else cost.T
    for chosen in itertools.permutations(range(large), small):
        pairs = [(i, j) for i, j in zip(range(small), chosen, strict=True) if matrix[i, j] <= gate]
        total = sum(matrix[i, j] for i, j in pairs)
        if len(pairs) > best[0] or (len(pairs) == best[0] and total < best[1] - 1e-12):
            best = (len(pairs), total)
    return best


def test_a_good_pair_is_not_broken_to_avoid_a_bad_one():
    # A-a is a person's two views; B is far from a, and b far from everyone: the cheapest
    # full assignment (A-b, B-a) would lose A-a to the gate
    cost = np.array([[1.0, 20.0], [30.0, 1000.0]])
    assert gated_pairs(cost, 4.0) == [(0, 0)]


@settings(max_examples=200, deadline=None)
@given(
    st.integers(1, 4),
    st.integers(1, 4),
    st.integers(0, 2**32 - 1),
)
def test_the_pairing_keeps_the_most_pairs_under_the_gate_then_the_cheapest(n, m, seed):
    rng = np.random.default_rng(seed)
    cost = rng.exponential(4.0, (n, m))
    cost[rng.random((n, m)) < 0.2] = np.inf  # no joint in common
    pairs = gated_pairs(cost, GATE_SIGMAS)
    assert all(cost[i, j] <= GATE_SIGMAS for i, j in pairs)
    assert len({i for i, _ in pairs}) == len({j for _, j in pairs}) == len(pairs)
    count, total = _brute_force(cost, GATE_SIGMAS)
    assert len(pairs) == count
    assert sum(cost[i, j] for i, j in pairs) == np.float64(total) or np.isclose(
        sum(cost[i, j] for i, j in pairs), total
    )


def _view(camera: KinectModel, skeleton: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera's noisy view of a skeleton, back in the world frame, with its sigma."""
    seen = camera.to_camera(skeleton)
    sigma = noise_for(seen, camera.lateral_noise)
    seen = seen + camera.noise(seen)
    world = seen @ camera.world_from_camera[:3, :3].T + camera.world_from_camera[:3, 3]
    return world, sigma


@settings(max_examples=60, deadline=None)
@given(
    st.floats(0.8, 3.8),
    st.floats(-np.pi, np.pi),
    st.floats(0.4, 1.0),
    st.integers(0, 2**32 - 1),
)
def test_two_cameras_views_of_a_person_match_and_a_neighbour_a_body_apart_does_not(
    distance, bearing, apart, seed
):
    cameras = [
        KinectModel(
            f"k{i}",
            look_at((3.0 * np.cos(a), 3.0 * np.sin(a), 2.2), (0.0, 0.0, 1.0)),
            rng=np.random.default_rng(seed + i),
        )
        for i, a in enumerate((0.0, 1.6))
    ]
    at = (distance * np.cos(bearing) * 0.5, distance * np.sin(bearing) * 0.5)
    person = standing(at, bearing)
    neighbour = standing((at[0] + apart, at[1]), bearing)
    a, sigma_a = _view(cameras[0], person)
    b, sigma_b = _view(cameras[1], person)
    c, sigma_c = _view(cameras[1], neighbour)
    cost = normalized_cost(a[None], sigma_a[None], np.stack([b, c]), np.stack([sigma_b, sigma_c]))
    assert cost[0, 0] <= GATE_SIGMAS, "one person's two views are one person"
    assert cost[0, 1] > GATE_SIGMAS, "people a body's width apart are two"
    assert gated_pairs(cost, GATE_SIGMAS) == [(0, 0)]


def test_joints_one_view_does_not_see_are_left_out_and_none_in_common_is_no_match():
    a = standing((0.0, 0.0))
    b = a.copy()
    b[:8] = np.nan
    sigma = np.full(15, 0.02)
    assert normalized_cost(a[None], sigma[None], b[None], sigma[None])[0, 0] == 0.0
    c = a.copy()
    c[8:] = np.nan
    assert np.isinf(normalized_cost(b[None], sigma[None], c[None], sigma[None])[0, 0])


def _median_by_hand(a: np.ndarray, b: np.ndarray) -> float:
    """The median joint distance over the joints both skeletons see, one pair at a time."""
    both = ~np.isnan(a).any(axis=1) & ~np.isnan(b).any(axis=1)
    if not both.any():
        return np.inf
    return float(np.median(np.linalg.norm(a[both] - b[both], axis=1)))


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 5), st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_the_robust_cost_is_the_median_of_the_common_joints_and_skips_only_distant_bodies(
    n, m, seed
):
    rng = np.random.default_rng(seed)

    def people(count: int) -> np.ndarray:
        out = np.stack([standing(rng.uniform(-2, 2, 2), rng.uniform(-3, 3)) for _ in range(count)])
        out += rng.normal(0, 0.05, out.shape)
        out[rng.random(out.shape[:2]) < 0.3] = np.nan  # joints unseen
        return out

    a, b = people(n), people(m)
    every = robust_cost(a, b)
    near = robust_cost(a, b, SAME_BODY)
    centres_a, centres_b = body_centers(a)[:, :2], body_centers(b)[:, :2]
    for i, j in itertools.product(range(n), range(m)):
        assert every[i, j] == pytest.approx(_median_by_hand(a[i], b[j]))
        apart = np.linalg.norm(centres_a[i] - centres_b[j])
        if apart <= SAME_BODY:
            assert near[i, j] == pytest.approx(every[i, j])
        else:
            assert near[i, j] == np.inf, "bodies this far apart are not costed"


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 8),
    st.integers(1, 4),
    st.integers(0, 2**32 - 1),
)
def test_each_person_is_one_group_of_the_views_that_see_them(people, cameras, seed):
    # people at least a body apart; each camera sees a random few of them, to half its
    # stated noise, some joints unseen; users in a random order per camera
    rng = np.random.default_rng(seed)
    spots: list[np.ndarray] = []
    while len(spots) < people:
        spot = rng.uniform(-2.5, 2.5, 2)
        if all(np.linalg.norm(spot - s) >= 0.45 for s in spots):
            spots.append(spot)
    bodies = [standing(s, rng.uniform(-3, 3)) for s in spots]
    truth: dict[tuple[str, int], int] = {}
    batches = []
    for c in range(cameras):
        seen = [p for p in rng.permutation(people) if rng.random() < 0.7]
        joints, sigma = [], []
        for row, p in enumerate(seen):
            noise = rng.uniform(0.01, 0.03)
            view = bodies[p] + rng.normal(0, noise / 2, (15, 3))
            view[rng.random(15) < 0.2] = np.nan
            joints.append(view)
            sigma.append(np.full(15, noise))
            truth[(f"k{c}", row)] = int(p)
        if seen:
            batches.append((f"k{c}", np.stack(joints), np.stack(sigma)))
    members, fused, _ = group_and_fuse_arrays(batches)
    assert sorted(member for group in members for member in group) == sorted(truth)
    found = [{truth[member] for member in group} for group in members]
    assert all(len(group) == 1 for group in found), "a group is one person"
    who = [next(iter(group)) for group in found]
    assert len(who) == len(set(who)), "a person is one group"
    for group in members:
        cameras_in = [camera for camera, _ in group]
        assert len(cameras_in) == len(set(cameras_in)), "a camera sees a person once"
    assert len(fused) == len(members)


@settings(max_examples=150, deadline=None)
@given(
    st.integers(1, 5), st.lists(st.integers(1, 4), min_size=1, max_size=4), st.integers(0, 2**32)
)
def test_pairing_camera_by_camera_equals_the_assignment_in_each_cameras_block(n, widths, seed):
    rng = np.random.default_rng(seed)
    cost = rng.exponential(6.0, (n, sum(widths)))  # often several pairs under the gate
    cost[rng.random(cost.shape) < 0.2] = np.inf
    bounds = np.cumsum(widths)[:-1]
    rows, cols = pairs_per_block(cost, bounds)
    expected = []
    for start, end in zip([0, *bounds], np.cumsum(widths), strict=True):
        expected += [(i, start + j) for i, j in gated_pairs(cost[:, start:end], GATE_SIGMAS)]
    assert sorted(zip(rows.tolist(), cols.tolist(), strict=True)) == sorted(expected)
