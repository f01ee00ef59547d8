"""The SEEG deployment under measurement: started on a private bus, watched by stamps.

`SeegRun` starts `topologies/seeg.yaml` with its own Zenoh port, namespace and Vicra
pseudo-terminal (so a benchmark never meets another deployment), follows the
chart's states through a Coordinator listener and keeps every sample of the keys
the experiments time, each with the time it was received here. All processes run on
this host, so `time.time()` stamps taken in different processes compare directly.
"""

from __future__ import annotations

import bisect
import dataclasses
import os
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from framework import keys
from framework.bus import free_port, free_udp_port
from framework.deployer import Deployment
from framework.errors import FwError
from framework.messages import ConfigAck, EventMessage, Scalar, decode
from framework.remote import RemoteComponent
from framework.statechart.events import Listener
from framework.topology import load_topology
from fw_bench.files import seeg_home

TASK_STATES = (
    "Wait_Start",
    "Moving_Fast",
    "Moving_Slow",
    "Target_Reached",
    "Stopped",
    "No_Tracker",
)
"""The SEEG chart's task states: where the procedure stands between experiments."""

WATCHED: dict[str, type] = {
    "sensor_manager/status": EventMessage,  # t_trackerfail: the verdict's stamp
    "navigator/sources": EventMessage,  # t_newtracker: first valid sample, on receipt
    "supervisor/halt": EventMessage,  # t_stop: the STOP command sent to the robot
    "interpolator/status": EventMessage,  # t_brake: the cycle the motion starts braking
    "people_detector/min_distance": Scalar,  # t_collision: the distance's stamp
    "fw/events": EventMessage,
    keys.ALL_SWITCHED: ConfigAck,  # a process's local switch (the navigator's: a swap)
    "robot/status": EventMessage,  # the robot side's own latched stops (SSM's)
}


TRACKER_WAIT = 10.0
"""Seconds after Wait_Start a run waits for a trusted tracker (the Certus and the
Vicra are trusted within ~0.1 s on a quiet host)."""
TRACKER_POLL = 0.02
"""Seconds between two questions to the Supervisor while waiting for a tracker."""


class BenchError(FwError):
    """An experiment could not run (the deployment did not reach a state in time)."""


@dataclass
class Sample:
    """A message seen on a watched key and when it arrived here."""

    key: str
    message: Any
    received: float


ABORTED = "Setup_Aborted"
"""SEEG's final state for a setup that failed (statecharts/seeg.yaml)."""
ABORTING = ("config.failed", "component.lost")
"""The events that take SEEG's chart there, whose payload says why (asked in this order)."""


class _States(Listener):
    def __init__(self) -> None:
        self.entered: list[tuple[str, float]] = []
        self.taken: list[tuple[str, float]] = []  # events as the chart takes them
        self.payloads: dict[str, Any] = {}  # the last payload of each event taken
        self.requested: list[tuple[str, float]] = []  # configurations the chart asks for
        self.changed = threading.Condition()

    def on_event(self, event: Any) -> None:
        with self.changed:
            self.taken.append((event.name, time.time()))
            self.payloads[event.name] = getattr(event, "payload", None)

    def on_entry(self, state: Any) -> None:
        with self.changed:
            self.entered.append((state.name, time.time()))
            self.changed.notify_all()

    def on_output(self, output: Any) -> None:
        if output.kind == "configure":
            with self.changed:
                self.requested.append((output.tag, time.time()))


@dataclass
class SeegRun:
    """A running SEEG deployment with the stamps the latency experiments need."""

    workdir: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="fw-bench-")))
    deployment: Deployment | None = None
    samples: dict[str, list[Sample]] = field(default_factory=dict)
    _states: _States = field(default_factory=_States)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _subscriptions: list[Any] = field(default_factory=list)
    secure: bool = True
    """The bus as fw deploy runs it (mutual TLS, access rules); False: plain TCP."""
    record: Path | None = None
    """A flight recording of the run (made as `fw deploy --record` makes it, from before
    the chart starts): `recording_gaps` compares it with what was published."""
    recorder: Any = None
    topology_file: Path | None = None
    """Another topology than topologies/seeg.yaml (one that extends it: seeg_ros2)."""
    hosts: tuple[Path, Path] | None = None
    """(topology, keys) of a deployment on several hosts: this run is its control
    host's part (in the control host's network namespace), the other hosts' parts run
    their own `fw deploy --host`; the topology's bus, ports and keys are used as they
    are (every host must agree on them)."""

    def start(self) -> SeegRun:
        """Deploy and wait until the robot waits for START (setup done). A start that
        fails shuts down what it had started before it raises (`with` calls `stop` only
        after a start that returned)."""
        try:
            return self._start()
        except BaseException:
            self.stop()
            raise

    def _start(self) -> SeegRun:
        home = seeg_home()
        old = os.getcwd()
        os.chdir(home)  # the topology's and the properties' paths are relative to it
        try:
            default = self.topology_file or home / "topologies/seeg.yaml"
            topology = load_topology(self.hosts[0] if self.hosts else default)
        finally:
            os.chdir(old)
        if self.hosts is not None:
            self.deployment = Deployment(  # the control host's part (no --host)
                topology, self.workdir, listeners=[self._states], keys=self.hosts[1]
            )
        else:
            self.deployment = Deployment(
                self._private(topology), self.workdir, listeners=[self._states]
            )
        os.chdir(home)  # property paths are relative to the repository
        try:
            self.deployment.start(run_chart=False)
            hub = self.deployment.hub
            assert hub is not None
            for key, kind in WATCHED.items():
                self._subscriptions.append(
                    hub.subscribe(key, self._receiver(key, kind), history=False)
                )
            if self.record is not None:
                from framework.recorder import FlightRecorder

                self.recorder = FlightRecorder.of_topology(
                    self.record, hub, self.deployment.topology
                )
            self.deployment.run_chart()
            self.wait_state("Wait_Start", 60.0)
            self.wait_tracker(TRACKER_WAIT)
        finally:
            os.chdir(old)
        return self

    def wait_tracker(self, timeout: float) -> str:
        """Wait until the Supervisor has a trusted tracker to name, as an operator waits
        for the console to show one before START; returns its name. Setup ends as the
        trackers' first frames arrive, and each must pass its hysteresis before it is
        trusted: a START sent in between is answered e_NOTRACKER and the chart brakes
        until RELEASE (thesis 3.3.4), which is right for the procedure and no run of
        a benchmark. Not trusted in `timeout`: an error with what each tracker lacks."""
        deadline = time.monotonic() + timeout
        while True:
            report = self.call("supervisor.report")
            if report.get("best"):
                return str(report["best"])
            if time.monotonic() >= deadline:
                health = self.call("sensor_manager.current").get("health", {})
                lacks = "; ".join(
                    f"{name}: {h.get('cause') or 'healthy, not trusted yet'}"
                    for name, h in sorted(health.items())
                )
                raise BenchError(
                    f"no tracker trusted {timeout:g} s after Wait_Start ({lacks or 'no sensor'})"
                )
            time.sleep(TRACKER_POLL)

    def recording_gaps(self) -> dict[str, int]:
        """Close the recording, then per channel how many of the chart's records (its
        status: events, transitions, configurations), its configuration requests and the
        Configurator's answers written so far are not in it (0 each: nothing lost)."""
        from framework.recorder import read_recording

        assert self.deployment is not None and self.recorder is not None
        coordinator, configurator = self.deployment.coordinator, self.deployment.configurator
        written = {
            "/fw/chart": coordinator.status.stats.written if coordinator else 0,
            "/fw/config/request": coordinator.requests.stats.written if coordinator else 0,
            "/fw/config/ack": configurator.acks.stats.written if configurator else 0,
        }
        time.sleep(0.5)  # the last ones on their way
        self.recorder.close()
        recorded = dict.fromkeys(written, 0)
        for topic, _, _ in read_recording(self.record):
            if topic in recorded:
                recorded[topic] += 1
        return {topic: max(0, written[topic] - recorded[topic]) for topic in written}

    def _private(self, topology: Any) -> Any:
        """`topology` on a bus, FRI port and Vicra line of this run alone."""
        topology.bus = dataclasses.replace(
            topology.bus,
            namespace=f"fw_bench_{os.getpid()}",
            hub_port=free_port(),
            secure=self.secure,
        )
        port = free_udp_port()  # the FRI link of this deployment alone
        topology.components["arm"].properties["fri_remote"] = f"127.0.0.1:{port}"
        topology.components["robot"].properties["fri_listen"] = f"127.0.0.1:{port}"
        link = str(self.workdir / "ttyVICRA")
        topology.components["vicra_sim"].properties["link"] = link
        topology.components["vicra"].properties["device"] = link
        return topology

    def _receiver(self, key: str, kind: type) -> Any:
        def receive(sample: Any) -> None:
            now = time.time()
            message, _, _ = decode(bytes(sample.payload.to_bytes()), kind)
            with self._lock:
                self.samples.setdefault(key, []).append(Sample(key, message, now))

        return receive

    def watch(self, key: str, kind: type) -> Any:
        """Also keep the samples of `key` (until `unwatch`): for high-rate keys that only
        one experiment needs, so they do not load the others."""
        assert self.deployment is not None and self.deployment.hub is not None
        subscription = self.deployment.hub.subscribe(key, self._receiver(key, kind), history=False)
        self._subscriptions.append(subscription)
        return subscription

    def unwatch(self, subscription: Any) -> None:
        """Stop keeping the samples of a `watch`."""
        subscription.undeclare()
        self._subscriptions.remove(subscription)

    def stop(self) -> None:
        """Shut the deployment down (always call it; `with` does)."""
        if self.recorder is not None:
            try:
                self.recorder.close()
            except Exception as exc:  # the deployment must stop whatever its recording did
                print(f"the recording did not close: {exc}", file=sys.stderr)
        for sub in self._subscriptions:
            sub.undeclare()
        self._subscriptions.clear()
        if self.deployment is not None:
            self.deployment.stop()
            self.deployment = None

    def __enter__(self) -> SeegRun:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- driving ---------------------------------------------------------------------
    def send(self, event: str, payload: dict[str, Any] | None = None) -> None:
        """Give the chart an event (as the console would)."""
        assert self.deployment is not None
        self.deployment.send(event, payload)

    def call(self, ref: str, **args: Any) -> Any:
        """Call `component.operation` on the running deployment."""
        assert self.deployment is not None and self.deployment.hub is not None
        component, _, op = ref.partition(".")
        return RemoteComponent(self.deployment.hub, component, timeout=5.0).call(op, **args)

    def mark(self) -> int:
        """A position in the state history; `wait_state(..., since=mark)` looks after it."""
        with self._states.changed:
            return len(self._states.entered)

    def wait_state(self, name: str, timeout: float, since: int | None = None) -> float:
        """Wait until state `name` is entered (after `since`); returns when it was. A
        setup that aborted (the chart's final `Setup_Aborted`) can never get there: it
        is an error at once, with the chart's reason, instead of a wait to `timeout`."""
        deadline = time.monotonic() + timeout
        with self._states.changed:
            while True:
                start = 0 if since is None else since
                for state, at in self._states.entered[start:]:
                    if state == name:
                        return at
                    if state == ABORTED:
                        raise BenchError(f"state {name} never reached: {self._aborted()}")
                left = deadline - time.monotonic()
                if left <= 0:
                    now = [s for s, _ in self._states.entered[-5:]]
                    raise BenchError(f"state {name} not reached in {timeout:g} s (last: {now})")
                self._states.changed.wait(left)

    def _aborted(self) -> str:
        """Why the setup aborted, from the event the chart took to abort it."""
        for event in ABORTING:
            payload = self._states.payloads.get(event)
            if isinstance(payload, dict):
                said = ", ".join(f"{k}: {v}" for k, v in payload.items())
                return f"the setup aborted on {event} ({said})"
        return "the setup aborted"

    def entered_after(self, name: str, t: float) -> float | None:
        """When state `name` was first entered at or after time `t` (None: not yet)."""
        return self._first_after(self._states.entered, name, t)

    def taken_after(self, name: str, t: float) -> float | None:
        """When the chart first took event `name` at or after time `t` (None: not yet)."""
        return self._first_after(self._states.taken, name, t)

    def left_after(self, names: tuple[str, ...], t: float) -> float | None:
        """When the chart first entered a task state other than `names` at or after
        time `t` (None: it stayed in them)."""
        with self._states.changed:
            history = self._states.entered
            start = bisect.bisect_left(history, t, key=lambda item: item[1])
            return next(
                (at for s, at in history[start:] if s in TASK_STATES and s not in names), None
            )

    def requested_after(self, tag: str, t: float) -> float | None:
        """When the chart first asked for configuration `tag` at or after `t` (None: not yet)."""
        return self._first_after(self._states.requested, tag, t)

    def _first_after(self, history: list[tuple[str, float]], name: str, t: float) -> float | None:
        # bisect: the lock is the Coordinator's too, so a long scan here would delay
        # the very chart being measured
        with self._states.changed:
            start = bisect.bisect_left(history, t, key=lambda item: item[1])
            return next((at for s, at in history[start:] if s == name), None)

    def last_requested(self, tags: tuple[str, ...]) -> str:
        """The most recently requested of the configurations `tags` ("" if none yet)."""
        return self._last_of(self._states.requested, tags)

    def last_entered(self, names: tuple[str, ...]) -> str:
        """The most recently entered of `names` ("" if none yet)."""
        return self._last_of(self._states.entered, names)

    def last_payload(self, event: str) -> Any:
        """The payload of the last `event` the chart took (None: none yet)."""
        with self._states.changed:
            return self._states.payloads.get(event)

    def task_state(self) -> str:
        """The task state the chart entered last ("" before any)."""
        return self.last_entered(TASK_STATES)

    def _last_of(self, history: list[tuple[str, float]], names: tuple[str, ...]) -> str:
        with self._states.changed:
            return next((name for name, _ in reversed(history) if name in names), "")

    def since(self, t: float, key: str) -> list[Sample]:
        """Samples of `key` received after time `t` (in order)."""
        with self._lock:
            samples = self.samples.get(key, [])
            return samples[bisect.bisect_left(samples, t, key=lambda s: s.received) :]
