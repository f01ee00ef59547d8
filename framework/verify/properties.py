"""Safety properties of a chart, as a reviewer writes them: the model and its loader.

A properties file names the chart it is about and lists checks, each one of four
specification patterns (Dwyer, Avrunin and Corbett, 1999):

    properties: seeg
    checks:
      - name: stop_brakes_at_once
        responds: {to: {event: e_STOP, in: Moving}, within: 0, with: {request: stop}}
      - name: no_motion_between_fault_and_release
        precedes:
          after: {enter: Fault}
          forbid: {request: [move_fast, move_slow]}
          unless: {event: e_RELEASE}
      - name: no_fast_motion_when_crowded
        never: {request: move_fast, in: Critical}
      - name: a_tracker_while_moving
        always: {when: "not active('Moving') or tracker != 'none'"}

An *observation* is something that happens inside a step (an event processed, a
state entered or left, a configuration requested), narrowed by `in` (one of these
states is active at that moment) and `when` (a chart expression, seeing the
variables, `active()` and the step's `event`). A *condition* has only `in` and
`when` and is judged once the step is over. Every name is checked against the
chart, and every mistake is a located finding.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from framework import schema
from framework.errors import Finding, FindingsError, Location
from framework.statechart.expressions import Expression, ExpressionError, compile_expression
from framework.statechart.model import Kind, Statechart
from framework.yamlio import Document, load_yaml

OBSERVED = ("event", "enter", "exit", "request")
"""The kinds of observation, in the order a matcher names them."""

PATTERNS = ("never", "always", "responds", "precedes")

DEFAULT_UNANSWERED = 2

TIMER_EVENT = "after"
"""The name of the event a time event is processed as (framework.statechart.interpreter)."""


@dataclass(frozen=True, eq=False)
class Matcher:
    """What one observation or condition must show; every given part must hold.

    `kind` is one of `OBSERVED` (with the `names` it accepts: events, state paths or
    configuration tags) or "" for a condition. `states` are the full paths of which
    one must be active; `when` an expression that must be true."""

    kind: str = ""
    names: frozenset[str] = frozenset()
    states: tuple[str, ...] = ()
    when: Expression | None = None
    text: str = ""

    def describe(self) -> str:
        """The matcher as a reviewer wrote it."""
        return self.text


@dataclass(frozen=True, eq=False)
class Property:
    """One check: its name, pattern and matchers (`first`, `second`, `third` in the
    pattern's own order: never/always use `first`; responds `to`, `with`; precedes
    `after`, `forbid`, `unless`)."""

    name: str
    pattern: str
    first: Matcher
    second: Matcher | None = None
    third: Matcher | None = None
    within: int = 0
    doc: str = ""
    location: Location = field(default_factory=Location)

    def describe(self) -> str:
        """One line that says what the property claims."""
        if self.pattern == "never":
            return f"never {self.first.describe()}"
        if self.pattern == "always":
            return f"always {self.first.describe()}"
        if self.pattern == "responds":
            assert self.second is not None
            return (
                f"after {self.first.describe()}, within {self.within} step(s): "
                f"{self.second.describe()}"
            )
        assert self.second is not None and self.third is not None
        return (
            f"after {self.first.describe()}, no {self.second.describe()} "
            f"unless {self.third.describe()} first"
        )


@dataclass
class PropertySet:
    """A properties file, loaded and checked against its chart."""

    chart: str
    properties: list[Property]
    file: str
    unanswered: int = DEFAULT_UNANSWERED
    description: str = ""


def load_properties(path: str | Path, chart: Statechart) -> PropertySet:
    """Load a properties file and check every name in it against `chart`; raise
    `FindingsError` with every problem located (file:line:col)."""
    doc = load_yaml(path)
    problems = schema.check(doc, "properties")
    if problems:
        raise FindingsError(problems)
    return _Reader(doc, chart).read()


def properties_findings(path: str | Path, chart: Statechart | None = None) -> list[Finding]:
    """Every problem of a properties file (for `fw validate`); without a chart only
    its form is checked."""
    try:
        doc = load_yaml(path)
        problems = schema.check(doc, "properties")
        if problems or chart is None:
            return problems
        _Reader(doc, chart).read()
    except FindingsError as exc:
        return list(exc.findings)
    return []


def requested_tags(chart: Statechart) -> set[str]:
    """Every configuration tag the chart can request (states' `configure:` and
    `configure` actions)."""
    tags = {s.configure.tag for s in chart.states.values() if s.configure is not None}
    actions = [a for s in chart.states.values() for a in (*s.entry, *s.exit, *s.do)]
    actions += [a for t in chart.transitions() for a in t.effect]
    return tags | {a.tag for a in actions if a.kind == "configure"}


class _Reader:
    """Builds the property set from a schema-valid document, collecting findings."""

    def __init__(self, doc: Document, chart: Statechart):
        self.doc = doc
        self.chart = chart
        self.findings: list[Finding] = []
        self.tags = requested_tags(chart)
        self.events = chart.event_names() | {TIMER_EVENT}
        self.states = {p for p, s in chart.states.items() if p and not s.kind.is_pseudo}

    def error(self, code: str, message: str, where: tuple[Any, ...], hint: str = "") -> None:
        self.findings.append(Finding("error", code, message, self.doc.location(where), hint))

    def read(self) -> PropertySet:
        data = self.doc.data
        if data["properties"] != self.chart.name:
            self.error(
                "wrong-chart",
                f"these properties are about chart {data['properties']!r}, not {self.chart.name!r}",
                ("properties",),
            )
        out: list[Property] = []
        seen: set[str] = set()
        for i, spec in enumerate(data["checks"]):
            where = ("checks", i)
            if spec["name"] in seen:
                self.error("duplicate", f"two checks are named {spec['name']!r}", (*where, "name"))
            seen.add(spec["name"])
            given = [p for p in PATTERNS if p in spec]
            if len(given) != 1:
                self.error(
                    "pattern",
                    f"check {spec['name']!r} must use exactly one of "
                    f"{', '.join(PATTERNS)} (it has {', '.join(given) or 'none'})",
                    where,
                )
                continue
            prop = self.check(spec, given[0], where)
            if prop is not None:
                out.append(prop)
        if self.findings:
            raise FindingsError(self.findings)
        return PropertySet(
            self.chart.name,
            out,
            self.doc.file,
            data.get("unanswered", DEFAULT_UNANSWERED),
            data.get("description", ""),
        )

    def check(self, spec: dict[str, Any], pattern: str, where: tuple[Any, ...]) -> Property | None:
        body = spec[pattern]
        at = (*where, pattern)
        name, doc, location = spec["name"], spec.get("doc", ""), self.doc.location(where)
        if pattern == "never":
            return Property(
                name, pattern, self.matcher(body, at, observed=None), doc=doc, location=location
            )
        if pattern == "always":
            return Property(
                name, pattern, self.matcher(body, at, observed=False), doc=doc, location=location
            )
        if pattern == "responds":
            return Property(
                name,
                pattern,
                self.matcher(body["to"], (*at, "to"), observed=True),
                self.matcher(body["with"], (*at, "with"), observed=None),
                within=body.get("within", 0),
                doc=doc,
                location=location,
            )
        return Property(
            name,
            pattern,
            self.matcher(body["after"], (*at, "after"), observed=True),
            self.matcher(body["forbid"], (*at, "forbid"), observed=True),
            self.matcher(body["unless"], (*at, "unless"), observed=True),
            doc=doc,
            location=location,
        )

    def matcher(self, spec: dict[str, Any], at: tuple[Any, ...], observed: bool | None) -> Matcher:
        """A matcher from its spec; `observed` True: it must name what happens, False:
        it must be a condition, None: either."""
        kinds = [k for k in OBSERVED if k in spec]
        if len(kinds) > 1:
            self.error("matcher", f"one observation at a time: {' and '.join(kinds)}", at)
        if observed is True and not kinds:
            self.error(
                "matcher",
                f"this must name something that happens: one of {', '.join(OBSERVED)}",
                at,
            )
        if observed is False and kinds:
            self.error("matcher", "a condition has only `in` and `when`", (*at, kinds[0]))
        kind = kinds[0] if kinds else ""
        names: set[str] = set()
        if kind:
            for i, name in enumerate(_listed(spec[kind])):
                where = (*at, kind) if isinstance(spec[kind], str) else (*at, kind, i)
                names.add(self.name(kind, name, where))
        states = tuple(
            self.state(ref, (*at, "in") if isinstance(spec["in"], str) else (*at, "in", i))
            for i, ref in enumerate(_listed(spec.get("in", [])))
        )
        when = self.expression(spec["when"], (*at, "when")) if "when" in spec else None
        text = ", ".join(
            f"{k} {'/'.join(_listed(spec[k]))}" if k != "when" else f"when {spec[k]}"
            for k in (*OBSERVED, "in", "when")
            if k in spec
        )
        return Matcher(kind, frozenset(names), states, when, text)

    def name(self, kind: str, name: str, where: tuple[Any, ...]) -> str:
        if kind in ("enter", "exit"):
            return self.state(name, where)
        known = self.events if kind == "event" else self.tags
        if name not in known:
            what = "an event of chart" if kind == "event" else "a configuration requested by"
            self.error(
                f"unknown-{kind}",
                f"{name!r} is not {what} {self.chart.name!r}",
                where,
                _close(name, known),
            )
        return name

    def state(self, ref: str, where: tuple[Any, ...]) -> str:
        try:
            state = self.chart.state(ref)
        except KeyError:
            self.error(
                "unknown-state",
                f"chart {self.chart.name!r} has no state {ref!r}",
                where,
                _close(ref.rsplit(".", 1)[-1], {p.rsplit(".", 1)[-1] for p in self.states}),
            )
            return ref
        if state.kind.is_pseudo or state.kind is Kind.JUNCTION:
            self.error(
                "pseudo-state", f"{ref!r} is a {state.kind.value}: it is never active", where
            )
        return state.path

    def expression(self, source: str, where: tuple[Any, ...]) -> Expression | None:
        try:
            expr = compile_expression(source)
        except ExpressionError as exc:
            self.error("expression", str(exc), where)
            return None
        for name in sorted(expr.variables - set(self.chart.variables)):
            self.error(
                "unknown-variable",
                f"chart {self.chart.name!r} has no variable {name!r}",
                where,
                _close(name, set(self.chart.variables)),
            )
        for ref in sorted(expr.states):
            try:
                self.chart.state(ref)
            except KeyError:
                self.error(
                    "unknown-state", f"chart {self.chart.name!r} has no state {ref!r}", where
                )
        return expr


def _listed(value: str | list[str]) -> list[str]:
    return [value] if isinstance(value, str) else list(value)


def _close(name: str, known: set[str]) -> str:
    close = difflib.get_close_matches(name, sorted(known), n=1)
    return f"did you mean {close[0]!r}?" if close else ""
