"""The Coordinator: runs the procedure's statechart, the only task-aware part of fw.

It takes events from its `events` port (components, console and `fw send` all
publish `EventMessage`s on `fw/events`), sends a `ConfigRequest` whenever the
chart asks for a configuration, and turns every `ConfigAck` into the chart's
`config.done` / `config.failed` event: a state that requested a configuration
completes only on its ack, and a failure or timeout is an event the chart
handles. The chart's `call` and `write` actions go to the Configurator too (it
is the only part that touches components); its `send` actions are published
on `sent`. Every step is published on `status`: the event, the transitions, and
the active configuration afterwards.

Given the deployment's components (`watch`), it also follows their liveliness for the
whole run: a component whose process dies or can no longer be reached becomes the
chart's builtin event `component.lost {component, process}` (and `component.back`
when it returns), so a lost process is a chart event, never silence.

The chart runs on its own thread, on monotonic time; tests can drive the same
chart deterministically with the interpreter and a `SimulatedClock`.
"""

from __future__ import annotations

import contextlib
import difflib
import itertools
import threading
import time
from dataclasses import dataclass
from typing import Any

from framework import keys
from framework.component import Component, In, Out, operation
from framework.configurator import CALL_TAG, WRITE_TAG
from framework.messages import ConfigAck, ConfigRequest, EventMessage
from framework.ports import ReadStatus
from framework.statechart.events import Event, Listener, Output
from framework.statechart.interpreter import Interpreter
from framework.statechart.model import (
    BUILTIN_EVENTS,
    COMPONENT_BACK,
    COMPONENT_LOST,
    CONFIG_DONE,
    CONFIG_FAILED,
    State,
    Statechart,
    Transition,
)

EVENTS_KEY = "fw/events"
REQUESTS_KEY = keys.CONFIG_REQUESTS
ACKS_KEY = keys.CONFIG_ACKS
STATUS_KEY = "fw/coordinator/status"
SENT_KEY = "fw/coordinator/sent"
ACTION_TIMEOUT = 2.0
"""Seconds a chart's `call` or `write` action may take (a configuration has its own)."""


IDLE_WAIT = 0.5
"""Longest sleep of the chart's loop with nothing due (an event wakes it at once)."""


def loop_wait(deadline: float | None, now: float) -> float:
    """How long the chart's loop may sleep: until its next time event is due (never
    negative), at most `IDLE_WAIT`."""
    if deadline is None:
        return IDLE_WAIT
    return max(0.0, min(IDLE_WAIT, deadline - now))


@dataclass(frozen=True)
class Admission:
    """Who may give the chart which event, from the topology: the operator's events
    (`external_events`, through `offer`: the console, `fw send`) and, per component,
    the events its class declares it emits (put on the events port). `None` for a
    part means anything goes (a Coordinator outside a deployment, in tests). Builtin
    events (`config.*`, `component.*`) only ever come from the Coordinator itself."""

    external: frozenset[str] | None = None
    emitters: dict[str, frozenset[str]] | None = None

    def refuse_sample(self, source: str, event: str) -> str:
        """Why an event put on the events port by `source` is refused ("" if taken)."""
        if event in BUILTIN_EVENTS:
            return f"{event} is the Coordinator's own event; nobody may send it"
        if self.emitters is None:
            return ""
        if source not in self.emitters:
            return f"{source or 'an unnamed sender'} is not a component of this deployment"
        if event not in self.emitters[source]:
            return f"{source} does not declare that it emits {event}"
        return ""

    def refuse_command(self, event: str) -> str:
        """Why an operator's command is refused before the chart sees it ("" if not)."""
        if event in BUILTIN_EVENTS:
            return f"{event} is the Coordinator's own event; nobody may send it"
        if self.external is not None and event not in self.external:
            allowed = ", ".join(sorted(self.external)) or "none"
            close = difflib.get_close_matches(event, sorted(self.external), n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]}?" if close else ""
            return (
                f"{event} is not an operator event of this topology (those are: {allowed})" + hint
            )
        return ""


class _Publisher(Listener):
    """Turns interpreter callbacks into status messages."""

    def __init__(self, coordinator: Coordinator):
        self.coordinator = coordinator

    def on_event(self, event: Event) -> None:
        self.coordinator.publish(
            "event", {"event": event.name, "payload": event.payload, "kind": event.kind}
        )

    def on_unhandled(self, event: Event, reason: str) -> None:
        self.coordinator.unhandled = (event.name, reason)
        self.coordinator.publish("unhandled", {"event": event.name, "reason": reason})

    def on_transition(self, transition: Transition, event: Event | None) -> None:
        self.coordinator.publish(
            "transition",
            {
                "source": transition.source.path,
                "target": transition.target.path if transition.target is not None else None,
                "event": event.name if event is not None else None,
            },
        )

    def on_entry(self, state: State) -> None:
        self.coordinator.publish("entry", {"state": state.path})

    def on_exit(self, state: State) -> None:
        self.coordinator.publish("exit", {"state": state.path})

    def on_error(self, message: str, event: Event | None) -> None:
        self.coordinator.publish("error", {"message": message})


class Coordinator(Component):
    """Hosts the procedure statechart and talks to the Configurator by tags and acks."""

    needs_configuration = False
    emits = ()
    events = In(
        EventMessage,
        doc="events for the chart (fw/events)",
        policy={"type": "buffer", "size": 1024, "overflow": "drop_newest"},
    )
    acks = In(
        ConfigAck,
        doc="answers of the Configurator",
        policy={"type": "buffer", "size": 256, "overflow": "drop_newest"},
    )
    requests = Out(ConfigRequest, doc="configuration tags for the Configurator")
    status = Out(EventMessage, doc="events, transitions and the active configuration")
    sent = Out(EventMessage, doc="events the chart sends to the outside world")

    def __init__(
        self,
        name: str,
        chart: Statechart,
        listeners: list[Listener] | None = None,
        watch: dict[str, str] | None = None,
        admission: Admission | None = None,
    ):
        """`watch` maps every component of the deployment to its process: their losses
        become `component.lost` events; `admission` says who may send what (every
        event's payload is checked against the chart's declaration in any case)."""
        super().__init__(name)
        self.chart = chart
        self.admission = admission or Admission()
        self.refused = 0
        """Events refused where they entered (each is also a `refused` status)."""
        self.watch = dict(watch or {})
        self.lost: dict[str, str] = {}
        """Components lost now -> their process."""
        self._alive: set[str] = set()
        self._tokens: Any = None
        self.extra_listeners = list(listeners or [])
        self.interpreter: Interpreter | None = None
        self._ids = itertools.count(1)
        self._pending: dict[int, str] = {}
        self._deadlines: dict[int, float] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._chart_lock = threading.RLock()  # not the lifecycle lock: stop() joins the loop
        self._status_lock = threading.Lock()  # see `publish`
        self.last_events: list[str] = []
        self.unhandled: tuple[str, str] | None = None  # the last event nothing took, why

    # -- lifecycle -----------------------------------------------------------------
    def start_hook(self) -> bool:
        """Build the interpreter and start the chart's own thread (`fw-<name>`), which
        from now on takes every event and ack; watch the components' liveliness if asked.
        Runs in the thread that starts the component (the deployer's)."""
        self.events.on_data = self.acks.on_data = lambda _port: self._wake.set()
        self.interpreter = Interpreter(
            self.chart,
            listeners=[_Publisher(self), *self.extra_listeners],
            on_output=self._on_output,
        )
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name=f"fw-{self.name}", daemon=True)
        self._thread.start()
        if self.watch and self.bus is not None:  # stop_hook let go of any earlier one
            self._tokens = self.bus.watch(keys.ALL_ALIVE, self._on_token)
        return True

    def _on_token(self, key: str, alive: bool) -> None:
        """A liveliness token appeared or vanished (the bus's thread)."""
        component = key.rsplit("/", 1)[-1]
        process = self.watch.get(component)
        if process is None:
            return
        payload = {"component": component, "process": process}
        if alive:
            self._alive.add(component)
            if self.lost.pop(component, None) is not None:
                self.inject(COMPONENT_BACK, payload)
        elif component in self._alive:
            self._alive.discard(component)
            self.lost[component] = process
            self.inject(COMPONENT_LOST, payload)

    def stop_hook(self) -> None:
        """Stop watching liveliness and end the chart's thread (joined for up to 2 s).
        Runs in the thread that stops the component."""
        if self._tokens is not None:
            self._tokens.undeclare()
            self._tokens = None
        self._stop.set()
        self._wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self._thread = None

    # -- the loop --------------------------------------------------------------------
    def _loop(self) -> None:
        interpreter = self.interpreter
        assert interpreter is not None
        with self._chart_lock:
            interpreter.start()
            self._publish_configuration()
        while not self._stop.is_set():
            self._wake.wait(loop_wait(interpreter.next_deadline(), time.monotonic()))
            self._wake.clear()
            with self._chart_lock:
                self._drain()
                if interpreter.run():
                    self._publish_configuration()

    def _drain(self) -> None:
        interpreter = self.interpreter
        assert interpreter is not None
        while True:
            status, ack = self.acks.read()
            if status is not ReadStatus.NEW:
                break
            tag = self._pending.pop(ack.request_id, None)
            self._deadlines.pop(ack.request_id, None)
            if tag is None:
                continue  # an answer to another coordinator, or already timed out
            if tag.startswith("@"):
                if not ack.ok:
                    self.publish("error", {"message": f"{tag}: {ack.step}: {ack.reason}"})
                continue
            name = CONFIG_DONE if ack.ok else CONFIG_FAILED
            payload = (
                {"tag": ack.tag}
                if ack.ok
                else {"tag": ack.tag, "step": ack.step, "reason": ack.reason}
            )
            interpreter.queue(name, payload)
        while True:
            status, message = self.events.read()
            if status is not ReadStatus.NEW:
                break
            reason = self.admission.refuse_sample(message.source, message.name)
            reason = reason or self._payload_problem(message.name, message.payload)
            if reason:
                self._refuse(message.name, message.source, reason)
                continue
            self.last_events = [*self.last_events[-19:], message.name]
            interpreter.queue(message.name, message.payload or None)

    def _payload_problem(self, event: str, payload: Any) -> str:
        """Why `payload` does not fit the chart's declaration of `event` ("" if it does
        or the chart declares nothing about it)."""
        if payload is not None and not isinstance(payload, dict):
            return f"{event}: a payload must be a mapping of fields"
        spec = self.chart.events.get(event)
        return spec.problem(payload or {}) if spec is not None else ""

    def _refuse(self, event: str, source: str, reason: str, publish: bool = True) -> None:
        """Count and report an event refused where it entered (`publish=False` when the
        caller's own status message already carries the refusal)."""
        self.refused += 1
        if publish:
            self.publish("refused", {"event": event, "source": source, "reason": reason})
        for listener in self.extra_listeners:
            with contextlib.suppress(Exception):
                listener.on_refused(event, source, reason)

    def _on_output(self, output: Output) -> None:
        if output.kind == "configure":
            self._request(output.tag, {}, output.timeout)
        elif output.kind == "call":
            self._request(CALL_TAG, {"target": output.operation, "args": output.args})
        elif output.kind == "write":
            self._request(WRITE_TAG, {"target": output.port, "value": output.value})
        elif output.kind == "send":
            self.sent.write(EventMessage(time.time(), output.event, self.name, output.payload))
        else:
            self.publish("log", {"state": output.state, "message": output.message})

    def _request(self, tag: str, args: dict[str, Any], timeout: float = ACTION_TIMEOUT) -> None:
        """One request for the Configurator, with the deadline after which the chart has
        given up on it (its configuration timeout): the Configurator refuses it then."""
        request_id = next(self._ids)
        now = time.time()
        alone = self._nothing_pending(now)
        self._pending[request_id] = tag
        deadline = now + timeout  # a chart's configuration timeout is positive (validated)
        self._deadlines[request_id] = deadline
        self.publish("request", {"tag": tag, "request_id": request_id, **args})
        self.requests.write(ConfigRequest(now, request_id, tag, args, deadline, alone))

    def _nothing_pending(self, now: float) -> bool:
        """True if every earlier request is answered or past its deadline (the
        Configurator starts no step after it); forgets those past it."""
        for request_id, deadline in list(self._deadlines.items()):
            if deadline < now:
                del self._deadlines[request_id]
        return not self._deadlines

    # -- status ----------------------------------------------------------------------
    def publish(self, kind: str, payload: dict[str, Any]) -> None:
        """Publish one status message (best effort: status never stops the chart).

        Called from the chart's thread and from operations (`offer`) that do not hold
        the component's lock, so the writes are serialized here: a port numbers each
        sample, and a reader drops a number at or below one it kept as a repeat, so two
        writers overtaking each other between numbering and sending lost the earlier
        record (a console missed `command e_START`)."""
        with self._status_lock, contextlib.suppress(Exception):
            self.status.write(EventMessage(time.time(), kind, self.name, payload))

    def _publish_configuration(self) -> None:
        interpreter = self.interpreter
        if interpreter is not None:
            self.publish(
                "configuration",
                {
                    "active": interpreter.leaves,
                    "pending": interpreter.pending_configurations,
                    "finished": interpreter.finished,
                },
            )

    def inject(self, event: str, payload: dict[str, Any] | None = None) -> bool:
        """Queue an event for the chart, unchecked: for this process only (liveliness,
        scenarios). Not a remote operation: from outside, events go through `offer`."""
        with self._chart_lock:
            if self.interpreter is None:
                return False
            self.interpreter.queue(event, payload)
        self._wake.set()
        return True

    @operation
    def offer(
        self, event: str, payload: dict[str, Any] | None = None, origin: str = ""
    ) -> dict[str, Any]:
        """Give the chart an operator's command and answer whether it was taken.

        The event is processed at once (not queued behind the loop), so the answer is
        the chart's: accepted, or refused with the reason (no transition on it in the
        active states, every guard false, the chart not running). Every command is
        published on `status` as `command` with its origin, so the flight recorder
        keeps who asked for what."""
        refusal = self.admission.refuse_command(event) or self._payload_problem(event, payload)
        with self._chart_lock:
            interpreter = self.interpreter
            if refusal:
                answer = {"accepted": False, "reason": refusal}
                self._refuse(event, origin or "operator", refusal, publish=False)  # `command`
            elif interpreter is None or interpreter.finished:
                answer = {"accepted": False, "reason": "the procedure chart is not running"}
            elif not interpreter.accepts(event):
                where = ", ".join(p.rsplit(".", 1)[-1] for p in interpreter.leaves)
                answer = {"accepted": False, "reason": f"{event} is not taken in {where}"}
            else:
                self.unhandled = None
                self.last_events = [*self.last_events[-19:], event]
                interpreter.queue(event, payload)
                if interpreter.run():
                    self._publish_configuration()
                if self.unhandled is not None and self.unhandled[0] == event:
                    answer = {"accepted": False, "reason": self.unhandled[1]}
                else:
                    answer = {"accepted": True, "reason": ""}
        self.publish("command", {"event": event, "payload": payload, "origin": origin, **answer})
        return answer

    @operation(readonly=True)
    def takeable(self, events: list[str]) -> list[str]:
        """Which of `events` the chart would take now (see `Interpreter.accepts`)."""
        with self._chart_lock:
            interpreter = self.interpreter
            if interpreter is None or interpreter.finished:
                return []
            return [e for e in events if interpreter.accepts(e)]

    @operation(readonly=True)
    def active(self) -> dict[str, Any]:
        """Active states, pending configurations and the last events."""
        interpreter = self.interpreter
        if interpreter is None:
            return {
                "active": [],
                "pending": {},
                "finished": False,
                "last_events": [],
                "lost": dict(self.lost),
            }
        with self._chart_lock:
            return {
                "active": interpreter.leaves,
                "pending": interpreter.pending_configurations,
                "finished": interpreter.finished,
                "last_events": list(self.last_events),
                "lost": dict(self.lost),
            }
