"""Where a process spends its CPU: a sampling profiler for one container process.

Set `FW_SAMPLE_STACKS=<folder>` in the environment of `fw deploy` (or of one
container) and each container process writes `<folder>/<process>.stacks` when it
stops: one line per distinct Python stack, `thread;outer;...;inner count`, the
"collapsed" format flame-graph tools read (flamegraph.pl, speedscope, inferno).

Every `interval` s the sampler reads each thread's scheduler state from
/proc/self/task/<tid>/stat and records the Python stack of those running on a core
(state R) only, so the counts follow CPU, not wall time: a thread blocked in Zenoh or
in a sleep is not counted. What it cannot see: work in native threads that run no
Python (Zenoh's own), counted as `native` when such a thread is running. It takes the
interpreter `1/interval` times a second: never on in a measured benchmark.
"""

from __future__ import annotations

import os
import sys
import threading
from collections import Counter
from pathlib import Path
from types import FrameType

ENV = "FW_SAMPLE_STACKS"
INTERVAL = 0.01
"""Seconds between two samples (100 Hz: the robot's 1 kHz loop loses the interpreter
about 100 times a second for some tens of microseconds)."""


def _state(tid: int) -> str:
    """The scheduler state letter of thread `tid` of this process ('' if it is gone)."""
    try:
        stat = Path(f"/proc/self/task/{tid}/stat").read_text()
    except OSError:
        return ""
    return stat[stat.rindex(")") + 2 :][:1]


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
        """Record one sample of every thread running on a core now (Python frames) and
        of native threads running (as `native;<thread name>`)."""
        frames = sys._current_frames()
        by_ident = {t.ident: t for t in threading.enumerate()}
        python_tids = set()
        for ident, frame in frames.items():
            thread = by_ident.get(ident)
            if thread is None or thread is self._thread or thread.native_id is None:
                continue
            python_tids.add(thread.native_id)
            if _state(thread.native_id) == "R":
                self.counts[";".join([thread.name, *_stack(frame)])] += 1
        for entry in os.scandir("/proc/self/task"):
            tid = int(entry.name)
            if tid in python_tids or tid == self._thread.native_id:
                continue
            if _state(tid) == "R":
                try:
                    name = Path(f"/proc/self/task/{tid}/comm").read_text().strip()
                except OSError:
                    continue
                self.counts[f"native;{name}"] += 1
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
