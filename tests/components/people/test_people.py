"""Spec: matching, fusion and tracking turn camera users into people (issue 6's cases)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.distance import capsule_distances, closest_pair
from components.domain.skeleton import (
    JOINTS,
    LIMBS,
    body_center,
    body_centers,
    envelope,
    envelopes,
    standing,
)
from components.people.fusion import (
    Detection,
    fuse,
    group,
    group_and_fuse,
    hungarian_matches,
    noise_for,
    rule_matches,
)
from components.people.tracking import PeopleTracker, Person

FRAME = 1.0 / 30.0


def seen(camera, user, skeleton, rng, sigma=0.02):
    joints = skeleton + rng.normal(0, sigma, skeleton.shape)
    return Detection(camera, user, joints, np.full(len(JOINTS), sigma))


def frame_people(detections, matcher="hungarian"):
    out = []
    for members in group(detections, matcher):
        joints, sigma = fuse(members)
        out.append(Person(joints, sigma, frozenset(d.camera for d in members)))
    return out


def run(tracker, frames, make, start=0):
    rng = np.random.default_rng(start)
    for k in range(start, start + frames):
        tracker.update(frame_people(make(rng, k)), k * FRAME)
    return tracker


def test_one_person_seen_by_both_cameras_is_one_confirmed_track_at_once():
    alice = standing((1.5, 0.3))
    tracker = run(
        PeopleTracker(), 1, lambda rng, k: [seen("k0", 1, alice, rng), seen("k1", 7, alice, rng)]
    )
    assert len(tracker.tracks) == 1 and len(tracker.people) == 1
    tracker = run(
        tracker, 60, lambda rng, k: [seen("k0", 1, alice, rng), seen("k1", 7, alice, rng)], start=1
    )
    assert [t.id for t in tracker.people] == [1], "the same identity all along"


def test_two_people_one_behind_the_other_in_one_camera_are_two_tracks():
    front, back = standing((1.5, 0.0)), standing((2.1, 0.0))  # 0.6 m apart on the axis
    tracker = run(
        PeopleTracker(), 45, lambda rng, k: [seen("k0", 1, front, rng), seen("k0", 2, back, rng)]
    )
    assert len(tracker.people) == 2


def test_a_half_second_ghost_never_becomes_a_person():
    alice, ghost = standing((1.5, 0.3)), standing((2.5, -1.0))

    def frames(rng, k):
        people = [seen("k0", 1, alice, rng), seen("k1", 3, alice, rng)]
        if 10 <= k < 25:  # 0.5 s, one camera only
            people.append(seen("k1", 9, ghost, rng))
        return people

    tracker = PeopleTracker()
    rng = np.random.default_rng(1)
    confirmed_ids = set()
    for k in range(90):
        tracker.update(frame_people(frames(rng, k)), k * FRAME)
        confirmed_ids |= {t.id for t in tracker.people}
    assert confirmed_ids == {1}, "only Alice was ever a person"
    assert len(tracker.tracks) == 1, "the ghost's tentative track was deleted"


def test_a_person_seen_by_one_camera_for_long_enough_is_confirmed():
    alice = standing((1.5, 0.3))
    tracker = run(PeopleTracker(confirm_after=1.0), 25, lambda rng, k: [seen("k0", 1, alice, rng)])
    assert tracker.people == []
    tracker = run(tracker, 10, lambda rng, k: [seen("k0", 1, alice, rng)], start=25)
    assert len(tracker.people) == 1


def test_the_eq_3_9_rule_and_the_global_assignment_agree_on_clear_cases():
    rng = np.random.default_rng(2)
    a = np.stack([standing((1.0, 0.0)), standing((2.0, 1.0))])
    b = a[::-1] + rng.normal(0, 0.02, a.shape)
    assert sorted(rule_matches(a, b)) == sorted(hungarian_matches(a, b)) == [(0, 1), (1, 0)]


def test_the_global_assignment_wins_where_the_greedy_rule_pairs_wrongly():
    # two people 0.3 m apart: the greedy rule takes the first candidate within 0.45 m
    a = np.stack([standing((1.0, 0.0)), standing((1.0, 0.3))])
    b = np.stack([a[1] + 0.01, a[0] + 0.01])
    assert rule_matches(a, b) == [(0, 0), (1, 1)], "the rule mixes them up"
    assert sorted(hungarian_matches(a, b)) == [(0, 1), (1, 0)]


def test_fusion_weights_by_noise_and_skips_unseen_joints():
    near = Detection("k0", 1, np.zeros((15, 3)), np.full(15, 0.01))
    far_joints = np.ones((15, 3))
    far_joints[0] = np.nan
    far = Detection("k1", 1, far_joints, np.full(15, 0.03))
    joints, sigma = fuse([near, far])
    assert np.allclose(joints[0], 0.0), "only the near camera sees the head"
    assert np.allclose(joints[1], 0.1), "1/0.01^2 vs 1/0.03^2 weights: 9 to 1"
    assert sigma[1] < 0.01
    assert noise_for(np.array([[0.0, 0.0, 2.0]]))[0] > noise_for(np.array([[0, 0, 1.0]]))[0]


def test_a_person_touching_the_robot_is_at_distance_zero_or_less():
    alice = standing((0.6, 0.0), facing=np.pi)
    link_p = np.array([[0.0, 0.0, 0.9]])  # a robot link reaching towards her torso
    link_q = alice[2:3] + np.array([[-0.17 - 0.05, 0.0, 0.0]])
    p, q, r = envelope(alice, 0.0)
    d, _, limb = closest_pair(capsule_distances(link_p, link_q, [0.05], p, q, r))
    assert d <= 1e-9
    assert "torso" in LIMBS[limb][:2], "the closest pair names the touched limb"
    far_q = np.array([[-0.5, 0.0, 0.9]])
    d_far, _, _ = closest_pair(capsule_distances(link_p, far_q, [0.05], p, q, r))
    assert d_far > 0.3


def test_envelopes_grow_with_noise_and_drop_unseen_limbs():
    alice = standing((1.0, 0.0))
    _, _, r_clean = envelope(alice, 0.0)
    _, _, r_noisy = envelope(alice, 0.02)
    assert np.allclose(r_noisy - r_clean, 0.06), "3 sigma margin"
    alice[JOINTS.index("left_hand")] = np.nan
    p, _, _ = envelope(alice, 0.0)
    assert len(p) == len(r_clean) - 1


@settings(max_examples=40, deadline=None)
@given(
    people=st.integers(1, 5),
    cameras=st.integers(1, 4),
    seed=st.integers(0, 10_000),
)
def test_grouped_fusion_equals_fusing_each_groups_members(people, cameras, seed):
    rng = np.random.default_rng(seed)
    detections = []
    for c in range(cameras):
        for p in rng.permutation(people):
            joints = standing((p * 1.5, 0.0)) + rng.normal(0, 0.02, (15, 3))
            joints[rng.random(15) < 0.2] = np.nan  # some joints unseen
            sigma = rng.uniform(0.01, 0.05, 15)
            detections.append(Detection(f"k{c}", int(p), joints, sigma))
    for members, joints, sigma in group_and_fuse(detections):
        expected_joints, expected_sigma = fuse(members)
        assert np.allclose(joints, expected_joints, equal_nan=True, atol=1e-12)
        assert np.allclose(sigma, expected_sigma, equal_nan=True)


@given(
    st.lists(
        st.tuples(
            st.floats(-2, 2), st.floats(-2, 2), st.lists(st.booleans(), min_size=15, max_size=15)
        ),
        min_size=1,
        max_size=6,
    )
)
@settings(max_examples=60, deadline=None)
def test_batched_centers_and_envelopes_equal_one_skeleton_at_a_time(people):
    skeletons, sigmas = [], []
    for x, y, hidden in people:
        joints = standing((x, y))
        joints[np.array(hidden)] = np.nan
        skeletons.append(joints)
        sigmas.append(np.full(15, 0.02))
    batch, sigma = np.stack(skeletons), np.stack(sigmas)
    for joints, center in zip(skeletons, body_centers(batch), strict=True):
        assert np.allclose(center, body_center(joints), equal_nan=True)
    p, q, r, owner, _ = envelopes(batch, sigma)
    for k, joints in enumerate(skeletons):
        one = envelope(joints, sigma[k])
        assert np.allclose(p[owner == k], one[0]) and np.allclose(q[owner == k], one[1])
        assert np.allclose(r[owner == k], one[2])
