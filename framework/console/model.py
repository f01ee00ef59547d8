"""What the operator console shows, gathered from a running deployment.

`ConsoleModel` listens on the deployment's bus (the Coordinator's status stream, the
people detector, the robot's TCP) and polls the components' `report` operations and
lifecycle states a few times a second. `snapshot()` is the whole picture as plain
data: a console that connects mid-procedure gets everything at once. Each section
carries its age, so a page can mark what went stale; nothing is invented when a
source is silent.

The procedure panels (operation, area, tracker in use, people, TCP) read the SEEG
components when the topology has them (`supervisor`, `interpolator`, `robot`,
`people_detector`); the chart, commands, component health and the event log work
for any topology.
"""

from __future__ import annotations

import collections
import contextlib
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from framework import keys, messages
from framework.bus import Bus
from framework.coordinator import STATUS_KEY
from framework.messages import EventMessage, Pose, Scalar
from framework.ports import ConnPolicy, InputPort, ReadStatus
from framework.remote import RemoteComponent, RemoteError
from framework.statechart.model import Statechart
from framework.topology import Topology

LOG_SIZE = 300
TRACE_SECONDS = 20.0
TRACE_RATE = 20.0
SEVERITY = {
    "error": "error",
    "unhandled": "debug",  # the chart ignoring an event is normal; refused commands warn
    "command": "info",
    "log": "info",
    "event": "debug",
    "entry": "debug",
}
"""Log severity by Coordinator status kind (anything else is `debug`)."""
STOP_EVENTS = ("e_STOP", "e_NOTRACKER", "e_TFAULT", "e_SETUP_FAILED", "component.lost")


@dataclass
class _Section:
    """One part of the picture and when it was last refreshed (monotonic)."""

    data: Any = None
    at: float = -math.inf

    def view(self, now: float) -> dict[str, Any]:
        return {"data": self.data, "age": None if self.at == -math.inf else now - self.at}


@dataclass
class ConsoleModel:
    """The deployment as the console sees it (see the module docstring)."""

    bus: Bus
    topology: Topology
    chart: Statechart | None
    poll_rate: float = 5.0
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _sections: dict[str, _Section] = field(default_factory=dict)
    _log: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LOG_SIZE))
    _log_seq: int = 0
    _trace: collections.deque = field(default_factory=collections.deque)
    _last_trace: float = 0.0
    _subscriptions: list[Any] = field(default_factory=list)
    _incidents: Any = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _changed: threading.Condition = field(default_factory=threading.Condition)
    _generation: int = 0
    _halt: float | None = None  # the last halt not yet matched by a braking cycle
    _fault: tuple[str, float] | None = None  # (tracker in use, verdict stamp) until a swap
    _in_use: str | None = None
    _thread: threading.Thread | None = None

    # -- lifecycle -----------------------------------------------------------------
    def start(self) -> ConsoleModel:
        """Subscribe and start polling."""
        self._listen(STATUS_KEY, EventMessage, self._on_status, 1024)
        self._listen("robot/tcp", Pose, self._on_tcp, 1)
        self._listen("people_detector/people", EventMessage, self._on_people, 1)
        self._listen("people_detector/min_distance", Scalar, self._on_distance, 1)
        self._listen("supervisor/halt", EventMessage, self._on_halt, 16)
        self._listen("interpolator/status", EventMessage, self._on_motion, 16)
        self._listen("sensor_manager/status", EventMessage, self._on_tracking, 16)
        self._listen("navigator/sources", EventMessage, self._on_source, 16)
        # fw deploy publishes these from its own session, which may be this one
        self._incidents = self.bus.subscribe(keys.DEPLOYER_EVENTS, self._on_incident, False)
        self._thread = threading.Thread(target=self._poll, name="fw-console-poll", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop polling and listening."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        for port in self._subscriptions:
            port.close()
        self._subscriptions.clear()
        if self._incidents is not None:
            with contextlib.suppress(Exception):
                self._incidents.undeclare()
            self._incidents = None

    # -- the picture -----------------------------------------------------------------
    @property
    def external_events(self) -> list[str]:
        """Events an operator may send (the topology's `external_events`)."""
        return list(self.topology.external_events)

    def snapshot(self, log: bool = True) -> dict[str, Any]:
        """Everything the console shows, with each section's age in seconds (`log`:
        with the event log so far; a stream sends it once, then line by line)."""
        now = time.monotonic()
        with self._lock:
            out = {name: section.view(now) for name, section in self._sections.items()}
            out["log"] = list(self._log) if log else []
            out["log_seq"] = self._log_seq
            out["trace"] = list(self._trace)
        out["topology"] = self.topology.name
        out["external_events"] = self.external_events
        out["status"] = self._status(out)
        return out

    def wait_change(self, generation: int, timeout: float) -> int:
        """Block until the chart or the log changed after `generation` (or `timeout`);
        the current generation. Streams use it to push changes at once."""
        with self._changed:
            self._changed.wait_for(lambda: self._generation != generation, timeout)
            return self._generation

    def _touch(self) -> None:
        with self._changed:
            self._generation += 1
            self._changed.notify_all()

    def log_since(self, seq: int) -> list[dict[str, Any]]:
        """Log entries newer than `seq`."""
        with self._lock:
            return [e for e in self._log if e["seq"] > seq]

    def note(self, severity: str, text: str, **extra: Any) -> None:
        """Add a line to the event log (the server logs the commands it forwards)."""
        with self._lock:
            self._log_seq += 1
            self._log.append(
                {
                    "seq": self._log_seq,
                    "t": time.time(),
                    "severity": severity,
                    "text": text,
                    **extra,
                }
            )
        self._touch()

    def _set(self, name: str, data: Any) -> None:
        with self._lock:
            section = self._sections.setdefault(name, _Section())
            section.data, section.at = data, time.monotonic()

    def _get(self, name: str) -> Any:
        with self._lock:
            section = self._sections.get(name)
            return None if section is None else section.data

    # -- listening -----------------------------------------------------------------------
    def _listen(self, key: str, kind: type, handler: Any, size: int) -> None:
        """An input port on `key` (it hears writers in this process and in others)."""
        port: InputPort[Any] = InputPort(key, kind, policy=ConnPolicy("buffer", size))
        port.bus = self.bus

        def drain(p: InputPort[Any]) -> None:
            while True:
                status, value = p.read()
                if status is not ReadStatus.NEW:
                    return
                handler(value)

        port.on_data = drain
        port.connect(key)
        self._subscriptions.append(port)

    def _on_status(self, message: EventMessage) -> None:
        payload = message.payload or {}
        if message.name == "configuration":
            self._set("chart", payload)
            self._touch()
            return
        severity = SEVERITY.get(message.name, "debug")
        if message.name == "event" and payload.get("event") in STOP_EVENTS:
            severity = "warning"
        if message.name == "event" and payload.get("event") == "config.failed":
            severity = "error"
            self._set("failure", payload.get("payload") or {})
        if message.name == "command" and not payload.get("accepted"):
            severity = "warning"
        self.note(severity, _describe(message.name, payload), kind=message.name)

    def _on_incident(self, sample: Any) -> None:
        """fw deploy lost, restarted or gave up on a process: kept in the log, as the
        health table shows only the present."""
        try:
            message, _, _ = messages.decode(sample.payload.to_bytes(), EventMessage)
        except messages.CodecError:
            return
        payload = message.payload or {}
        severity = "info" if message.name == "process_restarted" else "error"
        what = message.name.replace("_", " ")
        self.note(
            severity, f"{payload.get('process')}: {what}: {payload.get('detail')}", kind="incident"
        )

    def _on_tcp(self, pose: Pose) -> None:
        now = time.monotonic()
        if now - self._last_trace < 1.0 / TRACE_RATE:
            return
        self._last_trace = now
        with self._lock:
            self._trace.append([round(pose.stamp, 3), *[round(v, 5) for v in pose.position]])
            while self._trace and self._trace[-1][0] - self._trace[0][0] > TRACE_SECONDS:
                self._trace.popleft()
        self._set("tcp", {"position": list(pose.position), "stamp": pose.stamp})

    # reaction latencies, measured live as `fw bench` does (docs/bench.md)
    def _on_halt(self, message: EventMessage) -> None:
        self._halt = message.stamp

    def _on_motion(self, message: EventMessage) -> None:
        halt = self._halt
        if message.name == "stopping" and halt is not None and 0 <= message.stamp - halt < 1.0:
            self._latency("STOP sent -> braking", message.stamp - halt)
            self._halt = None

    def _on_tracking(self, message: EventMessage) -> None:
        in_use = ((self._get("supervisor") or {}).get("tracker")) or self._in_use
        health = (message.payload or {}).get("health", {}).get(in_use or "", {})
        fault = self._fault
        if fault is not None and message.stamp - fault[1] > 2.0:
            fault = self._fault = None  # no swap followed (no tracker left, or recovered)
        if in_use and health.get("ok") is False and fault is None:
            self._fault = (in_use, message.stamp)
        self._in_use = in_use

    def _on_source(self, message: EventMessage) -> None:
        fault = self._fault
        tracker = (message.payload or {}).get("tracker", "")
        if fault is not None and tracker and tracker != fault[0]:
            if 0 <= message.stamp - fault[1] < 2.0:
                self._latency("sensor swap", message.stamp - fault[1])
            self._fault = None

    def _latency(self, kind: str, seconds: float) -> None:
        with self._lock:
            section = self._sections.setdefault("latencies", _Section(data=[]))
            section.data = [
                *section.data[-49:],
                {"kind": kind, "ms": round(seconds * 1e3, 3), "t": time.time()},
            ]
            section.at = time.monotonic()

    def _on_people(self, message: EventMessage) -> None:
        self._set("people", message.payload)

    def _on_distance(self, value: Scalar) -> None:
        self._set("min_distance", None if math.isinf(value.value) else value.value)

    # -- polling ---------------------------------------------------------------------------
    def _poll(self) -> None:
        reports = [
            n for n in ("supervisor", "interpolator", "robot") if n in self.topology.components
        ]
        tick = 0
        while not self._stop.wait(1.0 / self.poll_rate):
            if "chart" not in self._sections:  # until the first status arrives
                self._ask("chart", "coordinator", "active")
            self._ask("takeable", "coordinator", "takeable", events=self.external_events)
            for name in reports:
                self._ask(name, name, "report")
            if "people_detector" in self.topology.components:
                self._ask("scene", "people_detector", "scene")
            if tick % round(self.poll_rate) == 0:
                self._health()
            tick += 1

    def _ask(self, section: str, component: str, operation: str, **args: Any) -> None:
        try:
            result = RemoteComponent(self.bus, component, timeout=0.5).call(operation, **args)
        except RemoteError:
            return  # the section ages and the page marks it stale
        self._set(section, result)

    def _health(self) -> None:
        alive = {name.rsplit("/", 1)[-1] for name in self.bus.alive(keys.ALL_ALIVE, 0.5)}
        health = {}
        for name, spec in self.topology.components.items():
            state = None
            if name in alive:
                try:
                    state = RemoteComponent(self.bus, name, timeout=0.5).state()
                except RemoteError:
                    state = "not responding"
            health[name] = {"process": spec.process, "alive": name in alive, "state": state}
        self._set("health", health)

    # -- the SEEG status panel --------------------------------------------------------------
    def _status(self, view: dict[str, Any]) -> dict[str, Any]:
        chart = (view.get("chart") or {}).get("data") or {}
        leaves = [p.rsplit(".", 1)[-1] for p in chart.get("active", [])]
        supervisor = (view.get("supervisor") or {}).get("data") or {}
        robot = (view.get("robot") or {}).get("data") or {}
        return {
            "robot": _robot(robot),
            "states": leaves,
            "operation": _operation(leaves, supervisor.get("goal") or ""),
            "area": supervisor.get("area") or ("critical" if "Critical" in leaves else None),
            "tracker": supervisor.get("tracker") or "No Sensor Available",
            "people_near": supervisor.get("users_near"),
            "min_distance": (view.get("min_distance") or {}).get("data"),
            "setup_failed": "Setup_Aborted" in leaves,
            "failure": _failure((view.get("failure") or {}).get("data")),
        }


def _robot(report: dict[str, Any]) -> str:
    """The robot side in one line: moving, braked (why), or a latched safety stop and
    whether a RELEASE would be taken now (every safety input healthy)."""
    if not report:
        return "-"
    if report.get("latched"):
        problems = report.get("problems") or []
        release = "RELEASE possible" if not problems else "not yet: " + "; ".join(problems[:2])
        return f"SAFETY STOP: {report.get('reason')} ({release})"
    if report.get("braked"):
        return f"braked ({report.get('reason') or 'power on'})"
    return "released"


def _failure(payload: dict[str, Any] | None) -> str:
    """The last failed configuration, in one line."""
    if not payload:
        return ""
    parts = [payload.get("tag"), payload.get("step"), payload.get("reason")]
    return ": ".join(str(p) for p in parts if p)


def _operation(leaves: list[str], goal: str) -> str:
    """wait / approaching <goal> / at the goal / stopped, from the chart's leaves."""
    if any(s in leaves for s in ("Stopped", "No_Tracker", "Fault", "Setup_Aborted")):
        return "stopped"
    if any(
        s.startswith("Moving") or s in ("Tracker_Selection", "Certus_Up", "Vicra_Up", "Releasing")
        for s in leaves
    ):
        return f"approaching {goal or 'goal'}"
    if "Target_Reached" in leaves:
        return "at the goal"
    if any(s.startswith(("Start_", "Setup_")) for s in leaves):
        return "setting up"
    return "wait"


def _describe(kind: str, payload: dict[str, Any]) -> str:
    if kind == "event":
        return f"event {payload.get('event')}" + (
            f" {payload['payload']}" if payload.get("payload") else ""
        )
    if kind == "entry":
        return f"entered {payload.get('state')}"
    if kind == "command":
        verdict = "accepted" if payload.get("accepted") else f"refused: {payload.get('reason')}"
        return f"command {payload.get('event')} from {payload.get('origin') or '?'}: {verdict}"
    if kind == "unhandled":
        return f"{payload.get('event')} not taken: {payload.get('reason')}"
    if kind == "log":
        return str(payload.get("message"))
    if kind == "error":
        return f"error: {payload.get('message')}"
    return f"{kind} {payload}"
