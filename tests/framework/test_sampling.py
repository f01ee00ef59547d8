"""Spec: the stack sampler adds each thread's CPU to the Python stack it is in, so a
waiting thread counts nothing, and writes the collapsed form flame-graph tools read."""

from __future__ import annotations

import threading
import time

from framework.sampling import StackSampler


def _busy_spinning_here(stop: threading.Event) -> None:
    while not stop.is_set():
        sum(range(1000))


def _asleep_here(stop: threading.Event) -> None:
    stop.wait()


def test_a_running_thread_is_counted_and_a_waiting_one_is_not(tmp_path):
    stop = threading.Event()
    threads = [
        threading.Thread(target=_busy_spinning_here, args=(stop,), name="spinner"),
        threading.Thread(target=_asleep_here, args=(stop,), name="sleeper"),
    ]
    for thread in threads:
        thread.start()
    sampler = StackSampler()
    began = time.process_time()
    try:
        while sum(n for s, n in sampler.counts.items() if s.startswith("spinner;")) < 20_000:
            sampler.sample()
            time.sleep(0.001)
    finally:
        stop.set()
        for thread in threads:
            thread.join()
    stacks = list(sampler.counts)
    assert any("_busy_spinning_here (test_sampling.py:" in s for s in stacks)
    assert not any(s.startswith("sleeper;") for s in stacks), "a waiting thread was counted"
    used = time.process_time() - began  # the whole process's CPU meanwhile
    assert sum(sampler.counts.values()) <= used * 1e6, "more CPU counted than was used"
    out = tmp_path / "p.stacks"
    sampler.write(out)
    first = out.read_text().splitlines()[0]
    stack, count = first.rsplit(" ", 1)
    assert int(count) == max(sampler.counts.values()) and ";" in stack
