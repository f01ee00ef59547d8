"""Spec: a deployment admits only its own processes and its operator. A Zenoh session
without the deployment's credentials reads nothing, puts nothing, and none of its
queries are answered; events are checked where they enter the Coordinator (who may
send which event, with which payload), and every refusal is on the status stream,
hence in the flight recording."""

import dataclasses
import os
import stat
import time

import pytest
import zenoh

from framework import keys, messages
from framework.bus import Bus, BusError
from framework.coordinator import EVENTS_KEY, STATUS_KEY, Admission
from framework.keystore import OPERATOR, create_keystore, keystore_for
from framework.messages import ConfigAck, ConfigRequest, EventMessage, Scalar
from tests.conftest import wait_until


def leaves(deployment):
    return deployment.coordinator.active()["active"]


def plain_session(port: int, namespace: str) -> zenoh.Session:
    """What any local process could open: no fw code, no credentials."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
    config.insert_json5("namespace", f'"{namespace}"')
    return zenoh.open(config)


def test_the_keystore_is_private_and_holds_one_certificate_per_process(deployed):
    store = keystore_for(deployed.topology.bus.namespace)
    assert stat.S_IMODE(os.stat(store.root).st_mode) == 0o700
    assert store.subjects() == ["control", "control_side", "operator", "trackers"]
    for subject in store.subjects():
        assert stat.S_IMODE(os.stat(store.private_key(subject)).st_mode) == 0o600
    assert not list(store.root.glob("ca.key")), "nobody can issue another certificate"


def test_a_session_without_credentials_reads_puts_and_asks_nothing(deployed):
    bus = deployed.topology.bus
    assert wait_until(lambda: "Use_T1" in leaves(deployed), timeout=10)
    heard = []
    listener = plain_session(bus.hub_port, bus.namespace)  # its own puts are not "read"
    foreign = plain_session(bus.hub_port, bus.namespace)
    try:
        listener.declare_subscriber("**", lambda sample: heard.append(str(sample.key_expr)))
        forged = EventMessage(time.time(), "e_SWAP", "t1", None)
        for _ in range(20):
            foreign.put(EVENTS_KEY, messages.encode(forged, EventMessage))
            time.sleep(0.02)
        replies = list(foreign.get("**", timeout=1.0))
        alive = list(foreign.liveliness().get("**", timeout=1.0))
        assert list(foreign.info.peers_zid()) == [] and list(listener.info.peers_zid()) == []
        assert heard == [] and replies == [] and alive == []
    finally:
        foreign.close()
        listener.close()
    assert leaves(deployed) == ["Use_T1"], "the forged e_SWAP never reached the chart"


def test_a_session_with_another_deployments_certificate_is_refused_too(deployed, tmp_path):
    other = create_keystore(tmp_path / "other", ["trackers"])
    config = dataclasses.replace(deployed.topology.bus, keys=str(other.root))
    with Bus(config, subject=OPERATOR) as intruder:
        assert not intruder.wait_for_peers(1, timeout=1.0)
        assert intruder.alive("**", timeout=0.5) == []


def test_a_secured_bus_cannot_be_joined_without_a_keystore(deployed):
    config = dataclasses.replace(deployed.topology.bus, keys="")
    with pytest.raises(BusError, match="admits only sessions with its credentials"):
        Bus(config, subject=OPERATOR)


def test_events_from_inside_are_checked_where_they_enter(deployed):
    """Even a sender the bus lets put on the events key (here with the deployment's
    control certificate) is checked by the Coordinator: what no component declares it
    emits never reaches the chart, and each refusal is published."""
    assert wait_until(lambda: "Use_T1" in leaves(deployed), timeout=10)
    refusals = []
    inside = Bus(deployed.topology.bus, subject="control")
    assert inside.wait_for_peers(3)
    sub = inside.subscribe(
        STATUS_KEY,
        lambda s: refusals.append(messages.decode(s.payload.to_bytes(), EventMessage)[0]),
        history=False,
    )
    publisher = inside.publisher(EVENTS_KEY, cache=False)
    try:
        for source, event in [("t1", "e_SWAP"), ("nobody", "e_SWAP"), ("t1", "config.done")]:
            message = EventMessage(time.time(), event, source, {"tag": "setup"})
            publisher.put(messages.encode(message, EventMessage))
        assert wait_until(lambda: deployed.coordinator.refused == 3)
        assert wait_until(lambda: len([m for m in refusals if m.name == "refused"]) == 3)
        reasons = [m.payload["reason"] for m in refusals if m.name == "refused"]
        assert reasons == [
            "t1 does not declare that it emits e_SWAP",
            "nobody is not a component of this deployment",
            "config.done is the Coordinator's own event; nobody may send it",
        ]
        assert leaves(deployed) == ["Use_T1"]
    finally:
        sub.undeclare()
        inside.close()


def test_an_operator_may_offer_only_the_topologys_external_events():
    admission = Admission(external=frozenset({"e_START"}), emitters={})
    assert admission.refuse_command("e_START") == ""
    assert admission.refuse_command("e_SAFE_AREA").startswith(
        "e_SAFE_AREA is not an operator event of this topology"
    )
    assert "Coordinator's own event" in admission.refuse_command("component.back")


def test_an_out_of_range_target_is_refused_by_the_coordinator_itself():
    """The console checks the chart's declared limits too; the Coordinator does it for
    every source, so `fw send` or a forged client gets the same answer."""
    from framework.coordinator import Coordinator
    from framework.statechart.loader import load_statechart
    from tests.conftest import REPO

    chart = load_statechart(REPO / "statecharts" / "seeg.yaml")
    coordinator = Coordinator("coordinator", chart, admission=Admission(external=None))
    target = {"x": 5.0, "y": -3.0, "z": -1.0, "roll": 1e9, "pitch": 0.0, "yaw": 0.0}
    answer = coordinator.offer("e_DEFINE_TARGET", target, origin="test")
    assert answer == {"accepted": False, "reason": "e_DEFINE_TARGET.x must be at most 0.5 m"}
    answer = coordinator.offer("e_DEFINE_TARGET", {**target, "x": 0.5, "y": 0.0, "z": 0.2})
    assert answer["reason"] == "e_DEFINE_TARGET.roll must be at most 180 deg"
    answer = coordinator.offer("e_DEFINE_TARGET", {"x": float("nan")})
    assert answer["reason"] == "e_DEFINE_TARGET.x must be a finite number"


def test_a_process_may_publish_only_on_its_own_outputs(deployed):
    """The access rules from the topology: neither `trackers` (t1, t2) nor `control_side`
    (the sink) has an output on the events key, so neither may put there; and
    control_side may not put on t1's output. Configuration requests come from control
    only, and a local switch report only from the process that made it."""
    assert wait_until(lambda: "Use_T1" in leaves(deployed), timeout=10)
    switched = keys.config_switched("control_side")
    heard: dict[str, list[bytes]] = {
        "t1/out": [],
        EVENTS_KEY: [],
        keys.CONFIG_REQUESTS: [],
        switched: [],
    }
    observer = Bus(deployed.topology.bus, subject=OPERATOR)
    forgers = [Bus(deployed.topology.bus, subject=s) for s in ("trackers", "control_side")]
    try:
        for key in heard:
            observer.subscribe(key, lambda s, k=key: heard[k].append(s.payload.to_bytes()), False)
        assert all(f.wait_for_peers(3) for f in (observer, *forgers))
        baseline = len(heard["t1/out"])
        forged = EventMessage(time.time(), "e_SWAP", "t1", None)
        for forger in forgers:
            forger.session.put(EVENTS_KEY, messages.encode(forged, EventMessage))
        forgers[1].session.put("t1/out", b"not a sample")
        # the real senders first (control, control_side), until they are heard: the
        # keys are routed to the observer, so a forgery not heard was refused
        probe = ConfigRequest(time.time(), 10**9, "no such configuration", {}, 0.0, False)
        report = ConfigAck(time.time(), 99, True, "tracker_2_up")

        def real_ones_heard():
            if not heard[keys.CONFIG_REQUESTS]:
                deployed.hub.session.put(
                    keys.CONFIG_REQUESTS, messages.encode(probe, ConfigRequest)
                )
            if not heard[switched]:
                forgers[1].session.put(switched, messages.encode(report, ConfigAck))
            return heard[keys.CONFIG_REQUESTS] and heard[switched]

        assert wait_until(real_ones_heard, 10, interval=0.2)
        request = messages.encode(
            ConfigRequest(time.time(), 99, "tracker_2_up", {}, time.time() + 5, True), ConfigRequest
        )
        forged_report = messages.encode(ConfigAck(time.time(), 98, True, "forged"), ConfigAck)
        for forger in forgers:
            forger.session.put(keys.CONFIG_REQUESTS, request)
        forgers[0].session.put(switched, forged_report)
        # then each forger puts where it may: a session's puts arrive in order, so once
        # these are heard, any forgery let through before them would have been heard too
        barriers = {
            "t1/out": messages.encode(Scalar(time.time(), 0.0), Scalar),
            switched: messages.encode(ConfigAck(time.time(), 97, True, "barrier"), ConfigAck),
        }
        forgers[0].session.put("t1/out", barriers["t1/out"])
        forgers[1].session.put(switched, barriers[switched])
        assert wait_until(lambda: all(b in heard[k] for k, b in barriers.items()), 10)
        assert request not in heard[keys.CONFIG_REQUESTS], "requests come from control only"
        assert forged_report not in heard[switched], "a process reports only its own switches"
        assert heard[EVENTS_KEY] == [], "nobody here may put on the events key"
        assert deployed.coordinator.refused == 0, "it never even reached the Coordinator"
        assert b"not a sample" not in heard["t1/out"], "control_side may not put on t1's output"
        assert len(heard["t1/out"]) > baseline + 1, "the real t1 keeps publishing"
    finally:
        for bus in (observer, *forgers):
            bus.close()
    assert leaves(deployed) == ["Use_T1"]


def test_operations_only_from_control_and_reads_from_the_operator(deployed):
    from framework.remote import RemoteComponent, RemoteError

    assert wait_until(lambda: "Use_T1" in leaves(deployed), timeout=10)
    with Bus(deployed.topology.bus, subject=OPERATOR) as operator:
        assert operator.wait_for_peers(3)
        supervisor = RemoteComponent(operator, "supervisor", timeout=1.0)
        assert supervisor.state() == "Running"
        assert isinstance(supervisor.call("received"), list), "a read-only operation"
        with pytest.raises(RemoteError, match="no answer"):
            supervisor.call("fail")
        with pytest.raises(RemoteError, match="no answer"):
            supervisor.stop()
        coordinator = RemoteComponent(operator, "coordinator", timeout=1.0)
        assert coordinator.call("offer", event="e_SWAP", origin="test")["accepted"]
    with Bus(deployed.topology.bus, subject="trackers") as process:
        assert process.wait_for_peers(3)
        with pytest.raises(RemoteError, match="no answer"):
            RemoteComponent(process, "supervisor", timeout=1.0).state()
    assert wait_until(lambda: leaves(deployed) == ["Use_T2"])
