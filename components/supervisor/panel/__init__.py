"""The SEEG procedure's panel of the operator console (`console: panels: [seeg]`).

Its tiles read the SEEG components (`supervisor`, `robot`, `people_detector`): the
operation from the chart's leaves, the area, the tracker in use, the people near the
table and the robot side's brakes and safety stop. Its script (seeg.js) draws the
3D view of robot and people, the TCP's position and speed, and the reaction latencies
it measures live as `fw bench` does (docs/bench.md): STOP sent -> first braking cycle,
and tracker fault -> swap to another tracker.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from pathlib import Path
from typing import Any

from framework.console.panels import Panel, PanelHost, Tile
from framework.console.text import robot_line
from framework.messages import EventMessage, Pose, Scalar

TRACE_SECONDS = 20.0
TRACE_RATE = 20.0
"""Hz: how often the TCP trace takes a point."""


def thinnest(key: str, thinned: dict[str, float] | None, rate: float) -> str:
    """The key to listen on for `rate` Hz of `key`'s samples: the slowest of the thinned
    streams the topology already has of it (`thinned`: thinned key -> Hz) that is at
    least that fast, else `key` itself (every sample)."""
    fast_enough = [(hz, k) for k, hz in (thinned or {}).items() if hz >= rate]
    return min(fast_enough)[1] if fast_enough else key


STALE_AFTER = 2.0

PATIENT_RATE = 5.0
"""Hz: how often the 3D view needs the patient's reference."""


class SeegPanel(Panel):
    """Tiles, the 3D view, plots and live latencies of the SEEG procedure."""

    name = "seeg"
    static = Path(__file__).resolve().parent
    scripts = ("seeg.js",)
    warnings = ("e_STOP", "e_NOTRACKER", "e_TFAULT", "e_SETUP_FAILED")

    def __init__(self) -> None:
        self.model: PanelHost | None = None
        self._lock = threading.Lock()
        self._trace: collections.deque = collections.deque()
        self._last_trace = -math.inf
        self._halt: float | None = None  # the last halt not yet matched by a braking cycle
        self._fault: tuple[str, float] | None = None  # (tracker in use, verdict stamp)
        self._in_use: str | None = None

    def start(self, model: PanelHost) -> None:
        """Listen to the robot, the people detector and the reactions; poll reports."""
        self.model = model
        components = model.topology.components

        def listen(
            component: str, port: str, kind: type, handler: Any, size: int, rate: float = 0.0
        ) -> None:
            if component in components:
                key = components[component].output_key(port)
                if rate:
                    key = thinnest(key, model.topology.thinned.get(component, {}).get(port), rate)
                model.listen(key, kind, handler, size)

        # the trace needs 20 Hz: on the robot's 1 kHz key each sample cost the robot's loop
        # its pose and a put, and this process a callback, with the console open
        listen("robot", "tcp", Pose, self._on_tcp, 1, rate=TRACE_RATE)
        listen(
            "people_detector", "people", EventMessage, lambda m: model.set("people", m.payload), 1
        )
        listen("people_detector", "min_distance", Scalar, self._on_distance, 1)
        listen("supervisor", "halt", EventMessage, self._on_halt, 16)
        listen("interpolator", "status", EventMessage, self._on_motion, 16)
        listen("sensor_manager", "status", EventMessage, self._on_tracking, 16)
        listen("navigator", "sources", EventMessage, self._on_source, 16)
        # where the patient's reference is, for the 3D view: a few times a second is
        # enough (the slowest thinned stream of the navigator's goals that gives it)
        listen(
            "navigator",
            "goals",
            EventMessage,
            lambda m: model.set("patient", m.payload.get("patient")),
            1,
            rate=PATIENT_RATE,
        )
        # the robot side says its brakes and latch itself (on change, and at 2 Hz): no
        # question to ask its real-time process, whose loop would answer it between cycles
        listen("robot", "status", EventMessage, lambda m: model.set("robot", m.payload), 4)
        for name in ("supervisor", "interpolator"):
            model.poll(name, name, "report")
        model.poll("scene", "people_detector", "scene")

    # -- what the page shows -------------------------------------------------------------
    def tiles(self, view: dict[str, Any]) -> list[Tile]:
        """Operation, area, tracker in use, people near / closest, robot side."""
        chart = (view.get("chart") or {}).get("data") or {}
        leaves = [p.rsplit(".", 1)[-1] for p in chart.get("active", [])]
        supervisor = (view.get("supervisor") or {}).get("data") or {}
        supervisor_stale = not _fresh(view.get("supervisor"))
        operation = _operation(leaves, supervisor.get("goal") or "")
        area = supervisor.get("area") or ("critical" if "Critical" in leaves else None)
        tracker = supervisor.get("tracker") or ""
        # a tracker is needed from the approach on (and No_Tracker says one is missing);
        # at rest, braked and waiting for START, none selected yet is not a fault
        needed = operation.startswith("approaching") or operation == "at the goal"
        needed = needed or "No_Tracker" in leaves
        distance = (view.get("min_distance") or {}).get("data")
        near = supervisor.get("users_near")
        robot = robot_line((view.get("robot") or {}).get("data") or {})
        robot_age = (view.get("robot") or {}).get("age")
        robot_stale = robot_age is not None and robot_age > STALE_AFTER
        if robot_stale:  # an old "released" must never read as the robot's state now
            robot = f"no report for {robot_age:.0f} s (last: {robot})"
        tone = {"stopped": "bad"}.get(
            operation, "ok" if operation.startswith("approaching") else ""
        )
        return [
            Tile("operation", "operation", operation, tone),
            Tile(
                "area",
                "area",
                area or "-",
                {"critical": "warn", "safe": "ok"}.get(area or "", ""),
                stale=supervisor_stale,
            ),
            Tile(
                "tracker",
                "tracker in use",
                tracker or ("No Sensor Available" if needed else "none selected yet"),
                "ok" if tracker else "bad" if needed else "",
                stale=supervisor_stale,
            ),
            Tile(
                "people",
                "people near / closest",
                f"{'-' if near is None else near} / "
                + ("-" if distance is None else f"{distance * 100:.0f} cm"),
                stale=not _fresh(view.get("people")),
            ),
            Tile(
                "robot",
                "robot side (brakes, safety stop)",
                robot,
                "bad"
                if robot.startswith(("SAFETY STOP", "no report"))
                else "ok"
                if robot == "released"
                else "",
                stale=robot_stale,
                wide=True,
            ),
        ]

    def alert(self, view: dict[str, Any]) -> dict[str, str] | None:
        """A failed setup: the robot will not move until the cause is fixed."""
        chart = (view.get("chart") or {}).get("data") or {}
        if not any(p.endswith("Setup_Aborted") for p in chart.get("active", [])):
            return None
        failure = _failure((view.get("failure") or {}).get("data"))
        return {
            "title": "Setup failed",
            "text": (failure or "a setup configuration failed")
            + ". The robot will not move. Fix the cause and deploy again.",
        }

    # -- listening -----------------------------------------------------------------------
    def _on_tcp(self, pose: Pose) -> None:
        assert self.model is not None
        now = time.monotonic()
        if now - self._last_trace < 1.0 / TRACE_RATE:
            return
        self._last_trace = now
        with self._lock:
            self._trace.append([round(pose.stamp, 3), *[round(v, 5) for v in pose.position]])
            while self._trace and self._trace[-1][0] - self._trace[0][0] > TRACE_SECONDS:
                self._trace.popleft()
            trace = list(self._trace)
        self.model.set("trace", trace)

    def _on_distance(self, value: Scalar) -> None:
        assert self.model is not None
        self.model.set("min_distance", None if math.isinf(value.value) else value.value)

    def _on_halt(self, message: EventMessage) -> None:
        self._halt = message.stamp

    def _on_motion(self, message: EventMessage) -> None:
        halt = self._halt
        if message.name == "stopping" and halt is not None and 0 <= message.stamp - halt < 1.0:
            self._latency("STOP sent -> braking", message.stamp - halt)
            self._halt = None

    def _on_tracking(self, message: EventMessage) -> None:
        assert self.model is not None
        in_use = (self.model.get("supervisor") or {}).get("tracker") or self._in_use
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
        assert self.model is not None
        with self._lock:
            latest = list(self.model.get("latencies") or [])[-49:]
            latest.append({"kind": kind, "ms": round(seconds * 1e3, 3), "t": time.time()})
            self.model.set("latencies", latest)


def _fresh(section: dict[str, Any] | None) -> bool:
    return bool(section) and section.get("age") is not None and section["age"] < STALE_AFTER


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
