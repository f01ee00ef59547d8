"""Shared fixtures: write YAML to a temporary file and load it as a chart."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import textwrap
from collections.abc import Callable
from pathlib import Path

import pytest

from framework.clock import SimulatedClock
from framework.statechart.events import Listener, Trace
from framework.statechart.interpreter import Interpreter
from framework.statechart.loader import load_statechart
from framework.statechart.model import Statechart

REPO = Path(__file__).resolve().parents[1]
# Deployments started by tests keep their credentials here, not in the user's own place
# (subprocesses inherit it: `fw deploy` run by a test, and its clients, agree).
if "FW_KEYS" not in os.environ:
    os.environ["FW_KEYS"] = tempfile.mkdtemp(prefix="fw-test-keys-")
    atexit.register(shutil.rmtree, os.environ["FW_KEYS"], True)
# Processes a test deploys may name test scaffolding (`tests.support.components:Broken`),
# which is not installed with fw: they find it through the checkout.
if str(REPO) not in os.environ.get("PYTHONPATH", "").split(os.pathsep):
    os.environ["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p
    )


@pytest.fixture
def write(tmp_path: Path) -> Callable[..., Path]:
    """Write dedented YAML text to a file under tmp_path and return its path."""

    def _write(text: str, name: str = "chart.yaml") -> Path:
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text), encoding="utf-8")
        return path

    return _write


@pytest.fixture
def chart(write: Callable[..., Path]) -> Callable[..., Statechart]:
    """Load a chart from YAML text (validated unless validate=False)."""

    def _chart(text: str, validate: bool = True) -> Statechart:
        return load_statechart(write(text), validate=validate)

    return _chart


class Run:
    """An interpreter on a simulated clock with a trace, for readable tests."""

    def __init__(self, chart: Statechart, auto_ack: bool = False):
        self.clock = SimulatedClock()
        self.trace = Trace()
        self.outputs: list = []
        self.auto_ack = auto_ack
        self.interpreter = Interpreter(chart, self.clock, [self.trace], on_output=self._output)
        self.interpreter.start()

    def _output(self, output) -> None:
        self.outputs.append(output)
        if self.auto_ack and output.kind == "configure":
            self.interpreter.queue("config.done", {"tag": output.tag})

    def send(self, *events: str | tuple[str, dict]) -> Run:
        for event in events:
            name, payload = (event, None) if isinstance(event, str) else event
            self.interpreter.dispatch(name, payload)
        return self

    @property
    def leaves(self) -> list[str]:
        return self.interpreter.leaves

    def kinds(self, kind: str) -> list[tuple]:
        return [r for r in self.trace.records if r[0] == kind]


@pytest.fixture
def run(chart: Callable[..., Statechart]) -> Callable[..., Run]:
    """Start a chart written as YAML text on a simulated clock."""

    def _run(text: str, auto_ack: bool = False, validate: bool = True) -> Run:
        return Run(chart(text, validate=validate), auto_ack)

    return _run


@pytest.fixture
def bus_config(request: pytest.FixtureRequest):
    """A private deployment for one test: its own namespace and hub port."""
    import re

    from framework.bus import BusConfig, free_port

    name = re.sub(r"[^A-Za-z0-9_]", "_", request.node.name)[:40]
    return BusConfig(namespace=f"t_{name}_{free_port()}", hub_port=free_port())


@pytest.fixture
def hub(bus_config):
    """The hub session of the test's deployment (closed after the test)."""
    from framework.bus import Bus

    bus = Bus(bus_config, hub=True)
    yield bus
    bus.close()


@pytest.fixture
def peer(bus_config, hub):
    """A second session joining the hub, as another process would (linked to it before
    the test starts: on a busy host the link can take longer than a test's first step)."""
    from framework.bus import Bus

    bus = Bus(bus_config)
    assert bus.wait_for_peers(1, timeout=10.0), "the peer session never linked to the hub"
    yield bus
    bus.close()


def join_deployment(bus_config, timeout: float = 30.0):
    """A session on the bus of an `fw deploy` started by the test (as the operator, with
    the credentials that deployment creates; waits for them to exist)."""
    import dataclasses

    from framework.bus import Bus, client_config
    from framework.keystore import OPERATOR, keystore_for

    store = keystore_for(bus_config.namespace)
    assert wait_until(lambda: store.private_key(OPERATOR).is_file(), timeout), "no keystore"
    secured = dataclasses.replace(bus_config, secure=True)
    return Bus(client_config(secured), subject=OPERATOR)


def writer_port(bus, key: str, kind, owner: str = "test"):
    """An output port of the test's own on `bus`, publishing on `key`, as a producer the
    test plays (a tracker, the Coordinator, the arm's controller) would."""
    from framework.ports import OutputPort

    port = OutputPort(key.rsplit("/", 1)[-1], kind)
    port.owner, port.bus = owner, bus
    port.connect(key)
    return port


def reader_port(bus, key: str, kind, size: int = 10000, owner: str = "test"):
    """An input port of the test's own on `bus`, keeping every sample of `key` (a buffer
    of `size`) for the test to read in order."""
    from framework.ports import InputPort

    port = InputPort(key.rsplit("/", 1)[-1], kind)
    port.owner, port.bus = owner, bus
    port.connect(key, {"type": "buffer", "size": size})
    return port


def drained(port) -> list:
    """Every sample waiting on an input port, oldest first (the port is left empty)."""
    from framework.ports import ReadStatus

    out = []
    while True:
        status, sample = port.read()
        if status is not ReadStatus.NEW:
            return out
        out.append(sample)


def decoded_into(into: list, kind):
    """A bus subscription callback that decodes each sample as `kind` into `into`."""
    from framework import messages

    def on(sample) -> None:
        message, _, _ = messages.decode(sample.payload.to_bytes(), kind)
        into.append(message)

    return on


def kernel_stamps_arrivals(timeout: float = 5.0) -> bool:
    """Wait until the kernel stamps UDP datagrams as they arrive (SO_TIMESTAMPNS).

    Linux turns its receive timestamps on for the whole host lazily, in deferred work
    queued when the first socket asks for them (net_enable_timestamp); a datagram that
    arrives before that work has run is stamped when it is read instead ("Race occurred
    between timestamp enabling and packet receiving", include/net/sock.h). On a busy
    host the work can lag a socket's configure by more than a test's setup, so a spec
    about arrival times waits for it first. False if it never came within `timeout`."""
    import socket as _socket
    import struct as _struct
    import time as _time

    receiver = _socket.socket(_socket.AF_INET, _socket.SOCK_DGRAM)
    sender = _socket.socket(_socket.AF_INET, _socket.SOCK_DGRAM)
    try:
        receiver.bind(("127.0.0.1", 0))
        receiver.setsockopt(_socket.SOL_SOCKET, getattr(_socket, "SO_TIMESTAMPNS", 35), 1)
        end = _time.monotonic() + timeout
        while _time.monotonic() < end:
            sent = _time.time()
            sender.sendto(b"?", receiver.getsockname())
            _time.sleep(0.02)
            _, ancillary, _, _ = receiver.recvmsg(16, 64)
            seconds, nanoseconds = _struct.unpack("ll", ancillary[0][2][:16])
            if seconds + nanoseconds * 1e-9 < sent + 0.01:  # stamped on arrival, not read
                return True
        return False
    finally:
        sender.close()
        receiver.close()


def wait_until(predicate, timeout: float = 5.0, interval: float = 0.005) -> bool:
    """Poll `predicate` until it holds or `timeout` passes (for asynchronous delivery;
    this bounds a wait, it does not assert on speed)."""
    import time as _time

    end = _time.monotonic() + timeout
    while _time.monotonic() < end:
        if predicate():
            return True
        _time.sleep(interval)
    return bool(predicate())


def check_scenarios(topology_file, scenarios) -> None:
    """Load every scenario against its topology's chart (events, states) and operations,
    as fw deploy does before anything starts; raises on the first wrong one."""
    from framework.scenario import load_scenario
    from framework.statechart.loader import load_statechart
    from framework.statechart.model import BUILTIN_EVENTS
    from framework.topology import load_topology

    topology = load_topology(topology_file)
    chart = load_statechart(topology.statechart)
    operations = {f"{n}.{op}" for n, c in topology.components.items() for op in c.info.operations}
    for path in scenarios:
        load_scenario(
            path,
            set(chart.events) | set(BUILTIN_EVENTS),
            operations,
            {s.path for s in chart.states.values()},
        )


SHARED_HOST_MARGIN = 3.0
"""How much longer than the shipped safety deadlines a scenario that tests the
procedure's behaviour, not the watches, gives producers on a shared CI host. The SEEG
topology's deadlines (50-200 ms) assume a computer the deployment has to itself; on 2
shared cores it needs ~1.7 of them, and a producer starved for 52-119 ms tripped a
fail-safe stop that the scenario then reported as the procedure's failure (CI, and
locally with one busy loop). The fault scenarios keep the shipped deadlines: they are
what prove the watches."""


def play_seeg_scenario(
    path, bus_config, tmp_path, history: list | None = None, margin: float = 1.0, record=None
) -> list:
    """Play a scenario on the SEEG deployment (real processes, a private bus); the
    outcomes that failed. `history` receives the Configurator's outcomes; `margin`
    stretches the safety deadlines (`SHARED_HOST_MARGIN`), the simulated KRC's FRI
    quality counter among them."""
    return play_scenario(
        REPO / "topologies" / "seeg.yaml", path, bus_config, tmp_path, history, margin, record
    )


def with_free_fri_port(topology):
    """`topology` with its FRI link (the KRC's `fri_remote`, the interface's
    `fri_listen`) on a free port: two deployments on one host never share it."""
    from framework.bus import free_udp_port

    port = free_udp_port()
    for component in topology.components.values():
        for prop in ("fri_remote", "fri_listen"):
            if prop in (component.info.properties if component.info else {}):
                component.properties[prop] = f"127.0.0.1:{port}"
    return topology


def with_deadlines_stretched(topology, margin: float):
    """`topology` with every safety deadline (watches, process heartbeats), every
    component's own command watchdog (a `watchdog_cycles` property, or the simulated
    KRC's FRI quality counter: `quality_top`, `quality_bad`, `quality_ok`)
    and reply timeout (a `timeout` property: the NDI driver's; `krc_timeout`: the FRI
    interface's wait for the KRC), and every tracker's
    staleness limit (`stale_periods` of a `sensors_file`, in a copy) x `margin` (a
    timeout no further than its property allows); the simulated KRC waits for every
    answer (`lockstep: always`), as it does on a host without real-time priority."""
    import dataclasses

    if margin == 1.0:
        return topology
    safety = topology.safety
    if safety is not None:
        watches = tuple(
            dataclasses.replace(w, deadline=w.deadline * margin) for w in safety.watches
        )
        topology.safety = dataclasses.replace(
            safety, watches=watches, process_deadline=safety.process_deadline * margin
        )
    for component in topology.components.values():
        for name in ("watchdog_cycles", "quality_top", "quality_bad", "quality_ok"):
            declared = component.info.properties.get(name)  # the KRC's FRI quality counter
            if declared is not None:
                cycles = component.properties.get(name, declared.default)
                component.properties[name] = round(cycles * margin)
        for name in ("timeout", "krc_timeout"):  # the NDI driver's; the FRI interface's
            declared = component.info.properties.get(name)
            if declared is not None:
                seconds = component.properties.get(name, declared.default) * margin
                component.properties[name] = min(seconds, declared.max or seconds)
        if "lockstep" in component.info.properties:  # the simulated KRC waits for every
            component.properties["lockstep"] = "always"  # answer: slows down, not brakes
        sensors = component.properties.get("sensors_file")
        if sensors:
            component.properties["sensors_file"] = _staleness_stretched(sensors, margin)
    return topology


def _staleness_stretched(path: str, margin: float) -> str:
    """A copy of the sensors file at `path` whose trackers are stale `margin` x later."""
    import yaml

    from components.domain.sensors import SensorConfig

    data = yaml.safe_load((REPO / path).read_text())  # topologies' paths: from the repository
    for sensor in data["sensors"].values():
        sensor["stale_periods"] = sensor.get("stale_periods", SensorConfig.stale_periods) * margin
    folder = tempfile.mkdtemp(prefix="fw-stretched-")
    atexit.register(shutil.rmtree, folder, True)
    copy = Path(folder) / Path(path).name
    copy.write_text(yaml.safe_dump(data))
    return str(copy)


def play_scenario(
    topology_file,
    path,
    bus_config,
    tmp_path,
    history: list | None = None,
    margin: float = 1.0,
    record=None,
) -> list:
    """Play a scenario on a deployment of `topology_file` (real processes, a private
    bus); the outcomes that failed. `history` receives the Configurator's outcomes;
    `margin` stretches the safety deadlines (`SHARED_HOST_MARGIN`); `record`: a path
    for its flight recording, made as `fw deploy --record` makes it."""
    from framework.deployer import Deployment
    from framework.scenario import load_scenario

    topology = private_topology(topology_file, bus_config, tmp_path)
    topology = with_deadlines_stretched(topology, margin)
    scenario = load_scenario(path)
    deployment = Deployment(topology, tmp_path / "logs", scenario=scenario)
    log = _ChartEvents()
    deployment.listeners.append(log)
    recorder = None
    deployment.start(run_chart=False)
    try:
        if record is not None:
            from framework.recorder import FlightRecorder

            recorder = FlightRecorder.of_topology(record, deployment.hub, topology)
        deployment.run_chart()
        assert deployment.runner.finished.wait(scenario.timeout + 30), "scenario never finished"
    finally:
        deployment.stop()
        if recorder is not None:
            recorder.close()
    if history is not None and deployment.configurator is not None:
        history.extend(deployment.configurator.history)
    failed = [o for o in deployment.runner.report() if not o.ok]
    if failed:  # what the chart was told, so a CI log says why it stopped
        from framework.scenario import Verdict

        failed.append(Verdict(False, "the chart's events", "; ".join(log.seen) or "none"))
    return failed


class _ChartEvents(Listener):
    """Collects the events a deployment's chart processes (configuration acknowledgements
    left out), with their payloads: the reasons behind a stop."""

    def __init__(self):
        self.seen: list[str] = []

    def on_event(self, event) -> None:
        if not event.name.startswith("config."):
            self.seen.append(f"{event.name} {event.payload}" if event.payload else event.name)


def interrupt(
    process, timeout: float = 60.0, sig: int | None = None
) -> tuple[str | None, str | None]:
    """Ctrl-C (SIGINT, or `sig`) a `fw` command run by a test and wait for it; its
    (stdout, stderr). One that does not stop in `timeout` is killed and fails the test
    with the end of its stderr (a bare TimeoutExpired told nothing, and hid the test's
    own failure)."""
    import signal
    import subprocess

    sig = signal.SIGINT if sig is None else sig
    process.send_signal(sig)
    try:
        return process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        _, err = process.communicate()
        tail = "\n".join((err or "").splitlines()[-30:])
        raise AssertionError(
            f"{' '.join(map(str, process.args[-6:]))}: not stopped {timeout:g} s after "
            f"{signal.Signals(sig).name}; its stderr ends:\n{tail}"
        ) from None


def explain(failed: list) -> str:
    """Failed scenario outcomes, one whole line each (pytest would cut a list's repr
    short, losing the detail a CI log needs)."""
    return "\n".join(f"{o.what}: {o.detail}" for o in failed)


def private_topology(path, bus_config, device_dir: Path | None = None):
    """A topology on the test's private bus and FRI port; with `device_dir`, a simulated
    Vicra's device node there instead of the shared path, so tests never share a pty."""
    import dataclasses

    from framework.topology import load_topology

    topology = with_free_fri_port(load_topology(path))
    topology.bus = dataclasses.replace(
        topology.bus, namespace=bus_config.namespace, hub_port=bus_config.hub_port
    )
    if device_dir is not None and "vicra_sim" in topology.components:
        link = str(device_dir / "ttyVICRA")
        topology.components["vicra_sim"].properties["link"] = link
        topology.components["vicra"].properties["device"] = link
    return topology


@pytest.fixture
def toy(bus_config):
    """The toy topology (tests/data/toy) on this test's private bus."""
    return private_topology(REPO / "tests" / "data" / "toy" / "toy.yaml", bus_config)


def _host_capabilities() -> str:
    """What this host lets a deployment have: cores, real-time priority, a raised nice
    level, the load when the suite ended (a CI log then says what its host allowed).
    Asked in a thread of its own, which ends with whatever it got."""
    import threading

    got: dict[str, str] = {}

    def ask() -> None:
        tid = threading.get_native_id()
        try:
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) - 1)
            got["nice"] = "yes"
        except OSError as exc:
            got["nice"] = f"no ({exc.strerror})"
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(1))
            got["fifo"] = "yes"
        except OSError as exc:
            got["fifo"] = f"no ({exc.strerror})"

    thread = threading.Thread(target=ask)
    thread.start()
    thread.join()
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    return (
        f"host: {os.cpu_count()} cores, SCHED_FIFO allowed: {got['fifo']}, "
        f"raise nice: {got['nice']}, load average {load}"
    )


def pytest_terminal_summary(terminalreporter) -> None:  # type: ignore[no-untyped-def]
    """End the run with what the host allowed (see `_host_capabilities`)."""
    terminalreporter.write_line(_host_capabilities())


# Tests that start a deployment's processes, a browser, network namespaces or the
# benchmarks: they run one at a time after the rest (`tools/test.sh`), as their
# processes watch each other's deadlines and a second test beside them on a 2-core host
# would starve them into safety stops that are correct but not what the test is about.
SERIAL = (
    "tests/bench/test_bench.py",
    "tests/docs/test_tutorial.py",
    "tests/topologies/",
    "tests/framework/console/",
    "tests/framework/test_cli_deploy.py",
    "tests/framework/test_deployer.py",
    "tests/framework/test_netns.py",
    "tests/framework/test_realtime.py",
    "tests/framework/test_scenario_links.py",
    "tests/framework/test_container.py",
    "tests/framework/ros2/test_bridge.py",
)


def pytest_configure(config) -> None:  # type: ignore[no-untyped-def]
    """Declare the `serial` marker (see `SERIAL`)."""
    config.addinivalue_line(
        "markers", "serial: starts real processes of a deployment; run alone (tools/test.sh)"
    )


def pytest_collection_modifyitems(config, items) -> None:  # type: ignore[no-untyped-def]
    """Mark the tests under `SERIAL` as `serial`."""
    for item in items:
        where = Path(str(item.fspath)).relative_to(REPO).as_posix()
        if where.startswith(SERIAL):
            item.add_marker(pytest.mark.serial)
