"""Static checks of a statechart: every defect that can be proven without running it.

Each check returns located `Finding`s with a fix hint. Errors make
`fw validate` exit 1; warnings point at things that are legal but probably
wrong. The checks are listed in docs/statecharts.md ("What fw validate proves").
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

from framework.errors import Finding, Location
from framework.statechart.expressions import Expression, provably_exclusive
from framework.statechart.model import (
    BUILTIN_EVENTS,
    COMPONENT_BACK,
    COMPONENT_LOST,
    CONFIG_DONE,
    CONFIG_FAILED,
    Action,
    Kind,
    State,
    Statechart,
    Transition,
)

_BUILTIN_FIELDS = {
    CONFIG_DONE: {"tag", "state"},
    CONFIG_FAILED: {"tag", "state", "reason", "step"},
    COMPONENT_LOST: {"component", "process"},
    COMPONENT_BACK: {"component", "process"},
}
_TIMER_FIELDS = {"state", "delay"}


class _Checker:
    def __init__(self, chart: Statechart, tags: dict[str, Location] | None):
        self.chart = chart
        self.tags = tags
        self.findings: list[Finding] = []
        self.states = list(chart.root.walk())
        self.transitions = chart.transitions()

    def error(self, code: str, message: str, location: Location, hint: str = "") -> None:
        self.findings.append(Finding("error", code, message, location, hint))

    def warn(self, code: str, message: str, location: Location, hint: str = "") -> None:
        self.findings.append(Finding("warning", code, message, location, hint))

    def run(self) -> list[Finding]:
        self.structure()
        self.transitions_shape()
        reachable = self.reachability()
        self.dead_ends(reachable)
        self.safe_state(reachable)
        self.determinism()
        self.shadowing()
        self.event_closure()
        self.names()
        self.connector_cycles()
        self.livelocks()
        self.configuration_tags()
        self.losses()
        return self.findings

    # -- structure -------------------------------------------------------------
    def structure(self) -> None:
        for s in self.states:
            real = [c for c in s.children if not c.kind.is_pseudo]
            if s.kind is Kind.COMPOUND:
                if s.initial_ref is None:
                    first = real[0].name if real else "<child>"
                    self.error(
                        "no-initial",
                        f"composite state {s.path or s.name!r} has no initial state",
                        s.location,
                        f"add `initial: {first}`",
                    )
                elif s.initial is not None and s.initial.parent is not s:
                    self.error(
                        "initial-not-child",
                        f"initial state {s.initial.path!r} is not a child of {s.path or s.name!r}",
                        s.location,
                        "name one of its direct children",
                    )
            if s.kind is Kind.PARALLEL:
                if s.initial_ref is not None:
                    self.error(
                        "parallel-initial",
                        f"parallel state {s.path!r} enters all its "
                        "regions; `initial` is meaningless here",
                        s.location,
                    )
                for region in s.children:
                    if region.kind is not Kind.COMPOUND:
                        self.error(
                            "region",
                            f"region {region.path!r} of parallel state "
                            f"{s.path!r} must be a composite state (with `states`)",
                            region.location,
                            "wrap it in a state with `states:`",
                        )
            if s.kind is Kind.FINAL:
                if s.transitions:
                    self.error(
                        "final-out",
                        f"final state {s.path!r} has outgoing transitions",
                        s.transitions[0].location,
                        "a final state is never left; move them to its parent",
                    )
                if s.do or s.configure is not None:
                    self.error(
                        "final-work",
                        f"final state {s.path!r} cannot have `do` or `configure`",
                        s.location,
                    )
            if s.kind is Kind.JUNCTION:
                self.junction(s)
            if s.kind in (Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY):
                self.history(s)
            if s.kind.is_pseudo and (s.entry or s.exit or s.do or s.configure is not None):
                self.error(
                    "pseudo-actions",
                    f"{s.kind.value} {s.path!r} is never active, so "
                    "it cannot have entry/exit/do/configure",
                    s.location,
                    "put the actions on the branches (effect)",
                )
            if s.configure is not None and s.configure.timeout <= 0:
                self.error(
                    "timeout",
                    f"configuration timeout of {s.path!r} must be positive",
                    s.configure.location,
                )
            if s.configure is not None and not self.handles(s, CONFIG_FAILED):
                self.error(
                    "unhandled-failure",
                    f"state {s.path!r} requests configuration "
                    f"{s.configure.tag!r} but neither it nor a parent handles "
                    f"'{CONFIG_FAILED}'",
                    s.configure.location,
                    f"add a transition on `{CONFIG_FAILED}` to a safe state",
                )

    def losses(self) -> None:
        """A chart that configures a deployment's components should say what a lost one
        means (checked with a topology only)."""
        if self.tags is None:  # the chart alone (fw run): no deployment, no processes to lose
            return
        configures = any(s.configure is not None for s in self.states)
        if configures and not any(COMPONENT_LOST in t.events for t in self.transitions):
            self.warn(
                "unhandled-loss",
                f"no transition handles '{COMPONENT_LOST}': when a process dies the chart "
                "stays where it is (the robot side still stops by itself)",
                self.chart.root.location,
                f"add a transition on `{COMPONENT_LOST}` to a fault state",
            )

    def junction(self, s: State) -> None:
        if not s.transitions:
            self.error(
                "junction-empty",
                f"junction {s.path!r} has no outgoing branch",
                s.location,
                "add branches with guards and one `guard: else`",
            )
        elses = [t for t in s.transitions if t.is_else]
        if len(elses) > 1:
            self.error(
                "junction-else",
                f"junction {s.path!r} has {len(elses)} else branches",
                elses[1].location,
            )
        for t in s.transitions:
            if t.events or t.after is not None:
                self.error(
                    "junction-trigger",
                    f"a branch of junction {s.path!r} cannot wait for an event or time",
                    t.location,
                    "remove `event`/`after`",
                )
            if t.target_ref is None:
                self.error(
                    "junction-target", f"a branch of junction {s.path!r} needs a target", t.location
                )
        guarded = all(t.guard is not None for t in s.transitions)
        if s.transitions and guarded and not elses:
            self.warn(
                "junction-blocks",
                f"junction {s.path!r} may block: no branch is certain to be enabled",
                s.location,
                "add a `guard: else` branch",
            )

    def history(self, s: State) -> None:
        parent = s.parent
        if parent is None or parent.kind is not Kind.COMPOUND:
            self.error(
                "history-parent",
                f"history {s.path!r} must be a child of a composite (non-parallel) state",
                s.location,
            )
        if s.transitions:
            self.error(
                "history-out",
                f"history {s.path!r} cannot have transitions",
                s.transitions[0].location,
                "use `default:` for the fallback target",
            )
        if s.default is not None and parent is not None and not s.default.is_descendant_of(parent):
            self.error(
                "history-default",
                f"default {s.default.path!r} of history {s.path!r} is not inside {parent.path!r}",
                s.location,
            )

    def handles(self, state: State, event: str) -> bool:
        node: State | None = state
        while node is not None:
            if any(event in t.events for t in node.transitions):
                return True
            node = node.parent
        return False

    def transitions_shape(self) -> None:
        for t in self.transitions:
            pseudo = t.source.kind is Kind.JUNCTION
            if t.is_else and not pseudo:
                self.error(
                    "else",
                    "`guard: else` is only meaningful on junction branches",
                    t.location,
                    "write the negated condition instead",
                )
            if t.after is not None and t.after <= 0:
                self.error("after", f"time event after {t.after:g} s must be positive", t.location)
            if t.is_completion and t.target_ref is None and not pseudo:
                self.error(
                    "livelock",
                    "a completion transition without a target would fire forever",
                    t.location,
                    "add an `event`, `after` or `target`",
                )
            if (
                t.is_completion
                and not pseudo
                and t.source.kind is Kind.COMPOUND
                and not any(c.kind is Kind.FINAL for c in t.source.children)
            ):
                self.error(
                    "completion-never",
                    f"completion transition of {t.source.path!r} "
                    "never fires: the state has no final child",
                    t.location,
                    "add a child with `type: final`, or give the transition an event",
                )
            if t.is_completion and not pseudo and t.source.kind is Kind.PARALLEL:
                for region in t.source.children:
                    if not any(c.kind is Kind.FINAL for c in region.children):
                        self.error(
                            "completion-never",
                            f"completion transition of "
                            f"{t.source.path!r} never fires: region {region.name!r} "
                            "has no final state",
                            t.location,
                        )
            target = t.target
            if (
                target is not None
                and target.kind in (Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY)
                and t.source.is_descendant_of(target.parent)
            ):  # type: ignore[arg-type]
                self.warn(
                    "history-inside",
                    f"transition to {target.path!r} from inside its "
                    "own state re-enters what was just left",
                    t.location,
                )

    # -- reachability -------------------------------------------------------------
    def defaults(self, state: State, out: set[State]) -> None:
        if state.kind is Kind.PARALLEL:
            for region in state.children:
                if region not in out:
                    out.add(region)
                    self.defaults(region, out)
        elif state.kind is Kind.COMPOUND and state.initial is not None:
            self.enter(state.initial, out)

    def enter(self, target: State, out: set[State]) -> None:
        """Every state that may become active when `target` is entered."""
        if target in out:
            return
        out.add(target)
        for anc in target.ancestors():
            out.add(anc)
        if target.kind is Kind.JUNCTION:
            for branch in target.transitions:
                if branch.target is not None:
                    self.enter(branch.target, out)
        elif target.kind in (Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY):
            parent = target.parent
            if target.default is not None:
                self.enter(target.default, out)
            elif parent is not None:
                self.defaults(parent, out)
        else:
            self.defaults(target, out)

    def reachability(self) -> set[State]:
        reached: set[State] = set()
        self.defaults(self.chart.root, reached)
        reached.add(self.chart.root)
        work = list(reached)
        while work:
            state = work.pop()
            for t in state.transitions:
                if t.target is None:
                    continue
                new: set[State] = set()
                self.enter(t.target, new)
                for s in new - reached:
                    reached.add(s)
                    work.append(s)
                    for child in s.children:  # a reached region's defaults
                        if s.kind is Kind.PARALLEL and child not in reached:
                            reached.add(child)
                            work.append(child)
        for s in self.states:
            if s not in reached and s.kind is not Kind.JUNCTION and s.parent is not None:
                if s.kind in (Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY):
                    self.warn("unused", f"history {s.path!r} is never a target", s.location)
                elif s.parent in reached or s.parent is self.chart.root:
                    self.error(
                        "unreachable",
                        f"state {s.path!r} can never become active",
                        s.location,
                        "add a transition into it, or remove it",
                    )
            elif (
                s.kind is Kind.JUNCTION
                and not any(t.target is s for t in self.transitions)
                and not any(x.initial is s for x in self.states)
            ):
                self.warn("unused", f"junction {s.path!r} is never a target", s.location)
        return reached

    def leaves_of(self, target: State) -> set[State]:
        entered: set[State] = set()
        self.enter(target, entered)
        return {s for s in entered if s.kind in (Kind.ATOMIC, Kind.FINAL)}

    def exits_from(self, state: State) -> list[Transition]:
        out = []
        node: State | None = state
        while node is not None:
            out.extend(t for t in node.transitions if t.target_ref is not None)
            node = node.parent
        return out

    def in_parallel(self, state: State) -> bool:
        return any(a.kind is Kind.PARALLEL for a in state.ancestors())

    def dead_ends(self, reachable: set[State]) -> None:
        for s in self.states:
            if (
                s.kind is Kind.ATOMIC
                and s in reachable
                and not self.exits_from(s)
                and not self.in_parallel(s)
            ):
                self.error(
                    "dead-end",
                    f"state {s.path!r} has no way out and is not final",
                    s.location,
                    "add a transition, or make it `type: final`",
                )

    def safe_state(self, reachable: set[State]) -> None:
        safe = self.chart.safe_state
        if safe is None:
            return
        good = {s for s in safe.walk() if s.kind in (Kind.ATOMIC, Kind.FINAL)} | {safe}
        leaves = [s for s in self.states if s.kind is Kind.ATOMIC and s in reachable]
        changed = True
        while changed:
            changed = False
            for leaf in leaves:
                if leaf in good:
                    continue
                if self.co_active_good(leaf, good, leaves):
                    good.add(leaf)
                    changed = True
                    continue
                for t in self.exits_from(leaf):
                    if t.target is None:
                        continue
                    if t.target in good or self.leaves_of(t.target) & good:
                        good.add(leaf)
                        changed = True
                        break
        for leaf in leaves:
            if leaf not in good:
                self.error(
                    "safe-unreachable",
                    f"safe state {safe.path!r} cannot be reached from {leaf.path!r}",
                    leaf.location,
                    "add a transition (on the state or a parent) towards the safe state",
                )

    def co_active_good(self, leaf: State, good: set[State], leaves: list[State]) -> bool:
        """A leaf inside a parallel state shares its configuration with the other regions:
        if one of their leaves can reach the safe state, the configuration can."""
        for anc in leaf.ancestors():
            if anc.kind is Kind.PARALLEL:
                region = next(r for r in anc.children if leaf is r or leaf.is_descendant_of(r))
                if any(
                    o in good and o.is_descendant_of(anc) and not o.is_descendant_of(region)
                    for o in leaves
                ):
                    return True
        return False

    # -- determinism ---------------------------------------------------------------
    @staticmethod
    def overlap(a: Transition, b: Transition) -> bool:
        if a.events or b.events:
            return bool(a.events & b.events)
        if a.after is not None or b.after is not None:
            return a.after == b.after
        return True

    def determinism(self) -> None:
        for s in self.states:
            if s.kind is Kind.JUNCTION:
                continue
            ts = s.transitions
            reported: set[int] = set()
            for i, a in enumerate(ts):
                for b in ts[i + 1 :]:
                    if id(b) in reported:
                        continue
                    if a.priority != b.priority or not self.overlap(a, b):
                        continue
                    if provably_exclusive(a.guard, b.guard):
                        continue
                    if a.guard is None:
                        self.error(
                            "shadowed",
                            f"transition at line {b.location.line} never "
                            f"fires: the unguarded one at line {a.location.line} on the "
                            "same trigger always wins",
                            b.location,
                            "remove it, add a guard to the first, or set `priority`",
                        )
                        reported.add(id(b))
                        continue
                    shared = ", ".join(sorted(a.events & b.events)) or "completion"
                    self.error(
                        "nondeterministic",
                        f"transitions at lines {a.location.line} and "
                        f"{b.location.line} of {s.path!r} both take {shared} with equal "
                        "priority and guards that may both hold",
                        b.location,
                        "give one a higher `priority:` or make the guards exclusive",
                    )
                    reported.add(id(b))

    def shadowing(self) -> None:
        for t in self.transitions:
            for anc in t.source.ancestors():
                for outer in anc.transitions:
                    if (
                        outer.guard is None
                        and outer.events
                        and t.events
                        and t.events <= outer.events
                        and self.always_enabled(outer)
                    ):
                        self.error(
                            "shadowed",
                            f"transition on {', '.join(sorted(t.events))} "
                            f"of {t.source.path!r} never fires: parent {anc.path!r} "
                            f"always takes it first (outer-first priority, line "
                            f"{outer.location.line})",
                            t.location,
                            "guard the outer transition, or handle the event there",
                        )
                        break
                else:
                    continue
                break

    @staticmethod
    def always_enabled(t: Transition) -> bool:
        target = t.target
        if target is None or target.kind is not Kind.JUNCTION:
            return True
        return any(b.is_else or b.guard is None for b in target.transitions)

    # -- events and names ----------------------------------------------------------
    def all_actions(self) -> Iterable[tuple[Action, Transition | None]]:
        for s in self.states:
            for action in (*s.entry, *s.exit, *s.do):
                yield action, None
        for t in self.transitions:
            for action in t.effect:
                yield action, t

    def event_closure(self) -> None:
        declared = self.chart.events
        raised = {a.event: a for a, _ in self.all_actions() if a.kind == "raise"}
        sent = {a.event for a, _ in self.all_actions() if a.kind == "send"}
        consumed: dict[str, Transition] = {}
        for t in self.transitions:
            for name in sorted(t.events):
                consumed.setdefault(name, t)
                if name not in declared and name not in raised and name not in BUILTIN_EVENTS:
                    close = difflib.get_close_matches(name, [*declared, *BUILTIN_EVENTS], n=1)
                    self.error(
                        "undeclared-event",
                        f"event {name!r} is neither declared nor raised by the chart",
                        t.location,
                        f"did you mean {close[0]!r}?" if close else "declare it under `events:`",
                    )
        for action, _ in self.all_actions():
            if (
                action.kind in ("raise", "send")
                and action.event not in declared
                and action.event not in BUILTIN_EVENTS
            ):
                self.error(
                    "undeclared-event",
                    f"{action.kind} of undeclared event {action.event!r}",
                    action.location,
                    "declare it under `events:`",
                )
        for name, spec in declared.items():
            if name not in consumed and name not in sent:
                self.warn(
                    "unused-event",
                    f"declared event {name!r} is never consumed",
                    spec.location,
                    "remove it, or handle it somewhere",
                )
        for name, action in raised.items():
            if name not in consumed:
                self.warn(
                    "unconsumed-raise",
                    f"raised event {name!r} is consumed by no "
                    "transition, so it will always be reported unhandled",
                    action.location,
                )

    def names(self) -> None:
        variables = self.chart.variables
        for t in self.transitions:
            if t.guard is not None:
                self.expression(t.guard, t.location, self.fields_for(t))
            for action in t.effect:
                self.action_names(action, self.fields_for(t))
        for s in self.states:
            for action in (*s.entry, *s.exit, *s.do):
                self.action_names(action, None)
        del variables

    def fields_for(self, t: Transition, seen: frozenset[int] = frozenset()) -> set[str] | None:
        """Payload fields every trigger of `t` carries (None: unknown, don't check)."""
        if t.source.kind is Kind.JUNCTION:  # a branch sees the event of whatever led here
            incoming = [x for x in self.transitions if x.target is t.source]
            if not incoming or any(st.initial is t.source for st in self.states) or id(t) in seen:
                return None
            fields: set[str] | None = None
            for x in incoming:
                got = self.fields_for(x, seen | {id(t)})
                if got is None:
                    return None
                fields = got if fields is None else fields & got
            return fields
        if t.after is not None:
            return set(_TIMER_FIELDS)
        if not t.events:
            return set()
        fields = None
        for name in t.events:
            if name in _BUILTIN_FIELDS:
                available = _BUILTIN_FIELDS[name]
            elif name in self.chart.events:
                available = set(self.chart.events[name].payload)
            else:
                return None
            fields = available if fields is None else fields & available
        return fields

    def expression(self, expr: Expression, location: Location, fields: set[str] | None) -> None:
        for name in sorted(expr.variables - set(self.chart.variables)):
            close = difflib.get_close_matches(name, list(self.chart.variables), n=1)
            self.error(
                "unknown-name",
                f"{expr.source!r} uses unknown variable {name!r}",
                location,
                f"did you mean {close[0]!r}?" if close else "declare it under `variables:`",
            )
        if fields is not None:
            for name in sorted(expr.event_fields - fields):
                what = (
                    f"its events carry only {sorted(fields)}"
                    if fields
                    else "its trigger carries no payload"
                )
                self.error(
                    "unknown-field",
                    f"{expr.source!r} reads event.{name} but {what}",
                    location,
                    "declare the field under the event's `payload:`",
                )
        for ref in sorted(expr.states):
            try:
                self.chart.state(ref)
            except KeyError:
                self.error(
                    "unknown-state", f"{expr.source!r} asks about unknown state {ref!r}", location
                )

    def action_names(self, action: Action, fields: set[str] | None) -> None:
        values = [*action.payload.values(), *action.assignments.values(), *action.args.values()]
        if action.value is not None:
            values.append(action.value)
        for value in values:
            if value.expression is not None:
                self.expression(value.expression, action.location, fields)
        for name in action.assignments:
            if name not in self.chart.variables:
                self.error(
                    "unknown-name",
                    f"`set` assigns undeclared variable {name!r}",
                    action.location,
                    "declare it under `variables:`",
                )

    # -- cycles --------------------------------------------------------------------
    def connector_cycles(self) -> None:
        for s in self.states:
            if s.kind is not Kind.JUNCTION:
                continue
            seen, frontier = {s}, [s]
            while frontier:
                node = frontier.pop()
                for t in node.transitions:
                    nxt = t.target
                    if nxt is s:
                        self.error(
                            "connector-cycle",
                            f"junction {s.path!r} leads back to itself through junctions only",
                            s.location,
                            "break the cycle with a real state",
                        )
                        frontier = []
                        break
                    if nxt is not None and nxt.kind is Kind.JUNCTION and nxt not in seen:
                        seen.add(nxt)
                        frontier.append(nxt)

    def livelocks(self) -> None:
        edges: dict[State, list[tuple[State, Transition]]] = {}
        for t in self.transitions:
            src = t.source
            if (
                t.is_completion
                and t.guard is None
                and t.target is not None
                and src.kind is Kind.ATOMIC
                and src.configure is None
                and t.target.kind is Kind.ATOMIC
                and t.target.configure is None
            ):
                edges.setdefault(src, []).append((t.target, t))
        for start, outs in edges.items():
            for nxt, t in outs:
                seen, node = {start}, nxt
                while node in edges and node not in seen:
                    seen.add(node)
                    node = edges[node][0][0]
                if node is start:
                    self.error(
                        "livelock",
                        f"unguarded completion transitions cycle through {start.path!r} forever",
                        t.location,
                        "add a guard, an event or a time trigger",
                    )

    def configuration_tags(self) -> None:
        if self.tags is None:
            return
        requests = [
            (s.configure.tag, s.configure.location) for s in self.states if s.configure is not None
        ]
        requests += [(a.tag, a.location) for a, _ in self.all_actions() if a.kind == "configure"]
        for tag, location in requests:
            if tag not in self.tags:
                close = difflib.get_close_matches(tag, list(self.tags), n=1)
                self.error(
                    "unknown-tag",
                    f"configuration {tag!r} is not defined in the topology",
                    location,
                    f"did you mean {close[0]!r}?"
                    if close
                    else "add it under the topology's `configurations:`",
                )


def validate_chart(chart: Statechart, tags: dict[str, Location] | None = None) -> list[Finding]:
    """All findings for a built chart; `tags` are the topology's configuration names."""
    findings = _Checker(chart, tags).run()
    findings.sort(key=lambda f: (f.location.file, f.location.line, f.location.column))
    return findings
