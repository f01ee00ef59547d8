"""Deploy a topology: check it, start its processes, wire it, hand control to the chart.

`Deployment.start()` does, in order: load and check the topology (nothing
starts if anything is wrong), open the deployment's hub session, spawn one
container process per topology process (components, properties, output
keys, initial connections, standby keys), wait for every component's
liveliness token (a timeout names the missing ones and what their process
printed), host the Configurator and the Coordinator in this process, bring
components to their `initial` states, and start the chart. `stop()` shuts
down in order: processes marked `shutdown: first` (the robot side) are
stopped and waited for before the others, the control components last.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from framework import keys, netns
from framework.access import access_control
from framework.activity import Activity
from framework.bus import Bus, BusConfig, BusError
from framework.configurator import Configurator
from framework.container import Container
from framework.container_main import raise_priority, spawn_container
from framework.coordinator import (
    ACKS_KEY,
    EVENTS_KEY,
    REQUESTS_KEY,
    SENT_KEY,
    STATUS_KEY,
    Admission,
    Coordinator,
)
from framework.errors import FwError
from framework.keystore import OPERATOR, Keystore, create_keystore, keystore_for
from framework.local_switch import switch_spec
from framework.process import Process
from framework.routes import RouteWatch
from framework.statechart.events import Listener
from framework.statechart.loader import load_statechart
from framework.topology import CONTROL_PROCESS, Step, StepKind, Topology, load_topology
from framework.watchdog import ProcessWatch


class DeployError(FwError):
    """The deployment could not be brought up (what is missing and why)."""


LOCAL = "local"
SAFETY_NICE = -10
"""With a safety monitor, every process of the deployment runs at this nice level (if
the user may raise priorities): the host's other programs must not starve them past
their deadlines."""
CONTROL_NICE = -15
"""The control loop's processes run ahead of the rest (three times their share of a
busy CPU): the monitor's and every process with a device loop (a paced or real-time
component: the robot interface, the arm's KRC). Their loops run at a real-time
priority of their own (framework/realtime.py); this is for their other threads (the
bus's, the heartbeat). A browser and the other processes on two cores starved the
robot process for 41 ms."""


def control_processes(topology: Topology) -> set[str]:
    """The processes of the safety monitor and of every device loop."""
    safety = topology.safety
    if safety is None:
        return set()
    spec = topology.components.get(safety.monitor)
    out = {spec.process} if spec is not None else set()
    used = {c.process for c in topology.components.values()}
    return out | {p for p in used if realtime_process(topology, p)}


def realtime_process(topology: Topology, process: str) -> bool:
    """Whether `process` hosts a device loop (a paced activity, or a component class
    that says it is `realtime`): its loops run at a real-time priority."""
    return any(
        spec.activity.kind == "paced"
        or getattr(spec.info.cls if spec.info else None, "realtime", False)
        for spec in topology.components_in(process)
    )


def _resume(popen: subprocess.Popen[bytes]) -> None:
    """SIGCONT, unless the process is gone meanwhile."""
    if popen.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(popen.pid, signal.SIGCONT)


def host_of(topology: Topology, process: str) -> str:
    """The host a process runs on (`local` unless the topology names one)."""
    return topology.processes.get(process, {}).get("host", LOCAL)


def not_up(topology: Topology, missing: list[str], host: str | None = None) -> str:
    """Which components never came up, by host and process: for a process on another
    host, the command that starts that host's part (a host that never came up is the
    usual cause on several machines, and waiting longer would not help)."""
    mine = LOCAL if host is None else host
    by_place: dict[tuple[str, str], list[str]] = {}
    for name in missing:
        spec = topology.components.get(name)
        process = spec.process if spec is not None else "?"
        by_place.setdefault((host_of(topology, process), process), []).append(name)
    parts = []
    for (where, process), names in sorted(by_place.items()):
        part = f"{', '.join(names)} (process {process}"
        if where != mine:
            part += (
                f" on host {where!r}: is its part running there? "
                f"fw deploy {topology.file} --keys DIR --host {where}"
            )
        parts.append(part + ")")
    return "; ".join(parts)


def mesh(topology: Topology) -> dict[str, tuple[str, int]]:
    """Where each process of a deployment on several hosts listens, (address, port):
    the port after the hub's for the first process by name, and so on; empty on one
    host. Each process connects to every process before it itself (`BusConfig.peers`),
    so every pair has one side that makes the link again after a partition: Zenoh's
    gossip makes a peer link once, when it learns of the peer, and a partition shorter
    than the lease (one side had closed the link, the other had not yet) left links
    unmade for good (docs/hosts.md)."""
    if not topology.hosts:
        return {}
    bus = topology.bus
    return {
        name: (topology.listen_address(host_of(topology, name)) or bus.host, bus.hub_port + 1 + i)
        for i, name in enumerate(
            sorted({c.process for c in topology.components.values()} - {CONTROL_PROCESS})
        )
    }


def process_bus(topology: Topology, process: str) -> BusConfig:
    """The bus settings of one process: where it listens and whom it connects to."""
    bus = dataclasses.replace(
        topology.bus, listen=topology.listen_address(host_of(topology, process))
    )
    places = mesh(topology)
    if process not in places:
        return bus
    names = list(places)  # by name (`mesh` builds it so)
    before = names[: names.index(process)]
    endpoint = {n: f"{bus.protocol}/{places[n][0]}:{places[n][1]}" for n in names}
    return dataclasses.replace(
        bus,
        listen_port=places[process][1],
        peers=tuple(endpoint[n] for n in before),
        others=tuple(endpoint[n] for n in names if n != process),
    )


def clock_peers(topology: Topology, process: str) -> tuple[dict[str, str], dict[str, str]]:
    """Which other host writes each key `process` reads, and per such host the process
    to ask its clock (framework/peer_clocks.py): samples stamped on another host's clock
    are judged with that clock's measured offset, never as if it were this host's. A
    process away from the control host also measures that host (`control` answers
    there): the Configurator's and the Coordinator's deadlines are on its clock."""
    mine = host_of(topology, process)
    writers: dict[str, tuple[str, str]] = {}  # key -> (host, process)
    for spec in topology.components.values():
        host = host_of(topology, spec.process)
        if host == mine or spec.info is None:
            continue
        for port in spec.info.outputs:
            writers[spec.output_key(port)] = (host, spec.process)
            for key in topology.thinned.get(spec.name, {}).get(port, {}):
                writers[key] = (host, spec.process)
    here = {c.name for c in topology.components_in(process)}
    read = {s.key for s in topology.connections if s.component in here}
    read |= {
        key
        for ref, candidates in topology.prepare.items()
        if ref.split(".", 1)[0] in here
        for key in candidates
    }
    key_hosts = {key: writers[key][0] for key in sorted(read) if key in writers}
    peers: dict[str, str] = {}
    for key in sorted(key_hosts):
        peers.setdefault(writers[key][0], writers[key][1])
    if mine != LOCAL:  # the Coordinator's and Configurator's: their requests' deadlines
        peers.setdefault(LOCAL, CONTROL_PROCESS)
    return key_hosts, peers


def container_spec(topology: Topology, process: str) -> dict[str, Any]:
    """What `python -m framework.container_main` needs to host one process of the topology."""
    components = []
    for spec in topology.components_in(process):
        connections = {
            s.target: {"key": s.key, "policy": s.policy}
            for s in topology.connections
            if s.component == spec.name
        }
        prepare = {
            ref.split(".", 1)[1]: keys_
            for ref, keys_ in topology.prepare.items()
            if ref.split(".", 1)[0] == spec.name
        }
        item = {
            "name": spec.name,
            "class": spec.class_path,
            "activity": spec.activity.to_spec(),
            "properties": spec.properties,
            "outputs": spec.outputs,
            "thinned": topology.thinned.get(spec.name, {}),
            "connections": connections,
            "prepare": prepare,
            "heartbeat": topology.heartbeats().get(spec.name),
        }
        if topology.safety is not None and topology.safety.monitor == spec.name:
            item["safety"] = topology.safety.to_dict()
        components.append(item)
    spec: dict[str, Any] = {
        "name": process,
        "bus": process_bus(topology, process).to_dict(),
        "components": components,
        "switches": switch_spec(topology, process),
        "import_paths": [str(p) for p in topology.import_paths],
    }
    key_hosts, peers = clock_peers(topology, process)
    if peers:
        spec["key_hosts"], spec["peer_clocks"] = key_hosts, peers
    if LOCAL in peers:
        spec["requester_host"] = LOCAL  # deadlines are on the control host's clock
    if topology.safety is not None:
        spec["beat"] = topology.safety.process_beat
        spec["nice"] = CONTROL_NICE if process in control_processes(topology) else SAFETY_NICE
    if realtime_process(topology, process):
        spec["realtime"] = True  # a device loop's process: framework/realtime.py
    return spec


def admission(topology: Topology) -> Admission:
    """Who may give the chart which event: the operator the topology's external events,
    each component the events its class declares it emits."""
    return Admission(
        external=frozenset(topology.external_events),
        emitters={
            name: frozenset(spec.info.emits if spec.info is not None else ())
            for name, spec in topology.components.items()
        },
    )


@dataclass
class Deployment:
    """A running topology (see the module docstring)."""

    topology: Topology
    workdir: Path
    listeners: list[Listener] = field(default_factory=list)
    liveliness_timeout: float = 30.0
    host: str | None = None
    """Start only this host's processes (`None`: the control host, see `host_of`)."""
    scenario: Any = None
    report: Any = None
    runner: Any = None
    processes: list[Process] = field(default_factory=list)
    hub: Bus | None = None
    control: Container | None = None
    configurator: Configurator | None = None
    coordinator: Coordinator | None = None
    watch: ProcessWatch | None = None
    """Watches the processes for the whole run (losses, restarts)."""
    keys: Path | None = None
    """A keystore made beforehand (`fw keys`); default: a fresh one per run."""
    _own_keys: Keystore | None = None
    _heals: list[threading.Timer] = field(default_factory=list)
    """Link faults still to be healed (healed at once by `stop`: no link stays down)."""

    @classmethod
    def from_file(cls, path: str | Path, workdir: str | Path, **options: Any) -> Deployment:
        """Load and check the topology file (raises `FindingsError` listing every error)."""
        return cls(load_topology(path), Path(workdir), **options)

    def start(self, run_chart: bool = True) -> None:
        """Bring everything up; on any failure, tear down what started and raise."""
        try:
            self._start(run_chart)
        except BaseException:
            self.stop()
            raise

    def _start(self, run_chart: bool) -> None:
        topo = self.topology
        chart = load_statechart(topo.statechart) if topo.statechart is not None else None
        self.workdir.mkdir(parents=True, exist_ok=True)
        control = self.host in (None, LOCAL)
        if topo.bus.secure:
            topo.bus = self._credentials(control)
        mine = LOCAL if self.host is None else self.host
        places = mesh(topo)  # the hub's reopened session links to every process itself
        here = dataclasses.replace(
            topo.bus,
            listen=topo.listen_address(mine),
            others=tuple(f"{topo.bus.protocol}/{a}:{p}" for a, p in places.values()),
        )
        try:
            self.hub = Bus(here, hub=control, subject=CONTROL_PROCESS if control else OPERATOR)
        except BusError as exc:  # name the file, so the command it suggests runs as written
            raise BusError(str(exc).replace("TOPOLOGY", topo.file)) from None
        names = sorted(
            {c.process for c in topo.components.values() if host_of(topo, c.process) == mine}
        )
        if not names and not control:
            raise DeployError(f"no process of topology {topo.name!r} runs on host {mine!r}")
        for name in names:
            settings = topo.processes.get(name, {})
            log = self.workdir / f"{name}.stderr.log"
            process = Process(
                name,
                [c.name for c in topo.components_in(name)],
                settings.get("shutdown", "normal"),
                stderr=log,
            )
            self.spawn(process, fresh=True)
            self.processes.append(process)
        self._wait_for_liveliness(
            None if control else [c for p in self.processes for c in p.components]
        )
        self.watch = ProcessWatch(self)
        if not control:  # another host runs the Coordinator and the Configurator
            self.watch.start()
            return
        if topo.safety is not None:
            # the Coordinator's process is watched too, whoever hosts it (fw deploy,
            # fw bench, a test)
            raise_priority(SAFETY_NICE, "control")
        beat = topo.safety.process_beat if topo.safety is not None else None
        self.control = Container(CONTROL_PROCESS, self.hub, beat=beat)
        self.control.routes = RouteWatch(
            self.hub, CONTROL_PROCESS, can_reopen=bool(self.hub.config.others)
        ).start()
        self.configurator = self.control.add(
            Configurator("configurator", topo, self.hub),
            Activity.event("requests"),
            outputs={"acks": ACKS_KEY},
        )
        self.control.connect(
            "configurator",
            "requests",
            REQUESTS_KEY,
            {"type": "buffer", "size": 64, "overflow": "drop_newest"},
        )
        if chart is not None:
            watch = {c.name: c.process for c in topo.components.values()}
            self.coordinator = self.control.add(
                Coordinator("coordinator", chart, self.listeners, watch, admission(topo)),
                None,
                outputs={"requests": REQUESTS_KEY, "status": STATUS_KEY, "sent": SENT_KEY},
            )
            self.control.connect("coordinator", "events", EVENTS_KEY)
            self.control.connect("coordinator", "acks", ACKS_KEY)
        self.control.start()
        self.configurator.start()
        for spec in topo.components.values():
            if spec.initial not in ("preoperational", "ignore"):
                outcome = self.configurator.run_steps(
                    f"initial state of {spec.name}",
                    [Step(StepKind.STATE, spec.name, spec.initial, timeout=5.0)],
                )
                if not outcome.ok:
                    raise DeployError(f"{outcome.step}: {outcome.reason}")
        if run_chart:
            self.run_chart()
        self.watch.start()

    def _credentials(self, control: bool) -> BusConfig:
        """The bus with the deployment's keystore: the one given (`keys`, shared by
        several hosts), else a fresh one per run, removed when the run ends."""
        topo = self.topology
        if self.keys is not None:
            store = Keystore(Path(self.keys))
        elif topo.bus.keys:
            store = Keystore(Path(topo.bus.keys))
        elif not control:
            raise DeployError(
                "a host without the Coordinator needs the deployment's keystore: make one "
                "with `fw keys TOPOLOGY -o DIR`, copy it to every host, and pass --keys DIR"
            )
        else:
            processes = {c.process for c in topo.components.values()}
            store = create_keystore(
                keystore_for(topo.bus.namespace).root, sorted(processes), topo.addresses()
            )
            self._own_keys = store
        return dataclasses.replace(topo.bus, keys=str(store.root), access=access_control(topo))

    def run_chart(self) -> None:
        """Start the Coordinator (the chart begins with its setup configurations) and the
        scenario, if any."""
        if self.coordinator is not None and self.coordinator.state.value != "Running":
            if self.scenario is not None:
                from framework.remote import RemoteComponent
                from framework.scenario import ScenarioRunner

                def call(ref: str, args: dict[str, Any]) -> Any:
                    component, _, op = ref.partition(".")
                    return RemoteComponent(self.hub, component).call(op, **args)  # type: ignore[arg-type]

                self.runner = ScenarioRunner(
                    self.scenario,
                    self.send,
                    call,
                    self.report or (lambda text: None),
                    self.inject_fault,
                )
                self.coordinator.extra_listeners.append(self.runner)
            self.coordinator.start()
            if self.runner is not None:
                self.runner.start()

    def spawn(self, process: Process, fresh: bool = False) -> None:
        """Start `process`'s container; its stderr goes to its log (kept across restarts,
        begun anew with `fresh`)."""
        assert process.stderr is not None
        with process.stderr.open("wb" if fresh else "ab") as err:
            process.popen = spawn_container(
                container_spec(self.topology, process.name), stdout=subprocess.DEVNULL, stderr=err
            )

    def wait_alive(self, components: list[str]) -> None:
        """Wait until these components' liveliness tokens are up (a restarted process)."""
        self._wait_for_liveliness(components)

    def wait_gone(self, components: list[str]) -> None:
        """Wait until these components' liveliness tokens are gone (a lost process). The
        process's exit can be seen before the bus drops its tokens: a restart that did not
        wait would take the old tokens for the new process's and ask a process that does
        not answer yet."""
        assert self.hub is not None
        expected = {keys.alive(c) for c in components}
        deadline = time.monotonic() + self.liveliness_timeout
        while time.monotonic() < deadline:
            left = expected & set(self.hub.alive(keys.ALL_ALIVE, 0.5))
            if not left:
                return
            time.sleep(0.02)
        names = ", ".join(sorted(k.rsplit("/", 1)[-1] for k in left))
        raise DeployError(
            f"still alive {self.liveliness_timeout:g} s after their process was lost: {names} "
            "(another process serves these names?)"
        )

    def _wait_for_liveliness(self, components: list[str] | None = None) -> None:
        assert self.hub is not None
        expected = {keys.alive(c) for c in (components or self.topology.components)}
        deadline = time.monotonic() + self.liveliness_timeout
        alive: set[str] = set()
        while time.monotonic() < deadline:
            alive = set(self.hub.alive(keys.ALL_ALIVE, 0.5))
            if expected <= alive:
                return
            mine = {c for c in (components or self.topology.components)}
            dead = [
                p
                for p in self.processes
                if p.popen is not None and p.popen.poll() is not None and mine & set(p.components)
            ]
            if dead:
                what = "; ".join(
                    f"process {p.name!r} exited with code {p.popen.returncode}: "
                    f"{p.tail() or 'no output'}"
                    for p in dead
                )  # type: ignore[union-attr]
                raise DeployError(f"deployment failed: {what}")
            time.sleep(0.05)
        missing = sorted(k.rsplit("/", 1)[-1] for k in expected - alive)
        raise DeployError(
            f"components not alive after {self.liveliness_timeout:g} s: "
            + not_up(self.topology, missing, self.host)
        )

    def inject_fault(self, fault: Any) -> None:
        """Signal one of this deployment's processes (a scenario's `fault` step, `fw bench
        chaos`): KILL, TERM, INT, or STOP followed by SIGCONT after `fault.hold` s; or,
        for a `link` fault, cut or impair a host's network link for `fault.hold` s (the
        hosts as network namespaces of this machine: framework/netns.py)."""
        if fault.link:
            self._link_fault(fault)
            return
        process = next((p for p in self.processes if p.name == fault.process), None)
        if process is None or process.popen is None or process.popen.poll() is not None:
            raise DeployError(f"no running process {fault.process!r} in this deployment")
        pid = process.popen.pid
        if self.watch is not None:
            self.watch.note("fault_injected", fault.process, fault.describe())
        os.kill(pid, getattr(signal, f"SIG{fault.signal}"))
        if fault.signal == "STOP":
            resume = threading.Timer(fault.hold, _resume, args=(process.popen,))
            resume.daemon = True
            resume.start()

    def _link_fault(self, fault: Any) -> None:
        hosts = netns.Hosts(prefix=os.environ.get("FW_NETNS_PREFIX", "fw-"))
        if not Path("/run/netns", hosts.namespace(fault.link)).exists():
            raise DeployError(
                f"no network namespace {hosts.namespace(fault.link)!r} for host "
                f"{fault.link!r}: link faults need the hosts as network namespaces of this "
                "machine (python -m framework.netns up)"
            )
        if self.watch is not None:
            self.watch.note("fault_injected", fault.link, fault.describe())
        try:
            if fault.partition:
                hosts.cut(fault.link)
            else:
                hosts.impair(fault.link, fault.loss, fault.delay, fault.jitter)
        except netns.NetnsError as exc:
            raise DeployError(str(exc)) from None
        heal = threading.Timer(fault.hold, hosts.heal, args=(fault.link,))
        heal.daemon = True
        heal.start()
        self._heals.append(heal)

    def send(self, event: str, payload: dict[str, Any] | None = None) -> None:
        """Give the chart an event (as `fw send` does)."""
        if self.coordinator is None:
            raise DeployError("this deployment runs no statechart")
        self.coordinator.offer(event, payload, origin="scenario")

    def stop(self) -> None:
        """Shut down in order: `shutdown: first` processes, then the others, then control."""
        for heal in self._heals:
            if heal.is_alive():
                heal.cancel()
                with contextlib.suppress(Exception):  # the namespace may be gone already
                    heal.function(*heal.args)
        if self.watch is not None:
            self.watch.stop()  # what exits from here on is the shutdown, not a loss
        if self.runner is not None:
            self.runner.stop()
        if self.coordinator is not None:
            with contextlib.suppress(Exception):
                if self.coordinator.state.value == "Running":
                    self.coordinator.stop()
        order = {"first": 0, "normal": 1, "last": 2}
        for rank in sorted(set(order.values())):
            batch = [p for p in self.processes if order.get(p.shutdown, 1) == rank]
            for process in batch:
                if process.popen is not None and process.popen.poll() is None:
                    process.popen.send_signal(signal.SIGTERM)
            for process in batch:
                if process.popen is None:
                    continue
                try:
                    process.popen.wait(10)
                except subprocess.TimeoutExpired:
                    process.popen.kill()
                    process.popen.wait(5)
        if self.control is not None:
            self.control.shutdown()
            self.control = None
        if self.hub is not None:
            self.hub.close()
            self.hub = None
        if self._own_keys is not None:
            self._own_keys.remove()
            self._own_keys = None
            self.topology.bus = dataclasses.replace(self.topology.bus, keys="", access={})
