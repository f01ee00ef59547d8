"""The statechart model: states, transitions and actions as plain data.

The model is what the loader builds and what the validator, exporter and
interpreter read; it knows nothing about YAML or about running. Like sismic,
the model/interpreter split lets one chart be checked, drawn and run by
separate tools.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from framework.errors import Location
from framework.statechart.expressions import Expression


class Kind(Enum):
    """What a node of the chart is."""

    ATOMIC = "atomic"
    COMPOUND = "compound"
    PARALLEL = "parallel"
    FINAL = "final"
    JUNCTION = "junction"
    SHALLOW_HISTORY = "shallow_history"
    DEEP_HISTORY = "deep_history"

    @property
    def is_pseudo(self) -> bool:
        """Junctions and history nodes are never active themselves."""
        return self in (Kind.JUNCTION, Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY)


CONFIG_DONE = "config.done"
CONFIG_FAILED = "config.failed"
COMPONENT_LOST = "component.lost"
COMPONENT_BACK = "component.back"
BUILTIN_EVENTS = {
    CONFIG_DONE: "The Configurator applied a requested configuration (payload: tag).",
    CONFIG_FAILED: "A requested configuration failed or timed out (payload: tag, reason).",
    COMPONENT_LOST: "A component of the deployment is gone: its process died or cannot be "
    "reached (payload: component, process).",
    COMPONENT_BACK: "A lost component is alive again, e.g. after a restart (payload: "
    "component, process). Nothing restarts motion by itself: RELEASE still decides.",
}


@dataclass(eq=False)
class Value:
    """An action argument: a literal, or an expression written as `= expr`."""

    literal: Any = None
    expression: Expression | None = None


@dataclass(eq=False)
class Action:
    """One declarative action: raise, send, configure, set, write, call or log."""

    kind: str
    location: Location
    event: str = ""
    payload: dict[str, Value] = field(default_factory=dict)
    tag: str = ""
    assignments: dict[str, Value] = field(default_factory=dict)
    port: str = ""
    value: Value | None = None
    operation: str = ""
    args: dict[str, Value] = field(default_factory=dict)
    message: str = ""


@dataclass(eq=False)
class ConfigureRequest:
    """A state's request for a named configuration, acknowledged by the Configurator."""

    tag: str
    timeout: float
    location: Location


@dataclass(eq=False)
class Transition:
    """A transition of the chart; `target is None` means internal (no exit, no entry)."""

    source: State
    target_ref: str | None
    events: frozenset[str]
    after: float | None
    guard: Expression | None
    is_else: bool
    effect: tuple[Action, ...]
    priority: int
    order: int
    location: Location
    doc: str = ""
    target: State | None = None

    @property
    def is_completion(self) -> bool:
        """Fires when its source has completed (no event and no time trigger)."""
        return not self.events and self.after is None

    @property
    def is_internal(self) -> bool:
        """Runs its effect without leaving or re-entering any state."""
        return self.target_ref is None

    def label(self) -> str:
        """A short human label: `e_A, e_B [guard] / 2 actions`."""
        if self.events:
            trigger = ", ".join(sorted(self.events))
        elif self.after is not None:
            trigger = f"after {self.after:g}s"
        else:
            trigger = ""
        if self.guard is not None:
            trigger += f" [{self.guard.source}]"
        elif self.is_else:
            trigger += " [else]"
        return trigger.strip()


@dataclass(eq=False)
class State:
    """A node of the chart: a real state, or a junction/history pseudostate."""

    name: str
    path: str
    kind: Kind
    location: Location
    parent: State | None = None
    children: list[State] = field(default_factory=list)
    initial_ref: str | None = None
    initial: State | None = None
    default_ref: str | None = None
    default: State | None = None
    entry: tuple[Action, ...] = ()
    exit: tuple[Action, ...] = ()
    do: tuple[Action, ...] = ()
    configure: ConfigureRequest | None = None
    transitions: list[Transition] = field(default_factory=list)
    doc: str = ""
    scope: str = ""
    """Path of the state that included the file this state comes from ('' = main file)."""
    depth: int = 0
    index: int = 0

    def __repr__(self) -> str:
        return f"<State {self.path or '<root>'} {self.kind.value}>"

    @property
    def is_composite(self) -> bool:
        """Compound or parallel: has child states."""
        return self.kind in (Kind.COMPOUND, Kind.PARALLEL)

    def ancestors(self) -> list[State]:
        """Parents from the nearest to the root."""
        out, node = [], self.parent
        while node is not None:
            out.append(node)
            node = node.parent
        return out

    def is_descendant_of(self, other: State) -> bool:
        """True if `other` is a proper ancestor of this state."""
        node = self.parent
        while node is not None:
            if node is other:
                return True
            node = node.parent
        return False

    def walk(self) -> list[State]:
        """This state and all its descendants in document (pre-)order."""
        out = [self]
        for child in self.children:
            out.extend(child.walk())
        return out


VALUE_TYPES: dict[str, tuple[type, ...]] = {
    "number": (int, float),
    "integer": (int,),
    "boolean": (bool,),
    "string": (str,),
}
"""Python types of the value types a chart declares (`any` accepts everything)."""


def has_type(value: Any, vtype: str) -> bool:
    """True if `value` is of the chart value type `vtype` (a bool is not a number)."""
    if vtype == "any":
        return True
    if isinstance(value, bool) and vtype != "boolean":
        return False
    return isinstance(value, VALUE_TYPES[vtype])


@dataclass(eq=False)
class EventSpec:
    """A declared event: name, documentation and payload fields with their types;
    `fields` holds the optional limits (min, max), unit and doc of each field."""

    name: str
    doc: str
    payload: dict[str, str]
    location: Location
    fields: dict[str, dict[str, Any]] = field(default_factory=dict)

    def problem(self, payload: dict[str, Any], complete: bool = True) -> str:
        """Why `payload` does not fit this declaration ("" if it does): an unknown or
        (if `complete`) missing field, a wrong type, a number not finite or out of its
        limits."""
        for name, value in payload.items():
            vtype = self.payload.get(name)
            if vtype is None:
                return f"{self.name} has no payload field {name!r}"
            if vtype in VALUE_TYPES and not has_type(value, vtype):
                return f"{self.name}.{name} must be a {vtype}"
            if isinstance(value, float) and not math.isfinite(value):
                return f"{self.name}.{name} must be a finite {vtype}"
            limits = self.fields.get(name, {})
            if "values" in limits and value not in limits["values"]:
                return f"{self.name}.{name} must be one of {', '.join(map(str, limits['values']))}"
            unit = f" {limits['unit']}" if limits.get("unit") else ""
            if "min" in limits and value < limits["min"]:
                return f"{self.name}.{name} must be at least {limits['min']:g}{unit}"
            if "max" in limits and value > limits["max"]:
                return f"{self.name}.{name} must be at most {limits['max']:g}{unit}"
        missing = [n for n in self.payload if n not in payload] if complete else []
        return f"{self.name} needs {', '.join(map(self.describe, missing))}" if missing else ""

    def describe(self, name: str) -> str:
        """One payload field as an operator should read it: `where (one of target,
        home)`, `x (number, -0.5..0.5 m)`, `reason (string)`."""
        limits = self.fields.get(name, {})
        if "values" in limits:
            return f"{name} (one of {', '.join(map(str, limits['values']))})"
        low, high = limits.get("min"), limits.get("max")
        span = ""
        if low is not None or high is not None:
            span = f", {'' if low is None else f'{low:g}'}..{'' if high is None else f'{high:g}'}"
        unit = f" {limits['unit']}" if limits.get("unit") else ""
        return f"{name} ({self.payload[name]}{span}{unit})"


@dataclass(eq=False)
class VariableSpec:
    """A declared variable with its type and initial value."""

    name: str
    type: str
    initial: Any
    doc: str
    location: Location


@dataclass(eq=False)
class Statechart:
    """A loaded chart: the root state plus its vocabulary and settings."""

    name: str
    root: State
    file: str
    description: str = ""
    events: dict[str, EventSpec] = field(default_factory=dict)
    variables: dict[str, VariableSpec] = field(default_factory=dict)
    safe_state_ref: str | None = None
    safe_state: State | None = None
    configure_timeout: float = 10.0
    files: list[str] = field(default_factory=list)
    states: dict[str, State] = field(default_factory=dict)
    """Every node by full dotted path (the root is '')."""

    def state(self, ref: str) -> State:
        """The state at a full path or with a unique (dotted) name; KeyError otherwise."""
        if ref in self.states:
            return self.states[ref]
        found = [s for p, s in self.states.items() if p.endswith("." + ref)]
        if len(found) == 1:
            return found[0]
        raise KeyError(ref)

    def transitions(self) -> list[Transition]:
        """All transitions in document order."""
        return sorted(
            (t for s in self.states.values() for t in s.transitions), key=lambda t: t.order
        )

    def event_names(self) -> set[str]:
        """Every event this chart knows: declared, consumed by a transition, built in."""
        used = {e for t in self.transitions() for e in t.events}
        return set(self.events) | used | set(BUILTIN_EVENTS)

    def event_problem(
        self, name: str, payload: dict[str, Any] | None = None, complete: bool = True
    ) -> str:
        """Why sending `name` with `payload` to this chart is a mistake ("" if it is not):
        an event the chart does not know (with the nearest it does), or a payload its
        declaration does not allow (missing fields only if `complete`)."""
        known = self.event_names()
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=1)
            hint = (
                f"did you mean {close[0]!r}?"
                if close
                else "it knows " + ", ".join(sorted(known - set(BUILTIN_EVENTS)))
            )
            return f"{name!r} is not an event of chart {self.name!r}; {hint}"
        spec = self.events.get(name)
        return spec.problem(payload or {}, complete) if spec is not None else ""
