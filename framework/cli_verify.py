"""`fw verify`: prove a chart's safety properties over every reachable state, and
write each violation's shortest trace as a scenario."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from framework.errors import FindingsError

EPILOG = """\
Explores every state the chart can reach with fw's own interpreter (the engine that runs
the procedure), under an environment that may send any event the chart can receive,
answer any configuration request with config.done or config.failed, and let time pass.
Each property holds, or is VIOLATED with a shortest trace, printed and written as a
scenario that `fw run CHART --scenario FILE` replays on the simulated clock.

examples:
  fw verify statecharts/seeg.yaml --properties procedures/seeg/properties.yaml \\
      --topology topologies/seeg.yaml
  fw verify statecharts/pick_place.yaml --properties procedures/pick_place/properties.yaml
  fw verify statecharts/seeg.yaml --properties p.yaml --counterexamples /tmp/cx --json

Properties are written as never / always / responds / precedes (docs/statecharts.md,
"Proving properties"). Exit code 0: every property holds; 1: one is violated, the
exploration stopped at --max-states, or a file has errors.
"""


def cmd_verify(args: argparse.Namespace) -> int:
    """Explore the chart and judge every property; print and write counterexamples."""
    from framework.statechart.loader import build_statechart
    from framework.verify.explore import Environment, Explorer
    from framework.verify.properties import load_properties
    from framework.verify.scenario import write_counterexample

    chart, findings = build_statechart(args.chart)
    errors = [f for f in findings if f.severity == "error"]
    if chart is None or errors:
        raise FindingsError(errors or findings)
    props = load_properties(args.properties, chart)
    unanswered = args.unanswered or props.unanswered
    senders, components = None, ()
    if args.topology:
        senders, components = _topology_environment(args.topology)
    expressions = [
        m.when
        for p in props.properties
        for m in (p.first, p.second, p.third)
        if m is not None and m.when is not None
    ]
    environment = Environment.of(chart, senders, components, expressions)
    explorer = Explorer(chart, props.properties, environment, unanswered, args.max_states)

    def progress(states: int, transitions: int) -> None:
        if not args.json:
            print(f"  ... {states} states, {transitions} transitions", file=sys.stderr)

    result = explorer.run(progress)
    out_dir = Path(args.counterexamples)
    written: dict[str, str] = {}
    for verdict in result.verdicts:
        if not verdict.holds:
            written[verdict.prop.name] = str(
                write_counterexample(out_dir, chart, verdict, args.chart)
            )
    if args.json:
        print(json.dumps(_as_json(result, written), indent=2))
    else:
        _print(result, written, chart.name)
    failed = any(not v.holds for v in result.verdicts) or not result.complete
    return 1 if failed else 0


def _topology_environment(path: str) -> tuple[list[str], list[tuple[str, str]]]:
    """The events a topology's world sends its chart (operator events and what its
    components emit) and its (component, process) pairs."""
    from framework.topology import check_topology

    topology, findings = check_topology(path)
    errors = [f for f in findings if f.severity == "error"]
    if topology is None or errors:
        raise FindingsError(errors or findings)
    senders = list(topology.external_events)
    for spec in topology.components.values():
        if spec.info is not None:
            senders += list(spec.info.emits)
    components = [(name, spec.process) for name, spec in topology.components.items()]
    return senders, components


def _print(result: Any, written: dict[str, str], chart: str) -> None:
    quantum = f"time step {result.quantum:g} s" if result.quantum else "no timers"
    print(
        f"fw verify: {chart}: {result.states} states, {result.transitions} transitions "
        f"in {result.seconds:.1f} s ({quantum}; at most {result.unanswered} requests "
        f"unanswered at once: {result.beyond_bound} steps beyond it not taken)"
    )
    if not result.complete:
        print("  INCOMPLETE: the exploration stopped at --max-states; raise it to finish")
    width = max((len(v.prop.name) for v in result.verdicts), default=0)
    for verdict in result.verdicts:
        prop = verdict.prop
        if verdict.holds:
            print(f"  holds     {prop.name:<{width}}  {prop.describe()}")
            continue
        print(f"  VIOLATED  {prop.name:<{width}}  {prop.describe()}")
        print(f"            {verdict.why}; shortest trace ({len(verdict.trace or [])} steps):")
        for step in verdict.trace or []:
            print(f"            {step.describe()}")
        print(f"            then: {', '.join(verdict.leaves)}")
        print(f"            scenario: {written[prop.name]}")


def _as_json(result: Any, written: dict[str, str]) -> dict[str, Any]:
    return {
        "states": result.states,
        "transitions": result.transitions,
        "seconds": round(result.seconds, 3),
        "quantum": result.quantum,
        "unanswered": result.unanswered,
        "beyond_bound": result.beyond_bound,
        "complete": result.complete,
        "properties": [
            {
                "name": v.prop.name,
                "holds": v.holds,
                "why": v.why,
                "trace": [
                    {"at": s.at, "kind": s.kind, "event": s.event, "payload": s.payload}
                    for s in v.trace or []
                ],
                "leaves": v.leaves,
                "scenario": written.get(v.prop.name),
            }
            for v in result.verdicts
        ],
    }


def add_commands(sub: Any) -> None:
    """Add `fw verify` to fw's subcommands."""
    p = sub.add_parser(
        "verify",
        help="prove a chart's safety properties over every reachable state",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("chart", metavar="CHART", help="the statechart YAML")
    p.add_argument("--properties", "-p", required=True, metavar="FILE", help="the properties YAML")
    p.add_argument(
        "--topology",
        "-t",
        metavar="T",
        help="send only the events this topology's operators and components send",
    )
    p.add_argument(
        "--unanswered",
        type=int,
        metavar="K",
        help="at most K configuration requests wait for an answer at once "
        "(default: the properties file's, else 2)",
    )
    p.add_argument(
        "--counterexamples",
        default="counterexamples",
        metavar="DIR",
        help="where violations' scenarios are written (default: ./counterexamples)",
    )
    p.add_argument(
        "--max-states",
        type=int,
        default=2_000_000,
        metavar="N",
        help="stop (and fail) after this many states (default: 2000000)",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_verify)
