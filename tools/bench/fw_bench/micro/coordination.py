#!/usr/bin/env python3
"""Benchmark the Coordinator-Configurator loop on a real multi-process deployment.

Deploys the toy topology (trackers and supervisor in their own processes) and
swaps trackers N times, measuring inside the Coordinator's chart:
  * event -> transition -> tag: e_SWAP dequeued -> configuration request sent;
  * tag -> ack: request sent -> the Configurator's ack processed by the chart
    (tracker swap: stop the supervisor, rewire its input to the other tracker,
    start it again; targets p50 <= 1 ms, p99 <= 3 ms);
and, as the baseline of the same run, one remote request round trip.

    python -m fw_bench.micro coordination [--swaps 200] [--quick] [--out out/bench]
"""

from __future__ import annotations

import os
import platform
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from framework.bus import free_port
from framework.deployer import Deployment
from framework.remote import RemoteComponent
from framework.statechart.events import Event, Listener, Output
from fw_bench.files import toy_topology
from fw_bench.micro.lib import bench_parser, percentiles, write_report


class Timing(Listener):
    """Stamps the chart's steps on the Coordinator's thread."""

    def __init__(self) -> None:
        self.event_at: float | None = None
        self.request_at: float | None = None
        self.event_to_tag: list[float] = []
        self.tag_to_ack: list[float] = []
        self.settled = threading.Event()

    def on_event(self, event: Event) -> None:
        now = time.perf_counter()
        if event.name == "e_SWAP":
            self.event_at = now
        elif event.name == "config.done" and self.request_at is not None:
            self.tag_to_ack.append(now - self.request_at)
            self.request_at = None
            self.settled.set()

    def on_output(self, output: Output) -> None:
        if output.kind == "configure" and self.event_at is not None:
            self.request_at = time.perf_counter()
            self.event_to_tag.append(self.request_at - self.event_at)
            self.event_at = None


def main() -> int:
    parser = bench_parser(__doc__, quick="30 swaps")
    parser.add_argument("--swaps", type=int, default=200)
    args = parser.parse_args()
    swaps = 30 if args.quick else args.swaps
    topology = toy_topology(f"bench_coord_{os.getpid()}", free_port())
    timing = Timing()
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as workdir:
        deployment = Deployment(topology, Path(workdir), listeners=[timing])
        deployment.start()
        try:
            coordinator = deployment.coordinator
            assert coordinator is not None
            deadline = time.monotonic() + 20
            while "Use_T1" not in coordinator.active()["active"] or coordinator.active()["pending"]:
                if time.monotonic() > deadline:
                    raise SystemExit("the toy deployment did not reach Use_T1")
                time.sleep(0.01)
            for _ in range(swaps):
                timing.settled.clear()
                deployment.send("e_SWAP")
                if not timing.settled.wait(5):
                    raise SystemExit("a swap was not acknowledged within 5 s")
                time.sleep(0.01)
            remote = RemoteComponent(deployment.hub, "supervisor")
            round_trips = []
            for _ in range(swaps):
                t0 = time.perf_counter()
                remote.request("state")
                round_trips.append(time.perf_counter() - t0)
            results["event_to_tag"] = percentiles(timing.event_to_tag)
            results["tag_to_ack_tracker_swap"] = percentiles(timing.tag_to_ack)
            results["baseline_remote_request"] = percentiles(round_trips)
            failures = [o for o in deployment.configurator.history if not o.ok]
        finally:
            deployment.stop()
    swap = results["tag_to_ack_tracker_swap"]
    targets = {
        "tracker swap tag -> ack p50 <= 1 ms": swap["p50_us"] <= 1000,
        "tracker swap tag -> ack p99 <= 3 ms": swap["p99_us"] <= 3000,
    }
    lines = [
        f"# Coordination benchmark ({time.strftime('%Y-%m-%d %H:%M')}, Python "
        f"{platform.python_version()}, {os.cpu_count()} cores)",
        "",
        f"{swaps} tracker swaps on the toy topology (3 processes); failures: {len(failures)}",
        "",
        "| measure | n | p50 µs | p99 µs |",
        "|---|---:|---:|---:|",
    ]
    lines += [
        f"| {name} | {r['n']} | {r['p50_us']:.1f} | {r['p99_us']:.1f} |"
        for name, r in results.items()
    ]
    write_report(args.out, "coordination", lines, targets, {"results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
