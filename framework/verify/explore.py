"""Explore every reachable state of a chart with fw's own interpreter, and judge
properties on the way.

The chart runs in an environment that may do, at any moment, whatever the
deployment could: send any event the chart can receive (an operator's, a
component's, `component.lost`/`back`), answer the oldest unanswered configuration
request with `config.done` or `config.failed`, or let time pass. One *step* is one
such input followed by everything the chart does until it is quiet. States are the
interpreter's snapshots (plus the requests awaiting an answer and each property's
monitor), deduplicated; the search is breadth first, so the first violation found
of a property has a shortest trace.

Abstractions, each said in the report and in docs/statecharts.md:

* **Time** advances in steps of the chart's time quantum (the greatest common
  divisor of its delays and timeouts) and events arrive between steps. Every
  timer starts and ends on a multiple of the quantum, so every order of events and
  deadlines the chart can tell apart is reached.
* **Payloads** take a few values per field: each value of an enumeration, the
  bounds of a range, the chart's own constants and one value unlike any of them.
  A field no guard, assignment or raised event reads takes one value: it cannot
  change the chart's state.
* **Configuration answers** come in request order, and at most `unanswered`
  requests wait at once (a finite bound on a queue the real system bounds by
  time); a step that would exceed it is not taken and is counted.
* **Events** a chart has no transition for in its current states are not sent
  (they would change nothing), unless a property watches for them.
"""

from __future__ import annotations

import ast
import json
import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

from framework.clock import SimulatedClock
from framework.statechart.events import Event, Listener, Output
from framework.statechart.expressions import Env, Expression
from framework.statechart.interpreter import Interpreter
from framework.statechart.model import (
    COMPONENT_BACK,
    COMPONENT_LOST,
    CONFIG_DONE,
    CONFIG_FAILED,
    State,
    Statechart,
)
from framework.verify.properties import DEFAULT_UNANSWERED, Matcher, Property

DONE, FAILED, TICK, SEND = "done", "failed", "tick", "event"
FAILED_REASON = "refused by the model's Configurator"


@dataclass(frozen=True)
class Input:
    """One thing the environment does: send an event, answer the oldest request, or
    let one time quantum pass."""

    kind: str
    name: str = ""
    payload: tuple[tuple[str, Any], ...] = ()

    def event(self, tag: str = "") -> tuple[str, dict[str, Any] | None]:
        """The event the chart receives for this input (`tag`: the answered request)."""
        if self.kind == DONE:
            return CONFIG_DONE, {"tag": tag}
        if self.kind == FAILED:
            return CONFIG_FAILED, {"tag": tag, "step": "model", "reason": FAILED_REASON}
        return self.name, dict(self.payload) or None


@dataclass
class TraceStep:
    """One step of a counterexample: when (simulated s) and what the chart received."""

    at: float
    kind: str
    event: str = ""
    payload: dict[str, Any] | None = None

    def describe(self) -> str:
        """The step as one line of the report."""
        if self.kind == TICK:
            return f"{self.at:8.3f}s  (time passes)"
        payload = f" {json.dumps(self.payload, sort_keys=True)}" if self.payload else ""
        return f"{self.at:8.3f}s  {self.event}{payload}"


@dataclass
class Verdict:
    """A property's outcome: holds, or violated with a shortest trace."""

    prop: Property
    trace: list[TraceStep] | None = None
    leaves: list[str] = field(default_factory=list)
    why: str = ""
    end: float = 0.0
    """The simulated time at which the property is violated."""

    @property
    def holds(self) -> bool:
        """True if no reachable step violates the property."""
        return self.trace is None


@dataclass
class Result:
    """What an exploration found."""

    states: int
    transitions: int
    seconds: float
    quantum: float | None
    unanswered: int
    beyond_bound: int
    complete: bool
    verdicts: list[Verdict]
    inputs: int = 0


# -- the environment -------------------------------------------------------------------


class Environment:
    """The events a chart may receive, each with the payloads to try."""

    def __init__(self, events: dict[str, list[dict[str, Any]]]):
        self.events = events

    @classmethod
    def of(
        cls,
        chart: Statechart,
        senders: Iterable[str] | None = None,
        components: Iterable[tuple[str, str]] = (),
        extra: Iterable[Expression] = (),
    ) -> Environment:
        """The environment of `chart`: `senders` are the events something outside the
        chart sends (a topology's external events and what its components emit; None:
        every event the chart consumes); `components` the (component, process) pairs
        `component.lost`/`back` may name; `extra` expressions (a property's) whose
        event fields count as read."""
        consumed = {e for t in chart.transitions() for e in t.events}
        consumed -= {CONFIG_DONE, CONFIG_FAILED}
        names = (
            consumed
            if senders is None
            else consumed & set(senders) | (consumed & {COMPONENT_LOST, COMPONENT_BACK})
        )
        read, constants = _reads(chart, extra)
        events: dict[str, list[dict[str, Any]]] = {}
        pairs = list(components) or [("component", "process")]
        for name in sorted(names):
            spec = chart.events.get(name)
            if name in (COMPONENT_LOST, COMPONENT_BACK):
                fields = {"component": [c for c, _ in pairs], "process": [p for _, p in pairs]}
                choices = {f: (v if f in read else v[:1]) for f, v in fields.items()}
                events[name] = _combine(choices, paired=pairs)
                continue
            fields = dict(spec.payload) if spec is not None else {}
            limits = spec.fields if spec is not None else {}
            if spec is None:  # undeclared: the fields its transitions' guards read
                fields = {f: "any" for f in _guard_fields(chart, name)}
            choices = {
                f: _values(vtype, limits.get(f, {}), constants.get(f, []), f in read)
                for f, vtype in fields.items()
            }
            events[name] = _combine(choices)
        return cls(events)

    def inputs(self, accepts: Callable[[str], bool], observed: frozenset[str]) -> list[Input]:
        """Every event input the chart's current states take, and those a property
        watches for (an event the chart ignores is still a step a property sees)."""
        return [
            Input(SEND, name, tuple(sorted(p.items())))
            for name, payloads in self.events.items()
            if name in observed or accepts(name)
            for p in payloads
        ]


def _reads(chart: Statechart, extra: Iterable[Expression]) -> tuple[set[str], dict[str, list[Any]]]:
    """Event fields that can change the chart's state (read by guards, assignments,
    raised events' payloads or `extra`), and for each the constants it can meet: those
    compared with it, or with a variable it is assigned to."""
    exprs: list[Expression] = list(extra)
    assigned: dict[str, set[str]] = {}  # event field -> variables it flows into
    for state in chart.states.values():
        for action in (*state.entry, *state.exit, *state.do):
            _action_exprs(action, exprs, assigned)
        for t in state.transitions:
            if t.guard is not None:
                exprs.append(t.guard)
            for action in t.effect:
                _action_exprs(action, exprs, assigned)
    read = {f for e in exprs for f in e.event_fields}
    compared: dict[str, list[Any]] = {}
    for e in exprs:
        for node in ast.walk(ast.parse(e.source.strip(), mode="eval")):
            if isinstance(node, ast.Compare):
                sides = [node.left, *node.comparators]
                names = [_operand(n) for n in sides]
                consts = [n.value for n in sides if isinstance(n, ast.Constant)]
                for name in filter(None, names):
                    bucket = compared.setdefault(name, [])
                    bucket.extend(c for c in consts if c not in bucket)
    constants: dict[str, list[Any]] = {}
    for f in read:
        values = list(compared.get(f"event.{f}", []))
        for variable in sorted(assigned.get(f, ())):
            values += [c for c in compared.get(variable, []) if c not in values]
        constants[f] = values
    return read, constants


def _operand(node: ast.AST) -> str | None:
    """`event.x` or a variable's name for an operand of a comparison, else None."""
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
        return f"{node.value.id}.{node.attr}" if node.value.id == "event" else None
    return node.id if isinstance(node, ast.Name) else None


def _action_exprs(
    action: Any, state_changing: list[Expression], assigned: dict[str, set[str]]
) -> None:
    """Collect an action's expressions that can change the chart's state (a `set`, a
    raised event's payload), and which variables each event field is assigned to."""
    if action.kind == "set":
        for variable, value in action.assignments.items():
            if value.expression is not None:
                state_changing.append(value.expression)
                for f in value.expression.event_fields:
                    assigned.setdefault(f, set()).add(variable)
    elif action.kind == "raise":
        state_changing.extend(
            v.expression for v in action.payload.values() if v.expression is not None
        )


def _guard_fields(chart: Statechart, event: str) -> list[str]:
    return sorted(
        {
            f
            for t in chart.transitions()
            if event in t.events and t.guard is not None
            for f in t.guard.event_fields
            if f != "name"
        }
    )


def _values(vtype: str, limits: dict[str, Any], constants: list[Any], read: bool) -> list[Any]:
    """The values one payload field takes in the exploration (see the module doc)."""
    if "values" in limits:
        values = list(limits["values"])
    elif vtype == "boolean":
        values = [False, True]
    elif vtype in ("number", "integer"):
        low, high = limits.get("min"), limits.get("max")
        nums = [c for c in constants if isinstance(c, int | float)]
        cands = [0, *nums, *(c + 1 for c in nums), *(c - 1 for c in nums)]
        cands += [x for x in (low, high) if x is not None]
        values = sorted(
            {
                c
                for c in cands
                if (low is None or c >= low)
                and (high is None or c <= high)
                and (vtype != "integer" or float(c).is_integer())
            }
        )
        if vtype == "integer":
            values = [int(v) for v in values]
        values = values or [low if low is not None else high]
    elif vtype == "string":
        values = [c for c in constants if isinstance(c, str)] + ["(other)"]
    else:
        values = [c for c in constants if isinstance(c, str | int | float)] + ["(other)"]
    return values if read else values[:1]


def _combine(
    choices: dict[str, list[Any]], paired: list[tuple[str, str]] | None = None
) -> list[dict[str, Any]]:
    """Every combination of the fields' values (component.lost: the real pairs)."""
    if paired is not None and len(choices.get("component", [])) > 1:
        return [{"component": c, "process": p} for c, p in paired]
    out: list[dict[str, Any]] = [{}]
    for name, values in choices.items():
        out = [{**o, name: v} for o in out for v in values]
    return out


def time_quantum(chart: Statechart) -> float | None:
    """The greatest common divisor of the chart's delays and timeouts (None: no timer)."""
    spans = [t.after for t in chart.transitions() if t.after is not None]
    spans += [s.configure.timeout for s in chart.states.values() if s.configure is not None]
    fractions = [Fraction(str(round(s, 6))) for s in spans if s and s > 0]
    if not fractions:
        return None
    q = fractions[0]
    for f in fractions[1:]:
        q = Fraction(
            math.gcd(q.numerator * f.denominator, f.numerator * q.denominator),
            q.denominator * f.denominator,
        )
    return float(q)


# -- the monitors ----------------------------------------------------------------------

_IDLE = -1


class _Observer(Listener):
    """Watches one step of the chart: requests for the Configurator, and every
    property's monitor (a `responds` countdown, a `precedes` latch) and violation."""

    def __init__(self, interpreter: Interpreter, properties: list[Property]):
        self.interpreter = interpreter
        self.properties = properties
        self.outstanding: list[str] = []
        self.monitors: list[int] = [_IDLE] * len(properties)
        self.violated: dict[int, str] = {}
        self.event: Event | None = None
        self._answered: set[int] = set()  # responds: its `with` seen in this step
        watching: dict[tuple[str, str], set[int]] = {}
        for i, p in enumerate(properties):
            for m in (p.first, p.second, p.third):
                if m is not None and m.kind:
                    for name in m.names:
                        watching.setdefault((m.kind, name), set()).add(i)
        self._watching = {k: sorted(v) for k, v in watching.items()}
        """The properties that watch each (kind, name): most observations concern none."""

    def begin(self, outstanding: list[str], monitors: list[int]) -> None:
        """Start a step from a state's requests and monitors."""
        self.outstanding = list(outstanding)
        self.monitors = list(monitors)
        self.violated = {}
        self.event = None
        self._answered = set()

    # listener hooks: run inside the interpreter's step, in its thread
    def on_event(self, event: Event) -> None:
        self.event = event
        self._observe("event", event.name)

    def on_entry(self, state: State) -> None:
        self._observe("enter", state.path)

    def on_exit(self, state: State) -> None:
        self._observe("exit", state.path)

    def on_output(self, output: Output) -> None:
        if output.kind == "configure":
            self.outstanding.append(output.tag)
            self._observe("request", output.tag)

    def _holds(self, m: Matcher) -> bool:
        interpreter = self.interpreter
        if m.states and not any(interpreter.is_active(s) for s in m.states):
            return False
        if m.when is None:
            return True
        try:
            return bool(m.when(Env(interpreter.variables, self.event, interpreter.is_active)))
        except Exception:  # a field the event lacks: the matcher does not match
            return False

    def _matches(self, m: Matcher | None, kind: str, name: str) -> bool:
        return m is not None and m.kind == kind and name in m.names and self._holds(m)

    def _observe(self, kind: str, name: str) -> None:
        for i in self._watching.get((kind, name), ()):
            p = self.properties[i]
            if p.pattern == "never":
                if self._matches(p.first, kind, name):
                    self._violate(i, f"{kind} {name}")
            elif p.pattern == "responds":
                if (
                    self.monitors[i] == _IDLE
                    and i not in self._answered
                    and self._matches(p.first, kind, name)
                ):
                    self.monitors[i] = p.within
                if self._matches(p.second, kind, name):
                    self.monitors[i] = _IDLE
                    self._answered.add(i)
            else:
                if self.monitors[i] == 1 and self._matches(p.second, kind, name):
                    self._violate(i, f"{kind} {name} after {p.first.describe()}")
                if self._matches(p.third, kind, name):
                    self.monitors[i] = 0
                if self._matches(p.first, kind, name):
                    self.monitors[i] = 1

    def end(self) -> None:
        """Judge the conditions once the step is over; count `responds` down."""
        for i, p in enumerate(self.properties):
            if p.pattern in ("never", "always") and not p.first.kind:
                if self._holds(p.first) is (p.pattern == "never"):
                    self._violate(i, f"in {', '.join(self.interpreter.leaves)}")
            elif p.pattern == "responds" and self.monitors[i] != _IDLE:
                assert p.second is not None
                if not p.second.kind and self._holds(p.second):
                    self.monitors[i] = _IDLE
                elif self.monitors[i] == 0:
                    self.monitors[i] = _IDLE
                    self._violate(i, f"no {p.second.describe()} within {p.within} step(s)")
                else:
                    self.monitors[i] -= 1

    def _violate(self, i: int, why: str) -> None:
        self.violated.setdefault(i, why)


# -- the search ------------------------------------------------------------------------


def _step(
    interpreter: Interpreter,
    observer: _Observer,
    quantum: float | None,
    inp: Input,
    outstanding: list[str],
    monitors: list[int],
) -> None:
    """One step: the input, then the chart until quiet, watched by `observer`."""
    observer.begin(outstanding, monitors)
    if inp.kind == TICK:
        assert quantum is not None
        interpreter.advance(quantum)
    else:
        tag = observer.outstanding.pop(0) if inp.kind in (DONE, FAILED) else ""
        name, payload = inp.event(tag)
        interpreter.queue(name, payload)
        interpreter.run()
    observer.end()


class Explorer:
    """Breadth-first search of a chart's reachable states under an `Environment`."""

    def __init__(
        self,
        chart: Statechart,
        properties: Sequence[Property] = (),
        environment: Environment | None = None,
        unanswered: int = DEFAULT_UNANSWERED,
        max_states: int = 2_000_000,
        first: bool = False,
    ):
        """`first`: stop at the first violation (hunting bugs, not counting states)."""
        self.chart = chart
        self.properties = list(properties)
        self.environment = environment or Environment.of(
            chart,
            extra=[
                m.when
                for p in self.properties
                for m in (p.first, p.second, p.third)
                if m is not None and m.when is not None
            ],
        )
        self.unanswered = unanswered
        self.max_states = max_states
        self.first = first
        self.observed = frozenset(
            name
            for p in self.properties
            for m in (p.first, p.second, p.third)
            if m is not None and m.kind == "event"
            for name in m.names
        )
        self.quantum = time_quantum(chart)
        self.interpreter = Interpreter(chart, SimulatedClock())
        self.observer = _Observer(self.interpreter, self.properties)
        self.interpreter.listeners.append(self.observer)
        self.visited: dict[str, Any] = {}
        """After `run`: every state explored (its key) with the step that first reached it."""

    def _key(self, outstanding: list[str], monitors: list[int]) -> str:
        snap = self.interpreter.snapshot()
        snap["timers"] = [[round(t[0], 6), t[1], t[2]] for t in snap["timers"]]
        snap["pending"] = {k: [v[0], round(v[1], 6)] for k, v in snap["pending"].items()}
        return json.dumps([snap, outstanding, monitors], sort_keys=True, default=repr)

    def _load(self, state: list[Any]) -> tuple[list[str], list[int]]:
        snap, outstanding, monitors = state
        self.interpreter.clock = SimulatedClock()
        self.interpreter.load(snap)
        return outstanding, monitors

    def _apply(self, inp: Input, outstanding: list[str], monitors: list[int]) -> None:
        _step(self.interpreter, self.observer, self.quantum, inp, outstanding, monitors)

    def judge(self, path: Sequence[Input]) -> dict[int, str]:
        """Play `path` from the start on a fresh interpreter with this explorer's
        monitors; return the properties violated on the way (index: why). How another
        checker's counterexample is confirmed by fw's own engine (`fw verify --spin`)."""
        interpreter = Interpreter(self.chart, SimulatedClock())
        observer = _Observer(interpreter, self.properties)
        interpreter.listeners.append(observer)
        observer.begin([], [_IDLE if p.pattern != "precedes" else 0 for p in self.properties])
        interpreter.start()
        observer.end()
        found = dict(observer.violated)
        for inp in path:
            _step(interpreter, observer, self.quantum, inp, observer.outstanding, observer.monitors)
            for i, why in observer.violated.items():
                found.setdefault(i, why)
        return found

    def _inputs(self, outstanding: list[str]) -> list[Input]:
        inputs = self.environment.inputs(self.interpreter.accepts, self.observed)
        if outstanding:
            inputs += [Input(DONE), Input(FAILED)]
        if self.quantum is not None and self.interpreter.next_deadline() is not None:
            inputs.append(Input(TICK))
        return inputs

    def run(self, progress: Callable[[int, int], None] | None = None) -> Result:
        """Explore every reachable state; return the counts and each verdict."""
        started = time.perf_counter()
        interpreter, observer = self.interpreter, self.observer
        observer.begin([], [_IDLE if p.pattern != "precedes" else 0 for p in self.properties])
        interpreter.start()
        observer.end()
        first = self._key(observer.outstanding, observer.monitors)
        parents: dict[str, tuple[str, Input] | None] = {first: None}
        found: dict[int, tuple[str, Input | None, str, list[str]]] = {
            i: (first, None, why, interpreter.leaves) for i, why in observer.violated.items()
        }
        frontier = deque([first])
        transitions = beyond = 0
        last_report = started
        complete = True
        while frontier:
            key = frontier.popleft()
            state = json.loads(key)
            outstanding, monitors = self._load(state)
            for inp in self._inputs(outstanding):
                self._load(state)
                self._apply(inp, outstanding, monitors)
                transitions += 1
                if len(observer.outstanding) > self.unanswered:
                    beyond += 1
                    continue
                for i, why in observer.violated.items():
                    if i not in found:
                        found[i] = (key, inp, why, interpreter.leaves)
                new = self._key(observer.outstanding, observer.monitors)
                if new not in parents:
                    parents[new] = (key, inp)
                    frontier.append(new)
            if len(parents) >= self.max_states or (self.first and found):
                complete = not frontier and len(parents) < self.max_states
                break
            if progress is not None and time.perf_counter() - last_report > 1.0:
                last_report = time.perf_counter()
                progress(len(parents), transitions)
        self.visited = parents
        verdicts = []
        for i, prop in enumerate(self.properties):
            if i not in found:
                verdicts.append(Verdict(prop))
                continue
            key, inp, why, leaves = found[i]
            path = self._path(parents, key) + ([inp] if inp is not None else [])
            trace, end = self._trace(path)
            verdicts.append(Verdict(prop, trace, leaves, why, end))
        return Result(
            len(parents),
            transitions,
            time.perf_counter() - started,
            self.quantum,
            self.unanswered,
            beyond,
            complete,
            verdicts,
            sum(len(v) for v in self.environment.events.values()),
        )

    @staticmethod
    def _path(parents: dict[str, tuple[str, Input] | None], key: str) -> list[Input]:
        path: list[Input] = []
        link = parents[key]
        while link is not None:
            key, inp = link
            path.append(inp)
            link = parents[key]
        path.reverse()
        return path

    def _trace(self, path: list[Input]) -> tuple[list[TraceStep], float]:
        """Replay `path` from the start to stamp each step with its time and the tag
        each answer carries; also the time at its end."""
        fresh = Interpreter(self.chart, SimulatedClock())
        requests = _Observer(fresh, [])  # only its record of the requests is used
        fresh.listeners.append(requests)
        fresh.start()
        outstanding = requests.outstanding
        steps: list[TraceStep] = []
        for inp in path:
            now = fresh.clock.now()
            if inp.kind == TICK:
                assert self.quantum is not None
                fresh.advance(self.quantum)
                steps.append(TraceStep(now, TICK))
                continue
            tag = outstanding.pop(0) if inp.kind in (DONE, FAILED) else ""
            name, payload = inp.event(tag)
            steps.append(TraceStep(now, inp.kind, name, payload))
            fresh.queue(name, payload)
            fresh.run()
        return steps, fresh.clock.now()
