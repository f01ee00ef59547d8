"""Spec: the documented example works as documented, and the docs name every finding."""

import re

from framework.statechart.files import validate_file
from framework.statechart.loader import load_statechart
from tests.conftest import REPO, Run

DOCS = REPO / "docs"


def test_the_tour_example_is_clean_and_uses_every_construct():
    path = DOCS / "examples" / "tour.yaml"
    assert validate_file(path) == []
    text = path.read_text() + (DOCS / "examples" / "lamp.yaml").read_text()
    for construct in [
        "type: parallel",
        "type: junction",
        "type: final",
        "deep_history",
        "include:",
        "after:",
        "priority:",
        "guard: else",
        "configure:",
        "raise",
        "send:",
        "set:",
        "write:",
        "call:",
        "log:",
        "entry:",
        "exit:",
        "do:",
        "payload:",
        "safe_state:",
        "event: [",
    ]:
        assert construct in text, construct


def test_the_tour_resumes_deep_drilling_after_a_pause():
    r = Run(load_statechart(DOCS / "examples" / "tour.yaml"), auto_ack=True)
    r.send("power", ("job", {"depth": 30}), "pause", "resume")
    assert "Machine.Work.Drilling.Deep" in r.leaves
    r.interpreter.advance(2.0)
    assert "Machine.Work.Idle" in r.leaves
    done = [o for o in r.outputs if o.kind == "send"]
    assert done[-1].event == "done" and done[-1].payload == {"jobs": 1}


def test_every_finding_code_is_documented():
    source = (REPO / "framework" / "statechart" / "validator.py").read_text()
    source += (REPO / "framework" / "statechart" / "loader.py").read_text()
    codes = set(re.findall(r'self\.(?:error|warn)\(\s*"([a-z-]+)"', source))
    docs = (DOCS / "statecharts.md").read_text()
    missing = [c for c in codes if f"`{c}`" not in docs and f"`{c.split('-')[0]}-*`" not in docs]
    assert len(codes) > 25 and not missing, missing
