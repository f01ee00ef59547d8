"""The robot-side safety monitor: deadlines on what the topology declares safety-relevant,
the liveliness of every component, and a latch only an operator's RELEASE opens.

A topology says what the robot depends on:

    safety:
      monitor: robot                         # the component that brakes, in its control loop
      watch:
        supervisor: 50ms                     # a component: its heartbeat (it runs)
        people_detector.min_distance: 100ms  # an output port: its samples

A watched *component* publishes a heartbeat from its own activity thread while it is
Running (`Component.heartbeat`); a watched *port* is watched by its samples. Besides
the watches, every process of the deployment beats from a thread of its own
(`ProcessHeartbeat`, deadline `process_deadline`, 50 ms by default), so a hung process
is a trip, and the liveliness token of every component (and of the Coordinator and
the Configurator) is watched, so a dead process is a trip at once, whether or not
anything of it is watched by name.

`SafetyMonitor.check()` runs once per control cycle of the hosting component. It
*arms* the first time every watch is healthy; once armed, the first problem trips
it and the trip **latches**: `check()` keeps returning the first reason until
`acknowledge()` is called (by the operator's RELEASE, through the chart) *and* every
watch is healthy again. A process that comes back therefore never restarts motion by
itself. Time is the hosting executor's clock, so stepped tests repeat exactly.

Hosted by a container, the monitor's watches are *polled* (`attach(polled=True)`):
their arrivals wait in Zenoh's ring and each check takes them in the control loop's
own thread. Called back instead, 400-450 arrivals a second (measured on SEEG: 407
braked, 446 moving; seven process heartbeats, the components' heartbeats, the people
detector's and the cameras' streams) each took the interpreter on one of Zenoh's
threads in the robot's process: each a chance for a thread preempted while holding it
to stall the 1 kHz loop (framework/realtime.py). Polled, a watch is as fine as the
checks are frequent (1 ms moving, 10 ms braked, 20 ms with the KRC silent).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from dataclasses import dataclass
from typing import Any

from framework import keys, messages
from framework.clock import Clock, MonotonicClock
from framework.messages import Scalar
from framework.ports import ConnPolicy, InputPort, OutputPort

DEFAULT_PROCESS_DEADLINE = 0.05
"""Seconds a process may go without beating before the monitor trips."""
STARVED = 0.01
"""A gap between two checks longer than this means the monitor's own thread starved."""


@dataclass(frozen=True)
class Watch:
    """One safety-relevant input: a component's heartbeat or an output port's samples."""

    name: str
    """As the topology names it: `supervisor` or `people_detector.min_distance`."""
    key: str
    deadline: float
    """Seconds without a sample before the input counts as lost."""
    producer: str
    """The component that writes it (its liveliness is watched too; '' for a process's
    own heartbeat)."""
    type_name: str = "Scalar"

    def to_dict(self) -> dict[str, Any]:
        """Plain data, for a container specification."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class SafetySpec:
    """What one monitor watches: the deadlines and every component whose loss trips it."""

    monitor: str
    watches: tuple[Watch, ...] = ()
    components: tuple[str, ...] = ()
    process_deadline: float = DEFAULT_PROCESS_DEADLINE
    """How long a process may go without beating (its beat period is a quarter of it)."""

    @property
    def process_beat(self) -> float:
        """How often every process of the deployment beats (s)."""
        return heartbeat_period(self.process_deadline)

    def to_dict(self) -> dict[str, Any]:
        """Plain data, for a container specification."""
        return {
            "monitor": self.monitor,
            "watches": [w.to_dict() for w in self.watches],
            "components": list(self.components),
            "process_deadline": self.process_deadline,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SafetySpec:
        """Inverse of `to_dict`."""
        return cls(
            data["monitor"],
            tuple(Watch(**w) for w in data.get("watches", [])),
            tuple(data.get("components", [])),
            float(data.get("process_deadline", DEFAULT_PROCESS_DEADLINE)),
        )


class ProcessHeartbeat:
    """A process's proof that it is scheduled: a sample every `period` (SIGSTOP, a frozen
    VM or a starved process all fall silent).

    Beaten from a thread of its own, or, in a process with a real-time loop, by that
    loop between its cycles (`driven`: `poll` runs in the loop's thread). There a thread
    of its own was one more holder of the interpreter lock at ordinary priority: preempted
    while it held the lock to write a beat, it made the loop wait a scheduler slice and
    the KRC count its answers late (framework/realtime.py)."""

    def __init__(self, bus: Any, process: str, period: float):
        self.period = period
        self.port: OutputPort[Scalar] = OutputPort("heartbeat", Scalar, "process heartbeat")
        self.port.owner, self.port.bus = process, bus
        self.port.connect(keys.process_heartbeat(process))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"fw-beat-{process}", daemon=True)
        self._count = 0
        self._due = 0.0

    def start(self, driven: bool = False) -> ProcessHeartbeat:
        """Begin beating: from a thread of its own, or (`driven`) whenever `poll` is
        called at least once a period (a real-time loop's thread, between cycles)."""
        if not driven:
            self._thread.start()
        return self

    def poll(self) -> None:
        """Beat if a period has passed since the last beat (a driven heartbeat; called
        in the real-time loop's thread, between cycles)."""
        now = time.monotonic()
        if now < self._due or self._stop.is_set():
            return
        self._due = now + self.period
        self._beat()

    def _run(self) -> None:
        beat_at_fifo()
        while not self._stop.wait(self.period):
            if not self._beat():
                return

    def _beat(self) -> bool:
        self._count += 1
        try:
            self.port.write(Scalar(time.time(), float(self._count)))
        except Exception:  # the session is closing: nothing left to prove
            return False
        return True

    def stop(self) -> None:
        """Stop beating (before the bus closes)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)
        self.port.disconnect()


BEAT_PRIORITY = 1
"""SCHED_FIFO priority of a heartbeat thread of its own: the lowest real-time one, below
the device loops (framework/realtime.py, 80) and the kernel's threaded interrupts (50)."""


def beat_at_fifo() -> None:
    """Put the calling heartbeat thread at SCHED_FIFO `BEAT_PRIORITY` where the host
    allows it (where not, it keeps its process's nice level, quietly: the device loops
    are the ones that say what they got). Runs in the heartbeat thread.

    Why: on a busy host an ordinary thread waits for a core behind the host's other
    programs: with 3 busy loops on 2 cores, healthy processes fell silent for 80-104 ms
    (35-55 ms at SCHED_FIFO 1; 2 runs of 60 s each way). At the lowest real-time priority it takes a core at once
    when its period is up; it still needs the interpreter, so a process whose Python
    is not running still falls silent. It beats 4 times per deadline for tens of
    microseconds, so it cannot starve anything."""
    with contextlib.suppress(OSError):  # PermissionError among them
        os.sched_setscheduler(
            threading.get_native_id(), os.SCHED_FIFO, os.sched_param(BEAT_PRIORITY)
        )


def heartbeat_period(deadline: float) -> float:
    """How often a component watched with `deadline` beats: four beats per deadline,
    so one late beat is not yet a trip."""
    return max(deadline / 4.0, 0.002)


class SafetyMonitor:
    """Deadlines and liveliness with a latch (see the module docstring)."""

    def __init__(self, spec: SafetySpec, clock: Clock | None = None, process: str = ""):
        """`process`: the one hosting the monitor; its own heartbeat is the reference
        against which the others are late."""
        self.spec = spec
        own = keys.process_heartbeat(process) if process else None
        self._own = next((i for i, w in enumerate(spec.watches) if w.key == own), None)
        self.clock = clock or MonotonicClock()
        self._lock = threading.Lock()
        n = len(spec.watches)
        self._arrived = [-float("inf")] * n
        self._samples = [0] * n
        self._worst = [0.0] * n  # the longest silence seen per watch (s): the margin left
        self._alive: dict[str, bool] = {c: False for c in spec.components}
        for watch in spec.watches:
            if watch.producer:  # a process heartbeat has no component behind it
                self._alive.setdefault(watch.producer, False)
        self._lost = len(self._alive)  # components whose token is gone (or not yet seen)
        self._alive_changes = 0  # how many times a token came or went
        self._healthy_until = -float("inf")
        """Until when every watch is on time whatever arrives meanwhile (each one's last
        arrival plus its deadline, the earliest of them): a check before it, with nobody
        lost, has nothing to look at. Arrivals only push it later; a token that comes or
        goes makes it unknown (-inf) until the next full look."""
        self._last_stall: float | None = None  # the own stall at the last check that looked
        self._ports: list[InputPort[Any]] = []
        self._polled = False
        self._taken = False  # whether `poll_after_cycle` took the arrivals since the last check
        self._token_watch: Any = None
        self._last_check: float | None = None
        self.armed = False
        """True once every watch was healthy at the same time (after start-up)."""
        self.latched = ""
        """The reason of the trip that latched ('' while not tripped)."""
        self.trips = 0

    # -- wiring ---------------------------------------------------------------------
    def attach(self, bus: Any, owner: str = "safety", polled: bool = False) -> SafetyMonitor:
        """Subscribe to every watched key and to the components' liveliness tokens.

        `polled`: the watches' arrivals wait in Zenoh's ring and each check takes them,
        in the checking thread (a 1 kHz loop's: no Python runs on Zenoh's threads for
        them, so none holds the interpreter against the loop); an arrival then counts
        from the check that sees it, so a watch is as fine as the checks are frequent
        (every cycle of the loop: 1 ms moving, 10 ms braked, 20 ms with the device
        silent). Otherwise each arrival is recorded by a callback as it comes."""
        for index, watch in enumerate(self.spec.watches):
            kind = messages.resolve_type(watch.type_name)
            port: InputPort[Any] = InputPort(
                f"watch_{index}", kind, policy=ConnPolicy(), arrivals_only=True
            )
            port.owner, port.bus = owner, bus
            if not polled:
                port.on_data = lambda _port, i=index: self.arrived(i)
            port.connect(watch.key)
            self._ports.append(port)
        self._polled = polled
        self._token_watch = bus.watch(keys.ALL_ALIVE, self._on_token)
        return self

    def close(self) -> None:
        """Drop every subscription."""
        for port in self._ports:
            port.close()
        self._ports.clear()
        if self._token_watch is not None:
            self._token_watch.undeclare()
            self._token_watch = None

    def _on_token(self, key: str, alive: bool) -> None:
        self.set_alive(key.rsplit("/", 1)[-1], alive)

    # -- inputs (any thread) ----------------------------------------------------------
    def arrived(self, index: int) -> None:
        """A sample of watch `index` arrived now. The silence it ends is the watch's
        age at the last check before it (what that check saw, or would have seen had
        it looked): the longest such silence is the watch's margin (`report`)."""
        with self._lock:
            previous, count = self._arrived[index], self._samples[index]
            stall, checked = self._last_stall, self._last_check
            if self.armed and count >= 2 and stall is not None and checked is not None:
                watch = self.spec.watches[index]
                if index != self._own and self._alive.get(watch.producer, True):
                    age = checked - previous - stall
                    if age > self._worst[index]:
                        self._worst[index] = age
            self._arrived[index] = self.clock.now()
            self._samples[index] = count + 1

    def set_alive(self, component: str, alive: bool) -> None:
        """A component's liveliness token appeared or vanished."""
        with self._lock:
            was = self._alive.get(component)
            if was is None or was == alive:
                return
            self._healthy_until = -float("inf")
            self._alive_changes += 1
            self._alive[component] = alive
            self._lost += -1 if alive else 1

    # -- the control cycle --------------------------------------------------------------
    def _own_stall(self, now: float, arrived: list[float], samples: list[int]) -> float:
        """How long the monitor's own process has not been running (s): its own process
        heartbeat, written and delivered inside this process, is the reference clock.
        What this process could not see while it stood still is not evidence that the
        producers stopped."""
        index = self._own
        if index is None or samples[index] < 2:
            return 0.0
        period = heartbeat_period(self.spec.watches[index].deadline)
        return max(0.0, now - arrived[index] - 2.0 * period)

    def problems(self) -> list[str]:
        """Every input that is not healthy now, in words (not latched): lost components
        first, then late inputs. Ages are counted in the time the monitor's own process
        was running (see `_own_stall`)."""
        self.poll()
        lost, late = self._problems()
        return lost + late

    def poll(self) -> None:
        """Take the arrivals of polled watches (see `attach`); checks do it first
        unless `poll_after_cycle` did since the last check."""
        if self._polled:
            for index, port in enumerate(self._ports):
                if port.poll():
                    self.arrived(index)

    def poll_after_cycle(self) -> None:
        """`poll`, by a paced loop after its cycle's command went out (the robot
        interface's `after_cycle_hook`), so the dozen rings are not asked between a
        measurement and its answer: the next check decides on what it took. An arrival
        then counts from this poll, at most one cycle later than it came, as when the
        check takes it: a watch is as fine as the polls are frequent. One that comes
        between this poll and the check waits for the next poll (data can look older
        than it is, by the time between the two, never fresher), except before a trip:
        a check that finds an input late takes the arrivals again and decides on them.
        Runs in the loop's thread."""
        self.poll()
        self._taken = True

    def _problems(self) -> tuple[list[str], list[str]]:
        now = self.clock.now()
        out: list[str] = []
        with self._lock:
            lost = [c for c, alive in self._alive.items() if not alive]
            arrived, samples = list(self._arrived), list(self._samples)
            changes = self._alive_changes
        gone = [f"{c} lost (its process died or cannot be reached)" for c in lost]
        stall = self._own_stall(now, arrived, samples)
        worst = self._worst
        healthy_until = float("inf")
        for index, (watch, at, count) in enumerate(
            zip(self.spec.watches, arrived, samples, strict=True)
        ):
            if watch.producer in lost or index == self._own:
                continue  # the monitor's own process hanging is the arm's watchdog's job
            if count < 2:  # the first sample may be a cached one from before a loss
                out.append(f"{watch.name}: no data yet")
                healthy_until = -float("inf")
                continue
            healthy_until = min(healthy_until, at + watch.deadline)
            age = now - at - stall
            if age > worst[index] and self.armed:  # start-up gaps are not the margin
                worst[index] = age
            if age > watch.deadline:
                out.append(
                    f"{watch.name}: no data for {age * 1e3:.0f} ms "
                    f"(deadline {watch.deadline * 1e3:.0f} ms)"
                )
        with self._lock:
            if changes == self._alive_changes:  # no token came or went meanwhile
                self._healthy_until = healthy_until
        return gone, out

    def check(self, released: bool = True) -> str:
        """Once per control cycle: the latched trip reason, or '' if the robot may move.

        A lost component always trips. A late input trips while the robot is `released`
        (it could move); while it stands braked, a late input only keeps it from being
        released (`ready`): a busy host that delays a heartbeat while nothing moves is
        not yet a fault, and the robot is released only with every input on time.

        A check that comes late (this thread itself was not scheduled for a while) only
        records the time: the samples that arrived meanwhile may still be queued in the
        bus's threads, and a starved monitor must not read its own starvation as a
        silent producer. The next check, one cycle later, decides."""
        now = self.clock.now()
        taken, self._taken = self._taken, False  # by a poll after the previous cycle
        if not taken:  # latched too: a RELEASE needs the arrivals meanwhile
            self.poll()
        if self.latched:
            return self.latched
        late = self._last_check is not None and now - self._last_check > STARVED
        self._last_check = now
        if late:
            self._last_stall = None  # what this check saw is not a margin
            return ""
        self._last_stall = self._own_stall(now, self._arrived, self._samples)
        if self.armed and not self._lost and now < self._healthy_until:
            return ""  # every input is on time until then (`_healthy_until`)
        lost, late_inputs = self._problems()
        if late_inputs and taken:  # what came since that poll may answer it: a trip polls
            self.poll()
            lost, late_inputs = self._problems()
        if not lost and not late_inputs:
            self.armed = True
            return ""
        if not self.armed:
            return ""  # start-up: not every input has appeared yet (see `ready`)
        if lost:
            self.trip(lost[0])
        elif released:
            self.trip(late_inputs[0])
        return self.latched

    def trip(self, reason: str) -> None:
        """Latch a trip (the first reason is kept)."""
        if not self.latched:
            self.latched = reason
            self.trips += 1

    def ready(self) -> str:
        """'' if the robot may be released now, else why not."""
        if self.latched:
            return f"safety stop latched: {self.latched}"
        problems = self.problems()
        if problems:
            return "safety inputs not healthy: " + "; ".join(problems)
        return ""

    def acknowledge(self) -> str:
        """The operator's RELEASE: clear the latch if every input is healthy now; '' if
        cleared, else why it stays latched."""
        problems = self.problems()
        if problems:
            return "safety inputs not healthy: " + "; ".join(problems)
        self.latched = ""
        self.armed = True
        return ""

    def report(self) -> dict[str, Any]:
        """Latch, arming and each watch's age (ms) and state, for status and `report`."""
        now = self.clock.now()
        with self._lock:
            ages = [
                None if n == 0 else round((now - at) * 1e3, 1)
                for at, n in zip(self._arrived, self._samples, strict=True)
            ]
            lost = sorted(c for c, alive in self._alive.items() if not alive)
        return {
            "latched": self.latched,
            "armed": self.armed,
            "trips": self.trips,
            "lost": lost,
            "watches": {
                w.name: {
                    "age_ms": age,
                    "worst_ms": round(worst * 1e3, 1),
                    "deadline_ms": round(w.deadline * 1e3, 1),
                }
                for w, age, worst in zip(self.spec.watches, ages, self._worst, strict=True)
            },
        }
