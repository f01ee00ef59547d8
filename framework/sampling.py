"""Where a process spends its CPU: a sampling profiler for one container process.

Set `FW_SAMPLE_STACKS=<folder>` in the environment of `fw deploy` (or of one
container) and each container process writes `<folder>/<process>.stacks` when it
stops: one line per distinct Python stack, `thread;outer;...;inner microseconds`, the
"collapsed" format flame-graph tools read (flamegraph.pl, speedscope, inferno).

Every `interval` s the sampler reads each thread's CPU time (its own clock for a
Python thread, /proc/self/task/<tid>/stat's ticks for the others) and adds what it
used since the last sample, in microseconds, to the Python stack it is in now: the
counts are CPU, not wall time (a thread blocked in Zenoh or asleep adds nothing, nor
does one waiting for a core). Threads that run no Python (Zenoh's own) count as
`native;<thread name>`. It takes the interpreter `1/interval` times a second: never
on in a measured benchmark.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from types import FrameType

ENV = "FW_SAMPLE_STACKS"
TICK = os.sysconf("SC_CLK_TCK")
INTERVAL = 0.01
"""Seconds between two samples (100 Hz: the robot's 1 kHz loop loses the interpreter
about 100 times a second for some tens of microseconds)."""


def _ticks(tid: int) -> int:
    """User + system clock ticks thread `tid` of this process has used (0 if gone)."""
    try:
        stat = Path(f"/proc/self/task/{tid}/stat").read_text()
    except OSError:
        return 0
    fields = stat[stat.rindex(")") + 2 :].split()
    return int(fields[11]) + int(fields[12])


def _thread_cpu(ident: int) -> float:
    """Seconds of CPU the Python thread `ident` has used (0.0 if it is gone)."""
    try:
        return time.clock_gettime(time.pthread_getcpuclockid(ident))
    except (OSError, OverflowError):
        return 0.0


def _stack(frame: FrameType | None) -> list[str]:
    """The frames of a stack, outermost first, as `function (file:line)`."""
    names: list[str] = []
    while frame is not None:
        code = frame.f_code
        names.append(f"{code.co_name} ({Path(code.co_filename).name}:{frame.f_lineno})")
        frame = frame.f_back
    return names[::-1]


class StackSampler:
    """Samples the running threads' Python stacks of this process on a thread of its
    own (`start` .. `stop`); `write` puts the counts in collapsed form."""

    def __init__(self, interval: float = INTERVAL):
        self.interval = interval
        self.counts: Counter[str] = Counter()
        """Microseconds of CPU per collapsed stack."""
        self._used: dict[object, float] = {}
        self.samples = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fw-sampler", daemon=True)

    def start(self) -> StackSampler:
        """Begin sampling."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop sampling (waits for the sampler's thread)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)

    def sample(self) -> None:
        """Add to each thread's current stack the CPU it used since the last sample
        (Python frames; a native thread's as `native;<thread name>`)."""
        frames = sys._current_frames()
        by_ident = {t.ident: t for t in threading.enumerate()}
        python_tids = {self._thread.native_id}
        seen: dict[object, float] = {}
        for ident, frame in frames.items():
            thread = by_ident.get(ident)
            if thread is None or thread is self._thread or thread.native_id is None:
                continue
            python_tids.add(thread.native_id)
            used = seen[ident] = _thread_cpu(ident)
            spent = used - self._used.get(ident, used)
            if spent > 0:
                stack = ";".join([thread.name, *_stack(frame)])
                self.counts[stack] += round(spent * 1e6)
        for entry in os.scandir("/proc/self/task"):
            tid = int(entry.name)
            if tid in python_tids:
                continue
            used = seen[tid] = _ticks(tid) / TICK
            spent = used - self._used.get(tid, used)
            if spent > 0:
                try:
                    name = Path(f"/proc/self/task/{tid}/comm").read_text().strip()
                except OSError:
                    continue
                self.counts[f"native;{name}"] += round(spent * 1e6)
        self._used = seen
        self.samples += 1

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self.sample()

    def write(self, path: Path) -> None:
        """Write the counts, most frequent first, in collapsed-stack form."""
        path.parent.mkdir(parents=True, exist_ok=True)
        lines = [f"{stack} {n}" for stack, n in self.counts.most_common()]
        path.write_text("\n".join(lines) + ("\n" if lines else ""))


def from_environment() -> StackSampler | None:
    """A started sampler if `FW_SAMPLE_STACKS` names a folder, else None."""
    return StackSampler().start() if os.environ.get(ENV) else None


def finish(sampler: StackSampler | None, process: str) -> None:
    """Stop `sampler` and write `<FW_SAMPLE_STACKS>/<process>.stacks` (no sampler: nothing)."""
    if sampler is None:
        return
    sampler.stop()
    folder = os.environ.get(ENV, "")
    if folder:
        sampler.write(Path(folder) / f"{process}.stacks")
