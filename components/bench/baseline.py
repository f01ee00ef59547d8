"""Baseline: one Zenoh hop between two processes of this host, on fw's own bus.

A child process echoes every ping; half the round trip is one hop. Every latency of
`fw bench` is also reported as a multiple of this hop, because on a shared machine
ratios hold where absolute times drift.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time

from framework.bus import Bus, BusConfig, free_port

PING, PONG = "bench/ping", "bench/pong"


def echo(namespace: str, port: int) -> None:
    """The child: answer every ping with the same bytes until stdin closes."""
    bus = Bus(BusConfig(namespace=namespace, hub_port=port))
    publisher = bus.publisher(PONG, cache=False)
    bus.subscribe(PING, lambda sample: publisher.put(sample.payload.to_bytes()), history=False)
    print("ready", flush=True)
    sys.stdin.read()
    bus.close()


def zenoh_hop(count: int) -> list[float]:
    """`count` one-way hop latencies (s): half of each measured round trip."""
    config = BusConfig(namespace=f"fw_bench_hop_{time.time_ns()}", hub_port=free_port())
    hub = Bus(config, hub=True)
    child = subprocess.Popen(
        [sys.executable, "-m", "components.bench.baseline", config.namespace, str(config.hub_port)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None
        child.stdout.readline()  # ready
        hub.wait_for_peers(1, 5.0)
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
    finally:
        if child.stdin:
            child.stdin.close()
        child.wait(5)
        hub.close()


if __name__ == "__main__":
    echo(sys.argv[1], int(sys.argv[2]))
