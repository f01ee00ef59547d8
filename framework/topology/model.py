"""A topology as fw holds it once loaded and checked: components and where they run,
the wiring, the named configurations the Configurator applies, and the step each is
made of. No file is read here (framework/topology/loader.py reads and checks them).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from framework import keys
from framework.activity import Activity
from framework.bus import BusConfig
from framework.component import Component, FileInput, In, Out, declarations
from framework.errors import Location
from framework.messages import type_name
from framework.properties import Property
from framework.safety import SafetySpec
from framework.topology.console import ConsoleSpec

LIFECYCLE = ("running", "stopped", "preoperational", "ignore")
CONTROL_PROCESS = "control"
RESERVED_PROCESSES = (CONTROL_PROCESS, "operator")
"""Process names fw uses itself (and as certificate subjects, framework/keystore.py)."""
"""The process `fw deploy` itself runs in (the Coordinator and the Configurator)."""
CONTROL_SLACK = 4.0
"""Its heartbeat deadline, in process deadlines: the chart is not on the robot's fast path
(the Supervisor's reflex and the robot side stop without it), and the process that hosts
it also hosts the console and, in tests and tools, the caller's own work."""
DEFAULT_STEP_TIMEOUT = 2.0


@dataclass
class ClassInfo:
    """What a component class declares, read without instantiating it."""

    cls: type[Component]
    inputs: dict[str, str]
    outputs: dict[str, str]
    properties: dict[str, Property]
    operations: dict[str, inspect.Signature]
    emits: tuple[str, ...]
    readonly: frozenset[str] = frozenset()
    """Operations that change nothing (`@operation(readonly=True)`)."""


def declares_file_inputs(cls: type) -> bool:
    """True if a component class declares input ports from its own files."""
    return getattr(cls.file_inputs, "__func__", None) is not Component.file_inputs.__func__


@dataclass
class ComponentSpec:
    """One component of the topology."""

    name: str
    class_path: str
    process: str
    activity: Activity
    properties: dict[str, Any]
    outputs: dict[str, str]
    initial: str
    location: Location
    info: ClassInfo | None = None
    file_inputs: dict[str, FileInput] = field(default_factory=dict)
    """Input ports its configuration files declare (port -> declaration)."""

    def output_key(self, port: str) -> str:
        """The key an output port publishes on."""
        return self.outputs.get(port, keys.default_output(self.name, port))


@dataclass(frozen=True)
class Recorded:
    """One `record:` entry: an output a flight recording keeps."""

    kind: str
    """Its message type name."""
    name: str
    """The output, as `component.port` (what a viewer names it)."""
    frame: str = ""
    """The frame a Pose output is in where its samples do not say (`frame:`)."""
    links: str = ""
    """`module:function` drawing a JointState output's robot links (`links:`)."""
    draw: str = ""
    """`module:function` turning each sample into `framework.scene.Shapes` (`draw:`)."""


class StepKind(StrEnum):
    """What one configuration step does. The same word everywhere a step goes: the
    topology (`connect`, `disconnect`, `set`, `call`, `write` under `do:`; `pre:` and
    `post:` give `state` steps), the request a container runs (`Step.request`), the
    local switches, the recording and `fw log` (`Step.describe`)."""

    STATE = "state"
    """Bring a component to a lifecycle state (`target`: running, stopped...)."""
    CONNECT = "connect"
    """Connect an input port (`target`) to a key with a policy."""
    DISCONNECT = "disconnect"
    """Disconnect an input port (`target`)."""
    SET = "set"
    """Set a property (`target`) to `value`; its old value comes back (for undo)."""
    CALL = "call"
    """Call an operation (`target`) with `args`."""
    WRITE = "write"
    """Write `value` on an output port (`target`): the Configurator does it itself."""


@dataclass
class Step:
    """One action of a configuration, in order."""

    kind: StepKind
    component: str
    target: str = ""  # port, property, operation or lifecycle state
    key: str = ""
    policy: dict[str, Any] | None = None
    value: Any = None
    args: dict[str, Any] = field(default_factory=dict)
    timeout: float = DEFAULT_STEP_TIMEOUT
    location: Location = field(default_factory=Location)

    def __post_init__(self) -> None:
        self.kind = StepKind(self.kind)  # ValueError for a kind fw does not have

    def describe(self) -> str:
        """Human label used in reports, the recording and `fw log`:
        `connect supervisor.lwr_pose -> certus/cto`, `state supervisor -> running`."""
        where = f"{self.kind} {self.component}.{self.target}"
        if self.kind is StepKind.STATE:
            return f"state {self.component} -> {self.target}"
        if self.kind is StepKind.CONNECT:
            return f"{where} -> {self.key}"
        if self.kind is StepKind.SET:
            return f"{where} = {self.value!r}"
        return where

    def request(self) -> dict[str, Any]:
        """The request a container runs for this step (framework/control_requests.py):
        `{"op": "step", "step": kind, "target": ...}` and what the kind needs."""
        out: dict[str, Any] = {"op": "step", "step": str(self.kind), "target": self.target}
        if self.kind is StepKind.CONNECT:
            out |= {"key": self.key, "policy": self.policy}
        elif self.kind is StepKind.SET:
            out["value"] = self.value
        elif self.kind is StepKind.CALL:
            out["args"] = self.args
        return out


@dataclass
class Configuration:
    """A named configuration: pre states, actions, post states, as one ordered list."""

    name: str
    steps: list[Step]
    timeout: float
    doc: str
    location: Location


@dataclass
class Topology:
    """A loaded, checked topology."""

    name: str
    file: str
    bus: BusConfig
    processes: dict[str, dict[str, Any]]
    components: dict[str, ComponentSpec]
    connections: list[Step]
    prepare: dict[str, list[str]]
    configurations: dict[str, Configuration]
    statechart: Path | None
    procedure: Path | None
    external_events: list[str]
    description: str = ""
    safety: SafetySpec | None = None
    """What the robot-side monitor watches (None: the topology declares no monitor)."""
    hosts: dict[str, str] = field(default_factory=dict)
    """Other machines -> the address their processes listen on (`hosts:`)."""
    import_paths: list[Path] = field(default_factory=list)
    """Folders its component classes are also imported from: its own folder and its
    `import_paths:` (relative to it)."""
    console: ConsoleSpec = field(default_factory=ConsoleSpec)
    """What the operator console shows besides the generic parts (`console:`)."""
    records: dict[str, Recorded] = field(default_factory=dict)
    """Key (a thinned key where a rate is given) -> what a flight recording keeps of
    that output and how Foxglove draws it (`record:`)."""
    thinned: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    """component -> output port -> thinned key -> rate (Hz): the thinned streams its
    connections' `rate:` ask the writers for (framework/ports.py)."""
    file_links: list[tuple[str, FileInput]] = field(default_factory=list)
    """(component, input) of the input ports components declare in their configuration
    files (a tracker's tools per sensor of sensors.yaml, a camera per camera of
    cameras.yaml); `connections:` wires them like any other."""

    def addresses(self) -> list[str]:
        """Every address a process of this deployment listens on (a certificate of the
        deployment names them all)."""
        return list(dict.fromkeys(["127.0.0.1", self.bus.host, *self.hosts.values()]))

    def listen_address(self, host: str) -> str:
        """Where the processes of `host` listen ('' for the control host's address)."""
        return self.hosts.get(host, "")

    def heartbeats(self) -> dict[str, float]:
        """Watched components and how often each proves it runs (s)."""
        from framework.safety import heartbeat_period

        if self.safety is None:
            return {}
        return {
            w.producer: heartbeat_period(w.deadline)
            for w in self.safety.watches
            if w.key == keys.heartbeat(w.producer)
        }

    def on_loss(self, process: str) -> str:
        """What losing `process` means: 'stop' (default) or 'restart'."""
        return str(self.processes.get(process, {}).get("on_loss", "stop"))

    def components_in(self, process: str) -> list[ComponentSpec]:
        """Components hosted by one process, in topology order."""
        return [c for c in self.components.values() if c.process == process]

    def published(self) -> list[tuple[str, str, str]]:
        """(component.port, key, message type) of every output port of the topology."""
        return [
            (f"{spec.name}.{port}", spec.output_key(port), kind)
            for spec in self.components.values()
            if spec.info is not None
            for port, kind in spec.info.outputs.items()
        ]

    def key_of(self, source: str) -> str:
        """The key of `component.port` if that is an output of the topology, else
        `source` itself (a key)."""
        name, _, port = source.partition(".")
        spec = self.components.get(name)
        if spec is not None and spec.info is not None and port in spec.info.outputs:
            return spec.output_key(port)
        return source

    def local_switch(self, tag: str) -> tuple[str, list[Step]]:
        """The process that can apply the first steps of configuration `tag` by itself,
        the moment the chart asks, and those steps: disconnects and connects of input
        ports its components have, each connect to a key the port keeps a standby
        subscription to (`prepare:`). A tracker swap is such a switch, so it costs no
        hop through the Configurator. ('', []) if the configuration begins otherwise."""
        configuration = self.configurations.get(tag)
        process, steps = "", []
        for step in configuration.steps if configuration is not None else []:
            spec = self.components.get(step.component)
            if (
                spec is None
                or spec.info is None
                or step.kind not in (StepKind.CONNECT, StepKind.DISCONNECT)
                or step.target not in spec.info.inputs
                or (process and spec.process != process)
                or (
                    step.kind is StepKind.CONNECT
                    and step.key not in self.prepare.get(f"{step.component}.{step.target}", [])
                )
            ):
                break
            process = spec.process
            steps.append(step)
        return process, steps

    def writers_of(self, key: str) -> list[tuple[str, str]]:
        """(component.port, message type) of every output port publishing on `key`."""
        return [(writer, kind) for writer, at, kind in self.published() if at == key]


def class_info(cls: type[Component]) -> ClassInfo:
    """Ports, properties and operations a Component class declares."""
    inputs, outputs, props, ops = {}, {}, {}, {}
    readonly = set()
    for attr, decl in declarations(cls):
        if isinstance(decl, In):
            inputs[attr] = type_name(decl.type)
        elif isinstance(decl, Out):
            outputs[attr] = type_name(decl.type)
        elif isinstance(decl, Property):
            props[attr] = decl
        else:
            signature = inspect.signature(decl)
            params = list(signature.parameters.values())[1:]  # drop self
            ops[attr] = signature.replace(parameters=params)
            if getattr(decl, "__fw_readonly__", False):
                readonly.add(attr)
    emits = tuple(getattr(cls, "emits", ()))
    return ClassInfo(cls, inputs, outputs, props, ops, emits, frozenset(readonly))
