"""Spec: loading reports every defect as file:line:col with the YAML path, never a traceback."""

import pytest

from framework.errors import FindingsError
from framework.statechart.loader import build_statechart, load_statechart, parse_duration
from framework.statechart.model import Kind
from tests.conftest import REPO


def findings_of(write, text, name="chart.yaml"):
    _, findings = build_statechart(write(text, name))
    return findings


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("2s", 2.0),
        ("500ms", 0.5),
        ("1.5min", 90.0),
        (" 3 s ", 3.0),
        (4, 4.0),
        ("1h", 3600.0),
    ],
)
def test_durations(text, seconds):
    assert parse_duration(text) == seconds


@pytest.mark.parametrize("bad", ["2 sec", "-1s", "soon", True])
def test_bad_durations(bad):
    with pytest.raises(ValueError):
        parse_duration(bad)


def test_the_shipped_seeg_chart_loads_with_its_include():
    chart = load_statechart(REPO / "statecharts" / "seeg.yaml")
    assert chart.states["System_OK"].kind is Kind.PARALLEL
    assert chart.state("Area.Critical").path == "System_OK.Area.Critical"
    assert len(chart.files) == 2


def test_schema_errors_point_at_the_offending_key(write):
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states:
          - name: A
            transitons: []
        """,
    )
    assert len(findings) == 1
    f = findings[0]
    assert (f.location.line, f.location.path) == (6, "states[0].transitons")
    assert "unknown key 'transitons'" in f.message and "transitions" in f.hint


def test_yaml_11_booleans_in_a_chart_are_explained(write):
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states:
          - name: A
            transitions: [{event: e, target: A, priority: true}]
        """,
    )
    assert findings and "boolean" in findings[0].message


def test_every_unknown_reference_is_reported_with_a_suggestion(write):
    findings = findings_of(
        write,
        """
        statechart: s
        initial: Idel
        states:
          - name: Idle
            transitions: [{event: e, target: Movng}]
          - name: Moving
        """,
    )
    messages = {f.location.line: (f.message, f.hint) for f in findings}
    assert messages[3] == ("unknown state 'Idel'", "did you mean 'Idle'?")
    assert messages[6] == ("unknown state 'Movng'", "did you mean 'Moving'?")


def test_ambiguous_short_names_must_be_qualified(write):
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states:
          - {name: A, initial: X, states: [{name: X}], transitions: [{event: e, target: X}]}
          - {name: B, initial: X, states: [{name: X}]}
        """,
    )
    assert any(f.code == "ambiguous" and "A.X, B.X" in f.message for f in findings)


def test_bad_expressions_and_durations_are_located(write):
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states:
          - name: A
            transitions:
              - {event: e, guard: "x ==", target: A}
              - {event: f, guard: "open('x')", target: A}
        """,
    )
    assert [(f.code, f.location.line) for f in findings] == [("expression", 7), ("expression", 8)]
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states:
          - {name: A, transitions: [{after: 2 parsecs, target: A}]}
        """,
    )
    assert findings[0].code == "schema" and findings[0].location.path.endswith("after")


def test_duplicate_sibling_names_are_refused(write):
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states: [{name: A}, {name: A}]
        """,
    )
    assert findings[0].code == "duplicate-state"


def test_includes_are_scoped_and_located_in_their_own_file(write):
    write(
        """
        statechart: part
        events: {e: null}
        initial: X
        states:
          - {name: X, transitions: [{event: e, target: Y}]}
          - {name: Y, transitions: [{event: e, target: Nowhere}]}
        """,
        "lib/part.yaml",
    )
    findings = findings_of(
        write,
        """
        statechart: s
        initial: A
        states:
          - {name: A, include: lib/part.yaml}
          - {name: B, include: lib/part.yaml}
        """,
    )
    # X/Y exist twice, but references inside each copy resolve within it
    assert [f.code for f in findings] == ["unknown-state", "unknown-state"]
    assert all(f.location.file.endswith("lib/part.yaml") and f.location.line == 7 for f in findings)


def test_include_cycles_and_missing_files_are_errors(write):
    write(
        """
        statechart: a
        initial: S
        states: [{name: S, include: b.yaml}]
        """,
        "a.yaml",
    )
    write(
        """
        statechart: b
        initial: T
        states: [{name: T, include: a.yaml}, {name: U, include: missing.yaml}]
        """,
        "b.yaml",
    )
    root = write(
        """
        statechart: r
        initial: R
        states: [{name: R, include: a.yaml}]
        """,
        "r.yaml",
    )
    _, findings = build_statechart(root)
    codes = sorted(f.code for f in findings)
    assert "include-cycle" in codes and "yaml" in codes


def test_load_statechart_raises_with_all_findings(write):
    path = write("""
        statechart: s
        initial: A
        states:
          - {name: A, transitions: [{event: e, target: B1}, {event: f, target: B2}]}
        """)
    with pytest.raises(FindingsError) as err:
        load_statechart(path)
    assert len(err.value.findings) >= 2 and "and" in str(err.value)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "the file is empty"),
        ("- a\n", "expected a mapping"),
        ("statechart: x\nstates: {A: 1}\n", "expected a list"),
        (
            "statechart: x\ninitial: A\nstates:\n  - {name: A, transitions: [{on: go}]}\n",
            "unknown key 'on'",
        ),
        ("\x00\x01", "NUL is not allowed"),
    ],
)
def test_odd_files_get_one_plain_line(write, text, expected):
    findings = findings_of(write, text)
    assert len(findings) == 1 and expected in findings[0].one_line()
    assert "\n" not in findings[0].one_line()
    if "'on'" in expected:
        assert "write `event:`" in findings[0].hint


def test_payload_fields_may_carry_limits_units_and_docs(chart):
    loaded = chart(
        """
statechart: limits
events:
  e_MOVE:
    payload:
      x: {type: number, min: 0.3, max: 0.8, unit: m, doc: base frame}
      label: string
initial: A
states: [{name: A, transitions: [{event: e_MOVE, target: A}]}]
"""
    )
    spec = loaded.events["e_MOVE"]
    assert spec.payload == {"x": "number", "label": "string"}
    assert spec.fields == {"x": {"min": 0.3, "max": 0.8, "unit": "m", "doc": "base frame"}}


@pytest.mark.parametrize(
    "field, message",
    [
        ("{type: string, min: 1}", "payload field e_MOVE.x is a string: min/max apply to numbers"),
        ("{type: number, min: 2, max: 1}", "payload field e_MOVE.x: min 2 is above max 1"),
        (
            "{type: number, values: [1, two, 3.5]}",
            "payload field e_MOVE.x is a number: 'two' cannot be one of its values",
        ),
    ],
)
def test_impossible_payload_limits_are_errors(write, field, message):
    findings = findings_of(
        write,
        f"""
statechart: limits
events:
  e_MOVE: {{payload: {{x: {field}}}}}
initial: A
states: [{{name: A}}]
""",
    )
    assert any(f.code.startswith("payload-") and f.message == message for f in findings), findings


def test_an_event_declaration_says_why_a_payload_does_not_fit(chart):
    spec = chart(
        """
statechart: limits
events:
  e_MOVE: {payload: {x: {type: number, min: 0.3, max: 0.8, unit: m}, where: string}}
initial: A
states: [{name: A, transitions: [{event: e_MOVE, target: A}]}]
"""
    ).events["e_MOVE"]
    assert spec.problem({"x": 0.5, "where": "home"}) == ""
    assert spec.problem({"x": 0.5}) == "e_MOVE needs where (string)"
    assert spec.problem({}) == "e_MOVE needs x (number, 0.3..0.8 m), where (string)"
    assert spec.problem({"x": 0.5, "where": "home", "y": 1}) == "e_MOVE has no payload field 'y'"
    assert spec.problem({"x": True, "where": "home"}) == "e_MOVE.x must be a number"
    assert spec.problem({"x": float("nan"), "where": "a"}) == "e_MOVE.x must be a finite number"
    assert spec.problem({"x": 0.9, "where": "a"}) == "e_MOVE.x must be at most 0.8 m"
    assert spec.problem({"x": 0.1, "where": "a"}) == "e_MOVE.x must be at least 0.3 m"


def test_a_field_with_allowed_values_takes_only_those_and_says_which(chart):
    """`values:` (e_GOTO's where: target or home) refuses anything else before the
    chart sees it, and a missing field says what it may be."""
    spec = chart(
        """
statechart: values
events:
  e_GOTO: {payload: {where: {type: string, values: [target, home]}}}
initial: A
states: [{name: A, transitions: [{event: e_GOTO, target: A}]}]
"""
    ).events["e_GOTO"]
    assert spec.problem({"where": "home"}) == ""
    assert spec.problem({"where": "hone"}) == "e_GOTO.where must be one of target, home"
    assert spec.problem({}) == "e_GOTO needs where (one of target, home)"
