"""Reading a scenario file: schema, durations, states the chart has, each finding
located (file:line:col)."""

from __future__ import annotations

from pathlib import Path

from framework import schema
from framework.durations import parse_duration
from framework.errors import Finding, FindingsError, Location
from framework.scenario.model import Expectation, Fault, Invariant, Scenario, ScenarioStep, matches
from framework.yamlio import load_yaml


def load_scenario(
    path: str | Path,
    events: set[str] | None = None,
    operations: set[str] | None = None,
    states: set[str] | None = None,
    processes: set[str] | None = None,
    hosts: set[str] | None = None,
) -> Scenario:
    """Load and check a scenario; `events`, `operations`, `states` (full paths),
    `processes` and `hosts`, when given, are the names it may use. Every problem is a
    located finding."""
    doc = load_yaml(path)
    problems = schema.check(doc, "scenario")
    if problems:
        raise FindingsError(problems)
    data = doc.data
    findings: list[Finding] = []

    def known_state(name: str, where: Location) -> None:
        if states is not None and not any(matches(s, name) for s in states):
            findings.append(
                Finding("error", "unknown-state", f"the chart has no state {name!r}", where)
            )

    steps = []
    for i, spec in enumerate(data["steps"]):
        where = doc.location(("steps", i))
        step = ScenarioStep(
            at=parse_duration(spec["at"]) if "at" in spec else None,
            when=tuple(spec["when"])
            if isinstance(spec.get("when"), list)
            else spec.get("when", ""),
            after=parse_duration(spec.get("after", 0)),
            send=spec.get("send", ""),
            call=spec.get("call", ""),
            check=spec.get("check", ""),
            payload=dict(spec.get("payload") or spec.get("args") or {}),
            expect=dict(spec.get("expect") or {}),
            maximum={k: float(v) for k, v in (spec.get("max") or {}).items()},
            wait=parse_duration(spec.get("wait", 0)),
            location=where,
        )
        if "fault" in spec and "link" in spec["fault"]:
            step.fault, problems = _link_fault(spec["fault"], where, hosts)
            findings += problems
        elif "fault" in spec:
            fault = spec["fault"]
            if "for" in fault and fault["signal"] != "STOP":
                findings.append(
                    Finding("error", "fault", "`for` is how long a STOP hangs: STOP only", where)
                )
            if fault["signal"] == "STOP" and "for" not in fault:
                findings.append(
                    Finding(
                        "error",
                        "fault",
                        "a STOP needs `for`: how long the process stays hung",
                        where,
                        "e.g. {process: robot, signal: STOP, for: 2s}",
                    )
                )
            if processes is not None and fault["process"] not in processes:
                findings.append(
                    Finding(
                        "error",
                        "unknown-process",
                        f"the topology has no process {fault['process']!r}",
                        where,
                        f"known: {', '.join(sorted(processes))}",
                    )
                )
            step.fault = Fault(
                fault["process"], fault["signal"], parse_duration(fault.get("for", 0))
            )
        for state in (step.when,) if isinstance(step.when, str) else step.when:
            if state:
                known_state(state, where)
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
        for ref in (step.call, step.check):
            if ref and operations is not None and ref not in operations:
                findings.append(
                    Finding(
                        "error", "unknown-operation", f"no operation {ref!r} in the topology", where
                    )
                )
        steps.append(step)
    expectations = []
    for i, spec in enumerate(data.get("expect") or []):
        where = doc.location(("expect", i))
        ((kind, name),) = ((k, v) for k, v in spec.items() if k != "within")
        within = parse_duration(spec["within"]) if "within" in spec else None
        if isinstance(name, list):
            name = tuple(name)
        if kind.endswith("state"):
            for one in (name,) if isinstance(name, str) else name:
                known_state(one, where)
        elif events is not None and name not in events:
            findings.append(
                Finding("error", "unknown-event", f"the chart has no event {name!r}", where)
            )
        expectations.append(Expectation(kind, name, within, where))
    invariants = []
    for i, spec in enumerate(data.get("invariants") or []):
        where = doc.location(("invariants", i))
        inv = Invariant(
            spec["check"],
            dict(spec.get("expect") or {}),
            {k: float(v) for k, v in (spec.get("max") or {}).items()},
            spec.get("while", ""),
            parse_duration(spec.get("grace", 0)),
            where,
        )
        if inv.state:
            known_state(inv.state, where)
        if operations is not None and inv.check not in operations:
            findings.append(
                Finding(
                    "error",
                    "unknown-operation",
                    f"no operation {inv.check!r} in the topology",
                    where,
                )
            )
        invariants.append(inv)
    for key in ("start", "end"):
        if data.get(key):
            known_state(data[key], doc.location((key,)))
    if findings:
        raise FindingsError(findings)
    return Scenario(
        data["scenario"],
        steps,
        expectations,
        data.get("start", ""),
        parse_duration(data.get("timeout", "120s")),
        data.get("end", ""),
        invariants,
    )


def _link_fault(spec: dict, where: Location, hosts: set[str] | None) -> tuple[Fault, list[Finding]]:
    """A `fault: {link: ...}` step: a partition, or loss/delay/jitter for a while."""
    problems = []
    impairs = [k for k in ("loss", "delay", "jitter") if k in spec]
    if ("partition" in spec) == bool(impairs):
        problems.append(
            Finding(
                "error",
                "fault",
                "a link fault is either a `partition` or `loss`/`delay`/`jitter`",
                where,
                "e.g. {link: cameras, partition: 2s} or {link: tracking, delay: 80ms, for: 5s}",
            )
        )
    if impairs and "for" not in spec:
        problems.append(
            Finding("error", "fault", "loss, delay and jitter need `for`: how long", where)
        )
    if "partition" in spec and "for" in spec:
        problems.append(
            Finding("error", "fault", "a partition says its own length: no `for`", where)
        )
    if hosts is not None and spec["link"] not in hosts:
        problems.append(
            Finding(
                "error",
                "unknown-host",
                f"the topology has no host {spec['link']!r}",
                where,
                f"known: {', '.join(sorted(hosts)) or 'none (a topology without hosts:)'}",
            )
        )
    loss = spec.get("loss", 0.0)
    if isinstance(loss, str):
        loss = float(loss.strip().rstrip("%")) / 100.0
    fault = Fault(
        link=spec["link"],
        partition="partition" in spec,
        hold=parse_duration(spec.get("partition", spec.get("for", 0))),
        loss=float(loss),
        delay=parse_duration(spec.get("delay", 0)),
        jitter=parse_duration(spec.get("jitter", 0)),
    )
    return fault, problems
