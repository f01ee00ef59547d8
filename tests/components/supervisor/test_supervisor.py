"""Spec: the Supervisor turns measurements into the SEEG chart's events (thesis 3.5.3)."""

import json
import math

import pytest

from components.domain.procedure import load_procedure
from components.supervisor.supervisor import SupervisorCore, _decision_problem, untracked
from framework.errors import FwError
from tests.conftest import REPO

PROCEDURE = load_procedure(REPO / "procedures" / "seeg.yaml")
TARGET = (0.60, 0.0, 0.12)  # where the navigator says the target on the patient is
HOME = (0.54, 0.0, 0.37)
GOALS = {"target": TARGET, "home": HOME}
FAR = (TARGET[0], TARGET[1], TARGET[2] + 0.25)
HEALTHY = {"certus": {"ok": True, "cause": ""}, "vicra": {"ok": True, "cause": ""}}


def names(events):
    return [name for name, _ in events]


def core(**kwargs) -> SupervisorCore:
    c = SupervisorCore(PROCEDURE, **kwargs)
    c.tracking("certus", HEALTHY)
    c.navigation(None, GOALS)  # where the goals are, before any tracker steers
    return c


def steer(c: SupervisorCore, tracker: str):
    """The navigator's samples now come from `tracker` (the chart connected it)."""
    return c.navigation(tracker, GOALS)


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
    steer(c, "certus")
    sick = {"certus": {"ok": False, "cause": "cto_missing"}, "vicra": {"ok": True}}
    assert c.tracking("vicra", sick) == [
        (
            "e_TFAULT",
            {
                "tracker": "vicra",
                "failed": "certus",
                "fault": "cto_missing",
                "detail": "",
                "numbers": {},
            },
        )
    ]
    assert c.tracking("vicra", sick) == [], "reported once; the chart reselects"
    assert c.report_best_tracker() == ("e_TOK", {"tracker": "vicra"})
    steer(c, "vicra")
    assert c.tracking(None, {}) == [("e_NOTRACKER", {"why": "the Sensor Manager has not said"})]
    assert c.report_best_tracker() == ("e_NOTRACKER", {"why": "the Sensor Manager has not said"})
    assert c.in_use is None, "no tracker is in use once none is left"
    assert c.limits("fast")["velocity"] == PROCEDURE.slowest


def test_a_tracker_failing_right_after_the_swap_to_it_is_reported_at_once():
    """Between e_TFAULT and the new tracker's first sample at the navigator, a verdict
    against the new tracker is not lost (it used to wait for the next status, 0.5 s)."""
    c = core()
    steer(c, "certus")
    sick = {"certus": {"ok": False, "cause": "cto_missing"}, "vicra": {"ok": True}}
    assert names(c.tracking("vicra", sick)) == ["e_TFAULT"]
    assert c.tracking(None, {}) == [("e_NOTRACKER", {"why": "the Sensor Manager has not said"})], (
        "the Vicra failed before it steered"
    )
    c = core()
    steer(c, "vicra")
    assert names(c.tracking("certus", HEALTHY)) == ["e_TFAULT"]  # back to the Certus...
    events = c.tracking("vicra", sick)  # ...which fails before its first sample steers
    assert events == [
        (
            "e_TFAULT",
            {
                "tracker": "vicra",
                "failed": "certus",
                "fault": "cto_missing",
                "detail": "",
                "numbers": {},
            },
        )
    ]
    assert c.limits("fast")["velocity"] == PROCEDURE.slowest, "no tracker steers yet"
    steer(c, "vicra")
    assert c.in_use == "vicra" and c.tracking("vicra", sick) == []


def test_a_tracker_failing_after_e_tok_and_before_its_first_sample_steers_is_no_tracker():
    """After No_Tracker and RELEASE the chart asks for the best tracker and connects the
    one e_TOK names; if it fails before its first sample reaches the navigator, the robot
    would move with no tracker and nobody saying so (found by the bench)."""
    c = core()
    steer(c, "certus")
    assert c.tracking(None, {}) == [("e_NOTRACKER", {"why": "the Sensor Manager has not said"})]
    c.navigation(None, {})  # its samples stopped
    assert c.tracking("certus", HEALTHY) == [], "no tracker in use: nothing to swap"
    assert c.report_best_tracker() == ("e_TOK", {"tracker": "certus"})
    assert c.tracking(None, {"certus": {"ok": False, "cause": "cto_missing"}}) == [
        ("e_NOTRACKER", {"why": "certus: cto_missing"})
    ]
    c = core()
    steer(c, "certus")
    assert c.report_best_tracker() == ("e_TOK", {"tracker": "certus"})
    assert c.tracking("certus", HEALTHY) == [], "the tracker in use, still in use"


def test_a_better_tracker_coming_back_is_reported_as_a_swap():
    c = core()
    c.tracking("vicra", {"certus": {"ok": False, "cause": "stale"}})
    steer(c, "vicra")
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


def test_the_same_robot_fault_again_after_it_cleared_stops_the_task_again():
    """A fault the operator cleared (RELEASE) that comes back, for the same reason (the
    same input silent again), is a new stop, not a repeat of the old one."""
    c = core()
    assert names(c.robot(braked=True, fault=True, reason="envelopes: no data")) == ["e_STOP"]
    assert c.robot(braked=True, fault=False, reason="") == []
    assert names(c.robot(braked=True, fault=True, reason="envelopes: no data")) == ["e_STOP"]


def test_the_speed_limit_is_the_cap_of_the_tracker_that_steers_not_the_best_one():
    """Until the chart swaps, the navigator follows the tracker it connected: that
    tracker's cap holds, whatever the Sensor Manager now calls best (its cap may be
    far higher: a limit meant for the Vicra must not speed up a motion the Certus
    steers)."""
    c = SupervisorCore(PROCEDURE)
    c.tracking("certus", HEALTHY, {"max_velocity": 0.002, "max_acceleration": 0.1})
    c.tracking("vicra", HEALTHY, {"max_velocity": 0.2, "max_acceleration": 0.5})
    steer(c, "certus")
    assert (c.in_use, c.best) == ("certus", "vicra")
    assert c.limits("fast") == {"velocity": 0.002, "acceleration": 0.1}


def test_limits_follow_the_tracker_in_use_and_the_area():
    c = core()
    steer(c, "certus")
    assert c.limits("fast")["velocity"] == 0.075 and c.limits("slow")["velocity"] == 0.010
    steer(c, "vicra")
    assert c.limits("fast")["velocity"] == 0.050
    with pytest.raises(FwError, match="fast' or 'slow"):
        c.limits("warp")
    steer(c, "kinect")  # a tracker the procedure gives no speeds: the slowest
    assert c.limits("fast")["velocity"] == 0.010


def test_without_a_tracker_in_use_the_slowest_speed_is_used():
    c = SupervisorCore(PROCEDURE)
    assert c.limits("fast")["velocity"] == min(s.slow for s in PROCEDURE.speeds.values())
    assert math.isinf(c.min_distance)


def test_the_sensor_managers_limits_cap_the_procedures_speeds():
    c = SupervisorCore(PROCEDURE)
    c.tracking("vicra", HEALTHY, {"max_velocity": 0.03, "max_acceleration": 0.1})
    steer(c, "vicra")
    assert c.limits("fast") == {"velocity": 0.03, "acceleration": 0.1}, "capped"
    assert c.limits("slow")["velocity"] == 0.010, "below the cap: the procedure's speed"


# --- boundaries, phases and the wire ------------------------------------------------------
# Names arrive decoded from the bus, so the Supervisor must compare them by value: `wire`
# gives a string as a message would carry it (equal to the literal, not the same object).


def wire(text: str) -> str:
    return json.loads(json.dumps(text))


def at_origin() -> SupervisorCore:
    """A Supervisor whose target is the base frame's origin, so distances along an axis
    are exact and the limits can be probed on the dot."""
    procedure = load_procedure(REPO / "procedures" / "seeg.yaml")
    procedure.define_target((0.0, 0.0, 0.0), (0, 180, 0))
    return SupervisorCore(procedure)


def test_a_person_already_too_close_at_the_first_measurement_stops():
    c = core()
    assert names(c.observe(min_distance=PROCEDURE.collision_distance / 2)) == ["e_STOP"]


def test_a_person_exactly_at_the_collision_distance_is_not_yet_a_collision():
    c = core()
    assert c.observe(min_distance=PROCEDURE.collision_distance) == []
    assert names(c.observe(min_distance=PROCEDURE.collision_distance * 0.999)) == ["e_STOP"]


def test_the_collision_reason_says_the_distance_and_the_limit_in_cm(write):
    c = core()
    ((_, payload),) = c.observe(min_distance=0.09)
    assert payload["reason"] == "possible collision: robot 9.0 cm from a person (limit 10 cm)"
    text = (REPO / "procedures" / "seeg.yaml").read_text(encoding="utf-8")
    text = text.replace("collision_distance: 0.10", "collision_distance: 0.70")
    wide = SupervisorCore(load_procedure(write(text, "seeg.yaml")))
    ((_, payload),) = wide.observe(min_distance=0.655)
    assert payload["reason"] == "possible collision: robot 65.5 cm from a person (limit 70 cm)"


def test_only_the_start_of_a_motion_during_a_collision_stops_again():
    c = core()
    c.observe(min_distance=PROCEDURE.collision_distance / 2)
    for phase in ("stopping", "stopped", "idle", "reached", "returning"):
        assert c.motion(wire(phase), "target") == [], phase
    assert names(c.motion(wire("moving"), "target")) == ["e_STOP"]
    assert c.motion(wire("moving"), "target") == [], "a repeated 'moving' is the same motion"
    assert c.motion(wire("returning"), "home") == []
    assert names(c.motion(wire("moving"), "home")) == ["e_STOP"], "moving after returning"


def test_passing_through_the_goal_or_stopping_at_it_is_not_reaching_it():
    c = at_origin()
    c.observe(tcp=(0.0, 0.0, 0.2))
    for phase in ("moving", "stopping", "stopped", "returning", "idle"):
        events = c.motion(wire(phase), wire("target")) + c.observe(tcp=(0.0, 0.0, 0.0))
        assert "e_TARGET" not in names(events), phase
    events = c.motion(wire("reached"), wire("somewhere")) + c.observe(tcp=(0.0, 0.0, 0.0))
    assert "e_TARGET" not in names(events), "no such goal"
    assert ("e_TARGET", {"goal": "target"}) in c.motion(wire("reached"), wire("target"))


def test_the_tcp_exactly_at_the_target_tolerance_has_arrived():
    c = at_origin()
    tolerance = c.procedure.target_tolerance
    c.observe(tcp=(0.0, 0.0, 0.2))
    c.motion("reached", "target")
    assert not [e for e in c.observe(tcp=(0.0, 0.0, tolerance * 1.001)) if e[0] == "e_TARGET"]
    assert [e for e in c.observe(tcp=(0.0, 0.0, tolerance)) if e[0] == "e_TARGET"]


def test_the_critical_sphere_is_open_at_its_radius_and_events_carry_the_distance():
    c = at_origin()
    radius = c.procedure.critical_radius
    assert c.observe(tcp=(0.0, 0.0, radius)) == [("e_SAFE_AREA", {"distance": radius})]
    events = c.observe(tcp=(0.0, 0.0, 0.0123456))
    assert events == [
        ("e_CRITICAL_AREA", {"distance": 0.0123, "users_near": 0, "why": "near the target"})
    ]
    assert c.area == "critical"
    assert c.observe(tcp=(0.0, 0.0, 0.0456789)) == [], "still inside"
    assert c.observe(tcp=(0.0, 0.0, 0.1234567)) == [("e_SAFE_AREA", {"distance": 0.1235})]
    assert c.area == "safe"


def test_a_different_robot_fault_while_the_first_holds_stops_again():
    c = core()
    assert names(c.robot(True, True, wire("the arm braked by itself: watchdog"))) == ["e_STOP"]
    assert c.robot(True, True, wire("the arm braked by itself: watchdog")) == [], "same fault"
    assert names(c.robot(True, True, wire("a monitor tripped"))) == ["e_STOP"], "a new one"


def test_the_tracker_in_use_reported_best_again_is_no_fault():
    c = core()
    steer(c, "certus")
    assert c.tracking(wire("certus"), HEALTHY) == []


def test_speeds_are_chosen_by_name_as_they_arrive_from_the_chart():
    c = core()
    steer(c, wire("certus"))
    assert c.limits(wire("fast"))["velocity"] == 0.075
    assert c.limits(wire("slow"))["velocity"] == 0.010


def test_without_a_tracker_in_use_the_slowest_slow_speed_of_any_tracker_is_used(write):
    text = (REPO / "procedures" / "seeg.yaml").read_text(encoding="utf-8")
    text = text.replace("vicra: {fast: 0.050, slow: 0.010}", "vicra: {fast: 0.050, slow: 0.004}")
    c = SupervisorCore(load_procedure(write(text, "seeg.yaml")))
    assert c.limits("fast")["velocity"] == c.limits("slow")["velocity"] == 0.004
    c.tracking("certus", HEALTHY)
    steer(c, "certus")
    assert c.limits("slow")["velocity"] == 0.010


@pytest.mark.parametrize(
    "payload, problem",
    [
        ({"best": "c"}, ""),
        ({"best": "c" * 64}, ""),
        ({"best": None, "health": {}}, ""),
        ({"best": "certus", "limits": {"max_velocity": 1e-6}}, ""),
        ({"best": ""}, "best sensor '' is not a sensor name"),
        ({"best": "c" * 65}, f"best sensor {'c' * 40!r} is not a sensor name"),
        ({"best": "certus", "limits": [0.1]}, "limits are not a table"),
        ({"best": "certus", "limits": {"v": 0}}, "limit 'v' = 0 is not a positive number"),
        ({"best": "certus", "limits": {"v": -0.5}}, "limit 'v' = -0.5 is not a positive number"),
        (
            {"best": "certus", "limits": {"n" * 50: "x" * 50}},
            f"limit {'n' * 40!r} = {'x' * 40} is not a positive number",
        ),
    ],
)
def test_a_sensor_manager_decision_is_believed_only_when_it_makes_sense(payload, problem):
    assert _decision_problem(payload) == problem


# --- the navigator's news: who steers, where the goals are, a refused patient motion -----


def test_the_tracker_in_use_is_the_one_whose_samples_steer_the_navigator():
    c = SupervisorCore(PROCEDURE)
    c.tracking("certus", HEALTHY)
    assert c.in_use is None
    steer(c, "certus")
    assert c.in_use == "certus"
    sick = {"certus": {"ok": False, "cause": "stale"}, "vicra": {"ok": True}}
    assert names(c.tracking("vicra", sick)) == ["e_TFAULT"]
    steer(c, "certus")  # its last samples, before the swap: still no tracker in use
    assert c.in_use is None and c.tracking("vicra", sick) == []
    steer(c, "vicra")
    assert c.in_use == "vicra"


def test_the_same_tracker_connected_again_after_its_samples_stopped_is_in_use_again():
    c = core()
    steer(c, "certus")
    assert c.tracking(None, {}) == [("e_NOTRACKER", {"why": "the Sensor Manager has not said"})]
    c.navigation(None, GOALS)  # no_tracker disconnected it: its samples stopped
    steer(c, "certus")  # RELEASE, reselected, connected again
    assert c.in_use == "certus"


def decoded(name: str) -> str:
    """A tracker name as it arrives from the bus: equal to, not the same object as, any
    other copy of it (each message decodes its own string)."""
    copy = json.loads(json.dumps(name))
    assert copy == name and copy is not name
    return copy


def test_tracker_names_from_different_messages_are_the_same_tracker():
    """The Sensor Manager's status and the navigator's samples each carry their own copy
    of a name: the Supervisor compares names, never string objects."""
    c = core()
    steer(c, decoded("certus"))
    assert c.tracking(None, {}) == [("e_NOTRACKER", {"why": "the Sensor Manager has not said"})]
    c.tracking(decoded("certus"), HEALTHY)
    assert c.report_best_tracker() == ("e_TOK", {"tracker": "certus"})
    steer(c, decoded("certus"))  # its samples steer again, under the same name
    assert c.in_use == "certus" and c.swapping_to is None
    c = core()
    steer(c, decoded("certus"))
    c.limits("fast")
    c.tracking(decoded("certus"), HEALTHY)
    assert c.report_best_tracker() == ("e_TOK", {"tracker": "certus"})
    assert c.swapping_to is None, "the tracker in use is not a swap"
    assert steer(c, decoded("certus")) == ([], False), "nothing new: no limits to resend"


def test_a_new_tracker_steering_asks_for_its_limits_once_a_speed_was_chosen():
    c = core()
    assert steer(c, "certus") == ([], False), "no speed chosen yet: nothing to resend"
    c.limits("fast")
    assert steer(c, "certus") == ([], False), "the same tracker: nothing new"
    assert steer(c, "vicra") == ([], True)
    assert c.limits(c.speed)["velocity"] == 0.050  # the Vicra's fast speed
    assert c.navigation(None, GOALS) == ([], False), "samples stopped: no new limits"


def test_a_refused_patient_motion_is_reported_once_per_refusal():
    c = core()
    events, _ = c.navigation("certus", GOALS, "the patient moved 12.0 mm")
    assert events == [("e_PATIENT_MOVED", {"reason": "the patient moved 12.0 mm"})]
    assert c.navigation("certus", GOALS, "the patient moved 12.5 mm")[0] == []
    assert c.navigation("certus", GOALS, "")[0] == []
    assert names(c.navigation("certus", GOALS, "the patient moves at 9 mm/s")[0]) == [
        "e_PATIENT_MOVED"
    ]


def test_the_critical_area_and_the_arrival_follow_the_target_where_the_navigator_says_it_is():
    c = core()
    c.observe(tcp=TARGET)
    assert c.area == "critical"
    moved = (TARGET[0], TARGET[1] + 0.06, TARGET[2])  # the head moved (a large motion)
    events, _ = c.navigation("certus", {"target": moved, "home": HOME})
    assert names(events) == ["e_SAFE_AREA"]
    c.motion("reached", "target")
    events, _ = c.navigation("certus", {"target": TARGET, "home": HOME})
    assert names(events) == ["e_CRITICAL_AREA", "e_TARGET"]


def test_a_target_on_the_patient_is_nowhere_until_the_navigator_says_where():
    c = SupervisorCore(PROCEDURE)
    assert PROCEDURE.frame("target") == "patient"
    assert c.observe(tcp=TARGET) == [] and c.area is None
    c.motion("reached", "target")
    assert c.observe(tcp=TARGET) == []
    assert c.goal_position("home") == pytest.approx(HOME)  # in the base frame: known


def test_no_tracker_says_what_each_tracker_lacks():
    """What the operator reads with "no tracker", from the Sensor Manager's verdicts."""
    c = core()
    steer(c, "certus")
    health = {
        "vicra": {
            "ok": False,
            "cause": "stale",
            "detail": "no new frame for 230 ms (limit 200 ms)",
        },
        "certus": {"ok": False, "cause": "cto_missing", "detail": ""},
    }
    assert c.tracking(None, health) == [
        (
            "e_NOTRACKER",
            {"why": "certus: cto_missing; vicra: stale, no new frame for 230 ms (limit 200 ms)"},
        )
    ]
    back = {"certus": {"ok": True}, "vicra": {"ok": False, "cause": "no_data"}}
    c.tracking(None, back)  # the Certus is healthy again, not yet for its hysteresis
    assert c.report_best_tracker() == (
        "e_NOTRACKER",
        {"why": "certus: healthy, not trusted again yet; vicra: no_data"},
    )


def test_no_tracker_is_explained_from_every_trackers_health_in_name_order():
    """What the operator reads with "no tracker": each tracker's cause and detail, a
    healthy one not trusted again yet, one the Sensor Manager said nothing of."""
    health = {
        "vicra": None,
        "certus": {"cause": "stale", "detail": "120 ms"},
        "aurora": {"ok": True, "cause": "stale"},
        "optotrak": {"cause": "calibration"},
    }
    assert untracked(health) == (
        "aurora: healthy, not trusted again yet; certus: stale, 120 ms; "
        "optotrak: calibration; vicra: unknown"
    )
    assert untracked({}) == "the Sensor Manager has not said"


def test_a_robot_fault_that_clears_and_comes_back_stops_the_task_again():
    """Once per fault: the same fault reported again is not news, but once the robot
    said it cleared (after the operator's RELEASE), the same fault again is."""
    c = core()
    assert names(c.robot(True, True, "monitor tripped")) == ["e_STOP"]
    assert c.robot(True, True, "monitor tripped") == []
    assert c.robot(True, False, "monitor tripped") == [], "cleared, the words still there"
    assert names(c.robot(True, True, "monitor tripped")) == ["e_STOP"]


def test_a_refused_speed_leaves_the_last_one_for_the_next_swap():
    c = core()
    steer(c, "vicra")
    c.limits("fast")
    with pytest.raises(FwError, match="speed is 'fast' or 'slow'"):
        c.limits("warp")
    _, resend = steer(c, "certus")
    assert resend and c.limits(c.speed) == c.limits("fast")
