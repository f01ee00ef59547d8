"""Spec: the People Detector from camera users to people, distances and counts,
containing bad input (NaN joints, a stopped camera, a wrong calibration)."""

import numpy as np
import pytest

from components.domain.geometry import look_at, rigid
from components.domain.skeleton import body_center, standing
from components.people.detector import CameraConfig, DetectorConfig, PeopleDetectorCore
from components.people.kinect_sim import KinectModel

FRAME = 1.0 / 30.0


def setup(ghosts=0.0, wrong=None, error=None, verified=False):
    cams = [
        KinectModel(
            "k0",
            look_at((0.0, -3.0, 2.0), (0.0, 0.0, 1.0)),
            ghost_rate=ghosts,
            dropout=0.0,
            rng=np.random.default_rng(1),
        ),
        KinectModel(
            "k1",
            look_at((3.0, 0.5, 2.0), (0.0, 0.0, 1.0)),
            ghost_rate=ghosts,
            dropout=0.0,
            rng=np.random.default_rng(2),
        ),
    ]
    master = cams[0].world_from_camera
    configs = []
    for cam in cams:
        calibration = np.linalg.inv(master) @ cam.world_from_camera
        if cam.name == wrong:
            calibration = (
                error if error is not None else rigid((0.8, 0.0, 0.0), (0.0, 0.4, 0.0))
            ) @ calibration
        configs.append(CameraConfig(cam.name, calibration, verified=verified))
    core = PeopleDetectorCore(DetectorConfig(configs, base_from_master=master, area_radius=1.2))
    return cams, core


def run(cams, core, people, frames, start=0, robot=None, drop=(), corrupt=False):
    frame = None
    for k in range(start, start + frames):
        users = {}
        for cam in cams:
            if cam.name in drop:
                continue
            seen = cam.observe(people, k * FRAME)
            if corrupt:
                seen = [(u, np.where(np.arange(15)[:, None] == 3, np.nan, j)) for u, j in seen]
                seen = [(u, j) for u, j in seen] + [(99, np.full((15, 3), np.inf))]
            users[cam.name] = seen
        frame = core.process(users, k * FRAME, robot)
    return frame


def test_people_are_counted_near_the_table_and_far_from_it():
    cams, core = setup()
    # 0.5 m and 1.6 m from the table centre; the area's radius is 1.2 m
    frame = run(cams, core, {1: standing((0.5, 0.0)), 2: standing((0.0, -1.6))}, 40)
    assert len(frame.people) == 2 and frame.users_near == 1


def test_the_robot_person_distance_names_the_closest_pair():
    cams, core = setup()
    alice = standing((0.7, 0.0), facing=np.pi)
    robot = (
        np.array([[0.0, 0.0, 0.3], [0.0, 0.0, 0.9]]),
        np.array([[0.0, 0.0, 0.9], [0.4, 0.0, 1.2]]),
        np.array([0.08, 0.06]),
    )
    frame = run(cams, core, {1: alice}, 40, robot=robot)
    assert 0.0 < frame.min_distance < 0.3
    track_id, limb, link = frame.closest
    assert track_id == frame.people[0].id and link == 1
    assert limb in {
        "torso-left_hip",
        "neck-torso",
        "torso-right_hip",
        "left_shoulder-right_shoulder",
        "head-neck",
        "head-head",
        "left_shoulder-left_elbow",
        "right_shoulder-right_elbow",
        "left_elbow-left_hand",
        "right_elbow-right_hand",
    }
    touching = (robot[0], np.array([[0.0, 0.0, 0.9], [0.62, 0.0, 1.2]]), robot[2])
    assert run(cams, core, {1: alice}, 3, start=40, robot=touching).min_distance <= 0.0


def test_nan_and_infinite_joints_are_contained_and_never_a_person():
    cams, core = setup()
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 40, corrupt=True)
    assert len(frame.people) == 1 and frame.rejected_joints > 0


def test_a_camera_that_stops_leaves_the_person_tracked_by_the_other():
    cams, core = setup()
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 40)
    person = frame.people[0].id
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 40, start=40, drop=("k1",))
    assert [t.id for t in frame.people] == [person]


@pytest.mark.parametrize("verified", [False, True], ids=["unverified", "verified-at-calibration"])
def test_a_camera_off_by_60_cm_makes_no_phantom_and_is_reported(verified):
    cams, core = setup(wrong="k1", error=rigid((0.6, 0.0, 0.0), (0.0, 0.0, 0.0)), verified=verified)
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 90)  # 3 s, three times the delay
    assert len(frame.people) == 1, "the real person only, seen by the master"
    assert frame.people[0].cameras == frozenset({"k0"})
    assert core.disagreements.get(("k1", "k0"), 0) > 60, "k1 is reported as disagreeing"


def test_a_grossly_wrong_camera_is_never_fused_into_the_person():
    # Known gap (see the notes): with a large rotation error the copy lands where no
    # other camera looks, which two cameras cannot tell from a second person; what holds
    # is that the copy is never fused into the real person.
    cams, core = setup(wrong="k1")
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 20)
    assert len(frame.tracks) == 2 and all(len(t.cameras) == 1 for t in frame.tracks)


def test_a_person_hidden_from_the_master_behind_another_is_still_confirmed():
    # the master sees only the front person; the back one, seen by k1 alone, is hidden
    # from the master by the front one, so k1 is not contradicted
    cams, core = setup()
    front, back = standing((0.0, -1.2)), standing((0.0, -0.2))
    frame = run(cams, core, {1: front, 2: back}, 60)
    assert len(frame.people) == 2


def test_a_person_with_an_unseen_joint_has_a_finite_envelope():
    # regression: an unseen fused joint had sigma = inf, an infinite envelope, and a
    # distance of -inf to the robot (a collision that was not there)
    cams, core = setup()
    alice = standing((0.7, 0.0))
    robot = (np.array([[-1.5, 0.0, 0.3]]), np.array([[-1.5, 0.0, 0.9]]), np.array([0.08]))

    def hide_hand(users):
        return [(u, np.where(np.arange(15)[:, None] == 5, np.nan, j)) for u, j in users]

    frame = None
    for k in range(40):
        users = {c.name: hide_hand(c.observe({1: alice}, k * FRAME)) for c in cams}
        frame = core.process(users, k * FRAME, robot)
    assert np.isnan(frame.people[0].sigma[5])
    assert 1.5 < frame.min_distance < 2.5, frame.min_distance


GROSS_ERRORS = (
    rigid((3.0, 0.0, 0.0), (0.0, 0.0, 1.5)),
    rigid((0.0, 0.0, 3.0), (0.0, 0.0, 0.0)),
    rigid((0.8, 0.0, 0.0), (0.0, 0.4, 0.0)),  # 23 degrees: the copy lands 2 m off
)


def test_a_camera_wrong_enough_to_place_its_user_out_of_everyones_sight_makes_no_phantom():
    for error in GROSS_ERRORS:
        cams, core = setup(wrong="k1", error=error)
        frame = run(cams, core, {1: standing((0.5, 0.0))}, 90)
        assert len(frame.people) == 1 and frame.people[0].cameras == {"k0"}, "the real one only"
        assert core.verified == {"k0"}, "k1 never agreed with the master"
        assert len(frame.suspects) == 1, "its misplaced user is kept as a suspect"


def test_a_verified_camera_bumped_out_of_everyones_sight_errs_toward_one_person_too_many():
    """Known limit: two cameras that share no one cannot tell a camera bumped so far that
    its people land where no other camera looks from cameras that simply see different
    people (a room's corners). Trust is withdrawn only on evidence (a camera's lone
    people where a trusted camera should see them), so the copy counts as a person: the
    robot keeps its distance from one person too many, never from one too few."""
    for error in GROSS_ERRORS:
        cams, core = setup(wrong="k1", error=error, verified=True)
        frame = run(cams, core, {1: standing((0.5, 0.0))}, 90)
        assert sorted(p.cameras for p in frame.people) == [{"k0"}, {"k1"}], "never fused"


def test_the_robot_keeps_its_distance_from_suspects_too():
    cams, core = setup(wrong="k1", error=rigid((3.0, 0.0, 0.0), (0.0, 0.0, 1.5)))
    phantom_side = run(cams, core, {1: standing((0.5, 0.0))}, 60)
    suspect = phantom_side.suspects[0].joints[2]
    robot = (suspect[None, :] + [[0.0, 0.0, -0.3]], suspect[None, :] + [[0.0, 0.0, 0.3]], [0.05])
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 3, start=60, robot=robot)
    assert frame.min_distance < 0.1 and frame.closest[0] == frame.suspects[0].id


def test_a_well_calibrated_camera_earns_trust_by_seeing_someone_with_the_master():
    cams, core = setup()
    run(cams, core, {1: standing((0.5, 0.0))}, 10)
    assert core.verified == {"k0", "k1"}


ONLY_K1_SEES = (-0.5, 1.5)  # behind k0's view, in the middle of k1's


def test_a_camera_verified_at_calibration_is_trusted_from_the_first_frame():
    cams, core = setup(verified=True)
    frame = run(cams, core, {1: standing(ONLY_K1_SEES)}, 45)
    assert [p.cameras for p in frame.people] == [{"k1"}], "a person only k1 sees is a person"
    cams, core = setup(verified=False)
    frame = run(cams, core, {1: standing(ONLY_K1_SEES)}, 45)
    assert frame.people == [] and len(frame.suspects) == 1, "unverified: a suspect at first"


def test_a_verified_camera_that_disagrees_with_the_master_loses_its_trust():
    # bumped after calibration: it places everyone 0.8 m off, beside the people the master
    # sees, where the master should see them too; its trust is revoked, no phantom appears
    cams, core = setup(wrong="k1", error=rigid((0.8, 0.0, 0.0), (0.0, 0.0, 0.0)), verified=True)
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 90)
    assert core.verified == {"k0"}, "k1 must earn its trust again by fusing with the master"
    assert len(frame.people) == 1 and frame.people[0].cameras == {"k0"}


def test_a_person_whose_torso_is_hidden_still_counts_near_the_table():
    cams, core = setup()
    alice = standing((0.3, 0.0))
    run(cams, core, {1: alice}, 40)
    frame = None
    for k in range(40, 45):  # the torso joint unseen by every camera
        users = {
            c.name: [
                (u, np.where(np.arange(15)[:, None] == 2, np.nan, j))
                for u, j in c.observe({1: alice}, k * FRAME)
            ]
            for c in cams
        }
        frame = core.process(users, k * FRAME)
    assert np.isnan(frame.people[0].joints[2]).all() and frame.users_near == 1


def test_the_robot_keeps_its_distance_from_someone_two_cameras_see_from_that_frame():
    """Speed and separation monitoring cannot wait a confirmation second (1.6 m at a
    walk): a person both cameras see in the same frame is guarded from that frame, and
    the envelope holds every limb of the guarded."""
    cams, core = setup()
    frame = run(cams, core, {1: standing((0.5, 0.0))}, 1)
    assert [t.id for t in frame.guarded] == [t.id for t in frame.tracks] != []
    a, b, radius = frame.envelopes
    assert a.shape == b.shape == (len(radius), 3) and len(radius) >= 10
    assert np.all(radius > 0.0)
    empty = run(*setup(), {}, 1).envelopes
    assert empty[0].shape == (0, 3) and empty[2].shape == (0,)


def _walk(cams, core, still, start, end, speed, hide=None):
    """A person walks from start to end (floor, m), past a person standing at `still`
    (None: nobody); k0 misses the walker while `hide(x)` (a camera losing a user behind
    someone). Each frame: (walker's track id or None, walker counted, k0 saw them)."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    steps = int(np.linalg.norm(end - start) / speed / FRAME)
    out = []
    for k in range(steps):
        at = start + (end - start) * k / steps
        people = {2: standing(tuple(at), 0.0)}
        if still is not None:
            people[1] = standing(still, -np.pi / 2)
        users = {c.name: c.observe(people, k * FRAME) for c in cams}
        walker_id = cams[0]._ids.get(2)
        if hide is not None and hide(at[0]):
            users["k0"] = [(u, j) for u, j in users["k0"] if u != walker_id]
        frame = core.process(users, k * FRAME)
        seen = any(u == walker_id for u, _ in users["k0"])
        walker = [t for t in frame.people if np.linalg.norm(body_center(t.joints)[:2] - at) < 0.3]
        out.append((walker[0].id if walker else None, bool(walker), seen))
    return out


def _one_camera():
    """k0 alone: where it cannot see, nobody can."""
    cams, core = setup(verified=True)
    config = core.config
    return cams[:1], PeopleDetectorCore(
        DetectorConfig(config.cameras[:1], config.base_from_master, area_radius=1.2)
    )


def _behind_the_standing_one(x):
    return abs(x) < 0.2


def test_a_person_hidden_behind_another_for_over_a_second_keeps_their_identity():
    cams, core = _one_camera()
    # k0 looks along +y from (0, -3); the walker passes slowly behind someone standing
    # at the origin, and k0 loses them there for 1.6 s
    frames = _walk(cams, core, (0.0, 0.0), (-1.4, 0.6), (1.4, 0.6), 0.25, _behind_the_standing_one)
    hidden = [k for k, (_, _, seen) in enumerate(frames) if not seen and k > 30]
    assert len(hidden) * FRAME >= 1.5
    before, after = frames[min(hidden) - 1], frames[max(hidden) + 1]
    assert before[0] is not None and after[0] == before[0], "the same identity after"
    assert all(frames[k][1] for k in hidden), "counted all the while they are hidden"


def test_a_person_missed_in_clear_view_stops_counting_soon():
    cams, core = _one_camera()
    frames = _walk(cams, core, None, (-1.4, 0.6), (1.4, 0.6), 0.25, _behind_the_standing_one)
    missed = [k for k, (_, _, seen) in enumerate(frames) if not seen and k > 30]
    assert frames[min(missed) - 1][1], "counted while seen"
    assert not any(frames[k][1] for k in missed[7:]), "nobody to hide behind: not counted"


def test_a_person_who_walks_out_of_every_view_stops_counting_when_the_camera_loses_them():
    """Last seen with only the joints still inside the view, they are judged on their
    whole body (the rest where their shape puts it): at the edge, walking out."""
    cams, core = _one_camera()
    frames = _walk(cams, core, None, (0.0, 0.4), (4.0, 0.4), 1.0)
    gone = next(k for k, (_, _, seen) in enumerate(frames) if k > 30 and not seen)
    assert frames[gone - 1][1], "counted while seen"
    assert not any(counted for _, counted, _ in frames[gone:]), "not counted out of view"


def test_someone_walking_into_one_cameras_view_counts_from_the_frame_it_sees_them():
    """People come into sight at the edge of a view; ghosts appear anywhere in it."""
    cams, core = _one_camera()
    frames = _walk(cams, core, None, (-3.0, 0.4), (1.0, 0.4), 1.0)
    first_seen = next(k for k, (_, _, seen) in enumerate(frames) if seen)
    assert frames[first_seen][1], "a walker is not a ghost: no 1 s wait"


def test_a_corner_camera_that_sees_people_no_other_camera_can_keeps_its_trust():
    """Seeing people apart from the master's is no evidence against a camera when the
    master cannot see where they stand (cameras in a room's corners share few people)."""
    cams, core = setup(verified=True)
    only_k0 = (-1.3, 0.0)  # in front of k0, beyond k1's view
    frame = run(cams, core, {1: standing(ONLY_K1_SEES), 2: standing(only_k0)}, 150)
    assert core.verified == {"k0", "k1"}
    assert sorted(p.cameras for p in frame.people) == [{"k0"}, {"k1"}]


@pytest.mark.parametrize("camera", ["k0", "k1"], ids=["master", "other"])
def test_a_ghost_at_the_edge_of_a_view_where_another_camera_looks_is_not_someone(camera):
    """Coming into sight at the edge of one view is no shortcut where another camera
    sees the place clearly and sees no one there, the master's view included."""
    cams, core = setup(verified=True)
    seer, other = cams if camera == "k0" else cams[::-1]
    ghost = standing({"k0": (0.0, 0.75), "k1": (-0.8, 0.0)}[camera])
    seen = seer.to_camera(ghost)
    inside = seer.in_view(seen)
    seen[~inside] = np.nan
    assert 0.5 < inside.mean() < 0.8 and other.in_view(other.to_camera(ghost)).all()
    frame = core.process({seer.name: [(50, seen)], other.name: []}, 0.0)
    assert frame.people == [], "not at once"
    core = setup(verified=True)[1]
    frame = core.process({seer.name: [(50, seen)]}, 0.0)
    assert len(frame.people) == 1, "with no one to say otherwise: someone walking in"


def test_a_ghost_where_the_master_looks_costs_its_camera_no_trust():
    """A ghost lives under a second; a bumped camera's copies are contradicted for as
    long as it is bumped. Only the lasting disagreement withdraws trust."""
    cams, core = setup(verified=True)
    ghost = standing((0.3, 0.4))
    assert all(c.in_view(c.to_camera(ghost)).all() for c in cams), "where both look"
    for k in range(27):  # 0.9 s: k1 alone sees it, k0 sees no one
        core.process({"k0": [], "k1": [(50, cams[1].to_camera(ghost))]}, k * FRAME)
    assert core.verified == {"k0", "k1"}
    assert core.process({"k0": [], "k1": []}, 27 * FRAME).people == [], "never someone"


def test_a_ghost_of_the_master_where_another_camera_looks_costs_that_camera_no_trust():
    """The other way round: the master's ghost is missed by every camera that looks
    there, for the ghost's whole life; they keep their trust, and who only they see
    still counts (5 frames of it took k1's trust: a scene's MOTA fell to 0.63)."""
    cams, core = setup(verified=True)
    ghost = standing((0.3, 0.4))
    assert all(c.in_view(c.to_camera(ghost)).all() for c in cams), "where both look"
    for k in range(27):  # 0.9 s: k0 alone sees it, k1 sees no one
        core.process({"k0": [(50, cams[0].to_camera(ghost))], "k1": []}, k * FRAME)
    assert core.verified == {"k0", "k1"}
    only_k1 = cams[1].to_camera(standing(ONLY_K1_SEES))
    for k in range(27, 27 + 40):  # as a lone user of a trusted camera: after 1 s
        frame = core.process({"k0": [], "k1": [(7, only_k1)]}, k * FRAME)
    assert [p.cameras for p in frame.people] == [{"k1"}]


def test_a_dropped_frame_is_no_evidence_that_someone_at_the_edge_of_a_view_left():
    """A camera that sends nothing in a frame says nothing about who it sees; a person
    with part of their body beyond its edge must not be taken for one walking out."""
    cams, core = _one_camera()
    camera = cams[0]
    spots = [(x, -0.5) for x in np.linspace(1.0, 1.8, 81)]
    inside = [camera.in_view(camera.to_camera(standing(s))).mean() for s in spots]
    at_edge = next(s for s, f in zip(spots, inside, strict=True) if 0.55 <= f <= 0.75)
    for k in range(60):  # seen whole in the middle, then walks to the edge and stands
        x = 0.6 + (at_edge[0] - 0.6) * min(max(k - 20, 0) / 30, 1.0)
        frame = run(cams, core, {1: standing((x, at_edge[1]))}, 1, start=k)
    assert len(frame.people) == 1, "seen and counted"
    person = {1: standing(at_edge)}
    frame = run(cams, core, person, 1, start=60, drop=("k0",))
    assert len(frame.people) == 1, "the camera sent nothing: still counted"
    frame = run(cams, core, person, 1, start=61)
    assert [p.id for p in frame.people] == [frame.people[0].id] and frame.people[0].id == 1


def test_frames_a_busy_host_delivers_late_do_not_stretch_a_ghost_into_someone_guarded():
    # a ghost one camera saw for 0.9 s: the host stalls after its first frame and the
    # rest arrive 0.35 s late. Counted in arrival time it lasted 1.2 s, a lasting
    # detection the robot would keep its distance from (a false protective stop seen on
    # a busy CI host); counted in the time the camera saw it, 0.9 s: no one
    import time

    from components.people.component import WorkspacePeopleDetector
    from framework import messages
    from framework.clock import SimulatedClock
    from framework.messages import Skeletons
    from tests.conftest import REPO

    detector = WorkspacePeopleDetector("people_detector")
    detector.set_property("cameras_file", str(REPO / "procedures/seeg/cameras.yaml"))
    assert detector.configure()
    detector.clock = clock = SimulatedClock(50.0)
    camera = KinectModel(
        "kinect_0", look_at((0.6, -2.3, 1.3), (0.6, 0.0, 0.0)), dropout=0.0, ghost_rate=0.0
    )
    ghost = {1: standing((0.6, -0.2))}
    guarded = []
    for k in range(90):
        taken = k * FRAME  # when the camera saw it
        late = 0.35 if k else 0.0
        clock.set(50.0 + taken + late)
        users = camera.observe(ghost, taken) if k < 27 else []
        message = camera.to_message(users, time.time() - late)
        detector.camera_ports["kinect_0"].deliver_local(messages.encode(message, Skeletons))
        detector.update_hook()
        guarded.append(len(detector.envelopes.last.radius))
    assert guarded[0] == 0 and max(guarded) == 0, "the ghost was never anyone"
