"""Spec: `FW_PROFILE`'s profiles count each thread's CPU per function, so a thread
that waits counts almost nothing, and the report names where the CPU went."""

from __future__ import annotations

import threading

from framework.profiling import ThreadProfiles


def _busy_spinning_here(stop: threading.Event) -> None:
    while not stop.is_set():
        sum(range(1000))


def _asleep_here(stop: threading.Event) -> None:
    stop.wait()


def _cpu_of(stats, name: str) -> float:
    return sum(v[2] for k, v in stats.stats.items() if k[2] == name)  # tottime


def test_a_spinning_thread_takes_the_cpu_and_a_waiting_one_none(tmp_path):
    profiles = ThreadProfiles().start()
    stop = threading.Event()
    threads = [
        threading.Thread(target=_busy_spinning_here, args=(stop,)),
        threading.Thread(target=_asleep_here, args=(stop,)),
    ]
    for thread in threads:
        thread.start()
    try:
        while (profiles.stats() is None) or _cpu_of(profiles.stats(), "_busy_spinning_here") < 0.05:
            stop.wait(0.01)
    finally:
        stop.set()
        for thread in threads:
            thread.join()
        profiles.stop()
    stats = profiles.stats()
    spun, slept = _cpu_of(stats, "_busy_spinning_here"), _cpu_of(stats, "_asleep_here")
    assert slept < spun / 10, f"a waiting thread was counted {slept:.3f} s"
    profiles.write(tmp_path, "p")
    report = (tmp_path / "p.txt").read_text()
    assert "_busy_spinning_here" in report and (tmp_path / "p.pstats").stat().st_size > 0
