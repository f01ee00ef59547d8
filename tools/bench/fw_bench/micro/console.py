#!/usr/bin/env python3
"""Benchmark the operator console on the toy deployment (a benchmark, not a test).

* command round trip: POST /api/command -> the chart's answer (HTTP, in process);
* change to page: from the chart entering a state (the Coordinator's stamp) to the
  page showing it, in Debian's chromium (Playwright), when it is installed;
* the size of one state picture and of the first one (with the log).

    python -m fw_bench.micro console [--quick] [--out out/bench]
"""

from __future__ import annotations

import contextlib
import json
import shutil
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

from framework.bus import BusConfig, free_port
from framework.console.model import ConsoleModel
from framework.console.server import ConsoleServer
from framework.deployer import Deployment
from fw_bench.files import toy_topology
from fw_bench.micro.lib import bench_parser, percentiles, write_report


@contextlib.contextmanager
def served(topology, workdir: Path) -> Iterator[ConsoleServer]:
    """Deploy `topology` and serve its console on 127.0.0.1 (any free port)."""
    deployment = Deployment(topology, workdir)
    deployment.start()
    model = ConsoleModel(deployment.hub, topology, deployment.coordinator.chart).start()
    server = ConsoleServer(model, "127.0.0.1", 0)
    server.start()
    try:
        yield server
    finally:
        server.stop()
        model.stop()
        deployment.stop()


def fetch(server: ConsoleServer, path: str, body: bytes | None = None) -> bytes:
    """One authenticated request to the console (the run's token as a bearer header)."""
    request = urllib.request.Request(
        server.base + path,
        body,
        headers={"Authorization": f"Bearer {server.token}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(request, timeout=5) as reply:
        return reply.read()


def post(server: ConsoleServer, event: str) -> dict:
    body = json.dumps({"event": event, "origin": "bench"}).encode()
    return json.loads(fetch(server, "api/command", body))


def leaf(server: ConsoleServer) -> list[str]:
    state = json.loads(fetch(server, "api/state"))
    return ((state.get("chart") or {}).get("data") or {}).get("active", [])


def settle(server: ConsoleServer, state: str) -> None:
    deadline = time.monotonic() + 10
    while leaf(server) != [state]:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the toy chart did not reach {state}")
        time.sleep(0.01)


def round_trips(server: ConsoleServer, n: int) -> list[float]:
    times = []
    for i in range(n):
        settle(server, "Use_T1" if i % 2 == 0 else "Use_T2")
        t0 = time.perf_counter()
        assert post(server, "e_SWAP")["accepted"]
        times.append(time.perf_counter() - t0)
    return times


def to_page(server: ConsoleServer, n: int) -> list[float] | None:
    chromium = shutil.which("chromium")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return None
    if chromium is None:
        return None
    out = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        page = browser.new_page()
        page.goto(server.url)
        page.wait_for_function(
            '() => typeof lastState !== "undefined" && lastState && lastState.chart'
        )
        for i in range(n):
            target = "Use_T2" if i % 2 == 0 else "Use_T1"
            settle(server, "Use_T1" if i % 2 == 0 else "Use_T2")
            page.wait_for_function(
                "(s) => lastState.chart.data.active.includes(s)",
                arg="Use_T1" if i % 2 == 0 else "Use_T2",
            )
            sent = time.time()
            post(server, "e_SWAP")
            page.wait_for_function("(s) => lastState.chart.data.active.includes(s)", arg=target)
            out.append(time.time() - sent)
        browser.close()
    return out


def main() -> int:
    parser = bench_parser(__doc__)
    args = parser.parse_args()
    n = 20 if args.quick else 200
    config = BusConfig(namespace=f"fw_bench_console_{time.time_ns()}", hub_port=free_port())
    topology = toy_topology(config.namespace, config.hub_port)
    with tempfile.TemporaryDirectory() as tmp, served(topology, Path(tmp)) as server:
        settle(server, "Use_T1")
        trips = percentiles(round_trips(server, n))
        page = to_page(server, n // 4)
        first = len(fetch(server, "api/state"))
    page_stats = percentiles(page) if page else None
    lines = [
        "# Console benchmark (toy deployment)",
        "",
        "| | n | p50 ms | p99 ms |",
        "|---|---:|---:|---:|",
        f"| command round trip (POST -> the chart's answer) | {trips['n']} | "
        f"{trips['p50_us'] / 1e3:.2f} | {trips['p99_us'] / 1e3:.2f} |",
    ]
    if page_stats:
        lines.append(
            f"| command sent -> the page shows the new state (chromium) | {page_stats['n']} | "
            f"{page_stats['p50_us'] / 1e3:.1f} | {page_stats['p99_us'] / 1e3:.1f} |"
        )
    else:
        lines.append("| command -> page | | n/a (no chromium or playwright) | |")
    lines += ["", f"First picture with the log: {first / 1024:.1f} KiB."]
    targets = {"command round trip p99 < 50 ms": trips["p99_us"] < 50_000}
    if page_stats:
        targets["command -> page p50 < 100 ms"] = page_stats["p50_us"] < 100_000
    write_report(args.out, "console", lines, targets, {"round_trip": trips, "to_page": page_stats})
    return 0


if __name__ == "__main__":
    sys.exit(main())
