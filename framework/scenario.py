"""Scenarios: what happens when during a deployment (`fw deploy --scenario FILE`).

A scenario is a list of timed steps relative to the chart's start: an event for
the chart (`send`, as an operator would) or an operation call on a component
(`call`, as a simulated-OR driver would). The SEEG issue extends the steps with
the simulated operating room (occluders, people walking).

    scenario: swap_then_stop
    steps:
      - {at: 1s, send: e_START}
      - {at: 3.5s, send: e_TOK, payload: {tracker: vicra}}
      - {at: 5s, call: supervisor.reset, args: {to: 0}}
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from framework import schema
from framework.errors import Finding, FindingsError, Location
from framework.statechart.loader import parse_duration
from framework.yamlio import load_yaml


@dataclass
class ScenarioStep:
    """One timed step."""

    at: float
    send: str = ""
    call: str = ""
    payload: dict[str, Any] = field(default_factory=dict)
    location: Location = field(default_factory=Location)


@dataclass
class Scenario:
    """A loaded scenario, steps in time order."""

    name: str
    steps: list[ScenarioStep]


def load_scenario(
    path: str | Path, events: set[str] | None = None, operations: set[str] | None = None
) -> Scenario:
    """Load and check a scenario; `events`/`operations` (when given) are the names it may
    use. Every problem is a located finding (`FindingsError`)."""
    doc = load_yaml(path)
    problems = schema.check(doc, "scenario")
    if problems:
        raise FindingsError(problems)
    steps, findings = [], []
    for i, spec in enumerate(doc.data["steps"]):
        where = doc.location(("steps", i))
        step = ScenarioStep(
            parse_duration(spec["at"]),
            spec.get("send", ""),
            spec.get("call", ""),
            dict(spec.get("payload") or spec.get("args") or {}),
            where,
        )
        if step.send and events is not None and step.send not in events:
            findings.append(
                Finding(
                    "error",
                    "unknown-event",
                    f"the chart has no event {step.send!r}",
                    where,
                    f"known: {', '.join(sorted(events))}",
                )
            )
        if step.call and operations is not None and step.call not in operations:
            findings.append(
                Finding(
                    "error",
                    "unknown-operation",
                    f"no operation {step.call!r} in the topology",
                    where,
                )
            )
        steps.append(step)
    if findings:
        raise FindingsError(findings)
    return Scenario(doc.data["scenario"], sorted(steps, key=lambda s: s.at))


class ScenarioRunner:
    """Plays a scenario on its own thread, on monotonic time from `start()`."""

    def __init__(
        self,
        scenario: Scenario,
        send: Callable[[str, dict[str, Any]], None],
        call: Callable[[str, dict[str, Any]], Any],
        report: Callable[[str], None] = lambda text: None,
    ):
        self.scenario, self._send, self._call, self._report = scenario, send, call, report
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.done: list[ScenarioStep] = []

    def start(self) -> None:
        """Begin playing (time zero is now)."""
        self._thread = threading.Thread(target=self._play, name="fw-scenario", daemon=True)
        self._thread.start()

    def _play(self) -> None:
        zero = time.monotonic()
        for step in self.scenario.steps:
            if self._stop.wait(max(0.0, zero + step.at - time.monotonic())):
                return
            try:
                if step.send:
                    self._send(step.send, step.payload)
                    self._report(f"scenario   {step.at:g}s: send {step.send}")
                else:
                    self._call(step.call, step.payload)
                    self._report(f"scenario   {step.at:g}s: call {step.call}")
            except Exception as exc:  # a failing step is reported, the scenario goes on
                self._report(f"scenario   {step.at:g}s: {step.send or step.call} failed: {exc}")
            self.done.append(step)

    def stop(self) -> None:
        """Stop playing (steps not yet due are skipped)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
