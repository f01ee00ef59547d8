"""Activities decide when a component's `update()` runs; executors make it happen.

* `periodic` at a rate (Hz), `event` when new data arrives on chosen input
  ports (with `idle`, the component's `idle_hook` also runs whenever no data came
  for that long: a watchdog that must act when its input falls silent), `after` another component of the same process (in its thread, right
  after each of its updates: OROCOS's slave activity, for a controller that must
  answer its robot every cycle without a thread hand-over), or `passive` (only
  operations and lifecycle calls).
* `RealTimeExecutor` gives each active component its own thread on
  monotonic time (like an RTT activity); missed periods are skipped and
  counted, never bunched up.
* `SteppedExecutor` runs the same components on a `SimulatedClock`: time
  moves only in `advance()`, periodic updates happen exactly at their
  deadlines in a fixed order, so behaviour tests repeat exactly.
"""

from __future__ import annotations

import heapq
import threading
import time
from dataclasses import dataclass
from typing import Any

from framework.clock import MonotonicClock, SimulatedClock
from framework.component import Component
from framework.errors import FwError


class ActivityError(FwError):
    """An activity specification is wrong (bad rate, unknown port)."""


@dataclass(frozen=True)
class Activity:
    """When a component updates: periodic (rate in Hz), event-driven (ports) or passive."""

    kind: str = "passive"
    rate: float = 0.0
    ports: tuple[str, ...] = ()
    master: str = ""
    idle: float = 0.0
    """Event-driven only: run `idle_hook` after this long without data (s; 0: never)."""

    @classmethod
    def periodic(cls, rate: float) -> Activity:
        """Update `rate` times per second."""
        if not rate > 0:
            raise ActivityError(f"a periodic activity needs a positive rate, got {rate!r}")
        return cls("periodic", float(rate))

    @classmethod
    def event(cls, *ports: str, idle: float = 0.0) -> Activity:
        """Update when any of these input ports receives a sample (and run `idle_hook`
        after `idle` seconds without one, if given)."""
        if not ports:
            raise ActivityError("an event-driven activity needs at least one input port")
        if not (isinstance(idle, int | float) and 0.0 <= idle <= 10.0):
            raise ActivityError(f"idle must be a duration up to 10 s, got {idle!r}")
        return cls("event", 0.0, tuple(ports), idle=float(idle))

    @classmethod
    def from_spec(cls, spec: Any) -> Activity:
        """From YAML: `passive`, `{periodic: 100}`, `{event: [port, ...]}` (optionally with
        `idle: 5ms`) or `{after: name}`."""
        if spec in (None, "passive"):
            return cls()
        if isinstance(spec, dict) and set(spec) == {"event", "idle"}:
            from framework.durations import parse_duration

            arg = spec["event"]
            try:
                idle = parse_duration(spec["idle"])
            except ValueError as exc:
                raise ActivityError(f"idle: {exc}") from None
            return cls.event(*([arg] if isinstance(arg, str) else arg), idle=idle)
        if isinstance(spec, dict) and len(spec) == 1:
            ((kind, arg),) = spec.items()
            if kind == "periodic":
                return cls.periodic(arg)
            if kind == "event":
                return cls.event(*([arg] if isinstance(arg, str) else arg))
            if kind == "after" and isinstance(arg, str) and arg.isidentifier():
                return cls("after", master=arg)
        raise ActivityError(
            "activity must be 'passive', {periodic: HZ}, {event: [PORTS]} (optionally with "
            f"idle: DURATION) or {{after: COMPONENT}}, not {spec!r}"
        )

    def check(self, component: Component) -> None:
        """Refuse event ports the component does not have (a port its unreadable file
        would declare is let through: its configure fails and says why)."""
        for name in self.ports:
            if name not in component.inputs and not component.file_error:
                known = ", ".join(sorted(component.inputs)) or "none"
                raise ActivityError(
                    f"{component.name}: event activity names unknown input "
                    f"port {name!r} (inputs: {known})"
                )

    def to_spec(self) -> Any:
        """The YAML form (inverse of `from_spec`)."""
        if self.kind == "periodic":
            return {"periodic": self.rate}
        if self.kind == "event":
            if self.idle:
                return {"event": list(self.ports), "idle": self.idle}
            return {"event": list(self.ports)}
        if self.kind == "after":
            return {"after": self.master}
        return "passive"

    def to_dict(self) -> dict[str, Any]:
        """Plain data for introspection."""
        out: dict[str, Any] = {"kind": self.kind, "rate": self.rate, "ports": list(self.ports)}
        if self.master:
            out["after"] = self.master
        if self.idle:
            out["idle"] = self.idle
        return out


def _idle_period(component: Component, activity: Activity) -> float:
    """How long an event-driven component waits for data before an idle tick (s)."""
    periods = [0.1, *([activity.idle] if activity.idle else [])]
    if component.heartbeat is not None:
        periods.append(component.heartbeat.period)
    return min(periods)


class RealTimeExecutor:
    """One thread per active component, on monotonic time."""

    def __init__(self) -> None:
        self.clock = MonotonicClock()
        self._entries: list[tuple[Component, Activity]] = []
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._wake: dict[str, threading.Event] = {}
        self._followers: dict[str, list[Component]] = {}
        self.overruns: dict[str, int] = {}

    def add(self, component: Component, activity: Activity) -> None:
        """Register a component (before or after `start`)."""
        activity.check(component)
        self._entries.append((component, activity))
        if activity.kind == "after":
            _add_follower(self._followers, activity.master, component)
        if activity.kind == "event":
            wake = self._wake[component.name] = threading.Event()
            component.wake_on(activity.ports, lambda _port, w=wake: w.set())
        if self._threads:
            self._spawn(component, activity)

    def start(self) -> None:
        """Start a thread for every periodic or event-driven component."""
        for component, activity in self._entries:
            self._spawn(component, activity)

    def _spawn(self, component: Component, activity: Activity) -> None:
        if activity.kind in ("passive", "after"):
            return
        target = self._periodic if activity.kind == "periodic" else self._event
        thread = threading.Thread(
            target=target, args=(component, activity), name=f"fw-{component.name}", daemon=True
        )
        self._threads.append(thread)
        thread.start()

    def _periodic(self, component: Component, activity: Activity) -> None:
        period = 1.0 / activity.rate
        deadline = time.monotonic()
        while not self._stop.is_set():
            component.update()
            _follow(self._followers, component)
            deadline += period * max(1, int(component.periods_per_update))
            delay = deadline - time.monotonic()
            if delay < 0:  # overrun: skip missed periods instead of bunching them up
                missed = int(-delay // period) + 1
                self.overruns[component.name] = self.overruns.get(component.name, 0) + missed
                deadline += missed * period
                delay = deadline - time.monotonic()
            self._stop.wait(max(delay, 0.0))

    def _event(self, component: Component, activity: Activity) -> None:
        wake = self._wake[component.name]
        idle = _idle_period(component, activity)
        ports: list[Any] = []
        while not self._stop.is_set():
            within = component.idle_within
            if not wake.wait(idle if within is None else min(idle, max(within, 0.0005))):
                component.idle()
                continue
            wake.clear()
            if len(ports) < len(activity.ports):  # a port its file declares comes later
                ports = [component.inputs[n] for n in activity.ports if n in component.inputs]
            while any(p.pending() for p in ports) and not self._stop.is_set():
                before = sum(p.pending() for p in ports)
                component.update()
                _follow(self._followers, component)
                if sum(p.pending() for p in ports) >= before:
                    break  # the component did not read: wait for the next sample

    def stop(self, timeout: float = 2.0) -> None:
        """Stop every thread and wait for them."""
        self._stop.set()
        for wake in self._wake.values():
            wake.set()
        for thread in self._threads:
            thread.join(timeout)
        self._threads.clear()


def _add_follower(followers: dict[str, list[Component]], master: str, component: Component) -> None:
    """Register `component` to run after `master`, refusing a chain that comes back to
    it (it would never end; topologies are checked for this before anything starts)."""
    masters = {f.name: m for m, fs in followers.items() for f in fs}
    at = master
    while at is not None:
        if at == component.name:
            raise ActivityError(f"{component.name!r} would run after itself (via {master!r})")
        at = masters.get(at)
    followers.setdefault(master, []).append(component)


def _follow(followers: dict[str, list[Component]], master: Component) -> int:
    """Update the components that run `after` `master`, and theirs in turn (a chain:
    the arm, then the robot interface, then the interpolator); how many updated."""
    updated = 0
    for follower in followers.get(master.name, ()):
        follower.update()
        updated += 1 + _follow(followers, follower)
    return updated


class SteppedExecutor:
    """Runs components on a simulated clock: deterministic order, exact deadlines."""

    def __init__(self, clock: SimulatedClock):
        self.clock = clock
        self._periodic: list[tuple[float, int, Component, float]] = []
        self._event: list[tuple[Component, tuple[str, ...]]] = []
        self._followers: dict[str, list[Component]] = {}
        self._order = 0

    def add(self, component: Component, activity: Activity) -> None:
        """Register a component; periodic ones first update one period from now."""
        activity.check(component)
        if activity.kind == "periodic":
            self._order += 1
            period = 1.0 / activity.rate
            heapq.heappush(
                self._periodic, (self.clock.now() + period, self._order, component, period)
            )
        elif activity.kind == "event":
            self._event.append((component, activity.ports))
            if component.heartbeat is not None or activity.idle:  # idle ticks, as in real time
                self._order += 1
                period = _idle_period(component, activity)
                heapq.heappush(
                    self._periodic, (self.clock.now() + period, self._order, component, -period)
                )
        elif activity.kind == "after":
            _add_follower(self._followers, activity.master, component)

    def start(self) -> None:
        """Nothing to start: time moves in `advance`."""

    def stop(self, timeout: float = 0.0) -> None:
        """Nothing to stop."""

    def run_pending(self, limit: int = 1000) -> int:
        """Update event-driven components that have unread data, until none has."""
        updates = 0
        for _ in range(limit):
            ready = [
                c
                for c, ports in self._event
                if any(c.inputs[p].pending() for p in ports if p in c.inputs)
            ]
            if not ready:
                break
            for component in ready:
                updates += self._update(component)
        return updates

    def _update(self, component: Component) -> int:
        component.update()
        return 1 + _follow(self._followers, component)

    def advance(self, seconds: float) -> int:
        """Move the clock forward, running every periodic update at its deadline."""
        end = self.clock.now() + seconds
        updates = self.run_pending()
        while self._periodic and self._periodic[0][0] <= end + 1e-12:
            deadline, order, component, period = heapq.heappop(self._periodic)
            self.clock.set(max(deadline, self.clock.now()))
            if period < 0:  # an event-driven component's idle beat (see `add`)
                component.idle()
                updates += self.run_pending()
                step = abs(period)
            else:
                updates += self._update(component) + self.run_pending()
                step = period * max(1, int(component.periods_per_update))
            heapq.heappush(self._periodic, (deadline + step, order, component, period))
        self.clock.set(max(end, self.clock.now()))  # a deadline within rounding of `end` ran
        return updates
