"""Spec: a topology deploys on real processes; the chart drives configurations that
really rewire data; failures are reported and handled; shutdown is orderly."""

import dataclasses
import json

import pytest

from framework.deployer import DeployError, Deployment
from framework.remote import RemoteComponent
from tests.conftest import wait_until


def active(deployment):
    return deployment.coordinator.active()


def settled_in(deployment, state):
    return wait_until(
        lambda: state in active(deployment)["active"] and not active(deployment)["pending"],
        timeout=10,
    )


def received(deployment):
    return RemoteComponent(deployment.hub, "supervisor").call("received")


def test_the_chart_sets_up_and_data_of_tracker_1_reaches_the_supervisor(deployed):
    assert settled_in(deployed, "Use_T1")
    assert wait_until(lambda: len(received(deployed)) >= 5)
    assert all(v > 0 for v in received(deployed)), "tracker 1 counts up"


def test_a_tracker_swap_rewires_live_and_only_new_data_arrives(deployed):
    assert settled_in(deployed, "Use_T1")
    deployed.send("e_SWAP")
    assert settled_in(deployed, "Use_T2")
    assert wait_until(lambda: len(received(deployed)) >= 5)
    after = received(deployed)  # the supervisor restarted during the swap
    assert all(v < 0 for v in after), "only tracker 2 after the swap"
    assert after == sorted(set(after), reverse=True), "no duplicate, no reordering"
    tags = [o.tag for o in deployed.configurator.history]
    assert tags == ["setup", "tracker_1_up", "tracker_2_up"]


def test_a_failing_operation_fails_the_configuration_and_the_chart_goes_where_it_says(deployed):
    assert settled_in(deployed, "Use_T1")
    deployed.send("e_SWAP")
    assert settled_in(deployed, "Use_T2")
    deployed.send("e_BREAK")
    assert settled_in(deployed, "Failed")
    outcome = deployed.configurator.history[-1]
    assert (outcome.tag, outcome.ok, outcome.step) == ("broken", False, "call supervisor.fail")
    assert "ValueError: asked to fail" in outcome.reason


def test_reapplying_a_configuration_is_harmless(deployed):
    assert settled_in(deployed, "Use_T1")
    first = deployed.configurator.apply("tracker_1_up")
    again = deployed.configurator.apply("tracker_1_up")
    assert first.ok and again.ok
    assert settled_in(deployed, "Use_T1")
    assert wait_until(lambda: len(received(deployed)) >= 3)
    assert all(v > 0 for v in received(deployed))


def test_an_unknown_tag_is_answered_with_a_failure(deployed):
    outcome = deployed.configurator.apply("tracker_9_up")
    assert not outcome.ok and "unknown configuration 'tracker_9_up'" in outcome.reason


def test_an_operator_command_is_answered_accepted_or_refused_with_the_reason(deployed):
    assert settled_in(deployed, "Use_T1")
    coordinator = RemoteComponent(deployed.hub, "coordinator")
    assert coordinator.call("takeable", events=["e_SWAP", "e_BREAK"]) == ["e_SWAP"]
    refused = coordinator.call("offer", event="e_BREAK", origin="console@test")
    assert refused == {"accepted": False, "reason": "e_BREAK is not taken in Use_T1"}
    assert coordinator.call("offer", event="e_SWAP", origin="console@test")["accepted"]
    assert settled_in(deployed, "Use_T2")
    assert coordinator.call("takeable", events=["e_SWAP", "e_BREAK"]) == ["e_SWAP", "e_BREAK"]


def test_a_process_that_dies_gives_a_clear_deploy_error(toy, tmp_path):
    toy.components["t2"] = dataclasses.replace(
        toy.components["t2"], class_path="tests.support.components:Broken"
    )
    with pytest.raises(
        DeployError,
        match=r"process 'trackers' exited with code 1: "
        r".*RuntimeError: the device driver is missing",
    ):
        Deployment(toy, tmp_path).start()


def test_a_process_that_never_comes_up_is_named(toy, tmp_path):
    toy.components["supervisor"] = dataclasses.replace(
        toy.components["supervisor"], class_path="tests.support.components:Sleepy"
    )
    deployment = Deployment(toy, tmp_path, liveliness_timeout=2.0)
    with pytest.raises(
        DeployError,
        match=r"not alive after 2 s: supervisor "
        r"\(process control_side\)",
    ):
        deployment.start()
    assert all(p.popen.poll() is not None for p in deployment.processes), "nothing left behind"


def test_a_failing_step_rolls_back_the_connections_and_properties_it_changed(deployed, toy):
    from framework.topology import Step

    assert settled_in(deployed, "Use_T1")
    configurator = deployed.configurator
    before = dict(configurator.wiring)
    outcome = configurator._run(
        "partial",
        [
            Step("connect", "supervisor", "inp", key="t2/out", policy={"type": "data"}),
            Step("call", "supervisor", "fail"),
        ],
    )
    assert not outcome.ok and outcome.step == "call supervisor.fail"
    assert outcome.rolled_back == 1
    assert configurator.wiring == before
    info = RemoteComponent(deployed.hub, "supervisor").describe()
    assert info["inputs"][0]["key"] == "t1/out", "the supervisor reads tracker 1 again"


def test_a_scenario_plays_timed_events_and_calls(toy, tmp_path, write):
    from framework.scenario import load_scenario

    path = write(
        """
        scenario: swap
        steps:
          - {at: 0.2s, call: supervisor.received}
          - {at: 0.5s, send: e_SWAP}
          - {when: Use_T2, check: supervisor.stats, expect: {dropped_invalid: 0}}
        expect:
          - {state: Use_T2, within: 10s}
          - {never_event: e_BREAK}
        """,
        "scenario.yaml",
    )
    scenario = load_scenario(
        path, {"e_SWAP", "e_BREAK"}, {"supervisor.received", "supervisor.stats"}
    )
    assert [s.at for s in scenario.steps] == [0.2, 0.5, None], "played in file order"
    reports = []
    deployment = Deployment(toy, tmp_path, scenario=scenario, report=reports.append)
    deployment.start()
    try:
        assert settled_in(deployment, "Use_T2"), "the scenario's e_SWAP arrived by itself"
        assert any("send e_SWAP" in r for r in reports)
        assert any("call supervisor.received" in r for r in reports)
        assert deployment.runner.finished.wait(10), "every step played, expectations met"
    finally:
        deployment.stop()
    outcomes = deployment.runner.report()
    assert [o.ok for o in outcomes] == [True, True, True], outcomes


def test_a_bad_scenario_is_refused_with_located_errors(write):
    from framework.errors import FindingsError
    from framework.scenario import load_scenario

    path = write(
        "scenario: s\nsteps:\n  - {at: 1s, send: e_SWP}\n  - {at: 2s, call: x.y}\n", "bad.yaml"
    )
    with pytest.raises(FindingsError) as err:
        load_scenario(path, {"e_SWAP"}, {"supervisor.received"})
    lines = [f.one_line() for f in err.value.findings]
    assert lines[0].startswith(f"{path}:3:5: steps[0]: error[unknown-event]")
    assert "no operation 'x.y'" in lines[1]
    bad = write("scenario: s\nsteps:\n  - {at: soon, send: e_SWAP}\n", "bad2.yaml")
    with pytest.raises(FindingsError, match="schema"):
        load_scenario(bad)


def test_a_fault_step_names_a_known_process_and_a_hang_says_how_long(write):
    from framework.errors import FindingsError
    from framework.scenario import load_scenario

    path = write(
        "scenario: s\nsteps:\n"
        "  - {at: 1s, fault: {process: trackrs, signal: KILL}}\n"
        "  - {at: 2s, fault: {process: trackers, signal: STOP}}\n"
        "  - {at: 3s, fault: {process: trackers, signal: KILL, for: 1s}}\n",
        "faults.yaml",
    )
    with pytest.raises(FindingsError) as err:
        load_scenario(path, processes={"trackers", "control_side"})
    lines = [f.one_line() for f in err.value.findings]
    assert "error[unknown-process]: the topology has no process 'trackrs'" in lines[0]
    assert "a STOP needs `for`" in lines[1] and ":4:" in lines[1]
    assert "`for` is how long a STOP hangs" in lines[2]
    bad = write("scenario: s\nsteps:\n  - {at: 1s, fault: {process: x, signal: HUP}}\n", "b.yaml")
    with pytest.raises(FindingsError, match="schema"):
        load_scenario(bad)


def listening(pid):
    """The (address, port) TCP sockets process `pid` listens on (from /proc)."""
    import os
    import socket
    import struct
    from pathlib import Path

    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[3] == "0A" and fields[9] in inodes:  # LISTEN
            address, port = fields[1].split(":")
            ip = socket.inet_ntoa(struct.pack("<I", int(address, 16)))
            found.add((ip, int(port, 16)))
    return found


def test_processes_placed_on_another_host_are_started_by_that_hosts_deploy(toy, tmp_path):
    """Another host's processes listen on its own address (here 127.0.0.2 stands for
    it), with certificates that name it; the chart runs across both."""
    import threading

    toy.processes["trackers"] = {"host": "trackhost"}
    toy.hosts = {"trackhost": "127.0.0.2"}
    control = Deployment(toy, tmp_path / "control")
    failure = []
    thread = threading.Thread(target=lambda: _start(control, failure))
    thread.start()
    other = Deployment(toy, tmp_path / "other", host="trackhost")
    assert wait_until(lambda: control.hub is not None, timeout=10)
    other.start()
    try:
        assert [p.name for p in other.processes] == ["trackers"] and other.coordinator is None
        thread.join(40)
        assert not failure, failure
        assert [p.name for p in control.processes] == ["control_side"]
        assert settled_in(control, "Use_T1"), "the chart runs across both hosts' processes"
        assert {ip for ip, _ in listening(other.processes[0].popen.pid)} == {"127.0.0.2"}
        assert {ip for ip, _ in listening(control.processes[0].popen.pid)} == {"127.0.0.1"}
    finally:
        control.stop()
        other.stop()


def _start(deployment, failure):
    try:
        deployment.start()
    except Exception as exc:  # reported by the test
        failure.append(exc)


def test_scenario_invariants_are_sampled_and_a_violation_fails(toy, tmp_path, write):
    from framework.scenario import load_scenario

    path = write(
        """
        scenario: invariants
        steps:
          - {at: 0.3s, send: e_SWAP}
        invariants:
          - {while: Use_T2, check: supervisor.stats, expect: {dropped_invalid: 0}}
          - {while: Use_T2, check: supervisor.stats, max: {received: -1}}
          - {while: Nowhere_Yet, check: supervisor.stats, expect: {received: 0}}
        end: Use_T2
        """,
        "invariants.yaml",
    )
    scenario = load_scenario(path)
    scenario.steps.append(  # stay in Use_T2 a little so the invariants get sampled
        dataclasses.replace(scenario.steps[0], at=1.0, send="", check="supervisor.stats")
    )
    deployment = Deployment(toy, tmp_path, scenario=scenario)
    deployment.start()
    try:
        assert deployment.runner.finished.wait(10)
    finally:
        deployment.stop()
    ok, violated, unexercised = deployment.runner.report()[-3:]
    assert ok.ok and "samples" in ok.detail
    assert not violated.ok and "violated at" in violated.detail and "received=" in violated.detail
    assert unexercised.ok and not unexercised.exercised
    assert unexercised.detail == "Nowhere_Yet was never active: nothing checked"
    assert ok.exercised and violated.exercised


def test_a_configuration_that_comes_after_its_deadline_is_refused_unapplied(deployed):
    """The chart gave up on it already (its configuration timeout passed): applying it
    late could undo what the chart did since, so the Configurator refuses it."""
    import time

    from framework.messages import ConfigRequest

    assert settled_in(deployed, "Use_T1")
    before = dict(deployed.configurator.wiring)
    outcome = deployed.configurator._serve(
        ConfigRequest(time.time() - 3.0, 99, "tracker_2_up", {}, time.time() - 1.0)
    )
    assert not outcome.ok and outcome.step == "deadline"
    assert "refused, not run" in outcome.reason
    assert deployed.configurator.wiring == before
    assert all(v > 0 for v in received(deployed)), "still tracker 1"


def test_a_lost_process_is_a_chart_event_and_a_deployer_incident(deployed):
    import os
    import signal

    assert settled_in(deployed, "Use_T1")
    trackers = next(p for p in deployed.processes if p.name == "trackers")
    os.kill(trackers.popen.pid, signal.SIGKILL)
    assert wait_until(lambda: set(deployed.coordinator.lost) == {"t1", "t2"}, timeout=10)
    assert deployed.coordinator.lost == {"t1": "trackers", "t2": "trackers"}
    assert wait_until(lambda: "trackers" in deployed.watch.lost, timeout=10)
    assert "killed by signal 9" in deployed.watch.lost["trackers"]
    assert any("process trackers process lost" in i for i in deployed.watch.incidents)
    assert "trackers" not in [p.name for p in deployed.processes if p.popen.poll() is None]


def test_a_process_marked_restart_comes_back_as_it_was(toy, tmp_path):
    """on_loss: restart: the process is started again, its components brought back to
    their states and to the wiring the configurations had made (here the supervisor
    reads tracker 2 after a swap, which is not the topology's initial wiring)."""
    import os
    import signal

    toy.processes["control_side"]["on_loss"] = "restart"
    deployment = Deployment(toy, tmp_path)
    deployment.start()
    try:
        assert settled_in(deployment, "Use_T1")
        deployment.send("e_SWAP")
        assert settled_in(deployment, "Use_T2")
        side = next(p for p in deployment.processes if p.name == "control_side")
        os.kill(side.popen.pid, signal.SIGKILL)
        assert wait_until(
            lambda: any("restarted" in i for i in deployment.watch.incidents), timeout=30
        ), deployment.watch.incidents
        assert "control_side" not in deployment.watch.lost
        assert wait_until(lambda: "supervisor" not in deployment.coordinator.lost)
        supervisor = RemoteComponent(deployment.hub, "supervisor")
        assert supervisor.state() == "Running"
        assert wait_until(lambda: len(received(deployment)) >= 3)
        assert all(v < 0 for v in received(deployment)), "tracker 2, as before the loss"
    finally:
        deployment.stop()


def test_a_restart_waits_until_the_lost_process_has_left_the_bus_and_tries_again(toy, tmp_path):
    """The exit of a process can be seen before the bus drops its liveliness: a restart
    must not take the old tokens for the new process's. Here a token outlives the process
    on purpose: nothing is spawned while it lingers, the attempt fails naming it, and the
    next attempt, once it is gone, brings the process back."""
    import os
    import signal

    from framework import keys

    toy.processes["control_side"]["on_loss"] = "restart"
    deployment = Deployment(toy, tmp_path)
    deployment.start()
    try:
        assert settled_in(deployment, "Use_T1")
        deployment.liveliness_timeout = 5.0
        lingering = deployment.hub.token(keys.alive("supervisor"))
        side = next(p for p in deployment.processes if p.name == "control_side")
        dead = side.popen
        os.kill(dead.pid, signal.SIGKILL)
        assert wait_until(
            lambda: any("attempt 1 of 3" in i for i in deployment.watch.incidents), timeout=30
        ), deployment.watch.incidents
        failed = next(i for i in deployment.watch.incidents if "attempt 1 of 3" in i)
        assert "still alive" in failed and "supervisor" in failed
        assert side.popen is dead, "spawned while the lost process was still on the bus"
        lingering.undeclare()
        assert wait_until(
            lambda: any("restarted" in i for i in deployment.watch.incidents), timeout=30
        ), deployment.watch.incidents
        assert RemoteComponent(deployment.hub, "supervisor").state() == "Running"
    finally:
        deployment.stop()


def test_an_event_a_scenario_says_must_never_come_is_reported_with_its_reason(write):
    """A failed `never_event` says when the event came and what it carried (an e_STOP's
    reason is what one needs to look at a run that failed once)."""
    from framework.scenario import ScenarioRunner, load_scenario
    from framework.statechart.events import Event

    path = write(
        "scenario: s\nsteps:\n  - {at: 0s, send: e_GO}\nexpect:\n  - {never_event: e_STOP}\n",
        "never.yaml",
    )
    runner = ScenarioRunner(load_scenario(path), lambda *a: None, lambda *a: None)
    runner.on_event(Event("e_GO"))
    runner.on_event(Event("e_STOP", {"reason": "protective stop: a person 30 cm away"}))
    outcome = runner.report()[-1]
    assert not outcome.ok and outcome.what == "never event e_STOP"
    assert "protective stop: a person 30 cm away" in outcome.detail


def test_the_control_loops_processes_run_ahead_of_the_rest():
    """The robot side (the monitor's process and the arm's KRC, both device loops) gets
    three times the others' share of a busy CPU, and its loops a real-time priority;
    every process runs ahead of the host's."""
    from framework.deployer import CONTROL_NICE, SAFETY_NICE, container_spec
    from framework.topology import load_topology
    from tests.conftest import REPO

    seeg = load_topology(REPO / "topologies" / "seeg.yaml")
    processes = sorted({c.process for c in seeg.components.values()})
    nice = {p: container_spec(seeg, p)["nice"] for p in processes}
    assert {p for p, n in nice.items() if n == CONTROL_NICE} == {"robot", "arm"}
    assert all(n == SAFETY_NICE for p, n in nice.items() if p not in ("robot", "arm"))
    assert CONTROL_NICE < SAFETY_NICE < 0
    realtime = {p for p in processes if container_spec(seeg, p).get("realtime")}
    assert realtime == {"robot", "arm"}
    demo = load_topology(REPO / "topologies" / "demo.yaml")
    assert "nice" not in container_spec(demo, "robot"), "no safety monitor: the host's own"


def test_on_several_hosts_each_process_keeps_its_links_to_the_ones_before_it():
    """A deployment on several hosts gives each process a port of its own on its host's
    address, and each connects itself to every process before it (by name): every pair
    of processes has a side that makes their link again after a partition, which
    gossip alone did not (docs/hosts.md). Only one side: the hub links to nobody itself
    (with links made from both sides, Zenoh left routes unmade after most heals,
    tools/zenoh_partition.py). On one host nothing is fixed."""
    from framework.bus import BusConfig, zenoh_config
    from framework.deployer import container_spec
    from framework.topology import load_topology
    from tests.conftest import REPO

    hosts = load_topology(REPO / "topologies" / "seeg_hosts.yaml")
    buses = {
        p: BusConfig.from_dict(container_spec(hosts, p)["bus"])
        for p in ("arm", "cameras", "robot", "supervision", "trackers", "vicra_device")
    }
    ports = {p: b.listen_port for p, b in buses.items()}
    assert len(set(ports.values())) == len(ports) and hosts.bus.hub_port not in ports.values()
    assert buses["robot"].listen == "10.77.0.4" and buses["arm"].listen == "10.78.0.2"
    assert buses["arm"].peers == (), "the first by name connects to the hub only"
    assert buses["robot"].peers == (
        f"tcp/10.78.0.2:{ports['arm']}",
        f"tcp/10.77.0.3:{ports['cameras']}",
    )
    assert len(buses["vicra_device"].peers) == 5
    config = zenoh_config(dataclasses.replace(buses["robot"], secure=False))
    assert f"tcp/10.77.0.4:{ports['robot']}" in config.get_json("listen/endpoints")
    connect = config.get_json("connect/endpoints")
    assert hosts.bus.hub_endpoint in connect and buses["robot"].peers[1] in connect
    retry = json.loads(config.get_json("connect/retry"))
    assert retry["period_max_ms"] <= 1000, "a link lost to a partition is tried every second"
    hub = zenoh_config(dataclasses.replace(hosts.bus, secure=False), hub=True)
    assert json.loads(hub.get_json("connect/endpoints")) == [], "the hub links to nobody"
    one = load_topology(REPO / "topologies" / "seeg.yaml")
    bus = BusConfig.from_dict(container_spec(one, "robot")["bus"])
    assert (bus.listen_port, bus.peers) == (0, ()), "one host: any free port, gossip"


def test_components_that_never_came_up_are_named_by_host_with_the_command_that_starts_it():
    """On several machines the usual cause is a host whose part was never started:
    the error names each such host, its processes and the command to run there."""
    from framework.deployer import not_up
    from framework.topology import load_topology
    from tests.conftest import REPO

    hosts = load_topology(REPO / "topologies" / "seeg_hosts.yaml")
    said = not_up(hosts, ["kinect_0", "people_detector", "robot"])
    assert "kinect_0, people_detector (process cameras on host 'cameras'" in said
    assert f"fw deploy {hosts.file} --keys DIR --host cameras" in said
    assert "robot (process robot on host 'robot'" in said
    assert not_up(hosts, ["robot"], host="robot") == "robot (process robot)", "its own: no hint"


def test_a_process_on_another_host_measures_the_clocks_of_the_hosts_it_depends_on():
    """On several hosts a process measures the clock of every host whose samples it
    reads (their stamps are that clock's) and of the control host (the Configurator's
    and the Coordinator's deadlines are on its clock); on one host, none."""
    from framework.deployer import container_spec
    from framework.topology import load_topology
    from tests.conftest import REPO

    hosts = load_topology(REPO / "topologies" / "seeg_hosts.yaml")
    supervision = container_spec(hosts, "supervision")
    assert supervision["peer_clocks"] == {
        "tracking": "trackers",
        "cameras": "cameras",
        "local": "control",
    }, "its own host (robot) has no offset"
    assert supervision["key_hosts"]["certus/calibration_tool_optical"] == "tracking"
    assert supervision["requester_host"] == "local"
    assert container_spec(hosts, "arm")["peer_clocks"] == {"local": "control"}
    one = load_topology(REPO / "topologies" / "seeg.yaml")
    spec = container_spec(one, "supervision")
    assert "peer_clocks" not in spec and "requester_host" not in spec


def test_on_several_hosts_each_pair_of_processes_has_one_side_that_links_and_a_reopen_links_all():
    """`mesh`/`process_bus`: each process connects to those before it by name (one side
    per pair makes the link again after a partition), and knows every other's endpoint
    for a reopened session, which listens on a port of its own (framework/bus.py)."""
    from framework.deployer import mesh, process_bus
    from framework.topology import load_topology
    from tests.conftest import REPO

    topology = load_topology(REPO / "topologies" / "seeg_hosts.yaml")
    places = mesh(topology)
    endpoint = {n: f"{topology.bus.protocol}/{a}:{p}" for n, (a, p) in places.items()}
    buses = {n: process_bus(topology, n) for n in places}
    for name, bus in buses.items():
        assert bus.listen_port == places[name][1]
        assert set(bus.others) == {endpoint[n] for n in places if n != name}
    for a in places:
        for b in places:
            if a < b:
                sides = (endpoint[a] in buses[b].peers) + (endpoint[b] in buses[a].peers)
                assert sides == 1, f"{a} and {b}: {sides} sides link"
