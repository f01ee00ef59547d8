"""A violated property's shortest trace, written as a scenario file.

The file is an ordinary fw scenario: every input of the trace is a `send` step at
its simulated time (the Configurator's answers as `config.done`/`config.failed`),
and `expect` names the states the chart is in once the property is violated.
`fw run CHART --scenario FILE` replays it on the simulated clock.
"""

from __future__ import annotations

import json
from pathlib import Path

from framework.statechart.model import Statechart
from framework.verify.explore import TICK, Verdict


def counterexample_text(chart: Statechart, verdict: Verdict, chart_file: str) -> str:
    """The scenario YAML of a violated property's trace."""
    assert verdict.trace is not None
    prop = verdict.prop
    lines = [
        f"# Counterexample to property {prop.name!r} of chart {chart.name!r}, found by",
        "# `fw verify`: a shortest sequence of inputs after which the property is violated.",
        f"# The property: {prop.describe()}",
        f"# What happened: {verdict.why}",
        f"# Replay it:     fw run {chart_file} --scenario THIS_FILE",
        f"scenario: counterexample_{prop.name}",
        f"description: {json.dumps('violates ' + prop.name + ': ' + verdict.why)}",
        "steps:",
    ]
    for step in verdict.trace:
        if step.kind == TICK:
            continue
        payload = f", payload: {json.dumps(step.payload, sort_keys=True)}" if step.payload else ""
        lines.append(f"  - {{at: {_seconds(step.at)}, send: {step.event}{payload}}}")
    end = verdict.end
    if len(lines) == 8:
        lines[-1] = "steps: []  # the chart violates it by itself, from its start"
    lines.append(f"timeout: {_seconds(end)}   # the violation happens at this time")
    lines.append("expect:")
    lines.extend(f"  - {{state: {leaf}}}" for leaf in verdict.leaves)
    return "\n".join(lines) + "\n"


def _seconds(t: float) -> str:
    return f"{round(t, 6):g}s"


def write_counterexample(
    directory: Path, chart: Statechart, verdict: Verdict, chart_file: str
) -> Path:
    """Write the scenario of a violated property into `directory`; return its path."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{chart.name}.{verdict.prop.name}.yaml"
    path.write_text(counterexample_text(chart, verdict, chart_file), encoding="utf-8")
    return path
