#!/usr/bin/env python3
"""Benchmark the component runtime over Zenoh (a benchmark, not a test).

In one run, on a private loopback deployment:
  * raw Zenoh put -> callback latency, in one process and between two processes
    (the baseline every other latency is compared with);
  * port hop latency (OutputPort.write -> InputPort delivery), in-process and
    inter-process, as a multiple of the raw figure (target <= 2x);
  * rewire time: connect() called -> first sample of the new key delivered, with
    100 Hz publishers (target p99 <= 2 ms);
  * remote operation round trip (RemoteComponent.call);
  * liveliness: SIGKILL of a container -> token loss seen by another process.

Prints median/p99 and writes out/bench/runtime.md and runtime.json.

    python -m fw_bench.micro runtime [--quick] [--out out/bench]
"""

from __future__ import annotations

import json
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from typing import Any

from framework import keys
from framework.bus import Bus, BusConfig, free_port
from framework.container_main import spawn_container
from framework.messages import Scalar
from framework.ports import InputPort, OutputPort
from framework.remote import RemoteComponent
from fw_bench.micro.lib import bench_parser, percentiles, write_report

RAW_PUBLISHER = """
import json, time
from framework.bus import Bus, BusConfig
bus = Bus(BusConfig.from_dict(json.loads({bus!r})))
pub = bus.publisher("raw/ping", cache=False)
time.sleep(1.0)
for i in range({count}):
    pub.put(repr(time.perf_counter()).encode())
    time.sleep({period})
time.sleep(0.5)
bus.close()
"""


def wait(predicate: Any, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.002)
    return bool(predicate())


def raw_in_process(bus: Bus, count: int) -> list[float]:
    got: list[float] = []
    done = threading.Event()

    def on_sample(sample: Any) -> None:
        got.append(time.perf_counter() - float(bytes(sample.payload.to_bytes())))
        done.set()

    sub = bus.session.declare_subscriber("raw/local", on_sample)
    pub = bus.session.declare_publisher("raw/local")
    time.sleep(0.2)
    for _ in range(count):
        done.clear()
        pub.put(repr(time.perf_counter()).encode())
        done.wait(1.0)
    sub.undeclare()
    pub.undeclare()
    return got


def raw_inter_process(bus: Bus, config: BusConfig, count: int, period: float) -> list[float]:
    got: list[float] = []
    sub = bus.session.declare_subscriber(
        "raw/ping", lambda s: got.append(time.perf_counter() - float(bytes(s.payload.to_bytes())))
    )
    code = RAW_PUBLISHER.format(
        bus=json.dumps(config.to_dict()),
        count=count,
        period=period,
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    sub.undeclare()
    return got


def port_in_process(bus: Bus, count: int) -> list[float]:
    out = OutputPort("out", Scalar)
    inp: InputPort[Scalar] = InputPort("inp", Scalar)
    out.bus = inp.bus = bus
    got: list[float] = []
    done = threading.Event()

    def on_data(port: InputPort[Scalar]) -> None:
        _, sample = port.read()
        got.append(time.perf_counter() - sample.stamp)
        done.set()

    inp.on_data = on_data
    out.connect("port/local")
    inp.connect("port/local")
    time.sleep(0.2)
    for i in range(count):
        done.clear()
        out.write(Scalar(time.perf_counter(), float(i)))
        done.wait(1.0)
    inp.disconnect()
    out.disconnect()
    return got[1:]  # the first is the cached sample replayed on connect


def start_pingers(config: BusConfig, names: list[str], rate: float) -> subprocess.Popen[bytes]:
    components = [
        {
            "name": n,
            "class": "fw_bench.components:Pinger",
            "activity": {"periodic": rate},
            "configure": True,
            "start": True,
        }
        for n in names
    ]
    return spawn_container(
        {"name": "bench_pingers", "bus": config.to_dict(), "components": components},
        stdout=subprocess.DEVNULL,
    )


def port_inter_process(bus: Bus, seconds: float) -> list[float]:
    inp: InputPort[Scalar] = InputPort("inp", Scalar)
    inp.bus = bus
    got: list[float] = []

    def on_data(port: InputPort[Scalar]) -> None:
        _, sample = port.read()
        got.append(time.perf_counter() - sample.stamp)

    inp.on_data = on_data
    inp.connect("ping_a/out")
    time.sleep(seconds)
    inp.disconnect()
    return got[5:]


def rewire(bus: Bus, count: int, prepared: bool = False) -> list[float]:
    """Alternate the port between the two pingers' keys: connect() -> first sample."""
    inp: InputPort[Scalar] = InputPort("inp", Scalar)
    inp.bus = bus
    first = threading.Event()
    inp.on_data = lambda port: first.set()
    if prepared:
        inp.prepare("ping_a/out")
        inp.prepare("ping_b/out")
        wait(lambda: inp.standby_ready("ping_a/out") and inp.standby_ready("ping_b/out"), 5)
    times = []
    for i in range(count):
        key = "ping_a/out" if i % 2 else "ping_b/out"
        first.clear()
        t0 = time.perf_counter()
        inp.connect(key)
        if first.wait(1.0):
            times.append(time.perf_counter() - t0)
        time.sleep(0.02)
    inp.close()
    return times


def remote_calls(bus: Bus, count: int) -> list[float]:
    remote = RemoteComponent(bus, "ping_a")
    remote.describe()
    times = []
    for _ in range(count):
        t0 = time.perf_counter()
        remote.request("state")
        times.append(time.perf_counter() - t0)
    return times


def liveliness(bus: Bus, config: BusConfig, count: int) -> list[float]:
    times = []
    for i in range(count):
        name = f"victim{i}"
        lost = threading.Event()
        seen = threading.Event()

        def on_token(
            key: str,
            alive: bool,
            name: str = name,
            seen: threading.Event = seen,
            lost: threading.Event = lost,
        ) -> None:
            if key.endswith("/" + name):
                (seen if alive else lost).set()

        watcher = bus.watch(keys.ALL_ALIVE, on_token)
        proc = spawn_container(
            {
                "name": f"v{i}",
                "bus": config.to_dict(),
                "components": [{"name": name, "class": "components.demo:Counter"}],
            },
            stdout=subprocess.DEVNULL,
        )
        if not seen.wait(20):
            proc.kill()
            watcher.undeclare()
            continue
        t0 = time.perf_counter()
        os.kill(proc.pid, signal.SIGKILL)
        if lost.wait(10):
            times.append(time.perf_counter() - t0)
        proc.wait(10)
        watcher.undeclare()
    return times


def main() -> int:
    parser = bench_parser(__doc__)
    args = parser.parse_args()
    n = 300 if args.quick else 2000
    config = BusConfig(namespace=f"bench_{os.getpid()}", hub_port=free_port())
    bus = Bus(config, hub=True)
    results: dict[str, dict[str, float]] = {}
    try:
        print("raw zenoh ...", file=sys.stderr)
        results["raw_in_process"] = percentiles(raw_in_process(bus, n))
        # same 100 Hz rate as the port test: at lower rates idle wake-ups dominate latency
        results["raw_inter_process_100hz"] = percentiles(
            raw_inter_process(bus, config, n // 4 if args.quick else n // 2, 0.01)
        )
        print("ports ...", file=sys.stderr)
        results["port_in_process"] = percentiles(port_in_process(bus, n))
        pingers = start_pingers(config, ["ping_a", "ping_b"], 100.0)
        try:
            wait(lambda: len(bus.alive(keys.ALL_ALIVE, 0.5)) >= 2, 30)
            results["port_inter_process_100hz"] = percentiles(
                port_inter_process(bus, 3.0 if args.quick else 15.0)
            )
            print("rewire ...", file=sys.stderr)
            results["rewire_to_first_sample"] = percentiles(rewire(bus, 40 if args.quick else 200))
            results["rewire_prepared_to_first_sample"] = percentiles(
                rewire(bus, 40 if args.quick else 200, prepared=True)
            )
            print("remote calls ...", file=sys.stderr)
            results["remote_request_round_trip"] = percentiles(remote_calls(bus, n // 2))
        finally:
            pingers.send_signal(signal.SIGTERM)
            pingers.wait(20)
        print("liveliness ...", file=sys.stderr)
        results["liveliness_after_sigkill"] = percentiles(
            liveliness(bus, config, 3 if args.quick else 10)
        )
    finally:
        bus.close()

    raw_local = results["raw_in_process"]["p50_us"]
    raw_remote = results["raw_inter_process_100hz"]["p50_us"]
    ratio_local = results["port_in_process"]["p50_us"] / raw_local
    ratio_remote = results["port_inter_process_100hz"]["p50_us"] / raw_remote
    targets = {
        "in-process port hop <= 2x raw Zenoh (p50)": ratio_local <= 2.0,
        "inter-process port hop <= 2x raw Zenoh (p50)": ratio_remote <= 2.0,
        "rewire to first sample p99 <= 2 ms (cold)": results["rewire_to_first_sample"]["p99_us"]
        <= 2000,
        "rewire to first sample p99 <= 2 ms (prepared)": results["rewire_prepared_to_first_sample"][
            "p99_us"
        ]
        <= 2000,
    }
    lines = [
        f"# Runtime benchmark ({time.strftime('%Y-%m-%d %H:%M')}, Python "
        f"{platform.python_version()}, {os.cpu_count()} cores)",
        "",
        "| measure | n | p50 µs | p99 µs | p50 / raw |",
        "|---|---:|---:|---:|---:|",
    ]
    base = {"port_in_process": raw_local, "port_inter_process_100hz": raw_remote}
    for name, row in results.items():
        ratio = f"{row['p50_us'] / base[name]:.2f}" if name in base else ""
        lines.append(
            f"| {name} | {row['n']} | {row['p50_us']:.1f} | {row['p99_us']:.1f} | {ratio} |"
        )
    write_report(args.out, "runtime", lines, targets, {"results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
