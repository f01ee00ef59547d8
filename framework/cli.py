"""The `fw` command: validate, draw and try statecharts (deploy comes with topologies).

Errors are printed as one line each (`file:line:col: path: message`) and
the exit code says what happened: 0 fine, 1 the input has errors, 2 bad
command line, 3 an internal error (a bug in fw: please report it).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import traceback
from collections.abc import Sequence
from importlib import metadata
from typing import Any

from framework.clock import SimulatedClock
from framework.errors import Finding, FindingsError, FwError, printable
from framework.statechart.events import Listener, Output
from framework.statechart.model import CONFIG_DONE, CONFIG_FAILED
from framework.statechart.trace import TracePrinter

COMMANDS_GROUP = "fw.commands"
"""Entry point group through which installed packages add `fw` commands (the way
ros2cli finds its verbs), so the framework never names a procedure's packages. The
extension contract: the entry point is named as the command it adds, and names a
function `add_commands(subparsers)` that adds that command's parser; its module may
say `FW_EXTENSION_API = N` (default 1), and one of another version than
`EXTENSION_API` is not loaded (a warning says so). Only the command named on the
command line is loaded (every one for `fw --help` and for an unknown command):

    [project.entry-points."fw.commands"]
    calibrate = "components.sim.calibrate:add_commands"
"""

EXTENSION_API = 1
"""The version of the extension contract above (`FW_EXTENSION_API` of a plugin)."""

SEPARATE_COMMANDS = {
    "bench": "it comes with fw-bench, the experiment harness: in an fw checkout, "
    "`pip install -e tools/bench` (or `bash tools/install.sh --test`)",
}
"""Commands of fw's own distributions that are installed apart, and how to get them."""

EPILOG_VALIDATE = """\
examples:
  fw validate statecharts/seeg.yaml
  fw validate statecharts/*.yaml --topology topologies/seeg.yaml
  fw validate topologies/seeg.yaml procedures/seeg.yaml procedures/seeg/*.yaml
  fw validate my_sensors.yaml --kind sensors
  fw validate statecharts/seeg.yaml --json | jq .

A file's kind comes from a key it has (topology:, scenario:, sensors:, ...,
statechart:) or from --kind; `fw validate --kinds` lists every kind known.
Every finding is printed as file:line:col: yaml.path: severity[code]: message (hint: ...).
Exit code 1 if any file has an error (or a warning, with --strict).
"""

EPILOG_DESCRIBE = """\
examples:
  fw describe components.robot.interface:RobotInterface
  fw describe topologies/seeg.yaml -o seeg-components.md
  fw describe topologies/*.yaml -o docs/reference.md     (the shipped reference)

Read from the classes' declarations, not from a running deployment (`fw ls` shows
that): each property's type, default, unit and range, each port's message type, and
whether each operation only reads or may change the component's state. Your own
classes are found on the Python path (run from your project's directory).
"""

EPILOG_GRAPH = """\
examples:
  fw graph statecharts/seeg.yaml -o seeg.svg
  fw graph statecharts/seeg.yaml -o seeg.mmd --active System_OK.Moving_Fast

The suffix picks the format: .svg/.png (needs Graphviz `dot`), .dot, .puml (PlantUML),
.mmd (Mermaid).
"""

EPILOG_RUN = """\
Steps the chart on a simulated clock and prints every event, transition, entry, exit and
output. Each token of --events is one of:
  NAME                 an event without payload       e_START
  NAME{json}           an event with a JSON payload   'e_TOK{"tracker": "certus"}'
  +DURATION            let simulated time pass         +2s  +500ms
Configuration requests are acknowledged at once with --auto-ack (tags listed in --fail
get config.failed instead), so a chart that sets up the system can be tried alone.

examples:
  fw run statecharts/seeg.yaml --auto-ack --events e_START,e_TOK,e_CRITICAL_AREA,e_TARGET
  fw run statecharts/seeg.yaml --auto-ack --fail setup_trackers
  fw run statecharts/seeg.yaml --auto-ack -i          (type events, '?' lists them)
  fw run statecharts/seeg.yaml --scenario counterexamples/seeg.no_motion.yaml
"""


def _print_findings(findings: list[Finding], as_json: bool, strict: bool) -> int:
    failing = {"error", "warning"} if strict else {"error"}
    if as_json:
        print(json.dumps([f.as_dict() for f in findings], indent=2))
    else:
        for finding in findings:
            print(finding.one_line())
    return 1 if any(f.severity in failing for f in findings) else 0


def cmd_validate(args: argparse.Namespace) -> int:
    """Check fw files statically (each by its kind); print every finding."""
    from framework.filekinds import detect, kinds
    from framework.statechart.files import validate_file

    known = kinds()
    if args.kinds:
        for kind in known.values():
            print(f"{kind.name:<12} {'(' + kind.key + ':)':<14} {kind.summary}")
        return 0
    if not args.files:
        raise FwError("name the file(s) to check (or --kinds to list what fw can check)")
    if args.kind is not None and args.kind not in known:
        raise FwError(f"--kind {args.kind!r}: not one of {', '.join(known)}")
    findings: list[Finding] = []
    for path in args.files:
        kind = known[args.kind] if args.kind else detect(path) or known["statechart"]
        if kind.name == "statechart":
            findings.extend(validate_file(path, args.topology))
        else:
            findings.extend(kind.check(path))
    code = _print_findings(findings, args.json, args.strict)
    if not args.json:
        errors = sum(f.severity == "error" for f in findings)
        warnings = len(findings) - errors
        verdict = "FAILED" if code else "ok"
        sys.stdout.flush()
        print(
            f"{verdict}: {len(args.files)} file(s), {errors} error(s), {warnings} warning(s)",
            file=sys.stderr,
        )
    return code


def _load(path: str) -> Any:
    from framework.statechart.loader import load_statechart

    return load_statechart(path)


def cmd_graph(args: argparse.Namespace) -> int:
    """Draw a chart to a file."""
    from framework.statechart.export import render

    chart = _load(args.file)
    active = [p for a in args.active for p in a.split(",") if p]
    resolved = []
    for name in active:
        try:
            state = chart.state(name)
        except KeyError:
            raise FwError(f"--active: unknown state {name!r}") from None
        resolved.extend(s.path for s in [state, *state.ancestors()] if s.path)
    out = render(chart, args.output, resolved)
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _parse_token(token: str) -> tuple[str, Any]:
    from framework.durations import parse_duration

    token = token.strip()
    if token.startswith("+"):
        try:
            return "advance", parse_duration(token[1:])
        except ValueError as exc:
            raise FwError(f"--events: {exc}") from None
    if "{" in token:
        name, _, rest = token.partition("{")
        try:
            payload = json.loads("{" + rest)
        except json.JSONDecodeError as exc:
            raise FwError(f"--events: bad JSON payload in {token!r}: {exc.msg}") from None
        return "event", (name.strip(), payload)
    return "event", (token, None)


def _split_tokens(text: str) -> list[str]:
    """Split on commas that are not inside a JSON payload."""
    tokens, depth, current = [], 0, ""
    for char in text:
        if char == "," and depth == 0:
            tokens.append(current)
            current = ""
            continue
        depth += char == "{"
        depth -= char == "}"
        current += char
    tokens.append(current)
    return [t for t in (t.strip() for t in tokens) if t]


def cmd_run(args: argparse.Namespace) -> int:
    """Step a chart on a simulated clock and print its trace."""
    from framework.statechart.interpreter import Interpreter

    chart = _load(args.file)
    clock = SimulatedClock()
    printer = TracePrinter(clock, args.json)
    failing = {t for f in args.fail for t in f.split(",") if t}
    interpreter: Interpreter

    def answer(output: Output) -> None:
        if output.kind == "configure" and args.auto_ack:
            if output.tag in failing:
                interpreter.queue(
                    CONFIG_FAILED, {"tag": output.tag, "reason": "injected by --fail"}
                )
            else:
                interpreter.queue(CONFIG_DONE, {"tag": output.tag})

    interpreter = Interpreter(chart, clock, [printer], on_output=answer)
    interpreter.start()

    def apply(token: str) -> None:
        kind, value = _parse_token(token)
        if kind == "advance":
            interpreter.advance(value)
        else:
            problem = chart.event_problem(*value, complete=False)  # stepping by hand
            if problem:
                raise FwError(problem)
            interpreter.queue(*value)
            interpreter.run()

    if args.scenario:
        return _replay(args.scenario, chart, interpreter, clock, args.json)
    for token in _split_tokens(args.events or ""):
        apply(token)
    if args.interactive:
        _interactive(interpreter, apply)
    if not args.json:
        print(
            f"active: {', '.join(interpreter.leaves) or '(none)'}"
            + ("  [finished]" if interpreter.finished else "")
        )
    return 0


def _replay(path: str, chart: Any, interpreter: Any, clock: SimulatedClock, as_json: bool) -> int:
    """Play a scenario's `send` steps at their times on the simulated clock (the chart
    alone: its `config.done`/`config.failed` steps are the Configurator's answers),
    then judge its expectations; 1 if one fails. A counterexample `fw verify` wrote
    is such a scenario."""
    from framework.errors import LocatedError
    from framework.scenario import load_scenario

    class Seen(Listener):
        def __init__(self) -> None:
            self.states: set[str] = set()
            self.events: set[str] = set()

        def on_entry(self, state: Any) -> None:
            self.states.add(state.path)

        def on_event(self, event: Any) -> None:
            self.events.add(event.name)

    scenario = load_scenario(path, events=chart.event_names(), states=set(chart.states))
    for step in scenario.steps:
        if not step.send or step.at is None or step.when or scenario.start:
            raise LocatedError(
                "fw run replays only `send` steps at given times (`at:`); "
                "`when`, `call`, `check`, `fault` and `start` need a deployment",
                step.location,
                f"fw deploy TOPOLOGY --scenario {path}",
            )
    seen = Seen()
    for state in interpreter.configuration:
        seen.states.add(state)
    interpreter.listeners.insert(0, seen)
    for step in scenario.steps:
        interpreter.advance_to(max(clock.now(), step.at + step.after))
        interpreter.queue(step.send, step.payload or None)
        interpreter.run()
    interpreter.advance_to(max(clock.now(), scenario.timeout))
    failed = 0
    for e in scenario.expect:
        names = [chart.state(n).path if e.kind.endswith("state") else n for n in e.names]
        pool = seen.states if e.kind.endswith("state") else seen.events
        hit = any(n in pool for n in names)
        ok = not hit if e.kind.startswith("never") else hit
        failed += not ok
        if not as_json:
            print(f"{'PASS' if ok else 'FAIL'}  {e.describe()}")
    if not as_json:
        print(f"active: {', '.join(interpreter.leaves) or '(none)'}")
    return 1 if failed else 0


def _interactive(interpreter: Any, apply: Any) -> None:
    print(
        "type events (NAME, NAME{json}, +2s), '?' for what the chart takes now, 'q' to quit",
        file=sys.stderr,
    )
    for line in sys.stdin:
        line = line.strip()
        if line in ("q", "quit", "exit"):
            break
        if line == "?":
            taken = sorted(
                {
                    e
                    for path in interpreter.configuration
                    for t in interpreter.chart.states[path].transitions
                    for e in t.events
                }
            )
            print("active:", ", ".join(interpreter.leaves), "| events:", ", ".join(taken))
            continue
        try:
            for token in _split_tokens(line):
                apply(token)
        except FwError as exc:
            print(printable(f"fw: {exc}"), file=sys.stderr)


def cmd_new(args: argparse.Namespace) -> int:
    """Make a new procedure from the template (`framework/scaffold.py`)."""
    from pathlib import Path

    from framework.scaffold import new_procedure

    for path in new_procedure(args.name, Path(args.dir), args.port):
        print(f"wrote {path}")
    folder = Path(args.dir) / args.name
    print(
        f"next: fw validate {folder / (args.name + '.yaml')} && python -m pytest {folder}\n"
        f"      fw deploy {folder / (args.name + '.yaml')}",
        file=sys.stderr,
    )
    return 0


def cmd_describe(args: argparse.Namespace) -> int:
    """Print (or write) the reference of component classes, named or used by topologies."""
    from pathlib import Path

    from framework.classes import load_class
    from framework.reference import reference
    from framework.topology import load_topology

    classes = []
    for target in args.targets:
        if target.endswith((".yaml", ".yml")):
            topology = load_topology(target)
            paths = [spec.class_path for spec in topology.components.values()]
        else:
            paths = [target]
        classes += [load_class(path) for path in paths]
    text = reference(classes, command="fw describe " + " ".join(args.targets))
    if args.output:
        Path(args.output).write_text(text, encoding="utf-8")
    else:
        print(text, end="")
    return 0


def installed_version() -> str:
    """fw's version as installed (pyproject.toml's), or a clear stand-in when fw runs
    from a checkout that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fw")
    except PackageNotFoundError:
        return "(not installed: run from a checkout)"


def _wanted(argv: Sequence[str] | None) -> str | None:
    """The command named on the command line (its first word that is no option), or
    None (`fw --help`, no command)."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    return words[0] if words else None


def _load_extension(entry: Any, sub: Any) -> None:
    """Add one installed command (`COMMANDS_GROUP`'s contract), or warn why not: a
    broken or incompatible plugin must not take `fw` down with it."""
    try:
        add = entry.load()
        module = sys.modules.get(getattr(add, "__module__", ""), None)
        api = getattr(module, "FW_EXTENSION_API", 1)
        if api != EXTENSION_API:
            raise FwError(f"it is written for extension API {api}, fw has {EXTENSION_API}")
        add(sub)
    except Exception as exc:  # any plugin failure: said as a warning, fw goes on
        print(
            f"fw: warning: commands of {entry.name!r} ({entry.value}) not loaded: "
            f"{type(exc).__name__}: {exc}",
            file=sys.stderr,
        )


def build_parser(argv: Sequence[str] | None = ()) -> argparse.ArgumentParser:
    """The argument parser of `fw` (also used to render --help in the docs). Of the
    installed commands, only the one `argv` names is loaded; every one when it names
    none or an unknown one (the default: every one)."""
    parser = argparse.ArgumentParser(
        prog="fw",
        description="fw supervises a semi-autonomous surgical robot: procedures are YAML "
        "statecharts, deployments are YAML topologies.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Run 'fw COMMAND --help' for examples. Docs: docs/statecharts.md",
    )
    parser.add_argument(
        "--version", action="version", version=f"fw {installed_version()}", help="fw's version"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    raw = argparse.RawDescriptionHelpFormatter

    p = sub.add_parser(
        "validate",
        help="check statecharts, topologies, procedure and scenario files (exit 1 on errors)",
        epilog=EPILOG_VALIDATE,
        formatter_class=raw,
    )
    p.add_argument(
        "files",
        nargs="*",
        metavar="FILE",
        help="fw YAML file(s) of any kind (a topology is checked with its "
        "statechart and every cross-reference)",
    )
    p.add_argument("--kind", metavar="K", help="check every FILE as this kind (see --kinds)")
    p.add_argument("--kinds", action="store_true", help="list the kinds of file fw can check")
    p.add_argument(
        "--topology",
        metavar="T",
        help="topology YAML whose `configurations:` must define every requested tag",
    )
    p.add_argument("--json", action="store_true", help="print findings as a JSON list")
    p.add_argument("--strict", action="store_true", help="fail on warnings too")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser(
        "graph",
        help="draw a statechart (svg, png, dot, puml, mmd)",
        epilog=EPILOG_GRAPH,
        formatter_class=raw,
    )
    p.add_argument("file", metavar="FILE")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT",
        help="output file; its suffix picks the format",
    )
    p.add_argument(
        "--active",
        action="append",
        default=[],
        metavar="STATE[,STATE]",
        help="highlight these states (and their parents)",
    )
    p.set_defaults(func=cmd_graph)

    p = sub.add_parser(
        "run",
        help="step a statechart on a simulated clock and print the trace",
        epilog=EPILOG_RUN,
        formatter_class=raw,
    )
    p.add_argument("file", metavar="FILE")
    p.add_argument(
        "--events",
        "-e",
        default="",
        metavar="LIST",
        help="comma-separated events and time steps (see below)",
    )
    p.add_argument("--interactive", "-i", action="store_true", help="then read events from stdin")
    p.add_argument(
        "--scenario",
        metavar="FILE",
        help="replay a scenario's timed `send` steps (e.g. a counterexample of fw verify) "
        "and judge its expectations",
    )
    p.add_argument(
        "--auto-ack", action="store_true", help="acknowledge every configuration request at once"
    )
    p.add_argument(
        "--fail",
        action="append",
        default=[],
        metavar="TAG[,TAG]",
        help="with --auto-ack: answer these tags with config.failed",
    )
    p.add_argument("--json", action="store_true", help="one JSON object per trace line")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser(
        "describe",
        help="the ports, properties and operations of component classes (Markdown)",
        epilog=EPILOG_DESCRIBE,
        formatter_class=raw,
    )
    p.add_argument(
        "targets",
        nargs="+",
        metavar="CLASS|TOPOLOGY",
        help="package.module:Class, or a topology YAML (every class it uses)",
    )
    p.add_argument("-o", "--output", metavar="OUT", help="write to this file (default: stdout)")
    p.set_defaults(func=cmd_describe)

    p = sub.add_parser(
        "new",
        help="start a new procedure from a template (components, topology, chart, specs)",
        description="Write a whole small procedure into DIR/NAME: two components of your "
        "own (NAME_components.py), a topology in two processes (NAME.yaml), a chart that "
        "rewires the reader live on e_SWAP (NAME_chart.yaml) and its specs (test_NAME.py). "
        "Nothing existing is overwritten. docs/tutorial.md walks through it.",
        epilog="examples:\n  fw new procedure hello\n"
        "  fw new procedure pick_place --dir ~/work --port 7600\n"
        "then:\n  fw validate hello/hello.yaml && python -m pytest hello\n"
        "  fw deploy hello/hello.yaml",
        formatter_class=raw,
    )
    p.add_argument("kind", choices=["procedure"], help="what to make")
    p.add_argument("name", metavar="NAME", help="a Python module name, e.g. hello")
    p.add_argument("--dir", default=".", metavar="DIR", help="where to make it (default: .)")
    p.add_argument(
        "--port", type=int, metavar="N", help="its bus port (default: from its name, 7470-7969)"
    )
    p.set_defaults(func=cmd_new)

    from framework import cli_deploy, cli_records, cli_ros2, cli_session, cli_verify

    for module in (cli_deploy, cli_session, cli_records, cli_verify, cli_ros2):
        module.add_commands(sub)
    wanted = _wanted(argv)
    if wanted in sub.choices:
        return parser  # a command of fw's own: no plugin needed
    entries = sorted(metadata.entry_points(group=COMMANDS_GROUP), key=lambda e: e.name)
    named = [e for e in entries if e.name == wanted]
    for entry in named or entries:
        _load_extension(entry, sub)
    if wanted in SEPARATE_COMMANDS and wanted not in sub.choices:
        parser.exit(2, f"fw: {wanted!r} is not installed: {SEPARATE_COMMANDS[wanted]}\n")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `fw` console script."""
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except FindingsError as exc:
        for finding in exc.findings:
            print(finding.one_line(), file=sys.stderr)
        return 1
    except FwError as exc:
        print(printable(f"fw: {exc}"), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    except Exception as exc:  # a bug in fw: one line unless asked for the traceback
        if os.environ.get("FW_DEBUG"):
            traceback.print_exc()
        print(
            f"fw: internal error: {type(exc).__name__}: {printable(str(exc))} "
            "(set FW_DEBUG=1 for a traceback and please report it)",
            file=sys.stderr,
        )
        return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
