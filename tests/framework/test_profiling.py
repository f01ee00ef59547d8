"""Spec: `FW_PROFILE`'s profiles count each thread's CPU per function, so a thread
that waits counts almost nothing, and the report names where the CPU went."""

from __future__ import annotations

import threading
import time

from framework.profiling import ThreadProfiles


def _busy_spinning_here(cpu: float) -> None:
    began = time.thread_time()
    while time.thread_time() - began < cpu:
        sum(range(1000))


def _asleep_here(stop: threading.Event) -> None:
    stop.wait()


def _cpu_of(stats, name: str) -> float:
    return sum(v[3] for k, v in stats.stats.items() if k[2] == name)  # with its callees


def test_a_spinning_thread_takes_the_cpu_and_a_waiting_one_none(tmp_path):
    profiles = ThreadProfiles().start()
    stop = threading.Event()
    spinner = threading.Thread(target=_busy_spinning_here, args=(0.1,))
    sleeper = threading.Thread(target=_asleep_here, args=(stop,))
    for thread in (spinner, sleeper):
        thread.start()
    spinner.join()  # 0.1 s of its own CPU, however busy the host
    stop.set()
    sleeper.join()
    profiles.stop()
    stats = profiles.stats()  # once, at the end, as a process's `finish` does
    spun, slept = _cpu_of(stats, "_busy_spinning_here"), _cpu_of(stats, "_asleep_here")
    assert spun >= 0.05, f"the spinning thread's CPU was counted {spun:.3f} s"
    assert slept < spun / 10, f"a waiting thread was counted {slept:.3f} s"
    profiles.write(tmp_path, "p")
    report = (tmp_path / "p.txt").read_text()
    assert "_busy_spinning_here" in report and (tmp_path / "p.pstats").stat().st_size > 0
