"""Properties of the statechart engine on random well-formed charts and event sequences.

Invariants: the active configuration is always consistent; exits run innermost-first
before entries run outermost-first; outer-first priority; determinism; every event is
processed or reported; snapshot/restore is invisible; the loader, validator and exporter
fail only with their own error types, whatever the YAML.
"""

from __future__ import annotations

import itertools
from typing import Any

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from framework.clock import SimulatedClock
from framework.errors import FwError
from framework.statechart.events import Listener, Trace
from framework.statechart.export import to_dot, to_mermaid, to_plantuml
from framework.statechart.interpreter import Interpreter
from framework.statechart.loader import build_statechart, load_statechart
from framework.statechart.model import Kind, Statechart
from framework.statechart.validator import validate_chart
from tests.conftest import REPO

EXTERNAL = ["a", "b", "c"]
RAISED = ["r"]
PROPS = settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


@st.composite
def chart_specs(draw: Any, guards: bool = True) -> dict[str, Any]:
    """A random chart as YAML-ready data: nested, parallel, history, final, junction, timed."""
    counter = itertools.count()
    all_states: list[dict[str, Any]] = []

    def make(depth: int, region: bool = False) -> dict[str, Any]:
        name = f"S{next(counter)}"
        choices = ["atomic", "atomic", "atomic"]
        if depth < 3:
            choices += ["compound", "compound", "parallel"]
        kind = "compound" if region else draw(st.sampled_from(choices))
        spec: dict[str, Any] = {"name": name}
        if kind == "atomic":
            pass
        else:
            if kind == "parallel":
                spec["type"] = "parallel"
                spec["states"] = [
                    make(depth + 1, region=True) for _ in range(draw(st.integers(2, 3)))
                ]
            else:
                kids = [make(depth + 1) for _ in range(draw(st.integers(1, 3)))]
                if draw(st.booleans()):
                    kids.append({"name": f"F{next(counter)}", "type": "final"})
                if draw(st.integers(0, 3)) == 0:
                    kids.append(
                        {
                            "name": f"H{next(counter)}",
                            "type": draw(st.sampled_from(["shallow_history", "deep_history"])),
                        }
                    )
                spec["states"] = kids
                spec["initial"] = kids[0]["name"]
        all_states.append(spec)
        return spec

    top = [make(1) for _ in range(draw(st.integers(1, 4)))]
    real = [s["name"] for s in all_states]
    finals_and_history = [
        k["name"]
        for s in all_states
        for k in s.get("states", [])
        if k.get("type") in ("final", "shallow_history", "deep_history")
    ]
    for spec in all_states:
        transitions = []
        for _ in range(draw(st.integers(1, 3))):
            t: dict[str, Any] = {}
            trigger = draw(st.sampled_from(["event", "event", "event", "after", "internal"]))
            if trigger == "after":
                t["after"] = draw(st.sampled_from([0.5, 1, 2]))
            else:
                t["event"] = draw(st.sampled_from(EXTERNAL + RAISED))
            if trigger != "internal":
                pool = (
                    finals_and_history
                    if finals_and_history and draw(st.integers(0, 3)) == 0
                    else real
                )
                t["target"] = draw(st.sampled_from(pool))
            if guards and draw(st.booleans()):
                t["guard"] = f"x > {draw(st.integers(0, 3))}"
            if draw(st.booleans()):
                t["priority"] = draw(st.integers(0, 2))
            effect = []
            if draw(st.booleans()):
                effect.append({"set": {"x": "= (x + 1) % 5"}})
            if t.get("event") != "r" and draw(st.integers(0, 3)) == 0:
                effect.append({"raise": "r"})
            if effect:
                t["effect"] = effect
            transitions.append(t)
        if (
            spec.get("states")
            and not spec.get("type")
            and any(k.get("type") == "final" for k in spec["states"])
            and draw(st.booleans())
        ):
            transitions.append({"target": draw(st.sampled_from(real))})  # completion
        if transitions:
            spec["transitions"] = transitions
        if draw(st.integers(0, 4)) == 0:
            spec["entry"] = [{"log": f"in {spec['name']}"}]
    return {
        "statechart": "random",
        "variables": {"x": 0},
        "events": {e: None for e in EXTERNAL + RAISED},
        "initial": top[0]["name"],
        "states": top,
    }


def load(spec: dict[str, Any]) -> Statechart:
    return load_statechart("random.yaml", validate=False, text=yaml.safe_dump(spec))


events_only = st.lists(st.sampled_from(EXTERNAL), min_size=4, max_size=20)
steps = st.lists(
    st.one_of(st.sampled_from(EXTERNAL), st.sampled_from([0.5, 1.0, 1.5])), min_size=4, max_size=25
)


class Checker(Listener):
    """Asserts consistency after every callback burst and records configurations."""

    def __init__(self, interpreter_ref: list[Interpreter]):
        self.ref = interpreter_ref
        self.before: list[list[str]] = []

    def on_event(self, event: Any) -> None:
        self.before.append(self.ref[0].configuration)


def assert_consistent(interpreter: Interpreter) -> None:
    active = set(interpreter.configuration)
    chart = interpreter.chart
    for path, state in chart.states.items():
        if not path:
            continue
        if path in active:
            assert not state.kind.is_pseudo, f"pseudostate {path} active"
            parent = state.parent
            assert parent is not None and (not parent.path or parent.path in active), path
        kids = [c for c in state.children if c.path in active]
        if path in active or not path:
            if state.kind is Kind.COMPOUND:
                assert len(kids) == 1, f"{path or 'root'} has active children {kids}"
            elif state.kind is Kind.PARALLEL:
                assert len(kids) == len(state.children), f"region missing in {path}"
        else:
            assert not kids, f"inactive {path} has active children"


def drive(chart: Statechart, seq: list, cut: int | None = None):
    clock = SimulatedClock()
    trace = Trace()
    ref: list[Interpreter] = []
    checker = Checker(ref)
    interpreter = Interpreter(chart, clock, [trace, checker])
    ref.append(interpreter)
    interpreter.start()
    assert_consistent(interpreter)
    snapshots = []
    for i, item in enumerate(seq):
        if i == cut:
            snapshots.append((interpreter.snapshot(), len(trace.records)))
        if isinstance(item, str):
            interpreter.dispatch(item)
        else:
            interpreter.advance(item)
        assert_consistent(interpreter)
    return interpreter, trace, checker, snapshots


@PROPS
@given(spec=chart_specs(), seq=steps)
def test_configuration_is_always_consistent(spec, seq):
    drive(load(spec), seq)


@PROPS
@given(spec=chart_specs(), seq=steps)
def test_exits_innermost_first_then_entries_outermost_first(spec, seq):
    chart = load(spec)
    _, trace, _, _ = drive(chart, seq)
    # split the trace into transitions: exits, 'transition', entries
    records = trace.records
    for i, rec in enumerate(records):
        if rec[0] != "transition" or rec[2] is None:
            continue
        j = i - 1
        exits = []
        while j >= 0 and records[j][0] == "exit":
            exits.insert(0, records[j][1])
            j -= 1
        k = i + 1
        entries = []
        while k < len(records) and records[k][0] in ("entry", "output"):
            if records[k][0] == "entry":
                entries.append(records[k][1])
            k += 1
        for n, path in enumerate(exits):
            assert not any(later.startswith(path + ".") for later in exits[n + 1 :]), exits
        for n, path in enumerate(entries):
            assert not any(earlier.startswith(path + ".") for earlier in entries[:n]), entries


@PROPS
@given(spec=chart_specs(guards=False), seq=events_only)
def test_outer_first_priority(spec, seq):
    chart = load(spec)
    _, trace, checker, _ = drive(chart, seq)
    step = -1
    for rec in trace.records:
        if rec[0] == "event":
            step += 1
            event = rec[1]
            continue
        if rec[0] != "transition" or rec[3] is None or event in ("after",):
            continue
        before = set(checker.before[step])
        source = chart.states[rec[1]]
        for anc in source.ancestors():
            if anc.path in before:
                assert not any(event in t.events for t in anc.transitions), (
                    f"{rec[1]} fired on {event} although active parent {anc.path} takes it"
                )


@PROPS
@given(spec=chart_specs(), seq=steps)
def test_runs_are_deterministic(spec, seq):
    chart = load(spec)
    _, first, _, _ = drive(chart, seq)
    _, second, _, _ = drive(load(spec), seq)
    assert first.records == second.records


@PROPS
@given(spec=chart_specs(), seq=events_only)
def test_every_event_is_processed_or_reported(spec, seq):
    chart = load(spec)
    interpreter, trace, _, _ = drive(chart, seq)
    assert interpreter.queued == 0
    externals = [r for r in trace.records if r[0] == "event" and r[3] == "external"]
    assert [r[1] for r in externals] == seq
    events = [i for i, r in enumerate(trace.records) if r[0] == "event"]
    for n, start in enumerate(events):
        end = events[n + 1] if n + 1 < len(events) else len(trace.records)
        outcome = {r[0] for r in trace.records[start + 1 : end]}
        assert outcome & {"transition", "unhandled"}, trace.records[start:end]


@PROPS
@given(spec=chart_specs(), seq=steps, data=st.data())
def test_snapshot_restore_is_invisible(spec, seq, data):
    chart = load(spec)
    cut = data.draw(st.integers(0, len(seq)))
    full, trace, _, snapshots = drive(chart, [*seq, "a"], cut)
    snapshot, mark = snapshots[0]
    clock = SimulatedClock()
    clock.set(0.0)
    restored_trace = Trace()
    restored = Interpreter(chart, clock, [restored_trace])
    # replay time so deadlines align: the snapshot stores times relative to its moment
    elapsed = sum(x for x in seq[:cut] if not isinstance(x, str))
    clock.set(elapsed)
    restored.restore(snapshot)
    for item in [*seq, "a"][cut:]:
        if isinstance(item, str):
            restored.dispatch(item)
        else:
            restored.advance(item)
    assert restored_trace.records == trace.records[mark:]
    assert restored.configuration == full.configuration
    assert restored.variables == full.variables


@PROPS
@given(spec=chart_specs())
def test_validator_and_exporters_accept_any_built_chart(spec):
    chart = load(spec)
    for finding in validate_chart(chart):
        assert finding.location.line > 0 and finding.message
    assert to_dot(chart) and to_plantuml(chart) and to_mermaid(chart)


SEEG_TEXT = (REPO / "statecharts" / "seeg.yaml").read_text()


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_mutated_yaml_fails_only_with_fw_errors(data):
    lines = SEEG_TEXT.splitlines()
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(lines) - 1))
        op = data.draw(st.sampled_from(["drop", "dup", "indent", "dedent", "garble", "swap"]))
        if op == "drop":
            del lines[i]
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "indent":
            lines[i] = "  " + lines[i]
        elif op == "dedent":
            lines[i] = lines[i][2:]
        elif op == "garble":
            pos = data.draw(st.integers(0, max(0, len(lines[i]))))
            junk = data.draw(
                st.sampled_from(
                    [":", "-", "[", "{", "'", "yes", "&a", "*a", "!!x", "\t", "on:", "#", "%"]
                )
            )
            lines[i] = lines[i][:pos] + junk + lines[i][pos:]
        else:
            j = data.draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        if not lines:
            lines = ["x"]
    text = "\n".join(lines)
    try:
        chart, findings = build_statechart(REPO / "statecharts" / "seeg.yaml", text)
        if chart is not None:
            validate_chart(chart)
            to_dot(chart)
    except FwError:
        pass
    for finding in findings:
        assert finding.one_line()


@settings(max_examples=100, deadline=None)
@given(text=st.text(max_size=200))
def test_random_text_fails_only_with_fw_errors(text):
    try:
        chart, _ = build_statechart("random.yaml", text)
        if chart is not None:
            validate_chart(chart)
    except FwError:
        pass
