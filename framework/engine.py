"""The execution engine of a paced loop: operations run by the loop's own thread, between
its cycles (OROCOS RTT's ExecutionEngine).

A component whose device paces it (`Activity.paced`: the robot interface answering the
KRC every millisecond) must never wait for a lock an operation holds: a Configurator's
`release`, a console's `brake` or an interpolator's `go_to` would otherwise take the
component's lock from a bus thread in the middle of a cycle. So while the loop runs,
an exclusive operation of the loop's components (the paced one and those that run
after it) is not run by the caller: it is queued, the loop runs it right after a cycle
has sent its command, and the caller waits for the result. The loop runs what is
queued within `budget` seconds per gap (the rest in the next gap), each operation
whole: so an operation of such a component must be short (a state change, a report,
not a computation that takes milliseconds). A report is run by the loop too (it reads
what the cycles write); only a non-exclusive operation (`await_ready`, which waits)
runs in the caller's thread.

When the loop does not run (the executor has not started it, or it stopped), the
caller runs the operation itself under the component's lock, as for any component.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from framework.errors import FwError

BUDGET = 0.0002
"""s: how long the loop runs queued operations after a cycle before it waits for the
next one (the operations left wait for the next gap)."""


class EngineStopped(FwError):
    """The loop stopped before it ran the operation (it was not run)."""


class _Call:
    """One queued operation and its outcome."""

    __slots__ = ("done", "error", "fn", "queued", "result")

    def __init__(self, fn: Callable[[], Any]):
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None
        self.queued = time.monotonic()


class ExecutionEngine:
    """Operations of a paced loop's components, run by the loop (module docstring)."""

    def __init__(self, name: str, budget: float = BUDGET):
        self.name = name
        self.budget = budget
        self._queue: deque[_Call] = deque()
        self.thread_id: int | None = None
        """The loop's thread while it runs (None: it does not)."""
        self.ran = 0
        self.longest = 0.0
        """s: the longest operation the loop ran, for `fw bench cost` and reports."""
        self.waited = 0.0
        """s: the longest an operation waited in the queue."""
        self.loop: Any = None
        """The loop's `LoopStats` (framework/realtime.py) once it runs."""

    @property
    def running(self) -> bool:
        """True while the loop's thread runs and takes operations."""
        return self.thread_id is not None

    def in_loop(self) -> bool:
        """True when called from the loop's own thread (an operation it runs, a hook)."""
        return self.thread_id == threading.get_ident()

    def call(self, fn: Callable[[], Any], timeout: float = 10.0) -> Any:
        """Queue `fn` for the loop, wait for it and return its result (or raise what it
        raised). `EngineStopped` if the loop stopped first or did not take it in time."""
        item = _Call(fn)
        self._queue.append(item)
        if not item.done.wait(timeout):
            try:
                self._queue.remove(item)
            except ValueError:  # the loop took it meanwhile: its outcome is coming
                item.done.wait()
            else:
                raise EngineStopped(f"{self.name}: the loop did not run it within {timeout:g} s")
        if item.error is not None:
            raise item.error
        return item.result

    def run_pending(self) -> int:
        """In the loop's thread, between cycles: run queued operations for at most
        `budget` seconds (each whole); how many ran."""
        if not self._queue:
            return 0
        start = time.perf_counter()
        ran = 0
        while self._queue:
            item = self._queue.popleft()
            began = time.perf_counter()
            self.waited = max(self.waited, time.monotonic() - item.queued)
            try:
                item.result = item.fn()
            except BaseException as exc:  # the caller gets it, the loop goes on
                item.error = exc
            item.done.set()
            ran += 1
            now = time.perf_counter()
            self.longest = max(self.longest, now - began)
            if now - start >= self.budget:
                break
        self.ran += ran
        return ran

    def stop(self) -> None:
        """The loop ends: what is still queued is refused, not run."""
        self.thread_id = None
        while self._queue:
            item = self._queue.popleft()
            item.error = EngineStopped(f"{self.name}: the loop stopped before running it")
            item.done.set()

    def scheduling(self) -> str | None:
        """What the loop got from the host (SCHED_FIFO 80, or why not); None before it runs."""
        return self.loop.scheduling if self.loop is not None else None

    def report(self) -> dict[str, Any]:
        """What the engine ran, for reports: count, longest run and wait (ms)."""
        out = {
            "operations": self.ran,
            "longest_operation_ms": round(self.longest * 1e3, 3),
            "longest_wait_ms": round(self.waited * 1e3, 3),
            "queued": len(self._queue),
        }
        if self.loop is not None:
            out.update(self.loop.report())
        return out
