"""Spec: a paced loop (a device's read -> update -> write in one thread) runs its
components' exclusive operations itself, between cycles, so nobody takes their lock in
the middle of one; the device's silence runs `idle_hook`; a stepped run cycles as often
as the device has data. framework/engine.py, framework/activity.py."""

from __future__ import annotations

import queue
import sys
import threading

import pytest

from framework.activity import Activity, ActivityError, RealTimeExecutor, SteppedExecutor
from framework.clock import SimulatedClock
from framework.component import Component, OperationError, Out, operation
from framework.engine import EngineStopped, ExecutionEngine
from framework.messages import Scalar
from framework.ports import ConnPolicy, InputPort, OutputPort
from framework.realtime import RealTimePolicy
from tests.conftest import wait_until


class Device(Component):
    """A paced component whose device is a queue of measurements; it records every hook
    and operation with the thread that ran it and whether a cycle was under way."""

    needs_configuration = False

    def __init__(self, name: str = "device"):
        super().__init__(name)
        self.inbox: queue.Queue[int] = queue.Queue()
        self.log: list[tuple[str, object]] = []
        self.threads: dict[str, int] = {}
        self.in_cycle = False
        self.sent: list[int] = []
        self.idles = 0
        self._taken: int | None = None

    def read_hook(self, timeout: float) -> bool:
        try:
            self._taken = (
                self.inbox.get(timeout=timeout) if timeout > 0 else self.inbox.get_nowait()
            )
        except queue.Empty:
            return False
        self.in_cycle = True
        self.threads["read"] = threading.get_ident()
        return True

    def update_hook(self) -> None:
        self.log.append(("update", self._taken))

    def write_hook(self) -> None:
        self.sent.append(self._taken)
        self.in_cycle = False

    def idle_hook(self) -> None:
        self.idles += 1

    @operation()
    def brake(self) -> str:
        """Exclusive: must run between cycles, in the loop's thread while it runs."""
        self.log.append(("brake", self.in_cycle))
        self.threads["brake"] = threading.get_ident()
        return "braked"

    @operation(readonly=True)
    def report(self) -> dict:
        """Reads what the cycles write: run by the loop like any exclusive operation."""
        self.threads["report"] = threading.get_ident()
        return {"sent": len(self.sent)}

    @operation(exclusive=False)
    def wait_for(self) -> bool:
        """Waits (as `await_ready` does): in the caller's thread, never the loop's."""
        self.threads["wait_for"] = threading.get_ident()
        return True

    @operation()
    def fail(self) -> None:
        raise ValueError("no such thing")


class Follower(Component):
    """Runs after the device, in its cycle."""

    needs_configuration = False

    def __init__(self, device: Device):
        super().__init__("follower")
        self.device = device

    def update_hook(self) -> None:
        self.device.log.append(("follow", self.device._taken))

    @operation()
    def set(self) -> bool:
        self.device.log.append(("follower.set", self.device.in_cycle))
        self.device.threads["follower.set"] = threading.get_ident()
        return True


def running(component: Component) -> Component:
    if component.state.value == "PreOperational":
        component.configure()
    component.start()
    return component


NO_RT = RealTimePolicy(enabled=False, manage_gc=False)  # nor the test process's collector


@pytest.fixture
def loop():
    """A device and its follower run by a real paced loop (no real-time priority: a test
    host need not allow it); stopped afterwards."""
    switch = sys.getswitchinterval()
    executor = RealTimeExecutor(NO_RT)
    device = running(Device())
    follower = running(Follower(device))
    executor.add(device, Activity.paced(0.05))
    executor.add(follower, Activity("after", master="device"))
    executor.start()
    wait_until(lambda: device.engine.running, timeout=5)
    yield executor, device, follower
    executor.stop()
    sys.setswitchinterval(switch)


def test_each_cycle_is_read_update_followers_write_in_the_loops_thread(loop):
    _, device, _ = loop
    for k in range(5):
        device.inbox.put(k)
    wait_until(lambda: len(device.sent) == 5, timeout=5)
    assert device.sent == [0, 1, 2, 3, 4]
    cycles = [entry for entry in device.log if entry[0] in ("update", "follow")]
    assert cycles == [(kind, k) for k in range(5) for kind in ("update", "follow")]
    assert device.threads["read"] == device.engine.thread_id


def test_an_exclusive_operation_runs_in_the_loop_between_cycles_never_inside_one(loop):
    _, device, follower = loop
    feeding = threading.Event()

    def feed():
        k = 0
        while not feeding.is_set():
            device.inbox.put(k)
            k += 1
            feeding.wait(0.0005)

    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        for _ in range(20):
            assert device.call("brake") == "braked"
            assert follower.call("set") is True
    finally:
        feeding.set()
        feeder.join()
    assert [mid for op, mid in device.log if op in ("brake", "follower.set")] == [False] * 40
    assert device.threads["brake"] == device.engine.thread_id
    assert device.threads["follower.set"] == device.engine.thread_id  # the follower's too


def test_a_report_is_run_by_the_loop_and_a_waiting_operation_by_its_caller(loop):
    _, device, _ = loop
    assert device.call("report") == {"sent": 0}
    assert device.threads["report"] == device.engine.thread_id
    assert device.call("wait_for") is True
    assert device.threads["wait_for"] == threading.get_ident()


def test_an_operation_that_fails_tells_its_caller_and_the_loop_goes_on(loop):
    _, device, _ = loop
    with pytest.raises(OperationError, match="no such thing"):
        device.call("fail")
    device.inbox.put(7)
    wait_until(lambda: device.sent == [7], timeout=5)


def test_a_silent_device_runs_idle_hook(loop):
    _, device, _ = loop
    wait_until(lambda: device.idles >= 2, timeout=5)


def test_once_the_loop_stops_the_caller_runs_the_operation_itself(loop):
    executor, device, _ = loop
    executor.stop()
    assert not device.engine.running
    assert device.call("brake") == "braked"
    assert device.threads["brake"] == threading.get_ident()


def test_what_is_still_queued_when_the_loop_stops_is_refused_not_run():
    engine = ExecutionEngine("robot")
    ran: list[int] = []
    outcomes: list[object] = []

    def ask():
        try:
            outcomes.append(engine.call(lambda: ran.append(1)))
        except EngineStopped as exc:
            outcomes.append(exc)

    caller = threading.Thread(target=ask)
    caller.start()
    wait_until(lambda: engine.report()["queued"] == 1, timeout=5)
    engine.stop()
    caller.join()
    assert ran == []
    assert isinstance(outcomes[0], EngineStopped)
    assert "stopped before running it" in str(outcomes[0])


def test_the_loop_runs_queued_operations_whole_within_its_budget_per_gap():
    engine = ExecutionEngine("robot", budget=0.0)
    ran: list[int] = []
    callers = [
        threading.Thread(target=engine.call, args=(lambda k=k: ran.append(k),)) for k in range(3)
    ]
    for caller in callers:
        caller.start()
    wait_until(lambda: engine.report()["queued"] == 3, timeout=5)
    assert engine.run_pending() == 1  # budget spent by the first: the rest wait a gap
    assert engine.run_pending() == 1
    assert engine.run_pending() == 1
    assert engine.run_pending() == 0
    for caller in callers:
        caller.join()
    assert sorted(ran) == [0, 1, 2]
    assert engine.report()["operations"] == 3


def test_a_follower_added_to_a_running_loop_joins_its_cycles_whole():
    """Registered after the loop started (`add` allows it): from then on it updates
    right after the device in each cycle, and its after-the-command work (deferred
    samples, `after_cycle_hook`) runs with the others', as for one there from the start."""
    switch = sys.getswitchinterval()
    executor = RealTimeExecutor(NO_RT)
    device = running(Device())
    executor.add(device, Activity.paced(0.05))
    executor.start()
    try:
        wait_until(lambda: device.engine.running, timeout=5)
        device.inbox.put(0)
        assert wait_until(lambda: device.sent == [0], timeout=5)
        follower = running(Follower(device))
        port = follower.outputs["news"] = OutputPort("news", Scalar)
        executor.add(follower, Activity("after", master="device"))
        for k in range(1, 4):
            device.inbox.put(k)
        assert wait_until(lambda: len(device.sent) == 4, timeout=5)
        cycles = [entry for entry in device.log if entry[0] in ("update", "follow")]
        assert cycles == [("update", 0)] + [
            (kind, k) for k in range(1, 4) for kind in ("update", "follow")
        ]
        assert follower.after_cycles, "its after-the-command work runs in the loop"
        assert port._deferred is not None, "its samples for other processes wait for the command"
    finally:
        executor.stop()
        sys.setswitchinterval(switch)


def test_a_caller_the_loop_does_not_serve_in_time_is_told_so():
    engine = ExecutionEngine("robot")
    with pytest.raises(EngineStopped, match="did not run it within"):
        engine.call(lambda: None, timeout=0.01)
    assert engine.report()["queued"] == 0  # taken back: it will never run late


def test_a_stepped_run_cycles_once_per_measurement_the_device_has():
    clock = SimulatedClock()
    executor = SteppedExecutor(clock)
    device = running(Device())
    follower = running(Follower(device))
    executor.add(device, Activity.paced(0.05))
    executor.add(follower, Activity("after", master="device"))
    for k in range(3):
        device.inbox.put(k)
    executor.advance(0.001)
    assert device.sent == [0, 1, 2]
    assert ("follow", 2) in device.log
    assert device.call("brake") == "braked"  # no loop thread: run directly


def test_paced_activities_are_specified_by_their_idle_time():
    assert Activity.from_spec({"paced": "20ms"}) == Activity.paced(0.02)
    assert Activity.paced(0.02).to_spec() == {"paced": 0.02}
    for bad in ({"paced": "forever"}, {"paced": -1}, {"paced": "20 s"}):
        with pytest.raises(ActivityError):
            Activity.from_spec(bad)


def test_a_component_without_a_device_cannot_be_paced():
    plain = running(Component("plain"))
    plain.read_cycle(0.0)
    assert plain.state.value == "Exception"
    assert "cannot be paced" in plain.last_error


class Publisher(Device):
    """A device whose cycles write a sample on an output port, and which records, at its
    write (the command to the device), how many of them still wait to be sent."""

    out = Out(Scalar, doc="one sample per cycle")

    def __init__(self) -> None:
        super().__init__("publisher")
        self.waiting_at_write: list[int] = []

    def update_hook(self) -> None:
        super().update_hook()
        self.out.write(Scalar(0.0, float(self._taken)))

    def write_hook(self) -> None:
        self.waiting_at_write.append(len(self.out._deferred or ()))
        super().write_hook()

    def after_cycle_hook(self) -> None:
        self.log.append(("after", self._taken))
        self.threads["after"] = threading.get_ident()


class LateFollower(Follower):
    def after_cycle_hook(self) -> None:
        self.device.log.append(("follower.after", self.device._taken))


def test_after_each_command_the_loop_runs_the_after_cycle_hooks_then_sends_what_was_written(
    hub, peer
):
    """The bus's work of a cycle (encoding, puts to other processes) and what needs no
    answer within it run after the command to the device went out: at the write the
    cycle's sample still waits; then the components' `after_cycle_hook`s run in the
    loop's thread, in their cycle order; and another process gets every sample."""
    executor = RealTimeExecutor(NO_RT)
    device = running(Publisher())
    follower = running(LateFollower(device))
    device.out.owner, device.out.bus = "publisher", hub
    device.out.connect("k/published")
    remote = InputPort("inp", Scalar, policy=ConnPolicy("buffer", 16))
    remote.owner, remote.bus = "reader", peer
    remote.connect("k/published")
    device.out.write(Scalar(0.0, -1.0))  # a probe: the route to the other process is up
    assert wait_until(lambda: remote.pending() == 1, timeout=10)
    remote.read()
    executor.add(device, Activity.paced(0.05))
    executor.add(follower, Activity("after", master="publisher"))
    switch = sys.getswitchinterval()
    executor.start()
    try:
        assert wait_until(lambda: device.engine.running and device.out._deferred is not None)
        for k in range(5):
            device.inbox.put(k)
        assert wait_until(lambda: len(device.sent) == 5, timeout=5)
        assert wait_until(lambda: remote.pending() == 5, timeout=5)
    finally:
        executor.stop()
        sys.setswitchinterval(switch)
    assert device.waiting_at_write == [1] * 5
    order = [entry for entry in device.log if entry[0] != "brake"]
    assert order == [
        (kind, k) for k in range(5) for kind in ("update", "follow", "after", "follower.after")
    ]
    assert device.threads["after"] == device.threads["read"]  # the loop's own thread
    got = [remote.read()[1].value for _ in range(remote.pending())]
    assert got == [0.0, 1.0, 2.0, 3.0, 4.0]
    # the loop ended: what is written now (a stop_hook's last word) goes out at once
    device.out.write(Scalar(0.0, 9.0))
    assert wait_until(lambda: remote.pending() == 1, timeout=5)
    assert remote.read()[1].value == 9.0


def test_a_sample_a_flush_cannot_encode_sends_its_component_to_exception():
    """What its write would have raised, said with the port's name."""
    device = running(Publisher())
    device.defer_outputs()  # as its loop does
    device.out.bus = None
    device.out._deferred.append((Scalar(0.0, "x"), 1, None, []))
    device.flush_outputs()
    assert device.state.value == "Exception"
    assert "publisher.out" in device.last_error
