"""`fw deploy`, `fw send`, `fw status` and `fw ls`: run a topology and talk to it."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from framework import keys
from framework.errors import FwError
from framework.statechart.events import Event, Listener
from framework.statechart.model import State, Transition

EPILOG_DEPLOY = """\
Checks the topology, its statechart and every cross-reference first (nothing starts if
anything is wrong), starts the topology's processes, waits until every component is
alive, then runs the statechart. Ctrl-C shuts down in order, the robot side first.

examples:
  fw deploy topologies/demo.yaml                    live status until Ctrl-C
  fw deploy topologies/demo.yaml --headless --duration 10
  fw deploy topologies/demo.yaml --record run.mcap  keep a flight recording
  fw deploy topologies/seeg.yaml --console-port 8080   the operator console on another port
  fw deploy topologies/seeg.yaml --console-host 0.0.0.0 --console-cert or3.pem --console-key or3.key
                                                    the console for the OR's network (HTTPS)

The operator console (a web page: status, START / RELEASE / Go To, the chart, the
event log) is served on http://127.0.0.1:8470/?token=... when fw deploy runs in a terminal, or
whenever --console-port is given; --no-console turns it off. It listens on
127.0.0.1 only, unless --console-host says otherwise; beyond this machine it is served
over TLS only: with --console-cert/--console-key if given, else with a certificate made
for the run, whose SHA-256 fingerprint is printed (compare it with the browser's).
"""

KEYS_HELP = "the deployment's keystore, if fw deploy was given --keys (default: its own)"
EPILOG_SEND = """\
examples:
  fw send e_START --topology topologies/demo.yaml
  fw send e_TOK --payload '{"tracker": "certus"}' --topology topologies/demo.yaml
"""


class _Printer(Listener):
    """Headless status: one line per chart step."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()

    def line(self, text: str) -> None:
        print(f"[{time.monotonic() - self.t0:8.3f}] {text}", flush=True)

    def on_event(self, event: Event) -> None:
        payload = f" {json.dumps(event.payload)}" if event.payload else ""
        self.line(f"event      {event.name}{payload}")

    def on_unhandled(self, event: Event, reason: str) -> None:
        self.line(f"unhandled  {event.name}: {reason}")

    def on_transition(self, transition: Transition, event: Event | None) -> None:
        target = transition.target.path if transition.target is not None else "(internal)"
        self.line(f"transition {transition.source.path} -> {target}")

    def on_entry(self, state: State) -> None:
        if state.configure is not None:
            self.line(f"configure  {state.configure.tag} (for {state.path})")

    def on_refused(self, event: str, source: str, reason: str) -> None:
        self.line(f"refused    {event} from {source or '?'}: {reason}")

    def on_error(self, message: str, event: Event | None) -> None:
        self.line(f"error      {message}")


def _screen(deployment: Any, started: float, console: str = "") -> str:
    """The one-screen live status."""
    from framework.remote import RemoteComponent, RemoteError

    lines = [
        f"fw deploy {deployment.topology.name}   up {time.monotonic() - started:6.1f} s"
        "   (Ctrl-C to stop)",
        f"operator console: {console}" if console else "",
        "",
    ]
    if deployment.coordinator is not None:
        info = deployment.coordinator.active()
        lines.append(
            "chart      "
            + ", ".join(info["active"])
            + ("   [finished]" if info["finished"] else "")
        )
        pending = ", ".join(info["pending"].values()) or "-"
        lines.append(f"waiting on {pending}")
        if deployment.topology.external_events:
            lines.append(
                f"send      {', '.join(deployment.topology.external_events)}   with: fw send "
                f"EVENT --topology {os.path.relpath(deployment.topology.file)}"
            )
    history = deployment.configurator.history[-5:] if deployment.configurator else []
    for outcome in history:
        mark = "ok  " if outcome.ok else "FAIL"
        extra = "" if outcome.ok else f"  {outcome.step}: {outcome.reason}"
        lines.append(f"  {mark} {outcome.tag:<24} {outcome.seconds * 1e3:7.2f} ms{extra}")
    watch = deployment.watch
    lost = deployment.coordinator.lost if deployment.coordinator is not None else {}
    lost_processes = watch.lost if watch is not None else {}
    lines += ["", f"{'component':<20} {'process':<16} state"]
    for spec in deployment.topology.components.values():
        if spec.name in lost or spec.process in lost_processes:
            state = f"LOST ({lost_processes.get(spec.process, 'no liveliness')})"
        else:
            try:
                state = RemoteComponent(deployment.hub, spec.name, 0.3).state()
            except RemoteError:
                state = "NOT RESPONDING"
        lines.append(f"{spec.name:<20} {spec.process:<16} {state}")
    if watch is not None and watch.incidents:
        lines += ["", *watch.incidents[-5:]]
    return "\n".join(lines)


def cmd_deploy(args: argparse.Namespace) -> int:
    """Run a topology (see EPILOG_DEPLOY)."""
    from framework.deployer import Deployment
    from framework.topology import load_topology

    topology = load_topology(args.topology)
    for item in args.record_samples:
        key, _, kind = item.partition("=")
        if not key or not kind:
            raise FwError(f"--record-samples takes KEY=TYPE, not {item!r}")
        from framework.messages import resolve_type

        resolve_type(kind)
    interactive = sys.stdout.isatty() and not args.headless
    serve_console = not args.no_console and (args.console_port is not None or interactive)
    console_tls = _console_tls(args) if serve_console else (None, "")  # before anything starts
    workdir = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="fw-"))
    listeners: list[Listener] = [] if interactive else [_Printer()]
    recorder = None
    console = None
    scenario = None
    if args.scenario:
        from framework.scenario import load_scenario
        from framework.statechart.loader import load_statechart
        from framework.statechart.model import BUILTIN_EVENTS

        events = states = None
        if topology.statechart is not None:
            chart = load_statechart(topology.statechart)
            events = set(chart.events) | set(BUILTIN_EVENTS)
            states = {state.path for state in chart.states.values()}
        operations = {
            f"{n}.{op}"
            for n, c in topology.components.items()
            if c.info
            for op in c.info.operations
        }
        processes = {c.process for c in topology.components.values()}
        scenario = load_scenario(args.scenario, events, operations, states, processes)
        if not args.record:  # a scenario run always leaves its flight recording
            args.record = str(Path("out") / "scenarios" / f"{scenario.name}.mcap")
            Path(args.record).parent.mkdir(parents=True, exist_ok=True)
    printer = next((x for x in listeners if isinstance(x, _Printer)), None)
    deployment = Deployment(
        topology,
        workdir,
        listeners=listeners,
        host=args.host,
        scenario=scenario,
        report=printer.line if printer else None,
        keys=Path(args.keys) if args.keys else None,
    )
    from framework.deployer import LOCAL, host_of

    mine = args.host or LOCAL
    n = len(
        {c.process for c in topology.components.values() if host_of(topology, c.process) == mine}
    )
    print(
        f"fw: {topology.name}: starting {n} process(es), {len(topology.components)} "
        f"component(s); logs in {workdir}",
        file=sys.stderr,
    )
    started = time.monotonic()
    if topology.safety is not None:  # the Coordinator's process is watched too
        from framework.container import raise_priority
        from framework.deployer import SAFETY_NICE

        raise_priority(SAFETY_NICE, "control")
    try:
        deployment.start(run_chart=False)
        if args.record:
            from framework.recorder import FlightRecorder

            samples = dict(item.split("=", 1) for item in args.record_samples)
            recorder = FlightRecorder(
                args.record,
                deployment.hub,
                samples,
                metadata={
                    "topology": str(Path(args.topology).resolve()),
                    "statechart": str(topology.statechart.resolve()) if topology.statechart else "",
                },
            )
        deployment.run_chart()
        print(
            f"fw: all components alive and wired in {time.monotonic() - started:.2f} s; "
            "the chart runs",
            file=sys.stderr,
        )
        if serve_console:
            console = _start_console(args, deployment, topology, console_tls)
        end = started + args.duration if args.duration else None
        runner = deployment.runner
        while end is None or time.monotonic() < end:
            if runner is not None and runner.finished.is_set():
                time.sleep(0.5)  # let the last reactions land in the recording
                break
            if interactive:
                sys.stdout.write(
                    "\x1b[H\x1b[2J"
                    + _screen(deployment, started, console.url if console else "")
                    + "\n"
                )
                sys.stdout.flush()
            time.sleep(0.5 if end is None else min(0.5, max(0.0, end - time.monotonic())))
    except KeyboardInterrupt:
        print("\nfw: shutting down (robot side first)...", file=sys.stderr)
    finally:
        if console is not None:
            console.stop()
            console.model.stop()
        deployment.stop()
        if recorder is not None:
            recorder.close()
            print(f"fw: flight recording in {args.record}", file=sys.stderr)
        if not args.workdir and not args.keep_logs:
            shutil.rmtree(workdir, ignore_errors=True)
    print("fw: stopped", file=sys.stderr)
    if deployment.runner is not None:
        return _scenario_report(deployment.runner)
    return 0


def _start_console(
    args: argparse.Namespace, deployment: Any, topology: Any, console_tls: tuple[Any, str]
) -> Any:
    """Serve the operator console (over TLS if `console_tls` has a context)."""
    from framework.console.model import ConsoleModel
    from framework.console.server import DEFAULT_PORT, ConsoleServer

    tls, certificate = console_tls
    chart = deployment.coordinator.chart if deployment.coordinator is not None else None
    model = ConsoleModel(deployment.hub, topology, chart).start()
    port = DEFAULT_PORT if args.console_port is None else args.console_port
    server = ConsoleServer(model, args.console_host, port, tls=tls)
    try:
        url = server.start()
    except FwError:
        model.stop()
        raise
    print(f"fw: operator console on {url} (the link carries this run's login)", file=sys.stderr)
    if certificate:
        print(f"fw: {certificate}", file=sys.stderr)
    return server


def _console_tls(args: argparse.Namespace) -> tuple[Any, str]:
    """The console's TLS context (None on loopback without a certificate) and what to
    tell the operator about its certificate. Beyond loopback there is no plain HTTP."""
    from framework.console import tls

    if bool(args.console_cert) != bool(args.console_key):
        raise FwError("--console-cert and --console-key go together (a certificate and its key)")
    if args.console_cert:
        cert = Path(args.console_cert)
        context = tls.server_context(cert, Path(args.console_key))
        return context, f"console certificate {cert} (SHA-256 {tls.fingerprint(cert)})"
    if tls.is_loopback(args.console_host):
        return None, ""
    made = Path(tempfile.mkdtemp(prefix="fw-console-"))
    try:
        cert, key = tls.self_signed(tls.names_for(args.console_host), made)
        context = tls.server_context(cert, key)
        digest = tls.fingerprint(cert)
    finally:
        shutil.rmtree(made, ignore_errors=True)  # the key lives on in memory only
    return context, (
        "the console's certificate was made for this run (no --console-cert): the browser "
        f"will warn; accept it only if it shows SHA-256 {digest}"
    )


def _scenario_report(runner: Any) -> int:
    """Print PASS/FAIL per check and expectation (NOT RUN for an invariant whose state
    never held: nothing was checked); 0 if nothing failed."""
    outcomes = runner.report()
    print(f"\nscenario {runner.scenario.name}:")
    for outcome in outcomes:
        detail = f"  ({outcome.detail})" if outcome.detail else ""
        verdict = "FAIL" if not outcome.ok else "PASS" if outcome.exercised else "NOT RUN"
        print(f"  {verdict:<7} {outcome.what}{detail}")
    failed = sum(not o.ok for o in outcomes)
    unrun = sum(o.ok and not o.exercised for o in outcomes)
    passed = len(outcomes) - failed - unrun
    print(
        f"{'PASSED' if not failed else 'FAILED'}: {passed} passed, {failed} failed, "
        f"{unrun} not run (their state never held)"
    )
    return 1 if failed else 0


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

    topology = load_topology(topology_path)
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


def cmd_send(args: argparse.Namespace) -> int:
    """Offer one operator event to the chart of a running deployment; print its answer."""
    import getpass

    from framework.remote import RemoteComponent, RemoteError

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
        _callable(topology, component, operation)
        remote = RemoteComponent(bus, component, timeout=min(args.timeout, 2.0))
        deadline = time.monotonic() + args.timeout
        while True:  # a fresh session learns the routes to the component's queryable first
            try:
                result = remote.call(operation, **call_args)
                break
            except RemoteError as exc:
                if exc.kind != "Timeout" or time.monotonic() > deadline:
                    raise FwError(str(exc)) from None
                time.sleep(0.1)
    print(json.dumps(result, indent=2, default=str))
    return 0


def _callable(topology: Any, component: str, operation: str) -> None:
    """Refuse, with what to do instead, a call the deployment would not answer."""
    import difflib

    spec = topology.components.get(component)
    if spec is None:
        close = difflib.get_close_matches(component, list(topology.components), n=1)
        hint = f"did you mean {close[0]!r}?" if close else "see `fw ls`"
        raise FwError(f"no component {component!r} in {topology.name!r}; {hint}")
    info = spec.info
    if info is None:
        return
    if operation not in info.operations:
        close = difflib.get_close_matches(operation, list(info.operations), n=1)
        hint = f"did you mean {close[0]!r}?" if close else "it has " + ", ".join(info.operations)
        raise FwError(f"{component} has no operation {operation!r}; {hint}")
    if operation not in info.readonly:
        raise FwError(
            f"{component}.{operation} changes state: an operator's session may call only "
            f"read-only operations ({', '.join(sorted(info.readonly)) or 'none here'}); what "
            "changes the robot goes through the chart (`fw send EVENT`)"
        )


def cmd_keys(args: argparse.Namespace) -> int:
    """Make a keystore for `fw deploy --keys` (several hosts share one)."""
    from framework.keystore import create_keystore
    from framework.topology import load_topology

    topology = load_topology(args.topology)
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


def _summary(topic: str, data: dict[str, Any]) -> str:
    if topic == "/fw/chart":
        payload = data.get("payload") or {}
        kind = data.get("kind", "")
        if kind == "event":
            extra = f" {json.dumps(payload['payload'])}" if payload.get("payload") else ""
            return f"event      {payload.get('event')}{extra} ({payload.get('kind')})"
        if kind == "transition":
            return f"transition {payload.get('source')} -> {payload.get('target')}"
        if kind == "configuration":
            return "active     " + ", ".join(payload.get("active", []))
        if kind in ("entry", "exit"):
            return f"{kind:<10} {payload.get('state')}"
        return f"{kind:<10} {json.dumps(payload)}"
    if topic == "/fw/components":
        reason = f" ({data['reason']})" if data.get("reason") else ""
        return f"component  {data.get('component')}: {data.get('old')} -> {data.get('new')}{reason}"
    if topic == "/fw/refused":
        times = f" (x{data['count']})" if data.get("count", 1) > 1 else ""
        return f"REFUSED    {data.get('component')}.{data.get('port')}: {data.get('reason')}{times}"
    if topic == "/fw/config/request":
        return f"request    #{data.get('request_id')} {data.get('tag')}"
    if topic == "/fw/config/switched":
        verdict = "ok" if data.get("ok") else f"FAILED at {data.get('step')}: {data.get('reason')}"
        return f"switched   #{data.get('request_id')} {data.get('tag')} in {data.get('process')} {verdict}"
    if topic == "/fw/config/ack":
        verdict = "ok" if data.get("ok") else f"FAILED at {data.get('step')}: {data.get('reason')}"
        return f"ack        #{data.get('request_id')} {data.get('tag')} {verdict}"
    return f"{topic} {json.dumps(data)}"


def cmd_log(args: argparse.Namespace) -> int:
    """Print the timeline of a flight recording."""
    from framework.recorder import read_recording

    records = [r for r in read_recording(args.file) if r[0].startswith(args.topic or "")]
    # the chart records each request it makes, and the Configurator the same request with
    # its id: in text, one line per request (--json keeps both records)
    requested = {d.get("request_id") for t, _, d in records if t == "/fw/config/request"}
    t0 = None
    for topic, stamp, data in records:
        if (
            not args.json
            and topic == "/fw/chart"
            and data.get("kind") == "request"
            and (data.get("payload") or {}).get("request_id") in requested
        ):
            continue
        t0 = stamp if t0 is None else t0
        if args.json:
            print(json.dumps({"t": stamp, "topic": topic, "data": data}))
        else:
            print(f"[{stamp - t0:9.3f}] {_summary(topic, data)}")
    return 0


def recorded_events(path: str) -> list[tuple[float, str, dict[str, Any] | None]]:
    """(time from the start, event, payload) of every external chart event recorded."""
    from framework.recorder import read_recording

    out: list[tuple[float, str, dict[str, Any] | None]] = []
    t0 = None
    for topic, stamp, data in read_recording(path):
        t0 = stamp if t0 is None else t0
        if topic == "/fw/chart" and data.get("kind") == "event":
            payload = data.get("payload") or {}
            if payload.get("kind") == "external":
                out.append((stamp - t0, payload["event"], payload.get("payload")))
    return out


def cmd_replay(args: argparse.Namespace) -> int:
    """Feed a recording's chart events back into the chart on a simulated clock."""
    from framework.clock import SimulatedClock
    from framework.recorder import recording_metadata
    from framework.statechart.interpreter import Interpreter
    from framework.statechart.loader import load_statechart
    from framework.statechart.trace import TracePrinter

    chart_path = args.chart or recording_metadata(args.file).get("statechart")
    if not chart_path:
        raise FwError("the recording does not name its statechart; pass --chart FILE")
    chart = load_statechart(chart_path)
    clock = SimulatedClock()
    interpreter = Interpreter(chart, clock, [TracePrinter(clock, False)])
    interpreter.start()
    for at, name, payload in recorded_events(args.file):
        interpreter.advance_to(max(at, clock.now()))
        interpreter.queue(name, payload)
        interpreter.run()
    print(
        f"active: {', '.join(interpreter.leaves)}"
        + ("  [finished]" if interpreter.finished else "")
    )
    return 0


def add_commands(sub: Any) -> None:
    """Register the deployment commands on the `fw` parser."""
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser(
        "deploy",
        help="check and run a topology (the main job)",
        epilog=EPILOG_DEPLOY,
        formatter_class=raw,
    )
    p.add_argument("topology", metavar="TOPOLOGY")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--headless",
        action="store_true",
        help="print one line per chart step instead of the live screen",
    )
    p.add_argument("--record", metavar="FILE", help="write a flight recording (MCAP)")
    p.add_argument(
        "--record-samples",
        action="append",
        default=[],
        metavar="KEY=TYPE",
        help="also record the samples of KEY (message type TYPE, e.g. certus/cto=Pose)",
    )
    p.add_argument(
        "--host",
        metavar="NAME",
        help="start only the processes placed on host NAME (the Coordinator and "
        "Configurator run where --host is not given)",
    )
    p.add_argument(
        "--keys",
        metavar="DIR",
        help="use this keystore (made by `fw keys`, copied to every host) instead of a "
        "fresh one per run; needed with --host",
    )
    p.add_argument(
        "--scenario",
        metavar="FILE",
        help="timed events and operation calls to play (see docs/topologies.md)",
    )
    p.add_argument("--workdir", metavar="DIR", help="where process logs go (kept)")
    p.add_argument("--keep-logs", action="store_true", help="keep the temporary log folder")
    p.add_argument(
        "--console-port",
        type=int,
        metavar="PORT",
        help="serve the operator console on this port (default 8470 in a terminal; 0: any)",
    )
    p.add_argument(
        "--console-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="address the console listens on (default 127.0.0.1: this machine only)",
    )
    p.add_argument(
        "--console-cert",
        metavar="PEM",
        help="the console's TLS certificate (chain), e.g. from the hospital's PKI",
    )
    p.add_argument("--console-key", metavar="PEM", help="the private key of --console-cert")
    p.add_argument("--no-console", action="store_true", help="do not serve the console")
    p.set_defaults(func=cmd_deploy)

    p = sub.add_parser(
        "send",
        help="offer an operator event to a running deployment's chart; prints its answer",
        epilog=EPILOG_SEND,
        formatter_class=raw,
    )
    p.add_argument("event", metavar="EVENT")
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
        "log",
        help="print the timeline of a flight recording",
        description="One line per recorded chart step, configuration request and "
        "acknowledgement, component state change, refusal and deployer event (plus the "
        "port samples `fw deploy --record-samples` asked for), timed from the first.",
        epilog="examples:\n  fw log run.mcap                        (from fw deploy ... --record run.mcap)\n"
        "  fw log run.mcap --topic /fw/config     only the configurations\n"
        "  fw log run.mcap --json | jq .topic     one JSON object per line",
        formatter_class=raw,
    )
    p.add_argument("file", metavar="FILE")
    p.add_argument("--topic", help="only topics starting with this (e.g. /fw/config)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=cmd_log)

    p = sub.add_parser(
        "replay",
        help="feed a flight recording's events back into the chart",
        description="Step the recorded chart (or --chart, e.g. a fixed version) through "
        "the external events of a recording, at their recorded times, on a simulated "
        "clock; prints the trace and the states it ends in.",
        epilog="examples:\n  fw replay run.mcap\n"
        "  fw replay run.mcap --chart statecharts/seeg.yaml     the same run, today's chart",
        formatter_class=raw,
    )
    p.add_argument("file", metavar="FILE")
    p.add_argument("--chart", metavar="C", help="statechart (default: the recorded one)")
    p.set_defaults(func=cmd_replay)

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
