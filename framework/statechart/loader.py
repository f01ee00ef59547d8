"""Build a `Statechart` model from YAML files (see docs/statecharts.md).

Loading is: safe YAML parse with positions, JSON Schema check, then model
build (includes, names, expressions, durations). Every defect becomes a
located `Finding`; `load_statechart` raises `FindingsError` carrying all of
them, so a user fixes a file in one pass instead of one error per run.
"""

from __future__ import annotations

import difflib
import os
from pathlib import Path
from typing import Any

from framework import schema
from framework.durations import parse_duration
from framework.errors import Finding, FindingsError, FwError, Location
from framework.statechart.expressions import ExpressionError, compile_expression
from framework.statechart.model import (
    VALUE_TYPES,
    Action,
    ConfigureRequest,
    EventSpec,
    Kind,
    State,
    Statechart,
    Transition,
    Value,
    VariableSpec,
    has_type,
)
from framework.statechart.validator import validate_chart
from framework.yamlio import Document, PathKey, load_yaml, load_yaml_text


class _Builder:
    """Builds one chart; collects findings instead of stopping at the first."""

    def __init__(self) -> None:
        self.findings: list[Finding] = []
        self.states: dict[str, State] = {}
        self.events: dict[str, EventSpec] = {}
        self.variables: dict[str, VariableSpec] = {}
        self.files: list[str] = []
        self.order = 0
        self.pending_refs: list[tuple[str, State | Transition, str, Location]] = []
        self.by_name: dict[str, list[State]] | None = None

    def error(self, code: str, message: str, location: Location, hint: str = "") -> None:
        self.findings.append(Finding("error", code, message, location, hint))

    # -- documents -------------------------------------------------------------------
    def read(
        self,
        path: Path,
        include_chain: tuple[str, ...],
        at: Location | None,
        text: str | None = None,
    ) -> Document | None:
        resolved = os.path.realpath(path)  # a link loop is reported by the read
        if resolved in include_chain:
            cycle = " -> ".join([*include_chain, resolved])
            self.error("include-cycle", f"include cycle: {cycle}", at or Location(str(path)))
            return None
        try:
            doc = load_yaml(path) if text is None else load_yaml_text(text, str(path))
        except FwError as exc:  # YamlError and friends
            location = getattr(exc, "location", Location(str(path)))
            message = getattr(exc, "message", str(exc))
            if at is not None and getattr(location, "line", 0) == 0:
                location, message = at, f"{str(path)!r}: {message}"
            self.error("yaml", message, location, getattr(exc, "hint", ""))
            return None
        problems = schema.check(doc, "statechart")
        if problems:
            self.findings.extend(problems)
            return None
        self.files.append(str(path))
        self.declare_vocabulary(doc)
        return doc

    def check_limits(self, event: str, name: str, spec: dict[str, Any], loc: Location) -> None:
        """Limits only on numbers, and the lower one first; allowed values of the field's
        type."""
        wrong = [v for v in spec.get("values", ()) if not has_type(v, spec["type"])]
        if wrong:
            self.error(
                "payload-values",
                f"payload field {event}.{name} is a {spec['type']}: "
                f"{', '.join(repr(v) for v in wrong)} cannot be one of its values",
                loc,
            )
        low, high = spec.get("min"), spec.get("max")
        if (low is not None or high is not None) and spec["type"] not in ("number", "integer"):
            self.error(
                "payload-limits",
                f"payload field {event}.{name} is a {spec['type']}: min/max apply to numbers",
                loc,
            )
        elif low is not None and high is not None and low > high:
            self.error(
                "payload-limits",
                f"payload field {event}.{name}: min {low:g} is above max {high:g}",
                loc,
            )

    def declare_vocabulary(self, doc: Document) -> None:
        for name, spec in (doc.data.get("events") or {}).items():
            loc = doc.location(("events", name))
            if isinstance(spec, dict):
                types, fields = {}, {}
                for field_name, field_spec in (spec.get("payload") or {}).items():
                    if isinstance(field_spec, dict):
                        types[field_name] = field_spec["type"]
                        fields[field_name] = {k: v for k, v in field_spec.items() if k != "type"}
                        self.check_limits(name, field_name, field_spec, loc)
                    else:
                        types[field_name] = field_spec
                event = EventSpec(name, spec.get("doc", ""), types, loc, fields)
            else:
                event = EventSpec(name, spec or "", {}, loc)
            known = self.events.get(name)
            if known is not None and (known.payload, known.fields) != (event.payload, event.fields):
                self.error(
                    "event-conflict",
                    f"event {name!r} declared twice with different "
                    f"payloads (first at {known.location})",
                    loc,
                )
            self.events.setdefault(name, event)
        for name, spec in (doc.data.get("variables") or {}).items():
            loc = doc.location(("variables", name))
            if isinstance(spec, dict):
                initial, vtype = spec["initial"], spec.get("type")
                doc_text = spec.get("doc", "")
            else:
                initial, vtype, doc_text = spec, None, ""
            vtype = vtype or _infer_type(initial)
            if vtype in VALUE_TYPES and not has_type(initial, vtype):
                self.error(
                    "variable-type",
                    f"initial value {initial!r} of {name!r} is not of type {vtype}",
                    loc,
                )
            variable = VariableSpec(name, vtype, initial, doc_text, loc)
            known = self.variables.get(name)
            if known is not None and (known.type, known.initial) != (vtype, initial):
                self.error(
                    "variable-conflict",
                    f"variable {name!r} declared twice differently (first at {known.location})",
                    loc,
                )
            self.variables.setdefault(name, variable)

    # -- states ----------------------------------------------------------------------
    def build_children(
        self,
        parent: State,
        doc: Document,
        specs: list[dict[str, Any]],
        base: PathKey,
        scope: str,
        chain: tuple[str, ...],
    ) -> None:
        seen: dict[str, Location] = {}
        for i, spec in enumerate(specs):
            here = (*base, i)
            loc = doc.location((*here, "name"))
            name = spec["name"]
            if name in seen:
                self.error(
                    "duplicate-state",
                    f"state {name!r} is defined twice in "
                    f"{parent.path or 'the chart root'} (first at line {seen[name].line})",
                    loc,
                    "rename one of them",
                )
                continue
            seen[name] = loc
            self.build_state(parent, doc, spec, here, scope, chain)

    def build_state(
        self,
        parent: State,
        doc: Document,
        spec: dict[str, Any],
        here: PathKey,
        scope: str,
        chain: tuple[str, ...],
    ) -> State:
        name = spec["name"]
        path = f"{parent.path}.{name}" if parent.path else name
        kind = Kind(spec["type"]) if "type" in spec else Kind.ATOMIC
        state = State(
            name=name,
            path=path,
            kind=kind,
            location=doc.location(here),
            parent=parent,
            doc=spec.get("doc", ""),
            scope=scope,
            depth=parent.depth + 1,
        )
        parent.children.append(state)
        self.states[path] = state
        children, child_base, child_doc = spec.get("states"), (*here, "states"), doc
        state.initial_ref = spec.get("initial")
        if "include" in spec:
            children, child_doc = self.include(state, doc, spec, here, chain)
            child_base = ("states",)
        if children:
            if kind is Kind.ATOMIC:
                state.kind = Kind.COMPOUND
            elif kind is not Kind.PARALLEL:
                self.error(
                    "children",
                    f"a {kind.value} state cannot have child states",
                    doc.location((*here, "type")),
                    "remove `states` or `type`",
                )
            if child_doc is not None:
                child_scope = path if child_doc is not doc else scope
                child_chain = (
                    (*chain, os.path.realpath(child_doc.file)) if child_doc is not doc else chain
                )
                self.build_children(
                    state, child_doc, children, child_base, child_scope, child_chain
                )
        elif kind is Kind.PARALLEL:
            self.error(
                "parallel-empty", "a parallel state needs regions (child states)", state.location
            )
        if state.initial_ref is not None:
            self.pending_refs.append(
                ("initial", state, state.initial_ref, doc.location((*here, "initial")))
            )
        if "default" in spec:
            state.default_ref = spec["default"]
            self.pending_refs.append(
                ("default", state, spec["default"], doc.location((*here, "default")))
            )
        state.entry = self.actions(doc, spec.get("entry"), (*here, "entry"))
        state.exit = self.actions(doc, spec.get("exit"), (*here, "exit"))
        state.do = self.actions(doc, spec.get("do"), (*here, "do"))
        if "configure" in spec:
            state.configure = self.configure(doc, spec["configure"], (*here, "configure"))
        for j, tspec in enumerate(spec.get("transitions") or []):
            self.transition(state, doc, tspec, (*here, "transitions", j))
        return state

    def include(
        self,
        state: State,
        doc: Document,
        spec: dict[str, Any],
        here: PathKey,
        chain: tuple[str, ...],
    ) -> tuple[list[dict[str, Any]] | None, Document | None]:
        at = doc.location((*here, "include"))
        if "states" in spec:
            self.error("include", "a state with `include` cannot also list `states`", at)
            return None, None
        target = Path(doc.file).parent / spec["include"]
        sub = self.read(target, (*chain, os.path.realpath(doc.file)), at)
        if sub is None:
            return None, None
        if state.initial_ref is None:
            state.initial_ref = sub.data.get("initial")
        return sub.data.get("states"), sub

    def configure(self, doc: Document, spec: Any, here: PathKey) -> ConfigureRequest:
        loc = doc.location(here)
        if isinstance(spec, str):
            return ConfigureRequest(spec, -1.0, loc)
        timeout = self.duration(doc, spec.get("timeout", -1.0), (*here, "timeout"))
        return ConfigureRequest(spec["tag"], timeout, loc)

    def duration(self, doc: Document, value: Any, here: PathKey) -> float:
        try:
            return parse_duration(value)
        except ValueError as exc:
            self.error("duration", str(exc), doc.location(here))
            return 0.0

    def transition(self, state: State, doc: Document, spec: dict[str, Any], here: PathKey) -> None:
        loc = doc.location(here)
        raw_events = spec.get("event", [])
        events = frozenset([raw_events] if isinstance(raw_events, str) else raw_events)
        after = self.duration(doc, spec["after"], (*here, "after")) if "after" in spec else None
        if events and after is not None:
            self.error(
                "trigger",
                "a transition has either `event` or `after`, not both",
                loc,
                "split it into two transitions",
            )
        guard, is_else = None, False
        if "guard" in spec:
            if spec["guard"].strip() == "else":
                is_else = True
            else:
                guard = self.expression(doc, spec["guard"], (*here, "guard"))
        self.order += 1
        transition = Transition(
            source=state,
            target_ref=spec.get("target"),
            events=events,
            after=after,
            guard=guard,
            is_else=is_else,
            effect=self.actions(doc, spec.get("effect"), (*here, "effect")),
            priority=spec.get("priority", 0),
            order=self.order,
            location=loc,
            doc=spec.get("doc", ""),
        )
        state.transitions.append(transition)
        if transition.target_ref is not None:
            self.pending_refs.append(
                ("target", transition, transition.target_ref, doc.location((*here, "target")))
            )

    def expression(self, doc: Document, source: str, here: PathKey):
        try:
            return compile_expression(source)
        except ExpressionError as exc:
            self.error("expression", str(exc), doc.location(here))
            return None

    # -- actions ---------------------------------------------------------------------
    def value(self, doc: Document, raw: Any, here: PathKey) -> Value:
        if isinstance(raw, str) and raw.startswith("="):
            return Value(expression=self.expression(doc, raw[1:], here))
        return Value(literal=raw)

    def values(self, doc: Document, raw: dict[str, Any] | None, here: PathKey) -> dict[str, Value]:
        return {k: self.value(doc, v, (*here, k)) for k, v in (raw or {}).items()}

    def actions(
        self, doc: Document, specs: list[dict[str, Any]] | None, here: PathKey
    ) -> tuple[Action, ...]:
        out = []
        for i, spec in enumerate(specs or []):
            ((kind, arg),) = spec.items()
            at = (*here, i, kind)
            loc = doc.location(at)
            if kind in ("raise", "send"):
                if isinstance(arg, str):
                    out.append(Action(kind, loc, event=arg))
                else:
                    out.append(
                        Action(
                            kind,
                            loc,
                            event=arg["event"],
                            payload=self.values(doc, arg.get("payload"), (*at, "payload")),
                        )
                    )
            elif kind == "configure":
                out.append(Action(kind, loc, tag=arg))
            elif kind == "set":
                out.append(Action(kind, loc, assignments=self.values(doc, arg, at)))
            elif kind == "write":
                out.append(
                    Action(
                        kind,
                        loc,
                        port=arg["port"],
                        value=self.value(doc, arg["value"], (*at, "value")),
                    )
                )
            elif kind == "call":
                if isinstance(arg, str):
                    out.append(Action(kind, loc, operation=arg))
                else:
                    out.append(
                        Action(
                            kind,
                            loc,
                            operation=arg["operation"],
                            args=self.values(doc, arg.get("args"), (*at, "args")),
                        )
                    )
            else:
                out.append(Action("log", loc, message=str(arg)))
        return tuple(out)

    # -- references ------------------------------------------------------------------
    def resolve(self, ref: str, scope: str, location: Location) -> State | None:
        if ref in self.states:
            return self.states[ref]
        if self.by_name is None:
            self.by_name = {}
            for state in self.states.values():
                self.by_name.setdefault(state.name, []).append(state)
        last = ref.rsplit(".", 1)[-1]
        candidates = [
            s for s in self.by_name.get(last, ()) if s.path.endswith("." + ref) or s.path == ref
        ]
        if scope:
            scoped = [s for s in candidates if s.path.startswith(scope + ".")]
            if len(scoped) == 1:
                return scoped[0]
        if len(candidates) == 1:
            return candidates[0]
        if candidates:
            names = ", ".join(sorted(s.path for s in candidates))
            self.error(
                "ambiguous",
                f"{ref!r} names several states: {names}",
                location,
                "write the dotted path of the one you mean",
            )
            return None
        names = sorted({s.name for s in self.states.values()} | set(self.states))
        close = difflib.get_close_matches(ref, names, n=1)
        self.error(
            "unknown-state",
            f"unknown state {ref!r}",
            location,
            f"did you mean {close[0]!r}?" if close else "check the spelling",
        )
        return None

    def resolve_all(self, chart: Statechart, safe_loc: Location | None) -> None:
        for what, owner, ref, loc in self.pending_refs:
            if what == "initial":  # a direct child by that name comes first
                child = next((c for c in owner.children if c.name == ref), None)
                if child is not None:
                    owner.initial = child
                    continue
            scope = owner.source.scope if isinstance(owner, Transition) else owner.scope
            setattr(owner, what, self.resolve(ref, scope, loc))
        if chart.safe_state_ref is not None:
            chart.safe_state = self.resolve(chart.safe_state_ref, "", safe_loc or Location())


def _infer_type(value: Any) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    return "string"


def build_statechart(
    path: str | Path, text: str | None = None, at: Location | None = None
) -> tuple[Statechart | None, list[Finding]]:
    """Load a chart file (or `text` named `path`); return the model (None if it cannot be
    built) and all findings. `at` is where another file named this one (a topology's
    `statechart:`): a file that cannot be read is reported there."""
    builder = _Builder()
    file = Path(path)
    doc = builder.read(file, (), at, text)
    if doc is None:
        return None, builder.findings
    data = doc.data
    root = State(
        name=data["statechart"],
        path="",
        kind=Kind.COMPOUND,
        location=doc.location(()),
        initial_ref=data.get("initial"),
    )
    builder.states[""] = root
    builder.build_children(root, doc, data["states"], ("states",), "", (os.path.realpath(file),))
    if root.initial_ref is not None:
        builder.pending_refs.append(("initial", root, root.initial_ref, doc.location(("initial",))))
    chart = Statechart(
        name=data["statechart"],
        root=root,
        file=str(file),
        description=data.get("description", ""),
        events=builder.events,
        variables=builder.variables,
        safe_state_ref=data.get("safe_state"),
        files=builder.files,
        states=builder.states,
    )
    if "configure_timeout" in data:
        chart.configure_timeout = builder.duration(
            doc, data["configure_timeout"], ("configure_timeout",)
        )
    builder.resolve_all(chart, doc.location(("safe_state",)) if "safe_state" in data else None)
    for index, state in enumerate(root.walk()):
        state.index = index
        if state.configure is not None and state.configure.timeout < 0:
            state.configure.timeout = chart.configure_timeout
        state.transitions.sort(key=lambda t: (-t.priority, t.order))
    return chart, builder.findings


def load_statechart(path: str | Path, validate: bool = True, text: str | None = None) -> Statechart:
    """Load (and by default validate) a chart; raise `FindingsError` listing every error."""
    chart, findings = build_statechart(path, text)
    errors = [f for f in findings if f.severity == "error"]
    if chart is None or errors:
        raise FindingsError(findings)
    if validate:
        found = validate_chart(chart)
        if any(f.severity == "error" for f in found):
            raise FindingsError(found)
    return chart
