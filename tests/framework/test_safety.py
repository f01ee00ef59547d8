"""Spec: the safety monitor trips when a watched input misses its deadline or a component
is lost, latches, and only an acknowledge with every input healthy clears it. Producers
run on a stepped clock in a real container (heartbeats through real ports)."""

import pytest

from components.demo import Counter, Doubler
from framework import keys
from framework.activity import Activity, SteppedExecutor
from framework.bus import Bus
from framework.clock import SimulatedClock
from framework.container import Container
from framework.safety import SafetyMonitor, SafetySpec, Watch, heartbeat_period
from tests.conftest import wait_until


class Cell:
    """A watched Counter (heartbeat, 100 ms deadline) and a watched port, stepped."""

    def __init__(self, bus):
        self.clock = SimulatedClock()
        self.executor = SteppedExecutor(self.clock)
        self.container = Container("cell", bus, self.executor)
        self.counter = self.container.add(
            Counter("counter"), Activity.periodic(100), heartbeat=heartbeat_period(0.1)
        )
        self.doubler = self.container.add(Doubler("doubler"), Activity.event("inp"))
        self.container.connect("doubler", "inp", "counter/out")
        spec = SafetySpec(
            "none",
            (
                Watch("counter", keys.heartbeat("counter"), 0.1, "counter"),
                Watch("doubler.out", "doubler/out", 0.05, "doubler"),
            ),
            ("counter", "doubler"),
        )
        self.monitor = SafetyMonitor(spec, self.clock).attach(bus)
        self.container.start()
        for c in (self.counter, self.doubler):
            assert c.configure() and c.start()

    def run(self, seconds: float, step: float = 0.005) -> list[str]:
        """Advance in steps, checking the monitor each step as a control loop would."""
        verdicts = []
        for _ in range(round(seconds / step)):
            self.executor.advance(step)
            verdicts.append(self.monitor.check())
        return verdicts

    def close(self):
        self.monitor.close()
        self.container.shutdown()


@pytest.fixture
def cell(hub):
    c = Cell(hub)
    assert wait_until(lambda: not any("lost" in p for p in c.monitor.problems()))
    yield c
    c.close()


def test_the_monitor_arms_once_every_input_is_healthy_and_stays_quiet(cell):
    assert not cell.monitor.armed
    assert set(cell.run(1.0)) == {""}
    assert cell.monitor.armed and cell.monitor.ready() == ""


def test_a_component_that_stops_running_trips_after_its_deadline_and_the_trip_latches(cell):
    cell.run(0.5)
    cell.counter.stop()  # no more updates: no heartbeat, no samples for the doubler
    verdicts = cell.run(0.2)
    tripped = [i for i, v in enumerate(verdicts) if v]
    assert tripped, "a silent producer must trip the monitor"
    assert tripped[0] * 5 <= 105, "within the deadline plus a step"
    first = verdicts[tripped[0]]
    assert "no data for" in first
    cell.counter.start()  # it comes back: the latch holds
    assert set(cell.run(0.5)) == {first}
    assert cell.monitor.ready().startswith("safety stop latched")


def test_only_an_acknowledge_with_every_input_healthy_clears_the_latch(cell):
    cell.run(0.5)
    cell.counter.stop()
    cell.run(0.3)
    assert cell.monitor.latched
    refused = cell.monitor.acknowledge()
    assert "counter: no data for" in refused and cell.monitor.latched
    cell.counter.start()
    cell.run(0.1)
    assert cell.monitor.acknowledge() == ""
    assert set(cell.run(0.5)) == {""}


def test_a_watched_port_has_its_own_deadline(cell):
    cell.run(0.5)
    cell.doubler.stop()  # the counter still beats; the doubler's samples stop
    verdicts = [v for v in cell.run(0.2) if v]
    assert verdicts and verdicts[0].startswith("doubler.out: no data for")


def test_a_lost_component_trips_at_once(bus_config, hub):
    """Liveliness: the producer's process (here its own session) goes away."""
    clock = SimulatedClock()
    spec = SafetySpec("none", (), ("counter",))
    monitor = SafetyMonitor(spec, clock).attach(hub)
    other = Bus(bus_config)
    container = Container("other", other)
    container.add(Counter("counter"))
    try:
        assert wait_until(lambda: monitor.problems() == [])
        assert monitor.check() == "" and monitor.armed
        other.close()  # like a killed process: the token vanishes
        assert wait_until(lambda: monitor.check() != "")
        assert monitor.latched.startswith("counter lost")
        assert monitor.report()["lost"] == ["counter"]
    finally:
        monitor.close()
        other.close()


def test_before_arming_nothing_trips_but_the_robot_may_not_be_released(hub):
    spec = SafetySpec("none", (Watch("x", "nobody/writes", 0.05, "ghost"),), ("ghost",))
    monitor = SafetyMonitor(spec, SimulatedClock()).attach(hub)
    try:
        assert monitor.check() == ""
        assert not monitor.armed
        assert "ghost lost" in monitor.ready()
    finally:
        monitor.close()


def test_a_monitor_that_was_not_scheduled_does_not_read_its_own_stall_as_a_fault(cell):
    """Its checks come 1 ms apart, then one comes 200 ms late (the host stalled it): the
    samples of that time may still be queued, so that late check decides nothing; the
    next check, when the samples are indeed missing, trips."""
    cell.run(0.5)
    cell.counter.stop()
    cell.clock.advance(0.2)  # nothing ran: the counter is silent, and so was the monitor
    assert cell.monitor.check() == "", "the first check after a stall only takes the time"
    cell.clock.advance(0.001)
    assert cell.monitor.check().startswith(("counter: no data", "doubler.out: no data"))


def test_while_braked_a_late_input_blocks_release_but_a_lost_one_latches(cell, bus_config):
    cell.run(0.5)
    cell.counter.stop()
    for _ in range(40):  # 200 ms, the robot standing braked
        cell.executor.advance(0.005)
        assert cell.monitor.check(released=False) == ""
    assert "counter: no data for" in cell.monitor.ready(), "it may not be released"
    cell.counter.start()
    for _ in range(20):
        cell.executor.advance(0.005)
        assert cell.monitor.check(released=False) == ""
    assert cell.monitor.ready() == "", "on time again: no RELEASE needed, nothing moved"
    cell.monitor.set_alive("doubler", False)  # a lost component is a fault even when braked
    assert cell.monitor.check(released=False).startswith("doubler lost")
