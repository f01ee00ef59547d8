"""Spec: `fw validate` proves each defect statically, with file:line and a fix hint."""

import pytest

from framework.statechart.files import validate_file
from tests.conftest import REPO

HEADER = """
statechart: v
events: {e: null, f: null, g: {payload: {n: integer}}}
variables: {x: 0}
"""


def codes(write, body, header=HEADER, **kw):
    findings = validate_file(write(header + body), **kw)
    return {(f.code, f.severity) for f in findings}, findings


def error_codes(write, body, **kw):
    found, _ = codes(write, body, **kw)
    return {c for c, s in found if s == "error"}


def test_the_shipped_charts_are_clean():
    for path in (REPO / "statecharts").rglob("*.yaml"):
        assert validate_file(path) == [], path


def test_a_clean_chart_has_no_findings(write):
    assert (
        error_codes(
            write,
            """
initial: A
states:
  - {name: A, transitions: [{event: e, target: B}]}
  - {name: B, transitions: [{event: f, target: A}, {event: g, guard: event.n > x, target: A}]}
""",
        )
        == set()
    )


@pytest.mark.parametrize(
    ("body", "code"),
    [
        ("initial: A\nstates:\n  - {name: A, states: [{name: X}]}\n", "no-initial"),
        (
            "initial: A\nstates:\n  - {name: A, initial: B, states: [{name: X}]}\n  - {name: B}\n",
            "initial-not-child",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, target: A}]}\n  - {name: B}\n",
            "unreachable",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, target: B}]}\n  - {name: B}\n",
            "dead-end",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, target: A}, "
            "{event: e, guard: x > 1, target: A}]}\n",
            "shadowed",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, guard: x > 1, target: A}, "
            "{event: e, guard: x > 2, target: A}]}\n",
            "nondeterministic",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: nope, target: A}]}\n",
            "undeclared-event",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, guard: y > 1, target: A}]}\n",
            "unknown-name",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, guard: event.n > 1, "
            "target: A}]}\n",
            "unknown-field",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, guard: \"active('Q')\", "
            "target: A}]}\n",
            "unknown-state",
        ),
        ("initial: A\nstates:\n  - {name: A, transitions: [{after: 0, target: A}]}\n", "after"),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{target: B}]}\n"
            "  - {name: B, transitions: [{target: A}]}\n",
            "livelock",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, target: J}]}\n"
            "  - {name: J, type: junction, transitions: [{guard: x > 1, target: K}, "
            "{guard: else, target: A}]}\n"
            "  - {name: K, type: junction, transitions: [{guard: else, target: J}]}\n",
            "connector-cycle",
        ),
        (
            "initial: A\nstates:\n  - {name: A, configure: t, transitions: [{event: e, target: A}]}\n",
            "unhandled-failure",
        ),
        (
            "initial: A\nstates:\n  - {name: A, initial: X, states: [{name: X, transitions: "
            "[{event: e, target: Y}]}, {name: Y, transitions: [{event: f, target: X}]}], "
            "transitions: [{target: A}]}\n",
            "completion-never",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, guard: else, target: A}]}\n",
            "else",
        ),
        (
            "initial: A\nstates:\n  - {name: A, transitions: [{event: e, target: F}]}\n"
            "  - {name: F, type: final, transitions: [{event: f, target: A}]}\n",
            "final-out",
        ),
        (
            "initial: P\nstates:\n  - {name: P, type: parallel, states: [{name: R}], "
            "transitions: [{event: e, target: P}]}\n",
            "region",
        ),
    ],
)
def test_each_defect_is_proven(write, body, code):
    assert code in error_codes(write, body)


def test_outer_first_shadowing_names_the_parent(write):
    _, findings = codes(
        write,
        """
initial: P
states:
  - name: P
    initial: A
    states:
      - {name: A, transitions: [{event: e, target: B}]}
      - {name: B, transitions: [{event: f, target: A}]}
    transitions: [{event: e, target: Q}]
  - {name: Q, transitions: [{event: f, target: P}]}
""",
    )
    shadowed = [f for f in findings if f.code == "shadowed"]
    assert len(shadowed) == 1 and shadowed[0].location.line == 11
    assert "parent 'P'" in shadowed[0].message and shadowed[0].hint


def test_a_guarded_outer_transition_does_not_shadow(write):
    assert "shadowed" not in error_codes(
        write,
        """
initial: P
states:
  - name: P
    initial: A
    states:
      - {name: A, transitions: [{event: e, target: B}]}
      - {name: B, transitions: [{event: f, target: A}]}
    transitions: [{event: e, guard: x > 3, target: Q}]
  - {name: Q, transitions: [{event: f, target: P}]}
""",
    )


def test_exclusive_guards_and_explicit_priority_are_deterministic(write):
    assert (
        error_codes(
            write,
            """
initial: A
states:
  - name: A
    transitions:
      - {event: e, guard: x > 1, target: B}
      - {event: e, guard: x <= 1, target: A}
      - {event: f, target: B, priority: 1}
      - {event: f, guard: x > 5, target: A}
  - {name: B, transitions: [{event: e, target: A}, {event: g, target: A}]}
""",
        )
        == set()
    )


TRAPPED = """
safe_state: Safe
initial: A
states:
  - {name: A, transitions: [{event: e, target: B}, {event: f, target: Safe}]}
  - {name: B, transitions: [{event: e, target: C}]}
  - {name: C, transitions: [{event: e, target: B}, {event: g, target: A}]}
  - {name: Trap, transitions: [{event: e, target: Trap2}]}
  - {name: Trap2, transitions: [{event: e, target: Trap}]}
  - {name: Safe, transitions: [{event: e, target: A}, {event: g, target: Trap}]}
"""


def test_safe_state_must_be_reachable_from_every_state(write):
    _, findings = codes(write, TRAPPED)
    unsafe = {f.message.split("from ")[1] for f in findings if f.code == "safe-unreachable"}
    assert unsafe == {"'Trap'", "'Trap2'"}
    assert not codes(write, TRAPPED.replace("target: Trap2}]}", "target: Safe}]}"))[0] & {
        ("safe-unreachable", "error")
    }


def test_event_closure_warns_about_unused_and_unconsumed_events(write):
    found, _ = codes(
        write,
        """
initial: A
states:
  - {name: A, transitions: [{event: e, target: A, effect: [{raise: f}]}]}
""",
    )
    assert ("unused-event", "warning") in found  # g is declared but never consumed
    assert ("unconsumed-raise", "warning") in found  # f is raised, nobody takes it


def test_configuration_tags_are_checked_against_the_topology(write):
    topology = write(
        "topology: t\ncomponents: {}\nconfigurations:\n  tracker_1_up: {}\n  robot_stop: {}\n",
        "topo.yaml",
    )
    body = """
initial: A
states:
  - name: A
    configure: tracker_1_upp
    transitions: [{event: config.failed, target: B}, {event: e, target: B}]
  - {name: B, configure: robot_stop, transitions: [{event: f, target: A}]}
"""
    _, findings = codes(write, body, topology=topology)
    unknown = [f for f in findings if f.code == "unknown-tag"]
    assert len(unknown) == 1 and unknown[0].hint == "did you mean 'tracker_1_up'?"
    _, findings = codes(write, body, topology=write("name: t\n", "empty.yaml"))
    assert any(f.code == "schema" and f.location.file.endswith("empty.yaml") for f in findings)


def test_findings_are_one_line_with_location_and_hint(write):
    path = write(HEADER + "initial: A\nstates:\n  - {name: A, states: [{name: X}]}\n")
    line = next(f for f in validate_file(path) if f.code == "no-initial").one_line()
    assert line.startswith(f"{path}:7:5: states[0]: error[no-initial]: ")
    assert "\n" not in line and "(hint: add `initial: X`)" in line
