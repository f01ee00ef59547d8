"""A second checker agrees: every seeded bug and random charts (the shipped charts:
tests/framework/verify/test_explore.py, which CI runs with --spin) get the same verdict from SPIN, on a Promela model whose semantics are written anew
(`framework.verify.promela`), as from `fw verify`'s exploration with fw's interpreter;
and each SPIN counterexample, played on fw's interpreter, breaks the same property."""

from __future__ import annotations

import shutil
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from framework.cli import main
from framework.statechart.loader import load_statechart
from framework.verify import spin
from framework.verify.explore import Explorer
from framework.verify.promela import Inputs, PromelaUnsupported, export
from framework.verify.properties import load_properties
from tests.conftest import REPO
from tests.framework.statechart.test_properties import chart_specs
from tests.framework.verify.test_seeded_bugs import BUGS, seeded

needs_spin = pytest.mark.skipif(
    spin.available() is not None, reason=f"SPIN cross-check: {spin.available()}"
)


@needs_spin
@pytest.mark.parametrize("bug", sorted(BUGS))
def test_spin_catches_each_seeded_bug_and_fws_interpreter_confirms_its_trace(bug: str) -> None:
    files, old, new, expected = BUGS[bug]
    chart, props = seeded(files, old, new)
    watched = [p for p in props.properties if p.name in expected.split()]
    explorer = Explorer(chart, props.properties, unanswered=props.unanswered)
    verdicts = spin.check(chart, watched, Inputs.of(explorer))
    caught = [v for v in verdicts if not v.holds]
    assert caught, f"SPIN missed {bug}"
    index = {p.name: i for i, p in enumerate(props.properties)}
    for verdict in caught:
        assert verdict.trace, "a violation comes with SPIN's trace"
        broken = explorer.judge(verdict.trace)
        assert index[verdict.prop.name] in broken, "fw's interpreter confirms SPIN's trace"


def _without_history_and_raise(spec: dict[str, Any]) -> dict[str, Any]:
    """A random chart the export covers: history states and `raise` taken out (the
    export refuses both; the shipped charts use neither)."""
    removed: set[str] = set()

    def walk(states: list[dict[str, Any]]) -> None:
        for s in list(states):
            if s.get("type") in ("shallow_history", "deep_history"):
                removed.add(s["name"])
                states.remove(s)
                continue
            walk(s.get("states", []))

    walk(spec["states"])

    def fix(states: list[dict[str, Any]]) -> None:
        for s in states:
            for t in s.get("transitions", []):
                if t.get("target") in removed:
                    t["target"] = spec["initial"]
                if "effect" in t:
                    t["effect"] = [a for a in t["effect"] if "raise" not in a]
            fix(s.get("states", []))

    fix(spec["states"])
    return spec


def _names(spec: dict[str, Any]) -> list[str]:
    out = []

    def walk(states: list[dict[str, Any]]) -> None:
        for s in states:
            if s.get("type") not in ("final",):
                out.append(s["name"])
            walk(s.get("states", []))

    walk(spec["states"])
    return out


@st.composite
def chart_and_property(draw: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    spec = _without_history_and_raise(draw(chart_specs()))
    names = _names(spec)
    pattern = draw(st.sampled_from(["never", "always", "responds", "precedes"]))
    a, b = draw(st.sampled_from(names)), draw(st.sampled_from(names))
    event = draw(st.sampled_from(["a", "b", "c"]))
    check: dict[str, Any] = {"name": "random"}
    if pattern == "never":
        check["never"] = {"enter": a, "when": f"x == {draw(st.integers(0, 4))}"}
    elif pattern == "always":
        check["always"] = {"when": f"not active('{a}') or x < {draw(st.integers(1, 4))}"}
    elif pattern == "responds":
        check["responds"] = {
            "to": {"event": event},
            "within": draw(st.integers(0, 2)),
            "with": {"in": b},
        }
    else:
        check["precedes"] = {
            "after": {"enter": a},
            "forbid": {"enter": b},
            "unless": {"event": event},
        }
    return spec, {"properties": "random", "checks": [check]}


@needs_spin
@settings(
    max_examples=6,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(case=chart_and_property())
def test_on_random_charts_spin_and_fw_verify_give_the_same_verdict(case, tmp_path_factory):
    """Our own cases, not the shipped ones: nested, parallel and final states, timers,
    guards and assignments, drawn at random; both checkers must agree on each."""
    spec, props_doc = case
    folder = tmp_path_factory.mktemp("random")
    (folder / "random.yaml").write_text(yaml.safe_dump(spec))
    (folder / "p.yaml").write_text(yaml.safe_dump(props_doc))
    chart = load_statechart(folder / "random.yaml", validate=False)
    props = load_properties(folder / "p.yaml", chart)
    explorer = Explorer(chart, props.properties, max_states=20_000)
    result = explorer.run()
    if not result.complete:
        return  # a counter without bound: nothing to compare
    (theirs,) = spin.check(chart, props.properties, Inputs.of(explorer))
    assert theirs.holds == result.verdicts[0].holds, (spec, props_doc)
    if not theirs.holds:
        assert 0 in explorer.judge(theirs.trace)


def test_the_export_refuses_what_it_does_not_cover_and_says_where(tmp_path) -> None:
    chart_file = tmp_path / "r.yaml"
    chart_file.write_text(
        "statechart: r\nevents: {e: go, f: again}\ninitial: A\nstates:\n"
        "  - name: A\n    transitions: [{event: e, target: B, effect: [{raise: f}]}]\n"
        "  - name: B\n"
    )
    (tmp_path / "p.yaml").write_text("properties: r\nchecks:\n  - {name: n, never: {in: B}}\n")
    chart = load_statechart(chart_file, validate=False)
    props = load_properties(tmp_path / "p.yaml", chart)
    explorer = Explorer(chart, props.properties)
    with pytest.raises(PromelaUnsupported, match=r"r\.yaml:6:\d+: .*'raise'"):
        export(chart, props.properties[0], Inputs.of(explorer))


def test_without_spin_the_cross_check_says_what_to_install(capsys, monkeypatch) -> None:
    real = shutil.which
    monkeypatch.setattr(shutil, "which", lambda tool: None if tool == "spin" else real(tool))
    code = main(
        [
            "verify",
            str(REPO / "statecharts/pick_place.yaml"),
            "-p",
            str(REPO / "procedures/pick_place/properties.yaml"),
            "--spin",
        ]
    )
    err = capsys.readouterr().err
    assert code != 0
    assert "not installed: spin" in err and "apt-get install spin" in err
    assert "Traceback" not in err
