"""Spec: the safety monitor trips when a watched input misses its deadline or a component
is lost, latches, and only an acknowledge with every input healthy clears it. Producers
run on a stepped clock in a real container (heartbeats through real ports)."""

import threading
import time

import pytest

from components.demo import Counter, Doubler
from framework import keys
from framework.activity import Activity, RealTimeExecutor, SteppedExecutor
from framework.bus import Bus
from framework.clock import SimulatedClock
from framework.container import Container
from framework.safety import SafetyMonitor, SafetySpec, Watch, heartbeat_period
from tests.conftest import wait_until


class Cell:
    """A watched Counter (heartbeat, 100 ms deadline) and a watched port, stepped."""

    def __init__(self, bus, polled=False):
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
        self.monitor = SafetyMonitor(spec, self.clock).attach(bus, polled=polled)
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


@pytest.fixture(params=["called back", "polled"])
def cell(hub, request):
    """Every spec below holds whether arrivals are recorded by callbacks or taken by
    each check (as the robot interface's 1 kHz loop takes them)."""
    c = Cell(hub, polled=request.param == "polled")
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
    assert cell.monitor.report()["trips"] == 1, "one trip, however long it is latched"


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
    assert cell.monitor.report()["armed"], "acknowledged with every input healthy: armed"
    assert set(cell.run(0.5)) == {""}


def test_a_stop_latched_before_arming_and_released_leaves_the_monitor_armed(cell):
    """A trip during start-up (the robot side's own, before every input appeared) keeps
    the monitor from arming while latched; the RELEASE arms it, so a component lost
    right after still stops the robot at the next check."""
    cell.monitor.trip("stopped during start-up")
    assert not cell.monitor.armed
    assert set(cell.run(0.3)) == {"stopped during start-up"}
    assert cell.monitor.acknowledge() == ""
    cell.monitor.set_alive("counter", False)  # lost before the next check
    verdicts = cell.run(0.05)
    assert verdicts[0] and "counter" in verdicts[0], verdicts


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


# --- the monitor alone, fed by hand on a simulated clock ---------------------------------
# Times are binary fractions (1/256 s steps) so that ages land exactly on deadlines.

TICK = 1 / 256  # a check every ~3.9 ms, under the 10 ms starvation limit


def lone_monitor():
    """A monitor hosted by process `robot`, watching its own process heartbeat (62.5 ms,
    beating every 15.6 ms), a component's heartbeat (`x`, 125 ms) and a port (`y.out`,
    62.5 ms); every component alive."""
    spec = SafetySpec(
        "robot",
        (
            Watch("process robot", keys.process_heartbeat("robot"), 0.0625, ""),
            Watch("x", keys.heartbeat("x"), 0.125, "x"),
            Watch("y.out", "y/out", 0.0625, "y"),
        ),
        ("x", "y", "coordinator"),
        process_deadline=0.0625,
    )
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock, "robot")
    for component in ("x", "y", "coordinator"):
        monitor.set_alive(component, True)
    return monitor, clock


def feed(monitor, clock, ticks, watches=(0, 1, 2)):
    """`ticks` control cycles: samples of `watches`, then a check; the verdicts."""
    verdicts = []
    for _ in range(ticks):
        clock.set(clock.now() + TICK)
        for index in watches:
            monitor.arrived(index)
        verdicts.append(monitor.check())
    return verdicts


def test_a_frozen_monitor_process_does_not_count_its_own_freeze_against_the_others():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    assert monitor.armed
    clock.set(clock.now() + 0.25)  # the whole process stood still (SIGSTOP, a frozen VM)
    assert monitor.check() == "", "a late check only records the time"
    clock.set(clock.now() + TICK)
    assert monitor.check() == "", "its own heartbeat was just as late: not the others' fault"
    assert monitor.problems() == []


def test_a_producer_silent_while_the_monitors_process_runs_trips_past_its_deadline():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    verdicts = feed(monitor, clock, 17, watches=(0, 1))  # y.out falls silent
    assert verdicts[:16] == [""] * 16, "62.5 ms exactly is not late yet"
    assert verdicts[16] == "y.out: no data for 66 ms (deadline 62 ms)"


def test_a_check_under_the_starvation_limit_decides_one_over_it_only_records():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    feed(monitor, clock, 14, watches=(0, 1))
    clock.set(clock.now() + 3 * TICK)  # 11.7 ms since the last check: this thread starved
    assert monitor.check() == ""
    monitor.arrived(0)
    clock.set(clock.now() + 2 * TICK)  # 7.8 ms: a normal cycle; y.out silent for 19 ticks
    assert monitor.check() == "y.out: no data for 74 ms (deadline 62 ms)"


def test_one_sample_is_not_yet_proof_of_life():
    monitor, clock = lone_monitor()
    clock.set(TICK)
    for index in range(3):
        monitor.arrived(index)
    assert monitor.problems() == ["x: no data yet", "y.out: no data yet"]
    assert "no data yet" in monitor.ready()
    for index in range(3):
        monitor.arrived(index)
    assert monitor.problems() == [] and monitor.ready() == ""


def test_the_monitors_own_process_heartbeat_is_not_its_problem():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    feed(monitor, clock, 64, watches=(1, 2))
    assert monitor.problems() == [], "the arm's watchdog covers a hung monitor process"


def test_a_lost_producer_is_reported_as_lost_not_also_as_late():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", False)
    feed(monitor, clock, 64, watches=(0,))
    assert monitor.problems() == [
        "y lost (its process died or cannot be reached)",
        "x: no data for 250 ms (deadline 125 ms)",
    ]
    monitor.set_alive("stranger", False)  # not a component of this deployment
    assert len(monitor.problems()) == 2


def test_a_component_lost_while_a_report_looked_still_trips_at_the_next_check():
    """A report (or a RELEASE's readiness) between two checks sees the loss first: the
    next check must still trip on it, whatever the report concluded about the others."""
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", False)
    assert monitor.problems()[0].startswith("y lost")  # a report between cycles
    clock.set(clock.now() + TICK)
    assert monitor.check() == "y lost (its process died or cannot be reached)"


def test_a_component_gone_and_back_between_checks_is_judged_by_its_inputs_at_once():
    """Its token went (a report saw it gone) and came back before the next check; its
    output fell silent meanwhile: the next check past its deadline trips, it is not
    left out as it was while gone."""
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", False)
    monitor.problems()  # a report while y was gone: y's output was not looked at
    monitor.set_alive("y", True)
    verdicts = feed(monitor, clock, 17, watches=(0, 1))  # y.out silent
    assert verdicts[:16] == [""] * 16
    assert verdicts[16] == "y.out: no data for 66 ms (deadline 62 ms)"


def test_a_token_that_comes_back_during_a_look_leaves_the_next_check_to_look_again():
    """The bus's thread may say a component is back while the loop's thread is judging
    the others without it: that judgement must not let the next check skip its inputs."""
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", False)
    judge = monitor._own_stall

    def back_meanwhile(*args):  # y's token returns in the middle of the look
        monitor.set_alive("y", True)
        return judge(*args)

    monitor._own_stall = back_meanwhile
    monitor.problems()
    monitor._own_stall = judge
    verdicts = feed(monitor, clock, 17, watches=(0, 1))  # y.out silent
    assert verdicts[16] == "y.out: no data for 66 ms (deadline 62 ms)"


def test_the_report_says_each_inputs_age_worst_silence_and_deadline():
    monitor, clock = lone_monitor()
    assert monitor.report()["watches"]["x"] == {
        "age_ms": None,
        "worst_ms": 0.0,
        "deadline_ms": 125.0,
    }
    feed(monitor, clock, 64)
    feed(monitor, clock, 10, watches=(0, 2))  # x skips 39 ms of beats
    feed(monitor, clock, 4)
    monitor.set_alive("coordinator", False)
    clock.set(clock.now() + 0.0015)
    report = monitor.report()
    assert report["latched"] == "" and report["armed"] and report["trips"] == 0
    assert report["lost"] == ["coordinator"]
    assert report["watches"]["y.out"]["age_ms"] == 1.5
    assert report["watches"]["x"]["worst_ms"] == 39.1
    assert report["watches"]["y.out"]["deadline_ms"] == 62.5


def test_a_safety_spec_travels_as_plain_data():
    monitor, _ = lone_monitor()
    spec = monitor.spec
    assert SafetySpec.from_dict(spec.to_dict()) == spec
    assert spec.process_beat == 0.015625, "four beats per deadline"
    assert SafetySpec.from_dict({"monitor": "robot"}).process_deadline == 0.05
    assert heartbeat_period(0.004) == 0.002, "never faster than 2 ms"


def test_a_process_heartbeat_beats_from_its_own_thread_until_stopped(hub):
    from framework.messages import Scalar
    from framework.safety import ProcessHeartbeat
    from tests.conftest import drained, reader_port

    seen = reader_port(hub, keys.process_heartbeat("worker"), Scalar)
    beat = ProcessHeartbeat(hub, "worker", 0.002).start()
    assert wait_until(lambda: seen.stats.received >= 3)
    beat.stop()
    assert not beat._thread.is_alive(), "stop returns once its thread has ended"
    counts = [sample.value for sample in drained(seen)]
    assert counts[:3] == [1.0, 2.0, 3.0], "counted from one"
    assert beat.port.keys == [], "stopped: nothing published any more"


def test_a_process_heartbeats_thread_runs_at_the_lowest_real_time_priority_if_allowed(hub):
    """On a busy host an ordinary beat thread waited for a core behind the host's other
    programs (healthy processes silent for 80-104 ms under 3 busy loops; 35-55 ms at
    SCHED_FIFO 1): it takes the lowest real-time priority where the host allows it, and
    beats at its process's nice level where not."""
    import os

    from framework.messages import Scalar
    from framework.safety import BEAT_PRIORITY, ProcessHeartbeat
    from tests.conftest import reader_port
    from tests.framework.test_realtime import fifo_allowed

    seen = reader_port(hub, keys.process_heartbeat("prioritised"), Scalar)
    beat = ProcessHeartbeat(hub, "prioritised", 0.002).start()
    try:
        assert wait_until(lambda: seen.stats.received >= 3), "it beats either way"
        thread = beat._thread.native_id
        if fifo_allowed():
            assert os.sched_getscheduler(thread) == os.SCHED_FIFO
            assert os.sched_getparam(thread).sched_priority == BEAT_PRIORITY == 1
        else:
            assert os.sched_getscheduler(thread) == os.SCHED_OTHER
    finally:
        beat.stop()


def test_a_polled_monitor_takes_the_arrivals_when_asked_if_ready_between_checks(hub):
    """A RELEASE asks `ready` in the loop's thread between two checks: a polled monitor
    takes what arrived meanwhile then, so healthy inputs are seen healthy."""
    cell = Cell(hub, polled=True)
    try:
        assert wait_until(lambda: not any("lost" in p for p in cell.monitor.problems()))
        for _ in range(3):
            cell.executor.advance(0.05)  # no check: only `ready` takes the arrivals
            verdict = cell.monitor.ready()
        assert verdict == ""
    finally:
        cell.close()


def test_a_real_time_loop_beats_for_its_process_and_a_hung_loop_falls_silent(hub):
    """In a process with a real-time loop the loop itself beats between its cycles: no
    thread of ordinary priority holds the interpreter it waits for; and a loop that hangs
    leaves its process silent, as SIGSTOP would."""
    from framework.component import Component
    from framework.messages import Scalar
    from framework.realtime import RealTimePolicy
    from tests.conftest import reader_port

    class Clock(Component):
        needs_configuration = False
        realtime = True  # a device's own clock: the loop of its process

        def __init__(self, name):
            super().__init__(name)
            self.hang = threading.Event()
            self.beaten_from: set[str] = set()

        def update_hook(self):
            while self.hang.is_set():
                time.sleep(0.001)

    seen = reader_port(hub, keys.process_heartbeat("loop_process"), Scalar)
    executor = RealTimeExecutor(RealTimePolicy(enabled=False))
    container = Container("loop_process", hub, executor, beat=0.005)
    clock = container.add(Clock("clock"), Activity.periodic(200))
    writes = container.beat.port.write
    container.beat.port.write = lambda v: (
        clock.beaten_from.add(threading.current_thread().name),
        writes(v),
    )[1]
    container.start()
    try:
        clock.start()
        assert wait_until(lambda: seen.stats.received >= 5, timeout=20.0)
        assert clock.beaten_from == {"fw-clock"}, "beaten by the loop's own thread"
        assert not any(t.name.startswith("fw-beat-") for t in threading.enumerate())
        clock.hang.set()
        time.sleep(0.05)  # the last beat before the hang arrives
        silent_from = seen.stats.received
        time.sleep(0.1)  # 20 periods
        assert seen.stats.received == silent_from, "a hung loop beats no more"
        clock.hang.clear()
        assert wait_until(lambda: seen.stats.received > silent_from), "and again once it runs"
    finally:
        clock.hang.clear()
        container.shutdown()


def test_a_process_without_a_real_time_loop_beats_from_a_thread_of_its_own(hub):
    from framework.messages import Scalar
    from tests.conftest import reader_port

    seen = reader_port(hub, keys.process_heartbeat("plain_process"), Scalar)
    container = Container("plain_process", hub, RealTimeExecutor(), beat=0.005)
    container.add(Counter("count"), Activity.periodic(50))
    container.start()
    try:
        assert wait_until(lambda: seen.stats.received >= 3)
        assert any(t.name == "fw-beat-plain_process" for t in threading.enumerate())
    finally:
        container.shutdown()


# --- what the quiet check skips, and the margins it keeps ------------------------------


def counting_looks(monitor):
    """Count the monitor's full looks at every watch (`_problems`)."""
    looks = [0]
    look = monitor._problems

    def counted():
        looks[0] += 1
        return look()

    monitor._problems = counted
    return looks


def test_a_quiet_cycle_looks_at_no_watch_until_one_could_be_late():
    """The 1 kHz loop's budget: with every input on time, a check only takes the
    arrivals; it looks at the watches again once the earliest (arrival + deadline) has
    come (here y.out's 62.5 ms, 16 ticks after its last sample)."""
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    looks = counting_looks(monitor)
    feed(monitor, clock, 64)  # every input arriving every tick
    assert looks[0] <= 4, "quiet: a look every 16 ticks at most"
    looks[0] = 0
    verdicts = feed(monitor, clock, 17, watches=(0, 1))  # y.out silent
    assert looks[0] >= 1 and verdicts[-1].startswith("y.out: no data for 66 ms")


def test_a_watchs_margin_is_its_longest_silence_while_armed_not_its_start_up():
    monitor, clock = lone_monitor()
    clock.set(TICK)
    monitor.arrived(2)
    clock.set(20 * TICK)  # y.out's first two samples 19 ticks apart: start-up, not armed
    monitor.arrived(2)
    feed(monitor, clock, 64)
    assert monitor.report()["watches"]["y.out"]["worst_ms"] <= round(TICK * 1e3, 1)
    feed(monitor, clock, 8, watches=(0, 1))  # y.out silent 8 ticks, then back
    feed(monitor, clock, 2)
    assert monitor.report()["watches"]["y.out"]["worst_ms"] == round(8 * TICK * 1e3, 1)
    feed(monitor, clock, 4, watches=(0, 1))  # a shorter silence leaves the margin
    feed(monitor, clock, 2)
    assert monitor.report()["watches"]["y.out"]["worst_ms"] == round(8 * TICK * 1e3, 1)


def test_a_frozen_monitor_process_does_not_count_its_freeze_in_anyones_margin():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    clock.set(clock.now() + 0.04)  # the whole process stood still 40 ms
    monitor.check()  # late: only records the time
    feed(monitor, clock, 2)
    assert monitor.report()["watches"]["x"]["worst_ms"] <= round(2 * TICK * 1e3, 1)
    clock.set(clock.now() + 0.04)  # again, and this time its own heartbeat says so
    monitor.arrived(1)
    monitor.arrived(2)
    feed(monitor, clock, 2)
    assert monitor.report()["watches"]["y.out"]["worst_ms"] <= round(2 * TICK * 1e3, 1)


def test_a_lost_producers_silence_is_not_its_inputs_margin():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", False)
    feed(monitor, clock, 8, watches=(0, 1))  # y gone: its output silent too
    monitor.set_alive("y", True)
    monitor.arrived(2)
    assert monitor.report()["watches"]["y.out"]["worst_ms"] <= round(TICK * 1e3, 1)


def test_two_components_lost_and_one_back_still_trips_on_the_other():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("x", False)
    monitor.set_alive("y", False)
    monitor.set_alive("x", False)  # said twice: still one loss of x
    monitor.set_alive("x", True)
    clock.set(clock.now() + TICK)
    assert monitor.check() == "y lost (its process died or cannot be reached)"


def test_a_component_said_alive_twice_then_lost_once_trips():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", True)  # already alive: nothing changes
    monitor.set_alive("y", False)
    clock.set(clock.now() + TICK)
    assert monitor.check().startswith("y lost")


def test_a_producer_named_only_by_a_watch_is_lost_until_its_token_comes():
    spec = SafetySpec("robot", (Watch("z.out", "z/out", 0.1, "z"),), ())
    monitor = SafetyMonitor(spec, SimulatedClock())
    assert monitor.problems()[0] == "z lost (its process died or cannot be reached)"
    monitor.set_alive("z", True)
    assert monitor.problems() == ["z.out: no data yet"]


def test_a_monitor_in_a_process_without_its_own_heartbeat_judges_by_ages_alone():
    spec = SafetySpec("robot", (Watch("y.out", "y/out", 0.0625, "y"),), ("y",))
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock)  # no hosting process named
    monitor.set_alive("y", True)
    verdicts = []
    for tick in range(40):
        clock.set(clock.now() + TICK)
        if tick < 20:
            monitor.arrived(0)
        verdicts.append(monitor.check())
    assert verdicts[:36] == [""] * 36, "62.5 ms after the last sample is not late yet"
    assert verdicts[36] == "y.out: no data for 66 ms (deadline 62 ms)"


def test_a_check_after_the_first_needs_no_earlier_one_to_decide():
    monitor, clock = lone_monitor()
    clock.set(TICK)
    for index in range(3):
        monitor.arrived(index)
        monitor.arrived(index)
    assert monitor.check() == "" and monitor.armed, "the very first check arms it"


def test_a_closed_monitor_hears_nothing_more(hub, bus_config):
    """Closed (its process stopping), it undeclares its subscriptions: later samples
    and tokens change nothing."""
    from framework.messages import Scalar
    from tests.conftest import writer_port

    peer = Bus(bus_config)
    spec = SafetySpec("robot", (Watch("w", "test/w", 0.1, "w"),), ("w",))
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock).attach(hub, polled=True)
    token = peer.token("fw/alive/w")
    beat = writer_port(peer, "test/w", Scalar, owner="w")
    try:
        assert wait_until(lambda: monitor.report()["lost"] == [])
        beat.write(Scalar(0.0, 1.0))
        assert wait_until(lambda: (monitor.poll(), monitor._samples[0])[1] == 1)
        monitor.close()
        beat.write(Scalar(0.0, 2.0))
        token.undeclare()
        time.sleep(0.2)
        monitor.poll()
        assert monitor._samples[0] == 1, "no arrival after close"
        assert monitor.report()["lost"] == [], "no token news after close"
        monitor.close()  # twice: nothing left to undeclare
    finally:
        peer.close()


def test_a_driven_process_heartbeat_beats_once_a_period_however_often_polled(hub):
    from framework.messages import Scalar
    from framework.safety import ProcessHeartbeat
    from tests.conftest import drained, reader_port

    seen = reader_port(hub, keys.process_heartbeat("looped"), Scalar)
    beat = ProcessHeartbeat(hub, "looped", 0.2).start(driven=True)
    started = time.monotonic()
    while time.monotonic() - started < 0.1:  # a 1 kHz loop polls it between cycles
        beat.poll()
        time.sleep(0.001)
    assert wait_until(lambda: seen.stats.received >= 1)
    time.sleep(0.05)
    assert [s.value for s in drained(seen)] == [1.0], "one beat in the first period"
    time.sleep(0.15)
    beat.poll()
    assert wait_until(lambda: seen.stats.received >= 2), "and one in the next"
    beat.stop()
    beat.poll()
    time.sleep(0.05)
    assert seen.stats.received == 2, "stopped: polls beat no more"
    assert not beat._thread.is_alive()


def test_a_process_heartbeat_whose_session_closes_ends_its_thread(hub):
    from framework.safety import ProcessHeartbeat

    beat = ProcessHeartbeat(hub, "closing", 0.002)

    def closed(value):
        raise RuntimeError("session closed")

    beat.port.write = closed
    escaped = []
    previous, threading.excepthook = threading.excepthook, escaped.append
    try:
        beat.start()
        assert wait_until(lambda: not beat._thread.is_alive()), "nothing left to prove"
    finally:
        threading.excepthook = previous
    assert beat._count == 1 and escaped == [], "it ends quietly, no exception escapes"
    beat.stop()


def test_a_component_gone_and_back_leaves_the_quiet_check_as_quiet_as_before():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("y", False)
    monitor.set_alive("y", True)  # back before any check saw it gone
    feed(monitor, clock, 2)
    looks = counting_looks(monitor)
    feed(monitor, clock, 64)
    assert looks[0] <= 4


def test_the_silence_a_margin_counts_leaves_out_the_monitors_own_stall():
    """Its own process heartbeat 12 ticks late (its beat thread starved while the loop
    ran): a silence of x over the same ticks is x's only beyond that stall."""
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    feed(monitor, clock, 12, watches=(2,))  # own beat and x silent 12 ticks (46.9 ms)
    feed(monitor, clock, 1)
    # stall at the last check before x came back: 12 ticks - 2 beat periods (8 ticks)
    assert monitor.report()["watches"]["x"]["worst_ms"] == round(8 * TICK * 1e3, 1)


def test_two_beats_of_its_own_are_enough_to_tell_the_monitors_own_freeze():
    """Two samples of its own process heartbeat (the first may be a cached one) and
    everyone falls silent together: the monitor's own process stood still, nobody is
    blamed; with one own sample it cannot tell, and the silent output trips."""
    for own_beats, trips in ((2, False), (1, True)):
        monitor, clock = lone_monitor()
        for _ in range(own_beats):
            clock.set(clock.now() + TICK)
            monitor.arrived(0)
        for _ in range(4):
            clock.set(clock.now() + TICK)
            monitor.arrived(1)
            monitor.arrived(2)
            monitor.check()
        verdicts = feed(monitor, clock, 40, watches=())
        assert any(verdicts) is trips, own_beats


def test_the_monitors_own_stall_allows_it_two_beat_periods():
    """Its own beat last at tick 26, y's at 20, x on time: at tick 37 y is 17 ticks
    (66 ms) silent, 3 of them inside the own stall (11 ticks late less two 4-tick
    periods): 14 ticks, not late; and the two grow together from there."""
    monitor, clock = lone_monitor()
    for tick in range(1, 61):
        clock.set(tick * TICK)
        if tick <= 26:
            monitor.arrived(0)
        if tick <= 20:
            monitor.arrived(2)
        monitor.arrived(1)
        assert monitor.check() == "", tick


def test_a_heartbeat_of_another_process_has_a_margin_too():
    spec = SafetySpec(
        "robot",
        (Watch("process trackers", keys.process_heartbeat("trackers"), 0.0625, ""),),
        (),
    )
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock, "robot")
    feed(monitor, clock, 8, watches=(0,))
    feed(monitor, clock, 6, watches=())
    feed(monitor, clock, 1, watches=(0,))
    assert monitor.report()["watches"]["process trackers"]["worst_ms"] == round(6 * TICK * 1e3, 1)


def test_the_monitors_own_heartbeat_has_no_margin_of_its_own():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    feed(monitor, clock, 10, watches=(1, 2))
    feed(monitor, clock, 2)
    assert monitor.report()["watches"]["process robot"]["worst_ms"] == 0.0


def test_a_margin_counts_from_the_third_sample_of_an_input_armed_on_two():
    monitor, clock = lone_monitor()
    for _ in range(2):  # every input's second sample arms the monitor
        clock.set(clock.now() + TICK)
        for index in range(3):
            monitor.arrived(index)
        monitor.check()
    assert monitor.armed
    feed(monitor, clock, 6, watches=(0, 1))  # y.out silent 6 ticks before its third
    feed(monitor, clock, 1)
    assert monitor.report()["watches"]["y.out"]["worst_ms"] == round(6 * TICK * 1e3, 1)


def test_a_silence_that_trips_is_the_watchs_margin():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    feed(monitor, clock, 17, watches=(0, 1))  # y.out trips at 66 ms
    assert monitor.report()["watches"]["y.out"]["worst_ms"] >= 62.5


def test_of_several_inputs_lost_or_late_at_once_the_first_named_is_the_reason():
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    monitor.set_alive("x", False)
    monitor.set_alive("y", False)
    clock.set(clock.now() + TICK)
    assert monitor.check() == "x lost (its process died or cannot be reached)"
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    verdicts = feed(monitor, clock, 33, watches=(0,))  # x and y.out silent together
    assert verdicts[16] == "y.out: no data for 66 ms (deadline 62 ms)", "y.out first"
    monitor, clock = lone_monitor()
    feed(monitor, clock, 64)
    feed(monitor, clock, 16, watches=(0, 2))  # x silent from here...
    verdicts = feed(monitor, clock, 17, watches=(0,))  # ...y.out 16 ticks later
    assert verdicts[:16] == [""] * 16
    assert verdicts[16] == "x: no data for 129 ms (deadline 125 ms)", "both late: x named"


@pytest.mark.parametrize(
    ("deadline", "silence", "said"),
    [
        (0.1006 - 1e-9, 0.1006, "no data for 101 ms (deadline 101 ms)"),
        (0.1, 0.1004, "no data for 100 ms (deadline 100 ms)"),
    ],
)
def test_a_trip_says_the_silence_and_the_deadline_to_the_millisecond(deadline, silence, said):
    spec = SafetySpec("robot", (Watch("w", "w/out", deadline, "w"),), ("w",))
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock)
    monitor.set_alive("w", True)
    monitor.arrived(0)
    monitor.arrived(0)
    monitor.check()
    clock.set(silence - 0.001)
    monitor.check()  # starved: records only
    clock.set(silence)
    assert monitor.check() == f"w: {said}"


def test_the_report_says_ages_to_a_tenth_of_a_millisecond():
    spec = SafetySpec("robot", (Watch("w", "w/out", 0.01234, "w"),), ("w",))
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock)
    monitor.arrived(0)
    clock.set(0.12346)
    watch = monitor.report()["watches"]["w"]
    assert watch["age_ms"] == 123.5 and watch["deadline_ms"] == 12.3


def test_a_monitor_attached_without_saying_how_records_arrivals_as_they_come(hub, bus_config):
    from framework.messages import Scalar
    from tests.conftest import writer_port

    peer = Bus(bus_config)
    spec = SafetySpec("robot", (Watch("w", "test/w2", 0.1, "w"),), ("w",))
    monitor = SafetyMonitor(spec, SimulatedClock())
    monitor.close()  # closing before attaching undeclares nothing
    monitor.attach(hub)
    beat = writer_port(peer, "test/w2", Scalar, owner="w")
    try:
        time.sleep(0.2)
        beat.write(Scalar(0.0, 1.0))
        assert wait_until(lambda: monitor._samples[0] == 1), "no check, no poll: called back"
        monitor.close()
        beat.write(Scalar(0.0, 2.0))
        time.sleep(0.2)
        assert monitor._samples[0] == 1, "closed: no callback any more"
    finally:
        peer.close()


def _polled_watch(hub, bus_config):
    """A polled monitor of one input (deadline 50 ms) fed by another session, armed on
    the simulated clock: (monitor, clock, the input's writer, the other session)."""
    from framework.messages import Scalar
    from tests.conftest import writer_port

    peer = Bus(bus_config)
    spec = SafetySpec("robot", (Watch("w", "test/w", 0.05, "w"),), ("w",))
    clock = SimulatedClock()
    monitor = SafetyMonitor(spec, clock).attach(hub, polled=True)
    token = peer.token("fw/alive/w")
    beat = writer_port(peer, "test/w", Scalar, owner="w")
    assert wait_until(lambda: monitor.report()["lost"] == [])
    for n in range(3):  # armed: two samples at least, then a check with both on time
        beat.write(Scalar(0.0, float(n)))
        assert wait_until(lambda n=n: (monitor.poll(), monitor._samples[0])[1] == n + 1)
        clock.advance(0.001)
    assert monitor.check() == "" and monitor.armed
    return monitor, clock, beat, (peer, token)


def test_arrivals_taken_after_a_cycle_count_for_the_next_check(hub, bus_config):
    """The paced loop polls the watches after its command went out; the next cycle's
    check decides on what that poll took, and an arrival the poll did not see waits
    for the next poll (uncounted, it can only make its input look older); a check with
    no poll since the previous one takes the arrivals itself."""
    from framework.messages import Scalar

    monitor, clock, beat, (peer, token) = _polled_watch(hub, bus_config)
    try:
        beat.write(Scalar(0.0, 8.0))
        time.sleep(0.1)
        clock.advance(0.001)
        monitor.poll_after_cycle()
        assert monitor._samples[0] == 4, "the poll after the cycle took it"
        beat.write(Scalar(0.0, 9.0))
        time.sleep(0.1)  # it waits in the ring
        clock.advance(0.001)
        assert monitor.check() == ""
        assert monitor._samples[0] == 4, "the check asked no ring: polled after the cycle"
        clock.advance(0.001)
        assert monitor.check() == ""
        assert monitor._samples[0] == 5, "no poll since the last check: the check takes them"
        beat.write(Scalar(0.0, 10.0))
        time.sleep(0.1)
        clock.advance(0.001)
        assert monitor.check() == ""
        assert monitor._samples[0] == 6, "nor since that one: its own poll was no cycle's"
    finally:
        monitor.close()
        token.undeclare()
        peer.close()


def test_a_check_that_finds_an_input_late_takes_the_arrivals_before_it_trips(hub, bus_config):
    """An input silent past its deadline at the last poll, whose sample came since: the
    check polls again before a trip, so a sample waiting in the ring is never a false
    trip, however recent the last poll was."""
    from framework.messages import Scalar

    monitor, clock, beat, (peer, token) = _polled_watch(hub, bus_config)
    try:
        for _ in range(9):  # checks 5 ms apart, as a braked loop's (a gap over 10 ms
            clock.advance(0.005)  # is the monitor's own starvation, and decides nothing)
            assert monitor.check() == ""
        clock.advance(0.006)
        monitor.poll_after_cycle()  # nothing came: 52 ms since the last sample
        beat.write(Scalar(0.0, 9.0))
        time.sleep(0.1)  # it waits in the ring
        clock.advance(0.001)
        assert monitor.check() == "", "the late input's sample was taken before a trip"
        assert monitor._samples[0] == 4
        beat.write(Scalar(0.0, 10.0))
        time.sleep(0.1)
        clock.advance(0.001)
        assert monitor.check() == ""
        assert monitor._samples[0] == 5, "that poll before a trip was no cycle's either"
        verdicts = []
        for _ in range(12):
            clock.advance(0.005)
            verdicts.append(monitor.check())
        assert verdicts[-1].startswith("w: no data for"), "silent since: it trips"
    finally:
        monitor.close()
        token.undeclare()
        peer.close()
