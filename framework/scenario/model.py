"""A scenario as fw holds it once loaded: its steps, faults, expectations and
invariants (the YAML form: framework/scenario/__init__.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from framework.errors import Location


@dataclass
class ScenarioStep:
    """One step: wait for its time or state, then send, call or check."""

    at: float | None = None
    when: str | tuple[str, ...] = ""
    """A state (or several: whichever is entered first) to wait for."""
    after: float = 0.0
    send: str = ""
    call: str = ""
    check: str = ""
    payload: dict[str, Any] = field(default_factory=dict)
    expect: dict[str, Any] = field(default_factory=dict)
    maximum: dict[str, float] = field(default_factory=dict)
    """Numeric fields of a check's result that must not exceed these."""
    wait: float = 0.0
    fault: Fault | None = None
    location: Location = field(default_factory=Location)

    def describe(self) -> str:
        """How the step reads in a report."""
        when = self.when if isinstance(self.when, str) else " or ".join(self.when)
        trigger = f"{self.at:g}s" if self.at is not None else f"on {when}"
        if self.after:
            trigger += f" +{self.after:g}s"
        if self.send:
            action = f"send {self.send}"
        elif self.call:
            action = f"call {self.call}"
        elif self.fault is not None:
            action = self.fault.describe()
        else:
            action = f"check {self.check}"
        return f"{trigger}: {action}"


@dataclass(frozen=True)
class Fault:
    """A fault to inject: into one process (a signal, and for STOP how long it hangs),
    or into one host's network link (`link`: a partition of `hold` s, or loss, delay
    and jitter for `hold` s)."""

    process: str = ""
    signal: str = ""
    hold: float = 0.0
    link: str = ""
    partition: bool = False
    loss: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0

    def describe(self) -> str:
        """How the fault reads in a report."""
        if self.link:
            if self.partition:
                return f"fault link {self.link} partition {self.hold:g}s"
            said = [f"loss {self.loss:.0%}"] if self.loss else []
            said += [f"delay {self.delay * 1e3:g}ms"] if self.delay else []
            said += [f"jitter {self.jitter * 1e3:g}ms"] if self.jitter else []
            return f"fault link {self.link} {' '.join(said)} for {self.hold:g}s"
        hold = f" for {self.hold:g}s" if self.signal == "STOP" else ""
        return f"fault {self.process} {self.signal}{hold}"


@dataclass
class Expectation:
    """One thing the run must (or must never) show."""

    kind: str  # state, event, never_state, never_event
    name: str | tuple[str, ...]
    """One name, or (`state` only) several: any one of them counts."""
    within: float | None = None
    location: Location = field(default_factory=Location)

    @property
    def names(self) -> tuple[str, ...]:
        """The name(s) as a tuple."""
        return (self.name,) if isinstance(self.name, str) else self.name

    def describe(self) -> str:
        """How the expectation reads in a report."""
        text = f"{self.kind.replace('_', ' ')} {' or '.join(self.names)}"
        return text + (f" within {self.within:g}s" if self.within is not None else "")


@dataclass
class Invariant:
    """Something that must hold whenever a state is active (after a grace period)."""

    check: str
    expect: dict[str, Any] = field(default_factory=dict)
    maximum: dict[str, float] = field(default_factory=dict)
    state: str = ""  # empty: always (from time zero)
    grace: float = 0.0
    location: Location = field(default_factory=Location)

    def describe(self) -> str:
        """How the invariant reads in a report."""
        when = f"while {self.state}" + (f" (+{self.grace:g}s)" if self.grace else "")
        what = ", ".join(
            [f"{k} == {v!r}" for k, v in self.expect.items()]
            + [f"{k} <= {v:g}" for k, v in self.maximum.items()]
        )
        return f"{when if self.state else 'always'}: {self.check} {what}"

    def violation(self, result: Any) -> str:
        """'' if `result` satisfies the invariant, else what is wrong."""
        if not isinstance(result, dict):
            return f"got {result!r}"
        wrong = [f"{k}={result.get(k)!r}" for k, v in self.expect.items() if result.get(k) != v]
        for k, v in self.maximum.items():
            value = result.get(k)
            if not isinstance(value, int | float) or value > v:
                wrong.append(f"{k}={value!r}")
        return ", ".join(wrong)


@dataclass
class Scenario:
    """A loaded scenario."""

    name: str
    steps: list[ScenarioStep]
    expect: list[Expectation] = field(default_factory=list)
    start: str = ""
    timeout: float = 120.0
    end: str = ""
    invariants: list[Invariant] = field(default_factory=list)


def matches(path: str, name: str) -> bool:
    """Does the state `path` carry `name`: its full path or a dotted suffix of it?"""
    return path == name or path.endswith("." + name)
