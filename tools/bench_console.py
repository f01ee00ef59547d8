#!/usr/bin/env python3
"""Benchmark the operator console on the toy deployment (a benchmark, not a test).

* command round trip: POST /api/command -> the chart's answer (HTTP, in process);
* change to page: from the chart entering a state (the Coordinator's stamp) to the
  page showing it, in Debian's chromium (Playwright), when it is installed;
* the size of one state picture and of the first one (with the log).

    python tools/bench_console.py [--quick] [--out out/bench]
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchlib import bench_parser, percentiles, write_report

from framework.bus import BusConfig, free_port
from tests.conftest import REPO, private_topology
from tests.framework.console.conftest import served


def post(url: str, event: str) -> dict:
    request = urllib.request.Request(
        url + "api/command", json.dumps({"event": event, "origin": "bench"}).encode()
    )
    with urllib.request.urlopen(request, timeout=5) as reply:
        return json.loads(reply.read())


def leaf(url: str) -> list[str]:
    with urllib.request.urlopen(url + "api/state", timeout=5) as reply:
        state = json.loads(reply.read())
    return ((state.get("chart") or {}).get("data") or {}).get("active", [])


def settle(url: str, state: str) -> None:
    deadline = time.monotonic() + 10
    while leaf(url) != [state]:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the toy chart did not reach {state}")
        time.sleep(0.01)


def round_trips(url: str, n: int) -> list[float]:
    times = []
    for i in range(n):
        settle(url, "Use_T1" if i % 2 == 0 else "Use_T2")
        t0 = time.perf_counter()
        assert post(url, "e_SWAP")["accepted"]
        times.append(time.perf_counter() - t0)
    return times


def to_page(url: str, n: int) -> list[float] | None:
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
        page.goto(url)
        page.wait_for_function(
            '() => typeof lastState !== "undefined" && lastState && lastState.chart'
        )
        for i in range(n):
            target = "Use_T2" if i % 2 == 0 else "Use_T1"
            settle(url, "Use_T1" if i % 2 == 0 else "Use_T2")
            page.wait_for_function(
                "(s) => lastState.chart.data.active.includes(s)",
                arg="Use_T1" if i % 2 == 0 else "Use_T2",
            )
            sent = time.time()
            post(url, "e_SWAP")
            page.wait_for_function("(s) => lastState.chart.data.active.includes(s)", arg=target)
            out.append(time.time() - sent)
        browser.close()
    return out


def main() -> int:
    parser = bench_parser(__doc__)
    args = parser.parse_args()
    n = 20 if args.quick else 200
    config = BusConfig(namespace=f"fw_bench_console_{time.time_ns()}", hub_port=free_port())
    topology = private_topology(REPO / "tests" / "data" / "toy" / "toy.yaml", config)
    with tempfile.TemporaryDirectory() as tmp, served(topology, Path(tmp)) as (server, _):
        settle(server.url, "Use_T1")
        trips = percentiles(round_trips(server.url, n))
        page = to_page(server.url, n // 4)
        with urllib.request.urlopen(server.url + "api/state", timeout=5) as reply:
            first = len(reply.read())
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
