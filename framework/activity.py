"""Activities decide when a component's `update()` runs; executors make it happen.

* `periodic` at a rate (Hz), `event` when new data arrives on chosen input
  ports (with `idle`, the component's `idle_hook` also runs whenever no data came
  for that long: a watchdog that must act when its input falls silent), `after` another component of the same process (in its thread, right
  after each of its updates: OROCOS's slave activity, for a controller that must
  answer its robot every cycle without a thread hand-over), `paced` by the
  component's own device (the robot interface by the KRC's measurements: each cycle
  is read -> update -> the components after it -> write, ros2_control's loop, in one
  thread; `idle_hook` when the device is silent for `idle`; its operations and its
  followers' run between cycles, framework/engine.py; real-time priority where the
  host allows, framework/realtime.py), or `passive` (only operations and lifecycle
  calls).
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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from framework.clock import MonotonicClock, SimulatedClock
from framework.component import Component, State
from framework.engine import ExecutionEngine
from framework.errors import FwError
from framework.realtime import LoopStats, RealTimePolicy, name_os_thread


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
    def paced(cls, idle: float = 0.02) -> Activity:
        """Update once per cycle of the component's device (its `read_hook` waits for
        it), `idle_hook` after `idle` seconds without one."""
        if not (isinstance(idle, int | float) and 0.0 < idle <= 10.0):
            raise ActivityError(f"idle must be a duration up to 10 s, got {idle!r}")
        return cls("paced", idle=float(idle))

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
            if kind == "paced":
                from framework.durations import parse_duration

                try:
                    return cls.paced(parse_duration(arg))
                except ValueError as exc:
                    raise ActivityError(f"paced: {exc}") from None
        raise ActivityError(
            "activity must be 'passive', {periodic: HZ}, {event: [PORTS]} (optionally with "
            f"idle: DURATION), {{after: COMPONENT}} or {{paced: IDLE}}, not {spec!r}"
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
        if self.kind == "paced":
            return {"paced": self.idle}
        return "passive"

    def to_dict(self) -> dict[str, Any]:
        """Plain data for introspection."""
        out: dict[str, Any] = {"kind": self.kind, "rate": self.rate, "ports": list(self.ports)}
        if self.master:
            out["after"] = self.master
        if self.idle:
            out["idle"] = self.idle
        return out


SHORT_WAIT = 0.005
"""s: a periodic thread waits shorter gaps by sleeping, longer ones on its stop event
(`Event.wait` makes and takes a lock each time: a 1 kHz loop's wait cost a third more
CPU than a sleep, measured 18 vs 12 us a cycle)."""


def _idle_period(component: Component, activity: Activity) -> float:
    """How long an event-driven component waits for data before an idle tick (s)."""
    periods = [0.1, *([activity.idle] if activity.idle else [])]
    if component.heartbeat is not None:
        periods.append(component.heartbeat.period)
    return min(periods)


def next_deadline(
    deadline: float, now: float, period: float, periods: int = 1
) -> tuple[float, int]:
    """When a periodic component updates next, after the update due at `deadline` ended
    at `now`: `periods` periods later, on the same grid. An update that ends past that
    runs the next one at once (a thread woken late, or one that waited for the
    interpreter, loses no period: a 30 Hz camera pipeline that skipped to the next tick
    on a 1 ms overrun went silent for 67-126 ms and tripped its 100 ms watch); periods
    missed entirely are skipped, not bunched. Returns the deadline and how many periods
    were late or skipped (0 on time)."""
    deadline += period * periods
    behind = now - deadline
    if behind <= 0.0:
        return deadline, 0
    skipped = int(behind // period)
    return deadline + skipped * period, skipped + 1


class RealTimeExecutor:
    """One thread per active component, on monotonic time."""

    def __init__(self, realtime: RealTimePolicy | None = None) -> None:
        self.clock = MonotonicClock()
        self._entries: list[tuple[Component, Activity]] = []
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._wake: dict[str, threading.Event] = {}
        self._followers: dict[str, list[Component]] = {}
        self.overruns: dict[str, int] = {}
        self.realtime = realtime or RealTimePolicy()
        """How a paced loop's thread asks the host for real-time priority."""
        self.loops: dict[str, LoopStats] = {}
        """Each paced loop's scheduling and cycle statistics, by component."""
        self._chains_changed = 0
        """Counts the followers added: a paced loop running already takes them in."""
        self.between_cycles: list[Callable[[], None]] = []
        """Run by a real-time loop's thread after each cycle (the process heartbeat of a
        loop's process: `has_loop`); each must take microseconds and never block."""

    def has_loop(self) -> bool:
        """Whether a component of this executor runs a real-time loop (paced, or a
        periodic device clock) whose thread can run `between_cycles`."""
        return any(
            a.kind == "paced" or (a.kind == "periodic" and c.realtime) for c, a in self._entries
        )

    def add(self, component: Component, activity: Activity) -> None:
        """Register a component (before or after `start`)."""
        activity.check(component)
        self._entries.append((component, activity))
        if activity.kind == "after":
            _add_follower(self._followers, activity.master, component)
            self._chains_changed += 1
        if activity.kind == "event":
            wake = self._wake[component.name] = threading.Event()
            component.wake_on(activity.ports, lambda _port, w=wake: w.set())
        if activity.kind == "paced":
            component.engine = ExecutionEngine(component.name)
        self._share_engines()
        if self._threads:
            self._spawn(component, activity)

    def _share_engines(self) -> None:
        """A component that runs after a paced one (or after one that does) has its
        operations run by that loop too: nobody takes its lock mid-cycle either."""
        by_name = {c.name: (c, a) for c, a in self._entries}
        for component, activity in self._entries:
            seen, at = {component.name}, activity
            while at.kind == "after" and at.master in by_name and at.master not in seen:
                master, at = by_name[at.master]
                seen.add(master.name)
                if master.engine is not None:
                    component.engine = master.engine
                    break

    def start(self) -> None:
        """Start a thread for every periodic, event-driven or paced component."""
        for component, activity in self._entries:
            self._spawn(component, activity)

    def _spawn(self, component: Component, activity: Activity) -> None:
        if activity.kind in ("passive", "after"):
            return
        target = {"periodic": self._periodic, "paced": self._paced}.get(activity.kind, self._event)
        thread = threading.Thread(
            target=_named(target),
            args=(component, activity),
            name=f"fw-{component.name}",
            daemon=True,
        )
        self._threads.append(thread)
        thread.start()

    def _periodic(self, component: Component, activity: Activity) -> None:
        period = 1.0 / activity.rate
        deadline = time.monotonic()
        stats = None
        if component.realtime:  # a device's own clock: as a paced loop, one priority below
            # the loops that answer devices (at the same priority on the same cores, a device
            # kept the robot interface waiting for a CPU, 1.6 ms seen); a simulated device
            # (the KRC of the simulated OR) takes a bounded share of each period instead
            # (SCHED_DEADLINE, framework/realtime.py; Component.simulated_device)
            priority = self.realtime.priority - 1
            stats = LoopStats(
                self.realtime.enter(
                    component.name, priority, fifo=not component.simulated_device, period=period
                )
            )
            stats.host_realtime = self.realtime.granted
            self.loops[component.name] = stats
            component.loop_stats = stats
        while not self._stop.is_set():
            began = time.perf_counter()
            component.update()
            _follow(self._followers, component)
            if stats is not None:
                stats.cycle(time.perf_counter() - began)
                for call in self.between_cycles:
                    call()
                # a device that reports every few cycles (a braked KRC) leaves slack
                self.realtime.between_cycles(stats, slack=component.periods_per_update > 1)
            now = time.monotonic()
            deadline, late = next_deadline(
                deadline, now, period, max(1, int(component.periods_per_update))
            )
            if late:
                self.overruns[component.name] = self.overruns.get(component.name, 0) + late
            wait = deadline - now
            if wait < SHORT_WAIT:  # a stop waits for it at most this long
                if wait > 0.0:
                    time.sleep(wait)
            else:
                self._stop.wait(wait)
        if stats is not None:
            self.realtime.leave()

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

    def _paced(self, component: Component, activity: Activity) -> None:
        """The device's loop: read -> update -> the components after it -> write, then
        the operations queued meanwhile; `idle` when the device is silent. Real-time
        priority for this thread where the host allows it (framework/realtime.py)."""
        engine = component.engine
        stats = self.loops[component.name] = LoopStats(self.realtime.enter(component.name))
        engine.loop = stats
        engine.thread_id = threading.get_ident()
        component.defer_outputs()  # its samples for other processes go out after the command
        chain: list[Component] = [component]
        followers: list[Component] = []
        seen = -1
        silent_since = time.monotonic()
        wait = min(activity.idle, 0.005)  # queued operations wait at most this long
        try:
            while not self._stop.is_set():
                cycled = component.read_cycle(wait)
                if seen != self._chains_changed:  # at start, and a follower added meanwhile
                    seen = self._chains_changed
                    followers = _chain(self._followers, component)
                    for member in followers:
                        if member not in chain:  # theirs too
                            member.defer_outputs()
                    chain = [component, *followers]
                if cycled:
                    began = time.perf_counter()
                    component.update()
                    updated = time.perf_counter()
                    stats.stage(component.update_stage, updated - began)
                    for follower in followers:  # in `_follow`'s order, its walk made once
                        at = time.perf_counter()
                        follower.update()
                        stats.stage(follower.update_stage, time.perf_counter() - at)
                    followed = time.perf_counter()
                    component.write_cycle()
                    done = time.perf_counter()
                    stats.stage("send", done - followed)
                    stats.cycle(done - began)
                    for member in chain:
                        member.after_cycle()
                    stats.after_cycle(time.perf_counter() - done)
                    silent_since = time.monotonic()
                elif time.monotonic() - silent_since >= activity.idle:
                    component.idle()
                    silent_since = time.monotonic()
                elif component.state is not State.RUNNING:
                    self._stop.wait(wait)  # nothing to read from: do not spin
                engine.run_pending()
                for member in chain:  # what the operations just run wrote
                    member.flush_outputs()
                for call in self.between_cycles:
                    call()
                self.realtime.between_cycles(stats, slack=not cycled)
        finally:
            for member in chain:  # no loop left to send what they write: at once again
                member.undefer_outputs()
            engine.stop()
            self.realtime.leave()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop every thread and wait for them."""
        self._stop.set()
        for wake in self._wake.values():
            wake.set()
        for thread in self._threads:
            thread.join(timeout)
        self._threads.clear()


def _named(target: Callable[[Component, Activity], None]) -> Callable[..., None]:
    """`target`, run in a thread that the host's tools (top -H, ps -L, /proc, py-spy)
    show by its component's name ("fw-" and the first 12 characters)."""

    def run(component: Component, activity: Activity) -> None:
        name_os_thread(f"fw-{component.name}")
        target(component, activity)

    return run


def _chain(followers: dict[str, list[Component]], master: Component) -> list[Component]:
    """The components that run after `master`, and theirs in turn, in the order they
    update (`_follow`)."""
    chain: list[Component] = []
    for follower in followers.get(master.name, ()):
        chain.append(follower)
        chain.extend(_chain(followers, follower))
    return chain


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
    the arm, then the robot interface, then the interpolator); how many updated. A paced
    loop walks the same order from its `_chain`, made once, each update a stage."""
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
        self._paced: list[Component] = []
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
        elif activity.kind == "paced":
            # a stepped test's device answers at once: each cycle it has ready is run
            # in `run_pending`, operations directly (no loop thread to queue them to);
            # its cycles and stages are kept as a real loop keeps them (`fw bench cost`)
            self._paced.append(component)
            component.loop_stats = LoopStats("stepped (simulated clock)")
            self._order += 1
            heapq.heappush(
                self._periodic,
                (self.clock.now() + activity.idle, self._order, component, -activity.idle),
            )

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
            cycled = 0
            for component in self._paced:
                while component.read_cycle(0.0) and cycled < limit:
                    began = time.perf_counter()
                    updates += self._update(component)
                    component.write_cycle()
                    done = time.perf_counter()
                    component.loop_stats.cycle(done - began)
                    for member in (component, *_chain(self._followers, component)):
                        member.after_cycle()
                    component.loop_stats.after_cycle(time.perf_counter() - done)
                    cycled += 1
            if not ready and not cycled:
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
