"""`fw deploy`: check and run a topology, with its live screen or one line per
chart step, its operator console and its scenario's verdicts."""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import signal
import socket
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from framework.errors import FwError
from framework.statechart.events import Event, Listener
from framework.statechart.model import State, Transition

EPILOG_DEPLOY = """\
Checks the topology, its statechart and every cross-reference first (nothing starts if
anything is wrong), starts the topology's processes, waits until every component is
alive, then runs the statechart. Ctrl-C shuts down in order, the robot side first, and
so do SIGTERM (a service manager's stop) and SIGHUP (its terminal closed).

examples:
  fw deploy topologies/demo.yaml                    live status until Ctrl-C
  fw deploy topologies/demo.yaml --headless --duration 10
  fw deploy topologies/demo.yaml --record run.mcap  keep a flight recording
  fw deploy topologies/seeg.yaml --foxglove         watch it live in Foxglove (ws://127.0.0.1:8765)
  fw deploy topologies/seeg.yaml --console-port 8080   the operator console on another port
  fw deploy topologies/seeg.yaml --console-host 0.0.0.0 --console-cert or3.pem --console-key or3.key
                                                    the console for the OR's network (HTTPS)

The operator console (a web page: status, START / RELEASE / Go To, the chart, the
event log) is served on http://127.0.0.1:8470/?token=... unless --headless (scripts,
tests) or --no-console; also without a terminal (a service, nohup: the link goes to the
log and to console.url in the work folder, readable by its owner only). On 8470 taken,
the deployment runs on without it and says so; --console-port N serves it on N (0: any
free port) and a taken N is an error. It listens on
127.0.0.1 only, unless --console-host says otherwise; beyond this machine it is served
over TLS only: with --console-cert/--console-key if given, else with a certificate made
for the run, whose SHA-256 fingerprint is printed (compare it with the browser's).
"""


STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
"""What stops a running deployment in order: Ctrl-C, a service manager's stop, the
terminal closing. The default action of the last two would kill fw before it stops
the robot side and closes the flight recording."""


def stop_on_signals() -> None:
    """Turn each of `STOP_SIGNALS` into KeyboardInterrupt, once: the first starts the
    shutdown, later ones, and any once a shutdown has begun by itself (a run's
    `--duration` or scenario over), are ignored so that nothing cuts it short. SIGINT
    counts even when fw was started with it ignored (a shell's background job): a
    Ctrl-C or `kill -INT` sent to fw itself means stop. They stay ignored until fw
    exits: a signal after the shutdown would otherwise kill fw while it prints the
    scenario's report, and give a clean stop the exit status of a killed process."""

    def stop(signum: int, frame: Any) -> None:
        ignore_stop_signals()
        raise KeyboardInterrupt

    for name in STOP_SIGNALS:
        signal.signal(getattr(signal, name), stop)


def ignore_stop_signals() -> None:
    """From here on, `STOP_SIGNALS` change nothing: the shutdown has begun (a signal's
    KeyboardInterrupt raised inside it left the control's threads running and fw
    waiting for them forever, the robot side's processes never stopped)."""
    for name in STOP_SIGNALS:
        signal.signal(getattr(signal, name), signal.SIG_IGN)


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


SLOW_SCREENS = 2
"""Screens in a row a live process may leave a state query unanswered before the live
screen says NOT RESPONDING (one miss is a busy moment, such as its first second)."""


def live_screen(
    deployment: Any,
    started: float,
    console: str = "",
    seen: dict[str, tuple[str, int]] | None = None,
) -> str:
    """The one-screen live status. `seen` (kept by the caller between screens): each
    component's last answered state and the screens it has not answered since."""

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
    safety = deployment.topology.safety
    if safety is not None:
        lines.append(f"robot      {_robot_side(deployment.hub, safety.monitor)}")
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
            state = _answered(deployment.hub, spec.name, {} if seen is None else seen)
            if state == "Running" and _device_loop(spec) and seen is not None:
                state += f"   loop: {_scheduling(deployment.hub, spec.name, seen)}"
        lines.append(f"{spec.name:<20} {spec.process:<16} {state}")
    if watch is not None and watch.incidents:
        lines += ["", *watch.incidents[-5:]]
    return "\n".join(lines)


def _robot_side(hub: Any, monitor: str) -> str:
    """The robot side in the console's words (`robot_line`): released, braked and why,
    or a latched safety stop with its reason and whether RELEASE would be taken now."""
    from framework.console.text import robot_line
    from framework.remote import RemoteComponent, RemoteError

    try:
        report = RemoteComponent(hub, monitor, 0.3).call("report")
    except RemoteError:
        return f"({monitor} does not answer)"
    return robot_line(report if isinstance(report, dict) else {})


def _device_loop(spec: Any) -> bool:
    """Whether the component runs a device's loop (paced, or a device's own clock)."""
    return spec.activity.kind == "paced" or bool(
        getattr(spec.info.cls if spec.info else None, "realtime", False)
    )


def _scheduling(hub: Any, name: str, seen: dict[str, tuple[str, int]]) -> str:
    """What a device loop got from the host (SCHED_FIFO 80, or why not), asked once."""
    from framework.remote import RemoteComponent, RemoteError

    key = f"{name}#scheduling"
    if key in seen:
        return seen[key][0]
    try:
        loop = RemoteComponent(hub, name, 0.5).call("report").get("loop") or {}
    except RemoteError:
        return "?"
    got = str(loop.get("scheduling") or "?")
    if got != "?":
        seen[key] = (got, 0)
    return got


def _answered(hub: Any, name: str, seen: dict[str, tuple[str, int]]) -> str:
    """A live component's state, or what the screen says while it does not answer."""
    from framework.remote import RemoteComponent, RemoteError

    last, misses = seen.get(name, ("", 0))
    try:
        state = RemoteComponent(hub, name, 0.3).state()
    except RemoteError:
        misses += 1
        seen[name] = (last, misses)
        if misses >= SLOW_SCREENS:
            return "NOT RESPONDING"
        return f"{last} (slow to answer)" if last else "(no answer yet)"
    seen[name] = (state, 0)
    return state


def cmd_deploy(args: argparse.Namespace) -> int:
    """Run a topology (see EPILOG_DEPLOY)."""
    from framework.console import tls
    from framework.deployer import Deployment
    from framework.filekinds import check_file
    from framework.topology import load_topology

    topology = load_topology(args.topology, files=check_file)
    for item in args.record_samples:
        key, _, kind = item.partition("=")
        if not key or not kind:
            raise FwError(f"--record-samples takes KEY=TYPE, not {item!r}")
        from framework.messages import resolve_type

        resolve_type(kind)
    interactive = sys.stdout.isatty() and not args.headless
    # served unless --headless (scripts, tests) or --no-console: a deployment started
    # without a terminal (a service, nohup) is exactly one whose operator needs the page
    serve_console = not args.no_console and (args.console_port is not None or not args.headless)
    console_tls = _console_tls(args) if serve_console else (None, "")  # before anything starts
    token = secrets.token_urlsafe(18)  # the run's login: the console's and the live view's
    gate_tls = (None, "")
    if args.foxglove is not None and not tls.is_loopback(args.foxglove_host):
        gate_tls = _tls_for(args, args.foxglove_host, "the live view")
    workdir = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="fw-"))
    listeners: list[Listener] = [] if interactive else [_Printer()]
    recorder = None
    live = None
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
        hosts = {*topology.hosts, "control"}
        scenario = load_scenario(args.scenario, events, operations, states, processes, hosts)
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
        liveliness_timeout=args.start_timeout,
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
    stop_on_signals()
    try:
        deployment.start(run_chart=False)
        if args.foxglove is not None:
            from framework.live_view import LiveView

            if gate_tls[0] is None:
                live = LiveView(args.foxglove)
                where = f"ws://127.0.0.1:{live.port}"
            else:  # beyond loopback: behind TLS and the run's token (framework/live_gate.py)
                from framework.live_gate import LiveGate

                live = LiveView(0)
                live.gate = LiveGate(
                    args.foxglove_host, args.foxglove, live.port, token, gate_tls[0]
                )
                host = (
                    socket.gethostname()
                    if tls.is_wildcard(args.foxglove_host)
                    else args.foxglove_host
                )
                where = f"wss://{host}:{live.gate.port}/?token={token}"
                if gate_tls[1]:
                    print(f"fw: {gate_tls[1]}", file=sys.stderr)
            print(
                f"fw: Foxglove live view on {where} (Foxglove: Open connection, Foxglove "
                "WebSocket)",
                file=sys.stderr,
            )
        if args.record or live is not None:
            from framework.recorder import FlightRecorder

            # the topology's `record:` outputs, and any --record-samples on top
            recorder = FlightRecorder.of_topology(
                args.record,
                deployment.hub,
                deployment.topology,
                dict(item.split("=", 1) for item in args.record_samples),
                live=live,
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
            console = _start_console(args, deployment, topology, console_tls, workdir, token)
        end = started + args.duration if args.duration else None
        runner = deployment.runner
        seen: dict[str, tuple[str, int]] = {}
        while end is None or time.monotonic() < end:
            if runner is not None and runner.finished.is_set():
                time.sleep(0.5)  # let the last reactions land in the recording
                break
            if interactive:
                sys.stdout.write(
                    "\x1b[H\x1b[2J"
                    + live_screen(deployment, started, console.url if console else "", seen)
                    + "\n"
                )
                sys.stdout.flush()
            time.sleep(0.5 if end is None else min(0.5, max(0.0, end - time.monotonic())))
        print("fw: the run is over: shutting down (robot side first)...", file=sys.stderr)
    except KeyboardInterrupt:
        print("\nfw: shutting down (robot side first)...", file=sys.stderr)
    finally:
        ignore_stop_signals()  # a signal now would cut the shutdown short
        if console is not None:
            console.stop()
            console.model.stop()
        deployment.stop()
        if recorder is not None:
            recorder.close()
            if args.record:
                print(f"fw: flight recording in {args.record}", file=sys.stderr)
        if live is not None:
            live.close()
        if not args.workdir and not args.keep_logs:
            shutil.rmtree(workdir, ignore_errors=True)
    print("fw: stopped", file=sys.stderr)
    if deployment.runner is not None:
        return scenario_report(deployment.runner)
    return 0


def _start_console(
    args: argparse.Namespace,
    deployment: Any,
    topology: Any,
    console_tls: tuple[Any, str],
    workdir: Path,
    token: str,
) -> Any:
    """Serve the operator console (over TLS if `console_tls` has a context); its link
    goes to stderr (a service's log) and to `console.url` in the work folder, readable
    by its owner only (the link carries the run's login). On the default port, taken,
    the deployment goes on without it and says why (None)."""
    from framework.console.model import ConsoleModel
    from framework.console.server import DEFAULT_PORT, ConsoleServer

    tls, certificate = console_tls
    chart = deployment.coordinator.chart if deployment.coordinator is not None else None
    model = ConsoleModel(deployment.hub, topology, chart).start()
    port = DEFAULT_PORT if args.console_port is None else args.console_port
    server = ConsoleServer(model, args.console_host, port, tls=tls, token=token)
    try:
        url = server.start()
    except FwError as exc:
        model.stop()
        if args.console_port is not None:
            raise
        print(
            f"fw: no operator console: {exc}; the deployment runs on without it",
            file=sys.stderr,
        )
        return None
    saved = workdir / "console.url"
    with os.fdopen(os.open(saved, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "w") as out:
        out.write(url + "\n")
    print(
        f"fw: operator console on {url} (the link carries this run's login; also in "
        f"{saved}, readable by you only)",
        file=sys.stderr,
    )
    if certificate:
        print(f"fw: {certificate}", file=sys.stderr)
    return server


def _console_tls(args: argparse.Namespace) -> tuple[Any, str]:
    """The console's TLS context (None on loopback without a certificate) and what to
    tell the operator about its certificate. Beyond loopback there is no plain HTTP."""
    return _tls_for(args, args.console_host, "the console")


def _tls_for(args: argparse.Namespace, host: str, what: str) -> tuple[Any, str]:
    """The TLS context of a server of this run on `host` (the console, the live view's
    gate): --console-cert's, else none on loopback, else a certificate made for the run
    (its fingerprint in what to tell the operator)."""
    from framework.console import tls

    if bool(args.console_cert) != bool(args.console_key):
        raise FwError("--console-cert and --console-key go together (a certificate and its key)")
    if args.console_cert:
        cert = Path(args.console_cert)
        context = tls.server_context(cert, Path(args.console_key))
        return context, f"console certificate {cert} (SHA-256 {tls.fingerprint(cert)})"
    if tls.is_loopback(host):
        return None, ""
    made = Path(tempfile.mkdtemp(prefix="fw-console-"))
    try:
        cert, key = tls.self_signed(tls.names_for(host), made)
        context = tls.server_context(cert, key)
        digest = tls.fingerprint(cert)
    finally:
        shutil.rmtree(made, ignore_errors=True)  # the key lives on in memory only
    return context, (
        f"{what}'s certificate was made for this run (no --console-cert): the browser "
        f"will warn; accept it only if it shows SHA-256 {digest}"
    )


def scenario_report(runner: Any) -> int:
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
        f"{unrun} not run (nothing to check: see each)"
    )
    return 1 if failed else 0


def _positive_seconds(text: str) -> float:
    """An argparse type: seconds > 0 (argparse turns the ValueError into a usage error)."""
    value = float(text)
    if not value > 0.0 or value == float("inf"):  # NaN and inf too
        raise ValueError(text)
    return value


_positive_seconds.__name__ = "seconds > 0"  # what argparse's error names


def add_commands(sub: Any) -> None:
    """Register `fw deploy` on the `fw` parser."""
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
        "--foxglove",
        nargs="?",
        type=int,
        const=8765,
        metavar="PORT",
        help="serve Foxglove's live view on PORT (default 8765) of --foxglove-host",
    )
    p.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="where the live view listens (default 127.0.0.1: ws://, this machine only); "
        "beyond it, wss:// with --console-cert's certificate (else one made for the run) "
        "and only for URLs with this run's token, the console's",
    )
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
        "--start-timeout",
        type=_positive_seconds,
        default=30.0,
        metavar="S",
        help="how long to wait for every component to come up, other hosts' included, "
        "before giving up and naming who did not (default 30)",
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
