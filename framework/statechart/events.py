"""Events, outputs and the listener interface of the statechart interpreter."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from framework.statechart.model import State, Transition


class Event:
    """A named event with an optional payload; `kind` is external, internal or timer."""

    __slots__ = ("kind", "name", "payload")

    def __init__(self, name: str, payload: dict[str, Any] | None = None, kind: str = "external"):
        self.name = name
        self.payload = payload
        self.kind = kind

    def __repr__(self) -> str:
        return f"Event({self.name!r}, {self.payload!r}, {self.kind!r})"

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Event)
            and self.name == other.name
            and self.payload == other.payload
            and self.kind == other.kind
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Output:
    """Something the chart asks the outside world to do (the host decides how).

    kinds: `send` (emit an event), `configure` (request a configuration tag),
    `write` (write a port), `call` (call an operation), `log` (a message).
    """

    kind: str
    state: str
    event: str = ""
    payload: dict[str, Any] = field(default_factory=dict)
    tag: str = ""
    timeout: float = 0.0
    port: str = ""
    value: Any = None
    operation: str = ""
    args: dict[str, Any] = field(default_factory=dict)
    message: str = ""


class Listener:
    """Sees everything the interpreter does; override what you need."""

    def on_event(self, event: Event) -> None:
        """An event is about to be processed (one step each)."""

    def on_unhandled(self, event: Event, reason: str) -> None:
        """An event enabled no transition and was not an awaited acknowledgement."""

    def on_transition(self, transition: Transition, event: Event | None) -> None:
        """A transition fires (after exits, before its effect)."""

    def on_entry(self, state: State) -> None:
        """A state was entered (its entry actions ran)."""

    def on_exit(self, state: State) -> None:
        """A state was exited (its exit actions ran)."""

    def on_output(self, output: Output) -> None:
        """An action asks the outside world for something."""

    def on_error(self, message: str, event: Event | None) -> None:
        """A guard or action failed at run time; the chart went on safely."""

    def on_refused(self, event: str, source: str, reason: str) -> None:
        """An event was refused where it entered (the Coordinator's admission or the
        chart's payload declaration): the chart never saw it."""


class Trace(Listener):
    """Records every interpreter callback as a tuple; used by `fw run` and tests."""

    def __init__(self) -> None:
        self.records: list[tuple[Any, ...]] = []

    def on_event(self, event: Event) -> None:
        self.records.append(("event", event.name, event.payload, event.kind))

    def on_unhandled(self, event: Event, reason: str) -> None:
        self.records.append(("unhandled", event.name, reason))

    def on_transition(self, transition: Transition, event: Event | None) -> None:
        target = transition.target.path if transition.target is not None else None
        self.records.append(
            ("transition", transition.source.path, target, event.name if event else None)
        )

    def on_entry(self, state: State) -> None:
        self.records.append(("entry", state.path))

    def on_exit(self, state: State) -> None:
        self.records.append(("exit", state.path))

    def on_output(self, output: Output) -> None:
        self.records.append(
            (
                "output",
                output.kind,
                output.tag or output.event or output.port or output.operation or output.message,
            )
        )

    def on_error(self, message: str, event: Event | None) -> None:
        self.records.append(("error", message))
