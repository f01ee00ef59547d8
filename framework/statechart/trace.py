"""A chart's trace, printed: every event, transition, entry, exit and output, stamped
with the (simulated) clock."""

from __future__ import annotations

import json
from typing import Any

from framework.clock import SimulatedClock
from framework.statechart.events import Event, Listener, Output
from framework.statechart.model import State, Transition


class TracePrinter(Listener):
    """Prints a chart's steps with the simulated time, as text or JSON lines (`fw run`,
    `fw replay`)."""

    def __init__(self, clock: SimulatedClock, as_json: bool):
        self.clock = clock
        self.as_json = as_json

    def emit(self, kind: str, text: str, **data: Any) -> None:
        """Print one step: `[time] kind text`, or a JSON line of `data` with t and kind."""
        if self.as_json:
            print(json.dumps({"t": round(self.clock.now(), 6), "kind": kind, **data}))
        else:
            print(f"[{self.clock.now():9.3f}] {kind:<10} {text}")

    def on_event(self, event: Event) -> None:
        payload = f" {json.dumps(event.payload)}" if event.payload else ""
        self.emit(
            "event",
            f"{event.name}{payload} ({event.kind})",
            name=event.name,
            payload=event.payload,
            source=event.kind,
        )

    def on_unhandled(self, event: Event, reason: str) -> None:
        self.emit("unhandled", f"{event.name}: {reason}", name=event.name, reason=reason)

    def on_transition(self, transition: Transition, event: Event | None) -> None:
        target = transition.target.path if transition.target is not None else "(internal)"
        self.emit(
            "transition",
            f"{transition.source.path} -> {target}",
            source=transition.source.path,
            target=target,
        )

    def on_entry(self, state: State) -> None:
        self.emit("enter", state.path, state=state.path)

    def on_exit(self, state: State) -> None:
        self.emit("exit", state.path, state=state.path)

    def on_output(self, output: Output) -> None:
        what = output.tag or output.event or output.port or output.operation or output.message
        self.emit("output", f"{output.kind} {what}", output=output.kind, what=what)

    def on_error(self, message: str, event: Event | None) -> None:
        self.emit("error", message, message=message)
