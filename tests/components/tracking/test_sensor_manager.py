"""Spec: the Sensor Manager detects every fault-tree leaf with the right cause and always
chooses the highest-priority healthy sensor (after hysteresis)."""

import dataclasses
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.geometry import rigid
from components.domain.rigs import ee_path, sensors_config, standard_rigs
from components.domain.sensors import SensorConfigError, load_sensors
from components.tracking.sensor_manager import (
    CHECK_LAG_LIMIT,
    POSE_GAP_LIMIT,
    SensorManagerCore,
)

TICK = 0.001  # the Sensor Manager's 1 kHz cycle


class World:
    """Trackers streaming at their rates into a Sensor Manager, on a simulated clock."""

    def __init__(self, rigs=None, hysteresis=3, kinematics=False, camera=False, **overrides):
        self.rigs = rigs or standard_rigs()
        self.core = SensorManagerCore(sensors_config(self.rigs, hysteresis, camera, **overrides))
        self.head = None  # where the patient's head put the reference tools (None: at rest)
        self.rng = np.random.default_rng(7)
        self.t = 0.0
        self.faults: dict[str, str] = {}
        self.kinematics = kinematics
        self.moved = np.eye(4)
        self.frames = {r.name: 0 for r in self.rigs}
        self.scale = 1.0
        self.kinematics_error = np.eye(4)
        self.head_at = None  # the head's motion: base_from_rto at time t (None: `head`)
        self.decisions = []  # every cycle's decision, with `keep`
        self.keep = False
        self.phase: dict[str, float] = {}  # a tracker's first frame this late (s)

    def run(self, seconds):
        decision = None
        for _ in range(round(seconds / TICK)):
            self.t += TICK
            if self.head_at is not None:
                self.head = self.head_at(self.t)
            truth = ee_path(self.t)
            for rig in self.rigs:
                period = 1.0 / rig.rate
                frame = int((self.t - self.phase.get(rig.name, 0.0)) / period + 1e-9)
                if frame == self.frames[rig.name]:
                    continue
                self.frames[rig.name] = frame
                self._sample(rig, truth)
            if self.kinematics:  # from the joints, maybe with an error of its own
                self.core.set_kinematics(truth @ self.kinematics_error)
            decision = self.core.evaluate(self.t)
            if self.keep:
                self.decisions.append(decision)
        return decision

    def _sample(self, rig, truth):
        faults = set(self.faults.get(rig.name, "").split("+"))  # several at once: a+b
        if "silent" in faults:
            return
        cto, rto = rig.observe(truth, self.rng, self.t, base_from_rto=self.head)
        if "rto_moved" in faults and self.head is not None:  # it slipped on the head clamp
            _, rto = rig.observe(truth, self.rng, self.t, base_from_rto=self.head @ self.moved)
        elif "rto_moved" in faults:  # someone bumped the reference tool: only it moved
            bumped = dataclasses.replace(rig, sensor_from_rto=rig.sensor_from_rto @ self.moved)
            _, rto = bumped.observe(truth, self.rng, self.t)
        if "sensor_moved" in faults:  # the tracker itself was pushed: it sees everything moved
            moved = dataclasses.replace(rig, sensor_from_rto=self.moved @ rig.sensor_from_rto)
            cto, rto = moved.observe(truth, self.rng, self.t, base_from_rto=self.head)
        if "cto_missing" in faults:
            cto = dataclasses.replace(cto, valid=False)
        if "rto_missing" in faults:
            rto = dataclasses.replace(rto, valid=False)
        if "nan" in faults:
            cto = dataclasses.replace(cto, position=(math.nan, 0.0, 0.0))
        if "z_nan" in faults:
            cto = dataclasses.replace(cto, position=(*cto.position[:2], math.nan))
        if "rto_nan" in faults:
            rto = dataclasses.replace(rto, position=(0.0, math.nan, 0.0))
        if "unnormalised" in faults:  # a quaternion that is not a rotation
            cto = dataclasses.replace(
                cto, orientation=tuple(v * self.scale for v in cto.orientation)
            )
        if "jump" in faults and self.frames[rig.name] % 2:  # a flickering, impossible track
            cto = dataclasses.replace(cto, position=tuple(v + 0.05 for v in cto.position))
        if "cto_silent" not in faults:  # the robot's tool stream froze
            self.core.offer(rig.name, "cto", cto, self.t)
        if "rto_silent" not in faults:  # the reference tool's stream froze
            self.core.offer(rig.name, "rto", rto, self.t)


def test_nominal_tracking_chooses_the_master_and_places_the_robot():
    world = World()
    decision = world.run(0.5)
    assert decision.best == "certus"
    assert all(h.ok for h in decision.health.values())
    truth = world.rigs[0].rto_from_base @ ee_path(world.t)
    assert np.linalg.norm(decision.robot_pose[:3, 3] - truth[:3, 3]) < 0.001


@pytest.mark.parametrize(
    ("fault", "cause"),
    [
        ("cto_missing", "cto_missing"),
        ("rto_missing", "rto_missing"),
        ("silent", "stale"),
        ("nan", "corrupt"),
        ("jump", "corrupt"),
    ],
)
def test_each_fault_tree_leaf_is_detected_and_the_next_sensor_takes_over(fault, cause):
    world = World()
    world.run(0.5)
    world.faults["certus"] = fault
    decision = world.run(0.05)
    assert decision.health["certus"].cause == cause, decision.health["certus"]
    assert decision.best == "vicra"


@pytest.mark.parametrize("kinematics", [True, False], ids=["vs kinematics", "vs other sensors"])
def test_a_moved_reference_tool_is_a_calibration_fault(kinematics):
    rigs = standard_rigs()
    if not kinematics:  # a third sensor breaks the tie between two that disagree
        rigs.append(dataclasses.replace(rigs[1], name="vicra2"))
    world = World(rigs, kinematics=kinematics)
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.05))
    world.faults["certus"] = "rto_moved"
    decision = world.run(0.1)
    assert decision.health["certus"].cause == "calibration", decision.health["certus"]
    assert decision.best == "vicra"
    assert all(h.ok for n, h in decision.health.items() if n != "certus")


def test_two_sensors_that_disagree_are_both_distrusted():
    world = World()
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "rto_moved"
    decision = world.run(0.1)
    assert decision.best is None
    assert {h.cause for h in decision.health.values()} == {"calibration"}


@pytest.mark.parametrize(("degrees", "ok"), [(2.0, True), (5.0, False)])
def test_two_sensors_whose_views_differ_by_more_than_the_angle_tolerance_disagree(degrees, ok):
    """The position tolerance set out of the way (1 m): the angle alone decides."""
    world = World(tolerance_position=1.0)
    world.run(0.5)
    world.moved = rigid((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(degrees)))
    world.faults["certus"] = "rto_moved"
    health = world.run(0.1).health
    assert (health["certus"].ok, health["vicra"].ok) == (ok, ok), health


def test_no_sensor_means_no_best():
    world = World()
    world.run(0.3)
    world.faults = {"certus": "silent", "vicra": "cto_missing"}
    assert world.run(0.2).best is None


def test_a_recovered_better_sensor_is_taken_back_only_after_n_healthy_samples():
    world = World(hysteresis=5)
    world.run(0.5)
    world.faults["certus"] = "cto_missing"
    assert world.run(0.05).best == "vicra"
    world.faults = {}
    assert world.run(0.035).best == "vicra", "4 healthy Certus samples are not enough"
    assert world.run(0.02).best == "certus"


def test_stale_detection_waits_the_configured_periods():
    world = World(stale_periods=2.0)
    world.run(0.5)
    world.faults["certus"] = "silent"
    assert world.run(0.015).best == "certus", "1.5 periods late is not yet stale"
    assert world.run(0.010).health["certus"].cause == "stale"


def test_it_says_when_a_silent_tracker_will_be_stale_so_it_need_not_poll():
    """Event-driven, the Sensor Manager wakes on samples; with none coming it must still
    look again once the earliest staleness limit has passed, and only then."""
    world = World(stale_periods=2.0)
    assert world.core.due_in(0.0) is None, "no sample yet: nothing falls due"
    world.run(0.5)
    world.faults["certus"] = "silent"
    world.faults["vicra"] = "silent"
    now = world.t
    due = world.core.due_in(now)
    assert 0.0 < due <= 0.0201, "the Certus (2 x 10 ms) falls due first"
    assert world.core.evaluate(now + due - 0.001).best == "certus"
    late = world.core.evaluate(now + due + 0.001)
    assert late.health["certus"].cause == "stale"
    vicra_due = world.core.due_in(now + due + 0.001)
    assert vicra_due is not None and vicra_due > 0.0, "the Vicra (2 x 50 ms) is due later"
    assert world.core.due_in(now + 1.0) is None, "every tracker stale: nothing more falls due"


def test_a_tracker_falls_due_when_the_older_of_its_two_tools_goes_stale():
    """Staleness counts from the older of a tracker's two tools: the reference tool
    last seen at 0 and the robot's tool at 15 ms, both then silent: the Certus (2 x 10
    ms) is stale at 20 ms, so the Sensor Manager must look again by then, not at 35 ms."""
    rig, core = single_certus()
    cto, rto = rig.observe(ee_path(0.0), np.random.default_rng(0), 0.0)
    core.offer("certus", "rto", rto, 0.0)
    core.offer("certus", "cto", cto, 0.015)
    assert core.due_in(0.016) == pytest.approx(0.004)
    assert core.evaluate(0.0201).health["certus"].cause == "stale"


@settings(max_examples=60, deadline=None)
@given(
    script=st.lists(
        st.tuples(
            st.sampled_from(["certus", "vicra", "vicra2"]),
            st.sampled_from(["", "cto_missing", "rto_missing", "silent", "nan", "jump"]),
            st.integers(5, 60),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_the_choice_is_always_the_best_healthy_sensor_after_hysteresis(script):
    rigs = standard_rigs()
    rigs.append(dataclasses.replace(rigs[1], name="vicra2"))
    world = World(rigs, hysteresis=3, kinematics=True)
    world.run(0.2)
    previous = world.core.best
    for sensor, fault, ms in script:
        world.faults[sensor] = fault
        for _ in range(ms):
            decision = world.run(TICK)
            expected = None
            for track in world.core.tracks:
                h = track.health
                if h.ok and (h.streak >= 3 or track.config.name == previous):
                    expected = track.config.name
                    break
            assert decision.best == expected
            if decision.best is not None:
                assert decision.health[decision.best].ok, "never an unhealthy sensor"
            previous = decision.best


def test_sensor_files_are_checked_with_locations(write):
    good = write(
        """
        sensors:
          certus: {priority: 1, rate: 100,
                   limits: {max_velocity: 0.1, max_acceleration: 0.5}}
          vicra: {priority: 2, rate: 20,
                  calibration: {C: {position: [0.1, 0, 0], quaternion: [1, 0, 0, 0]}}}
        """,
        "sensors.yaml",
    )
    config = load_sensors(good)
    assert [s.name for s in config.sensors] == ["certus", "vicra"]
    assert config.sensors[1].master_from_sensor[0, 3] == 0.1
    cases = [
        ("sensors: {a: {rate: 100}}", "'priority' is required"),
        ("sensors: {a: {priority: 1, rate: 0}}", "more than 0"),
        ("sensors: {a: {priority: 1, rate: 5, keys: {cto: x}}}", "'keys' are no longer read"),
        (
            "sensors: {a: {priority: 1, rate: 5, calibration: {X: {quaternion: [0, 0, 0, 0]}}}}",
            "unit length",
        ),
        (
            "sensors: {a: {priority: 1, rate: 5, calibration: {X: {quaternion: }}}}",
            "expected a list",
        ),
        ("sensors: {a: {priority: 1, rate: .nan}}", "finite"),
        (
            "sensors: {a: {priority: 1, rate: 5, calibration: {C: [[1, 0], [0, 1]]}}}",
            "needs at least 4 items",
        ),
        (
            "sensors: {a: {priority: 1, rate: 5}, b: {priority: 1, rate: 5}}",
            "share a priority",
        ),
        ("nothing: 1", "'sensors' is required"),
    ]
    for text, message in cases:
        path = write(text, "bad.yaml")
        with pytest.raises(SensorConfigError, match=message) as err:
            load_sensors(path)
        assert str(err.value).startswith(f"{path}:")


def test_a_late_sample_is_checked_against_where_the_robot_was_when_it_was_taken():
    from components.domain.rigs import ee_path, sensors_config, standard_rigs
    from components.tracking.sensor_manager import SensorManagerCore

    rigs = standard_rigs()
    core = SensorManagerCore(sensors_config(rigs, 1))
    rng = np.random.default_rng(0)
    then, later = ee_path(0.0), ee_path(0.0).copy()
    later[:3, 3] += (0.02, 0.0, 0.0)  # the robot moved 2 cm since the sample was taken
    for rig in rigs:
        cto, rto = rig.observe(then, rng, stamp=10.0)
        core.offer(rig.name, "cto", cto, 0.0)
        core.offer(rig.name, "rto", rto, 0.0)
    core.set_kinematics(then, stamp=10.0)
    core.set_kinematics(later, stamp=10.3)
    decision = core.evaluate(0.001)
    assert all(h.ok for h in decision.health.values()), decision.health
    core.set_kinematics(later)  # without stamps: only the latest pose is known
    assert {h.cause for h in core.evaluate(0.002).health.values()} == {"calibration"}


def test_a_frozen_reference_tool_is_stale_though_the_robots_tool_streams_on():
    world = World()
    world.run(0.5)
    world.faults["certus"] = "rto_silent"
    decision = world.run(0.03)
    assert decision.health["certus"].cause == "stale"
    assert decision.health["certus"].detail == "no new frame for 20 ms (limit 20 ms)"
    assert decision.best == "vicra"


@pytest.mark.parametrize(
    ("faults", "reported"),
    [
        ("cto_missing+rto_missing", "cto_missing"),
        ("cto_missing+nan", "cto_missing"),
        ("rto_missing+rto_nan", "rto_missing"),
        ("cto_missing+rto_silent", "cto_missing"),
        ("rto_silent+nan", "stale"),
        ("nan+jump", "corrupt"),
        ("nan+unnormalised", "corrupt"),
        ("nan+rto_nan", "corrupt"),
        ("z_nan", "corrupt"),
        ("rto_nan+rto_moved", "corrupt"),
        ("jump+rto_moved", "corrupt"),
    ],
)
def test_when_faults_coincide_the_first_in_the_trees_order_is_reported(faults, reported):
    world = World(kinematics=True)
    world.scale = 1.1  # what "unnormalised" does to a quaternion
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.run(0.5)
    world.faults["certus"] = faults
    decision = world.run(0.05)
    assert decision.health["certus"].cause == reported, decision.health["certus"]
    assert decision.best == "vicra"


def test_a_tool_still_reported_missing_when_its_stream_stops_stays_missing():
    world = World()
    world.run(0.5)
    world.faults["certus"] = "cto_missing"
    world.run(0.02)
    world.faults["certus"] = "silent"
    assert world.run(0.1).health["certus"].cause == "cto_missing"


@pytest.mark.parametrize(
    ("scale", "cause"), [(1.0008, ""), (0.9996, ""), (1.0012, "corrupt"), (0.99, "corrupt")]
)
def test_a_quaternion_must_be_a_rotation_to_rounding(scale, cause):
    world = World()
    world.run(0.5)
    world.scale = scale
    world.faults["certus"] = "unnormalised"
    decision = world.run(0.05)
    assert decision.health["certus"].cause == cause
    if cause:
        assert decision.health["certus"].detail == "a tool's pose is not a finite unit pose"


@pytest.mark.parametrize(("degrees", "cause"), [(2.0, ""), (5.0, "calibration")])
def test_a_tool_turned_but_not_moved_is_a_calibration_fault_beyond_the_angle_tolerance(
    degrees, cause
):
    world = World(kinematics=True)
    world.run(0.5)
    turn = rigid((0.0, 0.0, 0.0), (0.0, math.radians(degrees), 0.0))
    y = world.rigs[0].ee_from_cto  # turned about the tracked tool's own origin
    world.kinematics_error = y @ turn @ np.linalg.inv(y)
    health = world.run(0.05).health["certus"]
    assert health.cause == cause, health
    if cause:
        offset, angle = health.detail.removesuffix(" deg away from the robot's kinematics").split(
            ", "
        )
        assert float(offset.removesuffix(" mm")) < 0.5, "the tracker's noise only"
        assert angle == f"{degrees:.2f}"


def single_certus(hysteresis=1):
    rig = standard_rigs()[0]
    return rig, SensorManagerCore(sensors_config([rig], hysteresis))


def offer(core, rig, pose, stamp, arrival):
    cto, rto = rig.observe(pose, np.random.default_rng(1), stamp)
    core.offer(rig.name, "cto", cto, arrival)
    core.offer(rig.name, "rto", rto, arrival)


def shifted(pose, dx):
    out = pose.copy()
    out[0, 3] += dx
    return out


def test_a_long_step_after_a_gap_between_frames_is_motion_not_a_jump():
    rig, core = single_certus()
    start = ee_path(0.0)
    offer(core, rig, start, 0.0, arrival=0.0)
    assert core.evaluate(0.001).best == "certus"
    offer(core, rig, shifted(start, 0.05), 0.08, arrival=0.08)  # 5 cm in 80 ms: 0.6 m/s
    assert core.evaluate(0.081).health["certus"].ok
    offer(core, rig, shifted(start, 0.10), 0.09, arrival=0.09)  # 5 cm in 10 ms: 5 m/s
    health = core.evaluate(0.091).health["certus"]
    assert (health.cause, health.detail) == ("corrupt", "the robot's tool jumped 50.0 mm in 10 ms")


def test_frames_closer_than_the_rate_are_judged_over_one_period():
    rig, core = single_certus()
    start = ee_path(0.0)
    offer(core, rig, start, 0.0, arrival=0.0)
    offer(core, rig, shifted(start, 0.008), 0.001, arrival=0.001)  # two frames in one cycle
    assert core.evaluate(0.002).health["certus"].ok, "8 mm in one 10 ms period: 0.8 m/s"


def test_each_sample_is_checked_against_the_robot_pose_of_its_time():
    """Robot poses every 1/256 s (binary-exact stamps, as the 200 Hz stream), each 5 cm
    from the last (toward -x); a sample taken at stamp t shows where the robot was then,
    between the two poses around t, not the nearer of them (far beyond the tolerance)."""
    rig, core = single_certus()
    step = 1 / 256
    poses = [(10.0 + step * i, shifted(ee_path(0.0), -0.05 * i)) for i in range(6)]
    for stamp, pose in poses:
        core.set_kinematics(pose, stamp=stamp)
    cases = [
        (10.0, 0.0),  # at a pose
        (10.0 + step / 4, -0.0125),  # a quarter of the way to the second
        (10.0 + 1.5 * step, -0.075),  # halfway between the second and the third
        (10.0 + 4.75 * step, -0.2375),  # three quarters toward the newest
        (10.0 + 5 * step, -0.25),  # at the newest
    ]
    for arrival, (stamp, x) in enumerate(cases, start=1):
        offer(core, rig, shifted(ee_path(0.0), x), stamp, arrival=float(arrival))
        health = core.evaluate(arrival + 0.001).health["certus"]
        assert health.ok, (stamp, x, health)
    assert core.unchecked == 0
    # halfway between two poses, the tool seen where the later one is: 25 mm off
    offer(core, rig, poses[2][1], 10.0 + 1.5 * step, arrival=9.0)
    health = core.evaluate(9.001).health["certus"]
    assert health.cause == "calibration", health
    assert health.numbers["pose_gap_ms"] == pytest.approx(step * 1e3, abs=1e-3)
    assert health.numbers["pose_nearest"] == poses[2][0]  # a tie: the later one
    assert health.numbers["pose_newest"] == poses[-1][0]
    # a quarter of the way from the second pose, the tool seen where the third is
    offer(core, rig, poses[2][1], 10.0 + 1.25 * step, arrival=10.0)
    health = core.evaluate(10.001).health["certus"]
    assert health.cause == "calibration", health
    assert health.numbers["pose_nearest"] == poses[1][0], "the nearer: the earlier one"


def test_a_sample_older_than_every_robot_pose_names_the_oldest_as_the_nearest():
    """Samples older than every robot pose kept cannot be checked; after
    `CHECK_LAG_LIMIT` of them the verdict's numbers name the poses it had: the nearest
    in time is the oldest, not the newest."""
    rig, core = single_certus()
    poses = [(10.0 + i / 256, shifted(ee_path(0.0), 0.0003 * i)) for i in range(4)]
    for stamp, pose in poses:
        core.set_kinematics(pose, stamp=stamp)
    offer(core, rig, ee_path(0.0), 9.9, arrival=1.0)
    core.evaluate(1.001)
    offer(core, rig, ee_path(0.0), 9.91, arrival=1.0 + CHECK_LAG_LIMIT + 0.1)
    health = core.evaluate(1.002 + CHECK_LAG_LIMIT + 0.1).health["certus"]
    assert health.cause == "calibration" and "cannot be checked" in health.detail
    assert health.numbers["pose_nearest"] == poses[0][0]
    assert health.numbers["pose_newest"] == poses[-1][0]


def test_poses_as_far_apart_as_the_limit_still_place_the_tool():
    """Two poses exactly `POSE_GAP_LIMIT` apart (30 ms, the 100 Hz stream missing two)
    still say where the tool was between them."""
    rig, core = single_certus()
    core.set_kinematics(ee_path(0.0), stamp=0.0)
    core.set_kinematics(shifted(ee_path(0.0), -0.02), stamp=POSE_GAP_LIMIT)
    offer(core, rig, shifted(ee_path(0.0), -0.01), POSE_GAP_LIMIT / 2, arrival=1.0)
    assert core.evaluate(1.001).health["certus"].ok and core.unchecked == 0


def test_a_sample_in_a_pause_of_the_robots_poses_is_not_judged_by_a_pose_of_another_time():
    """The robot's side was starved for 100 ms while the tool moved 15 mm: a tracker's
    sample inside that pause cannot be checked (where the tool was then is not known),
    and must never be found a calibration fault; it is counted as unchecked and the
    sensor keeps its verdict (for `CHECK_LAG_LIMIT` at most: then it cannot be checked,
    a fault). Samples from before the poses kept are not checked either; once the poses
    are dense again, a wrong sample is found at once."""
    rig, core = single_certus()
    before = [(10.0 + i / 256, shifted(ee_path(0.0), 0.0003 * i)) for i in range(4)]
    after = [(10.1 + i / 256, shifted(ee_path(0.0), 0.015 + 0.0003 * i)) for i in range(4)]
    for stamp, pose in before:
        core.set_kinematics(pose, stamp=stamp)
    offer(core, rig, before[-1][1], before[-1][0], arrival=1.0)
    assert core.evaluate(1.001).health["certus"].ok
    for stamp, pose in after:
        core.set_kinematics(pose, stamp=stamp)
    # in the pause: the tool where it truly was (7.5 mm from either pose around it)
    offer(core, rig, shifted(ee_path(0.0), 0.0075), 10.05, arrival=1.1)
    assert core.evaluate(1.101).health["certus"].ok
    assert core.unchecked == 1
    offer(core, rig, ee_path(0.0), 9.999, arrival=1.2)  # 1 ms older than every pose
    assert core.evaluate(1.201).health["certus"].ok
    assert core.unchecked == 2
    offer(core, rig, shifted(after[2][1], 0.008), after[2][0], arrival=1.3)  # 8 mm off
    assert core.evaluate(1.301).health["certus"].cause == "calibration"


def test_robot_poses_unknown_for_a_while_leave_nothing_of_before_behind():
    """The joints were unknown (the robot's side restarted, its clock with it): the
    poses from before are forgotten, so a sample is placed by the poses known since, and
    a verdict from before is not carried over to the same sample checked again."""
    rig, core = single_certus()
    for stamp in (10.0, 10.004, 10.008):
        core.set_kinematics(shifted(ee_path(0.0), 0.3), stamp=stamp)
    core.set_kinematics(None)
    for stamp in (10.0, 10.004):
        core.set_kinematics(ee_path(0.0), stamp=stamp)
    offer(core, rig, ee_path(0.0), 10.002, arrival=1.0)
    assert core.evaluate(1.001).health["certus"].ok, "placed by the poses since"
    core.set_kinematics(None)
    for stamp in (10.0, 10.004):
        core.set_kinematics(shifted(ee_path(0.0), 0.3), stamp=stamp)
    health = core.evaluate(1.002).health["certus"]
    assert health.cause == "calibration", "the same sample, checked again against these"


def test_robot_poses_out_of_time_order_are_ignored():
    """A pose older than the last (or with no finite stamp) would break the time order
    the samples are matched in: it is left out, and the latest pose stays."""
    _, core = single_certus()
    core.set_kinematics(ee_path(0.0), stamp=10.0)
    core.set_kinematics(shifted(ee_path(0.0), 0.01), stamp=10.01)
    core.set_kinematics(shifted(ee_path(0.0), 0.5), stamp=10.005)
    core.set_kinematics(shifted(ee_path(0.0), 0.5), stamp=10.01)  # the same instant again
    core.set_kinematics(shifted(ee_path(0.0), 0.5), stamp=math.nan)
    core.set_kinematics(shifted(ee_path(0.0), 0.5), stamp=0.0)  # a clock's zero is a time
    assert core._times == [10.0, 10.01]
    assert core.kinematics[0, 3] == pytest.approx(ee_path(0.0)[0, 3] + 0.01)


def test_a_sample_newer_than_the_robots_poses_waits_for_the_pose_of_its_time():
    """Robot poses every 1/256 s, each 2 cm from the last; the newest at x = 10 cm. A
    sample taken halfway to the next pose shows the tool at 11 cm: against the newest
    pose it would be 1 cm off, so it waits (the sensor keeps its verdict) until a pose
    after its stamp has come, and is then checked against the pose of its time."""
    rig, core = single_certus()
    step = 1 / 256
    for i in range(6):
        core.set_kinematics(shifted(ee_path(0.0), 0.02 * i), stamp=10.0 + step * i)
    offer(core, rig, shifted(ee_path(0.0), 0.11), 10.0 + 5.5 * step, arrival=1.0)
    assert core.evaluate(1.001).health["certus"].ok, "not judged against an older pose"
    core.set_kinematics(shifted(ee_path(0.0), 0.12), stamp=10.0 + 6 * step)
    assert core.evaluate(1.002).health["certus"].ok, "against the pose of its time"
    core.set_kinematics(shifted(ee_path(0.0), 0.14), stamp=10.0 + 7 * step)
    offer(core, rig, shifted(ee_path(0.0), 0.14), 10.0 + 6.5 * step, arrival=2.0)
    assert core.evaluate(2.001).health["certus"].cause == "calibration", "1 cm off: checked"


@pytest.mark.parametrize("camera", [False, True])
def test_samples_are_checked_as_the_robots_poses_come_however_far_behind(camera):
    """The robot moves 10 cm/s; its poses reach the Sensor Manager 200 ms after the
    tracker's samples of the same moment (a starved robot process). Against the newest
    pose, each sample would be 2 cm off (tolerance 5 mm); each is checked against the
    pose of its own time, so a tool that slipped 6 mm on the robot at 10.5 s is found
    once the pose of 10.5 s has come, not before."""
    rig = standard_rigs()[0]
    core = SensorManagerCore(sensors_config([rig], 1, camera))

    def pose(t):
        return shifted(ee_path(0.0), 0.1 * (t - 10.0))

    seen = {}
    for cycle in range(100):  # 1 s of 100 Hz samples
        t = 10.0 + 0.01 * cycle
        slipped = 0.006 if t >= 10.5 else 0.0
        offer(core, rig, shifted(pose(t), slipped), t, arrival=t)
        for late in (0.205, 0.2):  # two poses per cycle, 200 ms late
            core.set_kinematics(pose(t - late), stamp=t - late)
        seen[round(t, 2)] = core.evaluate(t).health["certus"]
    assert all(seen[round(10.0 + 0.01 * k, 2)].ok for k in range(70)), "the slip is not seen yet"
    assert all(seen[round(10.7 + 0.01 * k, 2)].cause == "calibration" for k in range(30))


def test_a_frame_that_reported_the_tool_missing_is_never_the_one_checked():
    """While the robot's poses run behind, the sample checked may be an older one: never
    a frame that reported the tool missing (its position means nothing)."""
    rig, core = single_certus()
    still = ee_path(0.0)
    for stamp in (9.995, 10.0):
        core.set_kinematics(still, stamp=stamp)
    offer(core, rig, still, 10.0, arrival=1.0)
    cto, rto = rig.observe(still, np.random.default_rng(1), 10.004)
    core.offer(rig.name, "cto", dataclasses.replace(cto, valid=False, position=(0, 0, 0)), 1.001)
    core.offer(rig.name, "rto", rto, 1.001)
    assert core.evaluate(1.0011).health["certus"].cause == "cto_missing"
    core.set_kinematics(still, stamp=10.005)  # the poses now cover 10.004 too
    offer(core, rig, still, 10.02, arrival=1.002)
    assert core.evaluate(1.0021).health["certus"].ok, "checked: the frame of 10.0"


def test_samples_a_second_older_than_the_newest_are_still_checked():
    """The samples kept for the check span a second, both ends included: after a gap,
    a sample exactly a second older than the newest is still the one the robot's poses
    (half a second behind) cover; it shows the robot 2 cm off."""
    rig, core = single_certus()
    still = ee_path(0.0)
    for stamp in (9.995, 10.005, 10.5):  # the pose of 10.0 known, the newest at 10.5
        core.set_kinematics(still, stamp=stamp)
    offer(core, rig, shifted(still, 0.02), 10.0, arrival=1.0)
    offer(core, rig, still, 11.0, arrival=1.5)
    health = core.evaluate(1.5001).health["certus"]
    assert health.cause == "calibration" and "away from the robot's kinematics" in health.detail


def test_a_long_procedure_does_not_grow_the_sensor_managers_memory():
    """An hour of 100 Hz samples on a standing robot keeps about a second of them."""
    import tracemalloc

    rig, core = single_certus()
    still = ee_path(0.0)
    cto, _ = rig.observe(still, np.random.default_rng(1), 0.0)

    def run(start, count):
        for k in range(start, start + count):
            sample = dataclasses.replace(cto, stamp=k * 0.01)
            core.offer(rig.name, "cto", sample, k * 0.01)

    run(0, 2_000)
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    run(2_000, 20_000)
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert grown < 100_000, f"{grown} bytes more after 20,000 samples"


def test_a_sensor_too_far_ahead_of_the_robots_poses_cannot_be_checked():
    """The robot's poses stop coming (its side stalled) while the tracker streams on:
    past `CHECK_LAG_LIMIT`, its calibration cannot be checked, which is a fault; so is
    a sample without a valid stamp. Once the poses catch up, it is checked again."""
    rig, core = single_certus()
    still = ee_path(0.0)
    core.set_kinematics(still, stamp=9.995)
    core.set_kinematics(still, stamp=10.0)
    offer(core, rig, still, 10.0 + CHECK_LAG_LIMIT, arrival=1.0)
    assert core.evaluate(1.001).health["certus"].ok, "not checked yet, within the limit"
    offer(core, rig, still, 10.01 + CHECK_LAG_LIMIT, arrival=2.0)
    health = core.evaluate(2.001).health["certus"]
    assert (health.ok, health.cause, health.detail) == (
        False,
        "calibration",
        "cannot be checked: the robot's poses are 510 ms behind its samples (limit 0.5 s)",
    )
    core.set_kinematics(still, stamp=10.01 + CHECK_LAG_LIMIT)
    assert core.evaluate(2.002).health["certus"].ok, "checked again"
    offer(core, rig, still, math.nan, arrival=2.01)
    health = core.evaluate(2.011).health["certus"]
    assert (health.ok, health.cause, health.detail) == (
        False,
        "calibration",
        "cannot be checked: its sample has no valid stamp",
    )


def test_about_a_second_of_robot_poses_is_remembered():
    """The robot moves 2 cm/s; its poses come at 10 Hz, for a second, then (after a 3 s
    gap) for 2.5 s more. A sample 0.95 s old is checked against the pose of its own time;
    one from before the gap, whose time no pose remembered covers, cannot be checked: a
    second after the last check, that is a calibration fault (a tracker whose stamps lag
    seconds behind is never trusted unchecked)."""
    rig, core = single_certus()

    def pose(t):
        return shifted(ee_path(0.0), 0.02 * t)

    stamps = [100.0031 + 0.1 * k for k in range(11)] + [104.0031 + 0.1 * k for k in range(26)]
    for t in stamps:
        core.set_kinematics(pose(t), stamp=t)
    recent = stamps[-1] - 0.95
    offer(core, rig, pose(recent), recent, arrival=0.0)
    assert core.evaluate(0.001).health["certus"].ok, "matched against its own time"
    offer(core, rig, pose(100.5031), 100.5031, arrival=1.0)
    health = core.evaluate(1.001).health["certus"]
    assert (
        not health.ok
        and health.cause == "calibration"
        and health.detail.startswith(
            "cannot be checked: no robot pose of its samples' times for 1000 ms"
        )
    )


@pytest.mark.parametrize(("value", "error"), [("0", True), ("1", False), ("2.5", True)])
def test_hysteresis_is_a_whole_number_of_samples_from_one(write, value, error):
    path = write(
        f"""
        hysteresis: {value}
        sensors:
          a: {{priority: 1, rate: 5}}
        """,
        "sensors.yaml",
    )
    if error:
        with pytest.raises(SensorConfigError, match="hysteresis"):
            load_sensors(path)
    else:
        assert load_sensors(path).hysteresis == 1


def test_a_sensors_file_without_the_optional_fields_gets_the_documented_defaults(write):
    path = write(
        """
        sensors:
          vicra: {priority: 2, rate: 20}
          certus: {priority: 1, rate: 100}
        """,
        "sensors.yaml",
    )
    config = load_sensors(path)
    assert (config.hysteresis, config.master) == (5, "certus"), "master: the first by priority"
    certus = config.sensors[0]
    assert (certus.stale_periods, certus.max_speed) == (2.0, 1.0)
    assert certus.tolerance_position == 0.005
    assert certus.tolerance_angle == pytest.approx(math.radians(3.0))
    assert certus.limits == {} and np.array_equal(certus.master_from_sensor, np.eye(4))


def test_before_its_first_frame_a_sensor_has_no_data():
    world = World()
    world.faults = {"certus": "silent"}
    health = world.run(0.1).health["certus"]
    assert (health.ok, health.cause, health.detail) == (False, "no_data", "no frame yet")


def test_at_start_a_sensor_is_used_after_exactly_hysteresis_healthy_samples():
    rig, core = single_certus(hysteresis=3)
    for frame in range(1, 4):
        offer(core, rig, ee_path(0.0), 0.0, arrival=frame * 0.01)
        decision = core.evaluate(frame * 0.01 + 0.001)
        assert decision.health["certus"].streak == frame
        assert decision.best == ("certus" if frame == 3 else None), frame
    assert core.evaluate(0.032).health["certus"].streak == 3, "no new frame: no new proof"


def test_a_sensor_configured_without_calibration_is_taken_as_the_identity():
    from components.domain.sensors import SensorConfig

    plain = SensorConfig("a", 1, 10.0)
    for frame in (plain.master_from_sensor, plain.rto_from_base, plain.ee_from_cto):
        assert np.array_equal(frame, np.eye(4))


def test_a_calibration_may_give_some_frames_the_rest_are_the_identity_and_the_tip_is_kept(
    tmp_path,
):
    path = tmp_path / "sensors.yaml"
    path.write_text(
        "sensors:\n"
        "  a: {priority: 1, rate: 10, calibration: {C: {position: [0.1, 0, 0]}, "
        "tip: [0.001, -0.02, -0.08]}}\n"
        "  b: {priority: 2, rate: 10}\n"
    )
    a, b = load_sensors(path).sensors
    assert a.master_from_sensor[0, 3] == 0.1
    assert np.array_equal(a.ee_from_cto, np.eye(4)) and np.array_equal(a.rto_from_base, np.eye(4))
    assert a.sensor_from_base is None, "no S: not calibrated to the robot"
    assert a.tip.tolist() == [0.001, -0.02, -0.08]
    assert b.tip is None, "no pivot: navigation uses Y"
    path.write_text("sensors:\n  a: {priority: 1, rate: 10, calibration: {tip: [0, .nan, 0]}}\n")
    with pytest.raises(
        SensorConfigError,
        match=r"sensors.yaml:2:53: sensors.a.calibration.tip\[1\]: must be a finite number",
    ):
        load_sensors(path)


def step_taken(step, max_speed, rms):
    """Two frames 10 ms apart from a noise-free tracker whose samples claim `rms`, the
    robot's tool `step` m further on: is the second one healthy?"""
    rig = dataclasses.replace(standard_rigs()[0], noise=0.0)
    core = SensorManagerCore(sensors_config([rig], 1, max_speed=max_speed))
    start = ee_path(0.0)
    for arrival, pose in ((0.0, start), (0.01, shifted(start, step))):
        cto, rto = rig.observe(pose, np.random.default_rng(0), arrival)
        core.offer("certus", "cto", dataclasses.replace(cto, rms=rms), arrival)
        core.offer("certus", "rto", rto, arrival)
        decision = core.evaluate(arrival + 0.001)
    return decision.health["certus"].ok


@pytest.mark.parametrize(
    ("noise", "step", "ok"),
    [
        (0.0, 0.00045, True),
        (0.0, 0.00055, False),
        (0.0002, 0.00095, True),
        (0.0002, 0.00105, False),
    ],
)
def test_a_step_within_five_times_the_trackers_noise_is_not_a_jump(noise, step, ok):
    """A tracker that barely moves (max_speed 1 mm/s) may still jitter by five times its
    RMS noise, and never by less than 0.5 mm (a noise-free tracker rounds too)."""
    assert step_taken(step, max_speed=0.001, rms=noise) == ok


@pytest.mark.parametrize("came", ["cto", "rto"])
def test_a_sensor_with_one_tool_never_seen_has_no_data(came):
    rig, core = single_certus()
    cto, rto = rig.observe(ee_path(0.0), np.random.default_rng(0), 0.0)
    core.offer("certus", came, cto if came == "cto" else rto, 0.0)
    assert core.evaluate(0.001).health["certus"].cause == "no_data"


def test_a_tracker_that_sees_the_tools_at_negative_coordinates_is_healthy():
    certus = standard_rigs()[0]
    behind = dataclasses.replace(
        certus, sensor_from_rto=rigid((-3.0, -3.0, -3.0), (0.0, 0.0, 0.0)) @ certus.sensor_from_rto
    )
    world = World([behind], kinematics=True)
    decision = world.run(0.2)
    assert decision.best == "certus" and decision.health["certus"].ok


def test_a_robot_pose_more_than_two_seconds_older_than_the_newest_is_never_used():
    """Poses at 10 Hz for 6 s while the robot moves 5 cm/s: a sample 2.5 s older than
    the newest pose has no pose of its time left (only ones half a second younger, 2.5 cm
    away): it is not judged against them; such samples for over `CHECK_LAG_LIMIT` (a
    tracker's clock seconds behind) cannot be checked, a fault."""
    rig, core = single_certus()

    def pose(t):
        return shifted(ee_path(0.0), 0.05 * (t - 100.0))

    stamps = [100.0031 + 0.1 * k for k in range(60)]
    for t in stamps:
        core.set_kinematics(pose(t), stamp=t)
    old = stamps[-1] - 2.5
    offer(core, rig, pose(old), old, arrival=0.0)
    assert core.evaluate(0.001).health["certus"].ok and core.unchecked == 1
    offer(core, rig, pose(old + 0.6), old + 0.6, arrival=0.6)
    health = core.evaluate(0.601).health["certus"]
    assert not health.ok and health.cause == "calibration"
    assert health.detail.startswith("cannot be checked")


def test_a_frame_after_a_missing_one_is_not_judged_against_the_missing_ones_position(write):
    """A device reports a missing tool with a meaningless (zero) position; the next real
    frame is no jump from it. Tool names are the ones read from the sensors file."""
    rig = standard_rigs()[0]
    config = load_sensors(
        write(
            """
            sensors:
              certus: {priority: 1, rate: 100}
            """,
            "sensors.yaml",
        )
    )
    config.sensors[0].rto_from_base = rig.rto_from_base
    config.sensors[0].ee_from_cto = rig.ee_from_cto
    config.hysteresis = 1
    core = SensorManagerCore(config)
    cto_name, rto_name = "cto", "rto"
    rng = np.random.default_rng(0)
    cto, rto = rig.observe(ee_path(0.0), rng, 0.0)
    core.offer("certus", cto_name, cto, 0.0)
    core.offer("certus", rto_name, rto, 0.0)
    assert core.evaluate(0.001).health["certus"].ok
    missing = dataclasses.replace(cto, position=(0.0, 0.0, 0.0), valid=False)
    core.offer("certus", cto_name, missing, 0.01)
    core.offer("certus", rto_name, rto, 0.01)
    assert core.evaluate(0.011).health["certus"].cause == "cto_missing"
    core.offer("certus", cto_name, cto, 0.02)
    core.offer("certus", rto_name, rto, 0.02)
    assert core.evaluate(0.021).health["certus"].ok, "seen again, where it was"


def test_a_tool_seen_again_after_hidden_frames_is_judged_against_where_it_was_last_seen():
    """Hidden frames between two sightings do not excuse an impossible step: a tool
    seen 30 cm away 20 ms after it was last seen jumped (the time since counts, so a
    long occlusion allows a long way, as between any two frames)."""
    rig, core = single_certus()
    start = ee_path(0.0)
    offer(core, rig, start, 0.0, arrival=0.0)
    assert core.evaluate(0.001).health["certus"].ok
    cto, rto = rig.observe(start, np.random.default_rng(1), 0.01)
    core.offer("certus", "cto", dataclasses.replace(cto, valid=False), 0.01)
    core.offer("certus", "rto", rto, 0.01)
    assert core.evaluate(0.011).health["certus"].cause == "cto_missing"
    offer(core, rig, shifted(start, 0.3), 0.02, arrival=0.02)
    health = core.evaluate(0.021).health["certus"]
    assert (health.cause, health.detail) == ("corrupt", "the robot's tool jumped 300.0 mm in 20 ms")
    offer(core, rig, start, 0.5, arrival=0.5)  # back after 480 ms: 0.6 m/s, motion
    assert core.evaluate(0.501).health["certus"].cause != "corrupt"


@pytest.mark.parametrize(("step", "ok"), [(0.0102, True), (0.0108, False)])
def test_the_allowed_step_is_the_speed_over_the_gap_plus_the_noise_margin(step, ok):
    """1 m/s for 10 ms is 10 mm, plus 0.5 mm of noise margin."""
    assert step_taken(step, max_speed=1.0, rms=0.0) == ok


def test_a_tool_silent_for_exactly_its_stale_periods_is_not_yet_stale():
    """64 Hz and 2 periods: 31.25 ms, exact in binary."""
    rig = dataclasses.replace(standard_rigs()[0], rate=64.0)
    core = SensorManagerCore(sensors_config([rig], 1, stale_periods=2.0))
    cto, rto = rig.observe(ee_path(0.0), np.random.default_rng(0), 0.0)
    core.offer("certus", "cto", cto, 0.0)
    core.offer("certus", "rto", rto, 0.0)
    assert core.evaluate(0.03125).health["certus"].ok
    assert core.evaluate(0.0313).health["certus"].cause == "stale"


@pytest.mark.parametrize("frozen", ["cto_silent", "rto_silent"])
def test_either_tool_frozen_makes_the_second_of_three_trackers_stale(frozen):
    rigs = standard_rigs()
    rigs.append(dataclasses.replace(rigs[1], name="vicra2"))
    world = World(rigs)
    world.run(0.5)
    world.faults["vicra"] = frozen
    health = world.run(0.2).health["vicra"]
    assert (health.cause, health.detail) == ("stale", "no new frame for 100 ms (limit 100 ms)")


def test_the_stale_verdict_says_the_age_and_the_limit_in_ms():
    rig = dataclasses.replace(standard_rigs()[0], rate=20.0)
    core = SensorManagerCore(sensors_config([rig], 1, stale_periods=20.0))
    cto, rto = rig.observe(ee_path(0.0), np.random.default_rng(0), 0.0)
    core.offer("certus", "cto", cto, 0.0)
    core.offer("certus", "rto", rto, 0.0)
    health = core.evaluate(1.0006).health["certus"]
    assert health.detail == "no new frame for 1001 ms (limit 1000 ms)"


def test_a_jumps_verdict_says_how_far_in_how_long():
    rig, core = single_certus()
    start = ee_path(0.0)
    offer(core, rig, start, 0.0, arrival=0.25)
    core.evaluate(0.251)
    offer(core, rig, shifted(start, 0.2), 0.05, arrival=0.3)  # 20 cm in 50 ms: 4 m/s
    health = core.evaluate(0.301).health["certus"]
    assert (health.cause, health.detail) == ("corrupt", "the robot's tool jumped 200.0 mm in 50 ms")


def test_the_second_tracker_places_the_robot_where_the_master_would():
    world = World()
    world.run(0.5)
    world.faults["certus"] = "cto_missing"
    decision = world.run(0.1)
    assert decision.best == "vicra"
    truth = world.rigs[0].rto_from_base @ ee_path(world.t)  # in the master's frame
    assert np.linalg.norm(decision.robot_pose[:3, 3] - truth[:3, 3]) < 0.002


def test_with_the_first_of_three_trackers_lost_the_other_two_are_compared():
    rigs = standard_rigs()
    rigs.append(dataclasses.replace(rigs[1], name="vicra2"))
    world = World(rigs)
    world.run(0.5)
    world.faults["certus"] = "cto_missing"
    decision = world.run(0.1)
    assert decision.best == "vicra"
    assert decision.health["vicra"].ok and decision.health["vicra2"].ok
    truth = rigs[0].rto_from_base @ ee_path(world.t)
    assert np.linalg.norm(decision.robot_pose[:3, 3] - truth[:3, 3]) < 0.002


def test_a_reference_tool_both_shifted_and_turned_is_a_calibration_fault():
    world = World(kinematics=True)
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.1))  # 2 cm and 5.7 deg
    world.faults["certus"] = "rto_moved"
    assert world.run(0.05).health["certus"].cause == "calibration"


def test_a_decision_says_whether_the_choice_changed():
    rig, core = single_certus()
    offer(core, rig, ee_path(0.0), 0.0, arrival=0.0)
    assert core.evaluate(0.001).changed, "none -> certus"
    offer(core, rig, ee_path(0.0), 0.01, arrival=0.01)
    assert not core.evaluate(0.011).changed


def test_after_a_fault_the_count_of_healthy_samples_starts_again_from_zero():
    rig, core = single_certus(hysteresis=3)
    offer(core, rig, ee_path(0.0), 0.0, arrival=0.0)
    for k in range(1, 4):
        offer(core, rig, ee_path(0.0), 0.01 * k, arrival=0.01 * k)
        core.evaluate(0.01 * k + 0.001)
    assert core.best == "certus"
    cto, rto = rig.observe(ee_path(0.0), np.random.default_rng(0), 0.04)
    core.offer("certus", "cto", dataclasses.replace(cto, valid=False), 0.04)
    core.offer("certus", "rto", rto, 0.04)
    assert core.evaluate(0.041).best is None
    seen = []
    for k in range(5, 9):
        offer(core, rig, ee_path(0.0), 0.01 * k, arrival=0.01 * k)
        seen.append(core.evaluate(0.01 * k + 0.001).best)
    assert seen == [None, None, "certus", "certus"], "three healthy samples again"


def test_a_tracker_with_its_own_reference_tool_maps_the_robot_into_the_masters_frame():
    rigs = standard_rigs()
    elsewhere = rigid((0.30, 0.25, -0.06), (0.0, 0.0, -0.4)) @ rigs[1].rto_from_base
    rigs[1] = dataclasses.replace(rigs[1], rto_from_base=elsewhere)  # its own tool, 40 cm off
    world = World(rigs)
    decision = world.run(0.5)
    assert decision.best == "certus" and decision.health["vicra"].ok, "they agree"
    world.faults["certus"] = "cto_missing"
    decision = world.run(0.1)
    assert decision.best == "vicra"
    truth = rigs[0].rto_from_base @ ee_path(world.t)  # in the master's (Certus') frame
    assert np.linalg.norm(decision.robot_pose[:3, 3] - truth[:3, 3]) < 0.002
    assert np.allclose(decision.robot_pose[:3, :3], truth[:3, :3], atol=1e-6)


@pytest.mark.parametrize(("bad", "trusted"), [(1, {"vicra", "vicra2", "vicra3"}), (2, set())])
def test_with_four_trackers_each_must_agree_with_at_least_half_of_the_others(bad, trusted):
    rigs = standard_rigs()
    rigs += [dataclasses.replace(rigs[1], name=n) for n in ("vicra2", "vicra3")]
    world = World(rigs)
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.faults.update({name: "rto_moved" for name in ["certus", "vicra"][:bad]})
    decision = world.run(0.1)
    assert {n for n, h in decision.health.items() if h.ok} == trusted
    assert all(h.cause == "calibration" for n, h in decision.health.items() if n not in trusted)


@pytest.mark.parametrize(
    ("moved", "detail"),
    [
        (rigid((0.06, 0.0, 0.0), (0.0, 0.0, 0.0)), "60.0 mm, 0.00 deg"),
        (rigid((0.0, 0.0, 0.0), (0.0, 0.0, math.pi)), "180.00 deg"),
    ],
)
def test_the_calibration_verdict_says_how_far_from_the_kinematics_and_how_much_turned(
    moved, detail
):
    rigs = [dataclasses.replace(r, noise=0.0) for r in standard_rigs()]
    world = World(rigs, kinematics=True)
    world.run(0.5)
    world.moved = moved
    world.faults["certus"] = "rto_moved"
    health = world.run(0.05).health["certus"]
    assert not health.ok and health.cause == "calibration"
    assert detail in health.detail and health.detail.endswith("away from the robot's kinematics")


def test_two_sensors_that_disagree_are_both_reported_not_ok():
    world = World()
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "rto_moved"
    health = world.run(0.1).health
    assert not health["certus"].ok and not health["vicra"].ok
    assert health["certus"].detail == "disagrees with vicra beyond tolerance"


def test_a_jumps_verdict_over_a_long_gap_says_its_duration_to_the_millisecond():
    rig, core = single_certus()
    start = ee_path(0.0)
    offer(core, rig, start, 0.0, arrival=0.25)
    core.evaluate(0.251)
    offer(core, rig, shifted(start, 1.0), 0.6, arrival=0.85)  # 1 m in 600 ms
    health = core.evaluate(0.851).health["certus"]
    assert (health.cause, health.detail) == (
        "corrupt",
        "the robot's tool jumped 1000.0 mm in 600 ms",
    )


# --- trackers calibrated to the robot (S): the reference tool is on the patient's head ---


def moved_head(world, dx):
    """The head (and the reference tools clamped to it) moved by `dx` m along the base x."""
    return rigid((dx, 0.0, 0.0), (0.0, 0.0, 0.0)) @ np.linalg.inv(world.rigs[0].rto_from_base)


@pytest.mark.parametrize(
    ("camera", "healthy"),
    [(True, True), (False, False)],
    ids=["calibrated to the robot: followed", "reference frame only: a calibration fault"],
)
def test_a_head_that_moves_the_reference_tools_is_a_fault_only_without_the_robot_calibration(
    camera, healthy
):
    world = World(kinematics=True, camera=camera)
    world.run(0.5)
    world.head = moved_head(world, 0.006)  # beyond the 5 mm tolerance
    decision = world.run(0.1)
    assert [h.ok for h in decision.health.values()] == [healthy, healthy], decision.health
    assert decision.best == ("certus" if healthy else None)


@pytest.mark.parametrize("slipped", ["certus", "vicra"])
@pytest.mark.parametrize(
    "slip", [(0.02, 0.0, 0.0), (-0.02, 0.0, 0.0), (0.0, 0.02, 0.0), (0.0, 0.0, -0.02)]
)
def test_a_reference_tool_that_slipped_on_the_head_clamp_is_found_among_two_trackers(slipped, slip):
    """Of two that disagree, the one further from where the calibration found the
    patient is blamed, whichever way its tool slipped."""
    world = World(kinematics=True, camera=True)
    world.head = moved_head(world, 0.003)  # the head moved too: that alone is no fault
    world.run(0.5)
    world.moved = rigid(slip, (0.0, 0.0, 0.0))
    world.faults[slipped] = "rto_moved"
    decision = world.run(0.1)
    other = "vicra" if slipped == "certus" else "certus"
    assert decision.health[slipped].cause == "calibration"
    said = re.match(
        rf"disagrees with {other} by ([0-9.]+) mm about where the patient is",
        decision.health[slipped].detail,
    )
    assert said and float(said[1]) == pytest.approx(20.0, abs=0.5), decision.health[slipped]
    assert decision.health[other].ok
    assert decision.best == other


def test_a_tracker_whose_reference_slipped_stays_distrusted_alone_until_its_calibration_is_redone():
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "rto_moved"
    assert world.run(0.1).best == "vicra"
    world.faults["vicra"] = "silent"  # the only witness falls silent
    decision = world.run(1.0)
    assert decision.health["vicra"].cause == "stale"
    assert decision.health["certus"].cause == "calibration", "no witness: still distrusted"
    assert decision.best is None
    assert world.core.trust("certus") is True and world.core.trust("certus") is False
    assert world.run(0.2).best == "certus"  # recalibrated: trusted after the hysteresis


def test_a_tracker_pushed_out_of_place_disagrees_with_the_kinematics_in_its_own_frame():
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.0, 0.01, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "sensor_moved"
    decision = world.run(0.1)
    assert decision.health["certus"].cause == "calibration"
    assert "10.0 mm" in decision.health["certus"].detail, decision.health["certus"].detail
    assert decision.best == "vicra"


def test_two_of_four_references_slipped_alike_lack_a_majority_and_so_do_the_others():
    """Each of four must agree with at least half of the three others about where the
    patient is: two slipped alike agree only with each other, the two good ones too;
    nobody has a majority, so only the steadiest (nearest the registration) is kept."""
    vicra = standard_rigs()[1]
    rigs = [*standard_rigs(), *(dataclasses.replace(vicra, name=f"vicra{i}") for i in (2, 3))]
    world = World(rigs, kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.0, 0.0, 0.01), (0.0, 0.0, 0.0))
    world.faults["vicra2"] = world.faults["vicra3"] = "rto_moved"
    decision = world.run(0.1)
    trusted = [n for n, h in decision.health.items() if h.ok]
    assert len(trusted) == 1 and trusted[0] in ("certus", "vicra"), decision.health
    assert {decision.health[n].cause for n in ("vicra2", "vicra3")} == {"calibration"}


@pytest.mark.parametrize(("odd_for", "latched"), [(0.075, False), (0.125, True)])
def test_a_slipped_reference_is_latched_once_odd_for_two_periods_of_the_slowest(odd_for, latched):
    """The Vicra's period is 50 ms: odd for 1.5 periods and back is a glitch, trusted
    again; odd for 2.5 periods stays distrusted until its calibration is redone."""
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "rto_moved"
    assert world.run(odd_for).health["certus"].cause == "calibration"
    del world.faults["certus"]
    decision = world.run(0.3)
    assert (decision.health["certus"].cause == "calibration") is latched, decision.health
    assert decision.best == ("vicra" if latched else "certus")


def test_three_trackers_calibrated_to_the_robot_outvote_the_one_whose_reference_slipped():
    rigs = [*standard_rigs(), dataclasses.replace(standard_rigs()[1], name="vicra2")]
    world = World(rigs, kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.0, 0.0, 0.01), (0.0, 0.0, 0.0))
    world.faults["vicra"] = "rto_moved"
    decision = world.run(0.1)
    assert [n for n, h in decision.health.items() if not h.ok] == ["vicra"]
    assert decision.best == "certus"


# --- the head moves while trackers at different rates watch it --------------------------


def bumped_head(world, start, offset, duration):
    """The head (and the reference tools) bumped by `offset` (m, base frame) from `start`
    along a cosine ramp of `duration` s (a knock on the table), as a function of time."""
    rest = np.linalg.inv(world.rigs[0].rto_from_base)

    def head_at(t):
        u = 0.0 if t <= start else min(1.0, (t - start) / duration) if duration else 1.0
        return (
            rigid(tuple(np.asarray(offset) * (0.5 - 0.5 * math.cos(math.pi * u))), (0, 0, 0)) @ rest
        )

    return head_at


BUMPS = [
    (offset, duration)
    for offset in [(0.005, 0, 0), (-0.005, 0, 0), (0, 0.005, 0), (0, -0.005, 0), (0, 0, 0.005)]
    for duration in (0.0, 0.05)
]


@pytest.mark.parametrize(("offset", "duration"), BUMPS)
@pytest.mark.parametrize("phase", [0.0, 0.013, 0.031, 0.049])
def test_a_bumped_head_is_no_calibration_fault_of_the_tracker_that_sees_it_first(
    offset, duration, phase
):
    """The Certus (100 Hz) sees a 5 mm bump up to 50 ms before the Vicra's next frame:
    the trackers' views of the patient are compared at one instant, so the head's
    motion is never taken for a reference tool that moved on one of them (before, the
    Certus was blamed: its newest frame against the Vicra's older one). Every cycle,
    in every direction, a step or a 50 ms ramp, whatever the phase of the frames."""
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.head_at = bumped_head(world, 0.5 + phase, offset, duration)
    world.keep = True
    world.run(0.4)
    faults = {(name, h.detail) for d in world.decisions for name, h in d.health.items() if not h.ok}
    assert faults == set()
    assert {d.best for d in world.decisions} == {"certus"}


@pytest.mark.parametrize("slipped", ["certus", "vicra"])
def test_a_reference_moved_on_one_tracker_only_is_found_within_two_periods_of_the_slowest(slipped):
    """A reference tool that slips on its mount is seen by its own tracker only: found at
    the first instant both trackers' samples show it, within two Vicra periods (100 ms),
    and latched at the second. The verdict carries its numbers."""
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.0, 0.008, 0.0), (0.0, 0.0, 0.0))
    world.faults[slipped] = "rto_moved"
    world.keep = True
    world.run(0.1)
    found = [d for d in world.decisions if not d.health[slipped].ok]
    assert found, "not found within two periods of the Vicra"
    health = found[0].health[slipped]
    assert health.cause == "calibration" and "about where the patient is" in health.detail
    numbers = health.numbers
    assert numbers["check"] == "patient" and 0.5 <= numbers["time"] <= 0.6
    assert f"at {numbers['time']:.3f} s): its reference tool moved" in health.detail
    assert set(numbers["patient_mm"]) == {"certus", "vicra"}
    assert numbers["apart_mm"] == pytest.approx(8.0, abs=0.5)
    assert 5.0 <= numbers["tolerance_mm"] < 6.0, "the head is still: the tolerance is the file's"
    del world.faults[slipped]
    assert world.run(0.3).health[slipped].cause == "calibration", "latched"


@pytest.mark.parametrize("slipped", ["certus", "vicra"])
def test_a_reference_moved_is_found_between_trackers_whose_frames_never_coincide(slipped):
    """Two trackers on their own clocks (the Vicra's frames 3 ms after the Certus's)
    are compared at the newest instant both reached, each interpolated there: a slipped
    reference is found and latched as with frames that coincide."""
    world = World(kinematics=True, camera=True)
    world.phase["vicra"] = 0.003
    world.run(0.5)
    assert all(h.ok for h in world.run(0.1).health.values())
    world.moved = rigid((0.0, 0.008, 0.0), (0.0, 0.0, 0.0))
    world.faults[slipped] = "rto_moved"
    health = world.run(0.15).health[slipped]
    assert health.cause == "calibration" and "about where the patient is" in health.detail
    del world.faults[slipped]
    assert world.run(0.3).health[slipped].cause == "calibration", "latched"


def test_two_trackers_agree_about_the_patient_within_the_larger_of_their_tolerances():
    """The Vicra's file allows 12 mm, the Certus's 5: references 8 mm apart agree (the
    coarser tracker cannot be asked for the finer one's precision)."""
    world = World(kinematics=True, camera=True)
    world.core.config.sensors[1].tolerance_position = 0.012
    world.core = SensorManagerCore(world.core.config)
    world.run(0.5)
    world.moved = rigid((0.0, 0.008, 0.0), (0.0, 0.0, 0.0))
    world.faults["vicra"] = "rto_moved"
    health = world.run(0.3).health
    assert health["vicra"].ok and health["certus"].ok, health


def test_a_sensor_trusted_again_with_its_reference_back_in_place_is_healthy_at_once():
    """The reference tool put back and the sensor trusted again: its next cycle is
    healthy, not faulted by the verdict of the comparison before the trust."""
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.0, 0.008, 0.0), (0.0, 0.0, 0.0))
    world.faults["vicra"] = "rto_moved"
    assert world.run(0.2).health["vicra"].cause == "calibration"
    del world.faults["vicra"]
    assert world.core.trust("vicra") is True
    assert world.run(0.001).health["vicra"].ok


@pytest.mark.parametrize(("vicra_deg", "ok"), [(3.0, False), (10.0, True)])
def test_a_reference_that_turned_on_its_mount_is_found_by_the_larger_angle_tolerance(vicra_deg, ok):
    """A reference tool turned 6 degrees on its mount, not moved: the trackers disagree
    about the patient's orientation beyond 3 degrees, not beyond the Vicra's 10 (two
    agree within the larger of their tolerances). Positions are set out of the way."""
    world = World(kinematics=True, camera=True, tolerance_position=1.0)
    world.core.config.sensors[1].tolerance_angle = math.radians(vicra_deg)
    world.core = SensorManagerCore(world.core.config)
    world.run(0.5)
    world.moved = rigid((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(6.0)))
    world.faults["vicra"] = "rto_moved"
    health = world.run(0.3).health["vicra"]
    assert health.ok is ok, health
    if not ok:
        assert "about where the patient is" in health.detail


def test_a_verdict_against_the_kinematics_carries_its_numbers():
    world = World(kinematics=True, camera=True)
    world.run(0.5)
    world.moved = rigid((0.0, 0.01, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "sensor_moved"
    numbers = world.run(0.1).health["certus"].numbers
    assert numbers["check"] == "kinematics" and numbers["time"] <= world.t
    assert numbers["apart_mm"] == pytest.approx(10.0, abs=0.5)
    assert numbers["tolerance_mm"] == 5.0
    apart = np.linalg.norm(np.subtract(numbers["measured_mm"], numbers["predicted_mm"]))
    assert apart == pytest.approx(numbers["apart_mm"], abs=0.01)


def test_the_trackers_offset_is_their_calibrations_difference_not_the_heads_motion():
    """What a swap must carry: the Vicra's view of the end-effector on the patient against
    the Certus's, at one instant, averaged. Its calibration errs by 2 mm: the offset is
    those 2 mm, and a bump of the head while the robot moves changes it by far less
    than the bump (the views are compared at one instant)."""
    rigs = standard_rigs()
    world = World(rigs, kinematics=True, camera=True)
    vicra = world.core.config.sensors[1]
    vicra.master_from_sensor = rigid((0.002, 0.0, 0.0), (0, 0, 0)) @ vicra.master_from_sensor
    world.core = SensorManagerCore(world.core.config)
    world.run(3.0)
    before = world.core.offsets()["vicra"][:3, 3].copy()
    assert before == pytest.approx([0.002, 0.0, 0.0], abs=3e-4)
    world.head_at = bumped_head(world, world.t, (0.005, 0.0, 0.0), 0.05)
    for _ in range(20):
        world.run(0.025)
        shift = np.linalg.norm(world.core.offsets()["vicra"][:3, 3] - before)
        assert shift < 3e-4, "the bump leaks into the offset"
    assert world.core.offsets()["certus"] == pytest.approx(np.eye(4))


def offsets_over(seconds, core, rigs, vicra_off, start=0.0, rng=None, vicra_turn=None):
    """The Certus at 100 Hz from t = 0, the Vicra at 20 Hz 3 ms later (their frames
    never share a stamp, as two trackers' clocks do not), the Vicra seeing the tool
    `vicra_off(t)` m off along x (a calibration difference); `core` evaluated at 1 kHz."""
    rng = rng or np.random.default_rng(3)
    certus, vicra = rigs
    for tick in range(round(start * 1000), round((start + seconds) * 1000)):
        t = tick / 1000
        truth = ee_path(t)
        if tick % 10 == 0:
            for tool, pose in zip(("cto", "rto"), certus.observe(truth, rng, t), strict=True):
                core.offer("certus", tool, pose, t)
        if tick % 50 == 3:
            turned = rigid((0.0, 0.0, 0.0), (0.0, 0.0, vicra_turn(t) if vicra_turn else 0.0))
            seen = vicra.observe(shifted(truth, vicra_off(t)) @ turned, rng, t)
            for tool, pose in zip(("cto", "rto"), seen, strict=True):
                core.offer("vicra", tool, pose, t)
        core.evaluate(t + 0.0005)


def test_the_offset_is_measured_between_trackers_whose_frames_never_coincide():
    """The trackers' views are compared at an instant both reached (each interpolated
    there), so two trackers on their own clocks are compared at all; and the offset
    follows a calibration difference that changes (averaged over about a second)."""
    rigs = standard_rigs()
    core = SensorManagerCore(sensors_config(rigs, 1))
    offsets_over(2.0, core, rigs, lambda t: 0.002)
    # the tool seen off along the base's x: in the master's frame, as far but turned
    assert np.linalg.norm(core.offsets()["vicra"][:3, 3]) == pytest.approx(0.002, abs=3e-4)
    offsets_over(4.0, core, rigs, lambda t: 0.005, start=2.0)
    assert np.linalg.norm(core.offsets()["vicra"][:3, 3]) == pytest.approx(0.005, abs=3e-4)


def test_the_offset_follows_a_turn_between_the_trackers_views():
    """The offset's rotation is averaged too: a Vicra view turned 1 degree, then 2."""
    from components.domain.geometry import rotation_angle

    rigs = standard_rigs()
    core = SensorManagerCore(sensors_config(rigs, 1))
    one, two = math.radians(1.0), math.radians(2.0)
    offsets_over(2.0, core, rigs, lambda t: 0.0, vicra_turn=lambda t: one)
    assert rotation_angle(core.offsets()["vicra"][:3, :3]) == pytest.approx(one, abs=1e-3)
    offsets_over(4.0, core, rigs, lambda t: 0.0, start=2.0, vicra_turn=lambda t: two)
    assert rotation_angle(core.offsets()["vicra"][:3, :3]) == pytest.approx(two, abs=1e-3)


def test_the_offset_is_not_measured_against_a_master_found_faulty():
    """A swap carries the trackers' difference as measured while both were trusted:
    once the Certus (the master) is found faulty, the Vicra's offset keeps its last
    value instead of soaking up the Certus's error."""
    world = World(kinematics=True)
    world.run(2.0)
    before = world.core.offsets()["vicra"][:3, 3].copy()
    world.moved = rigid((0.02, 0.0, 0.0), (0.0, 0.0, 0.0))
    world.faults["certus"] = "rto_moved"
    decision = world.run(1.0)
    assert decision.health["certus"].cause == "calibration" and decision.health["vicra"].ok
    assert world.core.offsets()["vicra"][:3, 3] == pytest.approx(before, abs=1e-6)


def test_the_check_lag_counts_from_the_last_sample_that_could_be_checked():
    """A sample without a robot pose of its time keeps the sensor's verdict for
    `CHECK_LAG_LIMIT` counted from the last sample that was checked: unchecked at 1.0
    s, checked at 1.3 s, unchecked at 1.6 s is 0.3 s without a check, no fault."""
    rig, core = single_certus()
    step = 1 / 256

    def poses_from(start, count):
        for i in range(count):
            core.set_kinematics(ee_path(0.0), stamp=start + i * step)

    poses_from(10.0, 4)
    poses_from(10.2, 4)  # a pause of the robot's poses between 10.012 and 10.2
    offer(core, rig, ee_path(0.0), 10.1, arrival=1.0)
    assert core.evaluate(1.0).health["certus"].ok and core.unchecked == 1
    offer(core, rig, ee_path(0.0), 10.2, arrival=1.3)
    assert core.evaluate(1.3).health["certus"].ok and core.unchecked == 1
    poses_from(10.5, 4)
    offer(core, rig, ee_path(0.0), 10.4, arrival=1.6)
    health = core.evaluate(1.6).health["certus"]
    assert health.ok and core.unchecked == 2, health
    for now in (1.601, 1.605, 1.61):
        assert core.evaluate(now).health["certus"].ok
    assert core.unchecked == 2, "a sample is counted once, not every cycle it waits"


def test_a_new_sample_of_one_tracker_is_judged_as_its_own_while_the_other_has_none():
    """With the robot's poses kept, a sample already judged against the same pose is not
    judged again; the ones that are new are judged each as their own tracker's: the
    Vicra's new sample 10 mm off is the Vicra's fault, the Certus keeps its verdict,
    and evaluating again without news changes nothing."""
    rigs = standard_rigs()
    core = SensorManagerCore(sensors_config(rigs, 1))
    for i in range(8):
        core.set_kinematics(ee_path(0.0), stamp=10.0 + i / 256)
    for rig in rigs:
        offer(core, rig, ee_path(0.0), 10.01, arrival=1.0)
    assert all(h.ok for h in core.evaluate(1.001).health.values())
    offer(core, rigs[1], shifted(ee_path(0.0), 0.01), 10.02, arrival=1.002)
    for now in (1.003, 1.004):
        health = core.evaluate(now).health
        assert health["vicra"].cause == "calibration" and health["certus"].ok, health
    offer(core, rigs[1], ee_path(0.0), 10.025, arrival=1.005)  # right again
    health = core.evaluate(1.006).health
    assert health["vicra"].ok and health["certus"].ok, health
