"""Spec: the Sensor Manager detects every fault-tree leaf with the right cause and always
chooses the highest-priority healthy sensor (after hysteresis)."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.tracking.sensor_manager import (
    SensorConfigError,
    SensorManagerCore,
    load_sensors,
)
from components.tracking.synthetic import ee_path, rigid, sensors_config, standard_rigs

TICK = 0.001  # the Sensor Manager's 1 kHz cycle


class World:
    """Trackers streaming at their rates into a Sensor Manager, on a simulated clock."""

    def __init__(self, rigs=None, hysteresis=3, kinematics=False, **overrides):
        self.rigs = rigs or standard_rigs()
        self.core = SensorManagerCore(sensors_config(self.rigs, hysteresis, **overrides))
        self.rng = np.random.default_rng(7)
        self.t = 0.0
        self.faults: dict[str, str] = {}
        self.kinematics = kinematics
        self.moved = np.eye(4)
        self.frames = {r.name: 0 for r in self.rigs}

    def run(self, seconds):
        decision = None
        for _ in range(round(seconds / TICK)):
            self.t += TICK
            truth = ee_path(self.t)
            for rig in self.rigs:
                period = 1.0 / rig.rate
                frame = int(self.t / period + 1e-9)
                if frame == self.frames[rig.name]:
                    continue
                self.frames[rig.name] = frame
                self._sample(rig, truth)
            if self.kinematics:
                self.core.set_kinematics(truth)
            decision = self.core.evaluate(self.t)
        return decision

    def _sample(self, rig, truth):
        fault = self.faults.get(rig.name, "")
        if fault == "silent":
            return
        cto, rto = rig.observe(truth, self.rng, self.t)
        if fault == "rto_moved":  # someone bumped the reference tool: only it moved
            bumped = dataclasses.replace(rig, sensor_from_rto=rig.sensor_from_rto @ self.moved)
            _, rto = bumped.observe(truth, self.rng, self.t)
        if fault == "cto_missing":
            cto = dataclasses.replace(cto, valid=False)
        if fault == "rto_missing":
            rto = dataclasses.replace(rto, valid=False)
        if fault == "nan":
            cto = dataclasses.replace(cto, position=(math.nan, 0.0, 0.0))
        if fault == "jump" and self.frames[rig.name] % 2:  # a flickering, impossible track
            cto = dataclasses.replace(cto, position=tuple(v + 0.05 for v in cto.position))
        self.core.offer(rig.name, "cto", cto, self.t)
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
          certus: {priority: 1, rate: 100, keys: {cto: certus/cto, rto: certus/rto},
                   limits: {max_velocity: 0.1, max_acceleration: 0.5}}
          vicra: {priority: 2, rate: 20, keys: {cto: vicra/cto, rto: vicra/rto},
                  calibration: {C: {position: [0.1, 0, 0], quaternion: [1, 0, 0, 0]}}}
        """,
        "sensors.yaml",
    )
    config = load_sensors(good)
    assert [s.name for s in config.sensors] == ["certus", "vicra"]
    assert config.sensors[1].master_from_sensor[0, 3] == 0.1
    cases = [
        ("sensors: {a: {priority: 1, rate: 100}}", "'keys' is required"),
        ("sensors: {a: {priority: 1, rate: 0, keys: {cto: x, rto: y}}}", "more than 0"),
        ("sensors: {a: {priority: 1, rate: 5, keys: {cto: x}}}", "'rto' is required"),
        (
            "sensors: {a: {priority: 1, rate: 5, keys: {cto: x, rto: y}, "
            "calibration: {X: {quaternion: [0, 0, 0, 0]}}}}",
            "unit length",
        ),
        (
            "sensors: {a: {priority: 1, rate: 5, keys: {cto: x, rto: y}, "
            "calibration: {X: {quaternion: }}}}",
            "expected a list",
        ),
        ("sensors: {a: {priority: 1, rate: .nan, keys: {cto: x, rto: y}}}", "finite"),
        (
            "sensors: {a: {priority: 1, rate: 5, keys: {cto: x, rto: y}, "
            "calibration: {C: [[1, 0], [0, 1]]}}}",
            "needs at least 4 items",
        ),
        (
            "sensors: {a: {priority: 1, rate: 5, keys: {cto: x, rto: y}}, "
            "b: {priority: 1, rate: 5, keys: {cto: x, rto: y}}}",
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
    from components.tracking.sensor_manager import SensorManagerCore
    from components.tracking.synthetic import ee_path, sensors_config, standard_rigs

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
