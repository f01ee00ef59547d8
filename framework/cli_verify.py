"""`fw verify`: prove a chart's safety properties over every reachable state, and
write each violation's shortest trace as a scenario."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from framework.errors import FindingsError, FwError

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

--spin checks the same question a second way: the chart and each property exported to
Promela with semantics of their own (framework/verify/promela.py), searched by SPIN; a
SPIN counterexample is played on fw's interpreter to confirm it. Needs `spin` and `cc`
(tools/install.sh --test installs them).

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

    if args.promela and not args.spin:
        raise FwError("--promela DIR keeps the models of --spin: add --spin")
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
    second = _cross_check(args, chart, props.properties, explorer, result) if args.spin else None
    out_dir = Path(args.counterexamples)
    written: dict[str, str] = {}
    for verdict in result.verdicts:
        if not verdict.holds:
            written[verdict.prop.name] = str(
                write_counterexample(out_dir, chart, verdict, args.chart)
            )
    if args.json:
        report = _as_json(result, written)
        if second is not None:
            report["spin"] = second
        print(json.dumps(report, indent=2))
    else:
        _print(result, written, chart.name)
        if second is not None:
            _print_spin(second)
    failed = any(not v.holds for v in result.verdicts) or not result.complete
    disagree = second is not None and not all(c["agrees"] for c in second)
    return 1 if failed or disagree else 0


def _cross_check(
    args: argparse.Namespace, chart: Any, properties: list[Any], explorer: Any, result: Any
) -> list[dict[str, Any]]:
    """SPIN's verdict on every property beside fw's, and each SPIN counterexample played
    on fw's interpreter: agreement means the same verdict and, on a violation, a SPIN
    trace that fw's own engine confirms."""
    from framework.verify import spin
    from framework.verify.promela import Inputs

    if not args.json:
        print("  ... SPIN: one model per property (framework/verify/promela.py)", file=sys.stderr)
    inputs = Inputs.of(explorer)
    verdicts = spin.check(chart, properties, inputs, keep=args.promela)
    out = []
    for i, (theirs, ours) in enumerate(zip(verdicts, result.verdicts, strict=True)):
        confirmed = None
        if not theirs.holds:
            confirmed = i in explorer.judge(theirs.trace)
        out.append(
            {
                "name": theirs.prop.name,
                "spin_holds": theirs.holds,
                "fw_holds": ours.holds,
                "agrees": theirs.holds == ours.holds and confirmed is not False,
                "spin_states": theirs.states,
                "spin_seconds": round(theirs.seconds, 2),
                "spin_trace_steps": len(theirs.trace) if not theirs.holds else None,
                "fw_trace_steps": len(ours.trace) if not ours.holds else None,
                "spin_trace_confirmed_by_fw": confirmed,
                "model": theirs.model if args.promela else None,
            }
        )
    return out


def _print_spin(rows: list[dict[str, Any]]) -> None:
    agree = sum(r["agrees"] for r in rows)
    print(f"SPIN cross-check: {agree} of {len(rows)} properties agree")
    width = max((len(r["name"]) for r in rows), default=0)
    for r in rows:
        mark = "agrees   " if r["agrees"] else "DISAGREES"
        spin_says = "holds" if r["spin_holds"] else "violated"
        fw_says = "holds" if r["fw_holds"] else "violated"
        line = f"  {mark} {r['name']:<{width}}  SPIN {spin_says}, fw {fw_says}"
        if not r["spin_holds"]:
            ok = "confirmed" if r["spin_trace_confirmed_by_fw"] else "NOT confirmed"
            line += (
                f"; SPIN's trace ({r['spin_trace_steps']} steps) {ok} by fw's interpreter, "
                f"fw's shortest {r['fw_trace_steps']} steps"
            )
        print(line + f"  [{r['spin_states']} SPIN states, {r['spin_seconds']:.1f} s]")


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
    p.add_argument(
        "--spin",
        action="store_true",
        help="judge every property a second time with the SPIN model checker (Debian's "
        "spin and a C compiler) on a Promela model with semantics written anew; exit 1 "
        "if the two disagree",
    )
    p.add_argument(
        "--promela",
        metavar="DIR",
        help="with --spin: keep each property's Promela model (and SPIN's trail) in DIR",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_verify)
