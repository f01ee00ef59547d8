"""Spec: containers in real processes: remote control, rewiring under load, liveliness,
orderly shutdown, and clear errors for every bad request."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from components.demo import Sink
from framework import keys
from framework.activity import Activity
from framework.bus import BusError
from framework.component import FileInput
from framework.container import Container
from framework.container_main import spawn_container
from framework.errors import FwError
from framework.messages import Scalar
from framework.properties import prop
from framework.remote import RemoteComponent, RemoteError
from tests.conftest import wait_until


def spec(bus_config, name, components):
    return {"name": name, "bus": bus_config.to_dict(), "components": components}


@pytest.fixture
def process(bus_config, hub):
    """Start container processes; kill any left at the end."""
    started = []

    def start(name, components):
        proc = spawn_container(
            spec(bus_config, name, components), stderr=subprocess.PIPE, stdout=subprocess.DEVNULL
        )
        started.append(proc)
        names = [c["name"] for c in components]
        ok = wait_until(
            lambda: all(keys.alive(n) in hub.alive(keys.ALL_ALIVE, 0.5) for n in names), timeout=20
        )
        assert ok, proc.stderr.read().decode() if proc.poll() is not None else "no liveliness"
        return proc

    yield start
    for proc in started:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)


def counter(name, step=1.0, rate=100, run=True):
    return {
        "name": name,
        "class": "components.demo:Counter",
        "activity": {"periodic": rate},
        "properties": {"step": step},
        "configure": run,
        "start": run,
    }


@pytest.fixture
def sink(hub):
    container = Container("local", hub)
    component = container.add(Sink("snk"), Activity.event("inp"))
    container.start()
    component.start()
    yield container, component
    container.shutdown()


def test_remote_lifecycle_properties_and_operations(process, hub):
    process("c1", [counter("cnt", run=False)])
    remote = RemoteComponent(hub, "cnt")
    assert remote.state() == "PreOperational"
    assert remote.set("step", 3) == 3.0
    assert remote.configure() == {"ok": True, "state": "Stopped", "reason": ""}
    assert remote.call("reset", to=10) == 10.0
    info = remote.describe()
    assert info["container"] == "c1" and info["outputs"][0]["keys"] == ["cnt/out"]


def test_bad_requests_get_clear_errors_and_the_container_survives(process, hub):
    process("c1", [counter("cnt", run=False)])
    remote = RemoteComponent(hub, "cnt")
    cases = [
        (lambda: remote.start(), "cannot start 'cnt' in state PreOperational"),
        (lambda: remote.set("step", "fast"), "expects float, got str"),
        (lambda: remote.set("speed", 1), "has no property 'speed'"),
        (lambda: remote.connect("inn", "x"), "has no port 'inn'"),
        (lambda: remote.call("jump"), "has no operation 'jump'"),
        (lambda: remote.call("reset", too=1), "unexpected keyword argument 'too'"),
        (lambda: remote.request("dance"), "unknown request 'dance'"),
        (
            lambda: RemoteComponent(hub, "ghost", 0.3).state(),
            "no answer from component 'ghost'",
        ),
    ]
    for call, message in cases:
        with pytest.raises(RemoteError, match=message):
            call()
    assert remote.state() == "PreOperational"


def test_type_mismatch_on_connect_is_refused_naming_both_types(process, hub, sink):
    process("c1", [counter("cnt")])
    container, _ = sink
    with pytest.raises(
        Exception, match=r"snk\.pose \(Pose\).*carries Scalar \(written by cnt\.out\)"
    ):
        container.connect("snk", "pose", "cnt/out")


def test_an_operation_timeout_is_reported(hub, sink):
    with pytest.raises(RemoteError, match="operation 'slow' of component 'snk' timed out after"):
        RemoteComponent(hub, "snk").call("slow", timeout=0.2, seconds=2.0)


def test_rewiring_at_100hz_loses_nothing_and_mixes_nothing(process, hub, sink):
    # a counts up from 1, b counts down from -1, both at 100 Hz in another process
    process("c1", [counter("a", 1.0), counter("b", -1.0)])
    container, component = sink
    container.connect("snk", "inp", "a/out", {"type": "buffer", "size": 1000})
    assert wait_until(lambda: len(component.call("received")) >= 10)
    container.connect("snk", "inp", "b/out", {"type": "buffer", "size": 1000})
    switched = len(component.call("received"))
    assert wait_until(lambda: len(component.call("received")) >= switched + 20)
    after = component.call("received")[switched:]
    assert all(v < 0 for v in after), "no sample of the old key after the switch"
    assert after == sorted(set(after), reverse=True), "no duplicate, no reordering"
    steps = [after[i] - after[i + 1] for i in range(len(after) - 1)]
    assert set(steps) == {1.0}, "no sample lost on the new key"


def test_a_new_connection_gets_the_latest_value_without_waiting_for_a_write(process, hub, sink):
    proc = process("c1", [counter("once", 5.0, run=False)])
    remote = RemoteComponent(hub, "once")
    remote.configure()
    remote.start()
    assert wait_until(lambda: remote.describe()["outputs"][0]["stats"]["written"] >= 1)
    remote.stop()  # the counter is silent from now on
    container, component = sink
    container.connect("snk", "inp", "once/out")
    assert wait_until(lambda: len(component.call("received")) == 1)
    assert proc.poll() is None


def test_a_killed_process_is_seen_through_liveliness(process, hub):
    proc = process("c1", [counter("victim", run=False)])
    events = []
    watcher = hub.watch(keys.ALL_ALIVE, lambda key, alive: events.append((key, alive)))
    assert wait_until(lambda: ("fw/alive/victim", True) in events)
    os.kill(proc.pid, signal.SIGKILL)
    assert wait_until(lambda: ("fw/alive/victim", False) in events, timeout=10)
    watcher.undeclare()


def test_sigterm_shuts_down_in_order_and_exits_cleanly(process, hub):
    proc = process("c1", [counter("polite")])
    states = []
    sub = hub.subscribe(keys.state("polite"), lambda s: states.append(bytes(s.payload.to_bytes())))
    assert wait_until(lambda: any(b"Running" in s for s in states)), "subscription routed"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(20) == 0
    assert keys.alive("polite") not in hub.alive(keys.ALL_ALIVE, 0.5)
    assert any(b"Stopped" in s for s in states) and any(b"PreOperational" in s for s in states)
    sub.undeclare()


def test_a_bad_spec_fails_the_process_with_a_clear_message(bus_config):
    bad = spec(bus_config, "c1", [{"name": "x", "class": "components.demo:Nope"}])
    proc = spawn_container(bad, stderr=subprocess.PIPE)
    assert proc.wait(30) == 1
    err = proc.stderr.read().decode()
    assert "is not a Component class" in err and "Traceback" not in err


def test_a_request_that_comes_after_its_deadline_is_refused_not_run(process, hub):
    """The process hangs (SIGSTOP) while a request waits for it: after SIGCONT the
    request is delivered, past its deadline, and refused; the property never changes.
    (Without deadlines, requests queued during a hang ran after it.)"""
    proc = process("c1", [counter("cnt", step=1.0, run=False)])
    remote = RemoteComponent(hub, "cnt")
    assert remote.get("step") == 1.0
    os.kill(proc.pid, signal.SIGSTOP)
    try:
        with pytest.raises(RemoteError, match=r"no answer|timed out"):
            remote.request("set", timeout=0.3, property="step", value=7.0)
    finally:
        os.kill(proc.pid, signal.SIGCONT)
    assert wait_until(lambda: remote.get("step") is not None)
    assert remote.get("step") == 1.0, "the late request did not run"
    # a deadline in 1970, long past, asked on the bus itself: a RemoteComponent gives up
    # at the deadline, and the refusal must not have to come back within a millisecond
    late = {"op": "set", "property": "step", "value": 7.0, "deadline": 1.0}
    with pytest.raises(BusError, match="refused, not run: its deadline passed"):
        hub.query(keys.control_request("cnt", "set", ""), json.dumps(late).encode(), 10.0)
    assert remote.get("step") == 1.0


def requester_apart(container, offset):
    """The container's requests come from the control host (`local`), whose clock is
    `offset` s ahead of this one as measured by a 1 ms round trip (None: not yet)."""
    from tests.support.peer_clock import from_host_apart

    from_host_apart(container, "local", "control", offset)
    container.requester_host = "local"


@pytest.mark.parametrize(
    ("offset", "deadline_in", "runs"),
    [
        (1.0, -0.5, False),  # ahead: its deadline passed 0.5 s ago, here 0.5 s to come
        (-1.0, 0.5, True),  # behind: 0.5 s to go, though here 0.5 s passed
        (None, 60.0, False),  # not measured: it cannot be timed
    ],
    ids=["requester ahead", "requester behind", "requester unmeasured"],
)
def test_a_requests_deadline_is_judged_on_the_requesters_clock(hub, offset, deadline_in, runs):
    """The Configurator's deadlines are its host's wall clock. A control PC whose clock
    runs 1 s ahead of this one sets deadlines that look 1 s later here: judged on this
    clock, a request it gave up on would still run. By the control host's measured
    offset it is refused; one behind is not refused early; an unmeasured one is not
    run at all."""
    import time

    from components.demo import Counter

    container = Container("local", hub)
    component = container.add(Counter("counter"))
    container.start()
    requester_apart(container, offset)
    try:
        deadline = time.time() + (offset or 0.0) + deadline_in  # on the requester's clock
        request = {"op": "set", "property": "step", "value": 3.0, "deadline": deadline}
        if runs:
            container.requests.handle(component, request)
            assert component.get_property("step") == 3.0
        else:
            with pytest.raises(FwError, match=r"deadline passed|cannot be timed"):
                container.requests.handle(component, request)
            assert component.get_property("step") == 1.0, "the late request did not run"
    finally:
        container.shutdown()


def test_a_batch_stops_at_the_first_step_that_would_start_late(hub):
    """Steps on one component run in turn; the first that would start after the batch's
    deadline is refused with its reason, and the rest are not run."""
    import time

    from framework.component import Component, operation
    from framework.properties import prop

    class Slow(Component):
        needs_configuration = False
        mark = prop(float, 0.0)

        @operation
        def nap(self, seconds: float) -> None:
            time.sleep(seconds)

    container = Container("local", hub)
    component = container.add(Slow("slow"))
    container.start()
    try:
        answer = container.requests.handle(
            component,
            {
                "op": "batch",
                "deadline": time.time() + 0.1,
                "steps": [
                    {"op": "call", "operation": "nap", "args": {"seconds": 0.2}},
                    {"op": "set", "property": "mark", "value": 9.0},
                ],
            },
        )
        assert answer["failed"] == 1 and "deadline passed" in answer["error"]
        assert component.get_property("mark") == 0.0, "the late step did not run"
    finally:
        container.shutdown()


class PerLine(Sink):
    """A component with an input port per line of its file (as the Sensor Manager has
    one per tracker of its sensors file)."""

    lines_file = prop(str, "", doc="a name per line")

    @classmethod
    def file_inputs(cls, properties):
        path = Path(str(properties.get("lines_file", "")))
        if not path.is_file():
            raise FwError(f"{path}: no such file")
        return [FileInput(n, Scalar, str(path)) for n in path.read_text().split()]

    def configure_hook(self):
        try:
            self.file_ports()
        except FwError as exc:
            self.last_error = str(exc)
            return False
        return True


def test_a_port_a_file_declares_is_wired_even_when_the_file_comes_late(hub, tmp_path):
    """An unreadable file fails configure, not the deployment: the topology's connection
    of its port waits, and is made once configure reads the file."""
    lines = tmp_path / "lines.txt"
    container = Container("c", hub)
    try:
        component = container.add(PerLine("per_line"), properties={"lines_file": str(lines)})
        answer = container.connect("per_line", "left", "x/left")
        assert "no such file" in answer["awaiting"]
        assert not component.configure() and "no such file" in component.last_error
        lines.write_text("left right\n")
        assert component.configure(), component.last_error
        assert component.inputs["left"].key == "x/left"
        assert not component.inputs["right"].connected
        with pytest.raises(Exception, match="has no port 'middle'"):
            container.connect("per_line", "middle", "x/middle")
    finally:
        container.shutdown()


def test_a_process_that_hears_a_linked_peer_no_more_reopens_its_bus_and_keeps_serving(
    process, hub, sink
):
    """framework/routes.py on a real process: the test's session plays a process whose
    probes stop reaching the container while the two stay linked (the routes Zenoh
    leaves unmade after a partition). The container reopens its bus; its component
    still runs, publishes, answers and never looks lost."""
    proc = process("c1", [counter("steady", rate=50)])
    seen: list[tuple[str, bool]] = []
    watcher = hub.watch(keys.ALL_ALIVE, lambda key, alive: seen.append((key, alive)))
    probes: list[dict] = []
    listener = hub.subscribe(
        keys.route_probe("c1"), lambda s: probes.append(json.loads(s.payload.to_bytes())), False
    )
    publisher = hub.publisher(keys.route_probe("peer"), cache=False)
    for n in range(1, 6):  # heard, then silent: still linked, still answering
        publisher.put(json.dumps({"zid": hub.zid(), "n": n, "reopened": 0}))
        time.sleep(0.4)
    assert wait_until(lambda: probes and probes[-1]["reopened"] >= 1, timeout=30), (
        "the container never reopened its bus"
    )
    container, component = sink
    container.connect("snk", "inp", "steady/out")
    assert wait_until(lambda: len(component.call("received")) >= 5, timeout=10)
    assert RemoteComponent(hub, "steady").state() == "Running"
    assert ("fw/alive/steady", False) not in seen
    assert proc.poll() is None
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(20) == 0
    assert "routes lost: heard nothing from peer" in proc.stderr.read().decode()
    for declared in (watcher, listener, publisher):
        declared.undeclare()
