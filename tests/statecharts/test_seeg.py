"""Spec: the SEEG procedure chart replays the scenario of thesis 3.5.1 (Fig. 3.18/3.20)."""

import pytest

from framework.statechart.loader import load_statechart
from tests.conftest import REPO, Run

SETUP = ["setup_components", "setup_tracking", "setup_people", "setup_robot", "setup_safety"]


@pytest.fixture
def seeg():
    return load_statechart(REPO / "statecharts" / "seeg.yaml")


def configured(run):
    return [o.tag for o in run.outputs if o.kind == "configure"]


def task(run):
    return next(leaf for leaf in run.leaves if ".Task." in leaf).split(".")[-1]


def ok(tag):
    return ("config.done", {"tag": tag})


def test_setup_is_linear_and_waits_for_each_ack(seeg):
    r = Run(seeg)
    for i, tag in enumerate(SETUP):
        assert configured(r) == SETUP[: i + 1], "the next tag is asked only after the ack"
        r.send(ok(tag))
    assert task(r) == "Wait_Start"


@pytest.mark.parametrize("failing", SETUP)
def test_any_setup_failure_aborts_and_the_robot_never_moves(seeg, failing):
    r = Run(seeg)
    for tag in SETUP[: SETUP.index(failing)]:
        r.send(ok(tag))
    r.send(("config.failed", {"tag": failing, "reason": "component crashed"}))
    assert r.leaves == ["Setup_Aborted"] and r.interpreter.finished
    sent = [o for o in r.outputs if o.kind == "send"]
    assert sent[0].event == "e_SETUP_FAILED" and sent[0].payload["tag"] == failing
    r.send("e_START", ("e_TOK", {"tracker": "certus"}))
    assert not any(
        o.kind == "configure" and o.tag.startswith(("move", "tracker")) for o in r.outputs
    ), "no motion configuration after an abort"


def test_a_setup_step_that_never_answers_times_out_and_aborts(seeg):
    r = Run(seeg)
    r.send(ok("setup_components"))
    r.interpreter.advance(5.0)
    assert r.leaves == ["Setup_Aborted"]


def started(seeg, tracker="certus"):
    r = Run(seeg, auto_ack=True)
    r.send("e_START", ("e_TOK", {"tracker": tracker}))
    return r


def test_start_selects_the_best_tracker_then_moves_fast_in_the_safe_area(seeg):
    r = started(seeg)
    assert "tracker_1_up" in configured(r) and task(r) == "Moving_Fast"
    calls = [o.operation for o in r.outputs if o.kind == "call"]
    assert calls == ["supervisor.report_best_tracker"]
    assert configured(r)[-3:] == ["tracker_1_up", "goto_target", "move_fast"]
    assert r.interpreter.variables["tracker"] == "certus"


def test_the_second_tracker_gets_its_own_configuration(seeg):
    r = started(seeg, "vicra")
    assert "tracker_2_up" in configured(r) and "tracker_1_up" not in configured(r)


def test_critical_area_slows_and_safe_area_speeds_up(seeg):
    r = started(seeg)
    r.send("e_CRITICAL_AREA")
    assert task(r) == "Moving_Slow" and configured(r)[-1] == "move_slow"
    r.send("e_SAFE_AREA")
    assert task(r) == "Moving_Fast" and configured(r)[-1] == "move_fast"


FAULT = (
    "e_TFAULT",
    {"tracker": "vicra", "failed": "certus", "fault": "MISSING", "detail": "", "numbers": {}},
)


def test_a_tracker_fault_swaps_to_the_named_best_and_resumes_at_the_right_speed(seeg):
    r = started(seeg)
    calls = len([o for o in r.outputs if o.kind == "call"])
    r.send("e_CRITICAL_AREA", FAULT)
    assert task(r) == "Moving_Slow", "the area was remembered across the swap"
    assert configured(r)[-1] == "tracker_2_up", "one configuration: the motion goes on"
    assert r.interpreter.variables["tracker"] == "vicra"
    assert len([o for o in r.outputs if o.kind == "call"]) == calls, "no report round trip"


def test_no_tracker_stops_with_brakes_and_release_restarts(seeg):
    r = started(seeg)
    r.send("e_NOTRACKER")
    assert task(r) == "No_Tracker" and configured(r)[-1] == "no_tracker"
    assert r.interpreter.variables["tracker"] == "none"
    r.send("e_START")
    assert task(r) == "No_Tracker", "only RELEASE leaves the stop"
    r.send("e_RELEASE")
    assert configured(r)[-1] == "release" and task(r) == "Tracker_Selection"
    r.send(("e_TOK", {"tracker": "certus"}))
    assert task(r) == "Moving_Fast"


def test_a_silent_sensor_manager_counts_as_no_tracker(seeg):
    r = Run(seeg, auto_ack=True)
    r.send("e_START")
    r.interpreter.advance(1.0)
    assert task(r) == "No_Tracker"


def test_a_possible_collision_stops_from_any_task_state(seeg):
    for prefix in ([], ["e_START"], ["e_START", ("e_TOK", {"tracker": "certus"})]):
        r = Run(seeg, auto_ack=True)
        r.send(*prefix, ("e_STOP", {"reason": "collision"}))
        assert task(r) == "Stopped", prefix


def test_target_reached_waits_then_goes_home_on_request(seeg):
    r = started(seeg)
    r.send("e_TARGET")
    assert task(r) == "Target_Reached" and configured(r)[-1] == "hold_position"
    r.send(("e_GOTO", {"where": "home"}), ("e_TOK", {"tracker": "certus"}))
    assert task(r) == "Moving_Fast" and r.interpreter.variables["goal"] == "home"
    assert "goto_home" in configured(r)


def test_a_failed_motion_configuration_stops_the_robot(seeg):
    r = Run(seeg, auto_ack=True)
    r.auto_ack = False
    r.send("e_START", ("e_TOK", {"tracker": "certus"}))
    r.send(("config.failed", {"tag": "tracker_1_up", "reason": "port busy"}))
    assert task(r) == "Stopped"


def test_a_failed_stop_goes_to_fault_and_alerts(seeg):
    r = Run(seeg, auto_ack=True)
    r.auto_ack = False
    r.send(
        ("e_STOP", {"reason": "collision"}),
        ("config.failed", {"tag": "stop", "reason": "no answer"}),
    )
    assert task(r) == "Fault"
    alert = [o for o in r.outputs if o.kind == "send" and o.event == "e_FAULT"]
    assert alert and alert[0].payload == {"reason": "stop configuration failed"}


LOST = ("component.lost", {"component": "supervisor", "process": "supervision"})


@pytest.mark.parametrize("where", ["Wait_Start", "Moving_Fast", "Stopped", "Target_Reached"])
def test_a_lost_component_is_a_fault_from_any_state_and_says_which(seeg, where):
    r = Run(seeg, auto_ack=True)
    to = {
        "Wait_Start": [],
        "Moving_Fast": ["e_START", ("e_TOK", {"tracker": "certus"})],
        "Stopped": ["e_START", ("e_TOK", {"tracker": "certus"}), ("e_STOP", {"reason": "x"})],
        "Target_Reached": ["e_START", ("e_TOK", {"tracker": "certus"}), "e_TARGET"],
    }[where]
    r.send(*to)
    assert task(r) == where
    r.send(LOST)
    assert task(r) == "Fault"
    assert [o.tag for o in r.outputs if o.kind == "configure"][-1] == "fault"
    alert = [o for o in r.outputs if o.kind == "send" and o.event == "e_FAULT"]
    assert alert[-1].payload == {"reason": "supervisor lost"}


def test_in_fault_only_release_leads_out_and_a_failed_fault_configuration_stays(seeg):
    r = Run(seeg, auto_ack=True)
    r.send("e_START", ("e_TOK", {"tracker": "certus"}))
    r.auto_ack = False
    r.send(LOST, ("config.failed", {"tag": "fault", "reason": "robot: no answer"}))
    assert task(r) == "Fault", "the fault configuration failing is expected here"
    r.send(("e_STOP", {"reason": "robot braked"}), LOST, "e_START", "e_GOTO")
    assert task(r) == "Fault", "a stop, a second loss or a START do not leave Fault"
    r.send("e_RELEASE")
    assert task(r) == "Releasing"
    r.send(("config.failed", {"tag": "release", "reason": "robot: safety inputs not healthy"}))
    assert task(r) == "Stopped", "a refused RELEASE: braked, try again"


def test_a_lost_component_during_setup_aborts_it(seeg):
    r = Run(seeg)
    r.send(ok("setup_components"), LOST)
    assert r.leaves == ["Setup_Aborted"]
    sent = [o for o in r.outputs if o.kind == "send"]
    assert sent[0].event == "e_SETUP_FAILED"
    assert sent[0].payload == {"tag": "supervision", "reason": "supervisor lost"}


TARGET = {"x": 0.55, "y": 0.05, "z": 0.15, "roll": 0.0, "pitch": 180.0, "yaw": 10.0}


def test_a_target_defined_while_braked_goes_to_the_navigator_on_the_patient(seeg):
    r = Run(seeg, auto_ack=True)
    assert task(r) == "Wait_Start"
    r.send(("e_DEFINE_TARGET", TARGET))
    calls = [o for o in r.outputs if o.kind == "call"]
    assert calls[-1].operation == "navigator.define_target"
    assert calls[-1].args == {**TARGET, "frame": "patient"} and task(r) == "Wait_Start"


def test_a_target_is_not_redefined_while_moving(seeg):
    r = started(seeg)
    calls = len([o for o in r.outputs if o.kind == "call"])
    r.send(("e_DEFINE_TARGET", TARGET))
    assert len([o for o in r.outputs if o.kind == "call"]) == calls and task(r) == "Moving_Fast"
