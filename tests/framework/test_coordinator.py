"""Spec: the Coordinator runs the chart on its own thread, admits only the events each
source may send with payloads that fit their declaration, turns configurations and
actions into requests with deadlines and acks into `config.done` / `config.failed`,
and makes a lost component a chart event (docs/topologies.md, "The Coordinator").

The test plays the Configurator and the components: it answers the requests itself,
on another session of the test's bus, so every rule is seen from outside."""

import sys
import threading
import time

import pytest

from framework import keys, messages
from framework.container import Container
from framework.coordinator import (
    ACKS_KEY,
    EVENTS_KEY,
    IDLE_WAIT,
    REQUESTS_KEY,
    SENT_KEY,
    STATUS_KEY,
    Admission,
    Coordinator,
    loop_wait,
)
from framework.messages import ConfigAck, ConfigRequest, EventMessage
from framework.statechart.loader import load_statechart
from tests.conftest import decoded_into, wait_until, writer_port

CHART = """
statechart: coordinator_spec
configure_timeout: 3s
events:
  e_GO: Start working.
  e_CALL: Call an operation.
  e_WRITE: Write a port.
  e_SEND: Send an event out.
  e_DEPTH: {doc: A depth., payload: {depth: {type: number, min: 0, max: 10}}}
  e_OUT: {doc: Sent out., payload: {n: integer}}
  e_END: End the procedure.
  e_ODD: {doc: Take a guard that fails., payload: {x: any}}
  e_NEST: Go into a compound state.
initial: Idle
states:
  - name: Idle
    transitions:
      - {event: e_GO, target: Working}
      - {event: e_CALL, effect: [{call: {operation: sink.slow, args: {seconds: 0}}}]}
      - {event: e_WRITE, effect: [{write: {port: sink.inp, value: 2.5}}]}
      - {event: e_SEND, effect: [{send: {event: e_OUT, payload: {n: 1}}}]}
      - {event: e_DEPTH, target: Deep}
      - {event: component.lost, target: Lost}
      - {event: e_END, target: End}
      - {event: e_ODD, guard: event.x > 1, target: Deep}
      - {event: e_NEST, target: Nest}
  - name: Working
    configure: {tag: work, timeout: 1500ms}
    do: [{log: working}]
    transitions:
      - {target: Done}
      - {event: config.failed, target: Failed}
  - name: Deep
    transitions:
      - {event: e_DEPTH, target: Idle}
  - name: Done
    transitions:
      - {event: e_GO, target: Working}
  - name: Failed
    transitions:
      - {event: e_GO, target: Working}
  - name: Lost
    transitions:
      - {event: component.back, target: Idle}
  - name: Nest
    initial: Inner
    states:
      - name: Inner
        transitions:
          - {event: e_NEST, target: Idle}
  - {name: End, type: final}
"""


class Rig:
    """A Coordinator in a container on `hub`; the test's session (`peer`) collects its
    requests, status and sent events, answers acks and puts events on fw/events."""

    def __init__(self, hub, peer, write, admission=None, watch=None):
        chart = load_statechart(write(CHART, "chart.yaml"))
        self.control = Container("control", hub)
        self.coordinator = self.control.add(
            Coordinator("coordinator", chart, watch=watch, admission=admission),
            None,
            outputs={"requests": REQUESTS_KEY, "status": STATUS_KEY, "sent": SENT_KEY},
        )
        self.control.connect("coordinator", "events", EVENTS_KEY)
        self.control.connect("coordinator", "acks", ACKS_KEY)
        self.requests: list[ConfigRequest] = []
        self.status: list[EventMessage] = []
        self.sent: list[EventMessage] = []
        self.answer: dict[str, tuple[bool, str, str]] = {}  # tag -> ok, step, reason
        self._subs = [
            peer.subscribe(REQUESTS_KEY, self._on_request),
            peer.subscribe(STATUS_KEY, decoded_into(self.status, EventMessage)),
            peer.subscribe(SENT_KEY, decoded_into(self.sent, EventMessage)),
        ]
        self.acks = writer_port(peer, ACKS_KEY, ConfigAck)
        self.events = writer_port(peer, EVENTS_KEY, EventMessage)
        assert peer.wait_for_peers(1)
        self.control.start()
        assert self.coordinator.start()
        assert wait_until(lambda: self.kinds("configuration"), 10), "the chart started"
        self._routed()

    def _routed(self):
        """Wait until events put by the test reach the Coordinator (a subscription is
        routed a little after it is declared): offer a refused probe until it is seen."""
        port = self.coordinator.inputs["events"]
        sent = [0]

        def probe():
            sent[0] += 1
            self.events.write(EventMessage(time.time(), "config.done", f"probe{sent[0]}", {}))
            return port.stats.received > 0

        assert wait_until(probe, 10)
        last = f"probe{sent[0]}"  # delivered in order: once it is refused, all are
        assert wait_until(lambda: any(r["source"] == last for r in self.refusals()), 10)
        self.probes = len(self.refusals())
        self.status.clear()

    def _on_request(self, sample):
        request, _, _ = messages.decode(sample.payload.to_bytes(), ConfigRequest)
        self.requests.append(request)
        if request.tag in self.answer:
            ok, step, reason = self.answer[request.tag]
            self.ack(request, ok, step, reason)

    def ack(self, request, ok=True, step="", reason=""):
        self.acks.write(ConfigAck(time.time(), request.request_id, ok, request.tag, step, reason))

    def put(self, name, payload=None, source="supervisor"):
        self.events.write(EventMessage(time.time(), name, source, payload or {}))

    def kinds(self, kind):
        return [s.payload for s in self.status if s.name == kind]

    def refusals(self):
        return self.kinds("refused")

    def active(self):
        return self.coordinator.call("active")["active"]

    def close(self):
        for sub in self._subs:
            sub.undeclare()
        self.control.shutdown()


@pytest.fixture
def rig(hub, peer, write):
    rig = Rig(hub, peer, write)
    yield rig
    rig.close()


def test_a_configuration_is_requested_with_its_deadline_and_its_ack_completes_the_state(rig):
    rig.put("e_GO")
    assert wait_until(lambda: rig.requests, 10)
    (request,) = rig.requests
    assert request.tag == "work" and request.deadline - request.stamp == pytest.approx(1.5)
    assert wait_until(lambda: rig.kinds("request"), 10), "the flight recorder sees it too"
    assert rig.kinds("request") == [{"tag": "work", "request_id": request.request_id}]
    assert rig.active() == ["Working"], "waits for the ack"
    assert rig.coordinator.call("active")["pending"]
    rig.ack(request)
    assert wait_until(lambda: rig.active() == ["Done"], 10)
    assert wait_until(lambda: {"state": "Working", "message": "working"} in rig.kinds("log"))


def test_a_failed_configuration_is_the_charts_event_with_the_step_and_reason(rig):
    rig.answer["work"] = (False, "call sink.fail", "sink: asked to fail")
    rig.put("e_GO")
    assert wait_until(lambda: rig.active() == ["Failed"], 10)
    assert wait_until(lambda: any(e["event"] == "config.failed" for e in rig.kinds("event")))
    assert not [log for log in rig.kinds("log") if log["message"] == "working"], "no do"
    event = next(e for e in rig.kinds("event") if e["event"] == "config.failed")
    assert event["payload"]["step"] == "call sink.fail"
    assert event["payload"]["reason"] == "sink: asked to fail"


def test_an_ack_nobody_asked_for_or_a_second_one_is_ignored(rig):
    rig.put("e_GO")
    assert wait_until(lambda: rig.requests, 10)
    request = rig.requests[0]
    rig.acks.write(ConfigAck(time.time(), request.request_id + 100, True, "work", "", ""))
    rig.ack(request)
    assert wait_until(lambda: rig.active() == ["Done"], 10)
    rig.ack(request, ok=False, step="late", reason="a second answer")
    rig.put("e_GO")
    assert wait_until(lambda: len(rig.requests) == 2, 10)
    assert rig.active() == ["Working"], "the stray answers completed nothing"
    assert not [e for e in rig.kinds("event") if e["event"] == "config.failed"]


def test_the_charts_call_and_write_go_to_the_configurator_as_one_step_requests(rig):
    rig.put("e_CALL")
    rig.put("e_WRITE")
    assert wait_until(lambda: len(rig.requests) == 2, 10)
    call, write = rig.requests
    assert (call.tag, call.args) == ("@call", {"target": "sink.slow", "args": {"seconds": 0}})
    assert (write.tag, write.args) == ("@write", {"target": "sink.inp", "value": 2.5})
    assert call.deadline - call.stamp == pytest.approx(2.0), "an action's own timeout"
    rig.ack(call, ok=False, step="call sink.slow", reason="no answer")
    assert wait_until(lambda: rig.kinds("error"), 10)
    assert rig.kinds("error") == [{"message": "@call: call sink.slow: no answer"}]
    rig.ack(write)
    assert rig.active() == ["Idle"], "an action's answer is no chart event"


def test_a_request_is_alone_only_while_nothing_else_is_being_applied(rig):
    rig.put("e_CALL")
    assert wait_until(lambda: len(rig.requests) == 1, 10)
    rig.put("e_GO")
    assert wait_until(lambda: len(rig.requests) == 2, 10)
    call, work = rig.requests
    assert call.alone, "the first: nothing before it"
    assert not work.alone, "the call is not answered: no process may switch ahead of it"
    rig.ack(call)
    rig.ack(work)
    assert wait_until(lambda: rig.active() == ["Done"], 10)
    rig.put("e_GO")
    assert wait_until(lambda: len(rig.requests) == 3, 10)
    assert rig.requests[2].alone, "both answered"


def test_a_send_action_is_published_for_the_outside_world(rig):
    rig.put("e_SEND")
    assert wait_until(lambda: rig.sent, 10)
    (sent,) = rig.sent
    assert (sent.name, sent.source, sent.payload) == ("e_OUT", "coordinator", {"n": 1})


@pytest.mark.parametrize(
    "payload, why",
    [
        ({"depth": 11}, "depth"),
        ({"depth": 1, "extra": 2}, "extra"),
        ({}, "depth"),
    ],
)
def test_an_event_whose_payload_does_not_fit_its_declaration_never_reaches_the_chart(
    rig, payload, why
):
    rig.put("e_DEPTH", payload)
    assert wait_until(lambda: rig.refusals(), 10)
    (refusal,) = rig.refusals()
    assert refusal["event"] == "e_DEPTH" and refusal["source"] == "supervisor"
    assert why in refusal["reason"]
    assert rig.active() == ["Idle"] and rig.coordinator.refused == rig.probes + 1
    rig.put("e_DEPTH", {"depth": 5})
    assert wait_until(lambda: rig.active() == ["Deep"], 10)


def test_nobody_may_put_the_coordinators_own_events_on_the_bus(rig):
    rig.put("config.done", {"tag": "work"})
    rig.put("component.lost", {"component": "robot", "process": "robot"})
    assert wait_until(lambda: len(rig.refusals()) == 2, 10)
    assert all("the Coordinator's own event" in r["reason"] for r in rig.refusals())
    assert rig.active() == ["Idle"]


def test_an_event_that_is_not_a_mapping_of_fields_is_refused(rig):
    rig.events.write(EventMessage(time.time(), "e_GO", "supervisor", [1, 2]))  # type: ignore[arg-type]
    assert wait_until(lambda: rig.refusals(), 10)
    assert "a payload must be a mapping of fields" in rig.refusals()[0]["reason"]


def test_operator_commands_are_answered_with_the_charts_verdict(rig):
    answer = rig.coordinator.call("offer", event="e_DEPTH", payload={"depth": 3}, origin="ui")
    assert answer == {"accepted": True, "reason": ""}
    assert rig.active() == ["Deep"], "processed at once, before the answer"
    answer = rig.coordinator.call("offer", event="e_GO", origin="ui")
    assert answer == {"accepted": False, "reason": "e_GO is not taken in Deep"}
    answer = rig.coordinator.call("offer", event="e_DEPTH", payload={"depth": -1})
    assert not answer["accepted"] and "depth" in answer["reason"]
    assert wait_until(lambda: len(rig.kinds("command")) == 3, 10)
    first = rig.kinds("command")[0]
    assert first == {
        "event": "e_DEPTH",
        "payload": {"depth": 3},
        "origin": "ui",
        "accepted": True,
        "reason": "",
    }
    assert rig.coordinator.call("takeable", events=["e_GO", "e_DEPTH"]) == ["e_DEPTH"]


def test_takeable_says_which_commands_the_chart_would_take_now(rig):
    assert rig.coordinator.call("takeable", events=["e_GO", "e_SEND", "e_NOPE"]) == [
        "e_GO",
        "e_SEND",
    ]
    assert rig.coordinator.call("active")["last_events"] == []
    rig.put("e_SEND")
    assert wait_until(lambda: rig.coordinator.call("active")["last_events"] == ["e_SEND"], 10)


@pytest.fixture
def guarded(hub, peer, write):
    admission = Admission(
        external=frozenset({"e_GO"}), emitters={"supervisor": frozenset({"e_SEND"})}
    )
    rig = Rig(hub, peer, write, admission=admission)
    yield rig
    rig.close()


def test_each_component_may_send_only_the_events_its_class_declares(guarded):
    guarded.put("e_GO", source="supervisor")
    guarded.put("e_SEND", source="intruder")
    guarded.put("e_SEND", source="supervisor")
    assert wait_until(lambda: guarded.sent, 10), "the declared event was taken"
    reasons = [r["reason"] for r in guarded.refusals()]
    assert "supervisor does not declare that it emits e_GO" in reasons
    assert "intruder is not a component of this deployment" in reasons
    assert guarded.active() == ["Idle"]


def test_the_operator_may_send_only_the_topologys_external_events(guarded):
    answer = guarded.coordinator.call("offer", event="e_SEND")
    assert answer == {
        "accepted": False,
        "reason": "e_SEND is not an operator event of this topology (those are: e_GO)",
    }
    assert guarded.coordinator.call("offer", event="e_GO")["accepted"]


def test_a_misspelt_operator_event_is_refused_with_the_nearest_one():
    """A typo in `fw send` or a console gets the event meant, as `fw run` does."""
    admission = Admission(external=frozenset({"e_START", "e_STOP", "e_RELEASE"}))
    assert admission.refuse_command("e_STRAT") == (
        "e_STRAT is not an operator event of this topology "
        "(those are: e_RELEASE, e_START, e_STOP); did you mean e_START?"
    )
    assert admission.refuse_command("e_WHATEVER").endswith("e_STOP)"), "nothing near: no guess"


def test_a_deployment_that_declares_nobody_refuses_every_command_and_sample(hub, peer, write):
    """No operator events in the topology means the operator may send none (not: any),
    and no components means no component may put an event: an empty rule refuses, only
    a Coordinator outside any deployment (no rules at all) takes everything."""
    rig = Rig(hub, peer, write, admission=Admission(external=frozenset(), emitters={}))
    try:
        answer = rig.coordinator.call("offer", event="e_GO")
        assert answer == {
            "accepted": False,
            "reason": "e_GO is not an operator event of this topology (those are: none)",
        }
        rig.put("e_SEND", source="supervisor")
        assert wait_until(lambda: rig.refusals(), 10)
        assert rig.refusals()[0]["reason"] == "supervisor is not a component of this deployment"
        assert rig.active() == ["Idle"] and not rig.sent
    finally:
        rig.close()


def test_a_lost_component_is_a_chart_event_and_its_return_another(hub, peer, write):
    rig = Rig(hub, peer, write, watch={"sink": "workers"})
    try:
        token = peer.token(keys.alive("sink"))
        assert wait_until(lambda: "sink" in rig.coordinator._alive, 10)
        token.undeclare()
        assert wait_until(lambda: rig.active() == ["Lost"], 10)
        assert rig.coordinator.call("active")["lost"] == {"sink": "workers"}
        token = peer.token(keys.alive("sink"))
        assert wait_until(lambda: rig.active() == ["Idle"], 10)
        assert rig.coordinator.call("active")["lost"] == {}
        token.undeclare()
    finally:
        rig.close()


class Listening:
    """An extra listener, as the flight recorder is one."""

    def __init__(self):
        self.refused = []

    def on_refused(self, event, source, reason):
        self.refused.append((event, source, reason))


def test_unhandled_events_and_failing_guards_are_said_on_the_status(rig):
    rig.put("e_SEND")  # taken
    rig.put("config.done", {"tag": "work"}, source="supervisor")  # refused at the door
    answer = rig.coordinator.call("offer", event="e_ODD", payload={"x": "text"})
    assert answer["accepted"] is False
    assert wait_until(lambda: rig.kinds("error"), 10)
    assert "treated as false" in rig.kinds("error")[0]["message"]
    assert wait_until(lambda: rig.kinds("unhandled"), 10)
    assert rig.kinds("unhandled")[0]["event"] == "e_ODD"


def test_an_event_refused_once_is_judged_afresh_when_offered_again(rig):
    first = rig.coordinator.call("offer", event="e_ODD", payload={"x": 0})
    assert first["accepted"] is False  # its guard is false
    second = rig.coordinator.call("offer", event="e_ODD", payload={"x": 2})
    assert second["accepted"] is True, second  # the same event, now its guard holds


def test_the_operator_may_not_send_the_coordinators_own_events(rig):
    answer = rig.coordinator.call("offer", event="config.done", payload={"tag": "work"})
    assert answer == {
        "accepted": False,
        "reason": "config.done is the Coordinator's own event; nobody may send it",
    }


def test_a_finished_procedure_takes_no_more_commands(rig):
    assert rig.coordinator.call("offer", event="e_END")["accepted"]
    answer = rig.coordinator.call("offer", event="e_GO")
    assert answer == {"accepted": False, "reason": "the procedure chart is not running"}
    assert rig.coordinator.call("takeable", events=["e_GO"]) == []
    assert rig.coordinator.call("active")["finished"] is True


def test_refusals_reach_the_extra_listeners(hub, peer, write):
    from framework.statechart.loader import load_statechart as load

    listening = Listening()
    chart = load(write(CHART, "chart.yaml"))
    coordinator = Coordinator("c", chart, listeners=[listening])
    assert coordinator.inject("e_GO") is False, "not started: nothing to queue into"
    assert coordinator.takeable(["e_GO"]) == []
    assert coordinator.active() == {
        "active": [],
        "pending": {},
        "finished": False,
        "last_events": [],
        "lost": {},
    }
    answer = coordinator.offer("e_GO")
    assert answer == {"accepted": False, "reason": "the procedure chart is not running"}
    coordinator.offer("config.done")
    assert listening.refused == [
        (
            "config.done",
            "operator",
            "config.done is the Coordinator's own event; nobody may send it",
        )
    ]


def test_the_admission_rules_cannot_be_changed_once_made():
    import dataclasses

    admission = Admission(external=frozenset({"e_GO"}), emitters={})
    with pytest.raises(dataclasses.FrozenInstanceError):
        admission.external = None  # type: ignore[misc]


def test_a_stopped_coordinator_runs_no_more_steps_and_follows_no_liveliness(hub, peer, write):
    rig = Rig(hub, peer, write, watch={"sink": "workers"})
    token = peer.token(keys.alive("sink"))
    try:
        assert wait_until(lambda: "sink" in rig.coordinator._alive, 10)
        (loop,) = [t for t in threading.enumerate() if t.name == "fw-coordinator"]
        assert loop.daemon, "the chart's loop never keeps a dying process alive"
        assert rig.coordinator.stop()
        alive = [t.name for t in threading.enumerate()]
        assert "fw-coordinator" not in alive, "stop returns once the chart's loop has ended"
        rig.put("e_SEND")
        token.undeclare()
        time.sleep(0.5)  # a grace period for anything that would still happen
        assert rig.sent == [], "no step after stop"
        assert rig.coordinator.call("active")["lost"] == {}, "liveliness no longer followed"
    finally:
        rig.close()


def test_the_last_twenty_events_are_remembered_from_the_bus_and_the_operator(rig):
    for _ in range(25):
        rig.put("e_SEND")
    assert wait_until(lambda: len(rig.sent) == 25, 10)
    assert rig.coordinator.call("active")["last_events"] == ["e_SEND"] * 20
    rig.coordinator.call("offer", event="e_DEPTH", payload={"depth": 1})
    last = rig.coordinator.call("active")["last_events"]
    assert len(last) == 20 and last[-1] == "e_DEPTH" and last[0] == "e_SEND"


def test_operators_tools_may_only_ask_what_the_chart_would_take_and_where_it_is():
    from framework.topology import class_info

    info = class_info(Coordinator)
    assert {"takeable", "active"} <= info.readonly
    assert "offer" not in info.readonly


@pytest.mark.parametrize(
    ("deadline", "now", "wait"),
    [
        (None, 5.0, IDLE_WAIT),
        (5.25, 5.0, 0.25),
        (4.0, 5.0, 0.0),
        (9.0, 5.0, IDLE_WAIT),
        (0.0, 0.0, 0.0),  # due at a simulated clock's start: now, not "nothing due"
    ],
)
def test_the_charts_loop_wakes_for_its_next_time_event_at_the_latest(deadline, now, wait):
    assert loop_wait(deadline, now) == wait
    assert IDLE_WAIT == 0.5, "an idle chart still looks around twice a second"


def test_every_step_that_moves_the_chart_publishes_where_it_is(rig):
    rig.put("e_GO")
    assert wait_until(lambda: any(c["active"] == ["Working"] for c in rig.kinds("configuration")))
    working = next(c for c in rig.kinds("configuration") if c["active"] == ["Working"])
    assert working["pending"] == {"Working": "work"} and working["finished"] is False


def test_an_idle_chart_publishes_nothing(rig):
    time.sleep(1.2)  # more than two of the loop's idle wakes
    assert rig.status == [], "no step moved the chart: nothing to say"


def test_an_operators_command_that_moves_the_chart_publishes_where_it_is(rig):
    assert rig.coordinator.call("offer", event="e_DEPTH", payload={"depth": 1})["accepted"]
    assert wait_until(lambda: any(c["active"] == ["Deep"] for c in rig.kinds("configuration")))


def test_a_refused_command_is_said_once_as_the_command_it_was(rig):
    refused = rig.coordinator.refused
    answer = rig.coordinator.call("offer", event="e_DEPTH", payload={"depth": 99}, origin="ui")
    assert answer["accepted"] is False and "depth" in answer["reason"]
    assert wait_until(lambda: rig.kinds("command"), 10)
    assert rig.kinds("command")[0]["origin"] == "ui" and not rig.kinds("command")[0]["accepted"]
    assert rig.refusals() == [] and rig.coordinator.refused == refused + 1


def test_a_command_not_taken_names_the_innermost_active_state(rig):
    assert rig.coordinator.call("offer", event="e_NEST")["accepted"]
    assert rig.active() == ["Nest.Inner"]
    answer = rig.coordinator.call("offer", event="e_GO")
    assert answer == {"accepted": False, "reason": "e_GO is not taken in Inner"}


def test_a_command_whose_every_guard_is_false_is_refused_with_the_charts_reason(rig):
    answer = rig.coordinator.call("offer", event="e_ODD", payload={"x": 0})
    assert answer == {"accepted": False, "reason": "no enabled transition"}
    assert rig.active() == ["Idle"]


def test_an_event_injected_in_this_process_is_queued_for_the_chart(rig):
    assert rig.coordinator.inject("e_DEPTH", {"depth": 1}) is True
    assert wait_until(lambda: rig.active() == ["Deep"], 10)


def test_an_events_payload_from_the_bus_reaches_the_charts_guards(rig):
    rig.put("e_ODD", {"x": 5})
    assert wait_until(lambda: rig.active() == ["Deep"], 10)


def test_the_status_tells_each_transition_and_the_states_left_and_entered(rig):
    rig.put("e_DEPTH", {"depth": 1})
    assert wait_until(lambda: rig.kinds("entry"), 10)
    assert rig.kinds("transition") == [{"source": "Idle", "target": "Deep", "event": "e_DEPTH"}]
    assert rig.kinds("exit") == [{"state": "Idle"}] and rig.kinds("entry") == [{"state": "Deep"}]


def test_a_coordinator_started_again_after_a_stop_runs_its_chart_again(rig):
    assert rig.coordinator.stop() and rig.coordinator.start()
    assert wait_until(lambda: rig.active() == ["Idle"], 10)
    rig.put("e_SEND")
    assert wait_until(lambda: rig.sent, 10), "the restarted loop takes events"


def test_the_liveliness_of_a_component_not_watched_is_no_event(hub, peer, write):
    rig = Rig(hub, peer, write, watch={"sink": "workers"})
    try:
        token = peer.token(keys.alive("stranger"))
        time.sleep(0.3)  # the token is seen, then goes
        token.undeclare()
        time.sleep(0.3)
        assert rig.coordinator.call("active")["lost"] == {}
        assert not [e for e in rig.kinds("event") if e["event"].startswith("component.")]
    finally:
        rig.close()


@pytest.mark.parametrize("external", [None, frozenset({"e_GO"})])
@pytest.mark.parametrize("event", ["config.done", "component.lost"])
def test_the_coordinators_own_events_are_refused_from_anyone_by_their_name(external, event):
    """Whether or not the topology lists operator events, a builtin event is refused as
    the Coordinator's own, on the events port and as a command, naming the event."""
    admission = Admission(external=external, emitters={"supervisor": frozenset({event})})
    said = f"{event} is the Coordinator's own event; nobody may send it"
    assert admission.refuse_command(event) == said
    assert admission.refuse_sample("supervisor", event) == said


def test_a_request_after_an_earlier_one_ran_past_its_deadline_unanswered_is_alone(rig):
    """A request the chart gave up on (its configuration timed out, 1.5 s) holds back
    nothing: the Configurator starts no step of it after its deadline, so the next
    request may be applied at once."""
    rig.put("e_GO")
    assert wait_until(lambda: len(rig.requests) == 1, 10)
    assert wait_until(lambda: rig.active() == ["Failed"], 10), "unanswered: timed out"
    rig.put("e_GO")
    assert wait_until(lambda: len(rig.requests) == 2, 10)
    assert rig.requests[1].alone


@pytest.mark.parametrize("payload", [[], 0, "", [1]])
def test_a_payload_that_is_not_a_mapping_is_refused_even_when_empty(rig, payload):
    rig.events.write(EventMessage(time.time(), "e_ODD", "supervisor", payload))
    assert wait_until(lambda: [r for r in rig.refusals() if r["event"] == "e_ODD"], 10)
    (refusal,) = [r for r in rig.refusals() if r["event"] == "e_ODD"]
    assert refusal["reason"] == "e_ODD: a payload must be a mapping of fields"
    assert rig.active() == ["Idle"]


@pytest.fixture
def sleepy_rig(hub, peer, write, monkeypatch):
    """The rig with the chart's idle wait at an hour: whatever is handled was woken."""
    import framework.coordinator

    monkeypatch.setattr(framework.coordinator, "IDLE_WAIT", 3600.0)
    rig = Rig(hub, peer, write)
    yield rig
    rig.close()


def test_every_event_ack_and_injection_wakes_the_charts_loop(sleepy_rig):
    """The chart's loop sleeps until its next time event or something arrives: each
    event put, each configuration's answer and each event injected in the process is
    handled at once, never left for the idle wait (an hour here)."""
    rig = sleepy_rig
    rig.put("e_SEND")
    assert wait_until(lambda: rig.sent, 10)
    for _ in range(3):
        asked = len(rig.requests)
        rig.put("e_GO")
        assert wait_until(lambda: rig.active() == ["Working"], 10)
        # the request reaches this session a moment after the chart entered Working
        assert wait_until(lambda asked=asked: len(rig.requests) > asked, 10)
        rig.ack(rig.requests[-1])
        assert wait_until(lambda: rig.active() == ["Done"], 10)
    rig.coordinator.inject("e_GO")
    assert wait_until(lambda: rig.active() == ["Working"], 10)


def test_a_chart_whose_inputs_never_received_anything_keeps_running(hub, write, monkeypatch):
    """Nothing on the events or acks ports yet (a deployment still starting): the loop's
    idle wakes find nothing to read and go on; an event injected later is handled."""
    import framework.coordinator

    monkeypatch.setattr(framework.coordinator, "IDLE_WAIT", 0.005)
    chart = load_statechart(write(CHART, "chart.yaml"))
    control = Container("control", hub)
    try:
        coordinator = control.add(Coordinator("coordinator", chart), None)
        control.start()
        assert coordinator.start()
        time.sleep(0.1)  # twenty idle wakes with nothing on either port
        assert coordinator.inject("e_END")
        assert wait_until(lambda: coordinator.call("active")["finished"], 10)
    finally:
        control.shutdown()


def test_a_refused_event_does_not_hold_back_the_events_that_came_after_it(sleepy_rig):
    """Events taken in one wake are each judged: one refused (a sender not allowed to
    send it) does not leave the good event behind it queued until some later wake (the
    idle wait is an hour here)."""
    rig = sleepy_rig
    events = rig.coordinator.inputs["events"]
    assert rig.coordinator.stop()  # both arrive while nobody reads: one wake takes them
    before = events.stats.received
    rig.put("config.done", source="intruder")
    rig.put("e_GO")
    assert wait_until(lambda: events.stats.received == before + 2, 10)
    assert rig.coordinator.start()
    assert wait_until(lambda: rig.active() == ["Working"], 10), "e_GO taken after the refusal"


def test_status_records_written_from_several_threads_all_reach_a_port(rig, peer):
    """The chart's thread and an operator's `offer` both write the status: each record
    is numbered by the port, and a reader drops a number at or below one it kept as a
    repeat, so two writers overtaking each other lost a record (a console missed
    `command e_START` on a loaded host)."""
    from framework.ports import ConnPolicy, InputPort

    port = InputPort("status", EventMessage, policy=ConnPolicy("buffer", 20_000))
    port.owner, port.bus = "console", peer
    port.on_data = lambda _port: None  # delivered as it comes
    port.connect(STATUS_KEY)
    assert wait_until(lambda: rig.coordinator.publish("log", {}) or port.stats.received, 10)
    repeats = port.stats.dropped_duplicate

    def say(n):
        for i in range(n):
            rig.coordinator.publish("log", {"i": i})

    switching = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch between any two bytecodes
    try:
        writers = [threading.Thread(target=say, args=(3000,)) for _ in range(2)]
        for thread in writers:
            thread.start()
        for thread in writers:
            thread.join()
    finally:
        sys.setswitchinterval(switching)
    time.sleep(0.5)  # the last records in flight (counted, not asserted on time)
    assert port.stats.dropped_duplicate == repeats
    port.close()
