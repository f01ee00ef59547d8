"""Reading a topology file and checking everything that can be checked before
anything starts, each finding located like a statechart's (file:line:col, YAML path,
hint): the schema; that every class imports and is a Component; every port, property
and operation named anywhere exists, with compatible message types and valid values;
the statechart, and that every tag it can request is defined; and that every event
the chart consumes has a producer.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from framework import keys, schema
from framework.activity import Activity, ActivityError
from framework.bus import BusConfig
from framework.classes import ClassPathError, add_import_paths, load_class, load_function
from framework.durations import parse_duration
from framework.errors import (
    Finding,
    FindingsError,
    FwError,
    LocatedError,
    Location,
    MissingFileError,
)
from framework.ports import ConnPolicy, PortError
from framework.properties import PropertyError, load_property_file
from framework.ros2 import section as ros2_section
from framework.safety import DEFAULT_PROCESS_DEADLINE, SafetySpec, Watch
from framework.topology.console import parse_console
from framework.topology.model import (
    CONTROL_PROCESS,
    CONTROL_SLACK,
    DEFAULT_STEP_TIMEOUT,
    RESERVED_PROCESSES,
    ClassInfo,
    ComponentSpec,
    Configuration,
    Recorded,
    Step,
    StepKind,
    Topology,
    class_info,
    declares_file_inputs,
)
from framework.yamlio import Document, extend, load_yaml

FileCheck = Callable[[str, str], list[Finding] | None]
"""Checks a file of a kind (`framework.filekinds.check_file`): its findings, or None
when no installed package reads that kind."""


class _Loader:
    def __init__(self, doc: Document, classes: bool = True, files: FileCheck | None = None):
        self.doc = doc
        self.files = files
        self.base = Path(doc.file).parent
        self.findings: list[Finding] = []
        self.classes = classes
        self.checked_files: dict[str, list[Finding]] = {}  # "kind:path" -> its findings
        self.bad_files: set[str] = set()  # components a named file of which has errors
        self.unread_inputs: set[str] = set()  # components whose file inputs are unknown

    def here(self, *path: str | int) -> Path:
        """The folder of the file the value at `path` was written in (paths a topology
        gives are relative to it, also where it extends another topology)."""
        return Path(self.doc.origin(path)).parent

    def error(self, code: str, message: str, path: tuple[Any, ...], hint: str = "") -> None:
        self.findings.append(Finding("error", code, message, self.doc.location(path), hint))

    def close(self, name: str, options: Any) -> str:
        match = difflib.get_close_matches(name, list(options), n=1)
        return f"did you mean {match[0]!r}?" if match else f"known: {', '.join(sorted(options))}"

    def import_class(self, path: str, where: tuple[Any, ...]) -> ClassInfo | None:
        try:
            return class_info(load_class(path))
        except ClassPathError as exc:
            self.error("class", str(exc), where, "check the module path and class name")
        except Exception as exc:  # the user's module failed while importing
            self.error("class", f"importing {path!r} failed: {type(exc).__name__}: {exc}", where)
        return None

    def components(self, data: dict[str, Any]) -> dict[str, ComponentSpec]:
        processes = data.get("processes") or {}
        out = {}
        for name, spec in data["components"].items():
            here = ("components", name)
            process = spec.get("process", "main")
            if process in RESERVED_PROCESSES:
                self.error(
                    "process",
                    f"process name {process!r} is reserved (fw deploy's own process and "
                    "its clients use it)",
                    (*here, "process"),
                )
            elif processes and process not in processes and process != "main":
                self.error(
                    "process",
                    f"component {name!r} names unknown process {process!r}",
                    (*here, "process"),
                    self.close(process, processes),
                )
            info = self.import_class(spec["class"], (*here, "class")) if self.classes else None
            try:
                activity = Activity.from_spec(spec.get("activity"))
                declares_own = info is not None and declares_file_inputs(info.cls)
                if info is not None and not declares_own:  # else: once its files are read
                    for port in activity.ports:
                        if port not in info.inputs:
                            raise ActivityError(
                                f"event activity names unknown input port {port!r} of {name!r}"
                            )
            except ActivityError as exc:
                self.error("activity", str(exc), (*here, "activity"))
                activity = Activity()
            if activity.kind == "after":
                master = data["components"].get(activity.master)
                if not isinstance(master, dict):
                    self.error(
                        "activity",
                        f"{name!r} runs after {activity.master!r}, which is not a component",
                        (*here, "activity"),
                    )
                elif master.get("process", "main") != process:
                    self.error(
                        "activity",
                        f"{name!r} runs after {activity.master!r} in its thread, so both must "
                        f"be in one process ({process!r} vs {master.get('process', 'main')!r})",
                        (*here, "activity"),
                    )
                elif loop := _after_loop(name, data["components"]):
                    self.error(
                        "activity",
                        f"{name!r} runs after itself: {' -> '.join(loop)}",
                        (*here, "activity"),
                    )
            values = dict(spec.get("properties") or {})
            if info is not None:
                if "property_file" in spec:
                    try:
                        values = {
                            **load_property_file(
                                self.here(*here, "property_file") / spec["property_file"],
                                info.properties,
                                name,
                            ),
                            **values,
                        }
                    except FindingsError as exc:
                        self.findings.extend(exc.findings)
                    except FwError as exc:
                        self.error("property-file", str(exc), (*here, "property_file"))
                for prop, value in list(values.items()):
                    declared = info.properties.get(prop)
                    if declared is None:
                        self.error(
                            "unknown-property",
                            f"{name!r} has no property {prop!r}",
                            (*here, "properties", prop),
                            self.close(prop, info.properties),
                        )
                        continue
                    try:
                        values[prop] = declared.validate(value, name)
                    except PropertyError as exc:
                        self.error("property-value", str(exc), (*here, "properties", prop))
                for prop, declared in info.properties.items():
                    if declared.missing(values.get(prop, declared.default)):
                        self.error(
                            "missing-property",
                            f"{name!r} needs property {prop!r} ({declared.doc or 'no doc'})",
                            here,
                        )
                self.named_files(name, info, values, here)
                for port in spec.get("outputs") or {}:
                    if port not in info.outputs:
                        self.error(
                            "unknown-port",
                            f"{name!r} has no output port {port!r}",
                            (*here, "outputs", port),
                            self.close(port, info.outputs),
                        )
            out[name] = ComponentSpec(
                name,
                spec["class"],
                process,
                activity,
                values,
                dict(spec.get("outputs") or {}),
                spec.get("initial", "preoperational"),
                self.doc.location(here),
                info,
            )
        return out

    def named_files(
        self, name: str, info: ClassInfo, values: dict[str, Any], here: tuple[Any, ...]
    ) -> None:
        """Check every file a component's properties name (`prop(..., file=kind)`) with
        its kind's own check, as `fw validate FILE` would: a procedure or tools file
        that is wrong fails here, not when the deployed component configures. Paths are
        relative to where `fw deploy` runs, as the components read them; a file missing
        from here is a warning (the deployment may run elsewhere)."""
        if self.files is None:
            return
        for prop, declared in info.properties.items():
            value = values.get(prop, declared.default)
            if not declared.file or not isinstance(value, str) or not value:
                continue
            where = self.doc.location((*here, "properties", prop))
            path = Path(value)
            if not path.exists() and not path.is_symlink():
                self.findings.append(
                    Finding(
                        "warning",
                        "named-file",
                        f"{name}.{prop}: {value!r} is not found from {Path.cwd()}",
                        where,
                        "run fw validate from the folder fw deploy runs in",
                    )
                )
                continue
            key = f"{declared.file}:{os.path.realpath(path)}"
            first = key not in self.checked_files
            if first:
                self.checked_files[key] = self.files(declared.file, value) or []
            found = self.checked_files[key]
            # a file that cannot be read at all has no line: said where it is named (each
            # time); what is wrong inside it, once, where it is
            self.findings.extend(
                Finding(f.severity, f.code, f"{name}.{prop}: {f.message}", where, f.hint)
                for f in found
                if f.location.line == 0
            )
            if first:
                self.findings.extend(f for f in found if f.location.line != 0)
            if any(f.severity == "error" for f in found):
                self.bad_files.add(name)

    def file_inputs(self, topo: Topology) -> None:
        """The input ports components declare from their own files (a tracker per sensor
        of sensors.yaml, a camera per camera of cameras.yaml): ports like the class's own,
        wired by `connections:` (checked by `file_links` once those are read)."""
        for spec in topo.components.values():
            if spec.info is None or not declares_file_inputs(spec.info.cls):
                continue
            self.unread_inputs.add(spec.name)  # until its files are read
            if spec.name in self.bad_files:  # their errors are reported already
                continue
            where = ("components", spec.name, "properties")
            try:
                wanted = spec.info.cls.file_inputs(spec.properties)
            except MissingFileError as exc:
                self.findings.append(
                    Finding(
                        "warning",
                        "file-links",
                        f"cannot check the inputs {spec.name!r} declares in "
                        f"{exc.location.file!r}: not found from {Path.cwd()}",
                        self.doc.location(where),
                        "run fw validate from the folder fw deploy runs in",
                    )
                )
                continue
            except FwError as exc:
                self.error("file-links", f"{spec.name}: {exc}", where)
                continue
            self.unread_inputs.discard(spec.name)
            for link in wanted:
                if link.port in spec.info.inputs or link.port in spec.info.outputs:
                    self.error(
                        "file-links",
                        f"{spec.name}.{link.port} ({link.source}) has the name of a port "
                        f"{spec.info.cls.__name__} declares itself",
                        where,
                    )
                    continue
                spec.file_inputs[link.port] = link
                topo.file_links.append((spec.name, link))
        for spec in topo.components.values():
            if spec.info is None or not declares_file_inputs(spec.info.cls):
                continue
            for port in spec.activity.ports:
                if port not in spec.info.inputs and port not in spec.file_inputs:
                    known = sorted([*spec.info.inputs, *spec.file_inputs])
                    self.error(
                        "activity",
                        f"event activity names unknown input port {port!r} of {spec.name!r} "
                        f"(inputs: {', '.join(known) or 'none'})",
                        ("components", spec.name, "activity"),
                    )

    def file_links(self, topo: Topology, data: dict[str, Any]) -> None:
        """Every input a component's file declares is connected by `connections:`, or its
        data never comes (a sensor added to sensors.yaml, not to the topology)."""
        wired = {(step.component, step.target): step for step in topo.connections}
        written = {
            str(entry.get("port"))
            for entry in data.get("connections") or []
            if isinstance(entry, dict)
        }
        for name, link in topo.file_links:
            step = wired.get((name, link.port))
            if step is None and f"{name}.{link.port}" in written:
                continue  # wired, but its source could not be checked: said where it failed
            if step is not None:
                writers = [writer for writer, _ in topo.writers_of(step.key)]
                if link.suggest and writers and link.suggest not in writers:
                    self.findings.append(
                        Finding(
                            "warning",
                            "file-links",
                            f"{name}.{link.port} ({link.source}) reads {', '.join(writers)}, "
                            f"not {link.suggest}: is the file's entry another device?",
                            step.location,
                            f"connect it from {link.suggest}, or name the entry as its component",
                        )
                    )
                continue
            known = [writer for writer, _, kind in topo.published() if kind == link.type_name]
            suggest = link.suggest
            if suggest not in known:
                match = difflib.get_close_matches(suggest or link.port, known, n=1, cutoff=0.0)
                suggest = match[0] if match else ""
            hint = (
                f"add to connections: {{port: {name}.{link.port}, from: {suggest}}}"
                if suggest
                else f"no output of the topology publishes {link.type_name}"
            )
            self.error(
                "file-links",
                f"{name}.{link.port} ({link.type_name}, declared by {link.source}) is not "
                "connected: its data never comes",
                ("connections",) if "connections" in data else ("components", name),
                hint,
            )

    def port(
        self, topo: Topology, ref: str, where: tuple[Any, ...], direction: str = ""
    ) -> tuple[ComponentSpec | None, str, str]:
        """(component, port, type name) of `comp.port`, with a finding if it is unknown."""
        comp_name, port = ref.split(".", 1)
        comp = topo.components.get(comp_name)
        if comp is None:
            self.error(
                "unknown-component",
                f"unknown component {comp_name!r}",
                where,
                self.close(comp_name, topo.components),
            )
            return None, port, ""
        if comp.info is None:
            return None, port, ""
        inputs = {**comp.info.inputs, **{p: f.type_name for p, f in comp.file_inputs.items()}}
        table = {"in": inputs, "out": comp.info.outputs}.get(direction)
        ports = table if table is not None else {**inputs, **comp.info.outputs}
        if port not in ports:
            if direction != "out" and comp_name in self.unread_inputs:
                return None, port, ""  # its files could not be read: said where they are named
            what = {"in": "input port", "out": "output port"}.get(direction, "port")
            self.error(
                "unknown-port",
                f"{comp_name!r} has no {what} {port!r}",
                where,
                self.close(port, ports),
            )
            return None, port, ""
        return comp, port, ports[port]

    def recorded(self, topo: Topology, spec: dict[str, Any], where: tuple[Any, ...]) -> None:
        """One `record:` entry: the output's key (thinned to its rate, as a connection's
        `rate:` thins it: samples not recorded are never sent) and its message type."""
        src, src_port, src_kind = self.port(topo, spec["from"], (*where, "from"), "out")
        if src is None:
            return
        key = src.output_key(src_port)
        rate = spec.get("rate")
        if rate is not None:  # the schema made it a positive number
            key = keys.thinned(key, float(rate))
            topo.thinned.setdefault(src.name, {}).setdefault(src_port, {})[key] = float(rate)
        links, draw = spec.get("links", ""), spec.get("draw", "")
        if links and src_kind != "JointState":
            self.error(
                "record-links",
                f"{spec['from']} carries {src_kind}, and links are drawn from joints",
                (*where, "links"),
                "name links on a JointState output",
            )
        for field_name, path in (("links", links), ("draw", draw)):
            if path and self.classes:
                try:
                    load_function(path)
                except ClassPathError as exc:
                    self.error(
                        f"record-{field_name}", str(exc), (*where, field_name), "module:function"
                    )
        topo.records[key] = Recorded(src_kind, spec["from"], spec.get("frame", ""), links, draw)

    def connection(
        self, topo: Topology, spec: dict[str, Any], where: tuple[Any, ...], timeout: float
    ) -> Step | None:
        comp, port, kind = self.port(topo, spec["port"], (*where, "port"), "in")
        if "from" in spec:
            src, src_port, src_kind = self.port(topo, spec["from"], (*where, "from"), "out")
            if src is None:
                return None
            key = src.output_key(src_port)
            writers = [(spec["from"], src_kind)]
            rate = spec.get("rate")
            if rate is not None:  # the schema made it a positive number
                key = keys.thinned(key, float(rate))
                topo.thinned.setdefault(src.name, {}).setdefault(src_port, {})[key] = float(rate)
        else:
            key = spec["key"]
            writers = topo.writers_of(key)
            if "rate" in spec:
                self.error(
                    "rate",
                    f"{spec['port']}: a rate thins a writer's stream, and a key names none",
                    (*where, "rate"),
                    "name the writer: from: component.port",
                )
        try:
            ConnPolicy.from_spec(spec.get("policy"))
        except PortError as exc:
            self.error("policy", str(exc), (*where, "policy"))
        if comp is None:
            return None
        for writer, writer_kind in writers:
            if writer_kind != kind:
                self.error(
                    "type-mismatch",
                    f"{spec['port']} ({kind}) cannot read key {key!r}: "
                    f"{writer} writes {writer_kind} there",
                    where,
                    "connect it to a key of the same message type",
                )
        return Step(
            "connect",
            comp.name,
            port,
            key=key,
            policy=spec.get("policy"),
            timeout=timeout,
            location=self.doc.location(where),
        )

    def states(
        self, topo: Topology, spec: dict[str, Any] | None, where: tuple[Any, ...], timeout: float
    ) -> list[Step]:
        if not spec:
            return []
        default = spec.get("default", "ignore")
        steps, named = [], []
        for name, target in spec.items():
            if name == "default":
                continue
            if name not in topo.components:
                self.error(
                    "unknown-component",
                    f"unknown component {name!r}",
                    (*where, name),
                    self.close(name, topo.components),
                )
                continue
            named.append(name)
            if target != "ignore":
                steps.append(
                    Step(
                        "state",
                        name,
                        target,
                        timeout=timeout,
                        location=self.doc.location((*where, name)),
                    )
                )
        if default != "ignore":
            for name in topo.components:
                if name not in named:
                    steps.append(
                        Step(
                            "state",
                            name,
                            default,
                            timeout=timeout,
                            location=self.doc.location((*where, "default")),
                        )
                    )
        return steps

    def component(self, topo: Topology, name: str, where: tuple[Any, ...]) -> ComponentSpec | None:
        """The named component, or None with an `unknown-component` finding."""
        comp = topo.components.get(name)
        if comp is None:
            self.error(
                "unknown-component",
                f"unknown component {name!r}",
                where,
                self.close(name, topo.components),
            )
        return comp

    def step(
        self, topo: Topology, spec: dict[str, Any], where: tuple[Any, ...], timeout: float
    ) -> Step | None:
        ((kind, arg),) = spec.items()
        here = (*where, kind)
        loc = self.doc.location(here)
        if kind == StepKind.DISCONNECT:
            comp, port, _ = self.port(topo, arg, here)
            return (
                Step(StepKind.DISCONNECT, comp.name, port, timeout=timeout, location=loc)
                if comp
                else None
            )
        if kind == StepKind.CONNECT:
            return self.connection(topo, arg, here, timeout)
        if kind == StepKind.SET:
            comp_name, prop = arg["property"].split(".", 1)
            comp = self.component(topo, comp_name, here)
            if comp is None or comp.info is None:
                return None
            declared = comp.info.properties.get(prop)
            if declared is None:
                self.error(
                    "unknown-property",
                    f"{comp_name!r} has no property {prop!r}",
                    here,
                    self.close(prop, comp.info.properties),
                )
                return None
            try:
                value = declared.validate(arg["value"], comp_name)
            except PropertyError as exc:
                self.error("property-value", str(exc), (*here, "value"))
                return None
            return Step(StepKind.SET, comp_name, prop, value=value, timeout=timeout, location=loc)
        if kind == StepKind.CALL:
            ref = arg if isinstance(arg, str) else arg["operation"]
            args = {} if isinstance(arg, str) else dict(arg.get("args") or {})
            step_timeout = timeout
            if isinstance(arg, dict) and "timeout" in arg:
                step_timeout = parse_duration(arg["timeout"])
            comp_name, op = ref.split(".", 1)
            comp = self.component(topo, comp_name, here)
            if comp is None or comp.info is None:
                return None
            signature = comp.info.operations.get(op)
            if signature is None:
                self.error(
                    "unknown-operation",
                    f"{comp_name!r} has no operation {op!r}",
                    here,
                    self.close(op, comp.info.operations),
                )
                return None
            try:
                signature.bind(**args)
            except TypeError as exc:
                self.error("operation-args", f"{ref}: {exc}", here)
                return None
            return Step(StepKind.CALL, comp_name, op, args=args, timeout=step_timeout, location=loc)
        comp, port, _ = self.port(topo, arg["port"], (*here, "port"), "in")
        return (
            Step(StepKind.WRITE, comp.name, port, value=arg["value"], timeout=timeout, location=loc)
            if comp
            else None
        )

    def configurations(self, topo: Topology, data: dict[str, Any]) -> dict[str, Configuration]:
        out = {}
        for name, spec in (data.get("configurations") or {}).items():
            here = ("configurations", name)
            timeout = parse_duration(spec.get("timeout", DEFAULT_STEP_TIMEOUT))
            steps = self.states(topo, spec.get("pre"), (*here, "pre"), timeout)
            for i, item in enumerate(spec.get("do") or []):
                step = self.step(topo, item, (*here, "do", i), timeout)
                if step is not None:
                    steps.append(step)
            steps += self.states(topo, spec.get("post"), (*here, "post"), timeout)
            out[name] = Configuration(
                name, steps, timeout, spec.get("doc", ""), self.doc.location(here)
            )
        return out

    def safety(self, topo: Topology, data: dict[str, Any]) -> SafetySpec | None:
        """The `safety:` section: a monitor that can host one, watches that exist and
        have a producer that can keep their deadline."""
        spec = data.get("safety")
        if not spec:
            return None
        monitor = self.component(topo, spec["monitor"], ("safety", "monitor"))
        info = monitor.info if monitor is not None else None
        if info is not None and not info.cls.hosts_safety_monitor:
            self.error(
                "safety-monitor",
                f"{spec['monitor']!r} ({info.cls.__name__}) cannot host the safety monitor: "
                "it must brake in its own control loop",
                ("safety", "monitor"),
                "name the robot interface (its class sets hosts_safety_monitor = True)",
            )
        watches = []
        for name, value in (spec.get("watch") or {}).items():
            where = ("safety", "watch", name)
            try:
                deadline = parse_duration(value)
            except ValueError as exc:
                self.error("safety-watch", str(exc), where)
                continue
            if "." in name:
                comp, port, kind = self.port(topo, name, where, "out")
                if comp is None:
                    continue
                watches.append(Watch(name, comp.output_key(port), deadline, comp.name, kind))
                continue
            comp = self.component(topo, name, where)
            if comp is None:
                continue
            activity = comp.activity
            if activity.kind not in ("periodic", "event", "paced"):
                self.error(
                    "safety-watch",
                    f"{name!r} is watched by its heartbeat, but its activity is "
                    f"{activity.kind}: only a periodic, event-driven or paced component beats",
                    where,
                    "watch one of its output ports instead, or give it an activity",
                )
                continue
            if activity.kind == "periodic" and deadline < 2.0 / activity.rate:
                self.error(
                    "safety-watch",
                    f"deadline {deadline * 1e3:g} ms for {name!r} is shorter than two of its "
                    f"periods ({2e3 / activity.rate:g} ms): it would trip on every late update",
                    where,
                )
                continue
            watches.append(Watch(name, keys.heartbeat(name), deadline, name, "Scalar"))
        try:
            process_deadline = parse_duration(
                spec.get("process_deadline", DEFAULT_PROCESS_DEADLINE)
            )
        except ValueError as exc:
            self.error("safety-watch", str(exc), ("safety", "process_deadline"))
            process_deadline = DEFAULT_PROCESS_DEADLINE
        processes = sorted({c.process for c in topo.components.values()} | {CONTROL_PROCESS})
        watches += [
            Watch(
                f"process {p}",
                keys.process_heartbeat(p),
                process_deadline * (CONTROL_SLACK if p == CONTROL_PROCESS else 1.0),
                "",
                "Scalar",
            )
            for p in processes
        ]
        control = ["configurator", *(["coordinator"] if topo.statechart is not None else [])]
        return SafetySpec(
            spec["monitor"], tuple(watches), tuple([*topo.components, *control]), process_deadline
        )

    def chart(self, topo: Topology, data: dict[str, Any]) -> None:
        if topo.statechart is None:
            return
        from framework.statechart.loader import build_statechart
        from framework.statechart.model import BUILTIN_EVENTS
        from framework.statechart.validator import validate_chart

        chart, found = build_statechart(topo.statechart, at=self.doc.location(("statechart",)))
        self.findings.extend(found)
        if chart is None or any(f.severity == "error" for f in found):
            return
        tags = {name: c.location for name, c in topo.configurations.items()}
        self.findings.extend(f for f in validate_chart(chart, tags) if f.severity == "error")
        if not self.classes:
            return  # what the components emit is in their classes
        produced = set(topo.external_events)
        for spec in topo.components.values():
            if spec.info is not None:
                produced.update(spec.info.emits)
        for i, button in enumerate(topo.console.buttons or []):
            declared = chart.events.get(button.event)
            problem = declared.problem(button.payload) if declared is not None else ""
            if problem:
                self.error("console-button", problem, ("console", "buttons", i, "payload"))
        raised = {
            a.event
            for s in chart.states.values()
            for a in (*s.entry, *s.exit, *s.do)
            if a.kind == "raise"
        }
        raised |= {a.event for t in chart.transitions() for a in t.effect if a.kind == "raise"}
        consumed = sorted({e for t in chart.transitions() for e in t.events})
        for event in consumed:
            if event in BUILTIN_EVENTS or event in raised or event in produced:
                continue
            self.error(
                "no-producer",
                f"the chart consumes {event!r} but no component of this topology emits it",
                ("statechart",),
                "add a component whose class lists it in `emits`, or list it under "
                "`external_events` if the console or an operator sends it",
            )


def check_topology(
    path: str | Path, classes: bool = True, files: FileCheck | None = None
) -> tuple[Topology | None, list[Finding]]:
    """Load and check a topology; the model (None if it cannot be built) and findings.
    `classes=False` imports no component class (see `load_topology`). With `files`,
    every file a component's properties name is checked with it too (`fw validate`
    and `fw deploy` pass `framework.filekinds.check_file`, which sits above this
    module)."""
    try:
        doc = _read(Path(path), ())
    except FwError as exc:
        location = getattr(exc, "location", Location(str(path)))
        return None, [Finding("error", "yaml", getattr(exc, "message", str(exc)), location)]
    problems = schema.check(doc, "topology")
    if problems:
        return None, problems
    data = doc.data
    loader = _Loader(doc, classes, files)
    loader.findings.extend(ros2_section.expand(doc))
    base = Path(doc.file).parent

    def folder(key: str) -> Path:
        return Path(doc.origin((key,))).parent

    bus_spec = data.get("bus") or {}
    bus = BusConfig(
        namespace=bus_spec.get("namespace", data["topology"]),
        hub_port=bus_spec.get("hub_port", 7447),
        host=bus_spec.get("address", "127.0.0.1"),
        lease_ms=bus_spec.get("lease_ms", 2000),
        extra=bus_spec.get("extra", {}),
        secure=bus_spec.get("security", "mtls") == "mtls",
    )
    topo = Topology(
        name=data["topology"],
        file=str(path),
        bus=bus,
        processes={k: dict(v or {}) for k, v in (data.get("processes") or {}).items()},
        components={},
        connections=[],
        prepare={},
        configurations={},
        statechart=folder("statechart") / data["statechart"] if "statechart" in data else None,
        procedure=folder("procedure") / data["procedure"] if "procedure" in data else None,
        external_events=list(data.get("external_events") or []),
        description=data.get("description", ""),
        hosts={name: spec["address"] for name, spec in (data.get("hosts") or {}).items()},
    )
    topo.import_paths = [base.resolve()]
    for i, folder in enumerate(data.get("import_paths") or []):
        if (base / folder).is_dir():
            topo.import_paths.append((base / folder).resolve())
        else:
            loader.error(
                "import-path",
                f"import path {folder!r} is not a folder (relative to {str(base)!r})",
                ("import_paths", i),
            )
    add_import_paths(topo.import_paths)
    topo.components = loader.components(data)
    loader.file_inputs(topo)
    for i, spec in enumerate(data.get("connections") or []):
        step = loader.connection(topo, spec, ("connections", i), DEFAULT_STEP_TIMEOUT)
        if step is not None:
            topo.connections.append(step)
    loader.file_links(topo, data)
    for i, spec in enumerate(data.get("record") or []):
        loader.recorded(topo, spec, ("record", i))
    for ref, candidates in (data.get("prepare") or {}).items():
        comp, _port, _ = loader.port(topo, ref, ("prepare", ref), "in")
        if comp is not None:
            topo.prepare[ref] = [topo.key_of(c) for c in candidates]
    topo.configurations = loader.configurations(topo, data)
    topo.safety = loader.safety(topo, data)
    topo.console = parse_console(data.get("console"), topo, loader)
    for process, settings in topo.processes.items():
        host = settings.get("host")
        if topo.hosts and host is not None and host not in topo.hosts:
            loader.error(
                "host",
                f"process {process!r} runs on host {host!r}, which hosts: does not declare "
                f"(declared: {', '.join(sorted(topo.hosts))})",
                ("processes", process, "host"),
            )
    if topo.procedure is not None and not topo.procedure.exists():
        loader.error(
            "procedure", f"procedure folder {str(topo.procedure)!r} does not exist", ("procedure",)
        )
    if topo.statechart is not None and not topo.statechart.exists():
        loader.error(
            "statechart", f"statechart {str(topo.statechart)!r} does not exist", ("statechart",)
        )
    else:
        loader.chart(topo, data)
    findings = sorted(loader.findings, key=lambda f: (f.location.file, f.location.line))
    return topo, findings


MAX_EXTENDS = 8
"""How deep topologies may extend one another (a chain longer than this is a mistake)."""


def _read(path: Path, chain: tuple[str, ...]) -> Document:
    """A topology file, laid over the one it `extends:` (recursively): the other file's
    path is relative to this one; its values stay located in their own file."""
    doc = load_yaml(path)
    data = doc.data
    if not isinstance(data, dict) or "extends" not in data:
        return doc
    where = doc.location(("extends",))
    name = data["extends"]
    if not isinstance(name, str) or not name:
        raise LocatedError("`extends:` names the topology file this one lays over", where)
    base_path = (path.parent / name).resolve()
    here = str(path.resolve())
    if str(base_path) in (*chain, here):
        cycle = " -> ".join(Path(p).name for p in (*chain, here, str(base_path)))
        raise LocatedError(f"topologies extend each other in a circle: {cycle}", where)
    if len(chain) >= MAX_EXTENDS:
        raise LocatedError(f"more than {MAX_EXTENDS} topologies extend one another", where)
    try:
        base = _read(base_path, (*chain, here))
    except LocatedError as exc:
        if exc.location.line and not isinstance(exc, MissingFileError):
            raise  # a mistake inside the other file: located there
        raise LocatedError(f"`extends:` names no readable file: {exc.message}", where) from None
    overlay = Document(
        {k: v for k, v in data.items() if k != "extends"}, doc.file, doc.marks, doc.origins
    )
    return extend(base, overlay)


def load_topology(
    path: str | Path, classes: bool = True, files: FileCheck | None = None
) -> Topology:
    """Load a topology; raise `FindingsError` with every error found.

    `classes=False` gives a client's view (`fw send`, `status`, `ls`, `call`): no
    component class is imported, so a project's components need not be importable
    where the operator runs fw. Names, processes, the bus, the chart, the operator's
    events and the console are read and checked; ports, wiring and what the classes
    declare are not (`ComponentSpec.info` is None): the running deployment knows them.
    """
    topo, findings = check_topology(path, classes, files)
    if topo is None or any(f.severity == "error" for f in findings):
        raise FindingsError(findings)
    return topo


def _after_loop(name: str, components: dict) -> list[str]:
    """The chain of `after` masters from `name` back to itself ([] if it reaches a
    component with a thread of its own): a loop would never run."""
    chain = [name]
    spec = components.get(name)
    while isinstance(spec, dict) and isinstance(spec.get("activity"), dict):
        master = spec["activity"].get("after")
        if not isinstance(master, str):
            return []
        chain.append(master)
        if master == name:
            return chain
        if master in chain[:-1]:
            return []  # a loop further up: reported for the components on it
        spec = components.get(master)
    return []
