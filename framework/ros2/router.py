"""A Zenoh router for ROS 2 nodes where no rmw_zenohd runs (`fw ros2 router`).

rmw_zenoh's nodes and fw's bridge meet at a Zenoh router: on a ROS machine that is
`ros2 run rmw_zenoh_cpp rmw_zenohd`. This is the same role with the default settings
that matter to them (a router, no multicast scouting, listening on rmw_zenohd's
port), for a machine without ROS: the tests, a laptop, the examples. It binds
loopback by default: it is the ROS network's router, which carries no fw credentials
and admits anyone who reaches it, so reaching it from other hosts is a choice to write
out (`--listen tcp/0.0.0.0:7447`) and to protect as docs/ros2.md says.
"""

from __future__ import annotations

import json
import signal
import threading
from typing import Any

import zenoh

from framework.ros2.link import DEFAULT_ROUTER, RosLinkError


def open_router(listen: str = DEFAULT_ROUTER) -> Any:
    """Open a Zenoh router session listening on `listen`; `RosLinkError` if it cannot
    (the port is taken: another router already runs there)."""
    config = zenoh.Config()
    for key, value in {
        "mode": "router",
        "listen/endpoints": [listen],
        "scouting/multicast/enabled": False,
    }.items():
        config.insert_json5(key, json.dumps(value))
    try:
        return zenoh.open(config)
    except Exception as exc:  # zenoh raises its own error type
        reason = str(exc).split(" at /")[0].strip()
        taken = " (is a router already there?)" if "in use" in reason.lower() else ""
        raise RosLinkError(f"cannot listen on {listen}: {reason}{taken}") from None


def run_router(listen: str = DEFAULT_ROUTER) -> int:
    """Run a router until SIGINT or SIGTERM; 0 on a clean stop."""
    session = open_router(listen)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print(
        f"fw ros2 router: a Zenoh router for ROS 2 nodes on {listen} (Ctrl-C stops it)", flush=True
    )
    done.wait()
    session.close()
    return 0
