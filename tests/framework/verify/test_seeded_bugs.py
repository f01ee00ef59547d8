"""`fw verify` catches what it should: ten chart bugs, each a mistake a procedure's
author could make (a dropped transition, a retargeted one, a swapped configuration
tag, an inverted guard, a lost assignment), seeded into the shipped charts and checked
against the shipped properties. Each must be caught with a counterexample that, played
again on the seeded chart, ends where the property broke."""

from __future__ import annotations

import pytest

from framework.statechart.loader import load_statechart
from framework.verify.explore import Environment, Explorer
from framework.verify.properties import load_properties
from tests.conftest import REPO

SEEG = ("statecharts/seeg.yaml", "procedures/seeg/properties.yaml")
PICK = ("statecharts/pick_place.yaml", "procedures/pick_place/properties.yaml")

BUGS = {
    "seeg_dropped_lost_component": (
        SEEG,
        """          - event: component.lost
            guard: not active('Fault')
            target: Fault
            effect: [{log: a component was lost; fault}]
""",
        "",
        "a_lost_component_is_a_fault",
    ),
    "seeg_stop_retargeted": (
        SEEG,
        """            guard: not active('Stopped') and not active('Fault')
            target: Stopped
          - event: e_PATIENT_MOVED""",
        """            guard: not active('Stopped') and not active('Fault')
            target: Releasing
          - event: e_PATIENT_MOVED""",
        "stop_brakes_at_once",
    ),
    "seeg_stop_and_no_tracker_tags_swapped": (
        SEEG,
        """            configure: stop
            transitions:
              - event: e_RELEASE
                target: Releasing

          - name: No_Tracker
            doc: No tracker sees the robot; brakes on until the surgeon releases.
            configure: no_tracker""",
        """            configure: no_tracker
            transitions:
              - event: e_RELEASE
                target: Releasing

          - name: No_Tracker
            doc: No tracker sees the robot; brakes on until the surgeon releases.
            configure: stop""",
        "every_no_tracker_requests_the_halt",
    ),
    "seeg_speed_guard_inverted": (
        SEEG,
        "- guard: active('Critical')",
        "- guard: not active('Critical')",
        "never_fast_in_the_critical_area",
    ),
    "seeg_tracker_assignment_lost": (
        SEEG,
        """                target: Certus_Up
                effect: [{set: {tracker: certus}}]""",
        """                target: Certus_Up""",
        "moving_only_with_a_tracker tracker_swap_names_a_tracker",
    ),
    "seeg_failed_stop_retargeted": (
        SEEG,
        """            guard: event.tag == 'stop'
            target: Fault""",
        """            guard: event.tag == 'stop'
            target: Stopped""",
        "a_failed_stop_is_a_fault",
    ),
    "seeg_slow_down_dropped": (
        SEEG,
        """                    configure: move_fast
                    transitions:
                      - event: e_CRITICAL_AREA
                        target: Moving_Slow""",
        """                    configure: move_fast""",
        "never_moving_fast_in_the_critical_area",
    ),
    "seeg_no_tracker_assignment_lost": (
        SEEG,
        """              - event: e_NOTRACKER
                target: No_Tracker
                effect: [{set: {tracker: none}}]
              - after: 1s""",
        """              - event: e_NOTRACKER
                target: No_Tracker
              - after: 1s""",
        "no_tracker_means_none_in_use",
    ),
    "pick_hands_on_guard_dropped": (
        PICK,
        """          - event: e_MODE
            guard: event.mode == 'hands_on' and not held
            target: Hands_On

      - name: Auto""",
        """          - event: e_MODE
            guard: event.mode == 'hands_on'
            target: Hands_On

      - name: Auto""",
        "no_hands_on_while_holding",
    ),
    "pick_curtain_retargeted": (
        PICK,
        """      - event: e_CURTAIN
        target: Stopped""",
        """      - event: e_CURTAIN
        target: Cell""",
        "curtain_stops_at_once",
    ),
}


def seeded(files: tuple[str, str], old: str, new: str):
    chart_file, props_file = files
    text = (REPO / chart_file).read_text()
    assert text.count(old) == 1, "the seeded bug's anchor must be in the chart once"
    chart = load_statechart(REPO / chart_file, validate=False, text=text.replace(old, new))
    return chart, load_properties(REPO / props_file, chart)


@pytest.mark.parametrize("bug", sorted(BUGS))
def test_a_seeded_chart_bug_is_caught_with_a_counterexample(bug: str) -> None:
    files, old, new, expected = BUGS[bug]
    chart, props = seeded(files, old, new)
    result = Explorer(chart, props.properties, unanswered=props.unanswered, first=True).run()
    violated = {v.prop.name: v for v in result.verdicts if not v.holds}
    caught = set(expected.split()) & set(violated)
    assert caught, f"{bug} was not caught (violated: {sorted(violated)})"
    assert all(violated[name].trace is not None for name in caught)


def test_the_shipped_charts_hold_their_own_properties_in_the_same_harness() -> None:
    """The control: the same harness on the unseeded pick-and-place chart finds nothing,
    so what the seeded runs report comes from the seeded bug."""
    chart, props = seeded(PICK, "statechart: pick_place", "statechart: pick_place")
    result = Explorer(chart, props.properties, Environment.of(chart), props.unanswered).run()
    assert result.complete and all(v.holds for v in result.verdicts)
