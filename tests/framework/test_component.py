"""Spec: the component lifecycle follows RTT's table; failures land in documented states."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.demo import Doubler, Sink
from framework.component import ALLOWED, LifecycleError, OperationError, State
from framework.properties import PropertyError, prop
from tests.support.components import Flaky

S = State


def test_a_new_component_waits_for_configuration_unless_it_needs_none():
    assert Doubler("d").state is S.PRE_OPERATIONAL
    assert Sink("s").state is S.STOPPED


def test_the_nominal_cycle():
    d = Doubler("d")
    assert d.configure() and d.state is S.STOPPED
    assert d.start() and d.state is S.RUNNING
    assert d.stop() and d.state is S.STOPPED
    assert d.cleanup() and d.state is S.PRE_OPERATIONAL


@pytest.mark.parametrize(
    ("op", "state"),
    [
        ("start", S.PRE_OPERATIONAL),
        ("stop", S.PRE_OPERATIONAL),
        ("cleanup", S.PRE_OPERATIONAL),
        ("recover", S.PRE_OPERATIONAL),
    ],
)
def test_wrong_state_calls_are_refused_naming_the_state(op, state):
    d = Doubler("d")
    with pytest.raises(LifecycleError, match=f"cannot {op} 'd' in state {state.value}"):
        getattr(d, op)()
    assert d.state is state


@pytest.mark.parametrize(
    ("hook", "how", "ops", "expected"),
    [
        ("configure", "false", ["configure"], S.PRE_OPERATIONAL),
        ("configure", "raise", ["configure"], S.EXCEPTION),
        ("configure", "refuse", ["configure"], S.PRE_OPERATIONAL),
        ("start", "refuse", ["configure", "start"], S.STOPPED),
        ("start", "false", ["configure", "start"], S.STOPPED),
        ("start", "raise", ["configure", "start"], S.EXCEPTION),
        ("update", "raise", ["configure", "start", "update"], S.EXCEPTION),
        ("stop", "raise", ["configure", "start", "stop"], S.FATAL_ERROR),
        ("cleanup", "raise", ["configure", "cleanup"], S.FATAL_ERROR),
    ],
)
def test_failing_hooks_land_in_documented_states_with_a_reason(hook, how, ops, expected):
    f = Flaky("f")
    f.fail_in, f.how = hook, how
    changes = []
    f.add_state_listener(changes.append)
    for op in ops:
        getattr(f, op)()
    assert f.state is expected
    assert hook in f.last_error
    assert changes and changes[-1].new is expected and hook in changes[-1].reason


def test_runtime_error_runs_the_error_hook_until_recovered():
    d = Doubler("d")
    d.configure()
    d.start()
    d.error("sensor glitch")
    assert d.state is S.RUNTIME_ERROR and d.last_error == "sensor glitch"
    assert d.recover() and d.state is S.RUNNING
    d.exception("boom")
    assert d.state is S.EXCEPTION and d.recover() and d.state is S.PRE_OPERATIONAL


def test_every_state_change_is_reported():
    d = Doubler("d")
    seen = []
    d.add_state_listener(lambda c: seen.append((c.old, c.new)))
    d.configure()
    d.start()
    d.stop()
    assert seen == [(S.PRE_OPERATIONAL, S.STOPPED), (S.STOPPED, S.RUNNING), (S.RUNNING, S.STOPPED)]


def test_properties_are_validated_with_clear_errors():
    d = Doubler("d")
    d.gain = 3
    assert d.gain == 3.0 and isinstance(d.gain, float)
    with pytest.raises(PropertyError, match=r"d\.gain must be <= 1000\.0"):
        d.gain = 5000
    with pytest.raises(PropertyError, match="expects float, got str"):
        d.set_property("gain", "2")
    with pytest.raises(PropertyError, match=r"has no property 'gian'.*gain"):
        d.set_property("gian", 2)
    with pytest.raises(PropertyError, match="finite"):
        d.gain = float("nan")
    with pytest.raises(PropertyError, match="one of"):
        Flaky("f").how = "explode"
    with pytest.raises(PropertyError):
        prop(float, -1.0, min=0.0)


def test_a_required_property_left_empty_fails_configure_naming_it():
    from framework.component import Component

    class Reader(Component):
        source = prop(str, "", doc="what to read", required=True)

        def configure_hook(self) -> bool:
            self.opened = self.source
            return True

    r = Reader("r")
    assert not r.configure() and r.state is S.PRE_OPERATIONAL
    assert r.last_error == "required property source is empty (what to read)"
    assert not hasattr(r, "opened"), "the hook does not run without it"
    r.source = "file.yaml"
    assert r.configure() and r.opened == "file.yaml"
    assert r.describe()["properties"][0]["required"] is True


def test_set_properties_is_all_or_nothing():
    d = Doubler("d")
    with pytest.raises(PropertyError):
        d.set_properties({"gain": 4.0, "nope": 1})
    assert d.gain == 2.0


def test_operations_check_their_arguments_and_report_failures():
    s = Sink("s")
    assert s.call("slow", seconds=0) == "done"
    with pytest.raises(OperationError, match="unexpected keyword argument 'secs'"):
        s.call("slow", secs=1)
    with pytest.raises(OperationError, match=r"has no operation 'sleep'.*slow"):
        s.call("sleep")
    with pytest.raises(OperationError, match="ValueError: asked to fail"):
        s.call("fail")


def test_describe_lists_ports_properties_and_operations():
    info = Sink("s").describe()
    assert [p["name"] for p in info["inputs"]] == ["inp", "pose"]
    assert info["inputs"][0]["policy"] == {
        "type": "buffer",
        "size": 1000,
        "overflow": "drop_oldest",
    }
    assert {o["name"] for o in info["operations"]} >= {"received", "slow", "fail"}
    assert info["state"] == "Stopped"


# -- the lifecycle against a reference model of RTT's table -------------------------------
OPS = ["configure", "start", "stop", "cleanup", "recover", "error", "update", "exception"]


def model_step(state, initial, op, fail_in, how):
    """What RTT's table says happens (returns the new state, or 'refused')."""

    def exception_transition(was):
        if was in (S.EXCEPTION, S.FATAL_ERROR):
            return was
        if fail_in == "stop" and was in (S.RUNNING, S.RUNTIME_ERROR):
            return S.FATAL_ERROR
        if (
            fail_in == "cleanup"
            and was in (S.STOPPED, S.RUNNING, S.RUNTIME_ERROR)
            and initial is S.PRE_OPERATIONAL
        ):
            return S.FATAL_ERROR
        if fail_in == "exception":
            return S.FATAL_ERROR
        return S.EXCEPTION

    if op == "exception":
        return exception_transition(state)
    if op == "update":
        if state is S.RUNNING and fail_in == "update" and how == "raise":
            return exception_transition(state)
        return state
    if op in ALLOWED and state not in ALLOWED[op]:
        return "refused"
    hook_fails = fail_in == op
    if op == "configure":
        if hook_fails:
            return exception_transition(state) if how == "raise" else state
        return S.STOPPED
    if op == "start":
        if hook_fails:
            return exception_transition(state) if how == "raise" else S.STOPPED
        return S.RUNNING
    if op == "stop":
        return exception_transition(state) if hook_fails else S.STOPPED
    if op == "cleanup":
        return exception_transition(state) if hook_fails else S.PRE_OPERATIONAL
    if op == "recover":
        return S.RUNNING if state is S.RUNTIME_ERROR else initial
    if op == "error":
        return S.RUNTIME_ERROR
    raise AssertionError(op)


@settings(max_examples=300, deadline=None)
@given(
    fail_in=st.sampled_from(["", "configure", "start", "update", "stop", "cleanup", "exception"]),
    how=st.sampled_from(["raise", "false"]),
    ops=st.lists(st.sampled_from(OPS), max_size=30),
)
def test_random_operation_sequences_follow_the_table(fail_in, how, ops):
    f = Flaky("f")
    f.fail_in, f.how = fail_in, how
    state = f.state
    for op in ops:
        expected = model_step(state, S.PRE_OPERATIONAL, op, fail_in, how)
        if expected == "refused":
            with pytest.raises(LifecycleError):
                getattr(f, op)()
            assert f.state is state
            continue
        if op == "exception":
            f.exception("injected")
        elif op == "error":
            f.error("injected")
        else:
            getattr(f, op)()
        assert f.state is expected, (op, state, fail_in, how)
        assert f.state in set(State) - {S.INIT}
        state = f.state


def test_properties_load_from_yaml_with_located_errors(write):
    from framework.errors import FindingsError

    d = Doubler("d")
    d.load_properties(write("gain: 4\n", "ok.yaml"))
    assert d.gain == 4.0
    bad = write("gain: -1\ngian: 2\n", "bad.yaml")
    with pytest.raises(FindingsError) as err:
        d.load_properties(bad)
    lines = [f.one_line() for f in err.value.findings]
    assert lines[0].startswith(f"{bad}:1:1: gain: error[property-value]: property d.gain must")
    assert lines[1].startswith(f"{bad}:2:1: gian: error[unknown-property]")
    assert d.gain == 4.0, "nothing applied from a bad file"


def test_declarations_that_shadow_the_component_api_are_refused():
    from framework.component import Component, operation
    from framework.errors import FwError

    class Bad(Component):
        @operation
        def state(self):
            return "mine"

    with pytest.raises(FwError, match=r"Bad\.state shadows the component API"):
        Bad("b")


def test_a_refused_sample_is_said_and_a_flood_is_counted_not_repeated():
    from framework.clock import SimulatedClock

    clock = SimulatedClock()
    c = Sink("consumer")
    c.clock = clock
    said = []
    c.add_refusal_listener(said.append)
    for _ in range(5):
        c.refuse("inp", "value 7 is over the limit 5")
    assert [(r.port, r.count) for r in said] == [("inp", 1)]
    clock.advance(c.REFUSAL_PERIOD)
    c.refuse("inp", "value 9 is over the limit 5")
    assert [(r.reason, r.count) for r in said][1] == ("value 9 is over the limit 5", 5)
    c.refuse("other", "malformed")
    assert said[-1].port == "other", "each port has its own budget"


def test_the_flight_recorder_keeps_every_refusal(hub, tmp_path):
    import time

    from framework.activity import Activity, SteppedExecutor
    from framework.clock import SimulatedClock
    from framework.container import Container
    from framework.recorder import FlightRecorder, read_recording

    recorder = FlightRecorder(tmp_path / "run.mcap", hub)
    container = Container("c", hub, SteppedExecutor(SimulatedClock()))
    consumer = container.add(Sink("consumer"), Activity.event("inp"))
    before = recorder.count  # one session: its subscription hears its publishers at once
    consumer.refuse("inp", "a forged sample")
    deadline = time.monotonic() + 10
    while recorder.count == before and time.monotonic() < deadline:
        time.sleep(0.01)
    container.shutdown()
    recorder.close()
    refusals = [d for t, _, d in read_recording(tmp_path / "run.mcap") if t == "/fw/refused"]
    assert refusals and refusals[0]["component"] == "consumer"
    assert (refusals[0]["port"], refusals[0]["reason"], refusals[0]["count"]) == (
        "inp",
        "a forged sample",
        1,
    )
