"""Baselines: one Zenoh hop between two processes of this host, on fw's own bus, and
what a 1 kHz stream between two processes costs in CPU.

A child process echoes every ping; half the round trip is one hop. Every latency of
`fw bench` is also reported as a multiple of this hop, because on a shared machine
ratios hold where absolute times drift. With `secure`, the same hop over mutual TLS
with a deployment keystore, as `fw deploy` runs it: the price of authentication.

The stream: this process publishes 200-byte samples at 1 kHz (a sleeping loop, as a
1 kHz component's), a child subscribes; the CPU both processes use (all threads,
user + system, from /proc) per sample, less what the same loop costs publishing
nothing. It says what each 1 kHz link between processes of a deployment costs,
whatever its components compute (docs/bench.md, cost).
"""

from __future__ import annotations

import contextlib
import dataclasses
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from framework.bus import Bus, BusConfig, free_port
from framework.keystore import CONTROL, create_keystore

PING, PONG = "bench/ping", "bench/pong"


ECHO = "echo"
SINK = "sink"


def echo(namespace: str, port: int, keys: str = "") -> None:
    """The child: answer every ping with the same bytes until stdin closes."""
    bus = Bus(BusConfig(namespace=namespace, hub_port=port, keys=keys), subject=ECHO)
    publisher = bus.publisher(PONG, cache=False)
    bus.subscribe(PING, lambda sample: publisher.put(sample.payload.to_bytes()), history=False)
    print("ready", flush=True)
    sys.stdin.read()
    bus.close()


def sink(namespace: str, port: int) -> None:
    """The child of `stream_cost`: take every sample of PING until stdin closes."""
    bus = Bus(BusConfig(namespace=namespace, hub_port=port))
    bus.subscribe(PING, lambda sample: sample.payload.to_bytes(), history=False)
    print("ready", flush=True)
    sys.stdin.read()
    bus.close()


def _paced(seconds: float, rate: float, put: Any) -> float:
    """Call `put` at `rate` Hz for `seconds` (None: only the loop); CPU s it took."""
    data, period = b"x" * 200, 1.0 / rate
    start = time.process_time()
    due = time.perf_counter()
    for _ in range(int(seconds * rate)):
        if put is not None:
            put(data)
        due += period
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    return time.process_time() - start


@contextlib.contextmanager
def _with_child(config: BusConfig, *args: str) -> Iterator[tuple[Bus, subprocess.Popen[str]]]:
    """This process's hub on `config` and a child (this module with `args`) joined to
    it and ready; both end on leaving (the child when its stdin closes)."""
    hub = Bus(config, hub=True, subject=CONTROL if config.keys else "")
    child = subprocess.Popen(
        [sys.executable, "-m", "fw_bench.baseline", *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None
        child.stdout.readline()  # ready
        hub.wait_for_peers(1, 5.0)
        yield hub, child
    finally:
        if child.stdin:
            child.stdin.close()
        child.wait(5)
        hub.close()


def stream_cost(seconds: float = 3.0, rate: float = 1000.0) -> dict[str, float]:
    """CPU (us) per sample of a `rate` Hz stream to another process, at the publisher
    and at the subscriber, on a plain bus."""
    from fw_bench.cost import cpu_seconds

    config = BusConfig(namespace=f"fw_bench_stream_{time.time_ns()}", hub_port=free_port())
    with _with_child(config, SINK, config.namespace, str(config.hub_port)) as (hub, child):
        publisher = hub.publisher(PING, cache=False)
        time.sleep(0.5)  # the route is up
        loop = _paced(seconds, rate, None)
        before = cpu_seconds(child.pid)
        time.sleep(seconds)
        child_idle = cpu_seconds(child.pid) - before
        before = cpu_seconds(child.pid)
        sending = _paced(seconds, rate, publisher.put)
        child_busy = cpu_seconds(child.pid) - before
    samples = seconds * rate
    return {
        "publisher_us": max(0.0, sending - loop) / samples * 1e6,
        "subscriber_us": max(0.0, child_busy - child_idle) / samples * 1e6,
    }


def zenoh_hop(count: int, secure: bool = False) -> list[float]:
    """`count` one-way hop latencies (s): half of each measured round trip."""
    with tempfile.TemporaryDirectory(prefix="fw-bench-keys-") as keys:
        return _hop(count, str(create_keystore(Path(keys) / "ks", [ECHO]).root) if secure else "")


def _hop(count: int, keys: str) -> list[float]:
    config = BusConfig(namespace=f"fw_bench_hop_{time.time_ns()}", hub_port=free_port())
    config = dataclasses.replace(config, keys=keys)
    with _with_child(config, config.namespace, str(config.hub_port), keys) as (hub, _):
        answered = threading.Event()
        hub.subscribe(PONG, lambda sample: answered.set(), history=False)
        publisher = hub.publisher(PING, cache=False)
        hops = []
        for k in range(count + 20):
            answered.clear()
            t0 = time.perf_counter()
            publisher.put(k.to_bytes(8, "little"))
            if not answered.wait(2.0):
                continue  # lost during start-up
            if k >= 20:  # warm-up rounds
                hops.append((time.perf_counter() - t0) / 2)
        return hops


if __name__ == "__main__":
    if sys.argv[1] == SINK:
        sink(sys.argv[2], int(sys.argv[3]))
    else:
        echo(sys.argv[1], int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "")


def python_speed(repetitions: int = 3, additions: int = 10**7) -> float:
    """This host's speed for plain Python right now: the CPU seconds (median of
    `repetitions`) one thread takes for `additions` integer additions. A shared VM's
    speed moves by 2-3x within a day (the same code measured 0.385 and 1.05 cores), so
    every run reports it beside its figures: compare costs only between runs whose
    speeds agree, or scaled by them."""
    import statistics

    taken = []
    for _ in range(repetitions):
        began, total = time.thread_time(), 0
        for i in range(additions):
            total += i
        taken.append(time.thread_time() - began)
    return statistics.median(taken)


def wake_round_trip(count: int = 20000) -> float:
    """This host's cost of waking another process right now: the wall-clock
    microseconds (mean over `count`) of a one-byte round trip between two processes
    over a socket pair: the deployment wakes its threads ~10,000 times a second. A
    baseline beside `python_speed` to tell runs apart; neither explains why the same
    code measured 0.385 and 1.05 cores braked on two days (docs/bench.md)."""
    import os
    import socket

    here, there = socket.socketpair()
    child = os.fork()
    if child == 0:  # pragma: no cover - the echoing child
        try:
            for _ in range(count):
                there.recv(1)
                there.send(b"x")
        finally:
            os._exit(0)
    began = time.perf_counter()
    for _ in range(count):
        here.send(b"x")
        here.recv(1)
    took = time.perf_counter() - began
    os.waitpid(child, 0)
    here.close()
    there.close()
    return took / count * 1e6
