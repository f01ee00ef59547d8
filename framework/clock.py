"""Clocks: monotonic time for real runs, a stepped clock for deterministic tests.

Everything in fw that needs time (statechart time events, component
activities, watchdogs) takes a `Clock`, so the same code runs in real time
and on a simulated clock that only moves when a test says so.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Anything that tells the time in seconds (monotonic, arbitrary origin)."""

    def now(self) -> float:
        """Current time in seconds."""
        ...


class MonotonicClock:
    """Real time from `time.monotonic()`."""

    def now(self) -> float:
        """Current monotonic time in seconds."""
        return time.monotonic()


class SimulatedClock:
    """A clock that moves only when told to; makes timing behaviour repeatable."""

    def __init__(self, start: float = 0.0):
        self._now = float(start)

    def now(self) -> float:
        """Current simulated time in seconds."""
        return self._now

    def advance(self, seconds: float) -> float:
        """Move forward by `seconds` (never backwards); return the new time."""
        if seconds < 0:
            raise ValueError("a clock cannot go backwards")
        self._now += seconds
        return self._now

    def set(self, t: float) -> None:
        """Jump to absolute time `t` (not earlier than now)."""
        if t < self._now:
            raise ValueError(f"a clock cannot go backwards ({t} < {self._now})")
        self._now = float(t)


def late(deadline: float | None, now: float | None = None) -> str:
    """'' if a request with this wall-clock deadline (s; None or 0: none) may still run,
    else the reason to refuse it. Deadlines compare wall clocks: `now` is the
    requester's, on another host the latest its measured clock can read
    (`Container.requester_now`), so an offset never lets a late request run."""
    if not deadline:
        return ""
    overdue = (time.time() if now is None else now) - float(deadline)
    if overdue <= 0:
        return ""
    return (
        f"refused, not run: its deadline passed {overdue * 1e3:.0f} ms ago "
        "(the process was busy or hung; the requester has given up on it)"
    )
