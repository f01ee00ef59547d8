"""Baseline: one Zenoh hop between two processes of this host, on fw's own bus.

A child process echoes every ping; half the round trip is one hop. Every latency of
`fw bench` is also reported as a multiple of this hop, because on a shared machine
ratios hold where absolute times drift. With `secure`, the same hop over mutual TLS
with a deployment keystore, as `fw deploy` runs it: the price of authentication.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from framework.bus import Bus, BusConfig, free_port
from framework.keystore import CONTROL, create_keystore

PING, PONG = "bench/ping", "bench/pong"


ECHO = "echo"


def echo(namespace: str, port: int, keys: str = "") -> None:
    """The child: answer every ping with the same bytes until stdin closes."""
    bus = Bus(BusConfig(namespace=namespace, hub_port=port, keys=keys), subject=ECHO)
    publisher = bus.publisher(PONG, cache=False)
    bus.subscribe(PING, lambda sample: publisher.put(sample.payload.to_bytes()), history=False)
    print("ready", flush=True)
    sys.stdin.read()
    bus.close()


def zenoh_hop(count: int, secure: bool = False) -> list[float]:
    """`count` one-way hop latencies (s): half of each measured round trip."""
    with tempfile.TemporaryDirectory(prefix="fw-bench-keys-") as keys:
        return _hop(count, str(create_keystore(Path(keys) / "ks", [ECHO]).root) if secure else "")


def _hop(count: int, keys: str) -> list[float]:
    config = BusConfig(namespace=f"fw_bench_hop_{time.time_ns()}", hub_port=free_port())
    config = dataclasses.replace(config, keys=keys)
    hub = Bus(config, hub=True, subject=CONTROL)
    argv = [config.namespace, str(config.hub_port), keys]
    child = subprocess.Popen(
        [sys.executable, "-m", "components.bench.baseline", *argv],
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
    echo(sys.argv[1], int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "")
