"""Where a process spends its CPU: a per-thread profile of one container process.

Set `FW_PROFILE=<folder>` in the environment of `fw deploy` (or of one container) and
each container process writes, when it stops, `<folder>/<process>.pstats` (Python's
`pstats` format: `python -m pstats`, snakeviz) and `<folder>/<process>.txt` (the
functions that took most CPU, and each thread's total).

Every thread the process starts after the profile begins (`threading.Thread`: the
activities, Zenoh's handler threads) is profiled by `cProfile` on its own CPU clock
(`time.thread_time`), so a thread's time waiting for the interpreter, a core or a
sample counts nothing, and the per-function figures add up to that thread's CPU.
What it cannot see: Python run on Zenoh's own threads (a plain subscriber's callback)
and the threads' native work outside any Python call, which the per-thread totals
from /proc still include. Profiling slows Python calls about twofold: never on in a
measured benchmark.
"""

from __future__ import annotations

import cProfile
import io
import os
import pstats
import threading
import time
from pathlib import Path

ENV = "FW_PROFILE"
TICK = os.sysconf("SC_CLK_TCK")


def _thread_seconds() -> dict[str, float]:
    """CPU seconds per thread name of this process, from /proc (native threads too)."""
    out: dict[str, float] = {}
    for entry in os.scandir("/proc/self/task"):
        try:
            stat = Path(entry.path, "stat").read_text()
            name = Path(entry.path, "comm").read_text().strip()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / TICK
    return out


class ThreadProfiles:
    """A `cProfile.Profile` on each thread's CPU clock for every thread started after
    `start`; `stop` ends them and `write` merges them into one report."""

    def __init__(self) -> None:
        self.profiles: list[cProfile.Profile] = []
        self._lock = threading.Lock()
        self._began = 0.0

    def start(self) -> ThreadProfiles:
        """Profile every thread started from now on (threading.setprofile's hook runs
        first in each new thread: it starts that thread's own profile)."""
        self._began = time.process_time()
        threading.setprofile(self._enter)
        return self

    def _enter(self, *_: object) -> None:
        profile = cProfile.Profile(time.thread_time)
        with self._lock:
            self.profiles.append(profile)
        profile.enable()  # replaces this hook for the rest of the thread

    def stop(self) -> None:
        """No new thread is profiled; the running ones' profiles stop being added to
        (a profile stays enabled in its thread until that thread ends)."""
        threading.setprofile(None)  # type: ignore[arg-type]

    def stats(self) -> pstats.Stats | None:
        """Every thread's profile merged (None if no thread started)."""
        with self._lock:
            profiles = list(self.profiles)
        merged: pstats.Stats | None = None
        for profile in profiles:
            profile.create_stats()
            if not profile.stats:  # type: ignore[attr-defined]
                continue
            if merged is None:
                merged = pstats.Stats(profile)
            else:
                merged.add(profile)
        return merged

    def write(self, folder: Path, process: str) -> None:
        """Write `<process>.pstats` and `<process>.txt` into `folder`."""
        folder.mkdir(parents=True, exist_ok=True)
        text = io.StringIO()
        used = time.process_time() - self._began
        text.write(f"{process}: {used:.2f} s of CPU since the profile began\n")
        text.write("CPU per thread since the process began (s, /proc):\n")
        for name, seconds in sorted(_thread_seconds().items(), key=lambda kv: -kv[1]):
            text.write(f"  {seconds:8.2f}  {name}\n")
        merged = self.stats()
        if merged is not None:
            merged.dump_stats(str(folder / f"{process}.pstats"))
            merged.stream = text  # type: ignore[attr-defined]
            merged.sort_stats("tottime").print_stats(40)
            merged.sort_stats("cumulative").print_stats(40)
        (folder / f"{process}.txt").write_text(text.getvalue())


def from_environment() -> ThreadProfiles | None:
    """Started profiles if `FW_PROFILE` names a folder, else None."""
    return ThreadProfiles().start() if os.environ.get(ENV) else None


def finish(profiles: ThreadProfiles | None, process: str) -> None:
    """Stop `profiles` and write them into `FW_PROFILE`'s folder (None: nothing)."""
    if profiles is None:
        return
    profiles.stop()
    folder = os.environ.get(ENV, "")
    if folder:
        profiles.write(Path(folder), process)
