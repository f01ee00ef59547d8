"""Spec: the Supervisor turns measurements into the SEEG chart's events (thesis 3.5.3)."""

import math

import pytest

from components.supervisor.procedure import load_procedure
from components.supervisor.supervisor import SupervisorCore
from framework.errors import FwError
from tests.conftest import REPO

PROCEDURE = load_procedure(REPO / "procedures" / "seeg.yaml")
TARGET = tuple(PROCEDURE.target[:3, 3])
FAR = (TARGET[0], TARGET[1], TARGET[2] + 0.25)
HEALTHY = {"certus": {"ok": True, "cause": ""}, "vicra": {"ok": True, "cause": ""}}


def names(events):
    return [name for name, _ in events]


def core(**kwargs) -> SupervisorCore:
    c = SupervisorCore(PROCEDURE, **kwargs)
    c.tracking("certus", HEALTHY)
    return c


def test_entering_and_leaving_the_critical_sphere_raise_area_events_once():
    c = core()
    assert names(c.observe(tcp=FAR)) == ["e_SAFE_AREA"]
    assert c.observe(tcp=FAR) == [], "no repeat while nothing changes"
    inside = (TARGET[0], TARGET[1], TARGET[2] + PROCEDURE.critical_radius * 0.9)
    assert names(c.observe(tcp=inside)) == ["e_CRITICAL_AREA"]
    assert names(c.observe(tcp=FAR)) == ["e_SAFE_AREA"]


def test_too_many_people_near_the_table_is_critical_even_far_from_the_target():
    c = core()
    c.observe(tcp=FAR)
    events = c.observe(users_near=PROCEDURE.max_near + 1)
    assert names(events) == ["e_CRITICAL_AREA"] and events[0][1]["why"] == "crowded"
    assert names(c.observe(users_near=PROCEDURE.max_near)) == ["e_SAFE_AREA"]


def test_a_possible_collision_stops_once_and_again_when_motion_restarts():
    c = core()
    c.observe(tcp=FAR)
    close = PROCEDURE.collision_distance * 0.5
    events = c.observe(min_distance=close)
    assert names(events) == ["e_STOP"] and "possible collision" in events[0][1]["reason"]
    assert c.observe(min_distance=close) == [], "edge-triggered"
    assert names(c.motion("moving", "target")) == ["e_STOP"], "moving while still too close"
    c.observe(min_distance=1.0)
    assert c.motion("stopped", "") == [] and c.motion("moving", "target") == []


def test_losing_the_tracker_in_use_is_a_fault_and_losing_all_is_no_tracker():
    c = core()
    c.use_tracker("certus")
    sick = {"certus": {"ok": False, "cause": "cto_missing"}, "vicra": {"ok": True}}
    assert c.tracking("vicra", sick) == [
        ("e_TFAULT", {"tracker": "vicra", "failed": "certus", "fault": "cto_missing"})
    ]
    assert c.tracking("vicra", sick) == [], "reported once; the chart reselects"
    assert c.report_best_tracker() == ("e_TOK", {"tracker": "vicra"})
    c.use_tracker("vicra")
    assert c.tracking(None, {}) == [("e_NOTRACKER", {})]
    assert c.report_best_tracker() == ("e_NOTRACKER", {})


def test_a_better_tracker_coming_back_is_reported_as_a_swap():
    c = core()
    c.tracking("vicra", {"certus": {"ok": False, "cause": "stale"}})
    c.use_tracker("vicra")
    events = c.tracking("certus", HEALTHY)
    assert names(events) == ["e_TFAULT"] and events[0][1]["fault"] == "certus is better"


def test_the_goal_is_reached_when_the_interpolator_is_done_and_the_tcp_is_there():
    c = core()
    c.observe(tcp=FAR)
    assert c.motion("moving", "target") == []
    assert c.motion("reached", "target") == [], "the measured TCP is still far away"
    near = (TARGET[0], TARGET[1], TARGET[2] + PROCEDURE.target_tolerance / 2)
    assert [e for e in c.observe(tcp=near) if e[0] == "e_TARGET"] == [
        ("e_TARGET", {"goal": "target"})
    ]
    assert not [e for e in c.observe(tcp=TARGET) if e[0] == "e_TARGET"], "reported once"


def test_a_safety_stop_the_robot_latched_by_itself_stops_the_task_once():
    c = core()
    assert c.robot(braked=True, fault=False, reason="stop") == [], "asked for: no event"
    events = c.robot(braked=False, fault=True, reason="supervisor: no data for 61 ms")
    assert names(events) == ["e_STOP"], "already while the protective stop decelerates"
    assert "supervisor: no data" in events[0][1]["reason"]
    assert c.robot(braked=True, fault=True, reason="supervisor: no data for 61 ms") == []
    assert c.robot(braked=False, fault=False, reason="") == []
    again = c.robot(braked=True, fault=True, reason="the arm braked by itself: watchdog")
    assert names(again) == ["e_STOP"], "a new fault after the first was cleared"


def test_limits_follow_the_tracker_in_use_and_the_area():
    c = core()
    c.use_tracker("certus")
    assert c.limits("fast")["velocity"] == 0.075 and c.limits("slow")["velocity"] == 0.010
    c.use_tracker("vicra")
    assert c.limits("fast")["velocity"] == 0.050
    with pytest.raises(FwError, match="fast' or 'slow"):
        c.limits("warp")
    with pytest.raises(FwError, match="no speeds"):
        c.use_tracker("kinect")


def test_without_a_tracker_in_use_the_slowest_speed_is_used():
    c = SupervisorCore(PROCEDURE)
    assert c.limits("fast")["velocity"] == min(s.slow for s in PROCEDURE.speeds.values())
    assert math.isinf(c.min_distance)


def test_the_sensor_managers_limits_cap_the_procedures_speeds():
    c = SupervisorCore(PROCEDURE)
    c.tracking("vicra", HEALTHY, {"max_velocity": 0.03, "max_acceleration": 0.1})
    c.use_tracker("vicra")
    assert c.limits("fast") == {"velocity": 0.03, "acceleration": 0.1}, "capped"
    assert c.limits("slow")["velocity"] == 0.010, "below the cap: the procedure's speed"
