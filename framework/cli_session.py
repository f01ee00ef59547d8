"""`fw send`, `fw call`, `fw status`, `fw ls` and `fw keys`: an operator's session
with a running deployment. They read the topology without importing its component
classes (what the classes declare, the running deployment tells)."""

from __future__ import annotations

import argparse
import contextlib
import difflib
import json
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from framework import keys
from framework.errors import FwError

KEYS_HELP = "the deployment's keystore, if fw deploy was given --keys (default: its own)"
EPILOG_SEND = """\
examples:
  fw send --list --topology topologies/seeg.yaml      (each event, its payload fields)
  fw send e_START --topology topologies/seeg.yaml
  fw send e_STOP --payload '{"reason": "operator"}' --topology topologies/seeg.yaml
  fw send e_GOTO --payload '{"where": "home"}' --topology topologies/seeg.yaml
  fw send e_RELEASE --topology topologies/seeg.yaml
"""


@contextlib.contextmanager
def _joined(topology_path: str, keystore: str | None = None) -> Iterator[tuple[Any, Any]]:
    """Join a running deployment's bus (closed on the way out); see `_join`."""
    topology, bus = _join(topology_path, keystore)
    try:
        yield topology, bus
    finally:
        bus.close()


def _join(topology_path: str, keystore: str | None = None) -> tuple[Any, Any]:
    from framework.bus import Bus, client_config
    from framework.keystore import OPERATOR
    from framework.topology import load_topology

    topology = load_topology(topology_path, classes=False)  # the deployment knows them
    bus = Bus(client_config(topology.bus, keystore), subject=OPERATOR)
    processes = len({c.process for c in topology.components.values()}) + 1  # + the deployer
    if not bus.wait_for_peers(processes, timeout=2.0) and bus.peers() == 0:
        return topology, bus  # nobody at all: nothing to wait for
    # A container declares its queryables before its liveliness tokens and declarations
    # travel in order: once every token is visible, every queryable can be asked.
    expected = {keys.alive(name) for name in topology.components}
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and not expected <= set(bus.alive(keys.ALL_ALIVE, 1.0)):
        time.sleep(0.02)
    return topology, bus


def _json_object(text: str | None, option: str) -> dict[str, Any]:
    """A command-line option's JSON object ({} if not given); a clear error otherwise."""
    try:
        value = json.loads(text) if text else {}
    except json.JSONDecodeError as exc:
        raise FwError(f"{option} is not JSON: {exc.msg}") from None
    if not isinstance(value, dict):
        raise FwError(f"{option} must be a JSON object")
    return value


def example_payload(spec: Any) -> dict[str, Any]:
    """A payload `spec` (an EventSpec) takes, to show how its event is sent: the first
    allowed value, the lower limit (or 0) of a number, "..." for free text."""
    example: dict[str, Any] = {}
    for name, vtype in spec.payload.items():
        limits = spec.fields.get(name, {})
        if "values" in limits:
            example[name] = limits["values"][0]
        elif vtype in ("number", "integer"):
            low, high = limits.get("min"), limits.get("max")
            inside = 0 if (low is None or low <= 0) and (high is None or high >= 0) else low
            example[name] = inside if inside is not None else high
        elif vtype == "boolean":
            example[name] = True
        else:
            example[name] = "..."
    return example


def list_events(topology_path: str) -> str:
    """The operator events of a topology, each with its doc, its payload fields (type,
    allowed values, limits, unit) and a command that sends it: read from the topology
    and its chart, no deployment needed."""
    from framework.statechart.loader import load_statechart
    from framework.topology import load_topology

    topology = load_topology(topology_path, classes=False)
    if topology.statechart is None:
        return f"{topology.name} has no statechart: no operator events"
    chart = load_statechart(topology.statechart, validate=False)
    lines = [f"operator events of {topology.name} ({os.path.normpath(topology.statechart)}):"]
    for name in topology.external_events:
        spec = chart.events.get(name)
        if spec is None:
            lines.append(f"  {name}: not declared by the chart")
            continue
        payload = example_payload(spec)
        command = f"fw send {name}" + (f" --payload '{json.dumps(payload)}'" if payload else "")
        lines.append(f"  {command} --topology {topology_path}")
        if spec.doc:
            lines.append(f"      {spec.doc}")
        for field_name in spec.payload:
            doc = spec.fields.get(field_name, {}).get("doc")
            lines.append(f"      {spec.describe(field_name)}" + (f": {doc}" if doc else ""))
    if not topology.external_events:
        lines.append("  none: the topology lists no external_events, so every command is refused")
    return "\n".join(lines)


def cmd_send(args: argparse.Namespace) -> int:
    """Offer one operator event to the chart of a running deployment; print its answer."""
    import getpass

    from framework.remote import RemoteComponent, RemoteError

    if args.list:
        print(list_events(args.topology))
        return 0
    if args.event is None:
        raise FwError("name the EVENT to send (fw send --list shows them)")
    payload = _json_object(args.payload, "--payload")
    with _joined(args.topology, args.keys) as (topology, bus):
        try:
            answer = RemoteComponent(bus, "coordinator", timeout=args.timeout).call(
                "offer", event=args.event, payload=payload, origin=f"fw send@{getpass.getuser()}"
            )
        except RemoteError as exc:
            raise FwError(
                f"no answer from the Coordinator of {topology.bus.namespace!r} "
                f"(is the deployment running?): {exc}"
            ) from None
    shown = args.event + (f" {json.dumps(payload)}" if payload else "")
    if not answer.get("accepted"):
        print(f"refused {shown}: {answer.get('reason')}", file=sys.stderr)
        return 1
    print(f"accepted {shown}")
    return 0


def cmd_call(args: argparse.Namespace) -> int:
    """Call a read-only operation of a running deployment's component; print its result."""
    from framework.remote import RemoteComponent, RemoteError

    component, _, operation = args.target.partition(".")
    if not component or not operation:
        raise FwError(f"{args.target!r}: name it COMPONENT.OPERATION, e.g. robot.report")
    call_args = _json_object(args.args, "--args")
    with _joined(args.topology, args.keys) as (topology, bus):
        if component not in topology.components:
            close = difflib.get_close_matches(component, list(topology.components), n=1)
            hint = f"did you mean {close[0]!r}?" if close else "see `fw ls`"
            raise FwError(f"no component {component!r} in {topology.name!r}; {hint}")
        remote = RemoteComponent(bus, component, timeout=min(args.timeout, 2.0))
        deadline = time.monotonic() + args.timeout
        while True:  # a fresh session learns the routes to the component's queryable first
            try:
                _callable(component, operation, remote.describe())
                result = remote.call(operation, **call_args)
                break
            except RemoteError as exc:
                if exc.kind != "Timeout" or time.monotonic() > deadline:
                    raise FwError(str(exc)) from None
                time.sleep(0.1)
    print(json.dumps(result, indent=2, default=str))
    return 0


def _callable(component: str, operation: str, described: dict[str, Any]) -> None:
    """Refuse, with what to do instead, a call the component would not answer
    (`described`: what the running component says of itself)."""
    operations = {op["name"]: op for op in described.get("operations", [])}
    if operation not in operations:
        close = difflib.get_close_matches(operation, list(operations), n=1)
        hint = f"did you mean {close[0]!r}?" if close else "it has " + ", ".join(operations)
        raise FwError(f"{component} has no operation {operation!r}; {hint}")
    if not operations[operation].get("readonly"):
        readonly = sorted(n for n, op in operations.items() if op.get("readonly"))
        raise FwError(
            f"{component}.{operation} changes state: an operator's session may call only "
            f"read-only operations ({', '.join(readonly) or 'none here'}); what "
            "changes the robot goes through the chart (`fw send EVENT`)"
        )


def cmd_keys(args: argparse.Namespace) -> int:
    """Make a keystore for `fw deploy --keys` (several hosts share one)."""
    from framework.keystore import create_keystore
    from framework.topology import load_topology

    topology = load_topology(args.topology, classes=False)
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise FwError(f"{out} exists and is not empty: choose a new directory")
    processes = sorted({c.process for c in topology.components.values()})
    store = create_keystore(out, processes, [*topology.addresses(), *args.address])
    print(f"keystore for {topology.name!r} in {store.root}: {', '.join(store.subjects())}")
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    """Component states, active chart states and last events of a running deployment."""
    from framework.introspect import discover
    from framework.remote import RemoteComponent, RemoteError

    with _joined(args.topology, args.keys) as (topology, bus):
        found = discover(bus) if bus.peers() else {}
        if not found:
            raise FwError(f"nothing is running in deployment {topology.bus.namespace!r}")
        if args.watch:
            return _watch(topology, bus, args.frames)
        try:
            chart = RemoteComponent(bus, "coordinator", 3.0).call("active")
        except RemoteError:
            chart = None
        alive = {k.rsplit("/", 1)[-1] for k in bus.alive(keys.ALL_ALIVE, 1.0)}
        lost = {n: c.process for n, c in topology.components.items() if n not in alive}
        if args.json:
            print(json.dumps({"containers": found, "chart": chart, "lost": lost}, indent=2))
            return 0
        if chart is not None:
            print(
                "chart:   "
                + ", ".join(chart["active"])
                + ("  [finished]" if chart["finished"] else "")
            )
            print("pending: " + (", ".join(chart["pending"].values()) or "-"))
            print("events:  " + (", ".join(chart["last_events"]) or "-"))
        for container, names in found.items():
            for name in names:
                try:
                    state = RemoteComponent(bus, name, 2.0).state()
                except RemoteError:
                    state = "NOT RESPONDING"
                print(f"{name:<20} {container:<16} {state}")
        for name, process in lost.items():
            print(f"{name:<20} {process:<16} LOST (no liveliness: its process died or hangs)")
        return 0


def _watch(topology: Any, bus: Any, frames: int | None) -> int:
    """Redraw the console's essentials twice a second until Ctrl-C (or `frames`)."""
    from framework.console.model import ConsoleModel
    from framework.console.text import render_text
    from framework.statechart.loader import load_statechart

    chart = load_statechart(topology.statechart) if topology.statechart else None
    model = ConsoleModel(bus, topology, chart).start()
    clear = "\x1b[H\x1b[2J" if sys.stdout.isatty() else ""
    shown = 0
    try:
        while frames is None or shown < frames:
            time.sleep(0.5)
            sys.stdout.write(clear + render_text(model.snapshot()) + "\n\n")
            sys.stdout.flush()
            shown += 1
    except KeyboardInterrupt:
        pass
    finally:
        model.stop()
    return 0


def cmd_ls(args: argparse.Namespace) -> int:
    """Components, ports, keys and connections of a running deployment."""
    from framework.introspect import snapshot

    with _joined(args.topology, args.keys) as (topology, bus):
        snap = snapshot(bus)
        if not snap.containers:
            raise FwError(f"nothing is running in deployment {topology.bus.namespace!r}")
        if args.json:
            print(
                json.dumps(
                    {
                        "containers": snap.containers,
                        "components": snap.components,
                        "connections": [c.__dict__ for c in snap.connections],
                    },
                    indent=2,
                    default=str,
                )
            )
            return 0
        for name, info in snap.components.items():
            print(f"{name} ({info['class']}) {info['state']} in {info['container']}")
            for port in info["inputs"]:
                print(f"  in  {port['name']:<16} {port['type']:<12} <- {port['key'] or '-'}")
            for port in info["outputs"]:
                print(
                    f"  out {port['name']:<16} {port['type']:<12} -> "
                    f"{', '.join(port['keys']) or '-'}"
                )
        print("connections:")
        for conn in snap.connections:
            print(
                f"  {conn.key:<32} {', '.join(conn.writers) or '(no writer)'} -> "
                f"{', '.join(conn.readers) or '(no reader)'}"
            )
        return 0


def add_commands(sub: Any) -> None:
    """Register the commands that talk to a running deployment."""
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser(
        "send",
        help="offer an operator event to a running deployment's chart; prints its answer",
        epilog=EPILOG_SEND,
        formatter_class=raw,
    )
    p.add_argument("event", metavar="EVENT", nargs="?")
    p.add_argument(
        "--list",
        action="store_true",
        help="list the operator events with their payload fields and a command for each "
        "(reads the topology; no deployment needed)",
    )
    p.add_argument("--payload", metavar="JSON", help="event payload as a JSON object")
    p.add_argument("--topology", required=True, metavar="T")
    p.add_argument(
        "--timeout",
        type=float,
        default=3.0,
        metavar="S",
        help="how long to look for the Coordinator",
    )
    p.add_argument("--keys", metavar="DIR", help=KEYS_HELP)
    p.set_defaults(func=cmd_send)

    p = sub.add_parser(
        "call",
        help="call a read-only operation of a running deployment's component",
        description="Join a running deployment as its operator and call one of a "
        "component's read-only operations (those that change nothing); waits for the "
        "component up to --timeout. What changes the robot goes through the chart "
        "(`fw send`).",
        epilog="examples:\n  fw call robot.report --topology topologies/seeg.yaml\n"
        "  fw call people_world.where --topology topologies/seeg.yaml --timeout 10\n"
        "  fw call supervisor.stats --topology topologies/demo.yaml\n",
        formatter_class=raw,
    )
    p.add_argument("target", metavar="COMPONENT.OPERATION")
    p.add_argument("--args", metavar="JSON", help="keyword arguments as a JSON object")
    p.add_argument("--topology", required=True, metavar="T")
    p.add_argument(
        "--timeout", type=float, default=5.0, metavar="S", help="how long to wait for it"
    )
    p.add_argument("--keys", metavar="DIR", help=KEYS_HELP)
    p.set_defaults(func=cmd_call)

    p = sub.add_parser(
        "status",
        help="states of a running deployment",
        description="Component states, the chart's active states and last events; with "
        "--watch, the operator console's essentials redrawn live (for a terminal, over SSH).",
        epilog="examples:\n  fw status --topology topologies/seeg.yaml\n"
        "  fw status --topology topologies/seeg.yaml --watch",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--topology", required=True, metavar="T")
    p.add_argument("--json", action="store_true")
    p.add_argument(
        "--watch", action="store_true", help="operation, area, tracker, people, log: live"
    )
    p.add_argument("--frames", type=int, metavar="N", help="with --watch: stop after N screens")
    p.add_argument("--keys", metavar="DIR", help=KEYS_HELP)
    p.set_defaults(func=cmd_status)

    p = sub.add_parser(
        "ls",
        help="components, ports, keys and connections of a deployment",
        description="Ask a running deployment what it hosts: every process's components "
        "with their state, ports and the keys they are connected to.",
        epilog="examples:\n  fw ls --topology topologies/seeg.yaml\n"
        "  fw ls --topology topologies/demo.yaml --json",
        formatter_class=raw,
    )
    p.add_argument("--topology", required=True, metavar="T")
    p.add_argument("--json", action="store_true")
    p.add_argument("--keys", metavar="DIR", help=KEYS_HELP)
    p.set_defaults(func=cmd_ls)

    p = sub.add_parser(
        "keys",
        help="make a keystore for a deployment over several hosts",
        description="Issue a CA and one certificate per process of the topology (plus "
        "control and operator) into DIR, for `fw deploy --keys DIR` on every host. The "
        "CA's private key is not kept. Copy DIR to each host, readable by its user only.",
        epilog="examples:\n  fw keys topologies/seeg.yaml -o /etc/fw/seeg-keys\n"
        "  fw keys topologies/seeg.yaml -o keys --address 10.0.0.7   a host listens there",
        formatter_class=raw,
    )
    p.add_argument("topology", metavar="TOPOLOGY")
    p.add_argument("-o", "--out", required=True, metavar="DIR")
    p.add_argument(
        "--address",
        action="append",
        default=[],
        metavar="ADDR",
        help="an address the processes listen on, besides 127.0.0.1 and the topology's "
        "bus: address and hosts: addresses (repeatable)",
    )
    p.set_defaults(func=cmd_keys)
