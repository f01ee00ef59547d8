"""The container's process: `python -m framework.container_main --spec JSON` builds a
`Container` from its spec (components, activities, wiring, the safety monitor, local
switches), serves until SIGTERM/SIGINT and shuts down in order. `spawn_container`
starts one as a fresh interpreter (never fork: Zenoh sessions are not fork-safe).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from typing import Any

from framework.activity import Activity
from framework.bus import Bus, BusConfig
from framework.classes import add_import_paths, load_class
from framework.container import Container
from framework.control_requests import ContainerError
from framework.errors import FwError
from framework.local_switch import LocalSwitches
from framework.peer_clocks import PeerClocks
from framework.profiling import finish, from_environment
from framework.routes import RouteWatch
from framework.safety import SafetySpec

log = logging.getLogger("fw.container")


def build(spec: dict[str, Any], bus: Bus) -> Container:
    """A container with the components of `spec` added (configured/started if asked)."""
    container = Container(spec["name"], bus, beat=spec.get("beat"))
    add_import_paths(spec.get("import_paths", []))
    for item in spec.get("components", []):
        cls = load_class(item["class"])
        component = cls(item["name"])
        safety = item.get("safety")
        container.add(
            component,
            Activity.from_spec(item.get("activity")),
            item.get("properties"),
            item.get("outputs"),
            item.get("heartbeat"),
            SafetySpec.from_dict(safety) if safety else None,
        )
        for port, thinned in (item.get("thinned") or {}).items():
            for key, rate in thinned.items():
                container.connect_output(component.name, port, key, rate)
        for port, conn in (item.get("connections") or {}).items():
            container.connect(component.name, port, conn["key"], conn.get("policy"))
        for port, candidates in (item.get("prepare") or {}).items():
            for key in candidates:
                container.prepare(component.name, port, key)
        if item.get("configure", False) and not component.configure():
            raise ContainerError(f"{component.name}: configure failed: {component.last_error}")
        if item.get("start", False) and not component.start():
            raise ContainerError(f"{component.name}: start failed: {component.last_error}")
    container.key_hosts = dict(spec.get("key_hosts") or {})
    container.requester_host = spec.get("requester_host")
    if spec.get("peer_clocks"):
        container.clocks = PeerClocks(container.bus, spec["peer_clocks"])
        container.clocks.start()
    if spec.get("switches"):
        container.local_switches = LocalSwitches(
            container.bus,
            container.name,
            container.find_port,
            spec["switches"],
            lambda: container.requester_now(wait=False),  # runs in the bus's thread
        )
    if not bus.hub:
        container.routes = RouteWatch(bus, container.name, hold=container.holds_bus).start()
    container.start()
    return container


# Component processes keep Python's switch interval (5 ms): with 0.5 ms (tried,
# 2026-11-27) a thread forced to hand the interpreter over every half millisecond
# waited for the CPU each time it took it back on a saturated 2-core host (a Sensor
# Manager update of 5 ms CPU took 50-120 ms, 55 hand-overs; perf sched), and the SEEG
# approach stopped on that heartbeat in 3 of 3 runs, against 1 of 4 without. A device
# loop's process sets its own (framework/realtime.py): there the loop must not wait.


def raise_priority(nice: int, process: str) -> bool:
    """Run this process at `nice` (negative: ahead of the host's other programs), so
    a busy host does not starve the robot side or the safety producers past their
    deadlines; needs root or CAP_SYS_NICE, otherwise a warning and False."""
    try:
        current = os.getpriority(os.PRIO_PROCESS, 0)
        if current > nice:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
        return True
    except OSError as exc:
        log.warning(
            "process %s: cannot raise its priority to nice %d (%s): on a busy host a "
            "safety deadline may be missed and stop the robot",
            process,
            nice,
            exc.strerror,
        )
        return False


def serve(spec: dict[str, Any], ready: Callable[[], None] | None = None) -> int:
    """Run a container process until SIGTERM/SIGINT or a shutdown request."""
    done = threading.Event()
    starting = True

    def on_signal(*_: object) -> None:
        done.set()
        if starting:  # still constructing components: give up at once
            raise SystemExit(0)

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, on_signal)
    if spec.get("nice"):
        raise_priority(int(spec["nice"]), spec["name"])
    profiles = from_environment()  # FW_PROFILE: where this process spends its CPU
    bus = Bus(BusConfig.from_dict(spec["bus"]), hub=spec.get("hub", False), subject=spec["name"])
    try:
        container = build(spec, bus)
    except BaseException:
        bus.close()
        raise
    starting = False
    if ready is not None:
        ready()
    parent = os.getppid()
    while not done.is_set() and not bus.closed:
        done.wait(0.2)
        if os.getppid() != parent:  # whoever started us died: never linger as an orphan
            log.warning(
                "container %s: parent process %d is gone; shutting down", spec["name"], parent
            )
            break
    container.shutdown()
    finish(profiles, spec["name"])
    return 0


def spawn_container(spec: dict[str, Any], **popen: Any) -> subprocess.Popen[bytes]:
    """Start a container in a new Python process (never a fork)."""
    return subprocess.Popen(
        [sys.executable, "-m", "framework.container_main", "--spec", json.dumps(spec)], **popen
    )


def main(argv: list[str] | None = None) -> int:
    """`python -m framework.container_main --spec JSON`: one container process."""
    parser = argparse.ArgumentParser(
        prog="python -m framework.container_main", description="Host fw components in this process."
    )
    parser.add_argument("--spec", required=True, help="container specification as JSON")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    try:
        return serve(json.loads(args.spec))
    except FwError as exc:
        print(f"fw container: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # a component's own code failed while starting
        print(f"fw container: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
