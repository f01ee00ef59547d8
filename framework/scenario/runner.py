"""Playing a scenario against a running chart and judging it: steps on a thread of
their own, expectations and invariants checked, one `Verdict` per report line."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from framework.scenario.model import Expectation, Fault, Invariant, Scenario, ScenarioStep, matches
from framework.statechart.events import Event, Listener
from framework.statechart.model import CONFIG_DONE, CONFIG_FAILED


@dataclass
class Verdict:
    """One line of the final report: passed or failed (or not exercised), and why."""

    ok: bool
    what: str
    detail: str = ""
    exercised: bool = True
    """False for an invariant whose state never held: nothing was checked, so it is
    neither a pass nor a failure (reported apart: a scenario meant to exercise it
    does not)."""


ANSWERS = (CONFIG_DONE, CONFIG_FAILED)
"""Events only the Configurator sends: a scenario written for a chart alone (a
counterexample of `fw verify`, replayed by `fw run --scenario`) gives them as steps; a
deployment's own Configurator answers instead, so the runner does not send them."""


class ScenarioRunner(Listener):
    """Plays a scenario on its own thread while listening to the chart; `report()` says
    what passed. Attach it to the Coordinator's listeners before the chart starts."""

    def __init__(
        self,
        scenario: Scenario,
        send: Callable[[str, dict[str, Any]], None],
        call: Callable[[str, dict[str, Any]], Any],
        report: Callable[[str], None] = lambda text: None,
        fault: Callable[[Fault], None] | None = None,
    ):
        """`fault` injects a `Fault` into the deployment (the deployer's processes)."""
        self.scenario, self._send, self._call, self._report = scenario, send, call, report
        self._fault = fault
        self._stop = threading.Event()
        self.finished = threading.Event()
        self._thread: threading.Thread | None = None
        self._changed = threading.Condition()
        self._zero: float | None = None
        self._started = time.monotonic()
        self.entries: list[tuple[float, str]] = []  # (monotonic time, state path)
        self.events: list[tuple[float, str, Any]] = []  # (monotonic time, name, payload)
        self.active: set[str] = set()
        self.done: list[ScenarioStep] = []
        self.outcomes: list[Verdict] = []
        self._mark = 0.0  # when the previous step's `at` or `when` was met
        self.violations: dict[int, tuple[float, str]] = {}  # invariant -> first (time, what)
        self.samples: dict[int, int] = {}
        self.unanswered: dict[int, int] = {}  # an invariant's samples nobody answered
        self._unanswered_run: dict[int, int] = {}  # ...one after the other, lately

    # --- chart listener (the Coordinator's thread) -----------------------------------
    def on_entry(self, state: Any) -> None:
        with self._changed:
            now = time.monotonic()
            self.entries.append((now, state.path))
            self.active.add(state.path)
            if (
                self._zero is None
                and self.scenario.start
                and matches(state.path, self.scenario.start)
            ):
                self._zero = now
            self._changed.notify_all()

    def on_exit(self, state: Any) -> None:
        with self._changed:
            self.active.discard(state.path)
            self._changed.notify_all()

    def on_event(self, event: Event) -> None:
        with self._changed:
            self.events.append((time.monotonic(), event.name, event.payload))
            self._changed.notify_all()

    # --- playing ---------------------------------------------------------------------
    def start(self) -> None:
        """Begin playing (time zero is now, or the `start` state's first entry)."""
        self._started = time.monotonic()
        if not self.scenario.start:
            self._zero = self._started
        self._thread = threading.Thread(target=self._play, name="fw-scenario", daemon=True)
        self._thread.start()
        if self.scenario.invariants:
            self._watcher = threading.Thread(
                target=self._watch, name="fw-scenario-invariants", daemon=True
            )
            self._watcher.start()

    def _watch(self) -> None:
        """Sample every invariant at 10 Hz while its state is active (past its grace)."""
        while not self._stop.is_set() and not self.finished.is_set():
            now = time.monotonic()
            with self._changed:
                active = set(self.active)
                entries = list(self.entries)
            for index, inv in enumerate(self.scenario.invariants):
                if index in self.violations or self._zero is None:
                    continue
                if inv.state:
                    paths = [p for p in active if matches(p, inv.state)]
                    if not paths:
                        continue
                    entered = max(t for t, p in entries if p in paths)
                    if now - entered < inv.grace:
                        continue
                elif now - self._zero < inv.grace:
                    continue
                try:
                    result = self._call(inv.check, {})
                except Exception as exc:  # any failed check call is judged below, never lost
                    if getattr(exc, "kind", "") == "Timeout":  # asked, never answered
                        self.unanswered[index] = self.unanswered.get(index, 0) + 1
                        self._unanswered_run[index] = self._unanswered_run.get(index, 0) + 1
                        if self._unanswered_run[index] < UNANSWERED_LIMIT:
                            continue
                    result = f"call failed: {exc}"
                else:
                    self._unanswered_run[index] = 0
                with self._changed:  # the state may have changed during the call
                    still = not inv.state or any(matches(p, inv.state) for p in self.active)
                problem = inv.violation(result)
                self.samples[index] = self.samples.get(index, 0) + 1
                if problem and still:
                    self.violations[index] = (now - self._zero, problem)
            self._stop.wait(0.1)

    def _deadline(self) -> float:
        return self._started + self.scenario.timeout

    def _wait(self, condition: Callable[[], bool], until: float | None = None) -> bool:
        """Wait for `condition` (checked under the lock); False on stop, on timeout, or
        once the run failed for good (`failed_for_good`)."""
        end = self._deadline() if until is None else min(until, self._deadline())
        with self._changed:
            while not condition():
                left = end - time.monotonic()
                if left <= 0 or self._stop.is_set() or self.failed_for_good():
                    return condition()
                self._changed.wait(min(left, 0.05))
        return True

    def _where(self) -> str:
        """Where the chart stood, for a run that gave up waiting: its innermost active
        states and the last event it took (a configuration's answer among them)."""
        with self._changed:
            active = sorted(self.active)
            last = self.events[-1][1] if self.events else ""
        leaves = [a for a in active if not any(b.startswith(a + ".") for b in active)]
        where = f"the chart was in {', '.join(leaves)}" if leaves else "the chart never started"
        return where + (f"; its last event: {last}" if last else "; it took no event")

    def failed_for_good(self) -> str:
        """Why the run can no longer pass, or "": a `never_state` entered or a
        `never_event` come. The run then ends at once instead of waiting out its steps'
        states (a robot stopped by a fault never reaches the target: without this the
        run waited its whole timeout, minutes, to say so)."""
        for e in self.scenario.expect:
            if e.kind.startswith("never"):
                ok, detail = self._check(e)
                if not ok:
                    return f"{e.describe().replace('never ', '', 1)} came {detail}"
        return ""

    def _play(self) -> None:
        try:
            if not self._wait(lambda: self._zero is not None):
                self.outcomes.append(
                    Verdict(
                        False, f"start state {self.scenario.start} never entered", self._where()
                    )
                )
                return
            previous: ScenarioStep | None = None
            self._mark = self._zero
            for step in self.scenario.steps:
                share = previous is not None and bool(step.when) and previous.when == step.when
                if not self._run_step(step, share):
                    return
                previous = step
            if self.scenario.end:
                self._wait(lambda: any(matches(s, self.scenario.end) for s in self.active))
            else:
                self._wait(self._expectations_met)
        finally:
            self.finished.set()

    def _run_step(self, step: ScenarioStep, share: bool) -> bool:
        assert self._zero is not None
        if step.when and not share:
            mark = self._mark

            names = (step.when,) if isinstance(step.when, str) else step.when

            def entered() -> bool:
                for t, path in self.entries:
                    if t >= mark and any(matches(path, n) for n in names):
                        self._mark = t
                        return True
                return False

            if not self._wait(entered):
                why = self.failed_for_good()
                detail = f"not played: {why}" if why else f"{' or '.join(names)} never entered"
                self.outcomes.append(Verdict(False, step.describe(), detail))
                return False
        if step.at is not None:
            self._wait(lambda: False, self._zero + step.at)
            self._mark = max(self._mark, self._zero + step.at)
        if step.after:
            self._wait(lambda: False, time.monotonic() + step.after)
        why = self.failed_for_good()
        if why or self._stop.is_set() or time.monotonic() >= self._deadline():
            self.outcomes.append(
                Verdict(False, step.describe(), f"not played: {why or 'time out'}")
            )
            return False
        elapsed = time.monotonic() - self._zero
        try:
            if step.send in ANSWERS:
                self._report(
                    f"scenario   {elapsed:7.3f}s {step.describe()}: not sent, the "
                    "deployment's Configurator answers its requests itself"
                )
            elif step.send:
                self._send(step.send, step.payload)
            elif step.call:
                self._call(step.call, step.payload)
            elif step.fault is not None:
                if self._fault is None:
                    raise RuntimeError("this run cannot inject faults (no deployer)")
                self._fault(step.fault)
            else:
                until = time.monotonic() + step.wait
                while True:  # with `wait`, poll until the result matches (a hang bound)
                    try:
                        result = self._call(step.check, step.payload)
                    except Exception:  # retried until `until`, then raised: a FAIL of the step
                        if time.monotonic() >= until:  # no answer at all: a FAIL below
                            raise
                        self._stop.wait(0.05)
                        continue
                    wrong = {
                        k: result.get(k) if isinstance(result, dict) else result
                        for k, v in step.expect.items()
                        if not isinstance(result, dict) or result.get(k) != v
                    }
                    wrong.update(
                        {
                            k: result.get(k) if isinstance(result, dict) else result
                            for k, v in step.maximum.items()
                            if not isinstance(result, dict) or not _at_most(result.get(k), v)
                        }
                    )
                    if not wrong or time.monotonic() >= until or self._stop.wait(0.05):
                        break
                ok = not wrong
                fields = (*step.expect, *step.maximum)
                missing = isinstance(result, dict) and any(k not in result for k in fields)
                got = result if missing or not isinstance(result, dict) else wrong
                wanted = {**step.expect, **{k: f"<= {v:g}" for k, v in step.maximum.items()}}
                detail = "" if ok else f"expected {wanted}, got {got}"
                self.outcomes.append(Verdict(ok, step.describe(), detail))
            self._report(f"scenario   {elapsed:7.3f}s {step.describe()}")
        except Exception as exc:  # a failing step is reported, the scenario goes on
            self.outcomes.append(Verdict(False, step.describe(), f"failed: {exc}"))
            self._report(f"scenario   {elapsed:7.3f}s {step.describe()} failed: {exc}")
        self.done.append(step)
        return True

    def _expectations_met(self) -> bool:
        return all(
            self._check(e)[0] for e in self.scenario.expect if not e.kind.startswith("never")
        )

    def _check(self, e: Expectation) -> tuple[bool, str]:
        zero = self._zero if self._zero is not None else self._started
        limit = None if e.within is None else zero + e.within
        if e.kind in ("state", "never_state"):
            times = [t for t, p in self.entries if any(matches(p, n) for n in e.names)]
        else:
            came = [(t, payload) for t, n, payload in self.events if n in e.names]
            times = [t for t, _ in came]
            if e.kind == "never_event" and came:  # say why it came: the reason to look at
                t, payload = came[0]
                return False, f"at {t - zero:.3f}s" + (f" {payload}" if payload else "")
        if e.kind.startswith("never"):
            return (not times, f"at {times[0] - zero:.3f}s" if times else "")
        hits = [t for t in times if limit is None or t <= limit]
        if hits:
            return True, f"at {hits[0] - zero:.3f}s"
        return False, "late" if times else "never"

    def stop(self) -> None:
        """Stop playing (steps not yet due are skipped)."""
        self._stop.set()
        with self._changed:
            self._changed.notify_all()
        if self._thread is not None:
            self._thread.join(2.0)

    def report(self) -> list[Verdict]:
        """Every check and expectation with PASS or FAIL."""
        out = list(self.outcomes)
        played = len(self.done)
        if played < len(self.scenario.steps) and not any(not o.ok for o in self.outcomes):
            out.append(Verdict(False, f"only {played} of {len(self.scenario.steps)} steps played"))
        for e in self.scenario.expect:
            ok, detail = self._check(e)
            out.append(Verdict(ok, e.describe(), detail))
        for index, inv in enumerate(self.scenario.invariants):
            samples = self.samples.get(index, 0)
            if index in self.violations:
                at, what = self.violations[index]
                out.append(Verdict(False, inv.describe(), f"violated at {at:.3f}s: {what}"))
            elif samples:
                missed = self.unanswered.get(index, 0)
                note = f", {missed} more asked but not answered in time" if missed else ""
                out.append(Verdict(True, inv.describe(), f"{samples} samples{note}"))
            else:
                out.append(Verdict(True, inv.describe(), self._unrun(inv), exercised=False))
        return out

    def _unrun(self, inv: Invariant) -> str:
        """Why an invariant was never sampled, in words: its state never active, or
        never past its grace (the run ended or the state was left first)."""
        if not inv.state:
            return f"the run ended within its {inv.grace:g}s grace: nothing checked"
        with self._changed:
            entered = any(matches(path, inv.state) for _, path in self.entries)
        if not entered:
            return f"{inv.state} was never active: nothing checked"
        return (
            f"{inv.state} was entered but never held past its {inv.grace:g}s grace "
            "(left first, or the run ended): nothing checked"
        )


UNANSWERED_LIMIT = 3
"""Samples of an invariant in a row whose call timed out before that is a violation. A
check asked of a busy host's process may go unanswered once (the referee's question,
not the robot's behaviour: the next sample still sees a running maximum such as
`peak_step`); a component that answers none of three (300 ms) fails the invariant."""


def _at_most(value: Any, limit: float) -> bool:
    """True for a number no greater than `limit` (anything else fails the check)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and value <= limit
