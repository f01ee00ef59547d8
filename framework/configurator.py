"""The Configurator: applies named configurations of the topology, then acknowledges.

It is the only part of fw that changes the running topology (thesis 3.5.3,
after Klotzbücher's Coordinator-Configurator pattern). Requests arrive on its
`requests` port (`ConfigRequest`, from the Coordinator) and are applied one
at a time in arrival order: two configurations never interleave, later ones
wait in the queue. Each answer is a `ConfigAck` on `acks`: ok, or the failing
step and the reason.

A configuration is an ordered list of steps: bring components to their `pre`
states, the `do` actions (disconnect, connect, set, call, write), then the
`post` states. Every step is a remote request with the configuration's
timeout (or its own). On failure the Configurator stops, undoes the
connection and property changes this application made (newest first,
best effort) and reports the failure; lifecycle changes stay as they are,
and the statechart's `config.failed` transition decides what is safe. A request
carries the chart's deadline (its configuration timeout): one that comes too late is
refused, and no step starts after it, so nothing the chart has given up on runs late.
Re-applying a configuration is harmless: connections already in place and
components already in their target state are left alone (operations are
called again, so they should be idempotent).

A configuration that begins with a *local switch* (input ports of one process
switched between keys they keep standby subscriptions to, `Topology.local_switch`)
is switched by that process itself when the request is `alone`
(framework/local_switch.py): the Configurator then waits for the process's report
instead of sending those steps, records them as its own (a later failure undoes
them too), and applies the rest.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass
from typing import Any

from framework import keys, messages
from framework.bus import Bus
from framework.clock import late
from framework.component import Component, In, Out, operation
from framework.errors import FwError
from framework.messages import ConfigAck, ConfigRequest
from framework.ports import ReadStatus
from framework.remote import RemoteComponent, RemoteError
from framework.topology import Step, StepKind, Topology

CALL_TAG = "@call"
WRITE_TAG = "@write"
KEPT_REPORTS = 64
"""Local switch reports kept for requests not served yet."""


class StepFailed(FwError):
    """One step of a configuration failed; carries the step's label."""

    def __init__(self, step: str, reason: str):
        super().__init__(f"{step}: {reason}")
        self.step, self.reason = step, reason


@dataclass
class Outcome:
    """The result of applying one configuration."""

    tag: str
    ok: bool
    step: str = ""
    reason: str = ""
    seconds: float = 0.0
    rolled_back: int = 0
    switched_by: str = ""
    """The process that made the configuration's first steps itself (a local switch)."""


class Configurator(Component):
    """Applies the topology's named configurations on request and acknowledges them."""

    needs_configuration = False
    requests = In(
        ConfigRequest,
        doc="configuration requests (from the Coordinator)",
        policy={"type": "buffer", "size": 64, "overflow": "drop_newest"},
    )
    acks = Out(ConfigAck, doc="one answer per request, in request order")

    def __init__(self, name: str, topology: Topology, bus: Bus):
        super().__init__(name)
        self.topology = topology
        self.bus = bus
        self.wiring: dict[tuple[str, str], tuple[str, Any]] = {
            (s.component, s.target): (s.key, s.policy) for s in topology.connections
        }
        self._apply_lock = threading.Lock()
        self.history: list[Outcome] = []
        self._reports: dict[int, ConfigAck] = {}
        self._reported = threading.Condition()
        self._report_subscription: Any = None
        self._forced: dict[str, float] = {}  # component -> when steps were last forced on it

    def start_hook(self) -> bool:
        """Listen for the processes' local switch reports (framework/local_switch.py).
        Runs in the thread that starts the component."""
        self._report_subscription = self.bus.subscribe(
            keys.ALL_SWITCHED, self._on_report, history=False
        )
        return True

    def stop_hook(self) -> None:
        """Stop listening for local switch reports."""
        subscription, self._report_subscription = self._report_subscription, None
        if subscription is not None:
            subscription.undeclare()

    def _on_report(self, sample: Any) -> None:
        try:
            report, _, _ = messages.decode(sample.payload.to_bytes(), ConfigAck)
        except messages.CodecError:
            return  # not a report: the wait for a real one times out
        with self._reported:
            self._reports[report.request_id] = report
            while len(self._reports) > KEPT_REPORTS:
                del self._reports[next(iter(self._reports))]
            self._reported.notify_all()

    # -- the request port ----------------------------------------------------------
    def update_hook(self) -> None:
        """Serve every configuration request waiting, in order, and ack each (in the
        component's own thread, woken by a request's arrival)."""
        while True:
            status, request = self.requests.read()
            if status is not ReadStatus.NEW:
                return
            outcome = self._serve(request)
            self.acks.write(
                ConfigAck(
                    time.time(),
                    request.request_id,
                    outcome.ok,
                    request.tag,
                    outcome.step,
                    outcome.reason,
                )
            )

    def _serve(self, request: ConfigRequest) -> Outcome:
        process, switched = ("", [])
        if request.alone and not request.tag.startswith("@"):
            process, switched = self.topology.local_switch(request.tag)
        if switched:  # made (or not) by `process` already: recorded even if late
            configuration = self.topology.configurations[request.tag]
            local = (process, len(switched), request)
            return self._run(
                request.tag, configuration.steps, request.deadline or None, local=local
            )
        overdue = late(request.deadline)
        if overdue:  # the chart gave up on it already: never apply it late
            outcome = Outcome(request.tag, False, "deadline", overdue)
            self.history.append(outcome)
            return outcome
        deadline = request.deadline or None
        if request.tag == CALL_TAG:
            return self._single(request, "call", deadline)
        if request.tag == WRITE_TAG:
            return self._single(request, "write", deadline)
        return self.apply(request.tag, deadline)

    def _single(self, request: ConfigRequest, kind: str, deadline: float | None = None) -> Outcome:
        """A chart's `call`/`write` action, run as a one-step configuration."""
        args = request.args
        comp, _, target = str(args.get("target", "")).partition(".")
        step = Step(
            kind,
            comp,
            target,
            args=dict(args.get("args") or {}),
            value=args.get("value"),
            timeout=float(args.get("timeout", 2.0)),
        )
        return self._run(f"{request.tag} {args.get('target')}", [step], deadline)

    # -- applying ------------------------------------------------------------------
    @operation
    def apply_configuration(self, tag: str) -> dict[str, Any]:
        """Apply configuration `tag` now (after any running one); the outcome as data."""
        return dict(self.apply(tag).__dict__)

    def apply(self, tag: str, deadline: float | None = None) -> Outcome:
        """Apply configuration `tag` now (queued behind any running one); no step starts
        after `deadline` (wall clock, s), and every step's request carries it."""
        configuration = self.topology.configurations.get(tag)
        if configuration is None:
            known = ", ".join(sorted(self.topology.configurations)) or "none"
            outcome = Outcome(
                tag, False, "lookup", f"unknown configuration {tag!r} (known: {known})"
            )
            self.history.append(outcome)
            return outcome
        return self._run(tag, configuration.steps, deadline)

    def run_steps(self, label: str, steps: list[Step]) -> Outcome:
        """Apply steps that are not a named configuration (the deployer's initial states,
        a restarted process's restore), in turn with configurations, every step sent
        even where the wiring already says so."""
        return self._run(label, steps, force=True)

    def restore_steps(self, components: set[str]) -> list[Step]:
        """The connections of `components` that configurations changed since the
        topology's initial wiring (a restarted process starts with that one)."""
        initial = {(s.component, s.target): (s.key, s.policy) for s in self.topology.connections}
        steps = [
            Step(StepKind.CONNECT, comp, port, key=key, policy=policy)
            for (comp, port), (key, policy) in self.wiring.items()
            if comp in components and initial.get((comp, port)) != (key, policy)
        ]
        steps += [
            Step(StepKind.DISCONNECT, comp, port)
            for (comp, port) in initial
            if comp in components and (comp, port) not in self.wiring
        ]
        return steps

    def _run(
        self,
        tag: str,
        steps: list[Step],
        deadline: float | None = None,
        force: bool = False,
        local: tuple[str, int, ConfigRequest] | None = None,
    ) -> Outcome:
        """Apply `steps`; with `local` (process, count, request), the first `count` were
        switched by that process on `request` and are only recorded here."""
        with self._apply_lock:
            start = time.perf_counter()
            undo: list[Step] = []
            try:
                if local is not None:
                    process, count, request = local
                    self._take_switch(process, steps[:count], request, undo)
                    steps = steps[count:]
                    overdue = late(deadline)
                    if overdue:  # the chart gave up meanwhile: undo the switch too
                        raise StepFailed("deadline", overdue)
                for batch in self._batches(steps, force):
                    overdue = late(deadline)
                    if overdue:
                        raise StepFailed(batch[0].describe(), overdue)
                    self._send(batch, undo, deadline)
            except StepFailed as exc:
                rolled = self._roll_back(undo)
                outcome = Outcome(
                    tag, False, exc.step, exc.reason, time.perf_counter() - start, rolled
                )
            else:
                outcome = Outcome(tag, True, seconds=time.perf_counter() - start)
            if local is not None:
                outcome.switched_by = local[0]
            if force:
                for step in steps:
                    self._forced[step.component] = time.time()
            self.history.append(outcome)
            return outcome

    def _take_switch(
        self, process: str, steps: list[Step], request: ConfigRequest, undo: list[Step]
    ) -> None:
        """Wait for `process`'s report of the local switch it made on `request` and record
        its steps as made here. Without a report, or on a failure, the switch's steps
        are undone with the rest (`StepFailed`)."""
        wait = sum(step.timeout for step in steps)
        if request.deadline:
            wait = min(wait, max(0.0, request.deadline - time.time()) + steps[0].timeout)
        with self._reported:
            self._reported.wait_for(lambda: request.request_id in self._reports, wait)
            report = self._reports.pop(request.request_id, None)
        if report is None or not report.ok:
            # It may have made any of them (a report's step name is the process's word,
            # not a count): every switched port goes back to what the wiring says.
            for step in steps:
                undo.append(self._restore(step, self.wiring.get((step.component, step.target))))
            if report is None:
                why = f"{process} did not report its local switch within {wait:g} s"
                raise StepFailed(steps[0].describe(), why)
            raise StepFailed(report.step, f"{process}: {report.reason}")
        for step in steps:
            self._record(step, None, undo)
        if any(self._forced.get(step.component, 0.0) > request.stamp for step in steps):
            for batch in self._batches(steps, True):  # a restore ran meanwhile: again
                self._send(batch, [])

    def _batches(self, steps: list[Step], force: bool) -> list[list[Step]]:
        """Consecutive steps on one component travel together (one round trip each). A
        connection the wiring already has is not made again, judged against the wiring
        as the steps before it leave it: after a disconnect of the same port in this
        configuration (a tracker swap: disconnect, then connect), it is made."""
        batches: list[list[Step]] = []
        planned: dict[tuple[str, str], Any] = {}
        for step in steps:
            port = (step.component, step.target)
            if step.kind is StepKind.DISCONNECT:
                planned[port] = None
            elif step.kind is StepKind.CONNECT:
                wired = planned[port] if port in planned else self.wiring.get(port)
                planned[port] = (step.key, step.policy)
                if not force and wired == (step.key, step.policy):
                    continue  # already so: re-applying is harmless
            if (
                step.kind is StepKind.WRITE
                or not batches
                or batches[-1][0].kind is StepKind.WRITE
                or batches[-1][0].component != step.component
            ):
                batches.append([step])
            else:
                batches[-1].append(step)
        return batches

    def _send(self, batch: list[Step], undo: list[Step], deadline: float | None = None) -> None:
        first = batch[0]
        if first.kind is StepKind.WRITE:
            self._write(first)
            return
        remote = RemoteComponent(self.bus, first.component, sum(s.timeout for s in batch))
        try:
            answer = remote.request("batch", deadline=deadline, steps=[s.request() for s in batch])
        except RemoteError as exc:
            raise StepFailed(first.describe(), str(exc)) from None
        done = batch if answer["failed"] is None else batch[: answer["failed"]]
        for step, result in zip(done, answer["results"], strict=False):
            self._record(step, result, undo)
        if answer["failed"] is not None:
            raise StepFailed(
                batch[answer["failed"]].describe(), f"{first.component}: {answer['error']}"
            )

    def _record(self, step: Step, result: Any, undo: list[Step]) -> None:
        """Remember what an executed step changed, to undo it if a later step fails."""
        where = (step.component, step.target)
        if step.kind is StepKind.CONNECT:
            previous = self.wiring.get(where)
            self.wiring[where] = (step.key, step.policy)
            undo.append(self._restore(step, previous))
        elif step.kind is StepKind.DISCONNECT:
            undo.append(self._restore(step, self.wiring.pop(where, None)))
        elif step.kind is StepKind.SET:
            undo.append(
                Step(
                    StepKind.SET,
                    step.component,
                    step.target,
                    value=result["old"],
                    timeout=step.timeout,
                )
            )

    def _restore(self, step: Step, previous: tuple[str, Any] | None) -> Step:
        if previous is None:
            return Step(StepKind.DISCONNECT, step.component, step.target, timeout=step.timeout)
        return Step(
            "connect",
            step.component,
            step.target,
            key=previous[0],
            policy=previous[1],
            timeout=step.timeout,
        )

    def _roll_back(self, undo: list[Step]) -> int:
        done = 0
        for step in reversed(undo):
            try:
                self._send([step], [])
                done += 1
            except StepFailed:
                continue  # best effort: the failure report already says what broke first
        return done

    def _write(self, step: Step) -> None:
        spec = self.topology.components.get(step.component)
        key = self.wiring.get((step.component, step.target), (None, None))[0]
        if spec is None or spec.info is None or key is None:
            raise StepFailed(step.describe(), "the port is not connected to a key")
        kind = messages.resolve_type(spec.info.inputs[step.target])
        try:
            if isinstance(step.value, dict):
                value = kind(**step.value)
            elif "value" in {f.name for f in dataclasses.fields(kind)}:
                value = kind(value=step.value)  # a bare value is the message's `value`
            else:
                raise TypeError("give its fields as a mapping")
            data = messages.encode(value, kind)
        except (TypeError, messages.CodecError) as exc:
            raise StepFailed(step.describe(), f"bad value for {kind.__name__}: {exc}") from None
        publisher = self.bus.publisher(key, cache=False)
        try:
            publisher.put(data)
        finally:
            publisher.undeclare()
