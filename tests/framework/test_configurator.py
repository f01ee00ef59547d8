"""Spec: the Configurator applies named configurations as ordered steps, one at a time,
answers every request, and on a failure undoes what it changed, newest first
(docs/topologies.md, "The Configurator").

The components live in a container on one session of the test's bus, the Configurator
on another, as in a deployment (requests and answers cross the bus); they share the
test's process so a configuration costs milliseconds, not a process start."""

import threading
import time

import pytest

from framework import keys, messages
from framework.activity import Activity
from framework.configurator import Configurator, StepFailed
from framework.container import Container
from framework.container_main import build
from framework.deployer import container_spec
from framework.messages import ConfigAck, ConfigRequest
from framework.recorder import FlightRecorder, read_recording
from framework.topology import Step, StepKind
from tests.conftest import REPO, decoded_into, private_topology, wait_until, writer_port

TOPOLOGY = REPO / "tests" / "data" / "configurator" / "configurator.yaml"
REQUESTS, ACKS = keys.CONFIG_REQUESTS, "spec/acks"  # where a local switch hears requests


class Rig:
    """The workers' container on `peer`; the Configurator in a control container on
    `hub`, fed requests on its port and answering on `acks`, as the Coordinator sees it."""

    def __init__(self, hub, peer, bus_config):
        self.topology = private_topology(TOPOLOGY, bus_config)
        self.workers = build(container_spec(self.topology, "workers"), peer)
        self.control = Container("control", hub)
        self.configurator = self.control.add(
            Configurator("configurator", self.topology, hub),
            Activity.event("requests"),
            outputs={"acks": ACKS},
        )
        self.control.connect("configurator", "requests", REQUESTS)
        self.control.start()
        assert self.configurator.start()
        assert peer.wait_for_peers(1)
        self.acks: list[ConfigAck] = []
        self._sub = peer.subscribe(ACKS, decoded_into(self.acks, ConfigAck))
        self.requests = writer_port(hub, REQUESTS, ConfigRequest)  # from control, as ever
        self._ids = iter(range(1, 10**6))
        self._routed()
        assert self.apply("setup").ok

    def apply(self, tag):
        return self.configurator.apply(tag)

    def _routed(self):
        """Wait until requests put by the test reach the Configurator (a subscription is
        routed a little after it is declared): probes with an unknown tag, resent until
        one is answered; their answers are left out of `acks`."""
        probe = iter(range(10**9, 2 * 10**9))

        def answered():
            self.requests.write(ConfigRequest(time.time(), next(probe), "probe", {}, 0.0))
            return any(a.request_id >= 10**9 for a in self.acks)

        assert wait_until(answered, 10)

    def request(self, tag, args=None, deadline=0.0, alone=False) -> ConfigAck:
        """Send a request on the Configurator's port, as the Coordinator does; its ack."""
        request_id = next(self._ids)
        self.requests.write(
            ConfigRequest(time.time(), request_id, tag, args or {}, deadline, alone)
        )
        assert wait_until(lambda: any(a.request_id == request_id for a in self.acks), 20)
        return next(a for a in self.acks if a.request_id == request_id)

    def answers(self):
        """The answers to the test's own requests (not the probes), in arrival order."""
        return [a for a in self.acks if a.request_id < 10**9]

    def sink(self):
        return self.workers.components["sink"]

    def port(self, component, name):
        return self.workers.components[component].inputs[name]

    def close(self):
        self._sub.undeclare()
        self.control.shutdown()
        self.workers.shutdown()


@pytest.fixture
def rig(hub, peer, bus_config):
    rig = Rig(hub, peer, bus_config)
    yield rig
    rig.close()


def received(rig):
    return rig.sink().call("received")


def test_a_configuration_brings_states_and_rewires_in_order(rig):
    assert rig.sink().state.value == "Running"
    assert wait_until(lambda: received(rig) and received(rig)[-1] > 0), "a counts up"
    outcome = rig.apply("to_b")
    assert outcome.ok and outcome.tag == "to_b" and outcome.rolled_back == 0
    assert rig.port("sink", "inp").key.endswith("b/out")
    assert rig.sink().state.value == "Running", "post state"
    assert wait_until(lambda: received(rig) and received(rig)[-1] < 0), "b counts down"
    assert rig.configurator.history[-1] is outcome


def test_reapplying_leaves_a_connection_in_place_alone(rig):
    assert rig.apply("hold").ok
    sink = rig.port("sink", "inp")
    assert wait_until(lambda: rig.sink().inputs["inp"].stats.received >= 5), "queued, unread"
    assert rig.apply("hold").ok
    assert sink.stats.discarded_on_rewire == 0, "not reconnected: nothing queued was lost"
    assert rig.apply("to_b").ok
    assert sink.stats.discarded_on_rewire > 0, "a real rewire starts the port empty"


def test_a_swap_applied_again_leaves_the_port_connected_not_disconnected(rig):
    """A tracker swap disconnects, then connects. Applied again where the wiring already
    has that connection (the chart re-selects the tracker in use after a RELEASE), the
    disconnect runs, so the connect must too: judged "already so" against the wiring
    before the disconnect, it was skipped and the navigator was left with no tracker
    (steering None at Target_Reached, both trackers healthy)."""
    assert rig.apply("to_b").ok
    assert rig.apply("to_b").ok
    port = rig.port("sink", "inp")
    assert port.key is not None and port.key.endswith("b/out")
    assert wait_until(lambda: received(rig) and received(rig)[-1] < 0), "b still counts down"


def test_the_restore_of_a_restarted_process_says_every_change_since_deploy(rig):
    assert rig.configurator.restore_steps({"sink", "a"}) == []
    assert rig.apply("to_b").ok
    (step,) = rig.configurator.restore_steps({"sink"})
    assert (step.kind, step.component, step.target) == ("connect", "sink", "inp")
    assert step.key.endswith("b/out")
    assert rig.configurator.restore_steps({"a", "dbl"}) == [], "only the named components"
    assert rig.apply("unplug").ok
    (step,) = rig.configurator.restore_steps({"sink"})
    assert (step.kind, step.component, step.target) == ("disconnect", "sink", "inp")


def test_a_step_already_so_is_skipped_and_the_next_ones_still_run(rig):
    assert rig.apply("same_then_tune").ok
    assert rig.workers.components["dbl"].get_property("gain") == 7.0


def test_the_restore_names_a_port_wired_only_by_a_configuration(rig):
    assert rig.apply("feed_doubler").ok
    (step,) = rig.configurator.restore_steps({"dbl"})
    assert (step.kind, step.component, step.target) == ("connect", "dbl", "inp")
    assert step.key.endswith("a/out")


def test_an_outcome_says_how_long_it_took(rig):
    started = time.perf_counter()
    outcome = rig.apply("three_slow")
    took = time.perf_counter() - started
    assert 0.6 <= outcome.seconds <= took, "three calls of 0.2 s"
    started = time.perf_counter()
    failed = rig.apply("tune_then_fail")
    assert 0.0 < failed.seconds <= time.perf_counter() - started
    assert rig.apply("nope").seconds == 0.0, "nothing was tried"


def test_a_configuration_is_an_operation_with_its_outcome_as_data(rig):
    answer = rig.configurator.call("apply_configuration", tag="to_b")
    assert answer["ok"] is True and answer["tag"] == "to_b" and answer["step"] == ""
    answer = rig.configurator.call("apply_configuration", tag="tune_then_fail")
    assert answer["ok"] is False and answer["rolled_back"] == 3


def test_forced_steps_are_sent_even_where_the_wiring_already_says_so(rig):
    assert rig.apply("hold").ok
    sink = rig.port("sink", "inp")
    assert wait_until(lambda: sink.stats.received >= 5)
    again = Step("connect", "sink", "inp", key=sink.key, policy=None)
    assert rig.configurator.run_steps("restore of sink", [again]).ok
    assert sink.stats.discarded_on_rewire > 0, "reconnected: a restarted port is wired anew"


def test_a_rollback_goes_on_past_an_undo_that_fails(rig, monkeypatch):
    """Undoing is best effort: an undo that cannot be made is skipped and the ones after
    it are still made (the gain is back although the connection could not be undone)."""
    send = rig.configurator._send

    def refusing_disconnects(batch, undo, deadline=None):
        if batch[0].kind is StepKind.DISCONNECT and batch[0].component == "dbl":
            raise StepFailed(batch[0].describe(), "refused for the test")
        return send(batch, undo, deadline)

    monkeypatch.setattr(rig.configurator, "_send", refusing_disconnects)
    outcome = rig.apply("tune_then_fail")
    assert not outcome.ok and outcome.step == "call sink.fail"
    assert outcome.rolled_back == 2, "two of the three undone"
    assert rig.workers.components["dbl"].get_property("gain") == 2.0, "the oldest undo made"
    assert rig.port("dbl", "inp").key is not None, "the one that failed"


def test_a_failure_undoes_property_and_connection_changes_newest_first(rig):
    doubler = rig.workers.components["dbl"]
    assert doubler.get_property("gain") == 2.0 and rig.port("dbl", "inp").key is None
    outcome = rig.apply("tune_then_fail")
    assert not outcome.ok
    assert outcome.step == "call sink.fail"
    assert outcome.reason.startswith("sink: ") and "asked to fail" in outcome.reason
    assert outcome.rolled_back == 3
    assert doubler.get_property("gain") == 2.0, "3.0 then 5.0 undone: back to the first value"
    assert rig.port("dbl", "inp").key is None, "the new connection undone"
    assert ("dbl", "inp") not in rig.configurator.wiring


@pytest.mark.parametrize("tag", ["rewire_then_fail", "unplug_then_fail"])
def test_a_failure_within_one_components_batch_restores_its_previous_wiring(rig, tag):
    before = rig.port("sink", "inp").key
    outcome = rig.apply(tag)
    assert not outcome.ok and outcome.step == "call sink.fail" and outcome.rolled_back == 1
    assert rig.port("sink", "inp").key == before
    assert rig.configurator.restore_steps({"sink"}) == [], "the Configurator's map agrees"


def test_a_write_is_its_own_step_and_never_swallows_the_next(rig):
    assert rig.apply("hold").ok  # the sink keeps what arrives, unread
    outcome = rig.apply("write_then_fail")
    assert not outcome.ok and outcome.step == "call sink.fail", "the call after it ran"
    assert rig.apply("call_then_write").ok, "a write after a call is not sent as a call"
    assert rig.apply("write_twice").ok
    assert rig.sink().start()
    assert wait_until(lambda: {-7.5, -8.5, -9.5, -10.5} <= set(received(rig)))


def test_several_slow_steps_on_one_component_get_the_time_of_all_of_them(rig):
    outcome = rig.apply("three_slow")
    assert outcome.ok, outcome.reason


@pytest.mark.parametrize("tag", ["batched", "write_then_batched"])
def test_consecutive_steps_on_one_component_travel_together_with_their_time(rig, tag):
    """The slow call alone is over its own 500 ms; sent together, the steps have 1 s."""
    outcome = rig.apply(tag)
    assert outcome.ok, outcome.reason


def test_each_component_gets_only_its_own_steps(rig):
    assert rig.apply("sink_then_doubler").ok
    assert rig.workers.components["dbl"].get_property("gain") == 4.0


def test_an_unknown_configuration_is_answered_with_the_known_ones(rig):
    outcome = rig.apply("nope")
    assert (outcome.ok, outcome.step) == (False, "lookup")
    assert outcome.reason.startswith("unknown configuration 'nope' (known: batched, ")
    assert rig.configurator.history[-1] is outcome, "kept with every other outcome"


def test_requests_on_the_port_are_answered_one_each_in_order(rig):
    ack = rig.request("to_b")
    assert (ack.ok, ack.tag, ack.step, ack.reason) == (True, "to_b", "", "")
    ack = rig.request("tune_then_fail")
    assert (ack.ok, ack.step) == (False, "call sink.fail") and "asked to fail" in ack.reason
    ack = rig.request("nope")
    assert (ack.ok, ack.step) == (False, "lookup")
    ids = [a.request_id for a in rig.answers()]
    assert ids == sorted(ids) == [1, 2, 3]


def test_a_request_that_comes_after_its_deadline_is_refused_unapplied(rig):
    ack = rig.request("to_b", deadline=time.time() - 1.0)
    assert (ack.ok, ack.step) == (False, "deadline")
    assert not rig.port("sink", "inp").key.endswith("b/out"), "nothing ran"
    assert rig.configurator.history[-1].step == "deadline"
    ack = rig.request("to_b", deadline=time.time() + 30.0)
    assert ack.ok, "in time: applied"


def test_the_charts_call_action_gets_two_seconds_unless_it_says_otherwise(rig):
    assert rig.request("@call", {"target": "sink.slow", "args": {"seconds": 1.5}}).ok
    ack = rig.request("@call", {"target": "sink.slow", "args": {"seconds": 2.4}})
    assert not ack.ok, "over the default 2 s"
    ack = rig.request("@call", {"target": "sink.slow", "args": {"seconds": 2.4}, "timeout": 4})
    assert ack.ok


def test_the_charts_call_action_runs_one_operation(rig):
    ack = rig.request("@call", {"target": "sink.slow", "args": {"seconds": 0.0}})
    assert ack.ok and ack.tag == "@call"
    ack = rig.request("@call", {"target": "sink.fail"})
    assert not ack.ok and ack.step == "call sink.fail" and "asked to fail" in ack.reason
    assert rig.configurator.history[-1].tag == "@call sink.fail"
    ack = rig.request("@call", {"target": "sink.slow", "args": {"seconds": 0.5}, "timeout": 0.1})
    assert not ack.ok, "its own timeout"


def test_the_charts_write_action_puts_one_sample_on_the_ports_key(rig):
    ack = rig.request("@write", {"target": "sink.inp", "value": {"stamp": 0.0, "value": -3.5}})
    assert ack.ok, ack.reason
    assert wait_until(lambda: -3.5 in received(rig))
    ack = rig.request("@write", {"target": "sink.inp", "value": -4.5})
    assert ack.ok, "a bare value is the message's value"
    assert wait_until(lambda: -4.5 in received(rig))


@pytest.mark.parametrize(
    "target, value, why",
    [
        ("dbl.inp", {"stamp": 0.0, "value": 1.0}, "the port is not connected to a key"),
        ("ghost.inp", {"stamp": 0.0, "value": 1.0}, "the port is not connected to a key"),
        ("sink.inp", {"stamp": 0.0, "colour": "red"}, "bad value for Scalar"),
        ("sink.pose", 1.0, "bad value for Pose: give its fields as a mapping"),
    ],
)
def test_a_write_that_cannot_be_made_fails_with_the_reason(rig, target, value, why):
    ack = rig.request("@write", {"target": target, "value": value})
    assert not ack.ok and ack.step == f"write {target}" and why in ack.reason
    assert rig.configurator.history[-1].tag == f"@write {target}"


def test_a_batch_nobody_answers_fails_at_its_first_step(rig):
    rig.workers.shutdown()  # every component gone at once
    outcome = rig.apply("tune_then_fail")
    assert not outcome.ok and outcome.step == "set dbl.gain = 3.0"
    assert "dbl" in outcome.reason


def test_a_call_before_a_failure_leaves_nothing_to_undo(rig):
    outcome = rig.apply("call_then_fail")
    assert not outcome.ok and outcome.rolled_back == 0
    assert rig.configurator.restore_steps({"sink"}) == [], "an operation is no wiring"


def test_a_step_still_running_at_the_requests_deadline_fails_and_nothing_follows(rig):
    ack = rig.request("slow_then_tune", deadline=time.time() + 0.3)
    assert (ack.ok, ack.step) == (False, "call sink.slow")
    assert rig.workers.components["dbl"].get_property("gain") == 2.0, "never set"


def test_a_configuration_already_overdue_fails_at_its_first_step_and_runs_none(rig):
    """A configuration whose deadline passed before it started is refused at its first
    step (here the sink's stop, which travels with the rewiring after it), and nothing
    of it runs."""
    outcome = rig.configurator.apply("to_b", deadline=time.time() - 1.0)
    assert not outcome.ok and outcome.step == "state sink -> stopped"
    assert "its deadline passed" in outcome.reason
    assert rig.port("sink", "inp").key.endswith("a/out"), "not rewired"


# -- local switches (framework/local_switch.py) ------------------------------------------
def switch_routed(rig, hub):
    """Wait until the workers' process listens to the Coordinator's requests."""
    probe = hub.publisher(REQUESTS, cache=False, remote_only=True)
    try:
        assert wait_until(lambda: probe.matching_status.matching, 10)
    finally:
        probe.undeclare()


def test_a_prepared_switch_is_made_by_its_process_and_recorded_by_the_configurator(
    rig, hub, tmp_path
):
    recording = tmp_path / "flight.mcap"
    recorder = FlightRecorder(recording, hub)
    switch_routed(rig, hub)
    assert rig.workers.local_switches.switches.keys() >= {"switch_to_b", "unplug"}
    assert "to_b" not in rig.workers.local_switches.switches, "it begins with a state"
    ack = rig.request("switch_to_b", alone=True)
    assert ack.ok, ack.reason
    (report,) = rig.workers.local_switches.done
    assert report.ok and report.request_id == ack.request_id, "the process switched"
    assert rig.port("sink", "inp").key.endswith("b/out")
    assert rig.workers.components["dbl"].get_property("gain") == 6.0, "the rest ran after"
    (step,) = rig.configurator.restore_steps({"sink"})
    assert step.key.endswith("b/out"), "the Configurator's map has the switch"
    assert wait_until(lambda: received(rig) and received(rig)[-1] < 0), "b's samples arrive"
    assert rig.configurator.history[-1].switched_by == "workers"
    recorder.close()
    (switched,) = [d for t, _, d in read_recording(recording) if t == "/fw/config/switched"]
    assert switched["process"] == "workers" and switched["tag"] == "switch_to_b"
    assert switched["ok"] and switched["request_id"] == ack.request_id, "in the flight recording"


def test_a_request_that_is_not_alone_is_applied_by_the_configurator(rig, hub):
    switch_routed(rig, hub)
    ack = rig.request("switch_to_b")
    assert ack.ok and rig.port("sink", "inp").key.endswith("b/out")
    assert rig.workers.local_switches.done == [], "something else may still be applied"


def test_a_failure_after_a_local_switch_undoes_the_switch(rig, hub):
    switch_routed(rig, hub)
    before = rig.port("sink", "inp").key
    ack = rig.request("switch_then_fail", alone=True)
    assert not ack.ok and ack.step == "call sink.fail"
    assert rig.workers.local_switches.done[-1].ok
    assert rig.port("sink", "inp").key == before, "switched back"
    assert rig.configurator.history[-1].rolled_back == 1
    assert rig.configurator.restore_steps({"sink"}) == [], "the Configurator's map agrees"


def test_a_switch_the_process_cannot_make_fails_at_that_step(rig, hub):
    switch_routed(rig, hub)
    b_out = next(k for k in rig.port("sink", "inp").prepared if k.endswith("b/out"))
    rig.port("sink", "inp").unprepare(b_out)  # its standby subscription is gone
    ack = rig.request("switch_to_b", alone=True)
    assert not ack.ok
    assert ack.step == f"connect sink.inp -> {b_out}"
    assert "workers: " in ack.reason and "no standby subscription" in ack.reason
    assert rig.port("sink", "inp").key.endswith("a/out"), "the disconnect undone"
    assert rig.workers.components["dbl"].get_property("gain") == 2.0, "nothing after it ran"


def test_a_switch_nobody_reports_fails_and_is_undone(rig, hub):
    switch_routed(rig, hub)
    rig.workers.local_switches.switches.clear()  # the process no longer switches by itself
    ack = rig.request("unplug", alone=True)
    assert not ack.ok and ack.step == "disconnect sink.inp"
    assert "workers did not report its local switch within 2 s" in ack.reason
    assert rig.port("sink", "inp").key.endswith("a/out"), "the wiring is restored"


def test_a_failed_step_reads_as_the_step_and_its_reason():
    """What a log or a traceback prints of a failed step: which step, then why."""
    failed = StepFailed("call sink.fail", "sink: asked to fail")
    assert str(failed) == "call sink.fail: sink: asked to fail"
    assert (failed.step, failed.reason) == ("call sink.fail", "sink: asked to fail")


def test_each_request_is_applied_and_answered_once(rig):
    """One answer per request, in request order: a request read again (its sample is
    still the port's last) is never applied a second time."""
    before = len(rig.configurator.history)
    assert rig.request("to_b").ok
    assert rig.request("setup").ok
    assert rig.request("to_b").ok
    assert [a.request_id for a in rig.answers()] == [1, 2, 3]
    applied = [o.tag for o in rig.configurator.history[before:] if o.tag != "probe"]
    assert applied == ["to_b", "setup", "to_b"], "the routing probes aside"


def test_a_configurator_stopped_and_started_again_serves_as_before(rig):
    assert rig.configurator.stop() and rig.configurator.state.value == "Stopped"
    assert rig.configurator.start()
    assert rig.request("to_b").ok
    assert rig.port("sink", "inp").key.endswith("b/out")


def test_a_prepared_switch_with_a_deadline_is_made_and_answered_in_time(rig, hub):
    """The Coordinator's requests carry their deadline: the Configurator waits for the
    process's report no longer than the deadline allows, and a switch made in time is
    recorded as any other."""
    switch_routed(rig, hub)
    ack = rig.request("switch_to_b", alone=True, deadline=time.time() + 5.0)
    assert ack.ok, ack.reason
    assert rig.workers.local_switches.done[-1].request_id == ack.request_id
    assert rig.port("sink", "inp").key.endswith("b/out")


@pytest.mark.parametrize("ahead", [1.0, None], ids=["requester ahead", "requester unmeasured"])
def test_a_process_never_switches_for_a_request_late_on_the_requesters_clock(rig, hub, ahead):
    """The Coordinator's host runs 1 s ahead of the process's (or is not measured yet):
    a request whose deadline passed there is not switched by the process, though on its
    own clock half a second would be left. It says so at once, and the request fails
    with its reason, nothing switched."""
    switch_routed(rig, hub)
    switches = rig.workers.local_switches
    switches.requester_now = (lambda: time.time() + ahead) if ahead else (lambda: None)
    before = rig.port("sink", "inp").key
    ack = rig.request("switch_to_b", alone=True, deadline=time.time() + 0.5)
    assert not ack.ok and ("deadline passed" in ack.reason or "cannot be timed" in ack.reason)
    assert "workers" in ack.reason and "did not report" not in ack.reason, "said, not waited"
    assert rig.port("sink", "inp").key == before, "nothing switched"
    assert not switches.done[-1].ok and ack.step == "disconnect sink.inp"


def test_a_configuration_that_connects_a_port_twice_ends_on_the_second(rig):
    """A connection already so is skipped as judged by the steps before it: connecting
    b and then a again leaves the port on a (the wiring's own value), not on b."""
    assert rig.apply("there_and_back").ok
    assert rig.port("sink", "inp").key.endswith("a/out")
    assert rig.configurator.restore_steps({"sink"}) == [], "the Configurator's map agrees"


def test_a_configurator_stopped_no_longer_listens_for_switch_reports(rig, peer):
    """Stopping releases its subscription to the processes' switch reports (started and
    stopped again, nothing is left listening: no subscription leaks per restart)."""
    probe = peer.publisher(keys.config_switched("spec"), cache=False)
    try:
        assert wait_until(lambda: probe.matching_status.matching, 10), "listening"
        assert rig.configurator.stop()
        assert wait_until(lambda: not probe.matching_status.matching, 10), "released"
        assert rig.configurator.start()
        assert wait_until(lambda: probe.matching_status.matching, 10), "listening again"
    finally:
        probe.undeclare()


class Link:
    """The network between the workers' process and the Configurator as the switch
    reports cross it: `lose` drops them, `delay` holds each that long (s)."""

    def __init__(self, publisher, lose=False, delay=0.0, rewrite=None):
        self.publisher, self.lose, self.delay = publisher, lose, delay
        self.rewrite = rewrite

    def put(self, data):
        time.sleep(self.delay)
        if self.rewrite is not None:
            report, _, _ = messages.decode(data, ConfigAck)
            data = messages.encode(self.rewrite(report), ConfigAck)
        if not self.lose:
            self.publisher.put(data)

    def undeclare(self):
        self.publisher.undeclare()


def cut_reports(rig, **link):
    switches = rig.workers.local_switches
    switches._publisher = Link(switches._publisher, **link)


def test_a_switch_made_but_whose_report_is_lost_is_undone(rig, hub):
    """The process switched, its report never came: the Configurator cannot know what
    the port is on, so it restores what its wiring says and the request fails. With a
    deadline the wait is bounded by it (plus one step's time), not by all the steps'."""
    switch_routed(rig, hub)
    cut_reports(rig, lose=True)
    ack = rig.request("switch_to_b", alone=True, deadline=time.time() + 0.5)
    assert rig.workers.local_switches.done[-1].ok, "the process switched"
    assert not ack.ok and ack.step == "disconnect sink.inp"
    assert "workers did not report its local switch within" in ack.reason
    waited = float(ack.reason.split(" within ")[1].split(" s")[0])
    assert 2.0 < waited <= 2.5, "the deadline's 0.5 s and a step's 2 s, not both steps' 4 s"
    assert rig.port("sink", "inp").key.endswith("a/out"), "switched back"
    assert rig.workers.components["dbl"].get_property("gain") == 2.0, "nothing after it ran"
    assert rig.configurator.restore_steps({"sink"}) == [], "the Configurator's map agrees"


def test_a_failed_switch_report_naming_no_step_of_it_restores_every_switched_port(rig, hub):
    """A report that says the switch failed at a step the Configurator never asked for
    (a garbled label, another version's) tells nothing of what was made: every port of
    the switch goes back to what the wiring says, as when no report comes."""
    switch_routed(rig, hub)

    def garbled(report):
        return ConfigAck(report.stamp, report.request_id, False, report.tag, "connect ?", "x")

    cut_reports(rig, rewrite=garbled)
    ack = rig.request("switch_to_b", alone=True)
    assert rig.workers.local_switches.done[-1].ok, "the process switched"
    assert not ack.ok and ack.step == "connect ?"
    assert wait_until(lambda: rig.port("sink", "inp").key.endswith("a/out")), "switched back"
    assert rig.workers.components["dbl"].get_property("gain") == 2.0, "nothing after it ran"
    assert rig.configurator.restore_steps({"sink"}) == [], "the Configurator's map agrees"


def test_a_switch_reported_after_the_requests_deadline_is_undone(rig, hub):
    """A switch-only configuration whose report comes late is no success: the chart gave
    up on it, so the switch is undone and the failure says why."""
    switch_routed(rig, hub)
    cut_reports(rig, delay=0.8)
    ack = rig.request("unplug", alone=True, deadline=time.time() + 0.3)
    assert rig.workers.local_switches.done[-1].ok, "the process switched"
    assert not ack.ok and ack.step == "deadline" and "deadline passed" in ack.reason
    assert wait_until(lambda: rig.port("sink", "inp").key is not None)
    assert rig.port("sink", "inp").key.endswith("a/out"), "connected again"


def test_a_switch_reported_while_the_configurator_waits_wakes_it_at_once(rig, hub):
    """The report wakes the Configurator when it arrives (it does not sleep out its
    bound): a report 0.3 s on the way, so the Configurator is already waiting for it,
    and a step after the switch still fit in a 1.5 s deadline, under one step's 2 s."""
    switch_routed(rig, hub)
    cut_reports(rig, delay=0.3)
    ack = rig.request("switch_to_b", alone=True, deadline=time.time() + 1.5)
    assert ack.ok, ack.reason
    assert rig.workers.components["dbl"].get_property("gain") == 6.0


@pytest.mark.parametrize("tag", ["switch_to_b", "connect_b"])
def test_a_restore_forced_after_a_switch_was_asked_is_switched_over_again(rig, hub, tag):
    """A process switched on a request, then a forced restore (a restarted process's)
    put the port back before the Configurator got to the request: the Configurator
    makes the switch again, so the port is where the chart asked last and where the
    Configurator's map says it is."""
    switch_routed(rig, hub)
    restore = [
        Step("call", "sink", "slow", args={"seconds": 1.0}),
        Step("connect", "sink", "inp", key=rig.port("sink", "inp").key, policy=None),
    ]
    done = {}
    worker = threading.Thread(
        target=lambda: done.update(o=rig.configurator.run_steps("restore", restore))
    )
    worker.start()
    assert wait_until(lambda: rig.configurator._apply_lock.locked())
    ack = rig.request(tag, alone=True)
    worker.join(30)
    assert done["o"].ok and ack.ok, ack.reason
    assert rig.workers.local_switches.done[-1].request_id == ack.request_id
    assert rig.port("sink", "inp").key.endswith("b/out"), "switched over again"
    (step,) = rig.configurator.restore_steps({"sink"})
    assert step.key.endswith("b/out"), "the Configurator's map has the switch"
