#!/usr/bin/env python3
"""The operator console under hostile load, on the SEEG deployment (a benchmark).

Starts `fw deploy topologies/seeg.yaml`, then measures twice for --window s each:
idle, and with --streams live views (authenticated, as many as asked; the console
serves at most 16 and refuses the rest) plus --slow slowloris connections (a header
byte every 2 s, never finishing). Each time: GET /api/state latency (median, p99,
max, failures) for the operator polling every 50 ms, and the robot loop's real-time
factor (the arm controller's time against the wall clock, from `robot.report`).

    python -m fw_bench.micro console_load [--streams 200] [--slow 50] [--window 15]
"""

from __future__ import annotations

import contextlib
import json
import re
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.request
from typing import Any

from framework.bus import free_port
from fw_bench.files import seeg_home
from fw_bench.micro.lib import bench_parser, percentiles, write_report


class Console:
    """The console of a running deployment, as the operator's client sees it."""

    def __init__(self, port: int, token: str):
        self.port, self.token = port, token
        self.base = f"http://127.0.0.1:{port}"

    def state(self) -> dict[str, Any]:
        request = urllib.request.Request(
            self.base + "/api/state", headers={"Authorization": f"Bearer {self.token}"}
        )
        with urllib.request.urlopen(request, timeout=5) as reply:
            return json.loads(reply.read())

    def robot_time(self) -> float | None:
        """The arm controller's time (s), retried while the console refuses (503)."""
        deadline = time.monotonic() + 10
        while True:
            try:
                data = (self.state().get("robot") or {}).get("data") or {}
                return data.get("time")
            except (urllib.error.URLError, OSError):
                if time.monotonic() > deadline:
                    return None
                time.sleep(0.05)


def deploy(port: int) -> tuple[subprocess.Popen[str], Console]:
    proc = subprocess.Popen(
        ["fw", "deploy", "topologies/seeg.yaml", "--headless", "--console-port", str(port)],
        cwd=seeg_home(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        match = re.search(r"token=([A-Za-z0-9_-]+)", line)
        if match:
            threading.Thread(target=proc.stderr.read, daemon=True).start()  # keep it drained
            console = Console(port, match.group(1))
            while console.robot_time() is None:
                time.sleep(0.2)
            return proc, console
    proc.kill()
    raise SystemExit("fw deploy did not print the console URL")


def streams(console: Console, n: int, stop: threading.Event) -> dict[str, int]:
    """Open `n` live views; count the served and the refused; read the served ones."""
    counts = {"served": 0, "refused": 0}
    sockets = []
    for _ in range(n):
        s = socket.create_connection(("127.0.0.1", console.port), timeout=5)
        s.sendall(
            f"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:{console.port}\r\n"
            f"Authorization: Bearer {console.token}\r\n\r\n".encode()
        )
        head = s.recv(64)
        if b" 200 " in head:
            counts["served"] += 1
            sockets.append(s)
        else:
            counts["refused"] += 1
            s.close()

    def drain() -> None:
        for s in sockets:
            s.setblocking(False)
        while not stop.is_set():
            for s in sockets:
                with contextlib.suppress(OSError):  # BlockingIOError: nothing yet
                    s.recv(65536)
            time.sleep(0.05)
        for s in sockets:
            s.close()

    threading.Thread(target=drain, daemon=True).start()
    return counts


def slowloris(console: Console, n: int, stop: threading.Event) -> dict[str, int]:
    """`n` connections that send a header byte every 2 s and never finish; re-opened
    when the console drops them (counted)."""
    counts = {"dropped": 0}

    def one() -> None:
        while not stop.is_set():
            try:
                s = socket.create_connection(("127.0.0.1", console.port), timeout=5)
                s.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: ")
                while not stop.wait(2.0):
                    s.sendall(b"a")
            except OSError:
                counts["dropped"] += 1
                time.sleep(0.1)

    for _ in range(n):
        threading.Thread(target=one, daemon=True).start()
    return counts


def measure(console: Console, window: float) -> dict[str, Any]:
    """Poll /api/state every 50 ms for `window` s; the robot's real-time factor."""
    latencies, failures = [], 0
    t0, r0 = time.monotonic(), console.robot_time()
    while time.monotonic() - t0 < window:
        start = time.perf_counter()
        try:
            console.state()
            latencies.append(time.perf_counter() - start)
        except (urllib.error.URLError, OSError, TimeoutError):
            failures += 1
        time.sleep(0.05)
    t1, r1 = time.monotonic(), console.robot_time()
    stats = percentiles(latencies)
    return {
        **stats,
        "max_us": max(latencies, default=float("nan")) * 1e6,
        "failures": failures,
        "real_time": (r1 - r0) / (t1 - t0) if r0 is not None and r1 is not None else float("nan"),
    }


def main() -> None:
    parser = bench_parser(__doc__, quick=None)
    parser.add_argument("--streams", type=int, default=200)
    parser.add_argument("--slow", type=int, default=50)
    parser.add_argument("--window", type=float, default=15.0)
    args = parser.parse_args()
    proc, console = deploy(free_port())
    stop = threading.Event()
    try:
        time.sleep(3)  # settle after start-up
        idle = measure(console, args.window)
        served = streams(console, args.streams, stop)
        slow = slowloris(console, args.slow, stop)
        time.sleep(2)
        loaded = measure(console, args.window)
    finally:
        stop.set()
        proc.terminate()
        proc.wait(60)
    rows = [("idle", idle), (f"{args.streams} streams + {args.slow} slow", loaded)]
    lines = [
        "# Console under load (SEEG deployment, waiting braked for START)",
        "",
        "| phase | GET /api/state p50 ms | p99 ms | max ms | failed | robot loop x real time |",
        "|---|---|---|---|---|---|",
        *(
            f"| {name} | {r['p50_us'] / 1e3:.1f} | {r['p99_us'] / 1e3:.1f} | "
            f"{r['max_us'] / 1e3:.1f} | {r['failures']} | {r['real_time']:.2f} |"
            for name, r in rows
        ),
        "",
        f"Live views: {served['served']} served, {served['refused']} refused (at most 16); "
        f"slow connections dropped by the console and re-opened: {slow['dropped']}.",
    ]
    targets = {
        "GET /api/state p99 <= 50 ms under load": loaded["p99_us"] <= 50_000,
        "no GET refused under load": loaded["failures"] == 0,
        "robot loop >= 0.95x real time under load": loaded["real_time"] >= 0.95,
    }
    write_report(
        args.out,
        "console_load",
        lines,
        targets,
        {"idle": idle, "loaded": loaded, "streams": served, "slow": slow},
    )


if __name__ == "__main__":
    main()
