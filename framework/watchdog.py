"""The deployer's eye on its processes, for the whole run.

A process that exits while the deployment runs is a loss: it is reported at once
(an event on `fw/deployer/events`, which the flight recorder keeps; the live screen;
`fw status`), and the Coordinator's chart gets `component.lost` for each of its
components from their liveliness. What happens next is the topology's choice, per
process:

    processes:
      cameras: {on_loss: restart}   # start it again, as it was (states, wiring)
      robot: {}                     # on_loss: stop (default): it stays lost

A restarted process gets its components back to the lifecycle states they had and
the connections the configurations had made (not only the topology's initial ones).
Motion never restarts by itself: the robot side latched its stop when the process
was lost, and only the operator's RELEASE, through the chart, opens the latch.
A process that keeps dying is restarted at most `MAX_RESTARTS` times. A restart
that fails (the new process does not come up, or does not take its states and wiring
back) is tried again, up to `ATTEMPTS` times with a growing pause, each attempt
reported; a half-started process is killed first, never left running beside the next.
Restarts run in their own thread, so a loss elsewhere is seen meanwhile.
"""

from __future__ import annotations

import contextlib
import subprocess
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from framework import keys, messages
from framework.messages import EventMessage
from framework.process import Process
from framework.topology import Step, StepKind

if TYPE_CHECKING:
    from framework.bus import Bus
    from framework.configurator import Configurator
    from framework.topology import Topology

EVENTS_KEY = keys.DEPLOYER_EVENTS
MAX_RESTARTS = 3
ATTEMPTS = 3
"""Tries per restart (the first and two more)."""
BACKOFF = 1.0  # s before the second try, doubled before each later one
POLL = 0.05  # s between looks at the processes
TARGETS = {"Running": "running", "Stopped": "stopped"}
"""Lifecycle states a restarted component is brought back to (others stay as spawned)."""


class Watched(Protocol):
    """What the watch uses of the deployment it watches (framework/deployer.py's
    `Deployment` is one): its processes and their policy, a way to spawn one again and
    wait for its components, and the Configurator that restores their wiring."""

    hub: Bus | None
    topology: Topology
    processes: list[Process]
    configurator: Configurator | None
    report: Callable[[str], None] | None

    def spawn(self, process: Process, fresh: bool = False) -> None:
        """Start `process` again (its components come up unconfigured)."""

    def wait_alive(self, components: list[str]) -> None:
        """Return once every one of `components` is alive on the bus; raise otherwise."""

    def wait_gone(self, components: list[str]) -> None:
        """Return once none of `components` is alive on the bus any more."""


class ProcessWatch:
    """Watches a deployment's processes until `stop` (see the module docstring)."""

    def __init__(self, deployment: Watched):
        self.deployment = deployment
        self.states: dict[str, str] = {}
        """The last lifecycle state each component published."""
        self.lost: dict[str, str] = {}
        """Processes lost now -> what happened."""
        self.incidents: list[str] = []
        """Every loss and restart, in order, in words (for the live screen)."""
        self.restarts: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._restarting: list[threading.Thread] = []
        self._spawn_lock = threading.Lock()
        """Held while spawning, and by `stop`: nothing is spawned once the watch stops."""
        hub = deployment.hub
        assert hub is not None
        self._states_sub = hub.subscribe(keys.ALL_STATES, self._on_state)
        self._events = hub.publisher(EVENTS_KEY, cache=False)

    def _on_state(self, sample: Any) -> None:
        try:
            message, _, _ = messages.decode(sample.payload.to_bytes(), EventMessage)
        except messages.CodecError:
            return
        self.states[message.source] = str(message.payload.get("new", ""))

    def start(self) -> ProcessWatch:
        """Begin watching (after every process is up)."""
        self._thread = threading.Thread(target=self._run, name="fw-process-watch", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop watching (before the deployment shuts its processes down)."""
        with self._spawn_lock:
            self._stop.set()
        for thread in [self._thread, *self._restarting]:
            if thread is not None and thread is not threading.current_thread():
                thread.join(5.0)
        with contextlib.suppress(Exception):
            self._states_sub.undeclare()
            self._events.undeclare()

    def _run(self) -> None:
        while not self._stop.wait(POLL):
            for process in list(self.deployment.processes):
                popen = process.popen
                if popen is None or process.name in self.lost or popen.poll() is None:
                    continue
                self._lose(process, popen.returncode)

    def note(self, kind: str, process: str, detail: str) -> None:
        """Record something that happened to a process (a fault injected on purpose)."""
        self._report(kind, process, detail)

    def _report(self, kind: str, process: str, detail: str) -> None:
        text = f"process {process} {kind.replace('_', ' ')}: {detail}"
        self.incidents = [*self.incidents[-49:], f"{time.strftime('%H:%M:%S')} {text}"]
        message = EventMessage(
            time.time(), kind, "deployer", {"process": process, "detail": detail}
        )
        with contextlib.suppress(Exception):
            self._events.put(messages.encode(message, EventMessage))
        if self.deployment.report is not None:
            self.deployment.report(f"deployer   {text}")

    def _lose(self, process: Process, code: int) -> None:
        how = f"killed by signal {-code}" if code < 0 else f"exited with code {code}"
        tail = process.tail(3)
        detail = how + (f" ({tail})" if tail else "")
        self.lost[process.name] = detail
        self._report("process_lost", process.name, detail)
        policy = self.deployment.topology.on_loss(process.name)
        if policy != "restart":
            return
        if self.restarts.get(process.name, 0) >= MAX_RESTARTS:
            self._report("restart_refused", process.name, f"lost {MAX_RESTARTS + 1} times")
            return
        self.restarts[process.name] = self.restarts.get(process.name, 0) + 1
        wanted = {c: self.states.get(c, "") for c in process.components}
        thread = threading.Thread(
            target=self._recover,
            args=(process, wanted),
            name=f"fw-restart-{process.name}",
            daemon=True,
        )
        self._restarting = [t for t in self._restarting if t.is_alive()] + [thread]
        thread.start()

    def _recover(self, process: Process, wanted: dict[str, str]) -> None:
        """Restart `process`, trying again after a failed attempt (module docstring)."""
        pause = BACKOFF
        for attempt in range(1, ATTEMPTS + 1):
            try:
                self._restart(process, wanted)
            except Exception as exc:  # reported; tried again, or the process stays lost
                self._kill(process)
                if self._stop.is_set():
                    return
                again = f"; trying again in {pause:g} s" if attempt < ATTEMPTS else ""
                self._report(
                    "restart_failed", process.name, f"attempt {attempt} of {ATTEMPTS}: {exc}{again}"
                )
                if self._stop.wait(pause):
                    return
                pause *= 2
                continue
            if self._stop.is_set():
                return
            self.lost.pop(process.name, None)
            self._report("process_restarted", process.name, "back as it was; RELEASE resumes")
            return
        self._report("restart_refused", process.name, f"{ATTEMPTS} attempts failed; it stays lost")

    def _kill(self, process: Process) -> None:
        """End a half-started process (it must not run beside the next attempt)."""
        popen = process.popen
        if popen is not None and popen.poll() is None:
            popen.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                popen.wait(5)

    def _restart(self, process: Process, wanted: dict[str, str]) -> None:
        deployment = self.deployment
        deployment.wait_gone(process.components)
        with self._spawn_lock:
            if self._stop.is_set():
                raise RuntimeError("the deployment is shutting down")
            deployment.spawn(process)
        deployment.wait_alive(process.components)
        configurator = deployment.configurator
        if configurator is None:
            return
        steps = configurator.restore_steps(set(process.components))
        steps += [
            Step(StepKind.STATE, name, TARGETS[state], timeout=5.0)
            for name, state in wanted.items()
            if state in TARGETS
        ]
        outcome = configurator.run_steps(f"restart {process.name}", steps)
        if not outcome.ok:
            raise RuntimeError(f"{outcome.step}: {outcome.reason}")
