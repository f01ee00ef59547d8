"""Spec: tracks from frames of people: when a track is someone (confirmation), how
long it outlives its detections, and where its unseen joints are."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.skeleton import standing
from components.people.tracking import (
    TENTATIVE_KEEP,
    TORSO,
    WALK_SIGMAS,
    PeopleTracker,
    Person,
    Track,
    complete,
)

FRAME = 1.0 / 30.0
SIGMA = 0.015


def one_camera(skeleton, rng, entering=False, camera="k1"):
    joints = skeleton + rng.normal(0.0, SIGMA, skeleton.shape)
    return Person(joints, np.full(15, SIGMA), frozenset({camera}), entering=entering)


def test_a_ghost_seen_twice_with_a_pause_is_two_short_lives_never_a_confirmed_person():
    # two 0.6 s ghosts at the same place, 0.3 s apart: each alone is under the 1 s a
    # lone standing detection needs; added up they would pass it
    tracker, rng = PeopleTracker(confirm_after=1.0), np.random.default_rng(0)
    ghost = standing((2.0, 1.0))
    for k in range(int(1.5 / FRAME)):
        t = k * FRAME
        present = t < 0.6 or t >= 0.9
        tracker.update([one_camera(ghost, rng)] if present else [], t)
        assert tracker.people == [], f"confirmed at {t:.2f} s"
    assert TENTATIVE_KEEP < 0.3


def test_a_standing_lone_detection_waits_the_confirmation_time():
    tracker, rng = PeopleTracker(confirm_after=1.0), np.random.default_rng(1)
    alice = standing((1.5, 0.0))
    for k in range(29):
        tracker.update([one_camera(alice, rng)], k * FRAME)
    assert tracker.people == [], "standing still, as a ghost does: not yet"
    for k in range(29, 32):
        tracker.update([one_camera(alice, rng)], k * FRAME)
    assert len(tracker.people) == 1


def test_a_lone_walker_is_confirmed_once_they_walked_beyond_the_noise():
    tracker, rng = PeopleTracker(confirm_after=1.0), np.random.default_rng(2)
    evidence = WALK_SIGMAS * math.sqrt(2) * SIGMA
    for k in range(30):
        x = 0.6 * k * FRAME  # a slow walk, 2 cm a frame
        tracker.update([one_camera(standing((x, 0.0)), rng)], k * FRAME)
        if tracker.people:
            break
    walked = tracker.people[0].walked
    assert walked >= evidence, "never on noise alone"
    assert walked < evidence + 0.1, "but as soon as the walk shows (a few frames)"


def test_someone_coming_into_sight_at_the_edge_of_a_view_is_someone_at_once():
    tracker, rng = PeopleTracker(), np.random.default_rng(3)
    tracker.update([one_camera(standing((1.0, 0.0)), rng, entering=True)], 0.0)
    assert len(tracker.people) == 1


def test_coming_into_sight_where_another_camera_should_see_them_is_no_shortcut():
    tracker, rng = PeopleTracker(), np.random.default_rng(4)
    person = one_camera(standing((1.0, 0.0)), rng, entering=True)
    person.trusted = False
    tracker.update([person], 0.0)
    assert tracker.people == []
    for k in range(1, 4):  # then trusted: still not at once, once doubted
        tracker.update([one_camera(standing((1.0, 0.0)), rng)], k * FRAME)
    assert tracker.people == []


def test_a_confirmed_track_outlives_its_detections_for_keep_for_a_tentative_one_briefly():
    tracker, rng = PeopleTracker(keep_for=2.0), np.random.default_rng(5)
    both = [
        Person(standing((1.0, 0.0)), np.full(15, SIGMA), frozenset({"k0", "k1"})),
        one_camera(standing((-1.0, 0.5)), rng),
    ]
    tracker.update(both, 0.0)
    assert len(tracker.tracks) == 2 and len(tracker.people) == 1
    tracker.update([], TENTATIVE_KEEP + FRAME)
    assert [t.confirmed for t in tracker.tracks] == [True]
    tracker.update([], 2.0)
    assert len(tracker.tracks) == 1
    tracker.update([], 2.0 + FRAME)
    assert tracker.tracks == []


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
    st.floats(0.0, 2 * math.pi),
    st.floats(1.5, 2.0),
    st.lists(st.integers(0, 14), min_size=1, max_size=14, unique=True),
)
def test_unseen_joints_are_put_where_the_bodys_shape_says(x, y, facing, height, hidden):
    body = standing((x, y), facing, height)
    track = Track(1, body, np.full(15, SIGMA), 0.0, 0.0)
    track._seen(Person(body, np.full(15, SIGMA), frozenset({"k0"})), 0.0)
    now = body.copy()
    now[hidden] = np.nan
    assert np.allclose(complete(now, track.shape), body), "a shape once seen fills the gaps"
    assert np.array_equal(complete(now)[np.isfinite(now)], now[np.isfinite(now)])
    guess = complete(now)  # never seen whole: an upright body about the implied torso
    assert np.isfinite(guess).all()
    # within what a 1.75 m template misses on a body 1.5-2 m tall: a seventh of the
    # 1.6 m from head to feet
    assert np.allclose(guess[:, 2], body[:, 2], atol=0.25 / 1.75 * 1.6), "heights about right"
    # the template leaves out the side offsets (a hand 27 cm from the torso at 1.75 m),
    # so a lone joint puts the torso at most that far off, scaled to the body's height
    assert np.hypot(*(guess[TORSO, :2] - body[TORSO, :2])) <= 0.27 * height / 1.75 + 1e-9, (
        "where they stand"
    )


def test_where_a_track_began_is_where_its_torso_was_first_seen_not_before():
    # someone stepping out from behind another shows a hand before their torso: where
    # they began (to know them again, `reid`) is where the torso first was
    tracker, rng = PeopleTracker(), np.random.default_rng(5)
    body = standing((1.0, 2.0))
    hand_only = body.copy()
    hand_only[[i for i in range(15) if i != 6]] = np.nan
    tracker.update([one_camera(hand_only, rng)], 0.0)
    (track,) = tracker.tracks
    assert math.isnan(track.origin[0])
    tracker.update([one_camera(body, rng)], FRAME)
    assert np.allclose(track.origin, (1.0, 2.0), atol=4 * SIGMA)
