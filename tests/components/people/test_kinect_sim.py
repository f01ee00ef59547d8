"""Spec: the simulated Kinect reports what a camera could: people in its view, ghosts
in its view, and nothing at all for a frame it drops."""

import numpy as np

from components.domain.geometry import look_at
from components.domain.skeleton import standing
from components.people.kinect_sim import FAR, NEAR, KinectModel, frames

FRAME = 1.0 / 30.0


def camera(**kw) -> KinectModel:
    return KinectModel("k0", look_at((0.0, -3.0, 2.2), (0.0, 0.0, 1.0)), **kw)


def test_a_dropped_frame_sends_nothing_which_is_not_seeing_no_one():
    alice = {1: standing((0.0, 0.0))}
    dropping = camera(dropout=1.0)
    assert dropping.observe(alice, 0.0, FRAME) is None
    quiet = KinectModel("k1", look_at((0.0, 3.0, 2.2), (0.0, 0.0, 1.0)), dropout=0.0)
    sent = frames([dropping, quiet], {}, 0.0, FRAME)
    assert sent == {"k1": []}, "k0 sent nothing; k1 saw no one"


def test_ghosts_stand_in_the_cameras_own_view_and_are_reported_as_people_are():
    cam = camera(ghost_rate=30.0, dropout=0.0, rng=np.random.default_rng(3))
    ghosts = []
    for k in range(300):
        ghosts += [j for uid, j in cam.observe({}, k * FRAME, FRAME) if uid >= 50]
    assert len(ghosts) > 50
    for joints in ghosts:
        seen = ~np.isnan(joints).any(axis=1)
        assert seen.mean() > 0.5, "most of the body in view"
        depth = joints[seen, 2]
        assert np.all((depth > NEAR - 0.1) & (depth < FAR + 0.1)), "within the depth range"
