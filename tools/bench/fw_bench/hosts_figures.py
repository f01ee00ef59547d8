"""`fw bench hosts`: the network's figures of the SEEG deployment on several machines
(topologies/seeg_hosts.yaml, built as network namespaces of this one:
framework/netns.py), beside the same run's figures on one host.

* **hop per link**: a Zenoh hop on a plain bus (half a round trip, as `fw bench zenoh`
  measures one host's) between the control host and each other host, and between the
  robot's host and the KRC on its FRI link;
* **sensor swap and collision reaction across hosts**: the experiments of `fw bench
  swap collision`, run by the control host's part (a child in the control namespace:
  `python -m fw_bench.hosts_figures --control ...`) while every other host runs its
  own `fw deploy --host`; and the same experiments on one host first, in this run;
* **bytes and packets per second per link**, both ways, while those experiments run
  (the arm moving most of the time): the kernel's counters of each host's link at the
  bridge, and of the FRI link at the KRC's end (FRI's datagrams and the KRC process's
  bus traffic, routed through the robot's host), as each host sends and receives.

* **a LAN's delay** (`lan`, 0.2 ms by default): the hops are timed on the bare links,
  then every host on the bridge is given that delay on what it sends (the kernel's
  netem where it has it, else fw's wire: framework/netns_delay.py), the hops are timed
  again (what the delay added, measured, is a row), and the deployment's experiments
  and counters run with it. The KRC's link keeps no delay of its own without netem
  (its FRI traffic's delay is `arm.impair`'s), and the report says so.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from fw_bench.files import seeg_home
from fw_bench.hosts_chaos import make_keys
from fw_bench.report import Row, stats

LINKED = ("tracking", "cameras", "robot")
"""The hosts on the bridge beside the control host."""
COUNTERS = ("rx_bytes", "tx_bytes", "rx_packets", "tx_packets")
LAN = 0.0002
"""s each way: a LAN's delay on what each host sends (the issue's 0.2 ms)."""


def link_hop(hosts: Any, near: str, far: str, address: str, count: int) -> list[float]:
    """One-way hops (s) between `near` (a pinger listening on `address`, its address)
    and `far` (an echo joining it), over a plain Zenoh bus: half of each round trip."""
    port = 17900
    echo = subprocess.Popen(
        hosts.command(
            far, sys.executable, "-m", "fw_bench.hosts_figures", "--echo", address, str(port)
        ),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        ping = subprocess.run(
            hosts.command(
                near,
                sys.executable,
                "-m",
                "fw_bench.hosts_figures",
                "--ping",
                address,
                str(port),
                str(count),
            ),
            capture_output=True,
            text=True,
            timeout=120,
        )
    finally:
        if echo.stdin:
            echo.stdin.close()
        echo.wait(10)
    lines = [line for line in ping.stdout.splitlines() if line.startswith("[")]
    return json.loads(lines[-1]) if lines else []


def _bus(address: str, port: int, hub: bool) -> Any:
    from framework.bus import Bus, BusConfig

    config = BusConfig(namespace="fw_bench_link", hub_port=port, host=address)
    if not hub:  # the echo listens on its own host's address, and connects to the hub
        import dataclasses

        config = dataclasses.replace(config, listen="0.0.0.0")
    return Bus(config, hub=hub)


def _echo(address: str, port: int) -> None:
    from fw_bench.baseline import PING, PONG

    bus = _bus(address, port, hub=False)
    publisher = bus.publisher(PONG, cache=False)
    bus.subscribe(PING, lambda sample: publisher.put(sample.payload.to_bytes()), history=False)
    sys.stdin.read()
    bus.close()


def _ping(address: str, port: int, count: int) -> None:
    import threading

    from fw_bench.baseline import PING, PONG

    bus = _bus(address, port, hub=True)
    answered = threading.Event()
    bus.subscribe(PONG, lambda sample: answered.set(), history=False)
    publisher = bus.publisher(PING, cache=False)
    bus.wait_for_peers(1, 20.0)
    hops: list[float] = []
    for k in range(count + 20):
        answered.clear()
        sent = time.perf_counter()
        publisher.put(k.to_bytes(8, "little"))
        if answered.wait(2.0) and k >= 20:
            hops.append((time.perf_counter() - sent) / 2)
    print(json.dumps(hops), flush=True)
    bus.close()


def _counters(hosts: Any) -> dict[str, dict[str, int]]:
    """What each host sent and received on its link, by the kernel's counters: a host's
    link at the bridge (what the bridge's port receives, the host sent), and the KRC's
    FRI link at the KRC's end."""
    out: dict[str, dict[str, int]] = {}
    for host in hosts.names:
        base = Path("/sys/class/net") / hosts.bridge_port(host) / "statistics"
        read = {c: int((base / c).read_text()) for c in COUNTERS}
        out[host] = {
            "sent_bytes": read["rx_bytes"],
            "received_bytes": read["tx_bytes"],
            "sent_packets": read["rx_packets"],
            "received_packets": read["tx_packets"],
        }
    read = {}
    for c in COUNTERS:
        said = subprocess.run(
            hosts.command("krc", "cat", f"/sys/class/net/fri0/statistics/{c}"),
            capture_output=True,
            text=True,
        )
        read[c] = int(said.stdout.strip() or 0)
    out["krc (FRI link)"] = {
        "sent_bytes": read["tx_bytes"],
        "received_bytes": read["rx_bytes"],
        "sent_packets": read["tx_packets"],
        "received_packets": read["rx_packets"],
    }
    return out


def _control(topology: Path, keys: Path, trials: int) -> None:
    """The control host's part (in its namespace): deploy it, say `ready`, wait for
    `go`, run the swap and collision experiments, say `done`, print them as JSON."""
    from fw_bench import latency
    from fw_bench.seeg_run import SeegRun

    run = SeegRun(hosts=(topology, keys)).start()
    try:
        print("ready", flush=True)
        sys.stdin.readline()
        began = time.time()
        swap = latency.sensor_swap(run, trials)
        collision = latency.collision_reaction(run, max(3, trials // 2))
        print("done", flush=True)
        sys.stdin.readline()
        print(json.dumps(_series(swap, collision, time.time() - began)), flush=True)
    finally:
        run.stop()


def _series(swap: list[Any], collision: list[Any], seconds: float) -> dict[str, Any]:
    timed = [t for t in collision if not t.detail.get("preempted")]
    return {
        "swap_ms": [t.latency * 1e3 for t in swap],
        "collision_ms": [t.latency * 1e3 for t in timed],
        "brake_ms": [t.detail["brake"] * 1e3 for t in timed],
        "preempted": len(collision) - len(timed),
        "seconds": seconds,
    }


def _hops(hosts: Any, count: int, label: str) -> tuple[list[Row], dict[str, float]]:
    """The hop between the control host and each other (and robot <-> KRC): rows, and
    each link's p50 (ms)."""
    rows: list[Row] = []
    medians: dict[str, float] = {}
    pairs = [(h, "control", h, hosts.address("control")) for h in LINKED]
    pairs.append(("krc", "robot", "krc", hosts.krc_link_address))
    for link, near, far, address in pairs:
        hops = [h * 1e3 for h in link_hop(hosts, near, far, address, count)]
        if not hops:
            continue
        s = stats(hops)
        name = f"hop {near} <-> {far}" + (" (FRI link)" if far == "krc" else "")
        medians[link] = s["p50"]
        rows.append(Row("hosts", f"{name} p50{label}", s["p50"], n=len(hops)))
        if far != "krc":
            rows.append(Row("hosts", f"{name} p99{label}", s["p99"], n=len(hops)))
    return rows, medians


def delay_every_link(hosts: Any, lan: float) -> list[str]:
    """Give every host on the bridge `lan` s of delay on what it sends (netem, else fw's
    wire); the hosts whose link could not be delayed, each with why."""
    from framework.netns import NetnsError

    refused = []
    for host in ("control", *LINKED):
        try:
            hosts.impair(host, delay=lan)
        except NetnsError as exc:
            refused.append(f"{host}: {exc}")
    return refused


def run(quick: bool, context: dict[str, Any], lan: float = LAN) -> list[Row]:
    """One host, then five (module docstring); `lan`: s of delay on what each host
    on the bridge sends (0: bare links)."""
    from framework import netns
    from fw_bench import latency
    from fw_bench.seeg_run import BenchError, SeegRun

    why = netns.available()
    if why:
        raise BenchError(f"hosts needs the hosts as network namespaces: {why}")
    trials = 5 if quick else 20
    hop_count = 200 if quick else 1000
    single = SeegRun().start()
    try:
        one = _series(
            latency.sensor_swap(single, trials),
            latency.collision_reaction(single, max(3, trials // 2)),
            0.0,
        )
    finally:
        single.stop()
    home = seeg_home()
    topology = home / "topologies" / "seeg_hosts.yaml"
    folder = Path(tempfile.mkdtemp(prefix="fw-bench-hosts-"))
    hosts = netns.Hosts(prefix="fwb-", bridge="fwbbr0").up()
    parts: list[Any] = []
    rows: list[Row] = []
    try:
        keys = make_keys(topology, folder)
        bare, bare_p50 = _hops(hosts, hop_count, ", bare link")
        rows += bare
        if lan > 0:
            refused = delay_every_link(hosts, lan)
            if refused:
                raise BenchError("cannot add the LAN's delay: " + "; ".join(refused))
            slow, slow_p50 = _hops(hosts, hop_count, f", {lan * 1e3:g} ms LAN")
            rows += slow
            for link in LINKED:
                if link in bare_p50 and link in slow_p50:
                    rows.append(
                        Row(
                            "hosts",
                            f"delay the LAN added, control <-> {link} (asked {lan * 1e3:g} ms)",
                            slow_p50[link] - bare_p50[link],
                            n=hop_count,
                        )
                    )
        parts = hosts.deploy_others(topology, keys, home)
        argv = [sys.executable, "-m", "fw_bench.hosts_figures", "--control", str(topology)]
        argv += [str(keys), str(trials)]
        child = subprocess.Popen(
            hosts.command("control", "env", f"FW_NETNS_PREFIX={hosts.prefix}", *argv),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=home,
        )
        assert child.stdin is not None and child.stdout is not None
        if child.stdout.readline().strip() != "ready":
            raise BenchError("the control host's part did not come up")
        before, t0 = _counters(hosts), time.monotonic()
        child.stdin.write("go\n")
        child.stdin.flush()
        child.stdout.readline()  # done
        after, seconds = _counters(hosts), time.monotonic() - t0
        child.stdin.write("end\n")
        child.stdin.flush()
        lines = [line for line in child.stdout.read().splitlines() if line.startswith("{")]
        child.wait(60)
        if not lines:
            raise BenchError("the control host's part said no figures")
        many = json.loads(lines[-1])
    finally:
        hosts.end(parts)
        hosts.down()
        shutil.rmtree(folder, ignore_errors=True)
    single_swap = stats(one["swap_ms"])["p50"] if one["swap_ms"] else None
    targets = {  # five hosts: the swap within 2x one host's; the collision within 1 ms
        "swap_ms": 2 * single_swap if single_swap else None,
        "collision_ms": 1.0,
    }
    for name, key in (("sensor swap", "swap_ms"), ("collision reaction", "collision_ms")):
        for label, series in (("one host", one), ("five hosts", many)):
            if series[key]:
                s = stats(series[key])
                target = targets[key] if label == "five hosts" else None
                rows.append(
                    Row(
                        "hosts",
                        f"{name} L p50, {label}",
                        s["p50"],
                        target=target,
                        n=len(series[key]),
                    )
                )
                rows.append(Row("hosts", f"{name} L p99, {label}", s["p99"], n=len(series[key])))
        preempted = many["preempted"] if key == "collision_ms" else 0
        if preempted:
            rows.append(
                Row(
                    "hosts",
                    "collisions stopped first by separation monitoring, five hosts",
                    float(preempted),
                    unit="",
                )
            )
    for link in after:
        rate = {c: (after[link][c] - before[link][c]) / seconds for c in after[link]}
        rows += [
            Row("hosts", f"{link} sends", rate["sent_bytes"] / 1e3, unit="kB/s"),
            Row("hosts", f"{link} receives", rate["received_bytes"] / 1e3, unit="kB/s"),
            Row("hosts", f"{link} sends", rate["sent_packets"], unit="packets/s"),
            Row("hosts", f"{link} receives", rate["received_packets"], unit="packets/s"),
        ]
    context.setdefault("series", {})["hosts"] = {"one": one, "five": many}
    notes = context.setdefault("notes", [])
    if lan <= 0:
        notes.append("hosts: no LAN delay added: links without delay of their own")
    elif not netns.netem_available():
        notes.append(
            f"hosts: the {lan * 1e3:g} ms LAN delay is fw's wire (no sch_netem here: "
            "framework/netns_delay.py), on every host on the bridge; the KRC's FRI link "
            "has none"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    """The children: `--echo ADDRESS PORT`, `--ping ADDRESS PORT COUNT`, `--control
    TOPOLOGY KEYS TRIALS`."""
    parser = argparse.ArgumentParser(prog="python -m fw_bench.hosts_figures")
    parser.add_argument("--echo", nargs=2)
    parser.add_argument("--ping", nargs=3)
    parser.add_argument("--control", nargs=3)
    args = parser.parse_args(argv)
    if args.echo:
        _echo(args.echo[0], int(args.echo[1]))
    elif args.ping:
        _ping(args.ping[0], int(args.ping[1]), int(args.ping[2]))
    elif args.control:
        _control(Path(args.control[0]), Path(args.control[1]), int(args.control[2]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
