"""Spec: someone who left every view is known again by their build, and only when the
answer is clear."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.skeleton import Build as Body
from components.domain.skeleton import standing
from components.people.reid import KNOWN, REMEMBER, SIZES, Build, Departed, Gallery, sizes
from components.people.tracking import PeopleTracker, Person

FRAME = 1.0 / 30.0
SIGMA = 0.02


def measured(body: Body, frames: int, rng: np.random.Generator) -> Build:
    """A build as a track measures it: `frames` noisy detections of someone standing."""
    build = Build()
    for _ in range(frames):
        joints = standing((1.0, 0.0), rng.uniform(0, 6.28), build=body)
        joints = joints + rng.normal(0.0, SIGMA, joints.shape)
        values, variances = sizes(joints[None], np.full((1, 15), SIGMA))
        build.add(values[0], variances[0])
    return build


@settings(max_examples=40, deadline=None)
@given(
    st.floats(1.5, 1.98),
    st.floats(0.85, 1.15),
    st.floats(0.85, 1.15),
    st.floats(0.9, 1.1),
    st.floats(0.0, 6.28),
)
def test_sizes_are_the_bodys_whatever_its_place_and_facing(height, shoulders, hips, legs, facing):
    body = Body(height, shoulders, hips, legs)
    joints = standing((0.7, -1.2), facing, build=body)
    values, variances = sizes(joints[None], np.zeros((1, 15)))
    s = height / 1.75
    assert values[0, 0] == pytest.approx(0.18 * s)  # head-neck
    assert values[0, 2] == pytest.approx(0.40 * s * shoulders)  # shoulder breadth
    assert values[0, 3] == pytest.approx(0.20 * s * hips)  # hip breadth
    assert values[0, 6] == pytest.approx((0.52 * legs - 0.08) * s)  # shanks: the feet stay down
    assert len(values[0]) == len(SIZES) and np.all(variances == 0.0)


def test_an_unseen_bone_is_no_size_and_the_other_side_stands_in():
    joints = standing((0.0, 0.0))[None].copy()
    joints[0, 0] = np.nan  # the head
    joints[0, 10] = np.nan  # the left knee
    values, _ = sizes(joints, np.full((1, 15), SIGMA))
    assert np.isnan(values[0, 0]), "head-neck unseen"
    assert np.isfinite(values[0, 5]) and np.isfinite(values[0, 6]), "the right leg measures"


def test_half_a_second_tells_people_20_cm_apart_in_height_and_not_one_from_themself():
    """Bones change a centimetre with posture (`POSTURE`), whatever the frames averaged:
    builds a few centimetres apart are not told apart, and are not meant to be."""
    rng = np.random.default_rng(0)
    alice, bob = Body(1.62), Body(1.82)
    a1, a2, b = measured(alice, 15, rng), measured(alice, 15, rng), measured(bob, 15, rng)
    same, _ = a1.distance(a2)
    other, k = a1.distance(b)
    assert k == len(SIZES)
    assert same < 18.5 < other, "chi-square 99% with 7 sizes: 18.5"


def test_a_build_known_to_a_third_of_the_posture_term_takes_no_more_frames():
    rng = np.random.default_rng(3)
    build = measured(Body(1.7), 5, rng)
    assert not build.known, "five frames at 2 cm: 0.9 cm a size"
    build = measured(Body(1.7), 200, rng)
    assert build.known and (1.0 / np.sqrt(build.weight) <= KNOWN).all()
    before = build.weighted.copy()
    values, variances = sizes(standing((0.0, 0.0), build=Body(1.9))[None], np.full((1, 15), SIGMA))
    build.add(values[0], variances[0])
    assert (build.weighted == before).all(), "a known build is not averaged further"


def _gallery(*bodies, when=0.0, place=(2.0, 0.0)):
    rng = np.random.default_rng(1)
    gallery = Gallery()
    for i, body in enumerate(bodies, start=1):
        gallery.leave(Departed(i, measured(body, 30, rng), place, when))
    return gallery


def test_a_newcomer_built_like_one_who_left_takes_their_identity_once():
    gallery = _gallery(Body(1.60), Body(1.85))
    newcomer = measured(Body(1.85), 15, np.random.default_rng(2))
    assert gallery.recognise(newcomer, (1.5, 0.5), 5.0).id == 2
    assert gallery.recognise(newcomer, (1.5, 0.5), 5.0) is None, "taken: no one else gets it"


def test_no_identity_when_two_who_left_are_built_alike_or_none_like_the_newcomer():
    newcomer = measured(Body(1.72), 15, np.random.default_rng(3))
    assert _gallery(Body(1.72), Body(1.721)).recognise(newcomer, (2.0, 0.0), 5.0) is None
    assert _gallery(Body(1.55), Body(1.95)).recognise(newcomer, (2.0, 0.0), 5.0) is None


def test_no_identity_from_too_far_to_have_walked_or_from_too_long_ago():
    newcomer = measured(Body(1.85), 15, np.random.default_rng(4))
    assert _gallery(Body(1.85)).recognise(newcomer, (12.0, 0.0), 2.0) is None, "10 m in 2 s"
    assert _gallery(Body(1.85)).recognise(newcomer, (2.0, 0.0), REMEMBER + 1.0) is None


def test_someone_who_walks_out_of_every_view_and_back_later_is_the_same_track_id():
    tracker, rng = PeopleTracker(keep_for=2.0), np.random.default_rng(5)
    alice, bob = Body(1.62, 0.95), Body(1.88, 1.08)

    def both_cameras(body, at):
        joints = standing(at, 0.0, build=body) + rng.normal(0.0, SIGMA, (15, 3))
        return Person(joints, np.full(15, SIGMA), frozenset({"k0", "k1"}))

    for k in range(60):  # both in the room for 2 s
        tracker.update([both_cameras(alice, (1.0, 0.0)), both_cameras(bob, (-1.0, 0.0))], k * FRAME)
    first = {round(t.joints[2, 0]): t.id for t in tracker.people}
    for k in range(60, 210):  # both gone for 5 s
        tracker.update([], k * FRAME)
    assert tracker.tracks == []
    for k in range(210, 240):  # back, each where the other stood
        tracker.update([both_cameras(bob, (1.0, 0.0)), both_cameras(alice, (-1.0, 0.0))], k * FRAME)
    again = {round(t.joints[2, 0]): t.id for t in tracker.people}
    assert again == {1: first[-1], -1: first[1]}, "known by their build, not their place"


def test_one_who_left_a_moment_ago_where_the_newcomer_appears_is_told_from_one_long_gone():
    # built alike (a centimetre apart): the build alone cannot tell them apart, but one
    # left here a second ago and the other 40 s ago across the room (reach 2.6 m vs 65 m)
    rng = np.random.default_rng(6)
    gallery = Gallery()
    gallery.leave(Departed(1, measured(Body(1.72), 30, rng), (-2.0, 1.0), -20.0))
    gallery.leave(Departed(2, measured(Body(1.73), 30, rng), (2.0, 0.0), 19.0))
    newcomer = measured(Body(1.73), 1, rng)  # one frame: what confirmation sees
    assert gallery.recognise(newcomer, (2.2, 0.1), 20.0).id == 2
    # and no one is given an identity the place and time cannot tell
    gallery = Gallery()
    gallery.leave(Departed(1, measured(Body(1.72), 30, rng), (2.0, 0.5), 19.0))
    gallery.leave(Departed(2, measured(Body(1.73), 30, rng), (2.0, -0.5), 19.0))
    assert gallery.recognise(newcomer, (2.2, 0.0), 20.0) is None


def test_a_newcomer_where_someone_just_left_does_not_take_their_identity_if_built_otherwise():
    rng = np.random.default_rng(7)
    gallery = Gallery()
    gallery.leave(Departed(1, measured(Body(1.60, 0.9), 30, rng), (2.0, 0.0), 9.5))
    assert gallery.recognise(measured(Body(1.90, 1.1), 15, rng), (2.1, 0.0), 10.0) is None


def _walker(tracker, body, rng, at, k, cameras=frozenset({"k0", "k1"})):
    joints = standing(at, 0.0, build=body) + rng.normal(0.0, SIGMA, (15, 3))
    return Person(joints, np.full(15, SIGMA), cameras)


def test_who_turns_back_at_the_edge_of_the_views_has_their_identity_from_the_first_frame_back():
    tracker, rng = PeopleTracker(), np.random.default_rng(8)
    alice, bob = Body(1.66), Body(1.78)
    for k in range(45):  # both seen 1.5 s; alice stands far off, bob walks to the edge
        tracker.update(
            [
                _walker(tracker, alice, rng, (-2.0, 0.0), k),
                _walker(tracker, bob, rng, (2.0, 0.0), k),
            ],
            k * FRAME,
        )
    ids = {round(t.joints[2, 0]): t.id for t in tracker.people}
    bob_track = next(t for t in tracker.tracks if t.id == ids[2])
    tracker.lose(bob_track)  # the detector judged bob gone out of every view
    for k in range(45, 60):  # 0.5 s out of sight
        tracker.update([_walker(tracker, alice, rng, (-2.0, 0.0), k)], k * FRAME)
    k = 60
    tracker.update(
        [_walker(tracker, alice, rng, (-2.0, 0.0), k), _walker(tracker, bob, rng, (2.1, 0.0), k)],
        k * FRAME,
    )
    back = {round(t.joints[2, 0]): t.id for t in tracker.people}
    assert back == ids, "two cameras confirm him at once, and he is bob again at once"
    assert not any(t.gone for t in tracker.tracks), "the gone track made way for him"


@pytest.mark.parametrize(
    ("variant", "name"),
    [
        (1, "thesis-cross-7p2c"),  # a lost track found again after a newcomer took its name
        (0, "corners-wander-6p2c"),  # people in and out of sight at the far edges
        (0, "ring-in_out-4p4c"),
    ],
)
def test_no_two_tracks_ever_bear_one_identity(variant, name):
    from components.people.kinect_sim import frames
    from fw_bench import scenes
    from fw_bench.people import detector

    scene = dataclasses.replace({s.name: s for s in scenes.suite(variant)}[name], seconds=12.0)
    cams = scenes.cameras_for(scene)
    core, script = detector(cams), scenes.Script(scene)
    for k in range(int(scene.seconds / scenes.FRAME)):
        t = k * scenes.FRAME
        core.process(frames(cams, script.advance(t, scenes.FRAME), t), t)
        live = [track.id for track in core.tracker.tracks if not track.gone]
        assert len(live) == len(set(live)), f"t={t:.2f}: {sorted(live)}"


def test_a_track_found_again_takes_its_identity_back_from_a_newcomer_who_took_it():
    tracker, rng = PeopleTracker(), np.random.default_rng(9)
    alice = Body(1.70)
    for k in range(30):
        tracker.update([_walker(tracker, alice, rng, (2.0, 0.0), k)], k * FRAME)
    (track,) = tracker.people
    tracker.lose(track)  # missed for a moment
    # someone built like her appears 0.6 m away, two cameras at once: her identity
    tracker.update([_walker(tracker, alice, rng, (2.6, 0.0), 30)], 30 * FRAME)
    newcomer = next(t for t in tracker.people if t is not track)
    assert newcomer.id == track.id, "looks like her, where she was a moment ago"
    tracker.update(  # and she is there after all, where the track left her
        [
            _walker(tracker, alice, rng, (2.0, 0.0), 31),
            _walker(tracker, alice, rng, (2.6, 0.0), 31),
        ],
        31 * FRAME,
    )
    assert not track.gone and newcomer.id == newcomer.born_id != track.id
