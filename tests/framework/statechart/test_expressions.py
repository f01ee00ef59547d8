"""Spec: guards are a safe, compiled expression language with checkable references."""

import pytest

from framework.statechart.events import Event
from framework.statechart.expressions import (
    Env,
    EvaluationError,
    ExpressionError,
    compile_expression,
    provably_exclusive,
)


def evaluate(source, variables=None, event=None, active=()):
    return compile_expression(source)(Env(variables or {}, event, lambda s: s in active))


def test_arithmetic_comparisons_and_logic():
    assert evaluate("n * 2 + 1 > 6 and not flag", {"n": 3, "flag": False}) is True
    assert evaluate("1 < x <= 3", {"x": 3}) is True
    assert evaluate("'a' if x else 'b'", {"x": 0}) == "b"
    assert evaluate("x in ('certus', 'vicra')", {"x": "vicra"}) is True
    assert evaluate("max(abs(-4), 2)") == 4
    assert evaluate("true and null == None") is True


def test_event_payload_and_name():
    event = Event("e_TOK", {"tracker": "certus", "pose": {"x": 1.5}})
    assert evaluate("event.tracker == 'certus'", event=event) is True
    assert evaluate("event.pose.x", event=event) == 1.5
    assert evaluate("event.name", event=event) == "e_TOK"


def test_active_asks_about_states():
    assert evaluate("active('Critical')", active={"Critical"}) is True
    assert compile_expression("active('A') or active('B')").states == {"A", "B"}


@pytest.mark.parametrize(
    "source",
    [
        "__import__('os').system('ls')",
        "x.__class__",
        "lambda: 1",
        "[i for i in x]",
        "open('f')",
        "a is None",
        "x := 1",
        "f'{x}'",
        "2 ** 10",
        "getattr(x, 'y')",
        "active(name)",
        "",
    ],
)
def test_anything_else_is_refused_at_load(source):
    with pytest.raises(ExpressionError):
        compile_expression(source)


def test_references_are_recorded_for_the_validator():
    expr = compile_expression("n > limit and event.speed < 2")
    assert expr.variables == {"n", "limit"} and expr.event_fields == {"speed"}


def test_runtime_failures_are_evaluation_errors():
    with pytest.raises(EvaluationError, match="no payload field 'x'"):
        evaluate("event.x", event=Event("e"))
    with pytest.raises(EvaluationError, match="unknown variable"):
        evaluate("missing + 1")


@pytest.mark.parametrize(
    ("a", "b", "exclusive"),
    [
        ("x > 2", "x <= 2", True),
        ("x > 2", "x < 5", False),
        ("x == 'a'", "x == 'b'", True),
        ("x == 'a'", "x != 'a'", True),
        ("flag", "not flag", True),
        ("flag and y > 1", "not flag", True),
        ("x >= 2", "x <= 2", False),
        ("x > 2", "y <= 2", False),
        ("x > 2 or z", "x <= 2", False),
        ("event.tag != 'robot_stop'", "event.tag == 'robot_stop'", True),
        ("3 < x", "x < 3", True),
    ],
)
def test_exclusivity_proofs_are_sound(a, b, exclusive):
    assert provably_exclusive(compile_expression(a), compile_expression(b)) is exclusive
