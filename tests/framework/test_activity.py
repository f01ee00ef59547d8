"""Spec: activities run components periodically or on data, in real time or stepped."""

import sys
import threading
from pathlib import Path

import pytest

from components.demo import Counter, Doubler, Sink
from framework.activity import (
    Activity,
    ActivityError,
    RealTimeExecutor,
    SteppedExecutor,
    next_deadline,
)
from framework.clock import SimulatedClock
from framework.component import Component
from framework.container import Container
from tests.conftest import wait_until


class Stamper(Component):
    """Records the simulated time of each update."""

    needs_configuration = False

    def __init__(self, name, clock):
        super().__init__(name)
        self.clock, self.times = clock, []

    def update_hook(self):
        self.times.append(round(self.clock.now(), 9))


def running(component):
    if component.state.value == "PreOperational":
        component.configure()
    component.start()
    return component


def test_stepped_periodic_updates_happen_exactly_at_their_deadlines():
    clock = SimulatedClock()
    ex = SteppedExecutor(clock)
    fast, slow = Stamper("fast", clock), Stamper("slow", clock)
    ex.add(running(fast), Activity.periodic(100))
    ex.add(running(slow), Activity.periodic(30))
    ex.advance(0.1)
    assert fast.times == [round(0.01 * i, 9) for i in range(1, 11)]
    assert slow.times == [round(i / 30, 9) for i in range(1, 4)]
    assert clock.now() == pytest.approx(0.1)


def test_a_periodic_component_may_ask_for_its_next_update_several_periods_later():
    """A controller in monitor mode wakes every n periods and does n periods' work then;
    back in command mode, every period again (the request is read after each update)."""
    clock = SimulatedClock()
    ex = SteppedExecutor(clock)
    arm = Stamper("arm", clock)
    ex.add(running(arm), Activity.periodic(100))
    ex.advance(0.02)
    arm.periods_per_update = 5
    ex.advance(0.1)
    arm.periods_per_update = 1
    ex.advance(0.02)
    assert arm.times == [0.01, 0.02, 0.03, 0.08, 0.13, 0.14]


def test_stepped_runs_are_repeatable():
    def run():
        clock = SimulatedClock()
        ex = SteppedExecutor(clock)
        order = []
        for name, rate in [("a", 50), ("b", 50), ("c", 25)]:
            c = Stamper(name, clock)
            c.update_hook = lambda n=name: order.append((n, round(clock.now(), 9)))
            ex.add(running(c), Activity.periodic(rate))
        for _ in range(7):
            ex.advance(0.013)
        return order

    assert run() == run()


def test_stopped_components_are_not_updated():
    clock = SimulatedClock()
    ex = SteppedExecutor(clock)
    s = Stamper("s", clock)
    ex.add(s, Activity.periodic(10))
    ex.advance(1.0)
    assert s.times == []


def test_event_driven_components_wake_on_new_data(hub, peer):
    producer, consumer = Container("p", hub), Container("c", peer)
    counter = producer.add(Counter("cnt"), Activity.periodic(200))
    doubler = consumer.add(Doubler("dbl"), Activity.event("inp"))
    sink = consumer.add(Sink("snk"), Activity.event("inp"))
    consumer.connect("dbl", "inp", "cnt/out")
    consumer.connect("snk", "inp", "dbl/out")
    for c in (doubler, sink):
        running(c)
    producer.start()
    consumer.start()
    running(counter)
    assert wait_until(lambda: len(sink.call("received")) >= 20)
    seen = sink.call("received")
    assert seen == sorted(set(seen)), "increasing: no duplicates, no reordering"
    assert all(v % 2 == 0 for v in seen), "every value went through the doubler"
    consumer.shutdown()
    producer.shutdown()


def test_activity_specs_are_checked():
    assert Activity.from_spec({"periodic": 100}).rate == 100.0
    assert Activity.from_spec({"event": "inp"}).ports == ("inp",)
    assert Activity.from_spec("passive").kind == "passive"
    with pytest.raises(ActivityError, match="positive rate"):
        Activity.from_spec({"periodic": 0})
    with pytest.raises(ActivityError, match="must be 'passive'"):
        Activity.from_spec({"sometimes": 1})
    with pytest.raises(ActivityError, match=r"unknown input port 'in'.*inp"):
        RealTimeExecutor().add(Doubler("d"), Activity.event("in"))


def test_a_component_after_another_updates_right_after_it_in_its_thread(hub):
    clock = SimulatedClock()
    ex = SteppedExecutor(clock)
    order = []
    lead, follower = Stamper("lead", clock), Stamper("follower", clock)
    lead.update_hook = lambda: order.append(("lead", threading.get_ident()))
    follower.update_hook = lambda: order.append(("follower", threading.get_ident()))
    ex.add(running(lead), Activity.periodic(100))
    ex.add(running(follower), Activity.from_spec({"after": "lead"}))
    ex.advance(0.03)
    assert [name for name, _ in order] == ["lead", "follower"] * 3

    order.clear()
    container = Container("c", hub)  # real time: the follower runs in the lead's thread
    a, b = Stamper("a", clock), Stamper("b", clock)
    a.update_hook = lambda: order.append(("a", threading.get_ident()))
    b.update_hook = lambda: order.append(("b", threading.get_ident()))
    container.add(a, Activity.periodic(200))
    container.add(b, Activity.from_spec({"after": "a"}))
    running(a), running(b)
    container.start()
    try:
        assert wait_until(lambda: len(order) >= 10)
    finally:
        container.shutdown()
    names = [name for name, _ in order[:10]]
    assert names == ["a", "b"] * 5 and len({tid for _, tid in order}) == 1


def test_after_must_name_something():
    with pytest.raises(ActivityError, match="after: COMPONENT"):
        Activity.from_spec({"after": 3})


def test_a_chain_of_after_activities_runs_whole_in_the_masters_thread():
    # the arm, then the robot interface after it, then the interpolator after that: a
    # follower's own follower used to be registered and never run
    order: list[str] = []

    class Step(Component):
        def update_hook(self) -> None:
            order.append(self.name)

    clock = SimulatedClock()
    executor = SteppedExecutor(clock)
    arm, robot, interpolator = Step("arm"), Step("robot"), Step("interpolator")
    for component in (arm, robot, interpolator):
        assert component.configure() and component.start()
    executor.add(interpolator, Activity.from_spec({"after": "robot"}))
    executor.add(robot, Activity.from_spec({"after": "arm"}))
    executor.add(arm, Activity.from_spec({"periodic": 100}))
    executor.advance(0.02)
    assert order == ["arm", "robot", "interpolator"] * 2


def test_an_after_chain_that_comes_back_to_itself_is_refused():
    executor = SteppedExecutor(SimulatedClock())
    a, b = Component("a"), Component("b")
    executor.add(a, Activity.from_spec({"after": "b"}))
    with pytest.raises(ActivityError, match="after itself"):
        executor.add(b, Activity.from_spec({"after": "a"}))


def test_a_periodic_update_that_ends_a_little_late_runs_the_next_at_once_on_the_same_grid():
    period = 1 / 30
    # on time: one period later, nothing late
    assert next_deadline(0.0, 0.010, period) == (period, 0)
    # ended 1 ms past the next deadline: that deadline stands (run now), no period lost
    deadline, late = next_deadline(0.0, period + 0.001, period)
    assert deadline == period and late == 1
    # and the one after is back on the grid
    assert next_deadline(deadline, deadline + 0.005, period) == (2 * period, 0)


def test_periods_missed_entirely_are_skipped_not_bunched():
    period = 0.010
    deadline, late = next_deadline(0.0, 0.0355, period)  # 2.55 periods past the next one
    assert deadline == pytest.approx(0.030) and late == 3  # due at 30 ms: at once, then 40
    assert next_deadline(deadline, 0.036, period)[0] == pytest.approx(0.040)


def test_a_component_that_reports_every_few_periods_is_due_that_many_periods_later():
    assert next_deadline(0.0, 0.001, 0.001, periods=10) == (pytest.approx(0.010), 0)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread names in /proc")
def test_a_component_s_thread_shows_its_name_to_the_host_s_tools(hub):
    """top -H, ps -L and py-spy show which component a busy thread runs."""
    clock = SimulatedClock()
    seen = []
    component = Stamper("sensor_manager", clock)
    component.update_hook = lambda: seen.append(threading.get_native_id())
    container = Container("c", hub)
    container.add(component, Activity.periodic(200))
    running(component)
    container.start()
    try:
        assert wait_until(lambda: seen)
        name = Path(f"/proc/self/task/{seen[0]}/comm").read_text().strip()
    finally:
        container.shutdown()
    assert name == "fw-sensor_manag"  # the host keeps 15 bytes
