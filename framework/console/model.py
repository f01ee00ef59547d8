"""What the operator console shows, gathered from a running deployment.

`ConsoleModel` listens on the deployment's bus (the Coordinator's status stream, the
ports the topology's `console:` tiles and plots name) and polls read-only operations
(the tiles' and the panels') and the components' lifecycle states a few times a
second. `snapshot()` is the whole picture as plain data: a console that connects
mid-procedure gets everything at once. Each section carries its age, so a page can mark what went stale; nothing is
invented when a source is silent.

It knows no procedure: the chart, the operator's commands, component health, the
event log and the declared tiles and plots work for any topology; a procedure's own
views come from the panels the topology names (framework/console/panels.py).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from framework import keys, messages
from framework.bus import Bus
from framework.console.panels import Panel, Tile, load_panels
from framework.coordinator import STATUS_KEY
from framework.messages import EventMessage
from framework.ports import ConnPolicy, InputPort, ReadStatus
from framework.remote import RemoteComponent, RemoteError
from framework.statechart.model import Statechart
from framework.topology import Topology
from framework.topology.console import PlotSpec, Source, TileSpec

LOG_SIZE = 300
PLOT_RATE = 20.0
"""Plot points per second (faster samples are thinned)."""
STALE_AFTER = 2.0
"""Seconds after which a polled tile is greyed out."""
SEVERITY = {
    "error": "error",
    "unhandled": "debug",  # the chart ignoring an event is normal; refused commands warn
    "command": "info",
    "log": "info",
    "event": "debug",
    "entry": "debug",
}
"""Log severity by Coordinator status kind (anything else is `debug`)."""


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
    _plots: dict[str, collections.deque] = field(default_factory=dict)
    _listened: set[str] = field(default_factory=set)
    _polls: list[tuple[str, str, str, dict[str, Any]]] = field(default_factory=list)
    panels: list[Panel] = field(default_factory=list)
    _warnings: frozenset[str] = frozenset()
    _subscriptions: list[Any] = field(default_factory=list)
    _incidents: Any = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _changed: threading.Condition = field(default_factory=threading.Condition)
    _generation: int = 0
    _thread: threading.Thread | None = None

    # -- lifecycle -----------------------------------------------------------------
    def start(self) -> ConsoleModel:
        """Load the topology's panels, subscribe and start polling (`FwError` if a
        panel is not installed)."""
        spec = self.topology.console
        self.panels = load_panels(spec.panels)
        self._warnings = self._warning_events()
        self.listen(STATUS_KEY, EventMessage, self._on_status, 1024)
        for tile in spec.tiles:
            self._follow(tile.source)
        for plot in spec.plots:
            self._plots[plot.id] = collections.deque()
            self._follow(plot.source, plot)
        for panel in self.panels:
            panel.start(self)
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

    def layout(self) -> dict[str, Any]:
        """What the page builds once: the operator's buttons and forms (from the
        topology's `console:` section and the chart's event declarations), the plots and
        the panels' scripts."""
        chart = self.chart
        commands = {}
        for name in self.external_events:
            declared = chart.events.get(name) if chart is not None else None
            if declared is None:
                continue
            commands[name] = {
                "doc": declared.doc,
                "payload": {
                    key: {"type": kind, **declared.fields.get(key, {})}
                    for key, kind in declared.payload.items()
                },
            }
        with_payload = {name for name, c in commands.items() if c["payload"]}
        buttons = self.topology.console.all_buttons(self.external_events, with_payload)
        on_buttons = {b.event for b in buttons}
        return {
            "topology": self.topology.name,
            "buttons": [
                {**dataclasses.asdict(b), "doc": (commands.get(b.event) or {}).get("doc", "")}
                for b in buttons
            ],
            "forms": {name: c for name, c in commands.items() if name in with_payload - on_buttons},
            "plots": [
                {"id": p.id, "label": p.label, "unit": p.unit} for p in self.topology.console.plots
            ],
            "panels": [
                {"name": p.name, "scripts": [f"/panels/{p.name}/{s}" for s in p.scripts]}
                for p in self.panels
            ],
        }

    def snapshot(self, log: bool = True) -> dict[str, Any]:
        """Everything the console shows, with each section's age in seconds (`log`:
        with the event log so far; a stream sends it once, then line by line)."""
        now = time.monotonic()
        with self._lock:
            out = {name: section.view(now) for name, section in self._sections.items()}
            out["log"] = list(self._log) if log else []
            out["log_seq"] = self._log_seq
            out["plots"] = {
                name: {"t": [p[0] for p in points], "values": _columns(points)}
                for name, points in self._plots.items()
            }
        out["topology"] = self.topology.name
        out["external_events"] = self.external_events
        tiles = [self._tile(spec, out) for spec in self.topology.console.tiles]
        alert = None
        for panel in self.panels:
            tiles += panel.tiles(out)
            alert = alert or panel.alert(out)
        out["tiles"] = [tile.view() for tile in tiles]
        out["alert"] = alert
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

    def set(self, name: str, data: Any) -> None:
        """Replace a section of the picture (panels keep theirs here too)."""
        with self._lock:
            section = self._sections.setdefault(name, _Section())
            section.data, section.at = data, time.monotonic()

    def get(self, name: str) -> Any:
        """A section's data (None if it never came)."""
        with self._lock:
            section = self._sections.get(name)
            return None if section is None else section.data

    def poll(self, section: str, component: str, operation: str, **args: Any) -> None:
        """Call `component.operation(**args)` at the poll rate into `section`, if the
        topology has that component."""
        if component in self.topology.components:
            self._polls.append((section, component, operation, args))

    # -- listening -----------------------------------------------------------------------
    def listen(self, key: str, kind: type, handler: Any, size: int) -> None:
        """Call `handler` with each sample on `key` (writers in this process and in
        others), in the bus' thread: handlers must be quick."""
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
            self.set("chart", payload)
            self._touch()
            return
        severity = SEVERITY.get(message.name, "debug")
        if message.name == "event" and payload.get("event") in self._warnings:
            severity = "warning"
        if message.name == "event" and payload.get("event") == "config.failed":
            severity = "error"
            self.set("failure", payload.get("payload") or {})
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

    def _warning_events(self) -> frozenset[str]:
        """Events the log shows as warnings: a lost component, those that lead the chart
        into its safe state, and those a panel names."""
        names = {"component.lost", *(e for p in self.panels for e in p.warnings)}
        chart = self.chart
        if chart is not None and chart.safe_state is not None:
            safe = chart.safe_state.path
            for t in chart.transitions():
                if t.target is not None and (
                    t.target.path == safe or t.target.path.startswith(safe + ".")
                ):
                    names.update(t.events)
        return frozenset(names)

    def _follow(self, source: Source, plot: PlotSpec | None = None) -> None:
        """Keep the latest value of a tile's or plot's source (a port's samples: a
        section named after the key; an operation: polled)."""
        section = source.section
        if source.polled:
            if all(p[0] != section for p in self._polls):
                self.poll(section, source.component, source.operation)
            return
        kind = self._port_type(source)
        if kind is None:
            return
        if plot is None:
            if section not in self._listened:
                self._listened.add(section)
                self.listen(
                    source.key,
                    kind,
                    lambda v, s=section: self.set(s, _plain(v)),
                    1,
                )
            return
        points = self._plots[plot.id]
        last = [-math.inf]

        def add(value: Any) -> None:
            now = time.time()
            if now - last[0] < 1.0 / PLOT_RATE:
                return
            numbers = _numbers(_at(_plain(value), source.path), plot.scale)
            if numbers is None:
                return
            last[0] = now
            with self._lock:
                points.append((round(now, 3), numbers))
                while points and now - points[0][0] > plot.seconds:
                    points.popleft()

        self.listen(source.key, kind, add, 4)

    def _port_type(self, source: Source) -> type | None:
        """The message type of a port source: from the topology, or (a client that did
        not import the classes) from the running component; None, logged, if unknown."""
        name = source.type_name
        if not name:
            try:
                described = RemoteComponent(self.bus, source.component, timeout=2.0).describe()
                name = next(
                    (p["type"] for p in described["outputs"] if source.key in p["keys"]), ""
                )
            except RemoteError as exc:
                self.note("warning", f"console: {source.component} did not describe itself: {exc}")
                return None
        try:
            return messages.resolve_type(name)
        except messages.CodecError as exc:
            self.note("warning", f"console: no tile or plot on {source.key}: {exc}")
            return None

    def _tile(self, spec: TileSpec, view: dict[str, Any]) -> Tile:
        source = spec.source
        section = view.get(source.section) or {}
        age = section.get("age")
        value = _at(section.get("data"), source.path) if age is not None else None
        stale = age is None or (source.polled and age > STALE_AFTER)
        return Tile(
            spec.id, spec.label, _format(value, spec.scale, spec.digits, spec.unit), stale=stale
        )

    # -- polling ---------------------------------------------------------------------------
    def _poll(self) -> None:
        tick = 0
        while not self._stop.wait(1.0 / self.poll_rate):
            if "chart" not in self._sections:  # until the first status arrives
                self._ask("chart", "coordinator", "active")
            self._ask("takeable", "coordinator", "takeable", events=self.external_events)
            for section, component, operation, args in list(self._polls):
                self._ask(section, component, operation, **args)
            if tick % round(self.poll_rate) == 0:
                self._health()
            tick += 1

    def _ask(self, section: str, component: str, operation: str, **args: Any) -> None:
        try:
            result = RemoteComponent(self.bus, component, timeout=0.5).call(operation, **args)
        except RemoteError:
            return  # the section ages and the page marks it stale
        self.set(section, result)

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
        self.set("health", health)


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


def _plain(value: Any) -> Any:
    """A sample as plain data: a message's fields (an event's payload merged in)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
        if isinstance(out.get("payload"), dict):
            out = {**out, **out["payload"]}
        return out
    return value


def _at(value: Any, path: tuple[str, ...]) -> Any:
    """The field at `path` below `value` (None if it has none)."""
    for key in path:
        if isinstance(value, dict):
            value = value.get(key)
        elif isinstance(value, (list, tuple)) and key.isdigit() and int(key) < len(value):
            value = value[int(key)]
        else:
            return None
    return value


def _numbers(value: Any, scale: float) -> list[float] | None:
    """A plot point: a number or a list of numbers, scaled (None if it is neither)."""
    if isinstance(value, bool):
        return [float(value)]
    if isinstance(value, (int, float)):
        return [float(value) * scale]
    if (
        isinstance(value, (list, tuple))
        and value
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    ):
        return [float(v) * scale for v in value]
    return None


def _columns(points: Any) -> list[list[float]]:
    """One list per line of a plot (points whose length changed are left out)."""
    if not points:
        return []
    width = len(points[-1][1])
    return [[p[1][k] for p in points if len(p[1]) == width] for k in range(width)]


def _format(value: Any, scale: float, digits: int, unit: str) -> str:
    """A tile's text: numbers scaled and rounded, lists joined, nothing as a dash."""
    if value is None or value == "":
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return "-"
        number = value * scale
        text = f"{number:.{digits}f}" if isinstance(number, float) else str(number)
        return f"{text} {unit}".strip()
    if isinstance(value, (list, tuple)):
        return ", ".join(_format(v, scale, digits, "") for v in value) + (
            f" {unit}" if unit else ""
        )
    return str(value)
